"""The load matrix of issue 30: record on a busy 2-core host and lose nothing.

{serial, CAN FD, Modbus TCP, two devices} × {0, 4, 8 CPU hogs} at 16384 Hz with the near-live analysis on
(and the hit gate, live FRFs and confirmation, as a session runs by default). The hogs (tests/hogs.py) are
plain busy loops at the recorder's own priority, started by the test and killed in a fixture finaliser.

Each session runs in-process through :func:`daq.session.run_session` over the real transport (a pty, python-can's
virtual bus, Modbus TCP on 127.0.0.1), as tests/test_record_matrix.py does; the oracle is the simulated device's
own schedule (every sample 0..duration × fs exists; the second device's clock starts exactly ``start_delay`` late).
Asserted per cell:

* 0 samples lost: the session says so and the log holds exactly duration × fs samples per stream, no gap;
* two devices: the clock offset within ``OFFSET_BAR_SAMPLES`` (1) sample period of the truth (the view's whole-sample
  delay, ``TRUE_OFFSET_S``), the issue's figure, for the final estimate and for the whole-sample offset the merged
  stream applied. The systematic +0.4 to +1.4 samples measured until D95 are gone (the oracle's own 0.35, the
  14-channel frames' transfer time in the last-byte stamp, the simulated device's encoding before it sent), and so is
  the scatter of up to 1.4 samples that kept the bar at 2 until D129: the simulated devices woke to send up to a host
  timer's 50 µs slack late, most blocks late and the odd one on time, so each stream's floor was set by its luck. With
  the devices' 1 ns slack, final estimates within −0.17…+0.12 samples at 0 hogs and −0.41…+0.26 at 8 (3 s runs), and
  the applied offset exact in every run (docs/decisions.md D75, D95, D127, D129);
* every shed analysis window counted: the ``analysis_overrun`` events' counts add up to
  ``SessionResult.analysis_dropped_samples``, and the windows written (``/analysis/rq``) plus the samples shed
  cover the stream, less at most one window per run of data (the operator restarts after each gap and a
  window never spans one).

The analysis needs every rig sensor on one stream. Serial carries the full beam_ch4_exp (hammer + 14
accelerometers, int24); CAN FD and Modbus TCP carry 3 channels at 16384 Hz (their link budgets,
tests/test_record_matrix.py CASES), so those cells record beam_ch4_exp cut down to its sensors a01 and a02 (the
same structure and simulator; the model seen by the analysis is the 2-sensor reduction); two devices put the
hammer on one serial device and the 14 accelerometers on another, so the analysis runs on the second's stream.

Duration: ``GVT_LOAD_SECONDS`` per cell. The issue asks for 60 s; the full matrix at 60 s is 12 minutes of wall
clock and cannot fit in the 10-minute ``make test``, so the suite runs the same matrix with short cells (3 s: ~100 s
of wall clock; a loaded cell's lanes catch up for up to 2 s after it, not the recorder's 5 s: the rule under test is
that every shed window is counted, whatever the catch-up) and ``make bench`` runs it at 60 s
(bench/bench_load.py, which adds 16 hogs and a 10-minute session at 8 hogs). The cells with hogs are marked
host_timing: the hogs are the load, so the suite's own parallel phase must not add to it (make test runs these alone,
after the parallel phase); the 0-hog cells but the first run in the parallel phase (``_cells`` says why).
"""

from __future__ import annotations

import json
import os
import re
from contextlib import contextmanager
from dataclasses import dataclass
from itertools import pairwise
from pathlib import Path

import numpy as np
import pytest

from analysis.model.loader import load_config
from analysis.model.rigs import open_rig, resolve_rig_path
from daq.config.session import SessionConfig
from daq.log.reader import LogReader
from daq.session import SessionResult, run_session

from .hogs import Hogs, LoadSeen, sim_devices_wake_precisely

SECONDS = float(os.environ.get("GVT_LOAD_SECONDS", 3))
FS = 16384
HOGS = (0, 4, 8)
PRECISE = sim_devices_wake_precisely()
#: the issue's one sample where the simulated devices wake on time (the module docstring: why it holds since D129); where
#: they cannot, D129 measured the devices' own scatter up to 1.23 samples, so the bar is two and every failure says why
OFFSET_BAR_SAMPLES = 1 if PRECISE else 2
SLACK_NOTE = "" if PRECISE else " (bar 2 samples: this host refused the simulated devices' 1 ns timer slack, D129)"
TRUE_DELAY_S = 0.2371  # the second device's configured start_delay
#: the truth: the simulated view delays its clock by whole samples (round(start_delay × fs) = 3885, 0.2371216 s),
#: so the clocks' true offset is that, not 0.2371 s (which put 0.35 samples of every error in the oracle itself)
TRUE_OFFSET_S = round(TRUE_DELAY_S * FS) / FS
ACC = [f"a{k:02d}" for k in range(1, 15)]
SMALL = ["a01", "a02"]  # the cut-down rig's sensors: what CAN FD (GVT_FD3) and Modbus TCP carry at 16384 Hz

#: cell -> the [[devices]] tables (name, driver, config, simulate) and the rig (None: beam_ch4_exp, "small": cut down)
CELLS = {
    "serial": ([("dev0", "serial", {}, {"format": "int24"})], None),
    "can-fd": ([("dev0", "can", {"messages": ["GVT_FD3"]}, {})], "small"),
    "modbus-tcp": ([("dev0", "modbus", {"channels": ["hammer", *SMALL]}, {})], "small"),
    "two-devices": ([("hammer_daq", "serial", {}, {"channels": ["hammer"]}),
                     ("acc_daq", "serial", {}, {"channels": ACC, "start_delay": TRUE_DELAY_S})], None),
}  # fmt: skip


def _toml_value(v) -> str:
    if isinstance(v, str):
        return f'"{v}"'
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return repr(v)


def _table(d: dict) -> str:
    return "{ " + ", ".join(f"{k} = {_toml_value(v)}" for k, v in d.items()) + " }"


def small_rig(directory: Path) -> Path:
    """beam_ch4_exp with only the sensors a01 and a02 (everything else, the structure included, as shipped)."""
    text = resolve_rig_path("beam_ch4_exp").read_text()
    head, *blocks = text.split("[[sensors]]")
    last = blocks[-1]
    cut = last.index("\n[", 1)  # the last sensor block ends where the next table starts
    blocks[-1], tail = last[:cut], last[cut:]
    keep = [b for b in blocks if re.search(r'name = "(\w+)"', b).group(1) in SMALL]
    out = directory / "beam_ch4_exp_a01_a02.toml"
    out.write_text(head.replace('name = "beam_ch4_exp"', 'name = "beam_ch4_exp_a01_a02"', 1)
                   + "".join("[[sensors]]" + b for b in keep) + tail)  # fmt: skip
    return out


def schedule(seconds: float, devices: int) -> tuple[float, float, list[float]]:
    """(first, period, forces) of a cell's hits: two (300 N, 800 N) a second apart in a short cell; in a long one
    (the bench) 300 / 800 N alternating every 2 s to the end, so the hit gate and the FRF lane work throughout. Two
    devices: the first hit after the offset is fixed (settle 0.5 s). Every hit's 0.3 s record ends in the session."""
    first = 0.8 if devices > 1 else 0.5
    period = 1.0 if seconds < 10 else 2.0
    n = 2 if seconds < 10 else int((seconds - 0.3 - first) // period) + 1
    return first, period, [(300.0, 800.0)[k % 2] for k in range(n)]


def session_file(directory: Path, cell: str, seconds: float, rig_small: Path | None = None) -> Path:
    """The cell's session config: 16384 Hz, the hits of :func:`schedule`, the analysis on with its defaults."""
    devices, rig = CELLS[cell]
    rig_name = str(rig_small) if rig == "small" else "beam_ch4_exp"
    first, period, forces = schedule(seconds, len(devices))
    tables = []
    for k, (name, driver, config, sim) in enumerate(devices):
        simulate = dict(sim) if k else {"forces": forces, "period": period, "first": first, "seed": 3, **sim}
        head = "[[devices]]" if len(devices) > 1 else "[device]"  # one device: [device] (channels from the rig)
        tables.append(f'{head}\nname = "{name}"\ndriver = "{driver}"\nconfig = {_table(config)}\n'
                      f"simulate = {_table(simulate)}\n")  # fmt: skip
    text = f'''name = "load-{cell}"
rig = "{rig_name}"
duration = {seconds}
end_grace_s = 10.0

{"".join(tables)}
[trigger]
channel = "hammer"
level = 20.0
pre_trigger = 0.01
record_length = 0.3

[analysis]
enabled = true
'''
    p = directory / f"{cell}.toml"
    p.write_text(text)
    return p


@dataclass
class Cell:
    """One session of the matrix and what it measured (bench/bench_load.py prints these)."""

    cell: str
    hogs: int
    seconds: float
    res: SessionResult
    out: Path
    load: LoadSeen

    def check(self) -> dict:
        """Everything the issue asks of a cell, measured; ``failures`` lists what did not hold (empty: the cell passes)."""
        res, fail = self.res, []
        want = round(self.seconds * FS)
        r = LogReader(self.out)
        streams = {}
        for name in res.streams:
            d = r.read_stream(name, channels=r.streams()[name].channels[:1])  # one channel: the index is what counts
            streams[name] = {"samples": len(d.index), "gaps": list(d.gaps), "first": int(d.index[0]) if len(d.index) else None}
            if d.gaps or len(d.index) != want or (len(d.index) and d.index[0] != 0):
                fail.append(f"{name}: log holds {len(d.index)} of {want} samples, gaps {d.gaps[:3]}")
        if res.lost_samples or res.writer_overrun_samples:
            fail.append(f"lost {res.lost_samples}, writer overruns {res.writer_overrun_samples} samples")
        hits = [(round(h.t_s, 3), h.verdict) for h in res.hits]
        fail += self._hit_problems(hits)
        if res.outcome is None or res.outcome.exit_code != 0:
            fail.append(f"outcome {res.outcome}")
        events = r.json_messages("/daq/events")
        overrun = [e for e in events if e["kind"] == "analysis_overrun"]
        counted = sum(int(e["count"]) for e in overrun)
        if counted != res.analysis_dropped_samples:
            fail.append(f"analysis shed {res.analysis_dropped_samples} samples, the log's analysis_overrun events say {counted}")
        late = [e for e in events if e["kind"] == "overrun" and (e.get("start_index") or 0) >= want]
        if late:  # issue 30 item 6: blocks after the session's end are not lost, and must not be reported so
            n_late = sum(int(e.get("count") or 0) for e in late)
            fail.append(f"{len(late)} overrun events ({n_late} samples) after the session's end, "
                        f"e.g. {late[0]['stream']} {late[0]['start_index']}..{late[0]['end_index']}: {late[0]['message']}")
        errors = [e["message"] for e in events if e["kind"] == "analysis_error"]
        abandoned = any(e["kind"] == "lane_abandoned" for e in events)
        if abandoned and self.res.analysis_dropped_samples >= want:
            # a worker at nice +10 starved for the whole short cell (8 hogs): abandoned at its deadline and killed, every
            # sample counted as shed -- the bar ("every shed analysis window counted"); the kill is its error line
            errors = [m for m in errors if "while finishing" not in m]
        if errors:
            fail.append(f"analysis error: {errors[0]}")
        cover = self._coverage(r, want)
        if cover["problem"]:
            fail.append(cover["problem"])
        offset = self._offset(res)
        if offset is not None and not abs(offset["error_s"]) <= OFFSET_BAR_SAMPLES / FS:
            unc = float(offset["uncertainty_s"] or "nan") * FS
            fail.append(f"offset {offset['offset_s']:.7f} s vs true {TRUE_OFFSET_S:.7f} s "
                        f"({offset['error_s'] * FS:+.2f} samples, uncertainty {unc:.2f}){SLACK_NOTE}")  # fmt: skip
        if offset is not None and not abs((offset["applied_samples"] or 0) - offset["true_samples"]) <= OFFSET_BAR_SAMPLES:
            fail.append(f"the merged stream placed acc_daq {offset['applied_samples']} samples late, the truth is "
                        f"{offset['true_samples']}{SLACK_NOTE}")  # fmt: skip
        if fail and res.host_stalls:  # what the process itself went through (D132): said beside the failure
            spans = ", ".join(f"({a:.1f}, {b:.1f})" for a, b in res.host_stalls)
            fail.append(f"the recording process stalled (at s, for s): {spans}")
        lat = np.asarray(res.analysis_latencies_s)
        return {
            "cell": self.cell, "hogs": self.hogs, "seconds": self.seconds, "load": self.load.as_dict(), "streams": streams,
            "lost_samples": res.lost_samples, "writer_overrun_samples": res.writer_overrun_samples,
            "analysis_dropped_samples": res.analysis_dropped_samples, "analysis_overrun_counted": counted,
            "coverage": cover, "offset": offset, "wall_s": res.seconds,
            "latency_p50_ms": float(np.percentile(lat, 50) * 1e3) if lat.size else None,
            "latency_p99_ms": float(np.percentile(lat, 99) * 1e3) if lat.size else None,
            "hits": len(hits), "hits_accepted": sum(v == "accepted" for _, v in hits), "confirmations": len(res.confirmations),
            "events": {k: sum(e["kind"] == k for e in events) for k in sorted({e["kind"] for e in events})},
            "exit_code": None if res.outcome is None else res.outcome.exit_code,
            "failures": fail,
        }  # fmt: skip

    def _hit_problems(self, hits: list[tuple[float, str]]) -> list[str]:
        """The hit gate must see every sample: each scheduled hit found where it was (its trigger edge lies within the
        1 ms half-sine's rise of the scheduled start: 2 ms), and accepted; the aligner dropped nothing."""
        first, period, forces = schedule(self.seconds, len(self.res.streams))
        due = [first + k * period for k in range(len(forces))]
        out = []
        if len(hits) != len(due) or any(abs(t - d) >= 2e-3 for (t, _), d in zip(hits, due, strict=False)):
            out.append(f"hits {hits[:4]}{' ...' if len(hits) > 4 else ''} ({len(hits)}), scheduled {len(due)} from {first} s")
        elif any(v != "accepted" for _, v in hits):
            out.append(f"hits not all accepted: {[h for h in hits if h[1] != 'accepted'][:4]}")
        if any(self.res.aligner_dropped.values()):
            out.append(f"the hit gate missed samples: {self.res.aligner_dropped}")
        return out

    def _coverage(self, r: LogReader, want: int) -> dict:
        """The analysis stream's windows written plus samples shed against its samples.

        Windows tile each run of contiguous data from its first sample (analysis/operator.py ``_Grid``), and a run
        ends at a gap the lane made by shedding; so per run at most one window's length (the tail that never filled
        a window) is neither written nor shed. Single device: the shed samples are the analysis stream's own, so
        ``want − shed − written`` lies in [0, runs × L). Two devices: the lane also sheds the hammer device's blocks
        (its subscription sees both streams), so ``written + shed ≥ want − runs × L`` is what can be asserted."""
        rq = r.json_messages("/analysis/rq")
        spans = sorted((int(w["start"]), int(w["stop"])) for w in rq)
        restarts = sum(1 for w in r.json_messages("/analysis/warnings") if w.get("kind") == "gap")
        runs = restarts + 1
        length = max((b - a for a, b in spans), default=0)
        written = sum(b - a for a, b in spans)
        shed = self.res.analysis_dropped_samples
        out = {"windows": len(spans), "window_samples": length, "written": written, "shed": shed, "runs": runs,
               "uncovered": want - written - shed, "problem": None}  # fmt: skip
        if not spans and shed < want:  # nothing analysed is a failure unless all of it was shed and counted
            out["problem"] = "no analysis window written"
        elif not spans:
            pass
        elif any(b0 < a1 for (_, a1), (b0, _) in pairwise(spans)) or spans[0][0] < 0 or spans[-1][1] > want:
            out["problem"] = "analysis windows overlap or leave the stream"
        elif len(self.res.streams) == 1 and not 0 <= want - written - shed < runs * length:
            out["problem"] = f"windows {written} + shed {shed} samples vs {want} (runs {runs}, window {length}): not all counted"
        elif len(self.res.streams) > 1 and written + shed < want - runs * length:
            out["problem"] = f"windows {written} + shed {shed} samples vs {want} (runs {runs}, window {length}): not all counted"
        return out

    def _offset(self, res: SessionResult) -> dict | None:
        if len(res.streams) < 2:
            return None
        t = res.timeline.get("acc_daq") or {}
        off = t.get("offset_s")
        return {"offset_s": off, "applied_samples": t.get("applied_samples"), "true_samples": round(TRUE_DELAY_S * FS),
                "uncertainty_s": t.get("uncertainty_s"), "method": t.get("method"),
                "error_s": float("nan") if off is None else off - TRUE_OFFSET_S}  # fmt: skip


def run_cell(directory: Path, cell: str, hogs: Hogs, seconds: float, rig_small: Path | None = None) -> Cell:
    """Record one cell with ``hogs`` running (started once the simulated devices are built, :func:`load_from_device_start`;
    stopped when the session returns — the caller's finaliser stops them too if the session raises)."""
    import daq.lanes.host as host_module

    path = session_file(directory, cell, seconds, rig_small)
    cfg = load_config(SessionConfig, path)
    out = directory / f"{cell}-{hogs.n}.mcap"
    catch_up = host_module.END_CATCH_UP_S
    host_module.END_CATCH_UP_S = min(catch_up, max(2.0, seconds / 12))  # short cells: module docstring; 60 s: 5 s
    try:
        with load_from_device_start(hogs):
            res = run_session(cfg, open_rig(cfg.rig), out)
    finally:
        host_module.END_CATCH_UP_S = catch_up
        seen = hogs.stop()
    if hogs.started < hogs.n:  # the session no longer builds its devices through daq.session.start_simulation
        raise RuntimeError(f"{cell}: the {hogs.n} hogs never started (load_from_device_start found no hook)")
    return Cell(cell, hogs.n, seconds, res, out, seen)


@contextmanager
def load_from_device_start(hogs: Hogs):
    """Start ``hogs`` as soon as the session's simulated devices exist, before the recorder opens them.

    Why not before the session: building the simulated structure (``daq.sim_devices.start_simulation``: the beam's
    model and response, 1–2 CPU-s, which a real device does not need) took 9–10 s at 8 hogs (46 s in a cold process),
    which the matrix would pay 8 times over in make test's budget; what is under test — opening the links, the
    recording, every lane, the drain — all runs on the loaded host. ``run_session`` looks the function up in its
    module at call time, so wrapping the module's name is enough."""
    import daq.session as session_module

    original = session_module.start_simulation

    def start_then_load(*args, **kwargs):
        harness = original(*args, **kwargs)
        hogs.start()
        return harness

    session_module.start_simulation = start_then_load
    try:
        yield
    finally:
        session_module.start_simulation = original


@pytest.fixture(scope="module")
def rig_small(tmp_path_factory):
    return small_rig(tmp_path_factory.mktemp("rig"))


@pytest.fixture
def hogs(request):
    """The cell's hogs (not started): killed in the finaliser whatever happens to the test."""
    h = Hogs(request.param, limit_s=SECONDS + 120)  # each hog's own deadline: the cell plus a generous drain
    request.addfinalizer(h.stop)
    return h


def _cells() -> list:
    """Every (hogs, cell), 0 hogs first. The cells with hogs are host_timing (make test runs them alone, after the
    parallel phase); so is the 0-hog serial cell, which runs first there and warms that process (imports, numba's
    kernels, the lane worker's fork server) so no loaded cell pays for it. The other 0-hog cells start no hogs and
    run in the parallel phase, on a host the suite's own workers keep busy: a harder test than a quiet host."""
    out = []
    for n in HOGS:
        for cell in sorted(CELLS):
            timed = n > 0 or cell == "serial"
            out.append(pytest.param(n, cell, id=f"{n}hogs-{cell}", marks=[pytest.mark.host_timing] if timed else []))
    return out


@pytest.mark.slow
@pytest.mark.parametrize("hogs,cell", _cells(), indirect=["hogs"])
def test_a_loaded_host_loses_nothing_and_counts_what_the_analysis_shed(tmp_path, rig_small, cell, hogs):
    c = run_cell(tmp_path, cell, hogs, SECONDS, rig_small)
    m = c.check()
    if os.environ.get("GVT_LOAD_JSON"):  # a file to append each cell's figures to (bench/bench_load.py --table prints it)
        with open(os.environ["GVT_LOAD_JSON"], "a") as f:
            f.write(json.dumps(m, default=str) + "\n")
    # every figure is exact (sample counts from the log against duration × fs; the shed count against the log's own
    # events) except the offset, whose bound is OFFSET_BAR_SAMPLES sample period (61 µs) of the simulated truth
    assert m["failures"] == [], (f"{cell} at {hogs.n} hogs (load {c.load.as_dict()}): " + "; ".join(m["failures"]))


def test_hogs_end_at_their_own_deadline_and_stop_kills_them():
    """The bound that keeps a crashed test from leaving hogs behind: each ends itself at ``limit_s`` (wall clock),
    and ``stop`` kills the rest by pid."""
    import time

    t0 = time.monotonic()
    h = Hogs(2, limit_s=0.5).start()
    assert h.alive() == 2
    while h.alive() and time.monotonic() - t0 < 10:
        time.sleep(0.05)
    assert h.alive() == 0 and 0.5 <= time.monotonic() - t0 < 10  # 10 s: a python start-up on a loaded 2-core host
    h.stop()
    long = Hogs(1, limit_s=600).start()
    pid = long.procs[0].pid
    seen = long.stop()
    assert long.procs == [] and seen.samples >= 1
    with pytest.raises(ProcessLookupError):  # reaped: the pid is gone
        os.kill(pid, 0)


def test_hogs_run_at_the_priority_the_process_started_at_not_the_recorders():
    """A session raises its process to nice -5 (daq/priority.py); hogs started later from the same process must not
    inherit it (a lab's other programs run at normal priority). Run in a child so this worker's priority is untouched."""
    import subprocess
    import sys

    code = (
        "import sys, time\nsys.path.insert(0, 'tests')\nfrom daq.priority import base_nice, raise_priority\n"
        "from hogs import Hogs\nraise_priority()\nimport os\nh = Hogs(1, limit_s=5).start()\n"
        "time.sleep(0.2)\nnice = int(open(f'/proc/{h.procs[0].pid}/stat').read().rsplit(')', 1)[1].split()[16])\n"
        "print(base_nice(), os.getpriority(os.PRIO_PROCESS, 0), nice)\nh.stop()\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                         cwd=Path(__file__).resolve().parents[1])  # fmt: skip
    base, raised, hog = map(int, out.stdout.split())
    assert hog == base, f"hog at nice {hog}, the process started at {base} and records at {raised}"
