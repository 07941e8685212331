"""Live status of a recording session: a rich table on a terminal, one plain line a second otherwise."""

from __future__ import annotations

from rich.console import Console
from rich.live import Live

from daq.terminal import Col, FitTable


def plain_line(st: dict) -> str:
    v = ", ".join(f"{k} {n}" for k, n in sorted(st.get("verdicts", {}).items())) or "none"
    return (
        f"{st['seconds']:6.1f} s  {st['samples']} samples  {st['rate']:.0f} S/s  hits {st['hits']} ({v})  "
        f"lost {st['lost']}  crc {st.get('crc_errors', 0)}  reconnects {st.get('reconnects', 0)}  "
        f"file {st.get('file_bytes', 0) / 1e6:.1f} MB"
    ) + (f"  frf {st['frf']['averages']} avg" if st.get("frf") else "") + (
        f"  plan: {st['plan']['prompt']}" if st.get("plan") else ""
    )


def status_table(title: str, st: dict, width: int | None = None) -> FitTable:
    """Per channel the peak of the last second against its range (red at the range, yellow above 80 %),
    the counters below the table; fits ``width`` (default: the console's)."""
    t = FitTable(
        f"{title} — {st['seconds']:.0f} s, {st['rate']:.0f} S/s, file {st.get('file_bytes', 0) / 1e6:.1f} MB",
        [Col("channel", key=True), Col("peak (last s)", "right"), Col("of range", "right")],
        width=width,
    )
    for ch, lvl in st.get("levels", {}).items():
        rng = st.get("ranges", {}).get(ch)
        frac = f"{100 * lvl / rng:.0f} %" if rng else "—"
        style = "bold red" if rng and lvl >= 0.999 * rng else ("yellow" if rng and lvl >= 0.8 * rng else "")
        t.add_row(ch, f"{lvl:.4g}", frac, style=style)
    v = ", ".join(f"{k}: {n}" for k, n in sorted(st.get("verdicts", {}).items())) or "none"
    t.caption = (
        f"hits {st['hits']} ({v}) · lost samples {st['lost']} · CRC/frame errors {st.get('crc_errors', 0)} · "
        f"reconnects {st.get('reconnects', 0)} · writer overruns {st.get('writer_overruns', 0)}"
    )
    if st.get("frf"):
        t.caption += f" · FRF averages {st['frf']['averages']} ({st['frf']['refused']} refused)"
    if st.get("plan"):
        pts = " ".join(f"{p['name']} {p['done']}/{p['averages']}" for p in st["plan"]["points"])
        t.caption += f"\n{st['plan']['prompt']} · points {pts}"
    return t


class LiveStatus:
    def __init__(self, console: Console, title: str) -> None:
        self.console = console
        self.title = title
        self.live: Live | None = None

    def __enter__(self) -> LiveStatus:
        if self.console.is_terminal:
            self.live = Live(console=self.console, refresh_per_second=2, transient=False)
            self.live.start()
        return self

    def update(self, st: dict) -> None:
        if self.live is not None:
            self.live.update(status_table(self.title, st))
        else:
            self.console.print(plain_line(st), markup=False)

    def __exit__(self, *exc: object) -> None:
        if self.live is not None:
            self.live.stop()
