"""``gvt import`` of UFF 58 (issue 31): gvtlink's own export comes back as the same modes, samples and hits; UFF 58 as
other tools write it (ASCII, binary 58b with 4- and 8-byte values, short and free-format rows) reads the same
values; g and lbf ordinates are converted by their exact factors; bad input is one line, exit 2, nothing written;
a roving-hammer FRF file (one accelerometer, the hammer at every node) has the hit points as references and gives
the rig's modes.

Tolerances: a UFF abscissa step is written E13.5 (6 digits: 5e-6 relative), so a frequency read back is within
5e-6 and the modes of the same FRFs within that plus pLSCF's own round-off -- the issue's bar is 1e-4 (0.01 %);
samples go through the log as float32 (6e-8 relative); 58 ASCII ordinates are E20.11 (1e-11 relative)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from analysis.model.channels import Channel
from daq.cli import run
from daq.log.reader import LogReader
from daq.studies.importing import uff as uff_import
from daq.studies.importing.data import FrfImport, ImportError_, TimeImport
from daq.studies.importing.log import META_IMPORT
from daq.studies.uff import datasets as uff

G, LBF = 9.80665, 4.4482216152605  # standard gravity (ISO 80000-3) and the pound-force (0.45359237 kg x g), exact


@pytest.fixture(scope="module")
def exported(tmp_path_factory) -> dict[str, Path]:
    """Two hits on beam_ch4_exp through the simulator, gvt frf's FRFs, gvt modal's modes, and gvtlink's UFF export of
    them all (ASCII: FRFs, mode shapes, time histories) and of the time histories alone (binary 58b)."""
    d = tmp_path_factory.mktemp("imp")
    p = {k: d / n for k, n in (("log", "s.mcap"), ("npz", "f.npz"), ("frf_uff", "f.uff"), ("time_uff", "t.uff"))}
    assert run(["simulate", "beam_ch4_exp", "--forces", "30,60", "--spacing", "0.6", "--duration", "0.4",
                "--seed", "5", "--out", str(p["log"])]) == 0  # fmt: skip
    assert run(["frf", str(p["log"]), "--out", str(p["npz"])]) == 0
    p["modes"] = d / "modes.json"
    assert run(["modal", str(p["npz"]), "--modes-out", str(p["modes"])]) == 0
    assert run(["export", str(p["log"]), "--frf", str(p["npz"]), "--modes", str(p["modes"]), "--out", str(p["frf_uff"])]) == 0
    assert run(["export", str(p["log"]), "--binary", "--out", str(p["time_uff"])]) == 0
    p["frf_uff_b"] = d / "fb.uff"  # 58b FRFs as pyuff writes them: the header's byte count is half the data
    assert run(["export", str(p["log"]), "--binary", "--frf", str(p["npz"]), "--out", str(p["frf_uff_b"])]) == 0
    return p


def _modes(capsys, source: Path) -> list[dict]:
    capsys.readouterr()
    assert run(["modal", str(source), "--json"]) == 0
    return json.loads(capsys.readouterr().out)["modes"]


def test_gvtlink_uff_export_imports_to_the_same_modes(exported, tmp_path, capsys):
    out = tmp_path / "imported.mcap"
    assert run(["import", str(exported["frf_uff"]), "-o", str(out)]) == 0
    said = capsys.readouterr().out
    assert "14 output(s) x 1 reference(s) accelerance" in said and "coherence in the file" in said
    meta = LogReader(out).metadata()[META_IMPORT]
    assert meta["format"] == "uff58" and len(meta["sha256"]) == 64 and meta["tool"] == "gvt import"
    assert any("exponential window" in a for a in json.loads(meta["assumptions"]))
    shapes = json.loads(dict(LogReader(out).attachments())["import/modes.json"][1])
    orig = json.loads(exported["modes"].read_text())
    assert shapes["outputs"] == orig["outputs"] and len(shapes["freq_hz"]) == len(orig["freq_hz"])
    np.testing.assert_allclose(shapes["freq_hz"], orig["freq_hz"], rtol=5e-6)  # dataset 55 writes E13.5
    scale = np.abs(np.asarray(orig["shapes_re"])).max()
    np.testing.assert_allclose(shapes["shapes_re"], orig["shapes_re"], rtol=5e-6, atol=5e-6 * scale)
    np.testing.assert_allclose(shapes["shapes_im"], orig["shapes_im"], rtol=5e-6, atol=5e-6 * scale)
    want = _modes(capsys, exported["npz"])
    for source in (out, exported["frf_uff"], exported["frf_uff_b"]):  # the import; UFF files to gvt modal directly
        got = _modes(capsys, source)
        assert len(got) == len(want) >= 5
        for a, b in zip(got, want, strict=True):
            assert abs(a["freq_hz"] / b["freq_hz"] - 1) < 1e-4  # the 0.01 %
            assert abs(a["zeta"] / b["zeta"] - 1) < 1e-2  # the window's damping taken out again (else +200 %)
    capsys.readouterr()
    assert run(["frf", str(exported["frf_uff"]), "--json"]) == 0  # gvt frf of the file: the set as it is, judged
    got = json.loads(capsys.readouterr().out)
    assert run(["frf", str(exported["log"]), "--json"]) == 0
    orig = json.loads(capsys.readouterr().out)
    assert got["references"] == orig["references"] and got["window"]["sigma_added"] == pytest.approx(
        orig["window"]["sigma_added"], rel=1e-5)  # fmt: skip
    assert [p["freq_hz"] for p in got["peaks"]] == pytest.approx([p["freq_hz"] for p in orig["peaks"]], rel=5e-6)


def test_gvtlink_time_histories_import_with_their_hits(exported, tmp_path, capsys):
    out = tmp_path / "t.mcap"
    assert run(["import", str(exported["time_uff"]), "-o", str(out), "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert (s["format"], s["hits"], s["accepted"], len(s["channels"])) == ("uff58b", 2, 2, 15)
    orig, imp = LogReader(exported["log"]), LogReader(out)
    a, b = orig.read_stream("dev0"), imp.read_stream("import")
    hits = [h["index"] for h in orig.json_messages("/daq/hits")]
    found = [h["index"] for h in imp.json_messages("/daq/hits")]
    start = hits[0] - 164  # the export's first record starts 10 ms (164 samples) before the first hit
    # the recorder's trigger fires where the force crosses 5 % of the largest peak; the simulator marks the pulse's
    # first sample: a half-sine of 2 ms (33 samples) rises through 5 % of 60 N within its first 2 samples
    assert len(found) == 2 and all(0 <= f + start - h <= 2 for f, h in zip(found, hits, strict=True))
    n = b.data.shape[0]
    np.testing.assert_array_equal(b.data, a.data[start : start + n])  # float32 -> UFF float64 -> float32: exact
    assert imp.streams()["import"].units == orig.streams()["dev0"].units
    capsys.readouterr()
    assert run(["frf", str(out), "--rig", "beam_ch4_exp", "--json"]) == 0
    h_imp = json.loads(capsys.readouterr().out)["peaks"]
    assert run(["frf", str(exported["log"]), "--json"]) == 0
    h_orig = json.loads(capsys.readouterr().out)["peaks"]
    # the same samples, but each record starts where the trigger fired (up to 2 samples after the simulator's mark,
    # above), so the exponential window sits up to 0.12 ms later: the peaks move by far less than a line (1.7 Hz)
    # and their magnitudes by ~2 samples' decay over tau = 92 ms (2 %)
    assert len(h_imp) == len(h_orig)
    np.testing.assert_allclose([p["freq_hz"] for p in h_imp], [p["freq_hz"] for p in h_orig], rtol=1e-3)
    np.testing.assert_allclose([p["mag"] for p in h_imp], [p["mag"] for p in h_orig], rtol=0.03)


# --- UFF 58 as other tools write it -----------------------------------------------------------------------------
def _header(func_type: int, ord_type: int, n: int, dt: float, node: int, unit: str, spec: int, name: str,
            id1: str, le: int = 1, fe: int = 0) -> list[str]:  # fmt: skip
    """Records 1-11 of a dataset 58 (I-DEAS layout), a time history at (node, +Z) over node 1 +Z."""
    return [id1.ljust(80), "NONE", "NONE", "NONE", "NONE",
            f"{func_type:5d}{1:10d}{1:5d}{0:10d} {name:>10s}{node:10d}{3:4d} {'hammer':>10s}{1:10d}{3:4d}",
            f"{ord_type:10d}{n:10d}{1:10d}{0.0:13.5e}{dt:13.5e}{0.0:13.5e}",
            f"{17:10d}{0:5d}{0:5d}{0:5d} {'time':<20s} {'s':<20s}",
            f"{spec:10d}{le:5d}{fe:5d}{0:5d} {'x':<20s} {unit:<20s}",
            f"{0:10d}{0:5d}{0:5d}{0:5d} {'NONE':<20s} {'NONE':<20s}",
            f"{0:10d}{0:5d}{0:5d}{0:5d} {'NONE':<20s} {'NONE':<20s}"]  # fmt: skip


def _ascii_58(values: np.ndarray, rows: list[int], fmt: str = "{:.11E}", **kw) -> bytes:
    """A dataset 58 with ``rows`` values on each line in turn (short and irregular rows, free-format widths)."""
    lines = ["    -1", "    58", *_header(ord_type=4, n=values.size, **kw)]
    k, r = 0, 0
    while k < values.size:
        m = rows[r % len(rows)]
        lines.append(" ".join(fmt.format(float(v)) for v in values[k : k + m]))
        k, r = k + m, r + 1
    return ("\n".join([*lines, "    -1"]) + "\n").encode()


def _binary_58(values: np.ndarray, size: int, order: str = "<", **kw) -> bytes:
    """A dataset 58b: the type line with byte order (1 little, 2 big), format, 11 ASCII lines and the byte count,
    then the values as raw ``size``-byte floats, as Testlab and others write them."""
    data = np.asarray(values, dtype=f"{order}f{size}").tobytes()
    head = f"{58:6d}b{1 if order == '<' else 2:6d}{2:6d}{11:12d}{len(data):12d}{0:6d}{0:6d}{0:12d}{0:12d}"
    text = "\n".join(["    -1", head, *_header(ord_type=2 if size == 4 else 4, n=values.size, **kw)]) + "\n"
    return text.encode() + data + b"    -1\n"


def _two_channels(force: np.ndarray, acc: np.ndarray, make, force_unit: str = "N", acc_unit: str = "m/s^2") -> bytes:
    return make(force, node=1, unit=force_unit, spec=13, name="hammer", id1="force", le=0, fe=1, dt=1e-3,
                func_type=1) + make(acc, node=2, unit=acc_unit, spec=12, name="acc", id1="response", dt=1e-3,
                                    func_type=1)  # fmt: skip


@pytest.fixture(scope="module")
def signals():
    rng = np.random.default_rng(7)
    force = np.zeros(203)
    force[5:9] = [10.0, 40.0, 40.0, 10.0]
    return force, rng.normal(size=203)  # 203: no format's rows come out even


@pytest.mark.parametrize("how", ["ascii-fixed", "ascii-irregular", "58b-8", "58b-4", "58b-8-big"])
def test_every_58_layout_reads_the_same_values(tmp_path, signals, how):
    force, acc = signals
    make = {
        "ascii-fixed": lambda v, **k: _ascii_58(v, [4], **k),
        "ascii-irregular": lambda v, **k: _ascii_58(v, [3, 1, 5, 2], fmt="{!r}", **k),  # free width, short rows
        "58b-8": lambda v, **k: _binary_58(v, 8, **k),
        "58b-4": lambda v, **k: _binary_58(v, 4, **k),
        "58b-8-big": lambda v, **k: _binary_58(v, 8, ">", **k),
    }[how]
    path = tmp_path / "x.uff"
    path.write_bytes(_two_channels(force, acc, make))
    data = uff_import.read(path)
    assert isinstance(data, TimeImport) and [c.name for c in data.channels] == ["hammer", "acc"]
    assert data.fs == pytest.approx(1000.0, rel=5e-6)  # E13.5 step
    exact = {"58b-4": np.float32}.get(how, np.float64)
    rtol = 1e-11 if how == "ascii-fixed" else 0  # E.11 rounds; every other layout holds the value exactly
    np.testing.assert_allclose(data.samples, np.stack([force, acc], 1).astype(exact), rtol=rtol, atol=0)


def test_g_and_lbf_ordinates_are_converted_by_their_exact_factors(tmp_path, signals):
    force, acc = signals
    path = tmp_path / "imperial.uff"
    path.write_bytes(_two_channels(force, acc, lambda v, **k: _binary_58(v, 8, **k), force_unit="lbf", acc_unit="g"))
    data = uff_import.read(path)
    np.testing.assert_allclose(data.samples[:, 0], force * LBF, rtol=1e-15)
    np.testing.assert_allclose(data.samples[:, 1], acc * G, rtol=1e-15)
    assert data.source_units == ["lbf", "g"] and [c.unit for c in data.channels] == ["N", "m/s^2"]


def _refused(capsys, path: Path, out: Path, *words: str) -> None:
    capsys.readouterr()
    assert run(["import", str(path), "-o", str(out)]) == 2
    msg = capsys.readouterr().err.strip()
    assert len(msg.splitlines()) == 1 and all(w in msg for w in words), msg
    assert not out.exists() and not list(out.parent.glob(f".{out.stem}*"))  # nothing written, no temporary left


def test_bad_input_is_one_line_exit_2_and_nothing_written(tmp_path, signals, capsys):
    force, acc = signals
    out = tmp_path / "o.mcap"
    unknown = tmp_path / "unknown.uff"
    unknown.write_bytes(_two_channels(force, acc, lambda v, **k: _ascii_58(v, [4], **k), acc_unit="blorps"))
    _refused(capsys, unknown, out, "blorps", "not understood")
    wrong = tmp_path / "wrong.uff"  # pint knows furlongs: a length, where record 9 says acceleration
    wrong.write_bytes(_two_channels(force, acc, lambda v, **k: _ascii_58(v, [4], **k), acc_unit="furlongs"))
    _refused(capsys, wrong, out, "furlongs", "displacement", "acceleration")
    blank = tmp_path / "blank.uff"
    blank.write_bytes(_two_channels(force, acc, lambda v, **k: _ascii_58(v, [4], **k), acc_unit="NONE"))
    _refused(capsys, blank, out, "no unit")
    whole = _two_channels(force, acc, lambda v, **k: _binary_58(v, 8, **k))
    for cut in (len(whole) - 300, len(whole) // 2 + 40):  # in the second dataset's data; in its header
        (tmp_path / "cut.uff").write_bytes(whole[:cut])
        _refused(capsys, tmp_path / "cut.uff", out, "truncated")
    temp = tmp_path / "temp.uff"
    temp.write_bytes(_ascii_58(force, [4], node=1, unit="N", spec=13, name="hammer", id1="force", le=0, fe=1,
                               dt=1e-3, func_type=1)
                     + _ascii_58(acc, [4], node=9, unit="degC", spec=5, name="thermo", id1="oven thermocouple T3",
                                 le=0, dt=1e-3, func_type=1))  # fmt: skip
    _refused(capsys, temp, out, "oven thermocouple T3", "temperature", "not a vibration quantity")
    spectrum = tmp_path / "spec.uff"
    spectrum.write_bytes(_ascii_58(acc, [4], node=2, unit="g", spec=12, name="acc", id1="autopower acc", dt=1.0,
                                   func_type=2))  # fmt: skip
    _refused(capsys, spectrum, out, "autopower acc", "auto spectrum")
    out.write_bytes(b"mine")
    assert run(["import", str(unknown), "-o", str(out)]) == 2 and out.read_bytes() == b"mine"  # never overwritten


def test_roving_hammer_frfs_have_the_hit_points_as_references(tmp_path, rigs, capsys):
    """One accelerometer (a07) and the hammer at 7 of the sensor nodes, as a roving-hammer test exports it
    (rsp node fixed, ref node varying, every ref entity "hammer"): the set has 14 references and one output, and
    gvt modal finds the rig's modes from it. Oracle: the FE model's undamped frequencies; the analytic FRFs carry
    the rig's damping (zeta <= 0.5 %), which moves a damped peak by zeta^2/2 < 2e-5, so 1e-3 is pLSCF's own bar."""
    rig = rigs("beam_ch4_exp")
    modes = rig.modes
    keep = modes.frequencies_hz < 5000
    wr, phi = modes.omega[keep], modes.shapes[:, keep]
    zeta = np.array([rig.config.damping.zeta[r] if r < len(rig.config.damping.zeta) else rig.config.damping.zeta_rest
                     for r in range(wr.size)])  # fmt: skip
    freq = np.arange(0.0, 600.5, 0.5)
    w = 2 * np.pi * freq
    acc = rig.sensors[6]
    den = wr[None, :] ** 2 - w[:, None] ** 2 + 2j * zeta * wr * w[:, None]
    points = rig.sensor_dofs[::2]  # the hammer at every other sensor's node (7 hit points: a cheap pLSCF)
    H = -(w**2)[None, :] * ((phi[acc.dof] * phi[points]) @ (1 / den).T)  # (7 hit points, n_f)
    out_ch = Channel("a07", "acceleration", 100, (0.0, 0.0, 0.0), 3)
    refs = [Channel("hammer", "force", 1 + k, (0.0, 0.0, 0.0), 3) for k in range(len(points))]
    path = tmp_path / "roving.uff"
    uff.write_uff(path, uff.frf_sets(freq, H[None, :, :], [out_ch], refs))
    data = uff_import.read(path)
    assert isinstance(data, FrfImport) and not data.coherence_known
    assert data.frf.outputs == ["a07"] and data.frf.references == [f"hammer:{k}+Z" for k in range(1, 8)]
    np.testing.assert_allclose(data.frf.H[0], H, rtol=1e-11)  # E20.11
    capsys.readouterr()
    assert run(["modal", str(path), "--band", "5", "550", "--max-order", "24", "--json"]) == 0  # 4 modes: order 24 is plenty
    got = [m["freq_hz"] for m in json.loads(capsys.readouterr().out)["modes"]]
    fe = modes.frequencies_hz[(modes.frequencies_hz > 5) & (modes.frequencies_hz < 550)]
    assert len(got) == fe.size
    np.testing.assert_allclose(got, fe, rtol=1e-3)


def test_struct_layout_of_the_hand_written_58b(tmp_path, signals):
    """The hand-written 58b above is what pyuff reads too (the layout is the reference's, not this reader's)."""
    import pyuff

    force, _acc = signals
    path = tmp_path / "p.uff"
    path.write_bytes(_binary_58(force, 8, node=1, unit="N", spec=13, name="hammer", id1="force", le=0, fe=1, dt=1e-3,
                                func_type=1))  # fmt: skip
    d = pyuff.UFF(str(path)).read_sets(0)
    np.testing.assert_array_equal(d["data"], force)
    assert (d["rsp_node"], d["rsp_dir"], d["ordinate_axis_units_lab"]) == (1, 3, "N")


def test_time_histories_without_a_force_are_refused(tmp_path):
    p = tmp_path / "noforce.uff"
    p.write_bytes(_ascii_58(np.ones(10), [4], node=2, unit="g", spec=12, name="acc", id1="r", dt=1e-3, func_type=1))
    with pytest.raises(ImportError_, match="no force channel"):
        uff_import.read(p)


FUZZ_EXAMPLES = int(os.environ.get("GVT_FUZZ_EXAMPLES", 60))


@settings(max_examples=FUZZ_EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_fuzz_a_damaged_uff_is_read_or_refused_in_one_line(tmp_path, signals, data):
    """Any bytes changed, cut or inserted in a valid file (ASCII and 58b): the reader returns a record or raises
    ImportError_ (one line, exit 2), never another exception (a traceback) or a hang."""
    force, acc = signals
    binary = data.draw(st.booleans())
    make = (lambda v, **k: _binary_58(v, 8, **k)) if binary else (lambda v, **k: _ascii_58(v, [4], **k))
    raw = bytearray(_two_channels(force[:40], acc[:40], make))
    for _ in range(data.draw(st.integers(1, 4))):
        at = data.draw(st.integers(0, len(raw) - 1))
        op = data.draw(st.sampled_from(["flip", "cut", "insert"]))
        if op == "flip":
            raw[at] = data.draw(st.integers(0, 255))
        elif op == "cut":
            del raw[at : at + data.draw(st.integers(1, 40))]
        else:
            raw[at:at] = data.draw(st.sampled_from([b"\n", b"    -1\n", b" ", b"D", b"-", b"9" * 30, b"\x00" * 8]))
    path = tmp_path / "fuzz.uff"
    path.write_bytes(bytes(raw))
    try:
        got = uff_import.read(path)
    except ImportError_ as exc:
        assert "\n" not in str(exc)
    else:
        assert isinstance(got, TimeImport | FrfImport) and np.isfinite(got.samples).all()


def test_model_update_takes_the_modes_of_a_uff_frf_file(exported, rigs, capsys):
    """What ``gvt model update --from FILE.uff`` feeds the updater (the optimiser itself is tested in
    test_model_update.py): the modes gvt modal identifies from the file, with a frequency uncertainty each."""
    from daq.studies.importing.frfs import frf_file
    from daq.studies.update_log import modes_from_set

    frf, assumed = frf_file(exported["frf_uff"])
    log = modes_from_set(exported["frf_uff"], frf, assumed, rigs("beam_ch4_exp"))
    want = [m["freq_hz"] for m in _modes(capsys, exported["frf_uff"])]
    np.testing.assert_allclose(log.measured.freq_hz, want, rtol=1e-9)
    assert np.all(np.asarray(log.measured.freq_std_hz) > 0) and log.hits_used == []
    assert any("exponential window" in n for n in log.notes)


def test_a_band_limited_pulse_ringing_across_the_trigger_is_one_hit():
    """pyFRF's measured hits cut at 6.4 kHz ring across the trigger level after the pulse; the gate took each ring for
    a hit (7 hits 2 samples apart, 0.16 ms records). Two true hits 0.5 s apart must give one record each, ending at
    the next hit's pre-trigger (0.5 - 0.01 s)."""
    from daq.studies.importing.log import record_length

    fs = 51200.0
    f = np.zeros(int(1.2 * fs))
    for t0 in (0.1, 0.6):  # a 60 µs steel tip: a sharp pulse, then an ideal cut at 6.4 kHz
        i = int(t0 * fs)
        f[i : i + 3] = 500.0 * np.sin(np.pi * np.arange(1, 4) / 4)
    spec = np.fft.rfft(f)
    spec[np.fft.rfftfreq(f.size, 1 / fs) > 6400.0] = 0.0
    ringing = np.fft.irfft(spec, f.size)
    level = 0.05 * ringing.max()
    above = ringing >= level
    assert np.count_nonzero(above[1:] & ~above[:-1]) > 2  # the case: more upward crossings than hits
    assert record_length(ringing, level, fs) == pytest.approx(0.5 - 0.01 - 1 / fs, abs=2e-3)


def test_an_inverted_force_channel_is_said_not_left_at_zero_hits(tmp_path, capsys):
    """A hammer recorded with its sign flipped (negative sensitivity, swapped wires) swings negative: the gate looks
    for positive force and the import said only "0 hit(s)". It must say why in one line; the upright copy finds the
    hits and says nothing."""
    from analysis.model.channels import Channel
    from daq.studies.importing.data import Provenance, TimeImport
    from daq.studies.importing.log import write_log

    fs = 2048.0
    f = np.zeros(int(2 * fs))
    for t0 in (0.2, 1.2):  # two 3 ms half-sine hits of 400 N
        i = int(t0 * fs)
        f[i : i + 6] = 400.0 * np.sin(np.pi * np.arange(1, 7) / 7)
    acc = np.random.default_rng(1).normal(0.0, 0.01, f.size)
    chans = [Channel("hammer", "force", 1, (0.0, 0.0, 0.0), 3), Channel("a01", "acceleration", 2, (1.0, 0.0, 0.0), 3)]
    prov = Provenance("synthetic", "0" * 64, "csv")
    for sign, warned in ((1.0, False), (-1.0, True)):
        data = TimeImport(np.column_stack([sign * f, acc]), fs, chans, prov)
        s = write_log(data, tmp_path / f"s{sign:+.0f}.mcap")
        assert (s["hits"] == 2) is not warned
        assert bool(s["warnings"]) is warned
        if warned:
            assert "hammer" in s["warnings"][0] and f"{-f.max():.4g} N but only to 0 N" in s["warnings"][0]
