"""Campaigns (issue 31, item 4): ``gvt analyze`` and ``gvt modal`` over many logs as one Dask job.

A real ``distributed`` scheduler with two worker processes is started here (a ``LocalCluster`` of processes, reached
by its address through ``--scheduler``, as a lab's own cluster would be). Oracle: the single-log command, run here in
this process on each log; the campaign must give each log exactly what ``gvt VERB LOG --json`` gives it. Data: 20
short sessions of the seed's 2-DOF rig written by ``gvt simulate`` (two hits each, their forces and noise seeds
differing, so a result handed to the wrong log shows), one of them cut in half (a recorder that died); and for
``gvt modal`` the two beam logs of replay_logs/.
"""

from __future__ import annotations

import json
import logging
import shutil
from pathlib import Path

import pytest

from analysis.errors import BadInput
from daq.cli import run as gvt
from daq.studies.campaign.plan import find_logs, output_for, plan
from daq.studies.campaign.table import exit_code

ROOT = Path(__file__).resolve().parents[1]
N_LOGS = 20
DAMAGED = "run07.mcap"
#: what differs between two runs of one log: the wall clock
CLOCK = ("wall_seconds", "speed_x_real_time")


def _where_and_env() -> tuple[str, dict[str, str]]:
    import os

    import daq.studies.campaign.tasks as tasks

    return tasks.__file__, {k: os.environ.get(k, "") for k in ("OMP_NUM_THREADS", "NUMBA_NUM_THREADS", "NUMBA_CACHE_DIR")}


@pytest.fixture(scope="module")
def cluster():
    from distributed import Client, LocalCluster

    from analysis.jit_cache import cache_dir
    from daq.studies.campaign.runner import worker_env

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=None,
                      silence_logs=logging.ERROR, env=worker_env()) as lc, Client(lc) as client:  # fmt: skip
        # the workers run this tree's code (spawned with this process' sys.path), one thread per pool, and load the
        # numba kernels from the cache this process uses (analysis/jit_cache.py)
        env = {"OMP_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1", "NUMBA_CACHE_DIR": str(cache_dir())}
        where = client.run(_where_and_env)
        assert all(f.startswith(str(ROOT)) and e == env for f, e in where.values()), where
        yield lc.scheduler_address


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """20 two-hit sessions of two_dof (forces 0.1..1 N, seeds 1..20), the 8th cut at half its length."""
    d = tmp_path_factory.mktemp("campaign")
    for k in range(N_LOGS):
        f = f"{0.1 + 0.05 * k:.2f},1"
        p = d / f"run{k:02d}.mcap"
        assert gvt(["simulate", "two_dof", "--forces", f, "--spacing", "10", "--duration", "10", "--seed", str(k + 1),
                    "--out", str(p)]) == 0  # fmt: skip
    p = d / DAMAGED
    p.write_bytes(p.read_bytes()[: p.stat().st_size // 2])
    return d


def single(capsys, *argv: str) -> tuple[int, dict | None]:
    """``gvt VERB LOG --json`` in this process, on one BLAS thread as a gvt process (analysis/__init__.py, D19) and a
    campaign task (daq/studies/campaign/tasks.py) run it: this process's numpy, imported by test modules before
    analysis, has one thread per core, and after test_confirm and test_sweep_cmd the FRF window's tau moved by 1e-12
    relative (the results are compared bit for bit below)."""
    from threadpoolctl import threadpool_limits

    capsys.readouterr()
    with threadpool_limits(1):
        code = gvt([*argv, "--json"])
    text = capsys.readouterr().out
    return code, json.loads(text) if code == 0 else None


def test_campaign_of_20_logs_on_two_worker_processes_equals_each_log_alone(cluster, logs, tmp_path, capsys):
    out_dir = tmp_path / "out"
    code = gvt(["analyze", str(logs), "--scheduler", cluster, "--json", "--out-dir", str(out_dir)])
    doc = json.loads(capsys.readouterr().out)
    assert code == 3 and doc["exit_code"] == 3  # one log lost data (table.py's rule)
    failed = [(r["log"], r["error"]) for r in doc["rows"] if r["exit_code"] not in (0, 3) and not r["data_lost"]]
    assert (doc["logs"], doc["done"], doc["lost_data"], doc["failed"]) == (N_LOGS, N_LOGS - 1, 1, 0), failed
    rows = {Path(r["log"]).name: r for r in doc["rows"]}
    assert sorted(rows) == [f"run{k:02d}.mcap" for k in range(N_LOGS)]
    bad = rows.pop(DAMAGED)
    assert bad["data_lost"] and "gvt log recover" in bad["damage"] and bad["result"] is None, bad
    alone, _ = single(capsys, "analyze", str(logs / DAMAGED))
    assert bad["exit_code"] == alone and "\n" not in bad["error"]  # the single-log verb's own code, one line
    medians = set()
    for name, row in rows.items():
        code, want = single(capsys, "analyze", row["log"])
        assert code == 0 and row["exit_code"] == 0 and row["error"] is None, (name, row["error"])
        got = row["result"]
        for k in CLOCK:
            got.pop(k), want.pop(k)
        assert got == want, name  # bit for bit: the same kernels on the same samples, one thread each
        assert json.loads((out_dir / f"{Path(name).stem}.analyze.json").read_text()) | dict.fromkeys(CLOCK) == got | \
            dict.fromkeys(CLOCK)  # fmt: skip
        assert row["hits"] == 2 and row["events"] == len(want["events"])
        medians.add(tuple(want["rq_median_hz"]))
    assert len(medians) == N_LOGS - 1  # every log its own numbers: a result handed to another log would show


def _same(a, b, rel: float = 1e-6) -> bool:
    """Equal structures, floats to ``rel``: the modal chain's least squares run on BLAS, whose summation order
    depends on its thread count (one in a worker, the test process's own here): frequencies and damping moved by
    1e-15 relative, their uncertainties (a covariance of an ill-conditioned fit) by up to 1e-8 (OMP 1 against 2
    threads on beam_ch4_exp_weak)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k], rel) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y, rel) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) and isinstance(b, float):
        return a == pytest.approx(b, rel=rel, abs=1e-12)
    return a == b


def test_modal_campaign_writes_each_logs_modes_as_the_single_verb(cluster, logs, tmp_path, capsys):
    d = tmp_path / "logs"
    d.mkdir()
    for name in ("beam_ch4_exp_weak.mcap", "beam_ch4_exp_strong.mcap"):
        shutil.copy(ROOT / "replay_logs" / name, d / name)
    shutil.copy(logs / "run00.mcap", d / "two_dof.mcap")  # its hits are too soft for the FRF band: no FRF, exit 2
    out = tmp_path / "modes"
    argv = ["modal", str(d), "--scheduler", cluster, "--modes-out", str(out / "modes.json"), "--json"]
    out.mkdir()
    assert gvt(argv) == 2  # the worst per-log failure: bad input
    doc = json.loads(capsys.readouterr().out)
    rows = {Path(r["log"]).stem: r for r in doc["rows"]}
    assert rows["two_dof"]["exit_code"] == 2 and "no accepted hit" in rows["two_dof"]["error"]
    for stem in ("beam_ch4_exp_weak", "beam_ch4_exp_strong"):
        mine = tmp_path / f"{stem}.json"
        code, want = single(capsys, "modal", str(d / f"{stem}.mcap"), "--modes-out", str(mine))
        row = rows[stem]
        assert code == 0 and row["exit_code"] == 0 and _same(row["result"], want) and row["modes"] == len(want["modes"]) >= 5
        assert _same(json.loads((out / f"{stem}.modes.json").read_text()), json.loads(mine.read_text()))
        assert row["outputs"] == [str((out / f"{stem}.modes.json").resolve())]
    # gvt frf over the same directory: each log's document and FRF file as `gvt frf LOG --json --out F` gives them
    assert gvt(["frf", str(d), "--scheduler", cluster, "--out", str(out / "frf.npz"), "--json"]) == 2
    rows = {Path(r["log"]).stem: r for r in json.loads(capsys.readouterr().out)["rows"]}
    for stem in ("beam_ch4_exp_weak", "beam_ch4_exp_strong"):
        mine = tmp_path / f"{stem}.npz"
        code, want = single(capsys, "frf", str(d / f"{stem}.mcap"), "--out", str(mine))
        assert code == 0 and rows[stem]["result"] == want and rows[stem]["accepted"] == rows[stem]["hits"] == 1
        assert (out / f"{stem}.frf.npz").read_bytes() == mine.read_bytes()
    assert rows["two_dof"]["exit_code"] == 2 and rows["two_dof"]["accepted"] == 0
    # a second run would replace them: refused before anything runs, one line, exit 2
    capsys.readouterr()
    assert gvt(argv) == 2
    cap = capsys.readouterr()
    assert cap.out == "" and "the file exists (and 1 more" in cap.err and "--overwrite" in cap.err


def test_the_plan_names_outputs_per_log_and_refuses_collisions(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir(), b.mkdir()
    for p in (a / "run1.mcap", a / "run2.mcap", b / "run1.mcap", a / "notes.txt"):
        p.write_bytes(b"")
    assert find_logs([a]) == [a / "run1.mcap", a / "run2.mcap"]  # the directory's logs, in name order
    assert find_logs([a, a / "run2.mcap"]) == [a / "run1.mcap", a / "run2.mcap"]  # each once
    assert output_for(a / "run1.mcap", Path("res/modes.json"), None) == Path("res/run1.modes.json")
    assert output_for(a / "run1.mcap", Path("res/modes.json"), tmp_path) == tmp_path / "run1.modes.json"
    tasks = plan("modal", find_logs([a]), {"max_order": 40}, {"--modes-out": tmp_path / "m.json", "--png": None})
    assert [Path(t.outputs["--modes-out"]).name for t in tasks] == ["run1.m.json", "run2.m.json"]
    assert all(t.options == {"max_order": 40} and "--png" not in t.outputs for t in tasks)
    with pytest.raises(BadInput, match=r"both .*run1\.mcap and .*run1\.mcap would write it"):
        plan("modal", find_logs([a, b]), {}, {"--modes-out": tmp_path / "m.json"})
    with pytest.raises(BadInput, match=r"no \.mcap log in this directory"):
        find_logs([tmp_path])


@pytest.mark.parametrize(("codes", "lost", "want"), [
    ((0, 0, 0), False, 0), ((0, 1, 0), False, 1), ((0, 1, 2), False, 2), ((2, 1, 3), False, 3), ((0, 2, 0), True, 3),
])  # fmt: skip
def test_the_campaigns_exit_code_rule(codes, lost, want):
    rows = [{"exit_code": c, "data_lost": lost and i == 0} for i, c in enumerate(codes)]
    assert exit_code(rows) == want


def test_a_single_file_keeps_the_single_log_verb(tmp_path, capsys):
    """One log, no campaign option: the verb as before (no cluster, its own document), not a one-row table; a
    campaign asked both to start a cluster and to use one is refused before anything starts."""
    log = ROOT / "replay_logs" / "two_dof_3hits.mcap"
    assert gvt(["analyze", str(log), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert "rows" not in doc and doc["rq_windows"] > 0
    assert gvt(["analyze", str(log), str(log), "--scheduler", "tcp://127.0.0.1:1", "--workers", "2"]) == 2
    assert "--workers sizes the local cluster" in capsys.readouterr().err
