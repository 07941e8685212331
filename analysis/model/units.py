"""Sensitivities and directions as a calibration sheet and a test plan write them, in SI units.

A sensitivity is written with its unit ("100 mV/g", "1.02 mV/(m/s^2)", "2.25 mV/N", "11.2 mV/lbf", a charge sensor's
"10 pC/N" with its amplifier's gain "1 mV/pC") and converted by pint (https://pint.readthedocs.io) to volts per SI
unit, so a unit mistake is an error, never a silent factor of 9.81 or 1000. In a sensitivity ``g`` is standard
gravity (9.80665 m/s^2, ISO 80000-3), as on every accelerometer calibration sheet, not the gram pint reads it as. A
direction is +X .. -Z, kept as the UFF direction code +-1..3 of dataset 58, record 6, field 7.

Why a module of its own: the rig schema (analysis/model/config.py) converts what a rig file writes as it validates
it, and the channel table (analysis/model/channels.py) converts a CSV's rows and builds channels from a built rig, so
these conversions sit below both (issue 28: the schema imports no behaviour from the modules above it). pint loads
on the first conversion, not on import.
"""

from __future__ import annotations

import re
from functools import lru_cache

SI_UNITS = {"acceleration": "m/s^2", "velocity": "m/s", "displacement": "m", "force": "N"}
#: UFF direction codes (dataset 58 record 6 fields 7 and 10; dataset 55 puts +-1..3 in r1..r3).
DIRECTIONS = {"+X": 1, "-X": -1, "+Y": 2, "-Y": -2, "+Z": 3, "-Z": -3}
DIRECTION_HELP = "use one of +X, -X, +Y, -Y, +Z, -Z"

_NUMBER = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*(.*?)\s*$")
_BARE_G = re.compile(r"(?<![A-Za-z_0-9])g(?![A-Za-z_0-9])")


def parse_direction(text: str) -> int:
    """``"+Z"``, ``"z"``, ``"-x"``, ``"−Y"`` (a typographic minus) -> the UFF code (+3, +3, -1, -2); ValueError else."""
    t = str(text).strip().upper().replace("\u2212", "-").replace(" ", "")
    if len(t) == 2 and t[1] in "+-" and t[0] in "XYZ":  # "Z+" written the other way round
        t = t[1] + t[0]
    if len(t) == 1:
        t = "+" + t
    if t not in DIRECTIONS:
        raise ValueError(f"{text!r} is not a direction; {DIRECTION_HELP}")
    return DIRECTIONS[t]


def direction_label(code: int) -> str:
    """The UFF code +-1..3 as ``"+X"`` .. ``"-Z"``."""
    for label, c in DIRECTIONS.items():
        if c == code:
            return label
    raise ValueError(f"direction code {code} is not a translation (+-1, +-2, +-3)")


@lru_cache(maxsize=1)
def _units():
    """One pint registry for the process (building it reads pint's definition file: ~0.1 s)."""
    import pint

    return pint.UnitRegistry()


def _unit_text(unit: str) -> str:
    """A calibration sheet's unit in pint's syntax: a bare ``g`` is standard gravity (g_n), not the gram."""
    return _BARE_G.sub("g_n", unit.replace("\u00b5", "u").replace("\u03bc", "u").replace("\u2212", "-"))


def split_value(text: str) -> tuple[float, str]:
    """``"100 mV/g"`` -> (100.0, "mV/g"); ValueError when it does not start with a number."""
    m = _NUMBER.match(str(text))
    if not m:
        raise ValueError(f'{text!r} does not start with a number; write it as e.g. "100 mV/g"')
    return float(m.group(1)), m.group(2)


def _quantity(value: float, unit: str):
    """A pint quantity; ValueError (one line) for a unit pint cannot parse (its parser raises many kinds)."""
    try:
        return _units().Quantity(float(value), _unit_text(unit))
    except Exception as exc:  # pint's UndefinedUnitError, tokenize's TokenError, SyntaxError, ...
        raise ValueError(
            f"unit {unit!r} is not understood ({type(exc).__name__}); write e.g. mV/g, mV/(m/s^2), mV/N, pC/N"
        ) from None


def sensitivity_si(value: float, unit: str, gain: str | None = None) -> tuple[float, str]:
    """Convert a sensitivity to (V per SI unit, quantity). ``unit`` is electrical per mechanical: mV/g, V/(m/s^2),
    mV/(m/s), mV/mm, mV/N, mV/lbf ...; a charge sensitivity (pC/N, pC/g) needs ``gain``, the charge amplifier's
    output per charge ("1 mV/pC"). ValueError with the reason and the fix."""
    q = _quantity(value, unit)
    if any(q.is_compatible_with(f"C/({si})") for si in SI_UNITS.values()):
        if not gain:
            raise ValueError(f'{value:g} {unit} is a charge sensitivity; give the charge amplifier\'s gain (e.g. "1 mV/pC")')
        g = _quantity(*split_value(gain))
        if not g.is_compatible_with("V/C"):
            raise ValueError(f'gain {gain!r} is not volts per charge; write it as e.g. "1 mV/pC"')
        q = q * g
    elif gain:
        raise ValueError(f"a gain ({gain!r}) applies to a charge sensitivity (pC/N, pC/g), not to {unit!r}")
    for quantity, si in SI_UNITS.items():
        if q.is_compatible_with(f"V/({si})"):
            v = float(q.to(f"V/({si})").magnitude)
            if not v > 0:
                raise ValueError(f"sensitivity {value:g} {unit} must be positive")
            return v, quantity
    raise ValueError(
        f"{unit!r} is not volts (or charge) per acceleration, velocity, displacement or force; "
        "write e.g. mV/g, mV/(m/s^2), mV/(m/s), mV/mm, mV/N, pC/N"
    )


def parse_sensitivity(text: str, gain: str | None = None) -> tuple[float, str]:
    """``"100 mV/g"`` -> (V per SI unit, quantity); see :func:`sensitivity_si`."""
    value, unit = split_value(text)
    if not unit:
        raise ValueError(f'{text!r} has no unit; write it as e.g. "100 mV/g"')
    return sensitivity_si(value, unit, gain)


__all__ = [
    "DIRECTIONS",
    "DIRECTION_HELP",
    "SI_UNITS",
    "direction_label",
    "parse_direction",
    "parse_sensitivity",
    "sensitivity_si",
    "split_value",
]
