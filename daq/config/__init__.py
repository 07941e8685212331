"""Session config models (pydantic). The rig schema and the TOML loader live beside the rig model in
``analysis/model`` (``config.py``, ``loader.py``): the analysis needs them and must not import ``daq``."""
