"""Near-live analysis benchmark (issue 6). Prints a table, writes bench/results/bench_analysis.json.

1. Per-window latency — from the arrival of the block holding a window's last sample to that window's
   result (all detectors on: seed lane with 8 window grids, modal lane, exchange events) — p50 / p99,
   at 14 ch x 16384 Hz (beam_ch4_exp; target p99 <= 50 ms) and 64 ch x 51.2 kHz (bench_64ch), device
   blocks of 256 / 1024 samples fed at full speed (compute latency; a paced run adds only queueing).
   A paced run (real time) at 14 ch reports the same percentiles with the blocks arriving as from a DAQ.
2. Replay analysis as a multiple of real time at 14 ch x 16384 Hz (target >= 100x): ``gvt analyze``'s
   path (blocks coalesced into its chunks: 1 s here, daq/studies/analyze/batch.py ``replay_chunk``; 0.5 s before)
   and the live block size, on the same data in the same run.
   Baseline in the same run: the literal batch seed method (zero-phase preprocessing + SVD POD per
   window, analysis/pod.py) over the same data.
3. The compiled kernels beside the library calls they replace (same data, same run): the causal §4.3
   chain (analysis/preprocess.py) against ``lfilter`` + ``sosfilt`` stage by stage, the lattice window
   covariances (analysis/operator.py) against the ``np.add.reduceat`` form, the causal spike rule
   (analysis/rq_spikes.py) against its per-window numpy form — ms per second of 14-channel data, and
   whether the outputs are identical bit for bit.

4. ``--base REV`` (default: main before issue 30's replay-speed work, a37a3f0): the replay rows of 2. (gvt analyze's
   path, health on, and the same with health off) and the literal batch, measured for that commit in the same run — a
   subprocess importing a ``git archive`` of it — beside this tree's (``--base none``: skipped).
5. ``gvt analyze LOG`` first output (issue 30: < 1 s): seconds from process start to the first byte on stdout, median
   of 5 warm runs on replay_logs/beam_ch4_exp_weak.mcap, for this tree and the base in the same run.

The summary line gives, per tree: replay x real time, its ratio to the seed's literal batch in the same run, and the
first output (issue 30's targets: >= 100x, >= 2x, < 1 s).

    python bench/bench_analysis.py [--seconds 20] [--quick] [--base a37a3f0 | --base none]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the gvt CLI does (D19); before numpy is imported
import argparse
import json
import platform
import resource
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import numpy as np

from analysis.forked_worker import reap
from analysis.model.rigs import open_rig
from analysis.operator import AnalysisOperator, AnalysisSettings, RigModel
from analysis.rq_spikes import RobustSpikeSettings
from analysis.symeig import sym_eig
from drivers.blocks import SampleBlock

ROOT = Path(__file__).resolve().parents[1]
BASE_DEFAULT = "a37a3f0"  # main before issue 30's replay-speed work (lock fit, pipeline, first output, one numba cache)
FIRST_OUTPUT_LOG = ROOT / "replay_logs" / "beam_ch4_exp_weak.mcap"


def base_tree(rev: str) -> Path:
    """A ``git archive`` of ``rev`` in the temporary directory (kept: the next run reuses it and its numba cache)."""
    sha = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short=12", rev], check=True, capture_output=True,
                         text=True).stdout.strip()  # fmt: skip
    path = Path(tempfile.gettempdir()) / f"gvt-bench-archive-{sha}"
    if not (path / "daq").exists():
        path.mkdir(parents=True, exist_ok=True)
        arc = subprocess.run(["git", "-C", str(ROOT), "archive", "--format=tar", sha], check=True, capture_output=True).stdout
        tar = path / "tree.tar"
        tar.write_bytes(arc)
        with tarfile.open(tar) as t:
            t.extractall(path, filter="data")
        tar.unlink()
    return path


def at_base(rev: str, argv: list[str]) -> dict | None:
    """This script's ``--measure-replay`` run with the packages of ``rev`` first on the path; None (and a line) when
    that commit cannot run it."""
    env = {**os.environ, "PYTHONPATH": str(base_tree(rev))}
    p = subprocess.run([sys.executable, __file__, "--measure-replay", *argv], env=env, capture_output=True, text=True)
    if p.returncode:
        print(f"base {rev}: not measured ({p.stderr.strip().splitlines()[-1] if p.stderr.strip() else p.returncode})")
        return None
    return json.loads(p.stdout.strip().splitlines()[-1])


def first_output_s(tree: Path, repeats: int = 5) -> dict:
    """``gvt analyze`` of a small log with the packages of ``tree`` (``PYTHONPATH``): seconds from the process's start
    to the first byte on stdout, median and all of ``repeats`` runs after one warm-up (bytecode, numba cache), and the
    whole run's seconds. A run that fails gives its exit code."""
    import selectors

    cmd = [sys.executable, "-m", "daq.cli", "analyze", str(FIRST_OUTPUT_LOG)]
    env = {**os.environ, "PYTHONPATH": str(tree)}
    # the warm-up writes the bytecode an installed gvt has; a shell with PYTHONDONTWRITEBYTECODE set (this machine's
    # agent shell has it) made every run compile its imports from source: 0.8 against 0.3 s to the first output, 4.5
    # against 2.0 s for the whole run, measured here
    env.pop("PYTHONDONTWRITEBYTECODE", None)

    def once() -> tuple[float, float, int]:
        t0 = time.perf_counter()
        p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, cwd=tree, env=env)
        sel = selectors.DefaultSelector()
        sel.register(p.stdout, selectors.EVENT_READ)
        first = None
        while True:
            sel.select(timeout=600)
            chunk = os.read(p.stdout.fileno(), 65536)
            if first is None and chunk:
                first = time.perf_counter() - t0
            if not chunk:
                break
        rc = p.wait()
        total = time.perf_counter() - t0
        return (first if first is not None else total), total, rc

    once()
    runs = [once() for _ in range(repeats)]
    if any(rc for _, _, rc in runs):
        return {"error": f"exit {max(rc for _, _, rc in runs)}"}
    firsts = sorted(f for f, _, _ in runs)
    return {"first_output_s": firsts[len(firsts) // 2], "runs_s": [f for f, _, _ in runs],
            "total_s": sorted(t for _, t, _ in runs)[len(runs) // 2]}  # fmt: skip


def replay_block(fs: float, n_channels: int) -> int:
    """The chunk ``gvt analyze`` feeds the operator, in the tree on the path: its ``replay_chunk`` (1 s at 14 channels x
    16384 Hz), or half a second in a tree from before it (every commit's replay row measures what its own product ran)."""
    try:
        from daq.studies.analyze.batch import replay_chunk
    except ImportError:
        return max(1, round(0.5 * fs))
    return replay_chunk(fs, n_channels)


def replay_rows(secs: float) -> dict:
    """The replay rows compared across commits: gvt analyze's path (its chunks, :func:`replay_block`, pipelined) with
    sensor health on (the default) and off, and the literal batch seed method, on the same data."""
    d14, ch14, fs14 = _data("beam_ch4_exp", secs)
    m14 = RigModel.from_rig(open_rig("beam_ch4_exp"))
    rb = replay_block(fs14, len(ch14))
    _run(m14, d14[: int(fs14)], ch14, fs14, rb)  # warm-up
    on = _median_run(m14, d14, ch14, fs14, rb)
    off = _median_run(m14, d14, ch14, fs14, rb, settings=AnalysisSettings(health=None))
    seeds = sorted((_seed_batch(m14, d14, fs14) for _ in range(3)), key=lambda r: r["wall_s"])
    return {"health_on": on, "health_off": off, "seed_batch": seeds[1], "guard": _guard_cpu(m14, d14, ch14, fs14)}


def _guard_cpu(model: RigModel, data: np.ndarray, chans, fs: float) -> dict:
    """Sensor health alone, as the operator runs it (``HealthGuard.feed_clean``: the line canceller, then the checks)
    on the replay's 8192-sample blocks with the hammer's input mask: ms CPU per data-s, median of 5; with the line
    canceller off beside it. The difference of two whole-operator rows is too noisy on a shared machine for this."""
    from analysis.sensor_health import HealthGuard

    acc, inp = data[:, 1:].astype(np.float64), data[:, 0] > 20.0
    secs = data.shape[0] / fs
    out = {}
    for name, kw in (("ms_per_data_s", {}), ("no_lines_ms_per_data_s", {"lines": None})):
        def run(kw=kw):
            g = HealthGuard(model.M, model.K, chans[1:], fs, 4, **kw)
            for s in range(0, acc.shape[0], 8192):
                g.feed_clean(acc[s : s + 8192], inp[s : s + 8192])

        run()
        times = []
        for _ in range(5):
            c0 = time.process_time()
            run()
            times.append(time.process_time() - c0)
        out[name] = 1e3 * sorted(times)[2] / secs
    return out


def _data(rig_name: str, seconds: float, period: float = 2.0, seed: int = 0) -> tuple[np.ndarray, tuple[str, ...], float]:
    """Hits every ``period`` s at rising force, 1 % noise: (n, 1 + n_sensors) float32 with the hammer first."""
    rig = open_rig(rig_name)
    fs = rig.sample_rate
    res = rig.simulator.run(rig.hammer_force(), period, fs)
    one = np.column_stack([res.force[0], res.acceleration[0]])
    n_rep = int(np.ceil(seconds / period))
    rng = np.random.default_rng(seed)
    scale = np.linspace(0.3, 1.0, n_rep)
    data = np.concatenate([one * s for s in scale])[: int(seconds * fs)]
    data[:, 1:] += rng.standard_normal(data[:, 1:].shape) * 0.01 * one[:, 1:].std(axis=0)
    chans = (rig.hammer.name, *(s.name for s in rig.sensors))
    return data.astype(np.float32), chans, fs


def _run(
    model: RigModel, data: np.ndarray, chans, fs: float, block: int, paced: bool = False,
    settings: AnalysisSettings | None = None, pipelined: bool | None = None,
) -> dict:
    """One run; ``pipelined`` None: as the product runs it — pipelined for replay-sized blocks (``gvt analyze``
    feeds 0.5 s chunks), serial for device-sized ones (a live session)."""
    pipelined = block / fs >= 0.25 if pipelined is None else pipelined
    op = AnalysisOperator(model, chans, fs, settings, pipelined=pipelined)
    t0 = time.perf_counter()
    c0 = time.process_time() + _children_cpu()
    for s in range(0, data.shape[0], block):
        if paced:
            due = t0 + (s + block) / fs
            delay = due - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
        op.feed(SampleBlock("dev0", s, fs, chans, data[s : s + block]))
    op.finish()
    wall = time.perf_counter() - t0
    reap()  # the seed lane's worker process (D130) has been told to stop: its CPU counts once it is collected
    cpu = time.process_time() + _children_cpu() - c0
    lat = np.array(op.stats.latencies_s) * 1e3
    secs = data.shape[0] / fs
    return {
        "block": block, "paced": paced, "pipelined": pipelined,
        "data_s": secs, "wall_s": wall, "cpu_s": cpu, "x_real_time": secs / wall,
        "cpu_per_data_s": cpu / secs, "windows": op.stats.rq_windows, "events": op.stats.events,
        "latency_ms_p50": float(np.percentile(lat, 50)) if lat.size else float("nan"),
        "latency_ms_p99": float(np.percentile(lat, 99)) if lat.size else float("nan"),
        "latency_ms_max": float(lat.max()) if lat.size else float("nan"),
    }  # fmt: skip


def _children_cpu() -> float:
    """CPU seconds of this process's ended, waited-for children (the pipelined operator's seed worker, D130)."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _median_run(*args, repeat: int = 3, **kw) -> dict:
    """``repeat`` unpaced runs; the one with the median wall time, with every run's x real time beside it
    (one 20 s row is ~0.2 s of wall time: a single run moves ±10 % with the machine's load)."""
    runs = sorted((_run(*args, **kw) for _ in range(repeat)), key=lambda r: r["wall_s"])
    mid = dict(runs[len(runs) // 2])
    mid["runs_x_real_time"] = [r["x_real_time"] for r in runs]
    return mid


def _seed_batch(model: RigModel, data: np.ndarray, fs: float) -> dict:
    from analysis.pod import PodRqSettings, windowed_pod_rq
    from analysis.preprocess import PreprocessSettings, acc_to_disp

    t0 = time.perf_counter()
    _, disp = acc_to_disp(data[:, 1:].astype(np.float64), fs, PreprocessSettings())
    r = windowed_pod_rq(disp, fs, model.M, model.K, PodRqSettings(window_s=0.0216, pod_method="svd"))
    wall = time.perf_counter() - t0
    return {"data_s": data.shape[0] / fs, "wall_s": wall, "x_real_time": data.shape[0] / fs / wall, "windows": r.n_windows}


def _per_data_s(fn, data_s: float, repeat: int = 3) -> float:
    fn()
    t0 = time.process_time()
    for _ in range(repeat):
        fn()
    return (time.process_time() - t0) / repeat / data_s * 1e3


def _kernels(data: np.ndarray, fs: float, model: RigModel) -> dict:
    """Each compiled kernel against the library form it replaced, on the bench data (8192-sample blocks)."""
    import itertools

    import scipy.signal

    from analysis.operator import rq_from_covariance, window_covariances
    from analysis.preprocess import CausalPreprocessor, PreprocessSettings, highpass_sos
    from analysis.rq_spikes import CausalSpikeRule

    acc = data[:, 1:].astype(np.float64)
    secs = acc.shape[0] / fs
    blocks = [acc[s : s + 8192] for s in range(0, acc.shape[0], 8192)]
    out: dict = {}

    def compiled_chain():
        pre = CausalPreprocessor(fs, acc.shape[1], PreprocessSettings(mode="causal"))
        return [pre.feed(b) for b in blocks]

    def library_chain():
        b_int, a_int = np.array([0.5 / fs, 0.5 / fs]), np.array([1.0, -1.0])
        sv, sd = highpass_sos(18.0, fs, 3), highpass_sos(10.0, fs, 3)
        st = [(-b_int[0] * blocks[0][0])[None, :], np.zeros((2, 2, acc.shape[1])), np.zeros((1, acc.shape[1])),
              np.zeros((2, 2, acc.shape[1]))]  # fmt: skip
        res = []
        for b in blocks:
            v, st[0] = scipy.signal.lfilter(b_int, a_int, b, axis=0, zi=st[0])
            v, st[1] = scipy.signal.sosfilt(sv, v, axis=0, zi=st[1])
            d, st[2] = scipy.signal.lfilter(b_int, a_int, v, axis=0, zi=st[2])
            d, st[3] = scipy.signal.sosfilt(sd, d, axis=0, zi=st[3])
            res.append((v, d))
        return res

    same = all(np.array_equal(x[0], y[0]) and np.array_equal(x[1], y[1])
               for x, y in zip(compiled_chain(), library_chain(), strict=True))  # fmt: skip
    out["preprocess_14ch"] = {"library_ms": _per_data_s(library_chain, secs), "compiled_ms": _per_data_s(compiled_chain, secs),
                              "identical": bool(same)}  # fmt: skip

    disp = np.concatenate([d for _, d in compiled_chain()])
    base = round(0.0216 * fs)
    grids = [(round(o * base), round(L * base)) for L in (1.0, 1.5) for o in (0.0, 0.25, 0.5, 0.75)]
    edges = np.unique(np.concatenate([np.arange(o, disp.shape[0] + 1, L) for o, L in grids]))
    wins = [(a, a + L) for o, L in grids for a in range(o, disp.shape[0] - L + 1, L)]

    def reduceat_form():
        seg_s1 = np.add.reduceat(disp[edges[0] : edges[-1]], edges[:-1] - edges[0], axis=0)
        seg_s2 = np.stack([disp[a:b].T @ disp[a:b] for a, b in itertools.pairwise(edges)])
        idx = np.searchsorted(edges, np.asarray(wins)).ravel()
        s1 = np.add.reduceat(np.concatenate([seg_s1, np.zeros((1, seg_s1.shape[1]))]), idx, axis=0)[::2]
        s2 = np.add.reduceat(np.concatenate([seg_s2, np.zeros((1, *seg_s2.shape[1:]))]), idx, axis=0)[::2]
        n = np.array([b - a for a, b in wins], float)[:, None, None]
        return (s2 - s1[:, :, None] * s1[:, None, :] / n) / n

    C = window_covariances(disp, wins, edges)
    out["window_covariances_8_grids"] = {
        "library_ms": _per_data_s(reduceat_form, secs),
        "compiled_ms": _per_data_s(lambda: window_covariances(disp, wins, edges), secs),
        "identical": bool(np.array_equal(C, reduceat_form())), "windows": len(wins),
        "eigh_ms": _per_data_s(lambda: rq_from_covariance(C, model.M, model.K, 4), secs),
    }  # fmt: skip
    lam_lib, lam_own = np.linalg.eigh(C)[0], sym_eig(C)[0]
    out["pod_eigenproblems_8_grids"] = {  # analysis/symeig.py beside LAPACK's eigh (D131): equal up to rounding only
        "library_ms": _per_data_s(lambda: np.linalg.eigh(C), secs),
        "compiled_ms": _per_data_s(lambda: sym_eig(C), secs),
        "identical": bool(np.array_equal(lam_lib, lam_own)),
        "max_rel_eigenvalue_diff": float(np.max(np.abs(lam_lib - lam_own) / np.abs(lam_lib).max(axis=1, keepdims=True))),
    }  # fmt: skip
    f, _ = rq_from_covariance(C[: len(wins) // 8], model.M, model.K, 4)
    rule = RobustSpikeSettings()

    def per_window():
        r = CausalSpikeRule(rule)
        return np.array([r.feed(x) for x in f])

    out["spike_rule_8_grids"] = {  # one grid's windows timed, x 8
        "library_ms": _per_data_s(per_window, secs) * 8,
        "compiled_ms": _per_data_s(lambda: CausalSpikeRule(rule).feed_many(f), secs) * 8,
        "identical": bool(np.array_equal(per_window(), CausalSpikeRule(rule).feed_many(f))),
    }  # fmt: skip
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--quick", action="store_true", help="6 s of data")
    ap.add_argument("--base", default=BASE_DEFAULT, help="git revision to compare the replay with ('none': skip)")
    ap.add_argument("--measure-replay", action="store_true", help=argparse.SUPPRESS)  # the base tree's subprocess
    args = ap.parse_args()
    secs = 6.0 if args.quick else args.seconds
    if args.measure_replay:
        print(json.dumps(replay_rows(secs)))
        return
    rows = []
    out: dict = {"benchmark": "bench_analysis", "python": platform.python_version(), "machine": platform.machine()}
    d14, ch14, fs14 = _data("beam_ch4_exp", secs)
    m14 = RigModel.from_rig(open_rig("beam_ch4_exp"))
    _run(m14, d14[: int(fs14)], ch14, fs14, 256)  # warm-up (imports, caches)
    rb = replay_block(fs14, len(ch14))
    for block in sorted({256, 8192, rb}):
        r = _median_run(m14, d14, ch14, fs14, block)
        rows.append({"case": "14 ch x 16384 Hz", **r})
    rows.append({"case": "14 ch, one thread", **_median_run(m14, d14, ch14, fs14, rb, pipelined=False)})
    one_grid = AnalysisSettings(spikes=RobustSpikeSettings(offsets=(0.0,), lengths=(1.0,), min_fraction=1.0))
    rows.append({"case": "14 ch, 1 RQ grid", **_median_run(m14, d14, ch14, fs14, rb, settings=one_grid)})
    modal_only = AnalysisSettings(seed_lane=False)
    rows.append({"case": "14 ch, modal only", **_median_run(m14, d14, ch14, fs14, rb, settings=modal_only)})
    rows.append({"case": "14 ch x 16384 Hz", **_run(m14, d14[: int(min(secs, 10.0) * fs14)], ch14, fs14, 256, paced=True)})
    d64, ch64, fs64 = _data("bench_64ch", min(secs, 6.0))
    m64 = RigModel.from_rig(open_rig("bench_64ch"))
    rows.append({"case": "64 ch x 51.2 kHz", **_median_run(m64, d64, ch64, fs64, 1024)})
    seeds = sorted((_seed_batch(m14, d14, fs14) for _ in range(3)), key=lambda r: r["wall_s"])
    seed = {**seeds[1], "runs_x_real_time": [r["x_real_time"] for r in seeds]}
    kernels = _kernels(d14, fs14, m14)
    out["rows"] = rows
    out["seed_batch_baseline_14ch"] = seed
    out["kernels_ms_per_data_s"] = kernels
    out["load_avg_1_5_15"] = list(os.getloadavg())
    hdr = f"{'case':18s} {'block':>6s} {'paced':>5s} {'pipe':>5s} {'data s':>7s} {'wall s':>7s} {'x RT':>7s} {'cpu/s':>6s} " \
          f"{'win':>5s} {'p50 ms':>7s} {'p99 ms':>7s} {'max ms':>7s}"  # fmt: skip
    print(hdr)
    for r in rows:
        print(f"{r['case']:18s} {r['block']:6d} {r['paced']!s:>5s} "
              f"{r['pipelined']!s:>5s} {r['data_s']:7.1f} {r['wall_s']:7.2f} {r['x_real_time']:7.1f} "
              f"{r['cpu_per_data_s']:6.3f} {r['windows']:5d} {r['latency_ms_p50']:7.2f} {r['latency_ms_p99']:7.2f} "
              f"{r['latency_ms_max']:7.2f}")  # fmt: skip
    replay = next(r for r in rows if r["block"] == rb and r["case"] == "14 ch x 16384 Hz")
    runs = ", ".join(f"{x:.1f}" for x in replay["runs_x_real_time"])
    print(f"replay ({rb}-sample chunks, gvt analyze's) runs: {runs}x real time (median of 3 shown)")
    serial = next(r for r in rows if r["case"] == "14 ch, one thread")
    print(f"pipelined (the seed lane in a worker process where it can fork, D130) against one thread: "
          f"{replay['x_real_time'] / serial['x_real_time']:.2f}x wall, "
          f"{replay['cpu_per_data_s'] / serial['cpu_per_data_s']:.2f}x CPU")  # fmt: skip
    print(f"seed method, literal batch (zero-phase + SVD POD, one grid): {seed['x_real_time']:.1f}x real time; "
          f"gvtlink replay (8 grids + modal lane + events): {replay['x_real_time']:.1f}x "
          f"({replay['x_real_time'] / seed['x_real_time']:.2f}x the literal batch)")  # fmt: skip
    print(f"{'kernel (ms per data-s, 14 ch)':32s} {'library':>8s} {'compiled':>8s} identical")
    for name, k in kernels.items():
        print(f"{name:32s} {k['library_ms']:8.2f} {k['compiled_ms']:8.2f} {k['identical']}")
    print(f"(pod_eigenproblems: analysis/symeig.py against LAPACK's eigh, eigenvalues within "
          f"{kernels['pod_eigenproblems_8_grids']['max_rel_eigenvalue_diff']:.1e} of the largest; the eigenproblems + RQ "
          f"of the same windows: {kernels['window_covariances_8_grids']['eigh_ms']:.2f} ms per data-s; "
          f"load average {out['load_avg_1_5_15'][0]:.2f})")  # fmt: skip
    if args.base != "none":  # the same replay rows, this tree and the base commit, one after the other
        now = replay_rows(secs)
        base = at_base(args.base, ["--seconds", str(secs)])
        out["replay_vs_base"] = {"rev": args.base, "this_tree": now, "base": base}
        print(f"{'replay, 14 ch x 16384 Hz':32s} {'this tree':>18s} {'@' + args.base:>18s}   (x real time | CPU s/data s)")
        for key, name in (("health_on", "health on"), ("health_off", "health off"), ("seed_batch", "seed literal batch")):
            cols = []
            for r in (now, base):
                cpu = r[key].get("cpu_per_data_s") if r else None
                cols.append(f"{r[key]['x_real_time']:8.1f} | {cpu:6.4f}" if cpu else f"{r[key]['x_real_time']:8.1f} |      -"
                            if r else f"{'-':>18s}")  # fmt: skip
            print(f"{name:32s} {cols[0]:>18s} {cols[1]:>18s}")
        g = [f"{r['guard']['ms_per_data_s']:.2f} ({r['guard']['no_lines_ms_per_data_s']:.2f} without the line canceller)"
             if r and "guard" in r else "-" for r in (now, base)]  # fmt: skip
        print(f"sensor health alone (HealthGuard.feed_clean), ms CPU per data-s: this tree {g[0]}, @{args.base} {g[1]}")
        for who, r in (("this tree", now), (f"@{args.base}", base)):
            if r:
                print(f"{who}: health on is {r['health_on']['x_real_time'] / r['seed_batch']['x_real_time']:.2f}x the seed's "
                      f"literal batch; health costs {r['health_on']['cpu_per_data_s'] - r['health_off']['cpu_per_data_s']:.4f} "
                      f"CPU-s per data-s")  # fmt: skip
    trees = [("this tree", ROOT)] + ([(f"@{args.base}", base_tree(args.base))] if args.base != "none" else [])
    out["first_output"] = {who: first_output_s(tree) for who, tree in trees}
    for who, fo in out["first_output"].items():
        runs = ", ".join(f"{x:.2f}" for x in fo.get("runs_s", []))
        print(f"gvt analyze {FIRST_OUTPUT_LOG.name}, first output ({who}): "
              f"{fo['first_output_s']:.2f} s (runs {runs}; whole run {fo['total_s']:.2f} s)" if "error" not in fo
              else f"gvt analyze first output ({who}): {fo['error']}")  # fmt: skip
    if args.base != "none":
        for who, r in (("this tree", now), (f"@{args.base}", base)):
            fo = out["first_output"].get(who, {})
            if r:
                on = r["health_on"]["x_real_time"]
                print(f"summary {who}: replay {on:.1f}x real time (target >= 100x), {on / r['seed_batch']['x_real_time']:.2f}x "
                      f"the seed's literal batch (target >= 2x), gvt analyze first output "
                      f"{fo.get('first_output_s', float('nan')):.2f} s (target < 1 s)")  # fmt: skip
    dest = ROOT / "bench" / "results" / "bench_analysis.json"
    dest.parent.mkdir(parents=True, exist_ok=True)
    dest.write_text(json.dumps(out, indent=2))
    print(f"wrote {dest}")


if __name__ == "__main__":
    main()
