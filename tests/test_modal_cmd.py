"""``gvt modal`` end to end (issue 20): simulated linear hits → ``gvt frf`` → pLSCF + LSFD → the rig's FE modes,
and the modes file into UFF 55 through ``gvt export``, read back by pyuff.

Data: the linear ``beam_ch4_exp`` session of tests/test_frf.py (five 200 N hits, then a 3000 N hit that
``gvt frf`` refuses as an overload, 1 % noise, order-4 stepping; simulated once for the files that use it:
tests/test_frf.py ``shared_session``). Oracle: the rig's own FE model (frequencies, modal damping ratios, shapes at
the sensors). The exponential window's added damping is removed by ``identify`` (sigma_added); what remains of the tolerance
is the estimator's, on measured (simulated and noisy) FRFs rather than the analytic ones of test_modal_id.
"""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from daq.cli import run as gvt

from .test_frf import FORCE, shared_session


@pytest.fixture(scope="module")
def linear(tmp_path_factory):
    return shared_session(tmp_path_factory, 0.01, 0.01, (FORCE,) * 5 + (3000.0,))  # tests/test_frf.py's ``clean``


def test_gvt_modal_from_a_log_finds_the_fe_modes(linear, tmp_path, capsys):
    rig, log = linear
    modes, png = tmp_path / "modes.json", tmp_path / "stab.png"
    assert gvt(["modal", str(log), "--json", "--modes-out", str(modes), "--png", str(png)]) == 0
    doc = json.loads(capsys.readouterr().out)
    rows = doc["modes"]
    fe = rig.modes.frequencies_hz
    first6 = [r for r in rows if r["fe_mode"] <= 6]
    assert sorted(r["fe_mode"] for r in first6) == [1, 2, 3, 4, 5, 6], [(r["freq_hz"], r["fe_mode"]) for r in rows]
    for r in first6:
        assert abs(r["freq_error"]) < 1e-3, r  # 0.1 %
        assert abs(r["zeta_error"]) < 0.05, r  # 5 %, window damping removed
        assert r["mac"] >= 0.99 and r["mpc"] > 0.99, r
        assert r["fe_freq_hz"] == pytest.approx(fe[r["fe_mode"] - 1])
    m = json.loads(modes.read_text())
    assert len(m["freq_hz"]) == len(rows) and np.asarray(m["shapes_re"]).shape == (14, len(rows))
    assert png.stat().st_size > 10_000


def test_modes_file_goes_to_uff55_and_back(linear, tmp_path):
    pyuff = pytest.importorskip("pyuff", reason="pyuff is in the runtime dependencies; make test installs it")
    from daq.studies.uff.datasets import write_uff

    _rig, log = linear
    frf, modes, uff = tmp_path / "frf.npz", tmp_path / "modes.json", tmp_path / "s.uff"
    assert gvt(["frf", str(log), "--out", str(frf)]) == 0
    assert gvt(["modal", str(frf), "--modes-out", str(modes)]) == 0  # from the FRF file: no rig needed
    # --binary: datasets 58 (the hit records and FRFs) as 58b, which pyuff reads without parsing text; the 55 sets under
    # test are ASCII either way, and the ASCII 58 encoding is tests/test_uff.py's (same sets, same numbers as 58b)
    flags = ["--frf", str(frf), "--modes", str(modes), "--binary"]
    assert gvt(["export", str(log), "--format", "uff", "--out", str(uff), *flags]) == 0
    sets = pyuff.UFF(str(uff)).read_sets()
    # write_uff does not let pyuff re-read the file after each set (daq/studies/uff/datasets.py): a sample of the
    # sets (every kind, each 20th dataset 58) written through it and through plain pyuff gives the same bytes
    few = [d for k, d in enumerate(sets) if d["type"] != 58 or k % 20 == 0]
    write_uff(tmp_path / "ours.uff", copy.deepcopy(few))
    pyuff.UFF(str(tmp_path / "plain.uff")).write_sets(copy.deepcopy(few), mode="overwrite")
    assert {d["type"] for d in few} >= {15, 55, 58, 82} and any(d.get("binary") for d in few)
    assert (tmp_path / "ours.uff").read_bytes() == (tmp_path / "plain.uff").read_bytes()
    shapes = [s for s in sets if s["type"] == 55]
    m = json.loads(modes.read_text())
    assert len(shapes) == len(m["freq_hz"]) > 0
    for s, f, z in zip(shapes, m["freq_hz"], m["zeta"], strict=True):  # complex modes: the eigenvalue carries f, zeta
        lam = complex(s["eig"])
        assert abs(lam) / (2 * np.pi) == pytest.approx(f, rel=1e-5) and -lam.real / abs(lam) == pytest.approx(z, rel=1e-3)


def test_gvt_modal_bad_inputs_are_one_line(linear, tmp_path, capsys):
    _rig, log = linear
    bad = tmp_path / "x.npz"
    bad.write_bytes(b"not an npz")
    assert gvt(["modal", str(bad)]) == 2
    assert gvt(["modal", str(log), "--band", "500", "100"]) == 2
    poles = tmp_path / "p.toml"
    poles.write_text("[[poles]]\nfreq_hz = 3333.0\ntol = 0.001\n")
    assert gvt(["modal", str(log), "--poles", str(poles)]) == 2
    errs = capsys.readouterr().err.strip().splitlines()
    assert len([e for e in errs if e.startswith("gvt: error")]) == 3 and not any("Traceback" in e for e in errs)
