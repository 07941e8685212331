"""Config models (pydantic) and the TOML loader with one-line errors."""

from daq.config.loader import ConfigError, ConfigFieldError, load_config
from daq.config.rig import RigConfig

__all__ = ["ConfigError", "ConfigFieldError", "RigConfig", "load_config"]
