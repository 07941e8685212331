"""Terminal tables a test engineer reads (daq/terminal.py): units survive in headers, every table fits 80
columns, long free text is numbered below the table in full; the confirmation drain reports progress."""

from __future__ import annotations

import io
import re
from types import SimpleNamespace as NS

import numpy as np
import pytest
from rich.console import Console

from daq.terminal import DASH, Col, DrainProgress, FitTable, drain_progress, hits_table, short_list

WIDTHS = (80, 120)

LONG_REASON = (
    "overload: a09 reached its range of 2 m/s^2 [clipped 34 samples]; double_hit: the force crossed 50 N "
    "again 12.5 ms after the main pulse, a second impact of the hammer tip"
)
LONG_EVIDENCE = (
    "energy exchange between NNM1 and NNM2 over 3 beats; [a05] locked at 3:1 for 2.1 s while the receiver "
    "gained ×4.2 in energy (modal filter on 8 sensors)"
)
LONG_WHY = (
    "no captured loops (loops at 247.100–248.300 s do not overlap the event or come without an energy gain); "
    "slow-angle test: gain ×1.12 (needs 1.5), slowest Φ_3:1 moved 2.41 rad (needs < 1.57) [see docs/slowflow.md]"
)


def render(renderable, width: int, soft_wrap: bool = True) -> str:
    """As ``gvt`` prints it: the CLI's consoles soft-wrap (daq/cli/common.py), so test that mode and the default."""
    buf = io.StringIO()
    console = Console(width=width, record=True, file=buf, soft_wrap=soft_wrap, highlight=False)
    console.print(renderable)
    text = console.export_text(styles=False)
    assert text == buf.getvalue()  # not a terminal: no escape codes
    return text


def assert_fits(text: str, width: int) -> None:
    long = [ln for ln in text.splitlines() if len(ln) > width]
    assert not long, f"{len(long)} lines longer than {width}:\n" + "\n".join(long)


def flat(text: str) -> str:
    return " ".join(text.split())


def assert_below(text: str, header: str, full: str) -> None:
    """``full`` is printed in full (wrapping apart) after the line that holds ``header``."""
    lines = text.splitlines()
    k = next(i for i, ln in enumerate(lines) if header in ln)
    assert flat(full) in flat("\n".join(lines[k + 1 :])), text


# --- the shared helper ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("soft_wrap", [True, False])
@pytest.mark.parametrize("width", WIDTHS)
def test_fit_table_keeps_units_and_literal_text(width, soft_wrap):
    t = FitTable("title [with brackets] and [bold]no markup[/bold]", [Col("t [s]", "right"), Col("peak [N]", "right"),
                                                                       Col("reason", note=True)])  # fmt: skip
    t.add_row("1.000", "[red]12[/red]", "ok")
    t.add_row("2.000", "13", "[b]" + LONG_REASON)
    text = render(t, width, soft_wrap)
    assert_fits(text, width)
    assert "title [with brackets] and [bold]no markup[/bold]" in text
    assert "t [s]" in text and "peak [N]" in text and "[red]12[/red]" in text
    assert "[1]" in text and "ok" in text
    assert_below(text, "[red]12[/red]", "[1] [b]" + LONG_REASON)


def test_fit_table_shares_identical_notes_and_numbers_them_in_order():
    t = FitTable(None, [Col("#", "right"), Col("reason", note=True)])
    for k, r in enumerate(["a long reason number one, longer than ten cells", "ok", "second long reason, also long",
                           "a long reason number one, longer than ten cells"]):  # fmt: skip
        t.add_row(k, r)
    text = render(t, 80)
    rows = [ln.split() for ln in text.splitlines()[2:6]]
    assert [r[1] for r in rows] == ["[1]", "ok", "[2]", "[1]"]
    assert text.count("a long reason number one") == 1
    assert text.index("[1] a long reason") < text.index("[2] second long reason")


def test_wide_tables_split_into_parts_that_repeat_the_key_columns():
    cols = [Col("id", key=True), *(Col(f"quantity {k} [Hz]", "right") for k in range(10))]
    t = FitTable("wide", cols)
    t.add_row("r1", *(f"{1000 + k:.3f}" for k in range(10)))
    t.add_row("r2", *(f"{2000 + k:.3f}" for k in range(10)))
    for width in WIDTHS:
        text = render(t, width)
        assert_fits(text, width)
        parts = [ln for ln in text.splitlines() if ln.startswith("id")]
        assert len(parts) >= (2 if width == 80 else 1) and text.count("r1") == len(parts) == text.count("r2")
        for k in range(10):  # every column shows, its unit whole
            assert f"quantity {k} [Hz]" in flat(text) or f"{k} [Hz]" in text
        assert "1009.000" in text and "2009.000" in text
    assert len([ln for ln in render(t, 400).splitlines() if ln.startswith("id")]) == 1


def test_headers_wrap_between_words_keeping_the_unit_with_its_word():
    t = FitTable(None, [Col(f"a rather long header number {k} [rad/s]", "right") for k in range(4)])
    t.add_row(*(f"{k}.00" for k in range(4)))
    text = render(t, 80)
    assert_fits(text, 80)
    assert text.count("[rad/s]") == 4 and "\n[rad/s]" not in text.replace(" ", "")


def test_note_columns_make_way_for_row_labelled_notes_rather_than_split():
    t = FitTable(None, [Col("#", "right", key=True), Col("value", "right"), Col("why", note=True)])
    t.add_row(7, "x" * 75, LONG_REASON)
    t.add_row(8, "y" * 75, "ok")
    text = render(t, 80)
    assert_fits(text, 80)
    assert sum(ln.startswith("#") and "value" in ln for ln in text.splitlines()) == 1  # one table part
    assert_below(text, "value", "#7: " + LONG_REASON)
    assert "#8: ok" in text


def test_explicit_width_and_empty_message():
    t = FitTable("nothing yet", [Col("id"), Col("status"), Col("why", note=True)], empty="no IR events", width=80)
    text = render(t, 200)
    assert "no IR events" in text and "id" in text and "status" in text


def test_short_list_of_channels():
    assert short_list([]) == DASH
    assert short_list(["a09"]) == "a09"
    assert short_list(["a09", "a13"]) == "a09,a13"
    assert short_list(["a09", "a13", "a14", "a15"]) == "a09,a13 +2"
    assert len(short_list([f"a{k:02d}" for k in range(20)])) <= 10


# --- the verbs' tables --------------------------------------------------------------------------------------------


def _hits(excluded: bool) -> list:
    out = []
    for k in range(1, 9):
        h = NS(hit=k, index=k * 16384, t_s=61.25 * k, peak_force_N=812.0 + k, pulse_width_s=0.00123 * k,
               input_energy_J=None if k == 3 else 0.0123 * k, verdict=["accepted", "overload", "double_hit"][k % 3],
               reasons=() if k % 3 == 0 else (LONG_REASON,) if k % 3 == 1 else (f"double_hit: crossed again ({k})",))  # fmt: skip
        if excluded:
            h.excluded_channels = ("a09", "a13", "a14") if k == 4 else ("a09",) if k == 1 else ()
            h.channel_verdicts = {"a09": "overload"}
        out.append(h)
    return out


@pytest.mark.parametrize("excluded", [True, False])
@pytest.mark.parametrize("width", WIDTHS)
def test_hits_table_fits_with_units_and_reasons_below(width, excluded):
    text = render(hits_table(_hits(excluded), "demo_session: 8 hits"), width)
    assert_fits(text, width)
    for unit in ("t [s]", "peak [N]", "width [ms]", "energy [J]"):
        assert unit in text
    assert "verdict" in text and "excluded" in text and "490.000" in text
    assert_below(text, "peak [N]", LONG_REASON)
    assert "double_hit: crossed again (2)" in flat(text)
    assert text.count("overload: a09 reached") >= 1
    if excluded:
        assert "a09,a13 +1" in text and "excluded: a09, a13, a14" in flat(text)


def test_hits_table_with_the_real_hit_record():
    from dataclasses import MISSING, fields

    from daq.hits import HitRecord

    values = dict(hit=1, index=100, t_s=0.5, start_index=0, end_index=200, peak_force_N=900.0, pulse_width_s=0.002,
                  impulse_Ns=1.0, input_energy_J=None, verdict="accepted", reasons=(), clipped_channels=(),
                  data=np.zeros((2, 2), np.float32))  # fmt: skip
    required = {f.name for f in fields(HitRecord) if f.default is MISSING and f.default_factory is MISSING}
    values = {k: v for k, v in values.items() if k in {f.name for f in fields(HitRecord)}}
    if not required <= set(values):
        pytest.skip(f"HitRecord has new required fields {sorted(required - set(values))}")
    text = render(hits_table([HitRecord(**values)], "one hit"), 80)
    assert "0.500" in text and "accepted" in text and "ok" in text


def _events() -> list[dict]:
    ev = []
    for k in range(5):
        ev.append({"id": k, "start_s": 123.456 * k, "end_s": 123.456 * k + 3.2, "modes": [1, 2], "ratio": "3:1", "m": 3,
                   "n": 1, "f_give_hz": 12.34, "f_recv_hz": 37.02, "gain": 12.5,
                   "scores": {"gain": 0.9, "lock": 0.8, "exchange": 0.7, "rq": 0.6}, "confidence": 0.77,
                   "source": "modal-exchange"})  # fmt: skip
    ev[3]["evidence"] = LONG_EVIDENCE
    return ev


@pytest.mark.parametrize("width", WIDTHS)
def test_events_table_fits_with_units_and_evidence_below(width):
    from daq.studies.analyze.tables import events_table

    for events in (_events(), [{k: v for k, v in e.items() if k != "evidence"} for e in _events()], []):
        text = render(events_table(events, "internal-resonance events (near-live analysis)"), width)
        assert_fits(text, width)
        assert f"internal-resonance events (near-live analysis): {len(events)}" in text
        assert "t [s]" in text and "f [Hz]" in text
        if events:
            assert "493.82–497.02" in text and "12.3 / 37.0" in text and "0.77 (0.90/0.80/0.70/0.60)" in text
    text = render(events_table(_events(), "internal-resonance events"), width)
    assert_below(text, "f [Hz]", LONG_EVIDENCE)


def _confirmations() -> list[dict]:
    ev = {"id": 3, "start_s": 246.91, "end_s": 250.11, "modes": [1, 2], "ratio": "3:1"}
    return [
        {"event_id": 3, "event": ev, "sensor": "a05", "orthogonality_index": 0.0123, "status": "not_confirmed",
         "ratio": None, "start_s": None, "end_s": None, "evidence": None, "elapsed_s": 2.34, "reason": LONG_WHY},
        {"event_id": 4, "event": {**ev, "id": 4}, "sensor": "a05", "orthogonality_index": 0.0456, "status": "confirmed",
         "ratio": "3:1", "start_s": 247.1, "end_s": 249.8, "evidence": "slow_angle", "elapsed_s": 2.1,
         "reason": "Φ_3:1 moved 0.42 rad (slowest of the candidates) while the 37.0 Hz component gained ×2.31 in energy"},
        {"event_id": 5, "event": {**ev, "id": 5}, "status": "skipped", "ratio": None, "start_s": None, "end_s": None,
         "reason": "the log has a gap or no data in 246.910–250.110 s"},
    ]  # fmt: skip


@pytest.mark.parametrize("soft_wrap", [True, False])
@pytest.mark.parametrize("width", WIDTHS)
def test_confirmations_table_fits_with_units_and_reasons_below(width, soft_wrap):
    from daq.studies.confirm import confirmations_table

    recs = _confirmations()
    text = render(confirmations_table(recs, "confirmations (WBEMD + slow flow, in the background)"), width, soft_wrap)
    assert_fits(text, width)
    assert "confirmations (WBEMD + slow flow, in the background)" in text
    assert "event [s]" in text and "interval [s]" in text
    for status in ("not_confirmed", "confirmed", "skipped", "slow_angle", "247.10–249.80", "246.91–250.11"):
        assert status in text
    assert_below(text, "event [s]", LONG_WHY)
    assert_below(text, "event [s]", "sensor a05, IO 0.012, 2.3 s")
    assert_below(text, "event [s]", "the log has a gap or no data in 246.910–250.110 s")
    empty = render(confirmations_table([], "confirmations"), width)
    assert "no IR events" in empty and "event [s]" in empty


@pytest.mark.parametrize("width", WIDTHS)
def test_status_table_fits_with_the_counters_below(width):
    from daq.live_status import status_table

    st = {"seconds": 3.0, "samples": 49152, "rate": 16384.0, "hits": 2, "lost": 0, "verdicts": {"overload": 2, "accepted": 5},
          "levels": {"hammer": 500.0, **{f"a{k:02d}": 1.9 for k in range(1, 15)}},
          "ranges": {"hammer": 2224.0, **{f"a{k:02d}": 2.0 for k in range(1, 15)}}, "file_bytes": 2_000_000,
          "crc_errors": 3, "reconnects": 1, "writer_overruns": 0}  # fmt: skip
    text = render(status_table("beam_ch4_exp session [serial]", st), width)
    assert_fits(text, width)
    assert "beam_ch4_exp session [serial] — 3 s, 16384 S/s, file 2.0 MB" in text
    assert "a14" in text and "95 %" in text and "22 %" in text
    assert "accepted: 5, overload: 2" in flat(text) and "writer overruns 0" in flat(text)


def test_live_status_on_a_terminal_shows_the_table():
    from daq.live_status import LiveStatus

    buf = io.StringIO()
    console = Console(file=buf, width=80, force_terminal=True, color_system=None)
    st = {"seconds": 1.0, "samples": 16384, "rate": 16384.0, "hits": 0, "lost": 0, "levels": {"hammer": 5.0},
          "ranges": {"hammer": 2224.0}}  # fmt: skip
    with LiveStatus(console, "sess [a]") as live:
        live.update(st)
    out = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", buf.getvalue())
    assert "sess [a] — 1 s, 16384 S/s" in out and "hammer" in out and "peak (last s)" in out
    assert_fits(out, 80)


@pytest.mark.parametrize("width", WIDTHS)
def test_modes_table_keeps_hz(width):
    from daq.studies.modes import print_modes

    report = {"rig": "beam_ch4_exp", "limit": "low", "n_dof": 200, "guyan_masters": 8, "nonlinear_springs": 1,
              "modes": [{"mode": k + 1, "frequency_hz": 20.8 * (k + 1) ** 2, "guyan_hz": None if k > 6 else 20.81 * (k + 1) ** 2,
                         "damping_ratio": 0.01} for k in range(10)]}  # fmt: skip
    buf = io.StringIO()
    print_modes(Console(width=width, file=buf, soft_wrap=True), report)
    text = buf.getvalue()
    assert_fits(text, width)
    assert "f [Hz]" in text and "Guyan, 8 sensor DOFs [Hz]" in flat(text) and "20.8000" in text and "zeta" in text


def _sweep_report():
    from analysis.rqfep import RatioLock, SweepInteraction
    from analysis.sweep_capture import CaptureReport, SweepCapture
    from daq.studies.sweep import SweepReport, SweepSpec

    asym = [{"end": end, "nnm": j, "runs": 10, "reference_hz": 20.8 * j, "median_hz": 20.9 * j, "min_hz": 20.7 * j,
             "error_median": 0.0048, "error_min": -0.005, "pass": j < 4}
            for end in ("low", "high") for j in range(1, 5)]  # fmt: skip
    flags = [SweepInteraction(i_lo=10, i_hi=14, i_peak=12, p_lo=1.2345e6, p_hi=2.3456e7, energy_lo=1.23e-3, energy_hi=4.56e2,
                              f1_hz=23.45, f2_hz=93.21, ratio=(4, 1), ratio_left=3.91, ratio_right=4.12, bracketed=False,
                              n_points=5, score=0.42, kind=kind, modal_ratio=(7, 2), modal_ratio_left=3.41,
                              modal_ratio_peak=3.5, modal_ratio_right=3.62, modal_bracketed=True)
             for kind in ("spike", "band")]  # fmt: skip
    locks = [RatioLock(i_lo=3, i_hi=9, p_lo=136.2, p_hi=163.4, energy_lo=1.234e-2, energy_hi=2.345e-2, ratio=(4, 1),
                       ratio_mean=4.012, ratio_min=3.981, ratio_max=4.043, n_points=8, slope_in=0.012, slope_below=0.456,
                       slope_above=0.789)]  # fmt: skip
    cap = SweepCapture(ratio=(4, 1), p_lo=1.3618e2, p_hi=1.6342e2, energy_lo=1.234e-2, energy_hi=2.345e-2, n_confirmed=3,
                       n_tested=4, passage_p=(1.3618e2, 1.6342e2), passage_energy=(1.2e-2, 2.3e-2), passage_points=8,
                       passage_ratio=(3.951, 4.049), i_peak=5, interval_s=(0.31, 0.69), chain_s=(0.25, 0.75), strength=0.87,
                       sign_changes=3, phase_range=2.34, bracket={"3:1": -61.2, "5:1": 58.9}, runs=())  # fmt: skip
    capture = CaptureReport(captures=[cap], passages=[None] * 6, tests={}, untested=[4, 5], runs=12, wall_s=3.4)
    result = NS(modal_freq_hz=np.ones((3, 1, 2)), substep_cap_hits=np.zeros(3, int))
    return SweepReport(rig="beam_ch4_sim", spec=SweepSpec(n=3), output_dofs=[1, 2, 3, 4], result=result,
                       freqs=np.ones((3, 4)), fixed_free_hz=np.ones(4), fixed_pinned_hz=np.ones(4), asymptotes=asym,
                       flags=flags, robust=[True, False], wall_s=12.3, peak_rss_mb=100.0, locks=locks,
                       capture=capture)  # fmt: skip


@pytest.mark.parametrize("width", WIDTHS)
def test_sweep_tables_fit_with_every_unit(width, tmp_path):
    from daq.studies.sweep import print_report, report_tables

    rep = _sweep_report()
    tables = report_tables(rep)
    assert len(tables) == 4
    text = "".join(render(t, width) for t in tables)
    assert_fits(text, width)
    for unit in ("limit [Hz]", "RQ median [Hz]", "P [N]", "energy [J]", "[Hz]", "Φ range [rad]", "[rad/s]",
                 "[per decade of E]", "interval [s]", "chain [s]"):  # fmt: skip
        assert unit in text, unit
    for value in ("1.234e+06–2.346e+07", "not robust", "4:1 (nearest)", "3.41 / 3.50 / 3.62", "4.012 (3.981–4.043)",
                  "3 / 4", "-61 / +59", "fixed-pinned", "+0.48 %"):  # fmt: skip
        assert value in text, value
    assert "slow-flow captures (1)" in text and "12 runs re-simulated at 6 passages" in flat(text)
    paths = {k: tmp_path / f"x.{k}" for k in ("csv", "png", "json")}
    buf = io.StringIO()
    print_report(Console(width=width, file=buf, soft_wrap=True), rep, paths)
    assert "flagged NNM1–NNM2 interactions (2)" in buf.getvalue() and "wrote" in buf.getvalue()


# --- the drain after the data ends ---------------------------------------------------------------------------------


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_drain_progress_plain_lines_every_few_seconds():
    buf = io.StringIO()
    clock = Clock()
    console = Console(file=buf, width=80)
    with drain_progress(console, 7, clock=clock, every_s=5.0) as report:
        report(0, 7)
        clock.t += 1
        report(1, 7)  # too soon after the first line
        clock.t += 5
        report(3, 7)
        clock.t += 6
        report(7, 7)  # the end: said once
    lines = buf.getvalue().splitlines()
    assert lines == [
        "confirming 7 events ... 0/7 done, 0 s",
        "confirming 7 events ... 3/7 done, 6 s",
        "confirming 7 events ... 7/7 done, 12 s",
    ]


def test_drain_progress_clock_starts_at_the_first_report_and_the_hint_shows():
    buf = io.StringIO()
    clock = Clock()
    report = drain_progress(Console(file=buf, width=80), hint="--no-wait skips this", clock=clock)  # made before the data
    clock.t += 600  # the recording
    report(0, 0)  # nothing running
    clock.t += 1
    report(0, 2)
    clock.t += 3
    report(2, 2)
    assert buf.getvalue().splitlines() == [
        "confirming 2 events ... 0/2 done, 0 s (--no-wait skips this)",
        "confirming 2 events ... 2/2 done, 3 s (--no-wait skips this)",
    ]


def test_drain_progress_says_where_it_stopped_and_nothing_for_no_events():
    buf = io.StringIO()
    clock = Clock()
    p = DrainProgress(Console(file=buf, width=80), clock=clock)
    p(0, 0)
    p.close()
    assert buf.getvalue() == ""
    p = DrainProgress(Console(file=buf, width=80), clock=clock)
    p.report(0, 4)
    clock.t += 2
    p(2, 5)  # a total that grew while draining
    p.close()
    p.close()
    p(5, 5)  # after close: ignored
    assert buf.getvalue().splitlines() == ["confirming 4 events ... 0/4 done, 0 s", "confirming 5 events ... 2/5 done, 2 s"]


def test_drain_progress_spinner_on_a_terminal_then_the_last_state():
    buf = io.StringIO()
    console = Console(file=buf, width=80, force_terminal=True, color_system=None)
    with drain_progress(console, 3) as report:
        for k in range(3):
            report(k, 3)
        assert report._bar  # the spinner runs
        report(3, 3)
        assert not report._bar  # and stops by itself at the end
    out = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", buf.getvalue())
    assert "confirming 3 events …" in out  # the spinner line
    assert out.rstrip().splitlines()[-1].startswith("confirming 3 events ... 3/3 done")
    assert out.count("confirming 3 events ... ") == 1


def test_drain_progress_under_another_live_display():
    """The status table may still be live when the drain starts: rich nests the spinner (or, where it cannot,
    DrainProgress falls back to plain lines); the last state is printed either way."""
    from rich.live import Live

    buf = io.StringIO()
    console = Console(file=buf, width=80, force_terminal=True, color_system=None)
    with Live("status", console=console, auto_refresh=False), drain_progress(console, 2) as report:
        report(0, 2)
        report(2, 2)
    out = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", buf.getvalue())
    assert "confirming 2 events ... 2/2 done" in out
