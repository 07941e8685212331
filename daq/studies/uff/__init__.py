"""UFF: the datasets through pyuff (``datasets``) and ``gvt export --format uff`` (``export``)."""
