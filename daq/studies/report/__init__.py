"""``gvt report``: the session report (``build``) and its sections."""
