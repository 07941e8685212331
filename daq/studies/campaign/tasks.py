"""What a Dask worker runs for one log of a campaign: the single-log verb's study, and a small row about it.

Each verb here calls the study functions its ``gvt`` verb calls, with the same defaults, and returns the same
``--json`` document the verb prints (``row["result"]``), so a campaign gives each log what ``gvt VERB LOG --json``
gives it (tests/test_campaign.py checks it log by log). What the verb would say on failure is kept as the row's one
line and exit code (architecture.md: 2 bad input, 1 runtime failure, 3 data lost), and the campaign goes on.

Threads: one BLAS/OpenMP thread per task (``threadpoolctl``), whatever the worker was started with: a worker per
core is the parallelism, and a second layer of threads only makes the cores wait for each other (the local cluster
also starts its workers with the variables set: runner.py).
"""

from __future__ import annotations

import os
import socket
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

from analysis.errors import BadInput, DataLost, GvtError
from daq.studies.campaign.plan import Task


def empty_row(task: Task) -> dict[str, Any]:
    """A row before its log is run: what the table and ``--json`` show per log."""
    return {"index": task.index, "log": task.log, "verb": task.verb, "exit_code": 0, "error": None, "hits": None,
            "accepted": None, "events": None, "modes": None, "damage": None, "data_lost": False, "warnings": [],
            "outputs": [], "seconds": 0.0, "cpu_s": 0.0, "worker": None, "result": None}  # fmt: skip


def run_task(task: Task) -> dict[str, Any]:
    """Run ``task`` and return its row; never raises for a log's own trouble (a damaged log, bad input, a failed
    write): that is the row's ``exit_code`` and ``error``, as ``gvt VERB LOG`` would have said it."""
    from threadpoolctl import threadpool_limits

    row, t0, c0 = empty_row(task), time.perf_counter(), time.process_time()
    try:
        with threadpool_limits(1), warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            VERBS[task.verb](task, row)
    except GvtError as exc:
        row.update(exit_code=exc.exit_code, error=str(exc))
    except OSError as exc:  # as gvt's main() says it: which file and what
        where = f"{exc.filename}: " if exc.filename else ""
        row.update(exit_code=1, error=f"{where}{exc.strerror or exc}")
    except Exception as exc:  # never a traceback in the table
        row.update(exit_code=1, error=f"internal error: {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}")
    else:
        row["warnings"] += list(dict.fromkeys(f"{w.category.__name__}: {w.message}" for w in caught))
    row["damage"], row["data_lost"] = log_health(task.log)
    row["seconds"], row["cpu_s"] = time.perf_counter() - t0, time.process_time() - c0
    row["worker"] = f"{socket.gethostname()}:{os.getpid()}"
    return row


def log_health(path: str) -> tuple[str | None, bool]:
    """(None, False) for a log that is complete and whose every check passed; else ``gvt log info``'s health line
    and whether data was lost. Costs the summary read for a healthy log (no chunk is read)."""
    if not path.endswith(".mcap"):
        return None, False
    from daq.log.reader import LogReader, LogReadError

    try:
        r = LogReader(path)
    except LogReadError as exc:
        return str(exc), False
    except OSError:
        return None, False  # the row's error says it
    if r.report.complete and not r.damage and not r.problems:
        return None, False
    from daq.log.tools import log_info

    try:
        info = log_info(path)
    except GvtError as exc:
        return str(exc), bool(r.report.data_lost)
    return info["health"], bool(info["data_lost"])


def _rig(name: str | None):
    from analysis.model.rigs import open_rig

    return open_rig(name) if name else None


def _hits_of(path: str) -> int:
    from analysis.records import HITS_TOPIC
    from daq.log.reader import LogReader

    return LogReader(path).message_count(HITS_TOPIC)


def _write(target: str | None, what: str, write: Callable[[Path], Any], row: dict) -> Any:
    if target is None:
        return None
    from daq.outputs import atomic_output

    with atomic_output(target, what) as tmp:
        res = write(tmp)
    row["outputs"].append(target)
    return res


def analyze_task(task: Task, row: dict) -> None:
    """``gvt analyze LOG --json [--windows] [--rrd F]`` (daq/cli/analyze.py)."""
    from analysis.operator import AnalysisSettings
    from daq.studies.analyze.batch import analyze_log
    from daq.studies.analyze.tables import document

    o, r = task.options, _rig(task.options.get("rig"))
    # one thread: the campaign's parallelism is a log per worker process (the pipelined operator's three threads per
    # log made two workers on two cores 3x slower each; its emits are the serial operator's, D72)
    run = analyze_log(task.log, r, o.get("stream"), AnalysisSettings(window_s=o.get("window")), pipelined=False)

    def rrd(tmp: Path) -> None:
        from daq.studies.analyze.rrd import build_rrd

        build_rrd(task.log, tmp, rig=r, results=run.results)

    _write(task.outputs.get("--rrd"), "--rrd", rrd, row)
    row.update(result=document(run, bool(o.get("windows"))), events=len(run.events), hits=_hits_of(task.log))
    row["warnings"] += [str(w.get("message", w)) for w in row["result"]["warnings"]]
    if run.bad_blocks:  # the results are of what was readable: exit 3, as the single-log verb
        raise DataLost(f"skipped {len(run.bad_blocks)} undecodable sample block(s), analysed as gaps; "
                        f"first: {run.bad_blocks[0]}")  # fmt: skip


def frf_task(task: Task, row: dict) -> None:
    """``gvt frf LOG --json [--out F] [--plot F]`` (daq/cli/frf.py)."""
    from daq.log.reader import LogReader
    from daq.log.rig import rig_from_log
    from daq.studies.frf import frf_from_log, plot, summary

    o = task.options
    r = _rig(o.get("rig")) or rig_from_log(LogReader(task.log))
    peaks = o.get("peaks", 6)
    run = frf_from_log(task.log, r, reference=o.get("reference"), channels=o.get("channels"), band_hz=o.get("band"),
                       kind=o.get("kind", "H1"), quantity=o.get("quantity", "accelerance"), level=o.get("level"),
                       n_peaks=peaks)  # fmt: skip
    s = summary(run, peaks)
    row.update(result=s, hits=len(run.hits), accepted=sum(h["verdict"] == "accepted" for h in run.hits))
    row["warnings"] += list(s["warnings"])
    if run.frf is not None:
        _write(task.outputs.get("--out"), "--out", run.frf.to_npz, row)
    _write(task.outputs.get("--plot"), "--plot", lambda tmp: plot(run, tmp, o.get("show")), row)
    if run.frf is None:
        raise BadInput(f"{task.log}: no accepted hit, no FRF ({len(run.hits)} hit(s) refused: `gvt frf` says why)")


def _frfs_of_log(path: str, r, band_hi: float | None, row: dict) -> tuple:
    """(rig, FRFs, driving points, refused hits) as ``gvt modal LOG`` builds them (daq/cli/modal.py)."""
    from daq.log.reader import LogReader
    from daq.log.rig import rig_from_log
    from daq.studies.frf import frf_from_log

    r = r if r is not None else rig_from_log(LogReader(path))
    fr = frf_from_log(path, r, band_hz=band_hi)
    refused = [h for h in fr.hits if h["verdict"] != "accepted"]
    row.update(hits=len(fr.hits), accepted=len(fr.hits) - len(refused))
    if fr.frf is None:
        raise BadInput(f"{path}: no accepted hit to build FRFs from ({len(refused)} refused; `gvt frf {path}` says why)")
    return r, fr.frf, fr.driving, refused


def modal_task(task: Task, row: dict) -> None:
    """``gvt modal LOG --json [--modes-out F] [--png F] [--rrd F]`` (daq/cli/modal.py); LOG may be an FRF .npz."""
    from daq.studies.modal import load_frf_source, modal_from_frf, rows_summary, write_modes

    o, r, band = task.options, _rig(task.options.get("rig")), task.options.get("band")
    if task.log.endswith(".npz"):
        if "--rrd" in task.outputs and r is None:
            raise BadInput("--rrd draws the modes on the rig's test geometry: give --rig (an FRF file carries none)")
        frf, driving, refused = load_frf_source(Path(task.log)), None, []
    else:
        r, frf, driving, refused = _frfs_of_log(task.log, r, None if band is None else band[1], row)
    band = band or (2.0, min(1000.0, float(frf.freq[-1])))
    run = modal_from_frf(frf, r, band[0], band[1], o.get("targets"), o.get("max_order", 60), source=task.log,
                         driving=driving)  # fmt: skip
    run.refused_hits = refused
    _write(task.outputs.get("--modes-out"), "--modes-out", lambda tmp: write_modes(run, tmp), row)

    def png(tmp: Path) -> None:
        from analysis.modal_plot import stabilisation_png

        stabilisation_png(run.result.table, tmp, frf.freq, frf.H, run.result.selected)

    def rrd(tmp: Path) -> None:
        from daq.view.modes import write_modal_run_rrd

        write_modal_run_rrd(run, r, tmp)

    _write(task.outputs.get("--png"), "--png", png, row)
    _write(task.outputs.get("--rrd"), "--rrd", rrd, row)
    row.update(result=rows_summary(run), modes=len(run.rows))
    row["warnings"] += list(run.warnings)


VERBS: dict[str, Callable[[Task, dict], None]] = {"analyze": analyze_task, "frf": frf_task, "modal": modal_task}
