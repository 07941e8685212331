"""Units of imported ordinates to SI, through pint: a file's ``g``, ``lbf``, ``in/s``, ``mm`` become m/s^2, N, m/s, m.

Why pint and not a table: other tools spell units many ways (``m/s^2``, ``m/s2``, ``g``, ``lbf``, ``kN``, ``mm/s``),
and a table that misses one guesses or drops it. pint parses each and converts it exactly; a unit it does not
know, or one of a quantity gvtlink does not measure (a temperature, a voltage), is one line and exit 2, never a
guess (issue 31). ``g`` is standard gravity (9.80665 m/s^2, ISO 80000-3) as in ``analysis/model/units.py``, whose
registry this reuses (one per process).
"""

from __future__ import annotations

import re

from daq.studies.importing.data import ImportError_

#: What gvtlink measures, each with its SI unit (the log's unit strings) and the pint dimensionality.
QUANTITIES = {
    "acceleration": ("m/s^2", "[length] / [time] ** 2"),
    "velocity": ("m/s", "[length] / [time]"),
    "displacement": ("m", "[length]"),
    "force": ("N", "[mass] * [length] / [time] ** 2"),
    "pressure": ("Pa", "[mass] / [length] / [time] ** 2"),
}
_POWER = re.compile(r"(?<=[A-Za-z])(\d)(?![\d.])")  # "m/s2" -> "m/s^2" (a power written without the caret)
_BLANK = {"", "none", "nan", "-", "?", "unknown"}


def _pint_text(unit: str) -> str:
    from analysis.model.units import _unit_text

    text = re.sub(r"\bsecs?\b", "s", unit.strip()).replace("**", "^")
    return _unit_text(_POWER.sub(r"^\1", text))


def si_factor(unit: str, where: str) -> tuple[float, str]:
    """``unit`` (as a file writes it) -> (factor to SI, quantity): value_SI = factor * value. ImportError_ naming
    ``where`` for a missing unit, one pint cannot parse, or one of no quantity gvtlink measures."""
    from analysis.model.units import _units

    if unit is None or unit.strip().lower() in _BLANK:
        raise ImportError_(f"{where}: no unit; gvtlink does not guess one: give the unit in the file (or the channel table)")
    try:
        q = _units().Quantity(1.0, _pint_text(unit))
    except Exception as exc:  # pint's UndefinedUnitError, tokenize errors, ...: one line whatever it raised
        raise ImportError_(f"{where}: unit {unit!r} is not understood ({type(exc).__name__}); "
                           "write e.g. m/s^2, g, m/s, mm, N, lbf, Pa") from None  # fmt: skip
    for quantity, (si, dim) in QUANTITIES.items():
        if q.dimensionality == _units().get_dimensionality(dim):
            return float(q.to(si).magnitude), quantity
    raise ImportError_(f"{where}: unit {unit!r} is not of a vibration quantity (acceleration, velocity, displacement, "
                       f"force, pressure); not imported")  # fmt: skip


def ratio_factor(num: str, den: str, where: str) -> tuple[float, str, str]:
    """An FRF's ``num/den`` units -> (factor to SI, numerator quantity, denominator quantity)."""
    a, qa = si_factor(num, f"{where} (numerator)")
    b, qb = si_factor(den, f"{where} (denominator)")
    return a / b, qa, qb


__all__ = ["QUANTITIES", "ratio_factor", "si_factor"]
