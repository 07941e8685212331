"""Issue 30 item 2: the log writer's buffer sized by memory (D67), measured.

Two measurements, one run:

* **A device's burst after a stall.** A 6 s CAN FD session at 16384 Hz (3 channels, the simulated node) whose
  node sends nothing from 1 s to 4 s and then its 3 s backlog at once (the burst that lost 1,300 samples at
  load 20 in issue 30). Each case runs twice in the same run: ``before``, the writer's queue as it was
  (0.5 s of blocks by count, ``queue_seconds`` through the per-driver block guess) and ``now``, the memory
  budget (``writer_buffer_mib`` = 256 MiB) — with 0 and 8 CPU hogs on the machine (``--load``). Reported:
  samples lost on the link, writer overruns (NOT RECORDED), the writer's peak backlog (s of data, MiB), and
  the samples the hit gate skipped (``subscriber_overrun``: its own queue, which the burst also crosses).
* **The crash bound.** ``tests/crash_recorder.py`` records 8 ch x 8192 Hz while its disk stops answering
  0.5 s in; it is SIGKILLed 1, 2 and 4 s later and the log is recovered. Reported: the backlog the writer
  said at the kill, what the recovered log lacks, and the bound (backlog + one flush interval, 0.25 s here).

Prints two tables, writes bench/results/bench_writer_buffer.json. ~2 min.

    python bench/bench_writer_buffer.py [--load 0 8]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import platform
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

FS = 16384
DURATION = 6.0
SESSION = """name = "can-stall"
rig = "beam_ch4_exp"
duration = {duration}
end_grace_s = 20.0

[device]
name = "dev0"
driver = "can"
config = {{ messages = ["GVT_FD3"] }}
simulate = {{ forces = [300.0, 800.0], period = 1.0, first = 0.5, seed = 3, stall_at_s = 1.0, stall_for_s = 3.0 }}

[trigger]
level = 20.0
pre_trigger = 0.01
record_length = 0.3

[analysis]
enabled = false
"""


def _burn() -> None:  # a CPU hog standing in for other work on the machine
    x = 0
    while True:
        x += 1


def _old_queue(monkey_session) -> None:
    """The writer's queue before D67: 0.5 s of blocks by count (CAN's block guess: 256 samples), no byte budget."""
    from daq.lanes.log import LogLane

    class OldLogLane(LogLane):
        def __init__(self, path, **kw):
            kw.update(queue_size=max(8, int(0.5 * FS / 256)), buffer_bytes=None)
            super().__init__(path, **kw)

    monkey_session.LogLane = OldLogLane


def _session(sizing: str, load: int, tmp: Path) -> dict:
    """One session in a fresh process (so the old sizing's patch and the hogs' scheduling are its own)."""
    cfg = tmp / "can-stall.toml"
    cfg.write_text(SESSION.format(duration=DURATION))
    code = f"""
import json, sys, time
sys.path.insert(0, {str(ROOT)!r})
import daq.session as S
from analysis.model.loader import load_config
from analysis.model.rigs import open_rig
from daq.config.session import SessionConfig
sys.path.insert(0, {str(ROOT / "bench")!r})
import bench_writer_buffer as B
if {sizing!r} == "before":
    B._old_queue(S)
c = load_config(SessionConfig, {str(cfg)!r})
t0 = time.monotonic()
out = {str(tmp / f"{sizing}-{load}.mcap")!r}
res = S.run_session(c, open_rig(c.rig), out)
from daq.log.reader import LogReader
gate = sum(e.get("count", 0) for e in LogReader(out).json_messages("/daq/events") if e["kind"] == "subscriber_overrun")
print(json.dumps({{"wall_s": time.monotonic() - t0, "lost": res.lost_samples, "overrun": res.writer_overrun_samples,
                  "samples": res.samples, "backlog": res.writer_backlog, "hit_gate_dropped": gate}}))
"""
    hogs = [multiprocessing.Process(target=_burn, daemon=True) for _ in range(load)]
    for h in hogs:
        h.start()
    try:
        p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                           env={**os.environ, "PYTHONPATH": str(ROOT)})  # fmt: skip
    finally:
        for h in hogs:
            h.terminate()
    if p.returncode != 0:
        return {"sizing": sizing, "load_hogs": load, "error": (p.stderr.strip().splitlines() or ["?"])[-1]}
    r = json.loads(p.stdout.strip().splitlines()[-1])
    b = r.pop("backlog")
    return {"sizing": sizing, "load_hogs": load, **r, "peak_backlog_s": b.get("peak_seconds", 0.0),
            "peak_backlog_mib": b.get("peak_bytes", 0) / 2**20}  # fmt: skip


def _crash(kill_after_s: float, tmp: Path) -> dict:
    """SIGKILL ``kill_after_s`` into a stalled disk; what the recovered log lacks against the reported backlog."""
    from daq.log.reader import LogReader
    from daq.log.tools import recover

    fs, n_ch, block, flush_s, stall_at = 8192.0, 8, 512, 0.25, 0.5
    out = tmp / f"crash-{kill_after_s:g}.mcap"
    proc = subprocess.Popen([sys.executable, str(ROOT / "tests" / "crash_recorder.py"), str(out), str(fs), str(n_ch),
                             str(block), str(stall_at), "600"], stdout=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})  # fmt: skip
    last, backlog, t_kill = 0, 0.0, None
    try:
        assert proc.stdout is not None
        for line in proc.stdout:
            last, backlog = int(line.split()[0]), float(line.split()[1])
            t_kill = t_kill or time.monotonic() + stall_at + kill_after_s
            if time.monotonic() >= t_kill:
                break
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    rec = tmp / f"rec-{kill_after_s:g}.mcap"
    recover(out, rec)
    n = len(LogReader(rec).read_stream("dev0").index)
    lost_s = (last - n) / fs
    return {"kill_after_stall_s": kill_after_s, "handed_s": last / fs, "recovered_s": n / fs, "backlog_at_kill_s": backlog,
            "lost_s": lost_s, "bound_s": backlog + flush_s, "within": lost_s <= backlog + flush_s + 2 * block / fs}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--load", type=int, nargs="*", default=[0, 8], help="CPU hogs alongside the sessions")
    args = ap.parse_args()
    rows, crashes = [], []
    with tempfile.TemporaryDirectory() as d:
        for load in args.load:
            for sizing in ("before", "now"):
                rows.append(_session(sizing, load, Path(d)))
        for after in (1.0, 2.0, 4.0):
            crashes.append(_crash(after, Path(d)))
    print(f"\nA 3 s CAN FD stall at {FS} Hz, 3 ch, {DURATION:g} s session: the writer's queue before D67 (0.5 s of blocks) "
          "and now (256 MiB)")  # fmt: skip
    print(f"{'hogs':>5} {'sizing':>7} {'lost':>6} {'overrun':>8} {'peak backlog s':>15} {'MiB':>6} {'gate drop':>10} "
          f"{'wall s':>7}")  # fmt: skip
    for r in rows:
        if "error" in r:
            print(f"{r['load_hogs']:>5} {r['sizing']:>7}  failed: {r['error']}")
            continue
        print(f"{r['load_hogs']:>5} {r['sizing']:>7} {r['lost']:>6} {r['overrun']:>8} {r['peak_backlog_s']:>15.2f} "
              f"{r['peak_backlog_mib']:>6.2f} {r['hit_gate_dropped']:>10} {r['wall_s']:>7.1f}")  # fmt: skip
    print("\nSIGKILL during a stalled disk (8 ch x 8192 Hz, flush every 0.25 s): lost vs backlog + one flush interval")
    print(f"{'killed after s':>15} {'backlog s':>10} {'lost s':>8} {'bound s':>8} {'within':>7}")
    for c in crashes:
        print(f"{c['kill_after_stall_s']:>15.1f} {c['backlog_at_kill_s']:>10.3f} {c['lost_s']:>8.3f} {c['bound_s']:>8.3f} "
              f"{c['within']!s:>7}")  # fmt: skip
    out = ROOT / "bench" / "results" / "bench_writer_buffer.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"machine": platform.platform(), "cpus": os.cpu_count(), "stall": rows, "crash": crashes},
                              indent=1))  # fmt: skip
    print(f"\nwrote {out.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
