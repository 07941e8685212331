"""A campaign (issue 31, item 4): 20 logs through ``gvt analyze`` / ``gvt modal`` on 2 Dask workers vs one after another.

Logs: ``--distinct`` simulated ``beam_ch4_exp`` sessions (``--hits`` hits each at the rig's record length, rising to
the nominal force, each its own seed), copied round-robin up to ``--logs`` files: with the default 30 hits a log is
60 s of 15 channels at 16384 Hz, a run of a roving-hammer test (10 points x 3 averages).
Rows, all measured in this run on the same logs (the machine is shared: compare ratios of one run, bench/README):

* ``serial``: every log one after another in this process (``runner.run_here``: the same task function, imports and
  numba kernels already loaded by an untimed first log), the least a loop over the logs can cost;
* ``cli loop`` (``--cli-loop``): ``gvt VERB LOG --json`` as a process per log, what a user's shell loop costs today;
* ``campaign``: ``run_campaign(tasks, workers=2)``, what ``gvt VERB DIR --workers 2`` does: a local cluster started,
  its workers importing the studies, the logs, the cluster closed — everything included;
* ``running cluster``: the same on a cluster already up and warm (``--scheduler ADDRESS``).

Every campaign row's results are checked equal to the serial row's, log by log (the wall-clock fields aside).
Goal (issue 31): the campaign >= 1.6x faster than serial. Prints a table, writes bench/results/bench_campaign.json.

    .venv/bin/python bench/bench_campaign.py [--logs 20] [--workers 2] [--verbs analyze modal] [--cli-loop]
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import shutil
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from daq.studies.campaign.plan import find_logs, plan
from daq.studies.campaign.runner import run_campaign, run_here, worker_env
from daq.studies.campaign.tasks import run_task

RESULTS = Path(__file__).resolve().parent / "results"
CLOCK = ("wall_seconds", "speed_x_real_time")
GOAL = 1.6


def make_logs(d: Path, n: int, distinct: int, hits: int) -> list[Path]:
    from analysis.model.rigs import open_rig
    from daq.studies.simulate.session import SessionPlan, default_forces, simulate_session

    rig = open_rig("beam_ch4_exp")
    rec = rig.config.daq.record_length
    made = []
    for k in range(distinct):
        p = d / f"src{k}.mcap"
        peaks = tuple(f * (0.8 + 0.1 * k) for f in default_forces(rig, hits))
        simulate_session(rig, p, SessionPlan(forces=peaks, pre_trigger=0.1, spacing=rec, tail=rec, block_size=1024),
                         seed=100 + k)  # fmt: skip
        made.append(p)
    logs = d / "logs"
    logs.mkdir()
    for i in range(n):
        shutil.copy(made[i % distinct], logs / f"run{i:02d}.mcap")
    return find_logs([logs])


def results(rows: list[dict]) -> list:
    return [None if r["result"] is None else {k: v for k, v in r["result"].items() if k not in CLOCK} for r in rows]


def cli_loop(verb: str, logs: list[Path]) -> float:
    t0 = time.perf_counter()
    for p in logs:
        subprocess.run([sys.executable, "-m", "daq.cli", verb, str(p), "--json"], check=False, capture_output=True)
    return time.perf_counter() - t0


def bench_verb(verb: str, logs: list[Path], workers: int, address: str, with_cli: bool) -> dict:
    tasks = plan(verb, logs, {}, {})
    run_task(tasks[0])  # imports and numba kernels in this process, as a warm worker has them
    t0 = time.perf_counter()
    serial = run_here(tasks)
    t_serial = time.perf_counter() - t0
    t0 = time.perf_counter()
    fresh = run_campaign(tasks, workers=workers)
    t_fresh = time.perf_counter() - t0
    t0 = time.perf_counter()
    warm = run_campaign(tasks, scheduler=address)
    t_warm = time.perf_counter() - t0
    want = results(serial)
    equal = results(fresh) == want and results(warm) == want
    ok = sum(r["exit_code"] == 0 for r in serial)
    # cores this run was given: the logs' CPU seconds over the wall (on a shared machine the kernel's autogroup
    # scheduling gives a session one share, however many processes it runs: then no campaign can be faster)
    cores = {k: sum(r["cpu_s"] for r in rows) / t for k, rows, t in
             (("serial", serial, t_serial), ("campaign", fresh, t_fresh), ("running", warm, t_warm))}  # fmt: skip
    # what the campaign would take with a core per worker: the busiest worker's CPU seconds (its imports included:
    # they run inside its first task), against the serial run's CPU seconds — the speed-up the cores allow
    per_worker: dict[str, float] = {}
    for r in fresh:
        per_worker[r["worker"]] = per_worker.get(r["worker"], 0.0) + r["cpu_s"]
    serial_cpu = sum(r["cpu_s"] for r in serial)
    row = {"verb": verb, "logs": len(logs), "ok": ok, "workers": workers, "serial_s": t_serial, "campaign_s": t_fresh,
           "running_cluster_s": t_warm, "speedup": t_serial / t_fresh, "speedup_running": t_serial / t_warm,
           "per_log_s": [r["seconds"] for r in serial], "serial_cpu_s": serial_cpu, "cores_used": cores,
           "campaign_cpu_s_per_worker": per_worker, "speedup_a_core_each": serial_cpu / max(per_worker.values()),
           "equal_results": equal, "load": os.getloadavg()[0]}  # fmt: skip
    if with_cli:
        row["cli_loop_s"] = cli_loop(verb, logs)
        row["speedup_vs_cli_loop"] = row["cli_loop_s"] / t_fresh
    return row


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--logs", type=int, default=20)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--distinct", type=int, default=4)
    ap.add_argument("--hits", type=int, default=30)
    ap.add_argument("--verbs", nargs="+", default=["analyze", "modal"])
    ap.add_argument("--cli-loop", action="store_true", help="also time a `gvt VERB LOG` process per log")
    a = ap.parse_args()
    from distributed import Client, LocalCluster

    rows = []
    with tempfile.TemporaryDirectory() as d:
        logs = make_logs(Path(d), a.logs, a.distinct, a.hits)
        warnings.filterwarnings("ignore", message="Port .* is already in use")  # a dashboard nobody opens
        cluster = LocalCluster(n_workers=a.workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                               dashboard_address=None, silence_logs=logging.ERROR, env=worker_env())  # fmt: skip
        with cluster as lc, Client(lc) as c:
            for verb in a.verbs:
                c.run(run_task, plan(verb, logs[:1], {}, {})[0])  # the running cluster is warm: imports, kernels
                rows.append(bench_verb(verb, logs, a.workers, lc.scheduler_address, a.cli_loop))
    print(f"{a.logs} logs ({a.distinct} distinct beam_ch4_exp sessions, {a.hits} hits each), {a.workers} workers")
    print(f"{'verb':>8} {'ok':>3} {'serial [s]':>11} {'campaign [s]':>13} {'speed-up':>9} {'running cl. [s]':>16} "
          f"{'speed-up':>9} {'cli loop [s]':>13} {'equal':>6} {'cores s/c/r':>12} {'load':>5}")  # fmt: skip
    for r in rows:
        cli = f"{r['cli_loop_s']:13.1f}" if "cli_loop_s" in r else f"{'-':>13}"
        print(f"{r['verb']:>8} {r['ok']:>3} {r['serial_s']:11.1f} {r['campaign_s']:13.1f} {r['speedup']:8.2f}x "
              f"{r['running_cluster_s']:16.1f} {r['speedup_running']:8.2f}x {cli} {r['equal_results']!s:>6} "
              f"{'/'.join(f'{v:.1f}' for v in r['cores_used'].values()):>12} {r['load']:5.1f}")  # fmt: skip
    for r in rows:
        print(f"{r['verb']}: campaign {r['speedup']:.2f}x serial ({'meets' if r['speedup'] >= GOAL else 'MISSES'} the "
              f"{GOAL}x goal); on a running cluster {r['speedup_running']:.2f}x; the cores this run was given (CPU s "
              f"per wall s): serial {r['cores_used']['serial']:.1f}, campaign {r['cores_used']['campaign']:.1f}; with a "
              f"core per worker the busiest worker's CPU time bounds it at {r['speedup_a_core_each']:.2f}x")  # fmt: skip
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "bench_campaign.json").write_text(json.dumps({"goal_speedup": GOAL, "rows": rows}, indent=2))


if __name__ == "__main__":
    main()
