"""What a person sees: the rerun layout and drawing (``recording``, ``logger``, ``frf``, ``modes``, ``scores``) — docs/view.md.

Shared by the live view lane (``daq/lanes/view.py``) and the offline studies (``daq/studies/analyze/rrd.py``,
``gvt modal --rrd``, the report).
"""
