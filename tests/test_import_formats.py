"""``gvt import`` readers of CSV, NI TDMS and SEP005-in-HDF5 (issue 31): exact imports and one-line refusals.

Oracles: the samples a file was written from (by gvtlink's own ``gvt log export``, by npTDMS's ``TdmsWriter``, by
h5py), converted with the units' defining factors written out here (g = 9.80665 m/s^2 and lbf = 0.45359237 kg x
g = 4.4482216152605 N, ISO 80000-3 / NIST SP 811; mm = 1e-3 m). Equality is exact (``np.array_equal`` on float64):
a reader that parses, casts or scales differently is off by at least one ulp somewhere in a thousand samples.
"""

from __future__ import annotations

import csv as pycsv
from pathlib import Path

import h5py
import numpy as np
import pytest
from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

from daq.log.export import export
from daq.log.reader import LogReader
from daq.studies.importing import csv, hdf5, tdms
from daq.studies.importing.data import ImportError_

ROOT = Path(__file__).resolve().parents[1]
LOG = ROOT / "replay_logs" / "two_dof_3hits.mcap"  # the seed's 2-DOF system, 3 hits, 9005 samples x 3 channels
G, LBF = 9.80665, 4.4482216152605
RNG = np.random.default_rng(31)


def refused(fn, *args, **kw) -> str:
    """The one line a reader refuses with (exit 2)."""
    with pytest.raises(ImportError_) as info:
        fn(*args, **kw)
    line = str(info.value)
    assert info.value.exit_code == 2 and "\n" not in line and "Traceback" not in line
    return line


# --- CSV ----------------------------------------------------------------------------------------------------------
def test_gvt_log_export_csv_imports_back_exactly(tmp_path):
    out = tmp_path / "two_dof.csv"
    export(LOG, out, "csv")
    got = csv.read(out)
    r = LogReader(LOG)
    info = r.streams()["dev0"]
    want = r.read_stream("dev0")
    assert [c.name for c in got.channels] == list(want.channels) == ["hammer", "x1", "x2"]
    assert got.source_units == list(info.units) and [c.unit for c in got.channels] == list(info.units)  # N, m, m
    assert got.fs == info.sample_rate == 50.0 and got.t0_s == 0.0
    assert np.array_equal(got.samples, want.data.astype(np.float64))  # every float32 back, bit for bit
    assert got.provenance.format == "csv" and got.provenance.writer.startswith("gvtlink")
    assert len(got.provenance.sha256) == 64


def test_two_device_export_imports_the_rows_both_devices_have(tmp_path):
    """The format 1 two-device session: acc_daq starts 3885 samples after hammer_daq (docs/log-format.md, "Time
    base"); its export has empty cells at both ends. The import keeps the rows where both have samples, exactly."""
    log, out = ROOT / "tests" / "data" / "format1" / "two_devices.mcap", tmp_path / "two.csv"
    export(log, out, "csv", channels=["hammer", "a01", "a14"])  # three of the 15 channels: the export's text is the cost
    got = csv.read(out)
    r = LogReader(log)
    ham, acc = r.read_stream("hammer_daq"), r.read_stream("acc_daq", ["a01", "a14"])
    d = 3885  # the offset the log's timeline records
    assert got.samples.shape == (ham.data.shape[0] - d, 3) and got.t0_s == d / 16384
    assert np.array_equal(got.samples[:, 0], ham.data[d:, 0].astype(np.float64))
    assert np.array_equal(got.samples[:, 1:], acc.data[:-d].astype(np.float64))
    said = " | ".join(got.provenance.assumptions)
    assert "3885 row(s) before line 3887 lack a01, a14" in said and "3885 row(s) after line 32769 lack hammer" in said


def _write(path: Path, rows: list[list[str]]) -> Path:
    with open(path, "w", newline="") as fh:
        pycsv.writer(fh).writerows(rows)
    return path


def test_generic_csv_units_and_channel_table(tmp_path, monkeypatch):
    monkeypatch.setattr(csv, "CHUNK_ROWS", 7)  # rows cross several chunks (the streaming path), one with an empty cell
    n, fs = 40, 2000.0
    acc, ham, volts = RNG.standard_normal(n), 100 * RNG.standard_normal(n), RNG.standard_normal(n)
    rows = [["time [ms]", "acc [g]", "ham [lbf]", "v [mV]"]]
    rows += [[repr(1e3 * k / fs), *(repr(float(x[k])) for x in (acc, ham, volts))] for k in range(n)]
    for r in (1, 2, 3):
        rows[r][1] = ""  # acc starts 3 rows late (a two-device export's empty cells): those rows are not imported
    src = _write(tmp_path / "lab.csv", rows)
    table = tmp_path / "table.csv"
    table.write_text("name,node,x,y,z,direction,sensitivity,unit\nham,1,0,0,0,-Z,2.25,mV/N\n"
                     "acc,2,0.5,0,0,+Z,100,mV/g\nv,3,1.0,0,0,+Y,100,mV/g\n")  # fmt: skip
    got = csv.read(src, table)
    assert got.fs == fs and got.t0_s == 3 / fs and got.source_units == ["g", "lbf", "mV"]
    assert np.array_equal(got.samples[:, 0], acc[3:] * G) and np.array_equal(got.samples[:, 1], ham[3:] * LBF)
    # volts over the table's 100 mV/g = 0.1 V / 9.80665 (m/s^2): 2 roundings (pint, the division), 1e-15 relative
    assert np.allclose(got.samples[:, 2], volts[3:] * 1e-3 / (0.1 / G), rtol=1e-15, atol=0)
    assert [(c.name, c.quantity, c.node, c.direction) for c in got.channels] == [
        ("acc", "acceleration", 2, 3), ("ham", "force", 1, 1 * -3), ("v", "acceleration", 3, 2)]  # fmt: skip
    assert any("3 row(s) before line 5 lack acc (empty cells)" in a for a in got.provenance.assumptions)
    cr = tmp_path / "cr.csv"  # bare CR line ends: the row count from newlines is 0, the table grows as rows come
    cr.write_bytes(src.read_bytes().replace(b"\r\n", b"\r"))
    assert np.array_equal(csv.read(cr, table).samples, got.samples)


@pytest.mark.parametrize(
    ("rows", "where", "words"),
    [
        ([["t [s]", "a [g]"], ["0", "1"], ["0.001", "2", "3"]], ":3:", "3 fields but the header has 2 columns"),
        ([["t [s]", "a [g]"], ["0", "1"], ["0.001", "2"], ["0.002", "x7"]], ":4:", "column 'a [g]': 'x7' is not a number"),
        ([["t [s]", "a [g]"], ["0", "1"], ["0.001", "2"], ["0.003", "2"], ["0.004", "2"]], ":4:", "time column breaks"),
        ([["t [s]", "a"], ["0", "1"], ["0.001", "2"]], "", "channel 'a' has no unit"),
        ([["t [s]", "a [bananas]"], ["0", "1"], ["0.001", "2"]], "", "'bananas', which pint does not know"),
        ([["t [s]", "p [Pa]"], ["0", "1"], ["0.001", "2"]], "", "not an acceleration, velocity, displacement, force"),
        ([["a [g]"], ["1"], ["2"]], "", "no time column"),
        ([["t [s];a [g]"], ["0;1,5"], ["0,001;2"]], ":1:", "separated by semicolons, not commas"),
        ([["t [s]", "a [g]"], ["0", "1"], ["0.001", ""], ["0.002", "2"]], ":3:", "column 'a' is empty inside the record"),
    ],
)
def test_csv_bad_input_is_one_line_naming_the_line(tmp_path, monkeypatch, rows, where, words):
    monkeypatch.setattr(csv, "CHUNK_ROWS", 2)  # the bad row may sit in any chunk
    src = _write(tmp_path / "bad.csv", rows)
    line = refused(csv.read, src)
    assert line.startswith(f"{src}{where}") and words in line, line


def test_gvt_export_with_a_gap_is_refused_at_its_line(tmp_path):
    out = tmp_path / "two_dof.csv"
    export(LOG, out, "csv")
    lines = out.read_text().splitlines(keepends=True)
    out.write_text("".join(lines[:101] + lines[102:]))  # row of index 100 (file line 102) removed
    assert refused(csv.read, out).startswith(f"{out}:102: index goes from 99 to 101")


# --- TDMS ---------------------------------------------------------------------------------------------------------
def _tdms(path: Path, *objects) -> Path:
    with TdmsWriter(path) as w:
        w.write_segment([RootObject(properties={"author": "FlexLogger"}), *objects])
    return path


def test_tdms_written_by_nptdms_imports_exactly(tmp_path):
    n, inc = 1000, 1 / 51200
    acc = RNG.standard_normal(n).astype(np.float32)
    ham = (100 * RNG.standard_normal(n)).astype(np.float32)
    disp = RNG.integers(-3000, 3000, n).astype(np.int16)
    src = _tdms(tmp_path / "hits.tdms", GroupObject("Hits"),
                ChannelObject("Hits", "acc", acc, properties={"wf_increment": inc, "wf_start_offset": 0.25,
                                                              "unit_string": "g", "NI_ChannelName": "cDAQ1Mod1/ai0"}),
                ChannelObject("Hits", "ham", ham, properties={"wf_increment": inc, "unit_string": "lbf"}),
                ChannelObject("Hits", "disp", disp, properties={"wf_increment": inc, "unit_string": "mm"}))  # fmt: skip
    got = tdms.read(src)
    assert got.fs == 51200.0 and got.t0_s == 0.25 and [c.name for c in got.channels] == ["acc", "ham", "disp"]
    assert np.array_equal(got.samples[:, 0], acc.astype(np.float64) * G)
    assert np.array_equal(got.samples[:, 1], ham.astype(np.float64) * LBF)
    assert np.array_equal(got.samples[:, 2], disp.astype(np.float64) * 1e-3)
    assert got.provenance.writer == "FlexLogger" and got.source_units == ["g", "lbf", "mm"]
    assert any("cDAQ1Mod1/ai0" in a for a in got.provenance.assumptions)


def test_tdms_time_channel_groups_and_no_time_track(tmp_path):
    n = 300
    t = np.arange(n) / 1000.0
    a, b = RNG.standard_normal(n), RNG.standard_normal(2 * n)
    src = _tdms(tmp_path / "two.tdms", GroupObject("slow"), ChannelObject("slow", "Time", t, properties={"unit_string": "s"}),
                ChannelObject("slow", "a", a, properties={"unit_string": "m/s^2"}), GroupObject("fast"),
                ChannelObject("fast", "b", b, properties={"unit_string": "N", "wf_increment": 1 / 2000}))  # fmt: skip
    line = refused(tdms.read, src)
    assert "'slow' (1 ch, 1000 Hz" in line and "'fast' (1 ch, 2000 Hz" in line and "--group" in line
    got = tdms.read(src, group="slow")  # the rate from the time channel; the other group named as not imported
    assert got.fs == 1000.0 and np.array_equal(got.samples[:, 0], a) and [c.name for c in got.channels] == ["a"]
    assert any("not imported (--group slow): 'fast' (1 ch)" in x for x in got.provenance.assumptions)
    env = [ChannelObject("env", "T", np.ones(1), properties={"unit_string": "degC"}),
           ChannelObject("env", "p", np.ones(4), properties={"unit_string": "Pa"})]  # fmt: skip
    acc = ChannelObject("acc", "a", a, properties={"unit_string": "g", "wf_increment": 1e-3})
    mixed = _tdms(tmp_path / "mixed.tdms", GroupObject("acc"), acc, GroupObject("env"), *env)
    line = refused(tdms.read, mixed)  # an environment group beside the data, as a monitoring DAQ writes them
    assert "group 'env' has channels of different lengths (1 of 1 samples, 1 of 4 samples)" in line
    assert "--group NAME; groups: 'acc', 'env'" in line
    assert tdms.read(mixed, group="acc").samples.shape == (n, 1)
    same = _tdms(tmp_path / "same.tdms", *(o for g in ("g1", "g2") for o in (
        GroupObject(g), ChannelObject(g, "a", a, properties={"unit_string": "N", "wf_increment": 1e-3}))))  # fmt: skip
    assert [c.name for c in tdms.read(same).channels] == ["g1/a", "g2/a"]  # one grid: both groups, names told apart
    stamps = np.datetime64("2026-11-28T10:00:00", "ns") + (np.arange(n) * 1_000_000).astype("timedelta64[ns]")
    ts = _tdms(tmp_path / "ts.tdms", GroupObject("g"), ChannelObject("g", "Timestamp", stamps),
               ChannelObject("g", "a", a, properties={"unit_string": "m/s^2"}))  # fmt: skip
    got = tdms.read(ts)  # NI timestamps as the time track: 1 ms apart
    assert got.fs == 1000.0 and got.t0_s == 0.0 and any("2026-11-28T10:00:00" in x for x in got.provenance.assumptions)
    bare = _tdms(tmp_path / "bare.tdms", GroupObject("g"), ChannelObject("g", "a", a, properties={"unit_string": "g"}))
    assert "group 'g' has no time information" in refused(tdms.read, bare)
    nounit = _tdms(tmp_path / "nounit.tdms", GroupObject("g"), ChannelObject("g", "a", a, properties={"wf_increment": 1e-3}))
    assert "channel 'a' has no unit" in refused(tdms.read, nounit)
    assert "not a readable TDMS file" in refused(tdms.read, LOG)


# --- HDF5 (SEP005) ------------------------------------------------------------------------------------------------
def test_hdf5_sep005_written_by_h5py_imports_exactly(tmp_path):
    n = 1000
    acc, ham = RNG.standard_normal(n).astype(np.float32), 50 * RNG.standard_normal(n)
    src = tmp_path / "sep005.h5"
    with h5py.File(src, "w", track_order=True) as f:
        f.attrs["writer"] = "sep005 test"
        g = f.create_group("ch_z")  # created first, named last: creation order rules
        g["data"] = acc
        g.attrs.update(name="acc", unit_str="g", fs=2048.0, start_timestamp="2026-11-28T10:00:00+00:00", quantity="acceleration")
        f["hammer"] = ham  # a channel as a dataset with its fields as attributes
        f["hammer"].attrs.update(unit_str="N", fs=2048)
        f["notes"] = np.arange(3)  # not a channel: said, not imported
    got = hdf5.read(src)
    assert got.fs == 2048.0 and [c.name for c in got.channels] == ["acc", "hammer"] and got.provenance.writer == "sep005 test"
    assert np.array_equal(got.samples[:, 0], acc.astype(np.float64) * G) and np.array_equal(got.samples[:, 1], ham)
    said = " | ".join(got.provenance.assumptions)
    assert "creation order" in said and "2026-11-28T10:00:00+00:00" in said and "['notes']" in said


def test_hdf5_sep005_time_vector_and_bad_files(tmp_path):
    n = 200
    t, v = 0.5 + np.arange(n) / 512.0, RNG.standard_normal(n)
    src = tmp_path / "time.h5"
    with h5py.File(src, "w") as f:
        f.create_group("v")
        f["v/data"], f["v/time"] = v, t
        f["v"].attrs["unit_str"] = np.array([b"mm/s"])  # a 1-element array of bytes, as MATLAB writes a string
    got = hdf5.read(src)
    assert got.fs == 512.0 and got.t0_s == 0.5 and np.array_equal(got.samples[:, 0], v * 1e-3)
    with h5py.File(src, "a") as f:
        f.create_group("w")
        f["w/data"] = v[:100]
        f["w"].attrs.update(unit_str="N", fs=np.array([512.0]))
    assert "channels on different grids" in refused(hdf5.read, src)
    with h5py.File(src, "w") as f:
        f["x"] = v
        f["x"].attrs["unit_str"] = "g"
    assert "channel 'x' has neither fs nor time" in refused(hdf5.read, src)
    assert "not a readable HDF5 file" in refused(hdf5.read, LOG)


# --- through `gvt import` -----------------------------------------------------------------------------------------
def test_gvt_import_round_trip_and_bad_input_through_the_cli(tmp_path, capsys):
    from daq.cli import run

    src, out = tmp_path / "two_dof.csv", tmp_path / "back.mcap"
    export(LOG, src, "csv")
    assert run(["import", str(src), "-o", str(out)]) == 0
    back, orig = LogReader(out), LogReader(LOG)
    assert np.array_equal(back.read_stream("import").data, orig.read_stream("dev0").data)  # float32 log -> log, exact
    assert back.streams()["import"].units == orig.streams()["dev0"].units
    assert back.streams()["import"].sample_rate == 50.0
    bad_csv = _write(tmp_path / "bad.csv", [["t [s]", "a [g]"], ["0", "1"], ["0.001", "2", "3"]])
    bare = _tdms(tmp_path / "bare.tdms", GroupObject("g"), ChannelObject("g", "a", np.ones(9), properties={"unit_string": "g"}))
    for bad, words in ((bad_csv, f"{bad_csv}:3: 3 fields"), (bare, "has no time information")):
        capsys.readouterr()
        code = run(["import", str(bad), "-o", str(tmp_path / "x.mcap")])
        err = capsys.readouterr().err.strip()
        assert code == 2 and err.startswith("gvt: error: ") and words in err and len(err.splitlines()) == 1, err
        assert not (tmp_path / "x.mcap").exists() and not list(tmp_path.glob("*x.mcap*"))  # nothing written
    assert run(["import", str(bare), "-o", str(tmp_path / "x.mcap"), "--rate", "100"]) == 0  # the stated rate
