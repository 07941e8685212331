"""The confirmations of the IR events (WBEMD + slow flow): their table and their slow-flow phase trajectories.

They come from the log's ``/analysis/confirmations`` (the background lane of ``gvt record``), or else from the
companion file ``gvt confirm`` / ``gvt replay`` write beside the log (docs/decisions.md D22); without either the
table says "none".
"""

from __future__ import annotations

from pathlib import Path

from analysis.records import confirmation_status
from daq.log import layout
from daq.studies.report.page import num, png, table

TITLE = "confirmations (WBEMD + slow flow)"
CONF_COLS = ["event", "event m:n", "status", "evidence", "m:n found", "start [s]", "end [s]", "orthogonality", "IMF freqs [Hz]",
             "candidates (captured)", "why"]  # fmt: skip


def session_confirmations(results: dict[str, list[dict]], log: str | Path) -> list[dict]:
    """The log's confirmations, or those of its companion file when the log has none."""
    confs = results.get(layout.CONFIRMATIONS_TOPIC, [])
    if not confs:  # gvt confirm / gvt replay write theirs next to the log (docs/decisions.md D22)
        from daq.studies.confirm import read_confirmations

        confs = read_confirmations(log, include_log=False)
    return confs


def slow_flow_figure(confs: list[dict]) -> tuple[str, str] | None:
    """``(title, PNG)`` of every confirmation's slow-flow trajectory (φ, φ̇); None when none carries one."""
    with_traj = [c for c in confs if (c.get("trajectory") or {}).get("phi")]
    if not with_traj:
        return None
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4.5))
    for c in with_traj:
        tr = c["trajectory"]
        ax.plot(tr["phi"], tr["phi_dot"], "-", label=f"event {c.get('event_id')} {c.get('ratio') or ''} {confirmation_status(c)}")
    ax.set_xlabel("φ [rad]")
    ax.set_ylabel("φ̇ [rad/s]")
    ax.set_title("slow-flow phase trajectories of confirmations")
    ax.legend(fontsize=7)
    return "slow flow", png(fig)


def confirmations_table(confs: list[dict]) -> str:
    """One row per confirmation: its verdict (``other_ratio`` when the m:n found is not the event's, old logs
    included: :func:`analysis.records.confirmation_status`), the m:n found, the interval, the IMFs and why; "none"
    said."""
    return table(TITLE, CONF_COLS, [_conf_row(c) for c in confs], "none (no /analysis/confirmations in this log)")


def _conf_row(c: dict) -> list:
    cands = "; ".join(f"{d.get('ratio')} {100 * d.get('captured_fraction', 0):.0f} %" for d in c.get("candidates") or [])
    freqs = ", ".join(num(f, ".1f") for f in c.get("imf_freqs_hz") or [])
    return [c.get("event_id"), (c.get("event") or {}).get("ratio") or "—", confirmation_status(c), c.get("evidence") or "—",
            c.get("ratio") or "—", num(c.get("start_s")), num(c.get("end_s")), num(c.get("orthogonality_index"), ".3f"), freqs,
            cands, c.get("reason") or ""]  # fmt: skip
