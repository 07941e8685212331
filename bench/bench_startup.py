"""Start-up and footprint benchmark (issue: start-up and footprint). Prints a table, writes
bench/results/bench_startup.json.

Each case runs in a fresh interpreter, for this tree and for the previous commit (HEAD, checked out as a git
worktree, default /tmp/gvt-base; ``--base`` another) with the same venv's python and ``PYTHONPATH`` at the tree,
the runs of the two trees interleaved (A B, B A, ...) — so the figures are ratios measured in one run on one
machine (machines here are noisy, bench/README.md):

* ``gvt --help``, ``gvt log info LOG``, ``gvt log export LOG``, ``gvt replay --no-analysis LOG``, ``gvt analyze
  LOG``, ``gvt report LOG`` (small logs from replay_logs/, recorded without the analysis, so the report analyses),
  ``gvt report`` of a log that carries its near-live analysis (a 1.5 s ``gvt record`` of a simulated serial session,
  made once per run with this tree; not with ``--no-record``), ``gvt record --help`` and the import of the record
  path (``import daq.cli.record, daq.session``, a rig, every driver
  class): warm wall time to the first byte of output, median of ``--repeats`` runs after one warm-up run
  (hyperfine-style; for the import, the whole run), peak RSS from ``/usr/bin/time -v`` and the
  ``-X importtime`` total and top-10 cumulative modules;
* ``gvt record`` of a real device: ``gvt device serve`` (the simulated DAQ behind a pseudo-terminal, another
  process) read over the serial driver for ``--record-seconds``, analysis and confirmation on as configured
  by default: time to the first status line (printed after 1 s of data) and peak RSS of the recorder and
  of its confirmation worker (``/usr/bin/time -v`` reports the larger);
* ``gvt simulate`` of 10 s and 120 s sessions of the seed's rig: peak RSS and wall time.

    python bench/bench_startup.py [--repeats 7] [--base /tmp/gvt-base] [--no-base] [--quick]

/usr/bin/time is Debian's ``time`` package (``apt-get install time``).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import selectors
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable
LOG = ROOT / "replay_logs" / "two_dof_3hits.mcap"
ANALYZE_LOG = ROOT / "replay_logs" / "beam_ch4_exp_weak.mcap"  # 2.1 s of the seed's rig
TIME = "/usr/bin/time"
HEAVY = ("numba", "scipy", "dask", "distributed", "rerun", "matplotlib", "pyarrow", "PyEMD", "can", "cantools", "pymodbus")
RECORD_IMPORT = (
    "import daq.cli.record, daq.session\n"
    "from analysis.model.rigs import open_rig\n"
    "from drivers.base import available_drivers\n"
    "open_rig('beam_ch4_exp'); available_drivers()\n"
)


def env_for(tree: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree))
    env.pop("GVT_DEBUG", None)
    return env


def check_tree(tree: Path) -> None:
    """The packages must resolve inside ``tree`` (not the editable install of another checkout)."""
    code = "import analysis, daq, drivers; print('\\n'.join(m.__file__ for m in (analysis, daq, drivers)))"
    out = subprocess.run([PY, "-c", code], capture_output=True, text=True, cwd=tree, env=env_for(tree), check=True).stdout
    bad = [f for f in out.split() if not Path(f).resolve().is_relative_to(tree.resolve())]
    if bad:
        sys.exit(f"bench_startup: in {tree} the packages resolve elsewhere: {bad}")


def first_output(cmd: list[str], tree: Path, timeout: float = 600.0) -> tuple[float | None, float, int]:
    """(seconds to the first byte on stdout or stderr, total seconds, exit code)."""
    t0 = time.perf_counter()
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=tree, env=env_for(tree))
    sel = selectors.DefaultSelector()
    for f in (p.stdout, p.stderr):
        sel.register(f, selectors.EVENT_READ)
    first, open_streams = None, 2
    while open_streams:
        for key, _ in sel.select(timeout=0.05):
            if not os.read(key.fileobj.fileno(), 65536):
                sel.unregister(key.fileobj)
                open_streams -= 1
            elif first is None:
                first = time.perf_counter() - t0
        if time.perf_counter() - t0 > timeout:
            p.kill()
    rc = p.wait()
    return first, time.perf_counter() - t0, rc


def peak_rss_mb(cmd: list[str], tree: Path) -> tuple[float, float, int]:
    """(peak RSS in MB from /usr/bin/time -v — the largest of the process and its waited-for children —,
    wall seconds, exit code)."""
    t0 = time.perf_counter()
    p = subprocess.run([TIME, "-v", *cmd], capture_output=True, text=True, cwd=tree, env=env_for(tree))
    wall = time.perf_counter() - t0
    m = re.search(r"Maximum resident set size \(kbytes\): (\d+)", p.stderr)
    return (int(m.group(1)) / 1024 if m else float("nan")), wall, p.returncode


def import_profile(cmd: list[str], tree: Path) -> dict:
    """``-X importtime`` of ``cmd`` (a python command line): total import seconds (the top-level imports'
    cumulative times), the ten slowest modules by cumulative time, and which heavy packages were imported."""
    assert cmd[0] == PY
    p = subprocess.run([PY, "-X", "importtime", *cmd[1:]], capture_output=True, text=True, cwd=tree, env=env_for(tree))
    rows = []
    for line in p.stderr.splitlines():
        if line.startswith("import time:") and "cumulative" not in line:
            _, cum, name = line.split("|")
            depth = (len(name) - len(name.lstrip(" ")) - 1) // 2
            rows.append((name.strip(), int(cum) / 1e6, depth))
    top = sorted(rows, key=lambda r: -r[1])[:10]
    loaded = {r[0].split(".")[0] for r in rows}
    return {
        "import_s": sum(r[1] for r in rows if r[2] == 0),
        "top10_cumulative": [[name, round(s * 1000, 1)] for name, s, _ in top],
        "heavy_imported": sorted(loaded & set(HEAVY)),
    }


def measure_cli(case: str, cmds: dict[Path, list[str]], repeats: int) -> list[dict]:
    """One case on every tree, interleaved: a warm-up run of each, then ``repeats`` rounds of one run per tree,
    alternating the order (A B, B A, ...), so that a change of the host's load falls on both trees alike."""
    trees = list(cmds)
    for tree in trees:
        first_output(cmds[tree], tree)  # warm-up: file cache, bytecode, numba cache
    firsts: dict[Path, list[float]] = {t: [] for t in trees}
    walls: dict[Path, list[float]] = {t: [] for t in trees}
    errors: dict[Path, str] = {}
    for k in range(repeats):
        for tree in trees if k % 2 == 0 else trees[::-1]:
            f, w, rc = first_output(cmds[tree], tree)
            if rc != 0:
                errors[tree] = f"exit {rc}"
            firsts[tree].append(f if f is not None else w)
            walls[tree].append(w)
    rows = []
    for tree in trees:
        if tree in errors:
            rows.append({"case": case, "tree_path": tree, "error": errors[tree]})
            continue
        rss, _, _ = peak_rss_mb(cmds[tree], tree)
        rows.append({
            "case": case, "tree_path": tree, "first_output_s": statistics.median(firsts[tree]),
            "first_output_min_s": min(firsts[tree]), "first_output_max_s": max(firsts[tree]),
            "wall_s": statistics.median(walls[tree]), "peak_rss_mb": rss, **import_profile(cmds[tree], tree),
        })  # fmt: skip
    return rows


SESSION_TOML = """name = "bench-real-serial"
rig = "beam_ch4_exp"
output = "{out}"
duration = {seconds}

[device]
name = "dev0"
driver = "serial"
config = {{ port = "{port}", usb_cdc = true, sample_rate = 16384.0, channels = {channels} }}

[trigger]
level = 20.0
record_length = 0.3
force_range = [100.0, 2000.0]
"""


def start_device(tmp: Path) -> tuple[subprocess.Popen, str]:
    """``gvt device serve`` of this tree on a pty (the real device the recorders read: another process)."""
    # 60 hits every 0.5 s (the physics of 32 s is computed ahead), then the noise floor for as long as it runs
    cmd = [PY, "-m", "daq.cli", "device", "serve", "beam_ch4_exp", "--transport", "serial", "--hits", "60",
           "--period", "0.5", "--seconds", "3600"]  # fmt: skip
    log = open(tmp / "device.out", "w+")  # read back while the device runs
    dev = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, cwd=ROOT, env=env_for(ROOT))
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        text = (tmp / "device.out").read_text()
        m = re.search(r"port = '([^']+)'", text)
        if m:
            return dev, m.group(1)
        if dev.poll() is not None:
            break
        time.sleep(0.1)
    dev.kill()
    sys.exit(f"bench_startup: the simulated device did not start: {(tmp / 'device.out').read_text()}")


def measure_record(tree: Path, port: str, tmp: Path, seconds: float, repeats: int) -> dict:
    channels = json.dumps(["hammer", *[f"a{k:02d}" for k in range(1, 15)]])
    firsts, rss = [], []
    for k in range(repeats + 1):
        out = tmp / f"rec_{tree.name}_{k}.mcap"
        cfg = tmp / f"rec_{tree.name}_{k}.toml"
        cfg.write_text(SESSION_TOML.format(out=out, seconds=seconds, port=port, channels=channels))
        cmd = [PY, "-m", "daq.cli", "record", str(cfg)]
        if k == 0:
            first_output(cmd, tree)  # warm-up
            continue
        f, _w, rc = first_output(cmd, tree)
        if rc != 0:
            return {"case": "gvt record (real device)", "error": f"exit {rc}"}
        firsts.append(f)
        out.unlink(missing_ok=True)
        r, _, _ = peak_rss_mb(cmd, tree)
        rss.append(r)
    return {"case": "gvt record (real device)", "first_output_s": statistics.median(firsts),
            "first_output_min_s": min(firsts), "peak_rss_mb": max(rss), "peak_rss_runs_mb": rss,
            "note": f"{seconds:g} s of a pty serial device, analysis + confirmation on; first output = the first "
                    "status line, printed after 1 s of data"}  # fmt: skip


def measure_simulate(tree: Path, tmp: Path, seconds: float) -> dict:
    out = tmp / f"sim_{tree.name}_{seconds:g}.mcap"
    hits = max(1, round((seconds - 0.1) / 2.0))  # spacing = tail = the rig's 2 s record length
    cmd = [PY, "-m", "daq.cli", "simulate", "beam_ch4_exp", "--hits", str(hits), "--out", str(out), "--overwrite"]
    first_output(cmd, tree)  # warm-up (numba cache)
    rss, wall, rc = peak_rss_mb(cmd, tree)
    return {"case": f"gvt simulate {seconds:g} s", "hits": hits, "peak_rss_mb": rss, "wall_s": wall,
            **({"error": f"exit {rc}"} if rc else {})}  # fmt: skip


def analysed_log(tmp: Path) -> Path | None:
    """A small log that carries its near-live analysis (``/analysis/*``): 1.5 s of the simulated 20-hit serial
    session recorded by this tree (the replay_logs were simulated, without the analysis). None if it failed."""
    cfg_text = (ROOT / "configs" / "sessions" / "sim_serial_20hits.toml").read_text()
    out = tmp / "analysed.mcap"
    cfg = tmp / "analysed.toml"
    cfg.write_text(re.sub(r'(?m)^output = .*$', f'output = "{out}"', re.sub(r"(?m)^duration = .*$", "duration = 1.5", cfg_text)))
    p = subprocess.run([PY, "-m", "daq.cli", "record", str(cfg)], capture_output=True, text=True, cwd=ROOT, env=env_for(ROOT))
    return out if p.returncode == 0 and out.exists() else None


def cli_cases(tree: Path, args, tmp: Path) -> list[tuple[str, list[str], int]]:
    """(case, command line, repeats) of the verbs measured in ``tree``."""
    cli = [PY, "-m", "daq.cli"]
    html = ["--out", str(tmp / f"report_{tree.name}.html"), "--overwrite"]
    cases = [
        ("gvt --help", [*cli, "--help"], args.repeats),
        ("gvt log info", [*cli, "log", "info", str(LOG)], args.repeats),
        ("gvt log export", [*cli, "log", "export", str(LOG), "--out", str(tmp / f"x_{tree.name}.npz"), "--overwrite"],
         args.repeats),
        ("gvt replay --no-analysis", [*cli, "replay", "--no-analysis", str(LOG)], args.repeats),
        ("gvt analyze", [*cli, "analyze", str(ANALYZE_LOG)], args.repeats),
        ("gvt report", [*cli, "report", str(ANALYZE_LOG), *html], max(1, args.repeats // 3)),
    ]  # fmt: skip
    if args.analysed_log is not None:
        cases.append(("gvt report (analysed log)", [*cli, "report", str(args.analysed_log), *html], args.repeats))
    cases += [
        ("gvt record --help", [*cli, "record", "--help"], args.repeats),
        ("import record path", [PY, "-c", RECORD_IMPORT], args.repeats),
    ]
    return cases


def run_trees(trees: list[Path], args, tmp: Path) -> list[dict]:
    rows: list[dict] = []
    per_tree = {tree: cli_cases(tree, args, tmp) for tree in trees}
    for k, (case, _cmd, repeats) in enumerate(per_tree[trees[0]]):
        print(f"  {case} ...", flush=True)
        rows += measure_cli(case, {tree: per_tree[tree][k][1] for tree in trees}, repeats)
    for tree in trees:
        print(f"  record and simulate in {tree} ...", flush=True)
        if not args.no_record:  # a fresh device for each tree: both read the same hits
            dev, port = start_device(tmp)
            try:
                rows.append({**measure_record(tree, port, tmp, args.record_seconds, max(1, args.repeats // 3)),
                             "tree_path": tree})  # fmt: skip
            finally:
                dev.terminate()
                dev.wait(10)
        for seconds in args.simulate:
            rows.append({**measure_simulate(tree, tmp, seconds), "tree_path": tree})
    for r in rows:
        tree = r.pop("tree_path")
        r["tree"] = tree.name if tree != ROOT else "this tree"
    return rows


def ensure_base(path: Path) -> Path:
    if not (path / "daq").is_dir():
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(path), "HEAD"], check=True,
                       capture_output=True)  # fmt: skip
    return path


def fmt(x, spec: str) -> str:
    return format(x, spec) if isinstance(x, int | float) else "—"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--base", type=Path, default=Path("/tmp/gvt-base"), help="worktree of the previous commit")
    ap.add_argument("--no-base", action="store_true", help="only this tree")
    ap.add_argument("--no-record", action="store_true", help="skip the real-device recording")
    ap.add_argument("--record-seconds", type=float, default=3.0)
    ap.add_argument("--quick", action="store_true", help="3 repeats, simulate 10 s only")
    args = ap.parse_args()
    args.simulate = [10.0] if args.quick else [10.0, 120.0]
    if args.quick:
        args.repeats = 3
    if not Path(TIME).exists():
        sys.exit(f"bench_startup: {TIME} is missing (Debian: apt-get install time)")
    trees = [ROOT] if args.no_base else [ensure_base(args.base), ROOT]
    for tree in trees:
        check_tree(tree)
    base_commit = None if args.no_base else subprocess.run(
        ["git", "-C", str(args.base), "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()  # fmt: skip
    rows: list[dict] = []
    with tempfile.TemporaryDirectory() as tmpdir:
        tmp = Path(tmpdir)
        args.analysed_log = None if args.no_record else analysed_log(tmp)
        print(f"measuring {', '.join(map(str, trees))}, each case interleaved ...", flush=True)
        rows += run_trees(trees, args, tmp)
    by = {(r["tree"], r["case"]): r for r in rows}
    cases = list(dict.fromkeys(r["case"] for r in rows))
    base = None if args.no_base else args.base.name
    print()
    print(f"{'case':26s} {'first out s':>18s} {'ratio':>6s} {'peak RSS MB':>16s} {'ratio':>6s} {'imports s':>14s}  "
          "heavy imports (this tree)")  # fmt: skip
    ratios = {}
    for c in cases:
        new = by.get(("this tree", c), {})
        old = by.get((base, c), {}) if base else {}
        t_new = new.get("first_output_s", new.get("wall_s"))
        t_old = old.get("first_output_s", old.get("wall_s"))
        rt = t_new / t_old if isinstance(t_new, float) and isinstance(t_old, float) and t_old else None
        rr = new.get("peak_rss_mb", 0) / old["peak_rss_mb"] if old.get("peak_rss_mb") else None
        ratios[c] = {"time": rt, "rss": rr}
        print(
            f"{c:26s} {fmt(t_old, '8.3f')} → {fmt(t_new, '7.3f')} {fmt(rt, '6.2f')} "
            f"{fmt(old.get('peak_rss_mb'), '7.0f')} → {fmt(new.get('peak_rss_mb'), '6.0f')} {fmt(rr, '6.2f')} "
            f"{fmt(old.get('import_s'), '6.2f')} → {fmt(new.get('import_s'), '5.2f')}  "
            f"{','.join(new.get('heavy_imported', [])) or ('-' if 'heavy_imported' in new else '')}"
            f"{'  ERROR ' + new['error'] if 'error' in new else ''}{'  base ERROR ' + old['error'] if 'error' in old else ''}"
        )
    print(f"(previous commit {base_commit} → this tree; first out: median of {args.repeats} warm runs, time to the first "
          "byte of output; simulate: wall time)" if base else "")  # fmt: skip
    print("targets: --help, log info, record start within 1 s warm; recorder < 300 MB; simulate bounded (10 s ≈ 120 s)")
    res_dir = ROOT / "bench" / "results"
    res_dir.mkdir(parents=True, exist_ok=True)
    out = {"python": sys.version.split()[0], "cpus": os.cpu_count(), "repeats": args.repeats, "base_commit": base_commit,
           "rows": rows, "ratios_this_over_base": ratios}  # fmt: skip
    (res_dir / "bench_startup.json").write_text(json.dumps(out, indent=2))
    print(f"wrote {res_dir / 'bench_startup.json'}")
    if shutil.which("git") and not args.no_base:
        print(f"(base worktree kept at {args.base}; remove with: git worktree remove {args.base})")


if __name__ == "__main__":
    main()
