"""Load TOML configs into pydantic models; every problem becomes one :class:`ConfigError` line.

A bad file must give the user one line — file, field path, problem, what was given — and exit code 2,
never a traceback (architecture.md, "Configs"). Cross-field checks that pydantic cannot place on a
field (a sensor off the beam, a pulse shorter than two samples) raise :class:`ConfigFieldError` with
an explicit path from a model's ``check()`` method; the loader formats them the same way.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any, TypeVar

from pydantic import BaseModel, ValidationError

from analysis.errors import BadInput

M = TypeVar("M", bound=BaseModel)

#: Discriminator tags pydantic inserts into error locations of tagged unions; not field names.
_UNION_TAGS = {"beam", "lumped"}


class ConfigError(BadInput):
    """A config file is unusable. ``str(err)`` is the whole one-line message."""

    def __init__(self, path: str | Path, field: str | None, problem: str) -> None:
        self.path = str(path)
        self.field = field
        self.problem = problem
        where = f"{self.path}: {field}" if field else self.path
        super().__init__(f"{where}: {problem}")


class ConfigFieldError(ValueError):
    """Raised by a model's ``check()`` for a cross-field problem at a known path."""

    def __init__(self, field: str, problem: str) -> None:
        self.field = field
        self.problem = problem
        super().__init__(f"{field}: {problem}")


def format_loc(loc: tuple[Any, ...]) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        elif isinstance(part, str) and (part in _UNION_TAGS or "[" in part):
            continue
        else:
            out += ("." if out else "") + str(part)
    return out or "(top level)"


def _describe(err: dict[str, Any]) -> str:
    typ = err.get("type", "")
    msg = str(err.get("msg", "invalid value"))
    if typ == "extra_forbidden":
        return "unknown key (check the spelling; see the example configs in configs/)"
    if typ == "missing":
        return "required key is missing"
    msg = msg.removeprefix("Value error, ")
    if "input" in err and typ not in ("model_type", "dict_type"):
        shown = repr(err["input"])
        if len(shown) > 60:
            shown = shown[:57] + "..."
        msg += f" (got {shown})"
    return msg


def validation_error_to_config_error(path: str | Path, exc: ValidationError) -> ConfigError:
    errors = exc.errors(include_url=False)
    first = errors[0]
    problem = _describe(first)
    if len(errors) > 1:
        problem += f" [and {len(errors) - 1} more problem{'s' if len(errors) > 2 else ''}]"
    return ConfigError(path, format_loc(tuple(first.get("loc", ()))), problem)


def parse_toml(path: str | Path) -> dict[str, Any]:
    p = Path(path)
    try:
        text = p.read_bytes()
    except FileNotFoundError:
        raise ConfigError(p, None, "file not found") from None
    except IsADirectoryError:
        raise ConfigError(p, None, "is a directory, expected a .toml file") from None
    except OSError as exc:
        raise ConfigError(p, None, f"cannot read: {exc.strerror}") from None
    try:
        return tomllib.loads(text.decode("utf-8"))
    except UnicodeDecodeError:
        raise ConfigError(p, None, "not UTF-8 text; a config must be a TOML file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(p, None, f"invalid TOML: {exc}") from None


def validate(model: type[M], data: dict[str, Any], path: str | Path = "<config>") -> M:
    """Validate ``data`` into ``model`` and run its ``check()`` if it has one."""
    try:
        obj = model.model_validate(data)
    except ValidationError as exc:
        raise validation_error_to_config_error(path, exc) from None
    check = getattr(obj, "check", None)
    if callable(check):
        try:
            check()
        except ConfigFieldError as exc:
            raise ConfigError(path, exc.field, exc.problem) from None
    return obj


def load_config(model: type[M], path: str | Path) -> M:
    """Parse and validate a TOML file; raises :class:`ConfigError` (one line) on any problem."""
    return validate(model, parse_toml(path), path)
