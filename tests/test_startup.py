"""Start-up footprint (issue: start-up and footprint): each verb imports only what it uses. ``gvt --help``,
``gvt log info`` and the record path load none of the heavy libraries (numba, scipy, dask, rerun,
matplotlib ...); each driver's own library (python-can, cantools, pymodbus) loads with that driver's link,
not when the drivers are looked up. Read from ``python -X importtime`` in a fresh interpreter."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HEAVY = {"numba", "llvmlite", "scipy", "dask", "distributed", "rerun", "matplotlib", "pyarrow", "PyEMD"}
DRIVER_LIBS = {"can", "cantools", "pymodbus"}
LOG = ROOT / "replay_logs" / "two_dof_3hits.mcap"


def modules(*args: str, env: dict | None = None) -> set[str]:
    """Every module ``python -X importtime ARGS`` imports, dotted names (it must exit 0)."""
    p = subprocess.run([sys.executable, "-X", "importtime", *args], capture_output=True, text=True, cwd=ROOT, timeout=120,
                       env=env)  # fmt: skip
    assert p.returncode == 0, p.stderr[-2000:]
    lines = [line for line in p.stderr.splitlines() if line.startswith("import time:") and "cumulative" not in line]
    assert lines, "no -X importtime output"
    return {line.rsplit("|", 1)[1].strip() for line in lines}


def imported(*args: str, env: dict | None = None) -> set[str]:
    """Top-level packages ``python -X importtime ARGS`` imports (it must exit 0)."""
    return {m.split(".")[0] for m in modules(*args, env=env)}


def test_help_imports_nothing_heavy():
    mods = imported("-m", "daq.cli", "--help")
    assert "typer" in mods and "daq" in mods
    assert not mods & (HEAVY | DRIVER_LIBS | {"numpy"})


def test_log_info_imports_nothing_heavy():
    mods = imported("-m", "daq.cli", "log", "info", str(LOG))
    assert "mcap" in mods
    assert not mods & (HEAVY | DRIVER_LIBS)


def test_record_path_and_driver_lookup_import_nothing_heavy():
    """The record verb, the session, a rig and every installed driver class: the recorder of a real device
    without analysis needs no numba or scipy, and only the driver it opens loads its library."""
    code = (
        "import daq.cli.record, daq.session\n"
        "from analysis.model.rigs import open_rig\n"
        "from drivers.base import available_drivers\n"
        "open_rig('beam_ch4_exp'); assert {'serial', 'can', 'modbus'} <= set(available_drivers())\n"
    )
    mods = imported("-c", code)
    assert not mods & (HEAVY | DRIVER_LIBS)


def test_decomposition_does_not_load_matplotlib():
    """PyEMD's package import would load pylab (all of matplotlib) for a plotting helper the EMD never uses."""
    mods = imported("-c", "import analysis.emd, analysis.wbemd, analysis.confirm")
    assert "PyEMD" in mods and "scipy" in mods
    assert "matplotlib" not in mods


def test_one_blas_thread_default_still_set_before_numpy():
    """docs/decisions.md D19: ``import daq`` (any verb) sets the BLAS thread default before numpy loads."""
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    code = (
        "import sys, os, daq.cli; assert 'numpy' not in sys.modules; import daq.log.tools, analysis.model.rigs\n"
        "print(os.environ['OPENBLAS_NUM_THREADS'])"
    )
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120, env=env)
    assert p.returncode == 0 and p.stdout.strip() == "1", p.stderr


#: what a verb that runs no near-live analysis, confirmation or view must not load (docs/decisions.md D108): the
#: signal-processing package (0.5-1.3 s with the scipy.stats it pulls in), the JIT, the confirmation and detection
#: kernels, the viewer
ANALYSIS_ONLY = {"scipy.signal", "scipy.stats", "numba", "rerun", "PyEMD", "analysis.confirm", "analysis.operator"}


def test_log_export_imports_nothing_heavy(tmp_path):
    mods = imported("-m", "daq.cli", "log", "export", str(LOG), "--out", str(tmp_path / "x.npz"))
    assert (tmp_path / "x.npz").is_file()
    assert not mods & (HEAVY | DRIVER_LIBS)


def test_replay_without_analysis_loads_no_analysis_kernels():
    """``gvt replay --no-analysis`` runs the fan-out, the log lane and the live FRFs (scipy.linalg for the rig's modes,
    scipy.fft): it loaded the confirmation kernels (scipy.signal, scipy.stats, numba: 1.6 s) only for the companion
    log's file name."""
    mods = modules("-m", "daq.cli", "replay", "--no-analysis", str(LOG))
    assert "daq.replay_session" in mods and "daq.studies.confirm" in mods  # the path really ran
    assert not mods & ANALYSIS_ONLY, sorted(mods & ANALYSIS_ONLY)


def test_report_setup_and_study_modules_load_no_analysis_kernels():
    """What ``gvt report`` needs of a log that carries its analysis: the report's sections, the confirmation study and
    the .rrd builder (for a path, a table and the log's results), the view's setup of a rig (its sensors in model
    order and first mode) and the CWT. The kernels, their JIT and rerun load inside the functions that use them."""
    code = (
        "import daq.studies.report.build, daq.studies.confirm, daq.studies.analyze.rrd, analysis.wavelet\n"
        "from analysis.model.rigs import open_rig\n"
        "from daq.view.setup import ViewSetup\n"
        "s = ViewSetup.from_rig(open_rig('beam_ch4_exp'), {'dev0': ('a01',)}, 16384.0)\n"
        "assert len(s.sensors) == 14 and 5 < s.f_min_hz < 15, s  # half the FE NNM1 (20.8 Hz): the model really ran\n"
    )
    mods = modules("-c", code)
    assert not mods & ANALYSIS_ONLY, sorted(mods & ANALYSIS_ONLY)
