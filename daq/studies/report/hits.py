"""The hits and the hit gate's verdict on each (accepted, or rejected with its reason; a channel left out of a
hit is named in the reason), as ``/daq/hits`` holds them."""

from __future__ import annotations

from daq.studies.report.page import num, table

HIT_COLS = ["#", "t [s]", "peak [N]", "width [ms]", "energy [J]", "verdict", "reason"]


def hits_table(hits: list[dict]) -> str:
    """One row per hit, in the order of the log."""
    return table("hits and verdicts", HIT_COLS, [_hit_row(h) for h in hits])


def _hit_row(h: dict) -> list:
    return [h.get("hit"), num(h.get("t_s")), num(h.get("peak_force_N"), ".0f"), num(1000 * h.get("pulse_width_s", 0), ".2f"),
            num(h.get("input_energy_J"), ".3g"), h.get("verdict"), h.get("reason", "")]  # fmt: skip
