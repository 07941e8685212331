"""Load TOML configs into pydantic models; every problem becomes one :class:`ConfigError` line.

A bad file must give the user one line — file, field path, problem, what was given — and exit code 2,
never a traceback (architecture.md, "Configs"). Cross-field checks that pydantic cannot place on a
field (a sensor off the beam, a pulse shorter than two samples) raise :class:`ConfigFieldError` with
an explicit path from a model's ``check()`` method; the loader formats them the same way.

Values that would cost unbounded memory or time are refused here too, before anything is allocated:
:func:`at_most` / :func:`at_least` / :func:`at_most_items` put a named limit on a field and say the limit
(and why it exists) in the message. The limits themselves live beside the schemas that use them
(``analysis/model/config.py``, ``daq/config/session.py``).
"""

from __future__ import annotations

import math
import re
import tomllib
from pathlib import Path
from typing import Any, TypeVar

from pydantic import AfterValidator, BaseModel, ValidationError

from analysis.errors import BadInput

M = TypeVar("M", bound=BaseModel)

#: Discriminator tags pydantic inserts into error locations of tagged unions; not field names.
_UNION_TAGS = {"beam", "lumped", "matrices"}

#: The largest config file read. The shipped configs are 1-5 kB and a rig with 255 sensors written out one
#: ``[[sensors]]`` table each is ~40 kB; the cap keeps a wrong path (a log, /dev/zero, a FIFO) from being read
#: into memory whole.
MAX_CONFIG_BYTES = 1 << 20

UNKNOWN_KEY = "unknown key (check the spelling; see the example configs in configs/)"

#: "field: problem" at the start of a model-level message: the problem belongs to that field.
_FIELD_PREFIX = re.compile(r"^([a-z_][a-z0-9_]*): (.+)$", re.S)


class ConfigError(BadInput):
    """A config file is unusable. ``str(err)`` is the whole one-line message."""

    def __init__(self, path: str | Path, field: str | None, problem: str) -> None:
        self.path = str(path)
        self.field = field
        self.problem = " ".join(problem.split())  # one line, whatever a validator wrote
        where = f"{self.path}: {field}" if field else self.path
        super().__init__(f"{where}: {self.problem}")


class ConfigFieldError(ValueError):
    """Raised by a model's ``check()`` for a cross-field problem at a known path."""

    def __init__(self, field: str, problem: str) -> None:
        self.field = field
        self.problem = problem
        super().__init__(f"{field}: {problem}")


# --- limits -------------------------------------------------------------------------------------------
def _fmt(v: float, unit: str = "") -> str:
    num = f"{v:g}" if isinstance(v, float) else str(v)
    return f"{num} {unit}" if unit else num


def at_most(limit: float, unit: str, why: str) -> AfterValidator:
    """A field's upper limit, for ``Annotated[float, Field(gt=0), at_most(...)]``: the message names the limit,
    its unit and what it protects (pydantic's own ``le`` says only "less than or equal to 604800")."""

    def check(v: Any) -> Any:
        if v is not None and v > limit:
            raise ValueError(f"above the limit of {_fmt(limit, unit)} ({why})")
        return v

    return AfterValidator(check)


def at_least(limit: float, unit: str, why: str) -> AfterValidator:
    """A field's lower limit (e.g. a sample rate of at least 1 Hz), worded like :func:`at_most`."""

    def check(v: Any) -> Any:
        if v is not None and v < limit:
            raise ValueError(f"below the limit of {_fmt(limit, unit)} ({why})")
        return v

    return AfterValidator(check)


def at_most_items(limit: int, what: str, why: str) -> AfterValidator:
    """A list's length limit: "5000 masses: above the limit of 2000 (...)"."""

    def check(v: Any) -> Any:
        if v is not None and len(v) > limit:
            raise ValueError(f"{len(v)} {what}: above the limit of {limit} ({why})")
        return v

    return AfterValidator(check)


def check_limit(field: str, value: float, limit: float, unit: str, why: str) -> None:
    """The same limit for a value a model computes (a total, a product): :class:`ConfigFieldError` at ``field``."""
    if value > limit:
        raise ConfigFieldError(field, f"{_fmt(value, unit)}: above the limit of {_fmt(limit, unit)} ({why})")


def non_finite(obj: Any, prefix: str = "") -> tuple[str, float] | None:
    """The path and value of the first ``inf``/``nan`` inside a free-form table (a driver's ``config``), or None.
    pydantic's ``allow_inf_nan=False`` covers typed fields only; an ``Any`` table is walked here."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return prefix, obj
    if isinstance(obj, dict):
        for k, v in obj.items():
            found = non_finite(v, f"{prefix}.{k}" if prefix else str(k))
            if found is not None:
                return found
    elif isinstance(obj, list | tuple):
        for i, v in enumerate(obj):
            found = non_finite(v, f"{prefix}[{i}]")
            if found is not None:
                return found
    return None


# --- formatting ---------------------------------------------------------------------------------------
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


def _shown(value: Any) -> str:
    shown = repr(value)
    return shown if len(shown) <= 60 else shown[:57] + "..."


def _describe(err: dict[str, Any], unknown_key: str = UNKNOWN_KEY) -> tuple[str, str]:
    """(extra location, problem) of one pydantic error. A model-level message "field: problem" (a driver's
    ``model_validator``) is moved onto that field; a whole table is never echoed back as "(got {...})"."""
    typ = err.get("type", "")
    msg = str(err.get("msg", "invalid value"))
    if typ == "extra_forbidden":
        return "", unknown_key
    if typ == "missing":
        return "", "required key is missing"
    msg = msg.removeprefix("Value error, ").removeprefix("Assertion failed, ")
    value = err.get("input")
    extra = ""
    if isinstance(value, dict):
        m = _FIELD_PREFIX.match(msg)
        if m is not None and m.group(1) in value:
            extra, msg, value = m.group(1), m.group(2), value[m.group(1)]
        elif m is not None:
            extra, msg = m.group(1), m.group(2)
    if "input" in err and typ not in ("model_type", "dict_type") and not isinstance(value, dict):
        msg += f" (got {_shown(value)})"
    return extra, msg


def validation_error_to_config_error(
    path: str | Path, exc: ValidationError, prefix: str = "", unknown_key: str = UNKNOWN_KEY
) -> ConfigError:
    """One line for a :class:`ValidationError`: the first problem (its field path under ``prefix``), and how
    many more there are."""
    errors = exc.errors(include_url=False)
    first = errors[0]
    extra, problem = _describe(first, unknown_key)
    if len(errors) > 1:
        problem += f" [and {len(errors) - 1} more problem{'s' if len(errors) > 2 else ''}]"
    loc = tuple(first.get("loc", ()))
    field = format_loc(loc) if loc else ""
    field = ".".join(p for p in (prefix, field, extra) if p)
    return ConfigError(path, field or "(top level)", problem)


# --- reading ------------------------------------------------------------------------------------------
def parse_toml(path: str | Path) -> dict[str, Any]:
    p = Path(path)
    try:
        with p.open("rb") as f:
            text = f.read(MAX_CONFIG_BYTES + 1)
    except FileNotFoundError:
        raise ConfigError(p, None, "file not found") from None
    except IsADirectoryError:
        raise ConfigError(p, None, "is a directory, expected a .toml file") from None
    except OSError as exc:
        raise ConfigError(p, None, f"cannot read: {exc.strerror or exc}") from None
    if len(text) > MAX_CONFIG_BYTES:
        raise ConfigError(
            p, None, f"larger than the limit of {MAX_CONFIG_BYTES // 1024} kB for a config file; is this a TOML config?"
        )
    try:
        return tomllib.loads(text.decode("utf-8"))
    except UnicodeDecodeError:
        raise ConfigError(p, None, "not UTF-8 text; a config must be a TOML file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(p, None, f"invalid TOML: {exc}") from None


def validate(model: type[M], data: dict[str, Any], path: str | Path = "<config>") -> M:
    """Validate ``data`` into ``model`` and run its ``check()`` if it has one. A model with a private
    ``_source`` attribute is told the file it came from (for messages of later checks, e.g. against a rig)."""
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
    if "_source" in (getattr(model, "__private_attributes__", None) or {}):
        obj._source = str(path)  # type: ignore[attr-defined]
    return obj


def load_config(model: type[M], path: str | Path) -> M:
    """Parse and validate a TOML file; raises :class:`ConfigError` (one line) on any problem."""
    return validate(model, parse_toml(path), path)
