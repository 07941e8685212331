"""NSI columns recorded by ``gvt sweep`` (issue 22: identify a sweep without re-simulating) and the exact
one-DOF backbone law of analysis/nsi.py.

Oracles: the re-simulating path of ``daq.studies.identify.sweep.simulate_runs`` (the same integrator and reduction, so the
columns must agree to the CSV's 9 significant digits), the closed-form period of the pure cubic oscillator
(x'' + x³ = 0 at amplitude A: ω = π A / (2 K(m = 1/2)) = 0.847213 A) and the Duffing small-amplitude limit
(the harmonic-balance ω² = ω_n² + (3/4)(α/m) A²)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from analysis import nsi


def test_exact_backbone_limits():
    # pure cubic: ω/ω_n → c sqrt(u) as u = α A²/k → ∞, x'' + x³ = 0 having ω = c A, c = π / (2 K(1/2)) = 0.847213
    from scipy.special import ellipk

    r, s = nsi.backbone_ratios(np.array([1e-6, 1e8]), 2.0)
    assert r[1] / 1e4 == pytest.approx(math.pi / (2 * ellipk(0.5)), rel=1e-6)
    # small amplitude: harmonic balance and δ̄ = 2A/π
    assert r[0] ** 2 - 1 == pytest.approx(0.75e-6, rel=1e-3)
    assert s[0] == pytest.approx(2 / math.pi, rel=1e-6)
    # the law in δ̄ tends to the HB law at small δ̄ and is stiffer at large δ̄ (ω = 1.3 ω_n: +2.8 % in Δω²)
    om, m, a = 2 * math.pi * 26.0, 0.0509, 1.058e10
    lo, hi = 1e-6, 2e-4
    dw = lambda f: (2 * math.pi * f) ** 2 - om**2  # noqa: E731
    assert dw(nsi.exact_law_hz(lo, om, m, a, 2.0)) == pytest.approx(dw(nsi.law_hz(lo, om, m, a, 2.0, "hb")), rel=2e-3)
    assert 1.015 < dw(nsi.exact_law_hz(hi, om, m, a, 2.0)) / dw(nsi.law_hz(hi, om, m, a, 2.0, "hb")) < 1.04
    # eq. 5.9 on the exact backbone: the α it returns puts the curve through the intersection
    al = nsi.alpha_from_intersection(3.0297, 0.000196, 2.0391, 0.25, math.sqrt(40), "exact")
    assert nsi.law_hz(0.000196, math.sqrt(40), 0.25, al, 2.0391, "exact") == pytest.approx(3.0297, rel=1e-9)


def test_sweep_records_the_nsi_columns_identify_reads(tmp_path):
    """A 6-run sweep of beam_nes_ch5 writes nsi.csv; identify reads it (no simulation); an old sweep without nsi.csv
    is re-simulated (``simulate_runs``, the re-simulating path) and gives the same table and fit.

    The re-simulated table is the oracle for the recorded columns (one simulation of the 6 runs, not a second one
    beside it: identify_sweep's fallback is ``simulate_runs`` on the sweep.json's amplitudes, duration and order)."""
    from distributed import LocalCluster

    from analysis.model.rigs import open_rig
    from analysis.sweep_capture import CaptureSettings
    from daq.studies.identify.sweep import IdentifyOptions, identify_sweep
    from daq.studies.nsi_table import NSI_CSV, read_runs
    from daq.studies.sweep import SweepSpec, run_sweep, write_outputs

    rig = open_rig("beam_nes_ch5")
    # the sweep's runs on a dask scheduler in this process (a thread worker): the same submit/gather path as gvt sweep's
    # local cluster (SweepSpec.scheduler is its --scheduler), without a worker process's start-up and imports, which
    # are not what is tested here (gvt sweep's own processes: tests/test_sweep_cmd.py)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=":0") as cluster:
        spec = SweepSpec(pmin=0.3, pmax=30.0, n=6, duration=1.0, workers=1, capture=CaptureSettings(capture=False),
                         scheduler=cluster.scheduler_address)  # fmt: skip
        rep = run_sweep(rig, spec)
    paths = write_outputs(rep, tmp_path)
    assert paths["nsi"] == tmp_path / NSI_CSV
    swept = read_runs(paths["nsi"])
    opts = IdentifyOptions(frequency="pom", law="exact", n_boot=0)
    ident = identify_sweep(rig, tmp_path, opts)
    assert ident.source.startswith(str(paths["nsi"])) and "re-simulated" not in ident.source
    paths["nsi"].unlink()  # an old sweep: no NSI columns -> re-simulated, same table
    old = identify_sweep(rig, tmp_path, opts)
    assert "re-simulated" in old.source and (tmp_path / NSI_CSV).exists()
    again = old.runs  # the re-simulating path's columns, straight from simulate_runs (not through the CSV)
    assert np.allclose(again.P, spec.amplitudes, rtol=1e-12, atol=0)
    for k in ("P", "energy", "dbar", "f_rq", "f_pom"):  # written with 9 significant digits
        assert np.allclose(getattr(swept, k), getattr(again, k), rtol=1e-8, atol=0), k
    assert np.allclose(swept.mac, again.mac, rtol=0, atol=1e-6)  # written with 6 decimals
    assert np.array_equal(swept.capture, again.capture) and np.array_equal(swept.pom_index, again.pom_index)
    assert old.fit.beta == pytest.approx(ident.fit.beta, rel=1e-9)
    _full_disk_keeps_the_previous_files(rep, tmp_path / "full")


def _full_disk_keeps_the_previous_files(rep, full) -> None:
    """The sweep's files on a full 64 kB tmpfs (issue 30: "internal error" and .part files left before): one line,
    each file all or nothing, the 50 kB plot and the JSON after it the previous ones, no temporary file left."""
    import subprocess

    from analysis.errors import RuntimeFailure
    from daq.studies.sweep import write_outputs

    full.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(full)], capture_output=True).returncode:
        return  # mounting not permitted here: tests/test_probe_cases.py skips its full-disk cases too
    try:
        names = ["nsi.csv", "rqfep.csv", "rqfep.png", "sweep.json"]
        for name in names:
            (full / name).write_text("previous")
        (full / "filler").write_bytes(bytes(32 * 1024))  # 16 kB left: the two tables fit, the plot does not
        with pytest.raises(RuntimeFailure, match=r"rqfep\.png: not written: the disk is full"):
            write_outputs(rep, full)
        assert sorted(p.name for p in full.iterdir()) == sorted([*names, "filler"])
        assert (full / "rqfep.png").read_text() == "previous" and (full / "sweep.json").read_text() == "previous"
    finally:
        subprocess.run(["umount", "-l", str(full)], capture_output=True)
