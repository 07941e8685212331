"""A campaign's summary: one table row per log, the ``--json`` document, and the campaign's exit code.

The exit code (docs/campaign.md): 0 when every log was done; 3 when any log lost or had damaged data (its results,
if any, are of what was readable: the user must look at that log first, and it is what ``gvt VERB LOG`` says for
such a log); otherwise the worst per-log failure, 2 (bad input: a log that is not one, a rig that does not fit, no
accepted hit) over 1 (a runtime failure: a worker that died, a disk that refused a write).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from daq.terminal import Col, FitTable

RULE = "0 all done; 3 if any log lost or had damaged data; else the worst per-log failure, 2 (bad input) over 1 (runtime)"


def exit_code(rows: Sequence[Mapping[str, Any]]) -> int:
    """The campaign's exit code by :data:`RULE`."""
    if any(r["exit_code"] == 3 or r["data_lost"] for r in rows):
        return 3
    return max((int(r["exit_code"]) for r in rows), default=0)


def counts(rows: Sequence[Mapping[str, Any]]) -> dict[str, int]:
    lost = sum(bool(r["exit_code"] == 3 or r["data_lost"]) for r in rows)
    failed = sum(bool(r["exit_code"]) and not (r["exit_code"] == 3 or r["data_lost"]) for r in rows)
    return {"logs": len(rows), "done": len(rows) - lost - failed, "lost_data": lost, "failed": failed}


def document(verb: str, rows: Sequence[Mapping[str, Any]], wall_s: float, where: str) -> dict[str, Any]:
    """The ``--json`` document: the counts, the exit code and its rule, and every row (with its log's ``--json``
    document under ``result``)."""
    return {"verb": verb, **counts(rows), "exit_code": exit_code(rows), "exit_rule": RULE, "wall_s": wall_s,
            "cluster": where, "rows": list(rows)}  # fmt: skip


def _hits(r: Mapping[str, Any]) -> str | None:
    if r["hits"] is None:
        return None
    return f"{r['accepted']}/{r['hits']}" if r["accepted"] is not None else str(r["hits"])


def _note(r: Mapping[str, Any]) -> str:
    parts = [r["error"]] if r["error"] else []
    if r["damage"]:
        parts.append(r["damage"])
    if r["warnings"]:
        parts.append(f"{len(r['warnings'])} warning(s); first: {r['warnings'][0]}")
    return "; ".join(parts) or "ok"


def _state(r: Mapping[str, Any]) -> str:
    if r["exit_code"] == 3 or r["data_lost"]:
        return "data lost"
    if r["exit_code"]:
        return "failed"
    return "damaged" if r["damage"] else "done"


def summary_table(verb: str, rows: Sequence[Mapping[str, Any]], names: Sequence[str] | None = None,
                  width: int | None = None) -> FitTable:  # fmt: skip
    """One row per log (``names``: the logs as the user named them; default their paths): hits (accepted/all for
    frf and modal), IR events (analyze), modes (modal), the log's state, exit code, and the one line saying why."""
    c = counts(rows)
    title = (f"gvt {verb}: {c['logs']} logs, {c['done']} done, {c['lost_data']} with lost or damaged data, "
             f"{c['failed']} failed")  # fmt: skip
    cols = [Col("log", key=True), Col("hits", "right"), *([Col("events", "right")] if verb == "analyze" else []),
            *([Col("modes", "right")] if verb == "modal" else []), Col("state"), Col("exit", "right"),
            Col("s", "right"), Col("note", note=True, inline_max=24)]  # fmt: skip
    t = FitTable(title, cols, width=width)
    for k, r in enumerate(rows):
        extra = [r["events"]] if verb == "analyze" else [r["modes"]] if verb == "modal" else []
        t.add_row(names[k] if names else r["log"], _hits(r), *extra, _state(r), r["exit_code"], f"{r['seconds']:.1f}",
                  _note(r))  # fmt: skip
    return t
