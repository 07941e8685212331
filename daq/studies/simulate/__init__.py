"""``gvt simulate``: one hit into an .npz (``hit``) or a whole impact session into a log (``session``)."""
