"""Terminal output a test engineer reads: the few shared rules every ``gvt`` table follows.

* **Units survive.** Header and cell text is literal: ``t [s]`` would lose ``[s]`` to rich's markup, so
  every string goes in as :class:`rich.text.Text` (or through :func:`header`, rich's ``escape``).
* **Tables fit the terminal, 80 columns included.** :class:`FitTable` lays its columns out for the width it
  is printed at (the console's, or ``width=``): one table when the cells fit, headers wrapped between
  words (a unit stays with its word: ``peak [N]``) when that makes them fit, else the columns split into
  stacked tables that repeat the key columns. Cells do not wrap (only one wider than the terminal folds).
* **Long free text goes below.** A *note* column (reasons, messages, evidence) keeps short values in its
  cell; a longer one becomes a numbered reference ``[1]`` and its full text is printed under the table,
  wrapped to the width. Identical texts share one note. ``--json`` and the report carry the same text.

:func:`hits_table` is the record verb's table of hits; :func:`drain_progress` reports the confirmation
drain after the data ends (a spinner on a terminal, a plain line every few seconds otherwise).

Imports stay light (rich only): ``gvt --help`` loads the verb modules that import this.
"""

from __future__ import annotations

import atexit
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

from rich import box
from rich.cells import cell_len
from rich.console import Console, ConsoleOptions, RenderResult
from rich.markup import escape
from rich.measure import Measurement
from rich.table import Table
from rich.text import Text

#: The narrowest terminal every table is laid out to fit (tests render at this width).
MIN_WIDTH = 80
#: Cells between two columns (box.SIMPLE_HEAD, collapsed padding).
GAP = 2
DASH = "–"


def header(name: str) -> str:
    """A column header (or any text) as a rich markup string that prints literally: ``t [s]`` stays ``t [s]``."""
    return escape(name)


@dataclass(frozen=True)
class Col:
    """A column of a :class:`FitTable`.

    ``note``: free text: a value longer than ``inline_max`` cells becomes a ``[k]`` reference and its full
    text a numbered note below the table. ``key``: repeated in every part when the columns are split
    (default: the first column)."""

    name: str
    justify: str = "left"
    note: bool = False
    inline_max: int = 10
    key: bool = False


def _tokens(name: str, glue_units: bool) -> list[str]:
    """The pieces a header may wrap between: its words; with ``glue_units`` a bracketed unit is one piece and a
    short one sticks to the word before it (``peak [N]``, ``Φ̇ [rad/s]``), so a unit never starts a line alone."""
    words = name.split()
    if not glue_units:
        return words
    groups: list[str] = []
    i = 0
    while i < len(words):
        j = i
        if words[i].startswith("["):
            while j < len(words) - 1 and "]" not in words[j]:
                j += 1
        groups.append(" ".join(words[i : j + 1]))
        i = j + 1
    out: list[str] = []
    for g in groups:
        if out and g.startswith("[") and cell_len(g) <= 8:
            out[-1] = f"{out[-1]} {g}"
        else:
            out.append(g)
    return out


def _wrap_tokens(tokens: Sequence[str], width: int) -> list[str]:
    lines: list[str] = []
    for tok in tokens:
        if lines and cell_len(lines[-1]) + 1 + cell_len(tok) <= width:
            lines[-1] = f"{lines[-1]} {tok}"
        else:
            lines.append(tok)
    return lines or [""]


@dataclass
class _Part:
    columns: list[int]
    widths: list[int]
    headers: list[str]  # with "\n" where the header wraps


class FitTable:
    """A table that fits the width it is printed at, its long free text numbered below it.

    ``FitTable(title, [Col("#", "right"), Col("t [s]", "right"), Col("reason", note=True)])``, then
    ``add_row(...)`` with one value per column (``None`` prints as a dash), then ``console.print(table)``.
    ``width`` narrows the layout (default: the width it is printed at, the console's)."""

    def __init__(
        self,
        title: str | None,
        columns: Sequence[Col | str],
        *,
        caption: str | None = None,
        empty: str | None = None,
        width: int | None = None,
    ) -> None:
        self.title = title
        self.columns = [c if isinstance(c, Col) else Col(c) for c in columns]
        self.caption = caption
        self.empty = empty
        self.width = width
        self.rows: list[tuple[list[str], str]] = []

    @property
    def row_count(self) -> int:
        return len(self.rows)

    def add_row(self, *cells: object, style: str = "") -> None:
        if len(cells) != len(self.columns):
            raise ValueError(f"add_row: {len(cells)} cells for {len(self.columns)} columns")
        self.rows.append(([DASH if c is None else str(c) for c in cells], style))

    # --- layout -------------------------------------------------------------------------------------------------

    def _note_cols(self) -> list[int]:
        return [i for i, c in enumerate(self.columns) if c.note]

    def _note_text(self, i: int, text: str) -> str:
        return f"{self.columns[i].name}: {text}" if len(self._note_cols()) > 1 else text

    def _notes(self) -> tuple[list[list[str]], list[tuple[str, str]]]:
        """The cells as shown (long note text replaced by ``[k]``) and the notes ``(marker, text)``."""
        notes: dict[str, str] = {}
        shown = []
        for cells, _style in self.rows:
            row = list(cells)
            for i in self._note_cols():
                if cell_len(row[i]) > self.columns[i].inline_max or "\n" in row[i]:
                    row[i] = notes.setdefault(self._note_text(i, row[i]), f"[{len(notes) + 1}]")
            shown.append(row)
        return shown, [(m, t) for t, m in notes.items()]

    def _row_notes(self) -> list[tuple[str, str]]:
        """Every note-column value (a dash excepted) labelled with the rows it belongs to: ``#1 #4: text``."""
        key = next((i for i, c in enumerate(self.columns) if c.key), 0)
        name = self.columns[key].name
        labels: dict[str, list[str]] = {}
        for cells, _style in self.rows:
            label = f"#{cells[key]}" if name == "#" else f"{name} {cells[key]}"
            for i in self._note_cols():
                if cells[i] != DASH:
                    labels.setdefault(self._note_text(i, cells[i]), []).append(label)
        return [(" ".join(ls) + ":", t) for t, ls in labels.items()]

    def _fit(self, idx: list[int], cellw: list[int], width: int, unglue: bool = True) -> _Part | None:
        """Widths and wrapped headers for the columns ``idx`` within ``width``, or None. Headers wrap between
        words, a unit kept with its word; with ``unglue`` a unit may start a line of its own if that fits."""
        names = [self.columns[i].name for i in idx]
        cw = [cellw[i] for i in idx]
        full = [max(c, cell_len(n)) for c, n in zip(cw, names, strict=True)]
        room = width - GAP * (len(idx) - 1)
        if sum(full) <= room:
            return _Part(idx, full, names)
        for glue in (True, False) if unglue else (True,):
            toks = [_tokens(n, glue) for n in names]
            mins = [max(c, *(cell_len(t) for t in ts)) for c, ts in zip(cw, toks, strict=True)]
            if sum(mins) > room:
                continue
            widths = list(mins)
            spare = room - sum(widths)
            while spare > 0:  # widen the column with the tallest header by the least that saves it a line
                best = None
                for k, ts in enumerate(toks):
                    lines = len(_wrap_tokens(ts, widths[k]))
                    if lines == 1:
                        continue
                    for w in range(widths[k] + 1, min(full[k], widths[k] + spare) + 1):
                        if len(_wrap_tokens(ts, w)) < lines:
                            cand = (-lines, w - widths[k], k, w)
                            best = cand if best is None or cand < best else best
                            break
                if best is None:
                    break
                _, inc, k, w = best
                widths[k] = w
                spare -= inc
            heads = ["\n".join(_wrap_tokens(ts, w)) for ts, w in zip(toks, widths, strict=True)]
            return _Part(idx, widths, heads)
        return None

    def _layout(self, shown: list[list[str]], width: int, columns: list[int]) -> list[_Part]:
        """``columns`` in one table if they fit ``width``, else in stacked parts that repeat the key columns
        (filled in order, each unit kept on the line of its word)."""
        cellw = [max((cell_len(r[i]) for r in shown), default=0) for i in range(len(self.columns))]
        everything = self._fit(columns, cellw, width)
        if everything is not None:
            return [everything]
        keys = [i for i in columns if self.columns[i].key] or columns[:1]
        parts: list[list[int]] = []
        cur: list[int] = []
        for i in columns:
            if i in keys:
                continue
            if cur and self._fit(sorted([*keys, *cur, i]), cellw, width, unglue=False) is None:
                parts.append(cur)
                cur = []
            cur.append(i)
        if cur or not parts:
            parts.append(cur)
        out = []
        for p in parts:
            idx = sorted([*keys, *p])
            fitted = self._fit(idx, cellw, width)
            if fitted is None:  # one column wider than the terminal: rich folds it
                fitted = _Part(idx, [max(1, min(cellw[i], width)) for i in idx], [self.columns[i].name for i in idx])
            out.append(fitted)
        return out

    # --- rendering ----------------------------------------------------------------------------------------------

    def _table(self, part: _Part, shown: list[list[str]]) -> Table:
        t = Table(box=box.SIMPLE_HEAD, show_edge=False, pad_edge=False, collapse_padding=True, padding=(0, 1))
        for i, w, h in zip(part.columns, part.widths, part.headers, strict=True):
            c = self.columns[i]
            t.add_column(Text(h, style="table.header"), justify=c.justify, width=w, overflow="fold")  # type: ignore[arg-type]
        for row, (_cells, style) in zip(shown, self.rows, strict=True):
            t.add_row(*(Text(row[i]) for i in part.columns), style=style or None)
        return t

    def renderables(self, width: int) -> list[Any]:
        """What prints, in order, laid out for ``width`` cells: title, table part(s), caption, notes.

        The note columns hold ``[k]`` references to the notes below; when they would push the table into a
        second part and the other columns fit in one, they are left out and each note is labelled with its
        rows instead (``#2 #5: ...``)."""
        shown, notes = self._notes()
        every = list(range(len(self.columns)))
        parts = self._layout(shown, width, every)
        plain = [i for i in every if not self.columns[i].note]
        if len(parts) > 1 and len(plain) < len(every):
            alone = self._layout(shown, width, plain)
            if len(alone) == 1:
                parts, notes = alone, self._row_notes()
        out: list[Any] = []
        if self.title:
            out.append(Text(self.title, style="table.title"))
        for k, part in enumerate(parts):
            if k:
                out.append(Text(""))
            out.append(self._table(part, shown))
        if not self.rows and self.empty:
            out.append(Text(self.empty, style="dim"))
        if self.caption:
            out.append(Text(self.caption, style="table.caption"))
        for marker, text in notes:
            out.append(_Hanging(marker, text))
        return out

    def __rich_console__(self, console: Console, options: ConsoleOptions) -> RenderResult:
        width = min(self.width or options.max_width, options.max_width)
        opts = options.update(width=width, no_wrap=False, overflow="fold", highlight=False)
        for r in self.renderables(width):
            yield from console.render(r, opts)

    def __rich_measure__(self, console: Console, options: ConsoleOptions) -> Measurement:
        return Measurement(min(MIN_WIDTH, options.max_width), min(self.width or options.max_width, options.max_width))


class _Hanging:
    """``[1] text`` wrapped to the width, continuation lines indented under the text (at most 6 cells)."""

    def __init__(self, marker: str, text: str) -> None:
        self.marker = marker
        self.text = text

    def __rich_console__(self, console: Console, options: ConsoleOptions) -> RenderResult:
        indent = min(cell_len(self.marker) + 1, 6)
        body = Text(f"{self.marker} {self.text}").wrap(
            console, max(10, options.max_width - indent), overflow="fold", no_wrap=False
        )
        opts = options.update(no_wrap=True, overflow="ignore")
        for k, ln in enumerate(body):
            line = ln if k == 0 else Text(" " * indent) + ln
            line.rstrip()
            line.end = "\n"
            yield from console.render(line, opts)


# --- the record verb's hits -----------------------------------------------------------------------------------


def short_list(names: Iterable[str], limit: int = 10) -> str:
    """``a09,a13 +2``: as many names as fit in ``limit`` cells, then how many more; a dash for none."""
    names = list(names)
    if not names:
        return DASH
    out = ""
    for k, n in enumerate(names):
        rest = len(names) - k - 1
        cand = n if not out else f"{out},{n}"
        tail = f" +{rest}" if rest else ""
        if out and cell_len(cand + tail) > limit:
            return f"{out} +{len(names) - k}"
        out = cand
    return out


def hits_table(hits: Sequence[Any], title: str, *, width: int | None = None) -> FitTable:
    """The hits of a recording: ``#``, ``t [s]``, ``peak [N]``, ``width [ms]``, ``energy [J]``, ``verdict``,
    the channels excluded from the hit (short form), and the reasons as numbered notes below the table.

    ``hits`` are :class:`daq.hits.HitRecord` s (or anything with their fields); ``excluded_channels`` is
    read with ``getattr`` so a record without it shows a dash."""
    t = FitTable(
        title,
        [
            Col("#", "right", key=True),
            Col("t [s]", "right", key=True),
            Col("peak [N]", "right"),
            Col("width [ms]", "right"),
            Col("energy [J]", "right"),
            Col("verdict"),
            Col("excluded"),
            Col("reason", note=True, inline_max=6),
        ],
        width=width,
    )
    for h in hits:
        excl = tuple(getattr(h, "excluded_channels", ()) or ())
        short = short_list(excl)
        reason = "; ".join(h.reasons) or "ok"
        if excl and short != ",".join(excl):
            reason = f"{reason} (excluded: {', '.join(excl)})"
        energy = None if h.input_energy_J is None else f"{h.input_energy_J:.3g}"
        t.add_row(
            h.hit, f"{h.t_s:.3f}", f"{h.peak_force_N:.0f}", f"{1000 * h.pulse_width_s:.2f}", energy, h.verdict, short, reason
        )
    return t


def frf_line(rec: Any) -> str:
    """One line per hit of the live FRF lane (``/analysis/frf``): the verdict, the averages of the reference,
    and the driving point's peaks with their coherence (or the lowest coherence over the responses), or
    the reason a hit was refused. Plain text: printed with ``markup=False``."""
    head = f"FRF hit {rec['hit']} at {rec['t_s']:.3f} s: "
    avg = f"{rec['averages']} averages at {rec['reference']} ({rec['refused']} refused)"
    if rec["verdict"] != "accepted":
        return f"{head}refused ({rec['reason']}); {avg}"
    coh = rec.get("dp_coherence") or rec.get("min_coherence") or ()
    where = f"driving point {rec['driving_point']}" if rec.get("dp_coherence") else "peaks"
    peaks = ", ".join(f"{f:.1f} Hz ({c:.3f})" for f, c in zip(rec.get("peaks_hz", ()), coh, strict=False)) or DASH
    return f"{head}{avg}; {where}: {peaks}"


# --- the confirmation drain after the data ends -----------------------------------------------------------------


class DrainProgress:
    """Progress of a drain (the confirmations still running when the data ends): ``report(done, total)``.

    On a terminal a rich spinner line ``confirming 7 events … 3/7 done 0:00:12``; otherwise one plain line
    ``confirming 7 events ... 3/7 done, 12 s`` at the first report, then every ``every_s`` seconds. The
    last state is printed once as a plain line in both cases, when ``done`` reaches ``total`` or at ``close()``
    (leaving the ``with`` block, or the interpreter's exit for a spinner left running). The clock starts at the
    first report with a total above 0; nothing is printed while the total is 0. ``hint`` is appended to every
    plain line (``"--no-wait skips this"``). Thread-safe: the recorder may report from its drain thread."""

    def __init__(
        self,
        console: Console,
        total: int = 0,
        *,
        what: str = "confirming",
        noun: str = "events",
        hint: str = "",
        every_s: float = 5.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.console = console
        self.what = what
        self.noun = noun
        self.hint = hint
        self.every_s = every_s
        self.clock = clock
        self.done = 0
        self.total = total
        self.t0: float | None = None
        self._lock = threading.Lock()
        self._printed: tuple[int, int] | None = None
        self._last_print = -float("inf")
        self._bar: Any = None  # None: not started, False: no spinner here, else the rich Progress
        self._task: Any = None
        self._closed = False

    def line(self) -> str:
        """The plain line for the current state."""
        t = 0.0 if self.t0 is None else self.clock() - self.t0
        hint = f" ({self.hint})" if self.hint else ""
        return f"{self.what} {self.total} {self.noun} ... {self.done}/{self.total} done, {t:.0f} s{hint}"

    def _describe(self) -> str:
        return f"{self.what} {self.total} {self.noun} …"

    def _start_bar(self) -> None:
        from rich.errors import LiveError
        from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

        bar = Progress(
            SpinnerColumn(),
            TextColumn("{task.description}"),
            TextColumn("{task.completed:.0f}/{task.total:.0f} done"),
            TimeElapsedColumn(),
            *([TextColumn(f"({self.hint})")] if self.hint else []),
            console=self.console,
            transient=True,
        )
        try:
            bar.start()
        except LiveError:  # another live display on this console that rich cannot nest: plain lines then
            self._bar = False
            return
        self._bar = bar
        self._task = bar.add_task(self._describe(), total=max(self.total, 1), completed=self.done)
        atexit.register(self.close)  # never leave the terminal with a spinner and a hidden cursor

    def _stop_bar(self) -> None:
        if self._bar:
            self._bar.stop()
            atexit.unregister(self.close)
            self._bar = None

    def _print(self) -> None:
        self.console.print(self.line(), markup=False, highlight=False)
        self._printed = (self.done, self.total)
        self._last_print = self.clock()

    def __call__(self, done: int, total: int) -> None:
        with self._lock:
            if self._closed:
                return
            self.done, self.total = int(done), int(total)
            if self.total <= 0:
                return
            if self.t0 is None:
                self.t0 = self.clock()
            final = self.done >= self.total
            if self._bar is None and self.console.is_terminal and not final:
                self._start_bar()
            if self._bar:
                self._bar.update(self._task, description=self._describe(), total=self.total, completed=self.done)
                if final:
                    self._stop_bar()
                    self._print()
                return
            if self._printed is None or self.clock() - self._last_print >= self.every_s or (
                final and self._printed != (self.done, self.total)
            ):
                self._print()

    report = __call__

    def close(self) -> None:
        """Stop the spinner; print the last state (once) if anything was reported. Later reports are ignored."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._stop_bar()
            if self.total > 0 and self._printed != (self.done, self.total):
                self._print()

    def __enter__(self) -> DrainProgress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def drain_progress(console: Console, total: int = 0, **kw: Any) -> DrainProgress:
    """A :class:`DrainProgress` on ``console``: call it as ``report(done, total)``; it prints its last state by
    itself when ``done`` reaches ``total``; ``close()`` it (or use it as a context manager) when the drain may
    end short of that. Options: ``what``, ``noun``, ``hint``, ``every_s``, ``clock``."""
    return DrainProgress(console, total, **kw)
