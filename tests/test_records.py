"""Typed result records (analysis/records.py): one table of topics, schemas stored in the log, old logs decode.

The session log here is a real one (the simulated device, unpaced, with the live analysis and the background
confirmation lane), read back with the plain ``mcap`` package and checked with ``jsonschema`` against the
schema the file itself carries — what any other tool would do.
"""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path

import jsonschema
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader

from analysis import records as R

ROOT = Path(__file__).resolve().parents[1]
OLD_LOGS = sorted([*(ROOT / "replay_logs").glob("*.mcap"), *(ROOT / "tests" / "data" / "format1").glob("*.mcap")])
EXAMPLES = int(os.environ.get("GVT_FUZZ_EXAMPLES", 100))


def json_messages(path: Path) -> dict[str, tuple[dict, list[dict]]]:
    """topic -> (the schema stored in the file, the messages), for every JSON channel: an independent reader."""
    out: dict[str, tuple[dict, list[dict]]] = {}
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if channel.message_encoding != "json":
                continue
            assert schema is not None and schema.encoding == "jsonschema", channel.topic
            entry = out.setdefault(channel.topic, (json.loads(schema.data), []))
            entry[1].append(json.loads(message.data))
    return out


@pytest.fixture(scope="module")
def session_log(tmp_path_factory) -> Path:
    from analysis.model.rigs import open_rig
    from daq.config.session import AnalysisSpec, DeviceSpec, SessionConfig, TriggerSpec
    from daq.session import run_session

    out = tmp_path_factory.mktemp("records") / "session.mcap"
    cfg = SessionConfig(
        name="records", rig="beam_ch4_exp", duration=2.2,
        device=DeviceSpec(driver="sim", config={"paced": False, "block_size": 1024, "forces": [1583.0], "period": 2.2,
                                                "physics_seconds": 2.4, "seed": 5}),
        trigger=TriggerSpec(level=20.0, record_length=0.3),
        # the analysis in the recorder's process, at its priority (a lane host's worker at nice +10 sheds under load by
        # design, D64): this test is about what a complete live analysis logs, not about shedding (tests/test_load_matrix.py)
        analysis=AnalysisSpec(process="thread"),
    )  # fmt: skip
    res = run_session(cfg, open_rig("beam_ch4_exp"), out)
    assert res.lost_samples == 0
    return out


@pytest.fixture(scope="module")
def sim_log(tmp_path_factory) -> Path:
    from analysis.model.rigs import open_rig
    from daq.studies.simulate.session import SessionPlan, simulate_session

    out = tmp_path_factory.mktemp("records") / "sim.mcap"
    plan = SessionPlan(forces=(300.0, 2600.0), pre_trigger=0.05, spacing=0.13, tail=0.2, block_size=512)  # 2600 N clips
    simulate_session(open_rig("beam_ch4_exp"), out, plan, seed=5)
    return out


def check_log(path: Path, must_have: set[str]) -> dict[str, int]:
    """Every JSON topic has its record's schema in the file, and every message validates against it and
    decodes to its record and back to the same dict. Returns the message count per topic."""
    got = json_messages(path)
    assert must_have <= set(got), f"missing topics: {must_have - set(got)}"
    counts = {}
    for topic, (schema, msgs) in got.items():
        assert topic in R.TOPICS, f"{topic} has no typed record"
        assert schema == R.schema_for(topic) and schema["title"] != R.ANY_TITLE
        assert schema["type"] == "object" and schema["properties"] and schema["required"]
        assert all("description" in p for p in schema["properties"].values())
        validator = jsonschema.Draft202012Validator(schema)
        for m in msgs:
            validator.validate(m)
            assert R.decode(topic, m).to_json() == m
        counts[topic] = len(msgs)
    return counts


@pytest.mark.slow
def test_every_json_topic_of_a_session_log_has_a_real_schema_and_every_message_validates(session_log):
    counts = check_log(session_log, {R.HITS_TOPIC, R.RQ_TOPIC, R.MODAL_TOPIC, R.IR_EVENTS_TOPIC, R.CONFIRMATIONS_TOPIC})
    assert counts[R.RQ_TOPIC] >= 90 and counts[R.IR_EVENTS_TOPIC] >= 1
    assert counts[R.CONFIRMATIONS_TOPIC] == counts[R.IR_EVENTS_TOPIC]  # one confirmation record per IR event


def test_every_json_topic_of_a_simulated_log_has_a_real_schema_and_every_message_validates(sim_log):
    counts = check_log(sim_log, {R.HITS_TOPIC, R.SIM_HITS_TOPIC, R.SIM_ENERGY_TOPIC, R.EVENTS_TOPIC})
    assert counts[R.SIM_HITS_TOPIC] == counts[R.HITS_TOPIC] == 2


@pytest.mark.parametrize("path", OLD_LOGS, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_the_committed_old_logs_still_decode_to_records_and_validate(path):
    """On-disk keys are unchanged: the format-1 logs' JSON decodes, re-encodes to the same dict and meets
    today's schemas (the old files carry only a bare object schema or none per topic)."""
    got = json_messages(path)
    assert got, "the old log has JSON topics"
    for topic, (_old_schema, msgs) in got.items():
        validator = jsonschema.Draft202012Validator(R.schema_for(topic))
        for m in msgs:
            validator.validate(m)
            rec = R.decode(topic, m)
            assert isinstance(rec, R.TOPICS[topic][0]) and rec.to_json() == m


def test_the_schemas_are_not_vacuous():
    """A record without a required key, or with a wrong type, fails: the schemas say something."""
    for topic, (cls, schema) in R.TOPICS.items():
        assert schema["title"].startswith("gvtlink.") and schema["$schema"] == R.SCHEMA_DIALECT, topic
        jsonschema.Draft202012Validator.check_schema(schema)
        assert set(schema["required"]) <= set(schema["properties"]), cls.__name__
    ev = R.IREventRecord(3, 1.0, 1.5, (1, 2), "3:1", 3, 1, 20.8, 62.5, 4.2, {"exchange": 0.9}, 0.8).to_json()
    v = jsonschema.Draft202012Validator(R.IREventRecord.SCHEMA)
    v.validate(ev)
    assert not v.is_valid({k: x for k, x in ev.items() if k != "f_give_hz"})
    assert not v.is_valid({**ev, "modes": "1,2"})
    assert not jsonschema.Draft202012Validator(R.Confirmation.SCHEMA).is_valid(
        {**R.Confirmation.skipped({"id": 1}, "why").to_json(), "status": "maybe"}
    )


def test_confirmation_shapes_keep_their_on_disk_keys():
    """The three shapes the three builders used to write (skipped/error, one IMF, full), key for key."""
    skipped = R.Confirmation.skipped({"id": 4, "start_s": 1.0}, "no data", status="error").to_json()
    assert list(skipped) == ["event_id", "event", "status", "reason", "ratio", "m", "n", "start_s", "end_s",
                             "candidates", "trajectory"]  # fmt: skip
    assert skipped["event_id"] == 4 and skipped["status"] == "error" and skipped["candidates"] == []
    examined = {"event_id": 4, "event": {"id": 4}, "sensor": "a13", "imf_freqs_hz": [20.0, 61.0],
                "orthogonality_index": 0.01, "segment_s": [0.5, 2.0]}  # fmt: skip
    one_imf = R.Confirmation(**examined, status="not_confirmed", reason="one IMF", elapsed_s=0.2).to_json()
    assert set(one_imf) == set(skipped) | set(examined) | {"elapsed_s"}
    full = R.Confirmation(**examined, status="not_confirmed", reason="r", elapsed_s=0.2, slow_angle={"gain": 1.0},
                          evidence=None, label_agrees=False, bracketed=False).to_json()  # fmt: skip
    assert set(full) - set(one_imf) == {"evidence", "label_agrees", "bracketed", "slow_angle"} and full["evidence"] is None
    for rec in (skipped, one_imf, full):
        assert R.Confirmation.from_json(rec).to_json() == rec


def test_a_record_is_a_read_only_mapping_of_its_json():
    """Records travel through sinks and lanes as the typed object; key readers and ``dict()`` see the JSON."""
    w = R.RQWindow(0, 256, 0.0, 0.025, (20.8, float("nan")), (0.9, 0.1), False)
    assert dict(w) == w.to_json() and w["rq_hz"] == [20.8, w["rq_hz"][1]] and math.isnan(w["rq_hz"][1])
    assert w.get("missing") is None and "seed_spike" in w and len(w) == 7
    back = R.RQWindow.from_json(json.loads(json.dumps(dict(w))))  # NaN survives the log's JSON
    assert back.rq_hz[0] == 20.8 and math.isnan(back.rq_hz[1])
    with pytest.raises(TypeError):
        w["start"] = 3  # type: ignore[index]
    assert R.encode(w) == w.to_json() and R.encode({"a": 1}) == {"a": 1}


def test_unknown_topics_get_a_titled_permissive_schema_in_the_file(tmp_path):
    from daq.log.writer import LogWriter

    out = tmp_path / "x.mcap"
    with LogWriter(out, origin_ns=0) as w:
        w.write_json("/x/custom", {"anything": [1, 2]}, log_time_ns=0)
        w.write_event("note", log_time_ns=0, message="hello", operator="me")
    got = json_messages(out)
    assert got["/x/custom"][0]["title"] == R.ANY_TITLE and got["/x/custom"][1] == [{"anything": [1, 2]}]
    schema, msgs = got[R.EVENTS_TOPIC]
    assert schema["title"] == "gvtlink.Event" and msgs == [{"kind": "note", "message": "hello", "operator": "me"}]
    assert R.Event.from_json(msgs[0]).extra == {"operator": "me"}


def test_no_topic_literals_outside_layout_and_records():
    """Topic names live in analysis/records.py (re-exported by daq/log/layout.py): no module spells one."""
    pattern = re.compile(r"""["'](/daq/|/analysis/|/sim/)""")
    allowed = {ROOT / "analysis" / "records.py", ROOT / "daq" / "log" / "layout.py"}
    bad = []
    for package in ("analysis", "daq", "drivers"):
        for path in sorted((ROOT / package).rglob("*.py")):
            if path in allowed:
                continue
            for n, line in enumerate(path.read_text().splitlines(), 1):
                code = line.split("#", 1)[0]
                if pattern.search(code):
                    bad.append(f"{path.relative_to(ROOT)}:{n}: {line.strip()}")
    assert bad == []


finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
small = st.integers(-(2**53), 2**53)
text = st.text(max_size=12)
# fmt: off
STRATEGIES = [
    st.builds(R.RQWindow, small, small, finite, finite, st.tuples(finite, finite), st.tuples(finite, finite), st.booleans()),
    st.builds(R.ModalWindow, small, small, small, finite, finite, st.lists(finite, max_size=4).map(tuple),
              st.lists(finite, max_size=4).map(tuple), st.booleans()),
    st.builds(R.IREventRecord, small, finite, finite, st.tuples(small, small), text, small, small, finite, finite, finite,
              st.dictionaries(text, finite, max_size=3), finite, text),
    st.builds(R.RQSpike, finite, finite, finite),
    st.builds(R.AnalysisWarning, text, text),
    st.builds(R.Hit, small, small, finite, finite, finite, st.none() | finite, text, impulse_Ns=st.none() | finite,
              clipped_channels=st.none() | st.lists(text, max_size=3).map(tuple), source=st.none() | text),
    st.builds(R.Event, text, stream=st.none() | text, count=st.none() | small,
              extra=st.dictionaries(text.filter(lambda k: k not in R.Event.SCHEMA["properties"]), small, max_size=2)),
    st.builds(R.SimEnergy, small, st.lists(finite, max_size=10).map(tuple), finite, finite, finite, finite, finite),
    st.builds(R.Confirmation.skipped, st.fixed_dictionaries({"id": small}), text, st.sampled_from(["skipped", "error"])),
]
# fmt: on


@settings(max_examples=EXAMPLES)
@given(st.one_of(STRATEGIES))
def test_records_round_trip_property(rec):
    """``from_json(to_json(r)) == r``, also through the log's JSON text, and the JSON meets the record's schema."""
    d = rec.to_json()
    assert type(rec).from_json(d) == rec
    assert type(rec).from_json(json.loads(json.dumps(d))) == rec
    jsonschema.Draft202012Validator(type(rec).SCHEMA).validate(d)
