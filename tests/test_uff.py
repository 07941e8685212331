"""UFF export (issue 20 item 5): every dataset gvtlink writes is read back by pyuff with the right node, direction,
units and values, FRFs also by sdypy-EMA (``Model.read_uff``: it reads dataset 58 FRFs, function type 4, and no
mode shapes), on hits simulated by the project's simulator and logged by its writer.

Tolerances come from the format: ordinates are written E20.11 (12 significant digits: 5e-12 relative) or as
float64 (binary 58b: exact); the abscissa increment, eigenvalues, coordinates and 55 shape values E13.5 (6
significant digits: 5e-6 relative)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from analysis.model.channels import Channel, rig_channels
from analysis.model.geometry import rig_geometry
from analysis.model.rigs import open_rig
from analysis.model.wireframe import make_geometry
from daq.cli import run
from daq.log.reader import LogReader
from daq.studies.uff import datasets as uff

E13 = 5e-6  # E13.5: 6 significant digits
E20 = 1e-11  # E20.11: 12 significant digits
ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def session(tmp_path_factory) -> Path:
    """Two linear hits (30 N and 60 N, 0.6 s apart) on beam_ch4_exp through the simulator and the log writer."""
    out = tmp_path_factory.mktemp("uff") / "two_hits.mcap"
    assert run(["simulate", "beam_ch4_exp", "--forces", "30,60", "--spacing", "0.6", "--duration", "0.4",
                "--seed", "5", "--out", str(out)]) == 0  # fmt: skip
    return out


def _analytic_accelerance(rig, freq: np.ndarray) -> np.ndarray:
    """H[o, 0, k] = sum_r -w^2 phi_o,r phi_h,r / (w_r^2 - w^2 + 2 i zeta_r w_r w) over the rig's modes below 5 kHz
    (mass-normalised FE modes, the rig's modal damping): the model's accelerance at each sensor per hammer force."""
    modes = rig.modes
    keep = modes.frequencies_hz < 5000
    wr, phi = modes.omega[keep], modes.shapes[:, keep]
    cfg = rig.config.damping
    zeta = np.array([cfg.zeta[r] if r < len(cfg.zeta) else cfg.zeta_rest for r in range(wr.size)])
    w = 2 * np.pi * freq
    num = phi[rig.sensor_dofs] * phi[rig.hammer.dof]  # (n_out, n_modes)
    den = wr[None, :] ** 2 - w[:, None] ** 2 + 2j * zeta * wr * w[:, None]  # (n_f, n_modes)
    return (-(w**2)[None, :] * (num @ (1 / den).T))[:, None, :]


def test_export_of_a_simulated_session_reads_back_in_pyuff(session, tmp_path):
    out = tmp_path / "two_hits.uff"
    assert run(["export", str(session), "--format", "uff", "--out", str(out)]) == 0
    sets = uff.read_uff(out)
    rig = open_rig("beam_ch4_exp")
    table = {c.name: c for c in rig_channels(rig)}
    assert [d["type"] for d in sets[:3]] == [164, 15, 82] and sets[0]["units_code"] == 1  # SI
    geo = uff.geometry_from_sets(sets)
    want = rig_geometry(rig)
    assert geo.ids.tolist() == want.ids.tolist() and geo.lines.tolist() == want.lines.tolist()
    np.testing.assert_allclose(geo.xyz, want.xyz, rtol=E13, atol=0)
    # the time histories: 2 hits x 15 channels, each equal to the log's samples (read by the log reader itself)
    times = [d for d in sets if d["type"] == 58]
    assert len(times) == 30 and {d["func_type"] for d in times} == {1}
    reader = LogReader(session)
    info = reader.streams()["dev0"]
    whole = reader.read_stream("dev0")
    hits = reader.json_messages("/daq/hits")
    # records: 10 ms before each trigger, to 10 ms before the next one / the end of the log
    bounds = [(hits[0]["index"] - 164, hits[1]["index"] - 164), (hits[1]["index"] - 164, len(whole.index))]
    for d in times:
        name, hit = d["rsp_ent_name"], d["ver_num"] - 1
        ch, hammer = table[name], table["hammer"]
        assert (d["rsp_node"], d["rsp_dir"], d["ref_node"], d["ref_dir"]) == (ch.node, ch.direction, hammer.node, 3)
        assert d["ordinate_axis_units_lab"] == info.units[info.channels.index(name)] == ch.unit
        assert d["ordinate_spec_data_type"] == (13 if name == "hammer" else 12)
        assert d["abscissa_axis_units_lab"] == "s" and d["abscissa_spec_data_type"] == 17
        a, b = bounds[hit]
        expect = whole.data[a:b, info.channels.index(name)].astype(float)
        np.testing.assert_allclose(d["data"], expect, rtol=E20, atol=E20 * np.abs(expect).max())
        assert d["x"][0] == pytest.approx(a / info.sample_rate, rel=E13)
        assert d["abscissa_inc"] == pytest.approx(1 / info.sample_rate, rel=E13)
    peak = max(np.abs(d["data"]).max() for d in times if d["rsp_ent_name"] == "hammer" and d["ver_num"] == 2)
    assert peak == pytest.approx(60.0, rel=0.02)  # the 60 N hit (the hammer channel's noise and ADC: < 2 %)


def test_two_device_log_exports_every_device_on_the_session_timeline(tmp_path, capsys):
    """Issue 31 item 5: the format 1 two-device log (tests/data/format1/two_devices.mcap: the hammer on hammer_daq,
    14 accelerometers on acc_daq, whose sample 0 is the hammer's sample 3885) used to export the hammer alone.
    Now every hit holds all 15 channels; acc_daq's records are its own samples 3885 earlier on its clock, equal to
    the log's values, on the hammer's time axis -- and the driving point's response starts with the hammer's blow
    (onset within 1 ms, the physics of an impact: the oracle that does not use the offset)."""
    from .test_time_base import onset

    log = ROOT / "tests" / "data" / "format1" / "two_devices.mcap"
    out = tmp_path / "two.uff"
    assert run(["export", str(log), "--out", str(out), "--binary"]) == 0
    said = capsys.readouterr().out
    assert "3 accepted hit(s) x 15 channels of 2 streams (hammer_daq, acc_daq at +3885 samples)" in said, said
    times = [d for d in uff.read_uff(out) if d["type"] == 58]
    assert len(times) == 3 * 15 and {d["rsp_ent_name"] for d in times} == {"hammer", *(f"a{k:02d}" for k in range(1, 15))}
    reader = LogReader(log)
    hits = [h for h in reader.json_messages("/daq/hits") if h["verdict"] == "accepted"]
    acc = reader.read_stream("acc_daq")
    fs = 16384.0
    for h in hits:
        rec = {d["rsp_ent_name"]: d for d in times if d["ver_num"] == h["hit"] + 1}
        a, b = h["start_index"], h["end_index"]
        own = (acc.index >= a - 3885) & (acc.index < b - 3885)
        for k, name in enumerate(reader.streams()["acc_daq"].channels):
            assert np.array_equal(rec[name]["data"], acc.data[own, k].astype(float)), (h["hit"], name)  # 58b: exact
            assert rec[name]["x"][0] == pytest.approx(a / fs, rel=E13)  # the hammer's time axis, not acc_daq's own
        t = rec["hammer"]["x"]
        ts = h["index"] / fs
        dt = onset(t, rec["a13"]["data"], ts - 0.01, ts + 0.02) - onset(t, rec["hammer"]["data"], ts - 0.01, ts + 0.02)
        assert abs(dt) <= 1e-3, (h["hit"], dt)  # a13 is at the hammer's DOF (sim_two_devices.toml); 1 ms = 16 samples


def test_a_device_that_does_not_cover_a_hit_is_left_out_of_it_with_one_line(tmp_path, capsys):
    """A second device whose clock starts late (its sample 0 is the hammer's sample 600, 1 kHz): the first hit's
    record [290, 1290) is not all in it, so that hit has the hammer alone and one warning line names the device,
    its channels and the hit; the second hit has both, the accelerometer's samples its own 600 earlier."""
    from daq.log.writer import ChannelInfo, LogWriter
    from drivers.blocks import SampleBlock

    log, fs, d = tmp_path / "late.mcap", 1000.0, 600
    with LogWriter(log, origin_ns=0) as w:
        w.add_stream("h", [ChannelInfo("hammer", "force", "N")], fs, offset_ns=0)
        w.add_stream("a", [ChannelInfo("a1", "acceleration", "m/s^2")], fs, offset_ns=round(d * 1e9 / fs))
        force = np.zeros(2000, np.float32)
        force[[300, 1300]] = 50.0
        w.write_block(SampleBlock("h", 0, fs, ("hammer",), force[:, None]), wait=True)
        own = np.arange(1400, dtype=np.float32)  # value = own index
        w.write_block(SampleBlock("a", 0, fs, ("a1",), own[:, None]), wait=True)
        for k, (a, b) in enumerate(((290, 1290), (1290, 2000))):
            w.write_hit({"hit": k, "index": a + 10, "t_s": (a + 10) / fs, "verdict": "accepted", "start_index": a,
                         "end_index": b})  # fmt: skip
    table = tmp_path / "ch.csv"
    table.write_text("name,node,x,y,z,direction,sensitivity,unit\nhammer,1,0,0,0,+Z,2.25,mV/N\na1,2,1,0,0,+Z,100,mV/g\n")
    out = tmp_path / "late.uff"
    assert run(["export", str(log), "--out", str(out), "--channels", str(table), "--binary"]) == 0
    said = capsys.readouterr().out
    warn = [x for x in said.splitlines() if x.startswith("warning:")]
    assert warn == ["warning: a (a1) left out of hit(s) 0: the log has not all its samples of those records"], said
    times = [x for x in uff.read_uff(out) if x["type"] == 58]
    assert sorted((x["ver_num"], x["rsp_ent_name"]) for x in times) == [(1, "hammer"), (2, "a1"), (2, "hammer")]
    a1 = next(x for x in times if x["rsp_ent_name"] == "a1")
    np.testing.assert_array_equal(a1["data"], np.arange(1290 - d, 2000 - d))  # own index = hammer index - 600
    assert a1["x"][0] == pytest.approx(1.29, rel=E13)  # on the hammer's time axis


def test_binary_58b_is_exact_and_smaller(session, tmp_path):
    ascii_, binary = tmp_path / "a.uff", tmp_path / "b.uff"
    assert run(["export", str(session), "--out", str(ascii_)]) == 0
    assert run(["export", str(session), "--out", str(binary), "--binary"]) == 0
    a, b = uff.read_uff(ascii_), uff.read_uff(binary)
    assert binary.stat().st_size < 0.45 * ascii_.stat().st_size  # 8 bytes a value against 20 characters
    for da, db in zip(a[3:], b[3:], strict=True):
        assert db["binary"] == 1 and (da["rsp_node"], da["rsp_dir"]) == (db["rsp_node"], db["rsp_dir"])
        np.testing.assert_allclose(da["data"], db["data"], rtol=E20, atol=E20 * np.abs(db["data"]).max())


def test_frfs_and_coherence_read_back_in_pyuff_and_sdypy_ema(session, tmp_path):
    """An FRFSet (analysis/frf.py) of the rig's analytic accelerance, exported with --frf: pyuff gives back every
    FRF's node/direction pair, units and values, sdypy-EMA the same FRF matrix as accelerance."""
    from sdypy import EMA

    from analysis.frf import FRFSet

    rig = open_rig("beam_ch4_exp")
    freq = np.arange(0.0, 1000.25, 0.5)
    H = _analytic_accelerance(rig, freq)
    coh = np.clip(1 - 1e-3 * np.random.default_rng(1).random(H.shape), 0, 1)
    names = [s.name for s in rig.sensors]
    FRFSet(freq=freq, H=H, coherence=coh, outputs=names, references=["hammer"], n_averages=np.array([5])).to_npz(
        tmp_path / "f.npz"
    )
    out = tmp_path / "frf.uff"
    assert run(["export", str(session), "--out", str(out), "--frf", str(tmp_path / "f.npz")]) == 0
    sets = [d for d in uff.read_uff(out) if d["type"] == 58 and d["func_type"] in (4, 6)]
    assert len(sets) == 28
    table = {c.name: c for c in rig_channels(rig)}
    frfs = [d for d in sets if d["func_type"] == 4]
    for o, d in enumerate(frfs):
        ch = table[names[o]]
        assert (d["rsp_ent_name"], d["rsp_node"], d["rsp_dir"], d["ref_node"], d["ref_dir"]) == (ch.name, ch.node, 3, 13, 3)
        assert (d["ordinate_axis_units_lab"], d["orddenom_axis_units_lab"], d["abscissa_axis_units_lab"]) == ("m/s^2", "N", "Hz")
        assert (d["ordinate_spec_data_type"], d["orddenom_spec_data_type"]) == (12, 13)
        np.testing.assert_allclose(d["data"], H[o, 0], rtol=E20, atol=E20 * np.abs(H[o, 0]).max())
        np.testing.assert_allclose(d["x"], freq, rtol=0, atol=1e-9)
    cohs = [d for d in sets if d["func_type"] == 6]
    np.testing.assert_allclose(np.array([d["data"] for d in cohs]), coh[:, 0], rtol=E20)
    model = EMA.Model(lower=5, upper=900, pol_order_high=10)
    model.read_uff(str(out))
    cut = model.freq.size
    assert model.frf_form == "accelerance" and model.frf.shape == (14, cut)
    np.testing.assert_allclose(model.freq, freq[:cut])
    np.testing.assert_allclose(model.frf, H[:, 0, :cut], rtol=E20, atol=E20 * np.abs(H).max())


def test_mode_shapes_read_back_as_pyuff_55(tmp_path):
    """FE modes (real, normal modes) and complex shapes (complex modes, eigenvalue -zeta w + i w_d) of beam_ch4_exp
    at its sensors, with one sensor mounted -Z: node, r3 with the direction's sign, frequency and damping."""
    rig = open_rig("beam_ch4_exp")
    chans = [c for c in rig_channels(rig) if c.name != "hammer"]
    chans[3] = Channel(chans[3].name, "acceleration", chans[3].node, chans[3].xyz, -3, chans[3].sensitivity)
    f = rig.modes.frequencies_hz[:6]
    zeta = np.array([0.005, 0.005, 0.004, 0.004, 0.004, 0.004])
    real = rig.modes.shapes[rig.sensor_dofs, :6]
    cplx = real * np.exp(1j * np.linspace(0.1, 0.6, 6))
    for shapes, analysis_type in ((real, 2), (cplx, 3)):
        p = tmp_path / f"modes{analysis_type}.uff"
        uff.write_uff(p, uff.mode_shape_sets(f, zeta, shapes, chans))
        back = uff.read_uff(p)
        assert [d["type"] for d in back] == [55] * 6 and {d["analysis_type"] for d in back} == {analysis_type}
        for m, d in enumerate(back):
            freq, z, nodes, r = uff.mode_from_set(d)
            assert d["mode_n"] == m + 1 and freq == pytest.approx(f[m], rel=E13) and z == pytest.approx(zeta[m], rel=2e-5)
            assert nodes.tolist() == [c.node for c in chans]
            sign = np.array([np.sign(c.direction) for c in chans])
            scale = np.abs(shapes[:, m]).max()
            np.testing.assert_allclose(r[2], sign * shapes[:, m], rtol=E13, atol=E13 * scale)
            assert np.all(r[:2] == 0)


def test_export_with_modes_json_and_a_channel_csv(session, tmp_path):
    rig = open_rig("beam_ch4_exp")
    names = [s.name for s in rig.sensors]
    shapes = rig.modes.shapes[rig.sensor_dofs, :2]
    modes = tmp_path / "modes.json"
    modes.write_text(json.dumps({"freq_hz": rig.modes.frequencies_hz[:2].tolist(), "zeta": [0.005, 0.005], "outputs": names,
                                 "shapes_re": shapes.tolist(), "shapes_im": (0.1 * shapes).tolist()}))  # fmt: skip
    csv = tmp_path / "ch.csv"
    rows = ["hammer,100,0.7,0,0,-Z,2.25,mV/N"] + [f"{n},{101 + k},{0.05 * k},0.2,0,+Y,100,mV/g" for k, n in enumerate(names[:3])]
    csv.write_text("name,node,x,y,z,direction,sensitivity,unit\n" + "\n".join(rows) + "\n")
    out = tmp_path / "m.uff"
    assert run(["export", str(session), "--out", str(out), "--modes", str(modes)]) == 0
    m55 = [d for d in uff.read_uff(out) if d["type"] == 55]
    assert len(m55) == 2 and m55[0]["analysis_type"] == 3
    np.testing.assert_allclose(m55[1]["r3"], shapes[:, 1] * (1 + 0.1j), rtol=E13, atol=E13 * np.abs(shapes).max())
    out2 = tmp_path / "c.uff"
    assert run(["export", str(session), "--out", str(out2), "--channels", str(csv)]) == 0
    sets = uff.read_uff(out2)
    assert [np.asarray(d["node_nums"]).tolist() for d in sets if d["type"] == 15] == [[100, 101, 102, 103]]
    t58 = [d for d in sets if d["type"] == 58]
    assert len(t58) == 2 * 4  # the channels the CSV names; the other 11 are left out (and said so)
    assert {(d["rsp_ent_name"], d["rsp_node"], d["rsp_dir"]) for d in t58 if d["ver_num"] == 1} == {
        ("hammer", 100, -3), ("a01", 101, 2), ("a02", 102, 2), ("a03", 103, 2)}  # fmt: skip
    assert {(d["ref_node"], d["ref_dir"]) for d in t58} == {(100, -3)}


def test_trace_lines_of_a_branched_geometry_and_a_long_chain():
    geo = make_geometry([(1, 0, 0, 0), (2, 1, 0, 0), (3, 2, 0, 0), (4, 1, 1, 0)], [(1, 2), (2, 3), (2, 4)])
    assert uff.trace_polylines(geo.lines) == [[1, 2, 3, 0, 2, 4]]
    assert uff.trace_pairs([1, 2, 3, 0, 2, 4]) == [(1, 2), (2, 3), (2, 4)]
    ids = list(range(1, 601))
    chain = make_geometry([(i, float(i), 0, 0) for i in ids], [(a, a + 1) for a in ids[:-1]])
    polys = uff.trace_polylines(chain.lines)
    assert all(len(p) <= uff.MAX_TRACE_NODES for p in polys) and len(polys) == 3
    assert [pair for p in polys for pair in uff.trace_pairs(p)] == [(a, a + 1) for a in ids[:-1]]


def test_export_refusals_are_one_line(session, tmp_path, capsys):
    assert run(["export", str(session), "--format", "csv", "--out", str(tmp_path / "x")]) == 2
    bad_modes = tmp_path / "bad.json"
    bad_modes.write_text(json.dumps({"freq_hz": [20.0], "zeta": [0.01], "outputs": ["nope"], "shapes_re": [[1.0]]}))
    assert run(["export", str(session), "--out", str(tmp_path / "y.uff"), "--modes", str(bad_modes)]) == 2
    bad_csv = tmp_path / "bad.csv"
    bad_csv.write_text("name,node,x,y,z,direction,sensitivity,unit\nhammer,1,0,0,0,+Q,2.25,mV/N\n")
    assert run(["export", str(session), "--out", str(tmp_path / "z.uff"), "--channels", str(bad_csv)]) == 2
    assert run(["export", str(session), "--out", str(session), "--overwrite"]) == 2  # never over its own input
    lines = [x for x in capsys.readouterr().err.splitlines() if x]
    assert len(lines) == 4 and all(x.startswith("gvt: error: ") for x in lines)
    assert "--format must be uff" in lines[0] and "outputs ['nope'] are not in the channel table" in lines[1]
    assert f"{bad_csv}:2: column 'direction'" in lines[2] and "that is the input file" in lines[3]
    assert not list(tmp_path.glob("*.uff")) and not list(tmp_path.glob(".*.part"))
    with pytest.raises(uff.UffError, match="NaN"):
        uff.time_sets(np.array([[0.0], [np.nan]]), 100.0, [Channel("a", "acceleration", 1, (0, 0, 0), 3)],
                      Channel("h", "force", 1, (0, 0, 0), 3))  # fmt: skip
