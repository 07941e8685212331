"""``gvt report`` of a 60 s log: wall time, peak RSS and figure draws, before (HEAD) and after (this tree), one run.

Issue 20 item 3: "every figure is drawn twice and the report of a 60 s log takes 8 s and 440 MB". Why twice:
``savefig(bbox_inches="tight")`` (and ``savefig`` with any layout engine) makes ``print_figure`` draw the
whole figure once to measure it, then again to write it; ``daq/studies/report/page.py::png`` now draws each once.

The log: ``gvt simulate beam_ch4_exp --hits 10 --spacing 5 --duration 15`` = 0.1 + 9 x 5 + 15 = 60.1 s of
15 channels at 16384 Hz (the rig with its cubic spring, rising force to the nominal hit). Each report runs in a
fresh interpreter, ``python -m daq.cli report``, with ``PYTHONPATH`` at the tree: HEAD is checked out as a
git worktree (default /tmp/report_base). Wall time and peak RSS of that one child come from ``os.wait4``
(its own rusage); ``Figure.draw`` calls are counted by a wrapper installed before the CLI runs. The figures
of the two trees are not the same work: this tree's report adds the FRF section (3 figures, the FRFs of
the hits and a pLSCF identification); its time is given apart (``frf_s``, measured in process).
Median of ``--repeats`` alternated runs after one warm-up each; ``os.getloadavg()`` beside each figure.

    python bench/bench_report.py [--repeats 3] [--base /tmp/report_base] [--log LOG]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable
SIM = ["beam_ch4_exp", "--hits", "10", "--spacing", "5", "--duration", "15"]
CHILD = """
import atexit, os, runpy, sys
from matplotlib.figure import Figure
n = [0]
_draw = Figure.draw
def draw(self, renderer):
    n[0] += 1
    return _draw(self, renderer)
Figure.draw = draw
atexit.register(lambda: os.write(2, f"\\nDRAWS {n[0]}\\n".encode()))
sys.argv = ["gvt", *sys.argv[1:]]
runpy.run_module("daq.cli", run_name="__main__")
"""


def env_for(tree: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree), MPLBACKEND="Agg")
    env.pop("GVT_DEBUG", None)
    return env


def ensure_base(base: Path) -> None:
    """A worktree of HEAD at ``base`` to compare against, added once (any tree that has the daq package)."""
    if not (base / "daq" / "__init__.py").exists():
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(base), "HEAD"], check=True)


def run_report(tree: Path, log: Path, out: Path) -> dict:
    """One ``gvt report`` in a fresh interpreter: wall s, peak RSS MB (``os.wait4``: this child's own), draws."""
    load = os.getloadavg()[0]
    cmd = [PY, "-c", CHILD, "report", str(log), "--out", str(out), "--overwrite"]
    with tempfile.TemporaryFile("w+") as so, tempfile.TemporaryFile("w+") as se:
        t0 = time.perf_counter()
        p = subprocess.Popen(cmd, cwd=tree, env=env_for(tree), stdout=so, stderr=se, text=True)
        _pid, status, ru = os.wait4(p.pid, 0)
        wall = time.perf_counter() - t0
        p.returncode = os.waitstatus_to_exitcode(status)
        so.seek(0)
        se.seek(0)
        stdout, stderr = so.read(), se.read()
    if p.returncode:
        sys.exit(f"bench_report: {tree}: exit {p.returncode}\n{stderr[-2000:]}")
    draws = int(next(ln.split()[1] for ln in stderr.splitlines() if ln.startswith("DRAWS")))
    return {"wall_s": wall, "rss_mb": ru.ru_maxrss / 1024, "draws": draws, "out": stdout.strip(), "load1": load}


def frf_seconds(log: Path) -> float:
    """In this tree: the FRF section alone (FRFs of the hits, pLSCF + LSFD, three figures drawn)."""
    code = (
        "import time, matplotlib; matplotlib.use('Agg')\n"
        "from daq.log.reader import LogReader; from daq.log.rig import rig_from_log\n"
        "from daq.studies.report.page import png, table; from daq.studies.report.frf import frf_section\n"
        f"rig = rig_from_log(LogReader({str(log)!r})); t = time.perf_counter()\n"
        f"s = frf_section({str(log)!r}, rig, table); [png(f) for _, f in s.figures]\n"
        "print(time.perf_counter() - t)"
    )
    return float(subprocess.run([PY, "-c", code], cwd=ROOT, env=env_for(ROOT), capture_output=True, text=True, check=True).stdout)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--base", type=Path, default=Path("/tmp/report_base"))
    ap.add_argument("--log", type=Path, default=None, help="A 60 s log (default: simulated now)")
    a = ap.parse_args()
    ensure_base(a.base)
    tmp = Path(tempfile.mkdtemp(prefix="bench_report_"))
    log = a.log or tmp / "log60.mcap"
    if a.log is None:
        subprocess.run([PY, "-m", "daq.cli", "simulate", *SIM, "--out", str(log)], cwd=ROOT, env=env_for(ROOT), check=True,
                       capture_output=True)  # fmt: skip
    trees = {"before (HEAD)": a.base, "after (this tree)": ROOT}
    runs: dict[str, list[dict]] = {k: [] for k in trees}
    for tree in trees.values():
        run_report(tree, log, tmp / "warm.html")
    for _ in range(a.repeats):
        for name, tree in trees.items():
            runs[name].append(run_report(tree, log, tmp / f"{name.split()[0]}.html"))
    frf_s = statistics.median(frf_seconds(log) for _ in range(a.repeats))
    rows = []
    print(f"gvt report of {log} ({log.stat().st_size / 1e6:.1f} MB, 60.1 s x 15 ch at 16384 Hz); median of {a.repeats}")
    print(f"{'tree':<18} {'wall [s]':>9} {'peak RSS [MB]':>14} {'draws':>6} {'plots':>6} {'load1':>6}")
    for name, rs in runs.items():
        med = {k: statistics.median(r[k] for r in rs) for k in ("wall_s", "rss_mb", "load1")}
        plots = int(rs[0]["out"].split(": ")[1].split()[0])
        row = {"tree": name, **med, "draws": rs[0]["draws"], "plots": plots, "runs": rs}
        rows.append(row)
        print(f"{name:<18} {med['wall_s']:>9.2f} {med['rss_mb']:>14.0f} {row['draws']:>6} {plots:>6} {med['load1']:>6.2f}")
    print(f"after: the FRF section alone (FRFs of 10 hits, pLSCF + LSFD, 3 figures) {frf_s:.2f} s "
          f"(load {os.getloadavg()[0]:.2f})")  # fmt: skip
    res = ROOT / "bench" / "results" / "bench_report.json"
    res.write_text(json.dumps({"log": str(log), "simulate": SIM, "repeats": a.repeats, "rows": rows, "frf_section_s": frf_s,
                               "loadavg_end": os.getloadavg()}, indent=1))  # fmt: skip
    print(f"wrote {res}")


if __name__ == "__main__":
    main()
