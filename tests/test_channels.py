"""Channel table and test geometry (issue 20 item 6): sensitivities converted by pint, CSV import with one-line
errors, rigs' optional node/direction/sensitivity fields and [geometry] table, default geometry of beam rigs.

Oracles: standard gravity g_n = 9.80665 m/s^2 and 1 lbf = 4.4482216152605 N are exact by definition (ISO 80000-3,
NIST SP 811 B.8), so every conversion below is checked to 1e-12 relative (rounding only)."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
import pytest

from analysis.model.channels import ChannelTableError, read_channel_csv, rig_channels
from analysis.model.geometry import rig_geometry
from analysis.model.loader import ConfigError
from analysis.model.rig import load_rig
from analysis.model.rigs import open_rig
from analysis.model.units import parse_direction, parse_sensitivity

G_N = 9.80665
LBF = 4.4482216152605
HEADER = "name,node,x,y,z,direction,sensitivity,unit,gain\n"


def _csv(tmp_path: Path, body: str, header: str = HEADER) -> Path:
    p = tmp_path / "channels.csv"
    p.write_text(header + textwrap.dedent(body).lstrip())
    return p


def test_csv_with_mixed_units_converts_exactly(tmp_path):
    p = _csv(
        tmp_path,
        """
        hammer,13,0.7,0,0,-Z,2.25,mV/N,
        a01,1,0.056,0,0,+Z,100,mV/g,
        a02,2,0.105,0.01,0,z,1.02,mV/(m/s²),
        a03,3,0.161,0,0,Y-,1.02,mV/(m/s^2),
        f2,20,0.2,0,0,X,10,pC/N,1 mV/pC
        lbf,21,0.3,0,0,+x,11.2,mV/lbf,
        v1,22,0.4,0,0,+Y,20,mV/(mm/s),
        d1,23,0.5,0,0,-X,5,V/mm,
        c1,24,0.6,0,0,+Z,10,pC/g,10 mV/pC
        """,
    )
    t = {c.name: c for c in read_channel_csv(p)}
    assert t["a01"].sensitivity == pytest.approx(0.1 / G_N, rel=1e-12)
    assert t["a01"].sensitivity_mv_per_unit == pytest.approx(10.197162129779283, rel=1e-12)  # the 10.197 mV/(m/s^2)
    assert t["a02"].sensitivity == t["a03"].sensitivity == pytest.approx(1.02e-3, rel=1e-12)
    assert t["hammer"].sensitivity == pytest.approx(2.25e-3, rel=1e-12) and t["hammer"].quantity == "force"
    assert t["f2"].sensitivity == pytest.approx(10e-3, rel=1e-12) and t["f2"].quantity == "force"  # 10 pC/N x 1 mV/pC
    assert t["lbf"].sensitivity == pytest.approx(11.2e-3 / LBF, rel=1e-12)
    assert t["v1"].sensitivity == pytest.approx(20.0, rel=1e-12) and t["v1"].quantity == "velocity"  # 20 mV/(mm/s) = 20 V/(m/s)
    assert t["d1"].sensitivity == pytest.approx(5e3, rel=1e-12) and t["d1"].quantity == "displacement"
    assert t["c1"].sensitivity == pytest.approx(0.1 / G_N, rel=1e-12) and t["c1"].quantity == "acceleration"
    assert [t[n].direction for n in ("hammer", "a01", "a02", "a03", "f2", "lbf", "d1")] == [-3, 3, 3, -2, 1, 1, -1]
    assert t["a02"].xyz == (0.105, 0.01, 0.0) and t["a02"].node == 2 and t["a01"].unit == "m/s^2"


@pytest.mark.parametrize(
    ("row", "expect"),
    [
        ("a01,1,0,0,0,+W,100,mV/g,", "column 'direction': '+W' is not a direction; use one of +X"),
        ("a01,1,0,0,0,+Z,100,mV/kg,", "column 'unit': 'mV/kg' is not volts"),
        ("a01,1,0,0,0,+Z,100,mV/(m/s,", "column 'unit': unit 'mV/(m/s' is not understood"),
        ("a01,1,0,0,0,+Z,abc,mV/g,", "column 'sensitivity': 'abc' is not a number"),
        ("a01,0,0,0,0,+Z,100,mV/g,", "column 'node': '0' is not a node id"),
        ("a01,1,0,zero,0,+Z,100,mV/g,", "column 'y': 'zero' is not a number (m)"),
        ("a01,1,0,0,0,+Z,10,pC/N,", "charge sensitivity; give the charge amplifier's gain"),
        ("a01,1,0,0,0,+Z,100,mV/g,1 mV/pC", "applies to a charge sensitivity"),
        ("a01,1,0,0,0,+Z,-100,mV/g,", "must be positive"),
    ],
)
def test_a_bad_row_is_one_line_naming_file_line_and_fix(tmp_path, row, expect):
    p = _csv(tmp_path, f"a00,9,0,0,0,+Z,100,mV/g,\n{row}\n")
    with pytest.raises(ChannelTableError) as exc:
        read_channel_csv(p)
    msg = str(exc.value)
    assert msg.startswith(f"{p}:3: ") and "\n" not in msg
    assert expect in msg
    assert exc.value.exit_code == 2


def test_table_level_errors(tmp_path):
    with pytest.raises(ChannelTableError, match=r":1: header lacks column\(s\) \['direction'\]"):
        read_channel_csv(_csv(tmp_path, "a01,1,0,0,0,100,mV/g\n", header="name,node,x,y,z,sensitivity,unit\n"))
    with pytest.raises(ChannelTableError, match=r":3: channel 'a01' is already on line 2"):
        read_channel_csv(_csv(tmp_path, "a01,1,0,0,0,+Z,100,mV/g,\na01,2,0,0,0,+Z,100,mV/g,\n"))
    with pytest.raises(ChannelTableError, match="no channels"):
        read_channel_csv(_csv(tmp_path, ""))
    with pytest.raises(ChannelTableError, match="cannot read"):
        read_channel_csv(tmp_path / "missing.csv")
    p = _csv(tmp_path, "a01,1,0,0,0,+Z,100,mV/g,,acceleration\n", header=HEADER.strip() + ",quantity\n")
    assert read_channel_csv(p)[0].quantity == "acceleration"
    p = _csv(tmp_path, "a01,1,0,0,0,+Z,100,mV/g,,force\n", header=HEADER.strip() + ",quantity\n")
    with pytest.raises(ChannelTableError, match="column 'quantity' says 'force' but the unit 'mV/g' is of acceleration"):
        read_channel_csv(p)


def test_direction_spellings():
    assert [parse_direction(s) for s in ("+X", "x", "X+", "-Y", "\u2212y", "y-", " +z ", "-Z")] == [1, 1, 1, -2, -2, -2, 3, -3]
    for bad in ("", "W", "+-Z", "XY", "4"):
        with pytest.raises(ValueError, match="use one of"):
            parse_direction(bad)
    assert parse_sensitivity("100 mV/g") == pytest.approx((0.1 / G_N, "acceleration"))


def test_beam_rig_default_geometry_and_channels():
    """beam_ch4_exp: a node per sensor at its model x, lines between neighbours, the hammer on a13's node (both at
    0.700 m), +Z everywhere, sensitivities as the rig file states them (1.02 mV/(m/s^2), 2.25 mV/N)."""
    rig = open_rig("beam_ch4_exp")
    geo = rig_geometry(rig)
    xs = [s.x for s in rig.config.sensors]
    assert geo.ids.tolist() == list(range(1, 15))
    np.testing.assert_allclose(geo.xyz[:, 0], xs, atol=1e-12)  # the sensors sit on 7 mm mesh nodes (docs/rigs.md)
    assert np.all(geo.xyz[:, 1:] == 0)
    assert geo.lines.tolist() == [[k, k + 1] for k in range(1, 14)]
    ch = {c.name: c for c in rig_channels(rig)}
    assert ch["hammer"].node == ch["a13"].node == 13 and ch["hammer"].quantity == "force"
    assert all(c.direction == 3 for c in ch.values())
    assert ch["a01"].sensitivity == pytest.approx(1.02e-3) and ch["hammer"].sensitivity == pytest.approx(2.25e-3)
    lumped = {c.name: c for c in rig_channels(open_rig("two_dof"))}
    assert [lumped[n].node for n in ("hammer", "x1", "x2")] == [1, 1, 2] and lumped["x2"].direction == 1


FRAME = """
name = "frame"
[structure]
kind = "beam"
length = 1.0
width = 0.04
height = 0.01
youngs_modulus = 200e9
density = 7850.0
elements = 10

[hammer]
x = 1.0
node = 30
sensitivity = "{hammer_sens}"
direction = "-Z"
pulse_duration = 0.001
peak_force = 100.0

[[sensors]]
name = "a1"
x = 0.5
node = 20
sensitivity = "{a1_sens}"
direction = "{a1_dir}"

[[sensors]]
name = "a2"
x = 1.0
node = {a2_node}
sensitivity_mv_per_unit = 1.02
direction = "+Y"

[daq]
sample_rate = 4096.0

[geometry]
nodes = [{{id = 10, x = 0.0}}, {{id = 20, x = 0.5, y = 0.0, z = 0.3}},
         {{id = 30, x = 0.5, y = 0.4, z = 0.3}}, {{id = 40, x = 0.9}}]
lines = [[10, 20], [20, 30], [20, 40]]
"""


def _frame(tmp_path: Path, **kw: str) -> Path:
    fields = {"hammer_sens": "11.2 mV/lbf", "a1_sens": "100 mV/g", "a1_dir": "-Z", "a2_node": "30", **kw}
    p = tmp_path / "frame.toml"
    p.write_text(FRAME.format(**fields))
    return p


def test_rig_with_geometry_table_sensitivity_text_and_directions(tmp_path):
    """A beam FE model whose test geometry is a bent frame: the channels take their nodes' 3-D coordinates."""
    rig = load_rig(_frame(tmp_path))
    assert rig.sensors[0].props.sensitivity_mv_per_unit == pytest.approx(100 / G_N, rel=1e-12)
    assert rig.config.hammer.sensitivity_mv_per_unit == pytest.approx(11.2 / LBF, rel=1e-12)
    geo = rig_geometry(rig)
    assert geo.ids.tolist() == [10, 20, 30, 40] and geo.lines.tolist() == [[10, 20], [20, 30], [20, 40]]
    ch = {c.name: c for c in rig_channels(rig)}
    assert ch["a1"].xyz == (0.5, 0.0, 0.3) and ch["a1"].direction == -3
    assert ch["a2"].xyz == (0.5, 0.4, 0.3) and ch["a2"].direction == 2 and ch["hammer"].node == 30
    assert ch["hammer"].sensitivity == pytest.approx(11.2e-3 / LBF, rel=1e-12)


@pytest.mark.parametrize(
    ("kw", "field", "expect"),
    [
        (
            {"a1_sens": "2 mV/N"},
            "sensors[0].sensitivity",
            "'2 mV/N' is a sensitivity to force, but this channel measures acceleration",
        ),
        ({"a1_sens": "100 mV/kg"}, "sensors[0].sensitivity", "is not volts (or charge) per acceleration"),
        ({"a1_sens": "10 pC/g"}, "sensors[0].sensitivity", "give the charge amplifier's gain"),
        ({"hammer_sens": "100 mV/g"}, "hammer.sensitivity", "is a sensitivity to acceleration, but this channel measures force"),
        ({"a1_dir": "+Q"}, "sensors[0].direction", "'+Q' is not a direction; use one of +X"),
        ({"a2_node": "99"}, "sensors[1].node", "node 99 is not among the [geometry] nodes"),
    ],
)
def test_bad_channel_fields_in_a_rig_are_one_line(tmp_path, kw, field, expect):
    with pytest.raises(ConfigError) as exc:
        load_rig(_frame(tmp_path, **kw))
    msg = str(exc.value)
    assert "\n" not in msg and expect in msg, msg
    assert f"frame.toml: {field}: " in msg and exc.value.exit_code == 2
