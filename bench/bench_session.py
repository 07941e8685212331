"""Session benchmark (issue 18): the Recorder against the previous recorder, and the analysis lane's frames.

1. **Recorder vs the previous recorder**, in the same run: ``gvt record`` of the same session TOML from this
   tree and from a git worktree of the base commit (default 3ccae7c: the last commit with ``daq/session.py``'s
   ``_run``), alternating A/B so the machine's drift hits both alike. CPU (user + sys of the recorder and its
   children, from ``os.wait4``) per second of data; the ratio new/base per pair, median and range.
   Sessions: 15 ch × 16384 Hz over a pty (serial), 64 ch × 51.2 kHz in-process (paced), both with the
   near-live analysis off (the recording path the Recorder replaced), and the serial one with it on.
2. **The analysis lane's frames**: the same serial session in-process, the lane fed block by block (64-sample
   serial blocks) against joined into frames (up to 1024 samples, at most ``frame_wait_s`` after the first
   block arrived): the lane thread's CPU per second of data and the per-window latency (first block arrival →
   result) p50 / p99 / max.

    python bench/bench_session.py [--seconds 20] [--pairs 5] [--base 3ccae7c] [--quick]
    python bench/bench_session.py --isolation [--base REV --pairs 3 --seconds 20]

3. ``--isolation``: the lanes in a worker process against in the recorder's own process, quiet and with 4 hogs
   (issue 30 item 1). With ``--base REV`` instead: the quiet worker session from this tree and from REV, alternating
   A/B (issue 30 item 5: the recording process <= 0.1 core, the lanes <= 0.5 core), per thread in the JSON.

Each case first runs once per tree unrecorded (page cache, numba cache), then the counted pairs.

Prints tables; writes bench/results/bench_session.json.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
BASE_DEFAULT = "3ccae7c"

SERIAL = """name = "bench-serial-15ch"
rig = "beam_ch4_exp"
duration = {seconds}

[device]
name = "dev0"
driver = "serial"

[device.simulate]
forces = {forces}
period = 0.5
seed = 1

[trigger]
level = 20.0
record_length = 0.3
driving_point = "a13"

[analysis]
enabled = {analysis}
confirm = false
"""

SIM64 = """name = "bench-sim-64ch"
rig = "bench_64ch"
duration = {seconds}

[device]
name = "dev0"
driver = "sim"
config = {{ paced = true, block_size = 1024, forces = [800.0, 1500.0], period = 1.0, physics_seconds = 3.0 }}

[trigger]
level = 20.0
record_length = 0.3

[analysis]
enabled = {analysis}
confirm = false
"""


def worktree(base: str) -> Path:
    path = Path(tempfile.gettempdir()) / f"gvt-bench-base-{base}"
    if not (path / "daq").exists():
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(path), base], check=True,
                       capture_output=True)  # fmt: skip
    return path


def record_cpu(tree: Path, toml: Path, out: Path) -> tuple[float, float]:
    """(CPU s, wall s) of one ``gvt record`` from ``tree`` (its own daq/ first on the path)."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "daq.cli", "record", str(toml), "--out", str(out)], cwd=tree, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)  # fmt: skip
    _pid, status, ru = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"gvt record failed in {tree}: {proc.stderr.read().decode()[-400:] if proc.stderr else ''}")
    return ru.ru_utime + ru.ru_stime, wall


def compare(base_tree: Path, seconds: float, pairs: int, tmp: Path) -> list[dict]:
    forces = [400.0, 800.0, 1200.0, 1583.0] * int(seconds)
    cases = {
        "serial 15 ch x 16384 Hz, analysis off": SERIAL.format(seconds=seconds, forces=forces, analysis="false"),
        "sim 64 ch x 51.2 kHz paced, analysis off": SIM64.format(seconds=seconds, analysis="false"),
        "serial 15 ch x 16384 Hz, analysis on": SERIAL.format(seconds=seconds, forces=forces, analysis="true"),
    }
    rows = []
    for name, text in cases.items():
        toml = tmp / "s.toml"
        toml.write_text(text)
        new_cpu, base_cpu = [], []
        for tag, tree in (("new", ROOT), ("base", base_tree)):  # one warm-up each (page cache, numba cache): not counted
            record_cpu(tree, toml, tmp / f"warm-{tag}.mcap")
            (tmp / f"warm-{tag}.mcap").unlink(missing_ok=True)
        for k in range(pairs):
            order = [("new", ROOT), ("base", base_tree)] if k % 2 == 0 else [("base", base_tree), ("new", ROOT)]
            for tag, tree in order:
                out = tmp / f"{tag}-{k}.mcap"
                cpu, wall = record_cpu(tree, toml, out)
                (new_cpu if tag == "new" else base_cpu).append(cpu / seconds)
                print(f"  {name}: pair {k + 1} {tag}: {cpu / seconds:.4f} CPU-s per data-s ({wall:.1f} s wall)", flush=True)
                out.unlink(missing_ok=True)
        ratios = [n / b for n, b in zip(new_cpu, base_cpu, strict=True)]
        rows.append({"session": name, "new_cpu_per_s": new_cpu, "base_cpu_per_s": base_cpu, "ratios": ratios,
                     "ratio_median": statistics.median(ratios), "ratio_min": min(ratios), "ratio_max": max(ratios)})  # fmt: skip
    return rows


def frames(seconds: float, tmp: Path) -> list[dict]:
    from analysis.model.loader import load_config
    from analysis.model.rigs import open_rig
    from daq.config.session import SessionConfig
    from daq.session import run_session

    toml = tmp / "frames.toml"
    toml.write_text(SERIAL.format(seconds=seconds, forces=[400.0, 800.0, 1200.0, 1583.0] * int(seconds), analysis="true"))
    cfg = load_config(SessionConfig, toml)
    rows = []
    for label, frame in (("block by block", 0.0), ("frames (default)", None)):
        res = run_session(cfg, open_rig(cfg.rig), tmp / "frames.mcap", overwrite=True, analysis_frame_s=frame)
        lat = np.asarray(res.analysis_latencies_s) * 1000
        data_s = res.samples / 16384
        rows.append({"lane": label, "cpu_per_data_s": res.analysis_cpu_s / data_s, "windows": int(lat.size),
                     "latency_ms_p50": float(np.percentile(lat, 50)), "latency_ms_p99": float(np.percentile(lat, 99)),
                     "latency_ms_max": float(lat.max()), "events": len(res.analysis_events),
                     "dropped_samples": res.analysis_dropped_samples, "lost_samples": res.lost_samples})  # fmt: skip
        r = rows[-1]
        print(f"  analysis lane {label}: {r['cpu_per_data_s']:.4f} CPU-s/data-s, p99 {r['latency_ms_p99']:.1f} ms", flush=True)
    return rows


SERVED = """name = "bench-served-15ch"
rig = "beam_ch4_exp"
duration = {seconds}

[device]
name = "dev0"
driver = "serial"
config = {{ port = "{port}", sample_rate = 16384.0, channels = {channels}, usb_cdc = true }}

[trigger]
level = 20.0
record_length = 0.3

[analysis]
process = "{mode}"
worker_nice = {nice}
"""


def _serve(seconds: float) -> tuple[subprocess.Popen, str, list[str]]:
    """``gvt device serve`` in its own process (its cost is not the recorder's): 15 ch x 16384 Hz over a pty."""
    from analysis.model.rigs import open_rig

    rig = open_rig("beam_ch4_exp")
    channels = [p.name for p in [rig.hammer, *rig.sensors]]
    proc = subprocess.Popen([sys.executable, "-m", "daq.cli", "device", "serve", "beam_ch4_exp", "--transport", "serial",
                             "--seconds", f"{seconds:g}", "--hits", str(max(1, int(seconds / 2))), "--period", "2.0",
                             "--channels", ",".join(channels)], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, preexec_fn=_device_priority)  # fmt: skip
    line = proc.stdout.readline()
    m = re.search(r"port = '([^']+)'", line)
    if m is None:
        proc.kill()
        raise SystemExit(f"gvt device serve did not start: {line} {proc.stderr.read()[-400:]}")
    return proc, m.group(1), channels


def _device_priority() -> None:
    """The served device stands for hardware, which busy-loop hogs do not starve: nice -10 where permitted (at nice 0
    beside 4 hogs it went silent for 5.6 s and reconnected five times, which measured the simulator, not the
    recorder)."""
    try:
        os.nice(-10)
    except OSError:
        pass


class _CpuSampler:
    """CPU seconds of this process's threads (by name) and of its child processes, sampled every 0.25 s (a thread or
    process that ends keeps its last sample). ``skip``: pids not counted (the served device)."""

    def __init__(self, skip: set[int]) -> None:
        import psutil

        self.me, self.skip = psutil.Process(), skip
        self.threads: dict[str, float] = {}
        self.children: dict[int, float] = {}
        self.stop = threading.Event()
        self.t = threading.Thread(target=self._run, name="bench-sampler", daemon=True)
        self.t.start()

    def _run(self) -> None:
        tick = os.sysconf("SC_CLK_TCK")
        while not self.stop.wait(0.25):
            for th in threading.enumerate():
                try:
                    f = Path(f"/proc/self/task/{th.native_id}/stat").read_text().rsplit(")", 1)[1].split()
                    self.threads[th.name.split(":")[0]] = (int(f[11]) + int(f[12])) / tick
                except (OSError, TypeError):
                    pass
            for ch in self.me.children(recursive=True):
                if ch.pid in self.skip:
                    continue
                try:
                    t = ch.cpu_times()
                    self.children[ch.pid] = t.user + t.system
                except Exception:  # gone between the listing and the reading
                    pass

    def mark(self) -> None:
        """From now on (the session's start-up, imports and warm-up are not what a data-second costs)."""
        time.sleep(0.3)
        self.base = (dict(self.threads), dict(self.children))

    def close(self) -> tuple[dict[str, float], float]:
        """CPU since :meth:`mark`: per thread name, and of the child processes together."""
        self.stop.set()
        self.t.join()
        bt, bc = self.base
        return ({k: v - bt.get(k, 0.0) for k, v in self.threads.items()},
                sum(v - bc.get(p, 0.0) for p, v in self.children.items()))  # fmt: skip


def isolation(seconds: float, hog_seconds: float, tmp: Path) -> list[dict]:
    """Issue 30 item 1: the recorder with the analysis and confirmation lanes in a worker process against in its own
    process (``[analysis] process``), the device served by its own process; quiet, and with 4 busy-loop hogs."""
    rows = []
    for hogs, secs in ((0, seconds), (4, hog_seconds)):
        for mode, nice in (("worker", 10), ("worker", 0), ("thread", 0)):
            if mode == "worker" and nice == 0 and hogs == 0:
                continue  # on a quiet machine the step does not matter
            rows.append(_isolated_session(mode, secs, hogs, tmp, nice))
            r = rows[-1]
            print(f"  {mode:6s} nice+{nice} hogs={hogs}: recorder {r['recorder_cpu_per_s']:.3f} core, lanes (worker + pool) "
                  f"{r['lanes_cpu_per_s']:.3f}, lost {r['lost_samples']}, shed {r['analysis_shed_samples']}, "
                  f"p99 {r['latency_ms_p99']:.1f} ms", flush=True)  # fmt: skip
    return rows


def _isolated_session(mode: str, seconds: float, hogs: int, tmp: Path, nice: int = 10) -> dict:
    import resource

    from analysis.model.loader import load_config
    from analysis.model.rigs import open_rig
    from daq.config.session import SessionConfig
    from daq.session import Session, SessionOptions
    from daq.sim_devices import start_simulation

    dev, port, channels = _serve(seconds + 60)
    hog = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(hogs)]
    try:
        toml = tmp / f"iso-{mode}.toml"
        toml.write_text(SERVED.format(seconds=seconds, port=port, channels=json.dumps(channels), mode=mode, nice=nice))
        cfg = load_config(SessionConfig, toml)
        rig = open_rig(cfg.rig)
        harness = start_simulation(cfg, rig)
        sampler = _CpuSampler({dev.pid, *(h.pid for h in hog)})
        session = Session(cfg, rig, tmp / f"iso-{mode}.mcap", harness, SessionOptions(overwrite=True))
        sampler.mark()
        r0 = resource.getrusage(resource.RUSAGE_SELF)
        res = session.run()
        r1 = resource.getrusage(resource.RUSAGE_SELF)
        thread_cpu, child_cpu = sampler.close()
        harness.stop()
    finally:
        for h in hog:
            h.kill()
            h.wait()
        dev.terminate()
        dev.communicate(timeout=20)
    data_s = res.samples / 16384
    rec = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime) - thread_cpu.get("bench-sampler", 0.0)  # not the recorder's
    lane_threads = ("frf", "analysis", "confirm", "lanes-fwd", "lanes-recv", "gvt-seed-lane_0")
    lanes = child_cpu + sum(v for k, v in thread_cpu.items() if k in lane_threads)
    threads = {k: round(v / data_s, 4) for k, v in sorted(thread_cpu.items(), key=lambda kv: -kv[1])}
    lat = np.asarray(res.analysis_latencies_s or [0.0]) * 1000
    label = mode if mode == "thread" else f"worker+{nice}"
    return {"mode": label, "hogs": hogs, "seconds": seconds, "data_s": data_s, "recorder_cpu_per_s": rec / data_s,
            "lanes_cpu_per_s": lanes / data_s, "threads_cpu_per_s": threads, "frf_cpu_per_s": threads.get("frf", 0.0),
            "worker_cpu_per_s": res.analysis_cpu_s / data_s if mode == "worker" else None,  # its process, not the pool
            "lost_samples": res.lost_samples, "writer_overrun_samples": res.writer_overrun_samples,
            "analysis_shed_samples": res.analysis_dropped_samples, "windows": len(res.analysis_latencies_s),
            "latency_ms_p50": float(np.percentile(lat, 50)), "latency_ms_p99": float(np.percentile(lat, 99)),
            "events": len(res.analysis_events), "confirmations": len(res.confirmations),
            "skipped": sum(c.get("status") != "confirmed" for c in res.confirmations), "exit": res.outcome.exit_code}  # fmt: skip


def isolation_ab(base_tree: Path, seconds: float, pairs: int) -> list[dict]:
    """Issue 30 item 5: the quiet worker session (nice +10) from this tree and from ``base_tree``, alternating A/B in
    the same run, each in its own process (``--one-isolated``: that tree's daq/ first on the path)."""
    rows = []
    for k in range(pairs):
        order = [("new", ROOT), ("base", base_tree)] if k % 2 == 0 else [("base", base_tree), ("new", ROOT)]
        for tag, tree in order:
            env = {**os.environ, "PYTHONPATH": str(tree)}
            out = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--one-isolated", "--seconds", f"{seconds:g}"],
                                 cwd=tree, env=env, capture_output=True, text=True, check=True).stdout  # fmt: skip
            r = json.loads(out[out.index("{") :])
            r["tree"] = tag
            rows.append(r)
            print(f"  pair {k + 1} {tag}: recorder {r['recorder_cpu_per_s']:.3f} core, lanes {r['lanes_cpu_per_s']:.3f}, "
                  f"lost {r['lost_samples']}, events {r['events']}", flush=True)  # fmt: skip
    return rows


def print_isolation_ab(rows: list[dict]) -> None:
    print(f"{'tree':5s} {'recorder core (median, range)':>30s} {'lanes core (median, range)':>28s} {'lost':>5s}")
    for tag in ("base", "new"):
        rs = [r for r in rows if r["tree"] == tag]
        rec, lanes = [r["recorder_cpu_per_s"] for r in rs], [r["lanes_cpu_per_s"] for r in rs]
        lost = sum(r["lost_samples"] + r["writer_overrun_samples"] for r in rs)
        print(f"{tag:5s} {statistics.median(rec):14.3f} ({min(rec):.3f}-{max(rec):.3f}) {statistics.median(lanes):14.3f} "
              f"({min(lanes):.3f}-{max(lanes):.3f}) {lost:5d}")  # fmt: skip
    for tag in ("base", "new"):
        th: dict[str, list[float]] = {}
        for r in (r for r in rows if r["tree"] == tag):
            for k, v in r["threads_cpu_per_s"].items():
                th.setdefault(k, []).append(v)
        print(f"  {tag} per thread (median core): " + ", ".join(f"{k} {statistics.median(v):.4f}" for k, v in th.items()))


def print_isolation(rows: list[dict]) -> None:
    print(f"{'mode':9s} {'hogs':>4s} {'recorder':>8s} {'lanes':>6s} {'frf':>6s} {'lost':>6s} {'shed':>7s} {'p50 ms':>7s} "
          f"{'p99 ms':>7s} {'events':>6s} {'skipped':>7s}")  # fmt: skip
    for r in rows:
        print(f"{r['mode']:9s} {r['hogs']:4d} {r['recorder_cpu_per_s']:8.3f} {r['lanes_cpu_per_s']:6.3f} "
              f"{r['frf_cpu_per_s']:6.4f} {r['lost_samples'] + r['writer_overrun_samples']:6d} {r['analysis_shed_samples']:7d} "
              f"{r['latency_ms_p50']:7.1f} {r['latency_ms_p99']:7.1f} {r['events']:6d} {r['skipped']:7d}")  # fmt: skip
    print("CPU in cores (CPU-s per data-s); recorder: the whole recording process, lanes included in thread mode (per "
          "thread: the JSON); lanes: the worker and the confirmation pool, plus the recorder's lane threads (FRF, the "
          "forwarder and receiver; thread mode: the analysis)")
    print("target (issue 30): recorder <= 0.1 core, lanes <= 0.5 core; 0 lost")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--pairs", type=int, default=5)
    ap.add_argument("--base", default=BASE_DEFAULT, help="git revision of the previous recorder")
    ap.add_argument("--quick", action="store_true", help="6 s sessions, 1 pair")
    ap.add_argument("--isolation", action="store_true", help="only the lane-host comparison (worker vs thread)")
    ap.add_argument("--hog-seconds", type=float, default=30.0, help="the session with 4 busy-loop hogs")
    ap.add_argument("--one-isolated", action="store_true", help=argparse.SUPPRESS)  # one quiet worker session: JSON out
    args = ap.parse_args()
    seconds, pairs = (6.0, 1) if args.quick else (args.seconds, args.pairs)
    if args.one_isolated:
        with tempfile.TemporaryDirectory() as d:
            print(json.dumps(_isolated_session("worker", seconds, 0, Path(d), 10)))
        return
    if args.isolation and args.base != BASE_DEFAULT:  # this tree against a given commit, quiet worker sessions
        rows = isolation_ab(worktree(args.base), seconds, pairs)
        print()
        print_isolation_ab(rows)
        _save({"base": args.base, "seconds": seconds, "pairs": pairs, "isolation_ab": rows}, "bench_session_isolation_ab.json")
        return
    if args.isolation:
        with tempfile.TemporaryDirectory() as d:
            rows = isolation(seconds, 8.0 if args.quick else args.hog_seconds, Path(d))
        print()
        print_isolation(rows)
        _save({"isolation": rows}, "bench_session_isolation.json")
        return
    base_tree = worktree(args.base)
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        print("lanes in a worker vs in the recorder (issue 30 item 1), device served by its own process", flush=True)
        iso_rows = isolation(seconds, 8.0 if args.quick else args.hog_seconds, tmp)
        print(f"Recorder vs the recorder of {args.base}: {pairs} alternating pairs of {seconds:g} s sessions", flush=True)
        rows = compare(base_tree, seconds, pairs, tmp)
        print("analysis lane: block by block vs frames", flush=True)
        lanes = frames(seconds, tmp)
    print()
    print(f"{'session':44s} {'base CPU/s':>10s} {'new CPU/s':>10s} {'new/base':>9s} {'range':>13s}")
    for r in rows:
        base, new = statistics.median(r["base_cpu_per_s"]), statistics.median(r["new_cpu_per_s"])
        spread = f"{r['ratio_min']:6.3f}-{r['ratio_max']:.3f}"
        print(f"{r['session']:44s} {base:10.4f} {new:10.4f} {r['ratio_median']:9.3f} {spread}")
    print("target: new/base <= 1.05 (analysis off: the recording path)")
    print()
    heads = " ".join(f"{h:>7s}" for h in ("p50 ms", "p99 ms", "max ms"))
    print(f"{'analysis lane':18s} {'CPU/data-s':>10s} {'windows':>8s} {heads} {'events':>6s}")
    for r in lanes:
        lat = f"{r['latency_ms_p50']:7.1f} {r['latency_ms_p99']:7.1f} {r['latency_ms_max']:7.1f}"
        print(f"{r['lane']:18s} {r['cpu_per_data_s']:10.4f} {r['windows']:8d} {lat} {r['events']:6d}")
    print("target: per-window latency p99 <= 50 ms")
    print()
    print_isolation(iso_rows)
    _save({"base": args.base, "seconds": seconds, "pairs": pairs, "recorder": rows, "analysis_lane": lanes,
           "isolation": iso_rows}, "bench_session.json")  # fmt: skip


def _save(obj: dict, name: str) -> None:
    res_dir = ROOT / "bench" / "results"
    res_dir.mkdir(parents=True, exist_ok=True)
    (res_dir / name).write_text(json.dumps(obj, indent=2))
    print(f"wrote {res_dir / name}")


if __name__ == "__main__":
    main()
