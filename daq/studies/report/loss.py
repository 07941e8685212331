"""What the log lost and why: per stream the gaps, missing samples, writer overruns and undecodable blocks, and
the driver and session events by kind (CRC errors, timeouts, silences, restarts ...). A test engineer signs a
session off on these before any result drawn from it (the no-silent-loss contract, docs/log-format.md)."""

from __future__ import annotations

from typing import Any

from daq.studies.report.page import num, table

STREAM_COLS = ["stream", "channels", "fs [Hz]", "duration [s]", "samples", "gaps", "missing samples", "writer overruns",
               "undecodable blocks"]  # fmt: skip


def loss_tables(info: dict[str, Any]) -> list[str]:
    """The streams-and-loss table and the events-by-kind table of ``log_info``'s answer."""
    ev_rows = [[k, v] for k, v in sorted(info["events"].items())]
    return [
        table("streams and loss counters", STREAM_COLS, [_stream_row(s) for s in info["streams"]]),
        table("driver and session events by kind", ["kind", "count"], ev_rows, "no events (no gaps, CRC errors)"),
    ]


def _stream_row(s: dict) -> list:
    return [s["stream"], len(s["channels"]), num(s["sample_rate"], "g"), num(s["duration_s"]), s["samples"], len(s["gaps"]),
            s["missing_samples"], s["overrun_samples"], s["undecodable_blocks"]]  # fmt: skip
