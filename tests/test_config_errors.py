"""Every config mistake is one line naming file, field and value, exit 2 (issue 18).

A table of malformed session and rig files — each written into ``tmp_path`` as raw text or as a mutation of a
shipped config — is run through the command line in-process (``daq.cli.run``): ``gvt record SESSION`` for
sessions, ``gvt model modes RIG`` for rigs. Each must exit 2 with exactly one ``gvt: error:`` line on stderr
naming the file and the field, and no traceback. They all fail while loading, before anything starts, so the
table runs in a second or two.

Mistakes that need the rig as well (a trigger channel the session does not record, a buffer too big for the
rig's channels) are found by :func:`daq.config.rig_checks.check_session_against_rig`, which the recorder calls at
start-up before it opens anything; those are tested on the function, and through ``gvt record`` when the
recorder calls it.
"""

from __future__ import annotations

import inspect
import math
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import tomli_w
from hypothesis import given
from hypothesis import strategies as st
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from analysis.model.config import MAX_BEAM_ELEMENTS, MAX_FORCE_N, MAX_SENSORS, RigConfig
from analysis.model.loader import ConfigError, load_config, validate
from analysis.model.rigs import open_rig
from daq.cli import run
from daq.config.rig_checks import check_session_against_rig
from daq.config.session import (
    MAX_DURATION_S,
    MAX_PRE_TRIGGER_S,
    SessionConfig,
    driver_table_error,
)
from tests.test_config import _paths

ROOT = Path(__file__).resolve().parents[1]
SESSIONS = ROOT / "configs" / "sessions"
RIGS = ROOT / "configs" / "rigs"

Mutation = Callable[[dict], None]


def _load(path: Path) -> dict:
    return tomllib.loads(path.read_text())


@dataclass(frozen=True)
class Case:
    """A malformed file: ``base`` (a shipped config's stem) changed by ``edit``, or raw ``text``; the message must
    name ``field`` right after the file (``None``: a file-level problem) and contain ``words``."""

    id: str
    kind: str  # "session" | "rig"
    field: str | None
    words: str = ""
    base: str | None = None
    edit: Mutation | None = None
    text: bytes | None = None


def _set(path: str, value: Any) -> Mutation:
    """An edit setting a dotted path (``device.simulate.forces``; ``sensors[3].x``); ``value`` DELETE removes it."""

    def edit(d: dict) -> None:
        keys: list[Any] = []
        for part in path.split("."):
            name, *idx = part.replace("]", "").split("[")
            keys.append(name)
            keys.extend(int(i) for i in idx)
        cur: Any = d
        for k in keys[:-1]:
            cur = cur.setdefault(k, {}) if isinstance(cur, dict) else cur[k]
        if value is DELETE:
            del cur[keys[-1]]
        else:
            cur[keys[-1]] = value

    return edit


DELETE = object()


def _edits(*edits: Mutation) -> Mutation:
    def edit(d: dict) -> None:
        for e in edits:
            e(d)

    return edit


def S(id: str, field: str | None, words: str = "", base: str | None = "sim_serial_20hits", **kw: Any) -> Case:
    """A session case (default base: the 20-hit serial session)."""
    return Case(id, "session", field, words, base, **kw)


def R(id: str, field: str | None, words: str = "", base: str | None = "beam_ch4_exp", **kw: Any) -> Case:
    """A rig case (default base: the experimental beam)."""
    return Case(id, "rig", field, words, base, **kw)


def _two_devices(d: dict) -> None:
    d["devices"][1]["name"] = "hammer_daq"


def _both_device_tables(d: dict) -> None:
    d["device"] = {"name": "x", "driver": "serial"}


def _dup_channels(d: dict) -> None:
    d["devices"][1]["simulate"]["channels"] = ["hammer", "a01"]


def _many_sensors(d: dict) -> None:
    d["sensor_arrays"] = [dict(d["sensor_arrays"][0], prefix=p, count=200) for p in ("u", "v")]


CASES: list[Case] = [
    # --- sessions: keys and types ---------------------------------------------------------------------------
    S("unknown top-level key", "colour", "unknown key", edit=_set("colour", "red")),
    S("unknown trigger key", "trigger.levle", "unknown key", edit=_set("trigger.levle", 20.0)),
    S("unknown simulate key", "device.simulate.forcez", "unknown key", edit=_set("device.simulate.forcez", [1.0])),
    S("duration of the wrong type", "duration", "valid number", edit=_set("duration", "ten")),
    S("trigger level of the wrong type", "trigger.level", "valid number", edit=_set("trigger.level", "high")),
    S("missing trigger table", "trigger", "required key is missing", edit=_set("trigger", DELETE)),
    S("missing trigger level", "trigger.level", "required key is missing", edit=_set("trigger.level", DELETE)),
    S("missing name", "name", "required key is missing", edit=_set("name", DELETE)),
    S("missing driver", "device.driver", "required key is missing", edit=_set("device.driver", DELETE)),
    S("unknown driver", "device.driver", "'serial'", edit=_set("device.driver", "usb")),
    S("device name with a space", "device.name", "pattern", edit=_set("device.name", "dev 0")),
    S("unknown sample format", "device.simulate.format", "ascii", edit=_set("device.simulate.format", "int12")),
    S("negative simulate seed", "device.simulate.seed", "greater than or equal to 0", edit=_set("device.simulate.seed", -1)),
    # --- inf / nan -------------------------------------------------------------------------------------------
    S("inf duration", "duration", "finite", text=b'name = "x"\nrig = "beam_ch4_exp"\nduration = inf\n'
      b'[device]\ndriver = "serial"\n[device.simulate]\nforces = [100.0]\n[trigger]\nlevel = 20.0\n'),
    S("nan trigger level", "trigger.level", "finite", edit=_set("trigger.level", math.nan)),
    S("inf hit force", "device.simulate.forces[2]", "finite", edit=_set("device.simulate.forces[2]", math.inf)),
    S("inf in a driver table", "device.config.sample_rate", "finite", base="sim_modbus",
      edit=_set("device.config.sample_rate", -math.inf)),
    S("nan range override", "device.simulate.ranges.a09", "finite", edit=_set("device.simulate.ranges.a09", math.nan)),
    # --- negative / zero -------------------------------------------------------------------------------------
    S("negative duration", "duration", "greater than 0", edit=_set("duration", -1.0)),
    S("zero hit period", "device.simulate.period", "greater than 0", edit=_set("device.simulate.period", 0.0)),
    S("negative pre-trigger", "trigger.pre_trigger", "greater than or equal to 0", edit=_set("trigger.pre_trigger", -0.01)),
    S("zero queue", "queue_seconds", "greater than 0", edit=_set("queue_seconds", 0.0)),
    S("negative hit force", "device.simulate.forces[0]", "greater than or equal to 0",
      edit=_set("device.simulate.forces[0]", -5.0)),
    # --- resource limits -------------------------------------------------------------------------------------
    S("a week-plus duration", "duration", "limit of 604800 s", edit=_set("duration", 1e9)),
    S("a 1e9 s pre-trigger", "trigger.pre_trigger", f"limit of {MAX_PRE_TRIGGER_S:g} s", edit=_set("trigger.pre_trigger", 1e9)),
    S("a 1e4 s hit record", "trigger.record_length", "limit of 60 s", edit=_set("trigger.record_length", 1e4)),
    S("a 1e30 N hit", "device.simulate.forces[0]", "limit of 1e+06 N", edit=_set("device.simulate.forces[0]", 1e30)),
    S("a 1e30 N force range", "trigger.force_range[1]", "limit of 1e+06 N", edit=_set("trigger.force_range", [100.0, 1e30])),
    S("a huge lane queue", "queue_seconds", "limit of 60 s", edit=_set("queue_seconds", 1e6)),
    S("a 1 TiB writer buffer", "writer_buffer_mib", "limit of 4096 MiB", edit=_set("writer_buffer_mib", 2.0**20)),
    S("a 1 kiB writer buffer", "writer_buffer_mib", "limit of 1 MiB", edit=_set("writer_buffer_mib", 1 / 1024)),
    S("nan writer buffer", "writer_buffer_mib", "finite", edit=_set("writer_buffer_mib", math.nan)),
    S("a huge analysis queue", "analysis.queue_seconds", "limit of 60 s", edit=_set("analysis.queue_seconds", 1e6)),
    S("a huge analysis window", "analysis.window_s", "limit of 10 s", edit=_set("analysis.window_s", 1e6)),
    S("rotation every 10 bytes", "rotate_bytes", "limit of 1048576 bytes", edit=_set("rotate_bytes", 10)),
    S("rotation every millisecond", "rotate_seconds", "limit of 1 s", edit=_set("rotate_seconds", 0.001)),
    S("a 1 GHz simulated rate", "device.simulate.sample_rate", "limit of 1e+06 Hz",
      edit=_set("device.simulate.sample_rate", 1e9)),
    S("a 1 GHz device rate", "device.config.sample_rate", "1e+06 Hz", base="sim_modbus",
      edit=_set("device.config.sample_rate", 1e9)),
    S("a 1 mHz simulated rate", "device.simulate.sample_rate", "limit of 1 Hz", edit=_set("device.simulate.sample_rate", 0.001)),
    S("10,000 channels", "device.config.channels", "limit of 256 channels", base="sim_modbus",
      edit=_set("device.config.channels", [f"c{i}" for i in range(10_000)])),
    S("an end grace of years", "end_grace_s", "limit of 3600 s", edit=_set("end_grace_s", 1e9)),
    S("a huge timeline buffer", "timeline.max_buffer_s", "less than or equal to 120", base="sim_two_devices",
      edit=_set("timeline.max_buffer_s", 1e6)),
    S("a timeline message every ns", "timeline.report_s", "limit of 0.01 s", base="sim_two_devices",
      edit=_set("timeline.report_s", 1e-9)),
    S("a 1e30 N hit of the in-process device", "device.config.forces[1]", "1e+06 N", base="soak_1h",
      edit=_set("device.config.forces[1]", 1e30)),
    S("a fault at year 30", "device.simulate.stall_at_s", "limit of 604800 s", edit=_set("device.simulate.stall_at_s", 1e9)),
    S("a million wild frames", "device.simulate.wild_frames", "limit of 1000",
      edit=_set("device.simulate.wild_frames", [[1.0, 10]] * 1001)),
    # --- cross-field checks of the session alone ------------------------------------------------------------
    S("force range min >= max", "trigger.force_range", "min < max", edit=_set("trigger.force_range", [2000.0, 100.0])),
    S("trigger channel typo", "trigger.channel", "did you mean 'hammer'", base="sim_modbus",
      edit=_set("trigger.channel", "hamer")),
    S("driving point typo", "trigger.driving_point", "'a99' is not recorded", base="sim_modbus",
      edit=_set("trigger.driving_point", "a99")),
    S("excluded channel not recorded", "channels.exclude[0]", "'a13' is not recorded", base="sim_modbus",
      edit=_set("channels.exclude", ["a13"])),
    S("trigger channel required", "channels.required", "always required", edit=_set("channels.required", ["hammer"])),
    S("required and excluded", "channels.required", "both required and excluded",
      edit=_edits(_set("channels.required", ["a01"]), _set("channels.exclude", ["a01"]))),
    S("two devices with one name", "devices[1].name", "used twice", base="sim_two_devices", edit=_two_devices),
    S("[device] and [[devices]]", "devices", "not both", base="sim_two_devices", edit=_both_device_tables),
    S("a channel on two devices", "devices[1].channels", "on both", base="sim_two_devices", edit=_dup_channels),
    S("multi-device trigger typo", "trigger.channel", "on no device", base="sim_two_devices",
      edit=_set("trigger.channel", "hamer")),
    S("missing rig file", "rig", "no rig file", edit=_set("rig", "no_such_rig.toml")),
    S("simulate on the in-process driver", "device.simulate", "driver 'sim'", edit=_set("device.driver", "sim")),
    S("RTU transport on serial", "device.simulate.transport", "only for driver 'modbus'",
      edit=_set("device.simulate.transport", "rtu")),
    S("wild frames on modbus", "device.simulate.wild_frames", "only for driver 'serial'", base="sim_modbus",
      edit=_set("device.simulate.wild_frames", [[1.0, 10]])),
    S("double hit beyond the schedule", "device.simulate.double_hits", "not in the schedule",
      edit=_set("device.simulate.double_hits", [25])),
    S("a stall without a time", "device.simulate.stall_for_s", "stall_at_s", edit=_set("device.simulate.stall_for_s", 1.0)),
    S("start delay on one device", "device.simulate.start_delay", "only for [[devices]]",
      edit=_set("device.simulate.start_delay", 0.1)),
    S("simulated session without duration", "duration", "needs a duration", edit=_set("duration", DELETE)),
    S("channels not a list", "device.config.channels", "list of channel names", base="sim_modbus",
      edit=_set("device.config.channels", "hammer")),
    S("timeline reference unknown", "timeline.reference", "no device named", base="sim_two_devices",
      edit=_set("timeline.reference", "nope")),
    # --- files that are not configs --------------------------------------------------------------------------
    S("bad TOML syntax", None, "invalid TOML", text=b"name = \n"),
    S("non-UTF-8 bytes", None, "not UTF-8", text=b"\xff\xfe\x00garbage"),
    S("an empty file", "name", "required key is missing", text=b""),
    S("a 2 MB file", None, "limit of 1024 kB", text=b"# x\n" * 600_000),
    S("a rig given as the session", "rig", "required key is missing", base=None, text=(RIGS / "two_dof.toml").read_bytes()),
    # --- rigs --------------------------------------------------------------------------------------------------
    R("5000 beam elements", "structure.elements", f"limit of {MAX_BEAM_ELEMENTS} elements",
      edit=_set("structure.elements", 5000)),
    R("10,000 sensors in an array", "sensor_arrays[0].count", f"limit of {MAX_SENSORS} sensors", base="beam_ch4_sim",
      edit=_set("sensor_arrays[0].count", 10_000)),
    R("400 sensors in two arrays", "sensor_arrays", f"limit of {MAX_SENSORS} sensors", base="beam_ch4_sim", edit=_many_sensors),
    R("5000 lumped masses", "structure.masses", "limit of 2000", base="two_dof", edit=_set("structure.masses", [1.0] * 5000)),
    R("a 1e30 N nominal hit", "hammer.peak_force", f"limit of {MAX_FORCE_N:g} N", edit=_set("hammer.peak_force", 1e30)),
    R("a 1e30 N hammer range", "hammer.range", "limit of 1e+06 N", edit=_set("hammer.range", 1e30)),
    R("a 1 GHz DAQ", "daq.sample_rate", "limit of 1e+06 Hz", edit=_set("daq.sample_rate", 1e9)),
    R("a 1 mHz DAQ", "daq.sample_rate", "limit of 1 Hz", edit=_set("daq.sample_rate", 0.001)),
    R("a 1e9 s record", "daq.record_length", "limit of 3600 s", edit=_set("daq.record_length", 1e9)),
    R("a record too big to simulate", "daq.record_length", "channel-samples", edit=_set("daq.record_length", 3000.0)),
    R("a vanishing step", "simulation.max_omega_dt", "limit of 0.05 rad", edit=_set("simulation.max_omega_dt", 1e-9)),
    R("inf Young's modulus", "structure.youngs_modulus", "finite", edit=_set("structure.youngs_modulus", math.inf)),
    R("nan density", "structure.density", "finite", edit=_set("structure.density", math.nan)),
    R("sensor off the beam", "sensors[3].x", "off the beam", edit=_set("sensors[3].x", 1.2)),
    R("sensor on the clamp", "sensors[0].x", "constrained DOF", edit=_set("sensors[0].x", 0.001)),
    R("nonlinear spring on the clamp", "nonlinear_springs[0].x", "constrained DOF", edit=_set("nonlinear_springs[0].x", 0.0)),
    R("pulse longer than the record", "hammer.pulse_duration", "longer than the record", base="two_dof",
      edit=_set("hammer.pulse_duration", 300.0)),
    R("unknown DOF", "sensors[0].dof", "unknown DOF", base="two_dof", edit=_set("sensors[0].dof", "x9")),
    R("a sensor name twice", "sensors", "used twice", edit=_set("sensors[1].name", "a01")),
    R("unknown structure key", "structure.colour", "unknown key", edit=_set("structure.colour", "red")),
    R("missing hammer", "hammer", "required key is missing", edit=_set("hammer", DELETE)),
    R("negative simulator seed", "simulation.seed", "greater than or equal to 0", edit=_set("simulation.seed", -1)),
    R("an empty rig", "name", "required key is missing", base=None, text=b""),
    R("a binary rig", None, "not UTF-8", base=None, text=b"\x00\x9f\x92\x96"),
]  # fmt: skip


def _write(case: Case, tmp_path: Path) -> Path:
    f = tmp_path / f"bad_{case.kind}.toml"
    if case.text is not None:
        f.write_bytes(case.text)
        return f
    assert case.base is not None and case.edit is not None
    data = _load((SESSIONS if case.kind == "session" else RIGS) / f"{case.base}.toml")
    case.edit(data)
    f.write_bytes(tomli_w.dumps(data).encode())
    return f


def _argv(kind: str, path: Path | str) -> list[str]:
    return ["record", str(path)] if kind == "session" else ["model", "modes", str(path)]


def _one_error_line(capsys, code: int) -> str:
    out, err = capsys.readouterr()
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2, err
    assert len(lines) == 1, err
    assert "Traceback" not in err and out == "", (out, err)
    assert lines[0].startswith("gvt: error: "), lines[0]
    return lines[0]


def test_the_table_has_at_least_40_malformed_files():
    assert len(CASES) >= 40 and len({c.id for c in CASES}) == len(CASES)
    assert sum(c.kind == "session" for c in CASES) >= 40


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_every_config_mistake_is_one_line_exit_2(case, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)  # a session's relative output lands here (none is written: loading fails)
    f = _write(case, tmp_path)
    line = _one_error_line(capsys, run(_argv(case.kind, f)))
    where = f"gvt: error: {f}: " + (f"{case.field}: " if case.field else "")
    assert line.startswith(where), (where, line)
    assert case.words in line, line


@pytest.mark.parametrize("kind", ["session", "rig"])
def test_a_directory_and_a_missing_file_are_one_line(kind, tmp_path, capsys):
    line = _one_error_line(capsys, run(_argv(kind, tmp_path)))
    assert line == f"gvt: error: {tmp_path}: is a directory, expected a .toml file"
    line = _one_error_line(capsys, run(_argv(kind, tmp_path / "nope.toml")))
    assert line == f"gvt: error: {tmp_path / 'nope.toml'}: file not found"


def test_a_session_with_a_malformed_rig_names_the_rig_file_and_field(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    rig = _load(RIGS / "beam_ch4_exp.toml")
    rig["structure"]["elements"] = 5000
    rig_file = tmp_path / "big.toml"
    rig_file.write_bytes(tomli_w.dumps(rig).encode())
    sess = _load(SESSIONS / "sim_serial_20hits.toml")
    sess["rig"] = str(rig_file)
    f = tmp_path / "s.toml"
    f.write_bytes(tomli_w.dumps(sess).encode())
    line = _one_error_line(capsys, run(["record", str(f)]))
    assert line.startswith(f"gvt: error: {rig_file}: structure.elements: above the limit of 1000 elements"), line


def test_an_error_message_is_one_line_even_when_a_validator_writes_several(tmp_path):
    err = ConfigError(tmp_path / "x.toml", "a.b", "first line\n  second line")
    assert str(err) == f"{tmp_path / 'x.toml'}: a.b: first line second line"


# --- checks that need the rig too (check_session_against_rig) ----------------------------------------------------
RIG_CASES: list[Case] = [
    S("trigger channel typo, channels from the rig", "trigger.channel", "did you mean 'hammer'",
      edit=_set("trigger.channel", "hamer")),
    S("driving point typo, channels from the rig", "trigger.driving_point", "'a31' is not recorded",
      edit=_set("trigger.driving_point", "a31")),
    S("excluded channel not in the rig", "channels.exclude[0]", "'a99' is not recorded", edit=_set("channels.exclude", ["a99"])),
    S("required channel not in the rig", "channels.required[0]", "'a15' is not recorded",
      edit=_set("channels.required", ["a15"])),
    S("range override for an unknown channel", "device.simulate.ranges.a99", "not in rig beam_ch4_exp",
      edit=_set("device.simulate.ranges", {"a99": 2.0})),
    S("hum on a channel not in the rig", "device.simulate.hum_rms.a99", "not in rig beam_ch4_exp",
      edit=_set("device.simulate.hum_rms", {"a99": 0.5})),
    S("simulated channel not in the rig", "devices[1].simulate.channels[13]", "'a15' is not in rig", base="sim_two_devices",
      edit=_set("devices[1].simulate.channels[13]", "a15")),
    S("driver channel not in the rig", "device.config.channels[2]", "'b02' is not in rig", base="sim_modbus",
      edit=_set("device.config.channels[2]", "b02")),
    S("an hour simulated ahead", "duration", "channel-samples", edit=_set("duration", 3600.0)),
    S("a trigger level the hammer cannot reach", "trigger.level", "never fire", edit=_set("trigger.level", 5000.0)),
    S("a simulated rate too low for the pulse", "device.simulate.sample_rate", "shorter than two samples",
      edit=_set("device.simulate.sample_rate", 1000.0)),
    S("a 50 s record of 64 ch at 51.2 kHz", "trigger.record_length", "MiB in memory",
      edit=_edits(_set("rig", "bench_64ch"), _set("trigger.record_length", 50.0), _set("trigger.driving_point", DELETE),
                  _set("device.simulate.ranges", {}))),
    S("an hour of in-process physics", "device.config.physics_seconds", "channel-samples", base="soak_1h",
      edit=_set("device.config.physics_seconds", 3600.0)),
    S("an in-process device at another rate", "device.config.sample_rate", "rig's 16384 Hz", base="soak_1h",
      edit=_set("device.config.sample_rate", 8192.0)),
]  # fmt: skip


@pytest.mark.parametrize("case", RIG_CASES, ids=[c.id for c in RIG_CASES])
def test_mistakes_against_the_rig_are_one_line(case, tmp_path):
    f = _write(case, tmp_path)
    cfg = load_config(SessionConfig, f)  # the session alone is valid
    with pytest.raises(ConfigError) as ei:
        check_session_against_rig(cfg, open_rig(cfg.rig), cfg.name)
    msg = str(ei.value)
    assert "\n" not in msg and msg.startswith(f"{f}: {case.field}: "), msg  # the file, though the name was passed
    assert case.words in msg, msg
    assert ei.value.exit_code == 2


def _recorder_checks_the_rig() -> bool:
    try:
        import daq.session
    except Exception:
        return False
    return "check_session_against_rig" in inspect.getsource(daq.session)


@pytest.mark.parametrize("case", RIG_CASES, ids=[c.id for c in RIG_CASES])
def test_mistakes_against_the_rig_through_gvt_record(case, tmp_path, capsys, monkeypatch):
    if not _recorder_checks_the_rig():
        pytest.skip("the recorder (daq/session.py) does not call check_session_against_rig yet")
    import daq.session

    def started(*_a: Any, **_k: Any) -> None:
        raise AssertionError("the recorder started devices before checking the session against the rig")

    for name in ("start_simulation", "Session"):
        if hasattr(daq.session, name):
            monkeypatch.setattr(daq.session, name, started)
    monkeypatch.chdir(tmp_path)
    f = _write(case, tmp_path)
    line = _one_error_line(capsys, run(["record", str(f)]))
    assert line.startswith(f"gvt: error: {f}: {case.field}: ") and case.words in line, line


def test_shipped_sessions_pass_every_check():
    for f in sorted(SESSIONS.glob("*.toml")):
        cfg = load_config(SessionConfig, f)
        check_session_against_rig(cfg, open_rig(cfg.rig))


def test_a_config_built_in_code_is_named_by_the_path_given_or_its_name():
    data = _load(SESSIONS / "sim_serial_20hits.toml")
    data["trigger"]["channel"] = "hamer"
    cfg = SessionConfig.model_validate(data)
    rig = open_rig(cfg.rig)
    with pytest.raises(ConfigError, match=r"^sim-serial-20-hits: trigger\.channel: "):
        check_session_against_rig(cfg, rig)
    with pytest.raises(ConfigError, match=r"^given\.toml: trigger\.channel: "):
        check_session_against_rig(cfg, rig, "given.toml")
    again = validate(SessionConfig, data, "loaded.toml").model_copy(update={"duration": 2.0})  # `gvt record --duration`
    with pytest.raises(ConfigError, match=r"^loaded\.toml: trigger\.channel: "):
        check_session_against_rig(again, rig, again.name)


def test_new_session_fields_and_their_defaults():
    cfg = load_config(SessionConfig, SESSIONS / "sim_serial_20hits.toml")
    assert cfg.overwrite is False and cfg.end_grace_s == 10.0 and cfg.silence_s is None
    assert cfg.channels.exclude == [] and cfg.channels.required == []
    s = cfg.device.simulate
    assert s.sample_rate is None and s.transport == "tcp" and s.wild_frames == []
    assert (s.stall_at_s, s.stall_for_s, s.disconnect_at_s, s.disconnect_for_s, s.restart_at_s, s.restart_down_s) == (
        None, 0.0, None, 0.0, None, 0.0)  # fmt: skip
    data = _load(SESSIONS / "sim_serial_20hits.toml")
    data.update(overwrite=True, end_grace_s=2.5, silence_s=0.5, channels={"exclude": ["a09"], "required": ["a13"]})
    data["device"]["simulate"].update(format="ascii", sample_rate=2048.0, stall_at_s=1.0, stall_for_s=0.5,
                                      wild_frames=[[1.0, 10**9]])  # fmt: skip
    cfg = validate(SessionConfig, data, "new.toml")
    check_session_against_rig(cfg, open_rig(cfg.rig))
    assert cfg.overwrite and cfg.channels.exclude == ["a09"] and cfg.device.simulate.wild_frames == [(1.0, 10**9)]
    modbus = _load(SESSIONS / "sim_modbus.toml")
    modbus["device"]["simulate"]["transport"] = "rtu"
    assert validate(SessionConfig, modbus, "m.toml").device.simulate.transport == "rtu"


def test_a_simulated_can_device_is_accepted():
    data = _load(SESSIONS / "sim_serial_20hits.toml")
    data["device"]["driver"] = "can"
    cfg = validate(SessionConfig, data, "can.toml")
    check_session_against_rig(cfg, open_rig(cfg.rig))


def test_the_simulated_rate_is_shared_by_every_simulated_device():
    data = _load(SESSIONS / "sim_two_devices.toml")
    data["devices"][0]["simulate"]["sample_rate"] = 8192.0
    cfg = validate(SessionConfig, data, "two.toml")
    assert cfg.devices[1].simulate.sample_rate == 8192.0  # one structure, one clock
    data["devices"][1]["simulate"]["sample_rate"] = 4096.0
    with pytest.raises(ConfigError, match=r"devices\[1\]\.simulate\.sample_rate: "):
        validate(SessionConfig, data, "two.toml")
    data["devices"][0]["simulate"].update(stall_at_s=1.0, stall_for_s=0.2)  # fault knobs stay per device
    del data["devices"][1]["simulate"]["sample_rate"]
    cfg = validate(SessionConfig, data, "two.toml")
    assert cfg.devices[1].simulate.stall_at_s is None


# --- driver tables ----------------------------------------------------------------------------------------------
class _DemoDriverConfig(BaseModel):
    """Shaped like a driver's config model: strict, finite, a whole-table check that names its field."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    port: str
    sample_rate: float = Field(16384.0, gt=0)
    dbc: str = "missing.dbc"
    check_dbc: bool = False

    @model_validator(mode="after")
    def _dbc(self) -> _DemoDriverConfig:
        if self.check_dbc:
            raise ValueError(f"dbc: DBC file {self.dbc!r} not found")
        return self


@pytest.mark.parametrize(
    ("prefix", "table", "expect"),
    [
        ("device", {"port": "/dev/x", "sample_rate": -1},
         "s.toml: device.config.sample_rate: Input should be greater than 0 (got -1)"),
        ("devices[1]", {}, "s.toml: devices[1].config.port: required key is missing"),
        ("device", {"port": "/dev/x", "baud": 9600}, "s.toml: device.config.baud: unknown key for this driver"),
        ("device", {"port": "/dev/x", "sample_rate": math.inf}, "s.toml: device.config.sample_rate: Input should be a finite"),
        ("device.config", {"port": "/dev/x", "dbc": "x.dbc", "check_dbc": True},
         "s.toml: device.config.dbc: DBC file 'x.dbc' not found (got 'x.dbc')"),
        ("device", {"port": 5, "sample_rate": "x"},
         "s.toml: device.config.port: Input should be a valid string (got 5) [and 1 more problem]"),
    ],
)  # fmt: skip
def test_driver_table_errors_are_one_line(prefix, table, expect):
    with pytest.raises(ValidationError) as ei:
        _DemoDriverConfig.model_validate(table)
    err = driver_table_error("s.toml", prefix, ei.value)
    assert isinstance(err, ConfigError) and err.exit_code == 2
    assert str(err).startswith(expect) and "\n" not in str(err), str(err)


def test_a_real_driver_table_error():
    from drivers.serial.driver import SerialConfig

    with pytest.raises(ValidationError) as ei:
        SerialConfig.model_validate({"port": "/dev/ttyX", "sample_rate": 16384.0, "channels": []})
    msg = str(driver_table_error("s.toml", "devices[0]", ei.value))
    assert msg.startswith("s.toml: devices[0].config.channels: ") and "\n" not in msg, msg


# --- limits are refused before anything is built ------------------------------------------------------------------
def test_limits_are_refused_before_the_rig_is_built(monkeypatch):
    import analysis.model.rig as rig_mod

    def boom(*_a: Any, **_k: Any) -> None:
        raise AssertionError("built a rig the limits refuse")

    monkeypatch.setattr(rig_mod, "build_beam", boom)
    data = _load(RIGS / "beam_ch4_exp.toml")
    data["structure"]["elements"] = 5000
    with pytest.raises(ConfigError, match=r"structure\.elements: above the limit of 1000 elements"):
        validate(RigConfig, data, "r.toml")


def test_a_week_is_the_longest_session():
    data = _load(SESSIONS / "soak_1h.toml")
    data["duration"] = MAX_DURATION_S
    validate(SessionConfig, data, "week.toml")
    data["duration"] = MAX_DURATION_S + 1
    with pytest.raises(ConfigError, match="above the limit of 604800 s"):
        validate(SessionConfig, data, "week.toml")


# --- fuzz: whatever a user writes, loading and the rig checks answer with a ConfigError or a valid session ----------
_BASES = {n: _load(SESSIONS / f"{n}.toml") for n in ("sim_serial_20hits", "sim_modbus", "sim_two_devices", "soak_1h")}
_FUZZ_PATHS = [(n, p) for n, d in _BASES.items() for p in _paths(d)]
_leaf = st.one_of(
    st.none(), st.booleans(), st.integers(-(10**12), 10**12), st.floats(allow_nan=True), st.text(max_size=6),
    st.sampled_from(["hammer", "a13", "a99", "rtu", "ascii", "can", "sim", "modbus"]), st.lists(st.floats(), max_size=3),
)  # fmt: skip


def _set_path(d: Any, keys: tuple, value: Any) -> None:
    for k in keys[:-1]:
        d = d[k]
    d[keys[-1]] = value


@given(st.sampled_from(sorted(_BASES)), st.lists(st.tuples(st.integers(0, 10**6), _leaf), min_size=1, max_size=4))
def test_fuzz_session_mutations_never_escape_as_other_exceptions(base, edits):
    import copy

    data = copy.deepcopy(_BASES[base])
    paths = [p for n, p in _FUZZ_PATHS if n == base]
    for pick, value in edits:
        try:
            _set_path(data, paths[pick % len(paths)], value)
        except (KeyError, TypeError, IndexError):
            continue  # an earlier edit replaced this container
    try:
        cfg = validate(SessionConfig, data, "fuzz.toml")
        check_session_against_rig(cfg, open_rig(cfg.rig))
    except ConfigError as exc:
        msg = str(exc)
        assert msg.startswith("fuzz.toml") and "\n" not in msg, msg


def test_a_missing_dbc_file_is_one_line_naming_the_field():
    from drivers.can.driver import CanConfig

    with pytest.raises(ValidationError) as ei:
        CanConfig.model_validate({"dbc": "no_such_file.dbc", "stream": "dev0"})
    msg = str(driver_table_error("can.toml", "device", ei.value))
    assert msg.startswith("can.toml: device.config") and "no_such_file.dbc" in msg and "\n" not in msg, msg
    assert "{" not in msg  # the table itself is not echoed back
