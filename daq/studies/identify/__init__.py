"""``gvt identify``: NSI from a sweep (``sweep``) or a session log (``log``), RFS (``rfs``), validation (``validate``)."""
