"""Rig configs: the shipped rigs load; bad files give one line, exit 2, no traceback."""

from __future__ import annotations

import subprocess
import tomllib
from pathlib import Path

import pytest
import tomli_w
from hypothesis import given
from hypothesis import strategies as st

from analysis.model.config import RigConfig
from analysis.model.loader import ConfigError, validate
from analysis.model.rig import load_rig
from daq.cli import run

from .conftest import RIGS, gvt_command

SHIPPED = sorted(p.stem for p in RIGS.glob("*.toml"))


def test_the_four_rigs_ship():
    assert {"beam_ch3", "beam_ch4_sim", "beam_ch4_exp", "two_dof"} <= set(SHIPPED)


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_rigs_load(name):
    rig = load_rig(RIGS / f"{name}.toml")
    assert rig.sensors and rig.sample_rate > 0


def test_exp_rig_sensor_layout(rigs):
    rig = rigs("beam_ch4_exp")
    assert len(rig.sensors) == 14
    xs = [s.x_model for s in rig.sensors]
    assert xs == sorted(xs) and xs[-1] == pytest.approx(0.749) and 0.7 in [round(x, 6) for x in xs]
    assert all(abs(s.x_model - s.x_requested) < 1e-9 for s in rig.sensors)  # every sensor sits on a node
    assert rig.hammer.x_model == pytest.approx(0.7)
    assert all(s.props.sensitivity_mv_per_unit == pytest.approx(1.02) for s in rig.sensors)


def _base() -> dict:
    return tomllib.loads((RIGS / "beam_ch4_exp.toml").read_text())


def _mutations():
    def neg_length(d):
        d["structure"]["length"] = -1.0

    def sensor_off(d):
        d["sensors"][3]["x"] = 1.2

    def zero_rate(d):
        d["daq"]["sample_rate"] = 0.0

    def short_pulse(d):
        d["hammer"]["pulse_duration"] = 1e-4

    def unknown_key(d):
        d["hammer"]["colour"] = "red"

    def unknown_top(d):
        d["sensorz"] = []

    def wrong_type(d):
        d["structure"]["elements"] = "many"

    def bad_law(d):
        d["nonlinear_springs"][0]["law"] = "quintic"

    return [
        ("negative length", neg_length, "structure.length", "greater than 0"),
        ("sensor off the beam", sensor_off, "sensors[3].x", "off the beam"),
        ("non-positive sample rate", zero_rate, "daq.sample_rate", "greater than 0"),
        ("pulse shorter than two samples", short_pulse, "hammer.pulse_duration", "shorter than two samples"),
        ("unknown key", unknown_key, "hammer.colour", "unknown key"),
        ("unknown top-level key", unknown_top, "sensorz", "unknown key"),
        ("wrong type", wrong_type, "structure.elements", "integer"),
        ("unknown law", bad_law, "nonlinear_springs[0].law", "cubic"),
    ]


@pytest.mark.parametrize(("label", "mutate", "path", "text"), _mutations(), ids=[m[0] for m in _mutations()])
def test_bad_config_gives_one_line_and_exit_2(tmp_path, capsys, label, mutate, path, text):
    data = _base()
    mutate(data)
    f = tmp_path / "bad.toml"
    f.write_bytes(tomli_w.dumps(data).encode())
    line = _one_line(capsys, run(["model", "modes", str(f)]))
    assert str(f) in line and path in line and text in line, line


def _one_line(capsys, code: int) -> str:
    """In-process ``gvt`` (``daq.cli.run``, which maps every error to the line and code the console script gives;
    a real process is run once, in test_missing_file): exit 2, one stderr line, nothing on stdout."""
    out, err = capsys.readouterr()
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2 and len(lines) == 1 and "Traceback" not in err and out == "", (code, out, err)
    return lines[0]


@pytest.mark.parametrize(
    ("content", "text"),
    [(b"name = \n", "invalid TOML"), (b"\xff\xfe\x00garbage", "not UTF-8"), (b"", "required key is missing")],
)
def test_unparseable_files_give_one_line(tmp_path, capsys, content, text):
    f = tmp_path / "x.toml"
    f.write_bytes(content)
    assert text in _one_line(capsys, run(["model", "modes", str(f)]))


def test_missing_file(tmp_path):
    proc = subprocess.run(
        [*gvt_command(), "model", "modes", str(tmp_path / "nope.toml")], capture_output=True, text=True, timeout=60
    )
    # the one real process of this file: the console script's exit code and stderr as a shell sees them
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert proc.returncode == 2 and len(lines) == 1 and "file not found" in lines[0] and "Traceback" not in proc.stderr


# --- fuzz: whatever a user writes, the loader answers with a ConfigError or a valid config ----------

_leaf = st.one_of(st.none(), st.booleans(), st.integers(-(10**6), 10**6), st.floats(allow_nan=True), st.text(max_size=8))


def _set_path(d: dict, keys: list, value) -> None:
    cur = d
    for k in keys[:-1]:
        if isinstance(cur, dict):
            cur = cur[k]
        elif isinstance(cur, list) and cur and isinstance(k, int):
            cur = cur[k % len(cur)]
        else:
            raise KeyError(k)  # an earlier edit replaced this container: nothing to set
    if isinstance(cur, dict):
        cur[keys[-1]] = value
    elif isinstance(cur, list) and cur and isinstance(keys[-1], int):
        cur[keys[-1] % len(cur)] = value


def _paths(obj, prefix=()):
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield (*prefix, k)
            yield from _paths(v, (*prefix, k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield (*prefix, i)
            yield from _paths(v, (*prefix, i))


BASE_PATHS = list(_paths(_base()))


@given(st.lists(st.tuples(st.sampled_from(BASE_PATHS), _leaf), min_size=1, max_size=4))
def test_fuzz_config_mutations_never_escape_as_other_exceptions(edits):
    data = _base()
    for path, value in edits:
        try:
            _set_path(data, list(path), value)
        except (KeyError, TypeError, IndexError, ValueError):
            continue
    try:
        cfg = validate(RigConfig, data, "fuzz.toml")
    except ConfigError as exc:
        msg = str(exc)
        assert msg.startswith("fuzz.toml") and "\n" not in msg
        return
    from analysis.model.rig import build_rig

    try:
        build_rig(cfg)
    except ValueError:  # e.g. a sensor snapped onto the clamp: load_rig turns this into a ConfigError
        pass


def test_a_beam_beyond_floating_point_is_one_line_not_an_overflow(tmp_path):
    """Found by the fuzz test beside 4 hogs (make test-loaded at 017033b): a height of 5.6e102 m passed the schema
    (positive) and the beam's assembly raised OverflowError (a float power past 1e308), which no caller expects; now a
    ValueError, so load_rig's one-line ConfigError. A beam whose matrices overflow to inf (1e100 m: the power is
    finite, the stiffness is not) says the same."""
    from analysis.model.rig import build_rig

    for field, value in (("height", 5.643803094122362e102), ("height", 1e100)):
        data = _base()
        data["structure"][field] = value
        with pytest.raises(ValueError, match="beyond floating point"):
            build_rig(validate(RigConfig, data, "fuzz.toml"))


def test_sensor_on_the_clamp_is_a_config_error(tmp_path):
    data = _base()
    data["sensors"][0]["x"] = 0.001
    f = tmp_path / "clamp.toml"
    f.write_bytes(tomli_w.dumps(data).encode())
    with pytest.raises(ConfigError, match=r"clamp\.toml: sensors\[0\]\.x: a01 at x = 0\.001 m .*constrained DOF"):
        load_rig(f)


def test_lumped_rig_rejects_unknown_dof(tmp_path):
    data = tomllib.loads((RIGS / "two_dof.toml").read_text())
    data["sensors"][0]["dof"] = "x9"
    with pytest.raises(ConfigError, match=r"sensors\[0\]\.dof: unknown DOF"):
        validate(RigConfig, data, Path("two.toml"))
