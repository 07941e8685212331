"""The channel table: what each measured channel is, where it sits and how it converts volts to SI units.

Each channel has a name, a quantity (acceleration, velocity, displacement, force), a node id with its 3-D
coordinates (m), a direction (+X .. -Z, stored as the UFF direction code +-1..3 of dataset 58, record 6, field 7)
and a sensitivity in SI units (V per m/s^2, V/(m/s), V/m or V/N). Sensitivities and directions are written as on a
calibration sheet and converted by analysis/model/units.py (pint), so a unit mistake is an error, never a silent
factor of 9.81 or 1000.

A table comes from the rig (its sensors' ``node``, ``direction``, ``sensitivity`` fields and its geometry) or from
a CSV file ``name,node,x,y,z,direction,sensitivity,unit`` (optional columns ``gain`` and ``quantity``); a bad row
is one line: file:line: what is wrong and how to fix it.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from analysis.errors import BadInput
from analysis.model.units import SI_UNITS, direction_label, parse_direction, sensitivity_si

if TYPE_CHECKING:
    from analysis.model.rig import Rig

CSV_COLUMNS = ("name", "node", "x", "y", "z", "direction", "sensitivity", "unit")
#: A channel table holds at most the rig's channel limit (analysis/model/config.py MAX_CHANNELS); its file is small.
MAX_CSV_BYTES = 1 << 20
MAX_CSV_ROWS = 256


class ChannelTableError(BadInput):
    """A channel table (CSV) that cannot be used; ``str`` is one line: file:line: what, how to fix (exit 2)."""


@dataclass(frozen=True)
class Channel:
    """One channel: ``sensitivity`` is V per SI unit of ``quantity`` (None when not known), ``direction`` a UFF code."""

    name: str
    quantity: str
    node: int
    xyz: tuple[float, float, float]
    direction: int
    sensitivity: float | None = None

    @property
    def unit(self) -> str:
        return SI_UNITS[self.quantity]

    @property
    def direction_label(self) -> str:
        return direction_label(self.direction)

    @property
    def sensitivity_mv_per_unit(self) -> float | None:
        """mV per SI unit, as the rig files write it."""
        return None if self.sensitivity is None else 1e3 * self.sensitivity


# --- CSV --------------------------------------------------------------------------------------------------------
def _number(row: dict[str, str], key: str, what: str) -> float:
    text = (row.get(key) or "").strip()
    try:
        return float(text)
    except ValueError:
        raise ValueError(f"column {key!r}: {text!r} is not a number ({what})") from None


def _row_channel(row: dict[str, str]) -> Channel:
    """One CSV row as a :class:`Channel`; ValueError naming the column and the fix."""
    name = (row.get("name") or "").strip()
    if not name:
        raise ValueError("column 'name' is empty; name the channel as the log does (e.g. a01)")
    node_text = (row.get("node") or "").strip()
    if not node_text.isdigit() or int(node_text) < 1:
        raise ValueError(f"column 'node': {node_text!r} is not a node id (a whole number >= 1)")
    x, y, z = (_number(row, axis, "m") for axis in ("x", "y", "z"))
    try:
        direction = parse_direction(row.get("direction") or "")
    except ValueError as exc:
        raise ValueError(f"column 'direction': {exc}") from None
    value = _number(row, "sensitivity", "e.g. 100 with unit mV/g")
    unit = (row.get("unit") or "").strip()
    if not unit:
        raise ValueError("column 'unit' is empty; write e.g. mV/g, mV/(m/s^2), mV/N, pC/N")
    try:
        sens, quantity = sensitivity_si(value, unit, (row.get("gain") or "").strip() or None)
    except ValueError as exc:
        raise ValueError(f"column 'unit': {exc}") from None
    declared = (row.get("quantity") or "").strip()
    if declared and declared != quantity:
        raise ValueError(f"column 'quantity' says {declared!r} but the unit {unit!r} is of {quantity}; correct one of them")
    return Channel(name, quantity, int(node_text), (x, y, z), direction, sens)


def parse_channel_csv(text: str, where: str = "<csv>") -> tuple[Channel, ...]:
    """A channel table from CSV text (header row first); :class:`ChannelTableError` ``where:line: ...``."""
    reader = csv.DictReader(io.StringIO(text))
    header = [h.strip() for h in (reader.fieldnames or [])]
    missing = [c for c in CSV_COLUMNS if c not in header]
    if missing:
        raise ChannelTableError(
            f"{where}:1: header lacks column(s) {missing}; the header is {','.join(CSV_COLUMNS)} (optional: gain, quantity)"
        )
    reader.fieldnames = header
    out: list[Channel] = []
    seen: dict[str, int] = {}
    for row in reader:
        line = reader.line_num
        if not any((v or "").strip() for k, v in row.items() if k is not None):
            continue
        if len(out) >= MAX_CSV_ROWS:
            raise ChannelTableError(f"{where}:{line}: more than {MAX_CSV_ROWS} channels (the rig limit)")
        if row.get(None):
            raise ChannelTableError(
                f"{where}:{line}: {len(header) + len(row[None])} fields for {len(header)} columns; "
                "quote a unit that holds a comma"
            )
        try:
            ch = _row_channel(row)
        except ValueError as exc:
            raise ChannelTableError(f"{where}:{line}: {exc}") from None
        if ch.name in seen:
            raise ChannelTableError(f"{where}:{line}: channel {ch.name!r} is already on line {seen[ch.name]}; name each once")
        seen[ch.name] = line
        out.append(ch)
    if not out:
        raise ChannelTableError(f"{where}: no channels (a header and one row per channel)")
    return tuple(out)


def read_channel_csv(path: str | Path) -> tuple[Channel, ...]:
    """Read a channel table file (UTF-8, at most 1 MB); :class:`ChannelTableError` on any problem."""
    p = Path(path)
    try:
        if p.stat().st_size > MAX_CSV_BYTES:
            raise ChannelTableError(f"{p}: {p.stat().st_size} bytes, over the 1 MB a channel table may have")
        text = p.read_text(encoding="utf-8-sig")
    except OSError as exc:
        raise ChannelTableError(f"{p}: cannot read ({exc.strerror or exc})") from None
    except UnicodeDecodeError:
        raise ChannelTableError(f"{p}: not UTF-8 text; save the table as UTF-8 CSV") from None
    return parse_channel_csv(text, str(p))


# --- from a rig ------------------------------------------------------------------------------------------------
def rig_channels(rig: Rig) -> tuple[Channel, ...]:
    """The hammer then every sensor of ``rig`` as channels: node (the rig's, or numbered along the structure),
    coordinates from the rig's geometry, direction (given; else +Z on a beam, whose model deflection ``w`` is
    transverse, and +X on a lumped chain) and the sensitivity the rig states (mV per SI unit -> V per SI unit)."""
    from analysis.model.config import BeamSpec
    from analysis.model.geometry import rig_geometry, rig_nodes

    geometry, nodes = rig_geometry(rig), rig_nodes(rig)
    default = "+Z" if isinstance(rig.config.structure, BeamSpec) else "+X"
    given = {s.name: s.direction for s in rig.config.all_sensors}
    given["hammer"] = rig.config.hammer.direction
    out = []
    for ch in (rig.hammer, *rig.sensors):
        node = nodes[ch.name]
        out.append(
            Channel(
                ch.name,
                ch.quantity,
                node,
                geometry.coordinates(node),
                parse_direction(given[ch.name] or default),
                1e-3 * ch.props.sensitivity_mv_per_unit,
            )
        )
    return tuple(out)


def by_name(channels: tuple[Channel, ...] | list[Channel]) -> dict[str, Channel]:
    return {c.name: c for c in channels}


__all__ = [
    "CSV_COLUMNS",
    "Channel",
    "ChannelTableError",
    "by_name",
    "parse_channel_csv",
    "read_channel_csv",
    "rig_channels",
]
