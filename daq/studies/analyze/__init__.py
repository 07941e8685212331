"""``gvt analyze``: the near-live kernels in batch over a log (``batch``) and its tables (``tables``)."""
