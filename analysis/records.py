"""Typed result records: the one place where the log's topic names, JSON keys and JSON schemas live.

Results used to leave the kernels as plain dicts built at each call site, so the same ~20-key confirmation
record existed three times and nothing said which keys a topic carries. Each record kind here is a frozen
dataclass with one encoder (``to_json``: a dict with the on-disk keys, unchanged from format 1) and one decoder
(``from_json``: tolerant of old logs' missing optional keys), and one JSON Schema (draft 2020-12) that the log
writer stores with the topic, so any MCAP reader can decode and validate every JSON topic.

A record is also a read-only :class:`~collections.abc.Mapping` of its JSON form: it travels through the
session's sinks, lanes and the log writer as the typed object (``dict(record)`` is what the writer stores),
while code that reads results by key works on a record and on a dict read back from a log alike.

This module sits on the lowest floor (``analysis``): ``daq/log/layout.py`` re-exports the topic names.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field, fields
from typing import Any, ClassVar

# --- topic names ---------------------------------------------------------------------------------------
DAQ_PREFIX = "/daq/"
ANALYSIS_PREFIX = "/analysis/"
SIM_PREFIX = "/sim/"
SAMPLES_TOPIC = DAQ_PREFIX + "{stream}/samples"
HITS_TOPIC = DAQ_PREFIX + "hits"
EVENTS_TOPIC = DAQ_PREFIX + "events"
TIMELINE_TOPIC = DAQ_PREFIX + "timeline"
PLAN_TOPIC = DAQ_PREFIX + "plan"
RQ_TOPIC = ANALYSIS_PREFIX + "rq"
MODAL_TOPIC = ANALYSIS_PREFIX + "modal"
IR_EVENTS_TOPIC = ANALYSIS_PREFIX + "events"
RQ_SPIKES_TOPIC = ANALYSIS_PREFIX + "rq_spikes"
WARNINGS_TOPIC = ANALYSIS_PREFIX + "warnings"
CONFIRMATIONS_TOPIC = ANALYSIS_PREFIX + "confirmations"
FRF_TOPIC = ANALYSIS_PREFIX + "frf"
SIM_ENERGY_TOPIC = SIM_PREFIX + "energy"
SIM_HITS_TOPIC = SIM_PREFIX + "hits"

SCHEMA_DIALECT = "https://json-schema.org/draft/2020-12/schema"
ANY_TITLE = "gvtlink.AnyJSON"

Prop = tuple[Any, str]  # (JSON type or a full sub-schema, description with the unit)


def _schema(title: str, description: str, props: Mapping[str, Prop], required: tuple[str, ...]) -> dict[str, Any]:
    """A draft 2020-12 object schema; extra keys are allowed (new writers may add some, old readers ignore them)."""
    properties = {}
    for name, (typ, desc) in props.items():
        sub = dict(typ) if isinstance(typ, Mapping) else {"type": typ}
        properties[name] = {**sub, "description": desc}
    return {"$schema": SCHEMA_DIALECT, "title": title, "description": description, "type": "object",
            "properties": properties, "required": list(required)}  # fmt: skip


NUM_ARRAY: dict[str, Any] = {"type": "array", "items": {"type": "number"}}
INTERVAL: dict[str, Any] = {"type": "array", "items": {"type": "number"}, "minItems": 2, "maxItems": 2}
OPT_NUM: list[str] = ["number", "null"]
OPT_INT: list[str] = ["integer", "null"]
OPT_STR: list[str] = ["string", "null"]


def _plain(v: Any) -> Any:
    """A field value as JSON: tuples become lists, dicts are copied (the record stays unshared)."""
    if isinstance(v, tuple):
        return [_plain(x) if isinstance(x, (tuple, dict)) else x for x in v]
    if isinstance(v, dict):
        return {k: _plain(x) if isinstance(x, (tuple, dict)) else x for k, x in v.items()}
    return v


class Record(Mapping[str, Any]):
    """Base of every record: a JSON encoder/decoder pair, a schema, and the read-only Mapping view."""

    TOPIC: ClassVar[str]
    SCHEMA: ClassVar[dict[str, Any]]
    OMIT_NONE: ClassVar[frozenset[str]] = frozenset()  # optional keys: left out when None (as old writers did)
    TUPLES: ClassVar[frozenset[str]] = frozenset()  # list-valued keys held as tuples (hashable, immutable)
    # records with an ``extra`` field keep keys they do not name (event kinds carry their own details)

    def to_json(self) -> dict[str, Any]:
        """The on-disk dict: every field in declaration order, optional ones only when set."""
        out = {}
        for name in self._names():
            v = getattr(self, name)
            if name == "extra":
                out.update({k: _plain(x) for k, x in v.items() if k not in out})
            elif v is not None or name not in self.OMIT_NONE:
                out[name] = _plain(v) if isinstance(v, (tuple, dict)) else v
        return out

    @classmethod
    def _names(cls) -> tuple[str, ...]:
        """The field names, computed once per class (``dataclasses.fields`` is slow on the per-window path)."""
        names = cls.__dict__.get("_field_names")
        if names is None:
            names = tuple(f.name for f in fields(cls))  # type: ignore[arg-type]
            setattr(cls, "_field_names", names)  # noqa: B010 - a class attribute, not a dataclass field
        return names

    @classmethod
    def from_json(cls, d: Mapping[str, Any]) -> Any:
        """The record of an on-disk dict; a missing optional key takes its default, unknown keys are ignored."""
        kw: dict[str, Any] = {}
        names = {f.name for f in fields(cls)}  # type: ignore[arg-type]
        for name in names - {"extra"}:
            if name in d:
                v = d[name]
                kw[name] = tuple(v) if name in cls.TUPLES and isinstance(v, list) else v
        if "extra" in names:
            kw["extra"] = {k: v for k, v in d.items() if k not in names}
        return cls(**kw)

    def _view(self) -> dict[str, Any]:
        cache = self.__dict__.get("_json_view")
        if cache is None:  # a frozen record's JSON never changes: encode once
            cache = self.to_json()
            object.__setattr__(self, "_json_view", cache)
        return cache

    def __getitem__(self, key: str) -> Any:
        return self._view()[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._view())

    def __len__(self) -> int:
        return len(self._view())

    # the dict's own methods: Mapping's generic ones raise and catch KeyError for a missing key (20× slower)
    def get(self, key: str, default: Any = None) -> Any:
        return self._view().get(key, default)

    def __contains__(self, key: object) -> bool:
        return key in self._view()

    def keys(self):
        return self._view().keys()

    def items(self):
        return self._view().items()

    def values(self):
        return self._view().values()


# --- analysis ------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=True)
class RQWindow(Record):
    """One window of the seed lane's base grid: RQ frequency estimates of the kept NNMs and the POD."""

    TOPIC = RQ_TOPIC
    TUPLES = frozenset({"rq_hz", "pov_fraction"})
    start: int
    stop: int
    t_start_s: float
    t_end_s: float
    rq_hz: tuple[float, ...]
    pov_fraction: tuple[float, ...]
    seed_spike: bool
    SCHEMA = _schema("gvtlink.RQWindow", "One RQ window (seed lane, base grid)", {
        "start": ("integer", "first sample index of the window (stream samples)"),
        "stop": ("integer", "one past the last sample index of the window (stream samples)"),
        "t_start_s": ("number", "window start on the stream clock, s"),
        "t_end_s": ("number", "window end on the stream clock, s"),
        "rq_hz": (NUM_ARRAY, "Rayleigh-quotient frequency per kept NNM, Hz (NaN when undefined)"),
        "pov_fraction": (NUM_ARRAY, "proper orthogonal value per kept mode as a fraction of the total, 1"),
        "seed_spike": ("boolean", "the seed's literal spike rule flags this window"),
    }, ("start", "stop", "t_start_s", "t_end_s", "rq_hz", "pov_fraction", "seed_spike"))  # fmt: skip


@dataclass(frozen=True, eq=True)
class ModalWindow(Record):
    """One window of the modal lane: modal energies and frequencies on the rig's Guyan modes."""

    TOPIC = MODAL_TOPIC
    TUPLES = frozenset({"modal_energy_J", "modal_freq_hz"})
    index: int
    start: int
    stop: int
    t_start_s: float
    t_end_s: float
    modal_energy_J: tuple[float, ...]
    modal_freq_hz: tuple[float, ...]
    input: bool
    SCHEMA = _schema("gvtlink.ModalWindow", "One modal-filter window (modal lane)", {
        "index": ("integer", "window number from the stream start"),
        "start": ("integer", "first sample index of the window (stream samples)"),
        "stop": ("integer", "one past the last sample index (stream samples)"),
        "t_start_s": ("number", "window start on the stream clock, s"),
        "t_end_s": ("number", "window end on the stream clock, s"),
        "modal_energy_J": (NUM_ARRAY, "energy per mode, J"),
        "modal_freq_hz": (NUM_ARRAY, "measured frequency per mode, Hz"),
        "input": ("boolean", "a hammer input is active in the window"),
    }, ("index", "start", "stop", "t_start_s", "t_end_s", "modal_energy_J", "modal_freq_hz", "input"))  # fmt: skip


@dataclass(frozen=True, eq=True)
class IREventRecord(Record):
    """An internal-resonance event as logged: the detector's :class:`~analysis.exchange.IREvent` and its id."""

    TOPIC = IR_EVENTS_TOPIC
    TUPLES = frozenset({"modes"})
    OMIT_NONE = frozenset({"label_confidence"})
    id: int
    start_s: float
    end_s: float
    modes: tuple[int, ...]
    ratio: str
    m: int
    n: int
    f_give_hz: float
    f_recv_hz: float
    gain: float
    scores: dict[str, float] = field(default_factory=dict)
    confidence: float = 0.0
    source: str = "modal-exchange"
    label_confidence: float | None = None  # absent in logs written before issue 21
    SCHEMA = _schema("gvtlink.IREvent", "An internal-resonance (energy exchange) event", {
        "id": ("integer", "event number in the session, from 0"),
        "start_s": ("number", "event start on the stream clock, s"),
        "end_s": ("number", "event end on the stream clock, s"),
        "modes": ({"type": "array", "items": {"type": "integer"}}, "(giving, receiving) mode numbers, 1-based"),
        "ratio": ("string", "m:n, f_recv / f_give ≈ m / n"),
        "m": ("integer", "ratio numerator"),
        "n": ("integer", "ratio denominator"),
        "f_give_hz": ("number", "giving mode's frequency, Hz"),
        "f_recv_hz": ("number", "receiving mode's frequency, Hz"),
        "gain": ("number", "receiver energy peak / minimum, 1"),
        "scores": ({"type": "object", "additionalProperties": {"type": "number"}}, "evidence scores by name, 0–1"),
        "confidence": ("number", "calibrated probability that the event is a true major exchange, 0–1 (docs/evaluation.md §6)"),
        "source": ("string", "detector that flagged it"),
        "label_confidence": (OPT_NUM, "calibrated probability that it is one with this m:n, 0–1; a 1:1 ratio is a leak"),
    }, ("id", "start_s", "end_s", "modes", "ratio", "m", "n", "f_give_hz", "f_recv_hz", "gain"))  # fmt: skip

    @classmethod
    def of(cls, id: int, ev: Any) -> IREventRecord:
        """The record of the detector's event ``ev`` (an ``IREvent``), numbered ``id``."""
        return cls(id, ev.start_s, ev.end_s, tuple(ev.modes), f"{ev.m}:{ev.n}", ev.m, ev.n, ev.f_give_hz, ev.f_recv_hz,
                   ev.gain, dict(ev.scores), ev.confidence, ev.source, getattr(ev, "label_confidence", None))  # fmt: skip


@dataclass(frozen=True, eq=True)
class RQSpike(Record):
    """A window-robust RQ spike interval: flagged on enough of the shifted/stretched window grids."""

    TOPIC = RQ_SPIKES_TOPIC
    start_s: float
    end_s: float
    agreement: float
    SCHEMA = _schema("gvtlink.RQSpike", "A window-robust RQ spike interval", {
        "start_s": ("number", "interval start on the stream clock, s"),
        "end_s": ("number", "interval end on the stream clock, s"),
        "agreement": ("number", "fraction of window grids that flag it, 0–1"),
    }, ("start_s", "end_s", "agreement"))  # fmt: skip


@dataclass(frozen=True, eq=True)
class AnalysisWarning(Record):
    """An assumption of the seed's method that does not hold, or a lane restart."""

    TOPIC = WARNINGS_TOPIC
    kind: str
    message: str
    SCHEMA = _schema("gvtlink.Warning", "An analysis warning", {
        "kind": ("string", "what: nonlinearity | sensors | window | drift | restart | ..."),
        "message": ("string", "one line for the user"),
    }, ("kind", "message"))  # fmt: skip


#: A confirmation's status when the slow flow finds a resonance at another m:n than the event's (issue 29).
OTHER_RATIO = "other_ratio"


def confirmation_status(rec: Mapping[str, Any]) -> str:
    """The status to show for a confirmation record (as JSON). A record written before ``other_ratio`` existed
    says ``confirmed`` with another m:n than its event's (``label_agrees`` false, or the ratios differ): it is
    shown as ``other_ratio``, what it was. The log's bytes are never changed."""
    status = str(rec.get("status", "?"))
    if status != "confirmed":
        return status
    found, label = rec.get("ratio"), (rec.get("event") or {}).get("ratio")
    if rec.get("label_agrees") is False or (found and label and found != label):
        return OTHER_RATIO
    return status


@dataclass(frozen=True, eq=True)
class Confirmation(Record):
    """The confirmation of one IR event (WBEMD + slow flow), or why it was not examined.

    Three shapes share this one record, as they always had on disk: *skipped*/*error* (no ``sensor``: the
    segment was never decomposed), *one IMF* (decomposed; the two frequencies fell on one IMF, no
    ``slow_angle``), and the full test (every key).
    """

    TOPIC = CONFIRMATIONS_TOPIC
    event_id: int | None
    event: dict[str, Any]
    status: str  # confirmed | other_ratio | not_confirmed | skipped | error
    reason: str
    ratio: str | None = None
    m: int | None = None
    n: int | None = None
    start_s: float | None = None
    end_s: float | None = None
    candidates: list[dict[str, Any]] = field(default_factory=list)
    trajectory: dict[str, list[float]] | None = None
    sensor: str | None = None  # set when the segment was decomposed, with the next four and elapsed_s
    imf_freqs_hz: list[float] | None = None
    orthogonality_index: float | None = None
    segment_s: list[float] | None = None
    elapsed_s: float | None = None
    slow_angle: dict[str, Any] | None = None  # set by the full test, with the next three
    evidence: str | None = None
    label_agrees: bool | None = None
    bracketed: bool | None = None

    @classmethod
    def skipped(cls, event: Mapping[str, Any], reason: str, status: str = "skipped") -> Confirmation:
        """An event that was not examined (``status`` skipped, or error), with the reason."""
        return cls(event.get("id"), dict(event), status, reason)

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"event_id": self.event_id, "event": _plain(self.event)}
        if self.sensor is not None:
            out.update(sensor=self.sensor, imf_freqs_hz=list(self.imf_freqs_hz or []),
                       orthogonality_index=self.orthogonality_index, segment_s=list(self.segment_s or []))  # fmt: skip
        out.update(status=self.status)
        if self.slow_angle is not None:
            out.update(evidence=self.evidence)
        out.update(reason=self.reason, ratio=self.ratio, m=self.m, n=self.n)
        if self.slow_angle is not None:
            out.update(label_agrees=self.label_agrees)
        out.update(start_s=self.start_s, end_s=self.end_s)
        if self.slow_angle is not None:
            out.update(bracketed=self.bracketed, slow_angle=_plain(self.slow_angle))
        out.update(candidates=_plain(self.candidates), trajectory=_plain(self.trajectory))
        if self.sensor is not None:
            out.update(elapsed_s=self.elapsed_s)
        return out

    SCHEMA = _schema("gvtlink.Confirmation", "The confirmation of one IR event (WBEMD + slow flow)", {
        "event_id": (OPT_INT, "id of the IR event in /analysis/events"),
        "event": ({"type": "object"}, "the IR event as logged (gvtlink.IREvent)"),
        "sensor": ("string", "sensor whose displacement was decomposed"),
        "imf_freqs_hz": (NUM_ARRAY, "characteristic frequency per intrinsic mode function, Hz"),
        "orthogonality_index": ("number", "WBEMD orthogonality index of the IMFs, 1"),
        "segment_s": (INTERVAL, "[start, end] of the data used, stream clock, s"),
        "status": ({"enum": ["confirmed", OTHER_RATIO, "not_confirmed", "skipped", "error"]},
                   "outcome; other_ratio: a resonance at another m:n than the event's (ratio, m, n say which)"),
        "evidence": (OPT_STR, "captured | slow_angle, or null when not confirmed"),
        "reason": ("string", "why, one line"),
        "ratio": (OPT_STR, "m:n found (confirmed or other_ratio), or null"),
        "m": (OPT_INT, "confirmed ratio numerator, or null"),
        "n": (OPT_INT, "confirmed ratio denominator, or null"),
        "label_agrees": ("boolean", "confirmed with the detector's own m:n"),
        "start_s": (OPT_NUM, "confirmed interval start, stream clock, s"),
        "end_s": (OPT_NUM, "confirmed interval end, stream clock, s"),
        "bracketed": ("boolean", "the captured loops are bracketed by free rotation"),
        "slow_angle": ({"type": "object"}, "slow-angle test: gain (1), phase_range per m:n (rad), slowest m:n"),
        "candidates": ({"type": "array", "items": {"type": "object"}}, "per candidate m:n: captured fraction (1), "
                       "intervals and end-effect intervals ([s, s]), drift sign"),
        "trajectory": ({"type": ["object", "null"]}, "slow-flow phase trajectory: t (s), phi (rad), phi_dot (rad/s)"),
        "elapsed_s": ("number", "computing time of the confirmation, s"),
    }, ("event_id", "event", "status", "reason", "ratio", "m", "n", "start_s", "end_s", "candidates",
        "trajectory"))  # fmt: skip


@dataclass(frozen=True, eq=True)
class FRFUpdate(Record):
    """The live FRF lane's verdict on one hit (``/analysis/frf``), and the averaged FRFs' peaks after it.

    Small on purpose (a few dozen numbers a hit): the FRF arrays are ``gvt frf``'s job, recomputed from the
    log; this is what the engineer watches between hits. ``peaks_hz``: the largest peaks of the mode
    indicator ``sum |H|`` (:meth:`analysis.frf.FRFSet.peaks`, as ``gvt frf``); per peak the driving point's
    |H| and coherence, and the lowest coherence over all responses."""

    TOPIC = FRF_TOPIC
    TUPLES = frozenset({"peaks_hz", "dp_mag", "dp_coherence", "min_coherence"})
    hit: int
    index: int
    t_s: float
    reference: str
    verdict: str  # accepted | refused
    reason: str
    averages: int
    refused: int
    peaks_hz: tuple[float, ...] = ()
    driving_point: str | None = None
    dp_mag: tuple[float, ...] = ()
    dp_coherence: tuple[float, ...] = ()
    min_coherence: tuple[float, ...] = ()
    units: str = "m/s^2/N"
    record_s: float = 0.0
    tau_s: float | None = None
    band_hz: float = 0.0
    checks: dict[str, Any] | None = None
    elapsed_s: float = 0.0
    SCHEMA = _schema("gvtlink.FRFUpdate", "The live FRF lane's verdict on one hit and the averaged FRFs' peaks", {
        "hit": ("integer", "hit number in /daq/hits"),
        "index": ("integer", "trigger sample index of the hit (stream samples)"),
        "t_s": ("number", "trigger time on the stream clock, s"),
        "reference": ("string", "reference (force) channel"),
        "verdict": ({"enum": ["accepted", "refused"]}, "whether the hit joined the average"),
        "reason": ("string", "'ok', or why it was refused (hit gate, record incomplete, hammer checks)"),
        "averages": ("integer", "hits averaged so far for this reference"),
        "refused": ("integer", "hits refused so far"),
        "peaks_hz": (NUM_ARRAY, "peaks of the mode indicator sum|H| over the responses, ascending, Hz"),
        "driving_point": (OPT_STR, "response at the reference's DOF, or null"),
        "dp_mag": (NUM_ARRAY, "|H| of the driving point at each peak, units"),
        "dp_coherence": (NUM_ARRAY, "coherence of the driving point at each peak, 1"),
        "min_coherence": (NUM_ARRAY, "lowest coherence over all responses at each peak, 1"),
        "units": ("string", "unit of |H| (accelerance m/s^2/N)"),
        "record_s": ("number", "record length, s"),
        "tau_s": (OPT_NUM, "exponential window decay constant, s (null: none)"),
        "band_hz": ("number", "band of interest, Hz"),
        "checks": ({"type": ["object", "null"]}, "the hammer checks (analysis/hammer.py HammerCheck), or null"),
        "elapsed_s": ("number", "the lane's computing time for this hit, s"),
    }, ("hit", "index", "t_s", "reference", "verdict", "reason", "averages", "refused"))  # fmt: skip


# --- acquisition ---------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=True)
class Hit(Record):
    """One hammer hit as the hit gate judged it (``/daq/hits``), or the simulator's truth (``/sim/hits``)."""

    TOPIC = HITS_TOPIC
    OMIT_NONE = frozenset({"impulse_Ns", "reason", "clipped_channels", "start_index", "end_index", "channels",
                           "excluded_channels", "source"})  # fmt: skip
    TUPLES = frozenset({"clipped_channels", "excluded_channels"})
    hit: int
    index: int
    t_s: float
    peak_force_N: float
    pulse_width_s: float
    input_energy_J: float | None
    verdict: str
    impulse_Ns: float | None = None
    reason: str | None = None
    clipped_channels: tuple[str, ...] | None = None
    start_index: int | None = None
    end_index: int | None = None
    channels: dict[str, str] | None = None
    excluded_channels: tuple[str, ...] | None = None
    source: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    SCHEMA = _schema("gvtlink.Hit", "One hammer hit", {
        "hit": ("integer", "hit number in the session, from 0"),
        "index": ("integer", "sample index of the trigger edge (stream samples)"),
        "t_s": ("number", "trigger time on the stream clock, s"),
        "peak_force_N": ("number", "peak hammer force, N"),
        "pulse_width_s": ("number", "force pulse width, s"),
        "impulse_Ns": ("number", "force impulse, N·s"),
        "input_energy_J": (OPT_NUM, "energy put in at the driving point, J (null without one)"),
        "verdict": ("string", "accepted | rejected | ..."),
        "reason": ("string", "failing checks, then notes; 'ok' when none"),
        "clipped_channels": ({"type": "array", "items": {"type": "string"}}, "channels that reached their range"),
        "start_index": ("integer", "first sample of the hit record (stream samples)"),
        "end_index": ("integer", "one past the last sample of the hit record (stream samples)"),
        "channels": ({"type": "object", "additionalProperties": {"type": "string"}}, "verdict per channel"),
        "excluded_channels": ({"type": "array", "items": {"type": "string"}}, "response channels not usable"),
        "source": ("string", "who judged it: simulator, or absent for the hit gate"),
    }, ("hit", "index", "t_s", "peak_force_N", "pulse_width_s", "input_energy_J", "verdict"))  # fmt: skip


@dataclass(frozen=True, eq=True)
class Event(Record):
    """Something that happened (``/daq/events``): a ``kind`` and its details (overrun, overload, note,
    driver gaps and CRC errors, lane errors, writer failures, ...); details beyond the named ones stay in ``extra``."""

    TOPIC = EVENTS_TOPIC
    OMIT_NONE = frozenset({"stream", "channel", "start_index", "end_index", "count", "message"})
    kind: str
    stream: str | None = None
    channel: str | None = None
    start_index: int | None = None
    end_index: int | None = None
    count: int | None = None
    message: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    SCHEMA = _schema("gvtlink.Event", "A session event", {
        "kind": ("string", "overrun | overload | note | analysis_error | confirm_error | timeline_moved | ..."),
        "stream": ("string", "stream it concerns"),
        "channel": ("string", "channel it concerns"),
        "start_index": ("integer", "first sample index concerned (stream samples)"),
        "end_index": ("integer", "one past the last sample index concerned (stream samples)"),
        "count": ("integer", "how many (samples, blocks or occurrences, by kind)"),
        "message": ("string", "one line for the user"),
    }, ("kind",))  # fmt: skip


@dataclass(frozen=True, eq=True)
class TimelineMessage(Record):
    """The clock alignment of a stream to the reference device (``/daq/timeline``)."""

    TOPIC = TIMELINE_TOPIC
    OMIT_NONE = frozenset({"reference", "stream", "offset_s", "offset_samples", "uncertainty_s", "drift_ppm", "method",
                           "applied_samples"})  # fmt: skip
    kind: str
    reference: str | None = None
    stream: str | None = None
    offset_s: float | None = None
    offset_samples: int | None = None
    uncertainty_s: float | None = None
    drift_ppm: float | None = None
    method: str | None = None
    applied_samples: int | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    SCHEMA = _schema("gvtlink.Timeline", "Clock offset of a stream to the reference stream", {
        "kind": ("string", "fixed | periodic | moved | final"),
        "reference": ("string", "reference stream"),
        "stream": ("string", "stream placed on the reference's timeline"),
        "offset_s": ("number", "stream clock minus reference clock, s"),
        "offset_samples": ("integer", "the offset in reference samples"),
        "uncertainty_s": ("number", "offset uncertainty, s"),
        "drift_ppm": ("number", "clock drift, ppm"),
        "method": ("string", "how the offset was found"),
        "applied_samples": (OPT_INT, "offset applied to the merged stream, samples"),
    }, ("kind",))  # fmt: skip


@dataclass(frozen=True, eq=True)
class SimEnergy(Record):
    """The simulator's energy truth at a block's last sample (``/sim/energy``)."""

    TOPIC = SIM_ENERGY_TOPIC
    TUPLES = frozenset({"modal_energy_J"})
    index: int
    modal_energy_J: tuple[float, ...]
    kinetic_J: float
    potential_linear_J: float
    potential_nonlinear_J: float
    dissipated_J: float
    input_work_J: float
    SCHEMA = _schema("gvtlink.SimEnergy", "Simulator energy truth at one sample", {
        "index": ("integer", "sample index (stream samples)"),
        "modal_energy_J": (NUM_ARRAY, "linear modal energy of the first modes, J"),
        "kinetic_J": ("number", "kinetic energy, J"),
        "potential_linear_J": ("number", "linear potential energy, J"),
        "potential_nonlinear_J": ("number", "nonlinear potential energy, J"),
        "dissipated_J": ("number", "energy dissipated so far, J"),
        "input_work_J": ("number", "work done by the hammer so far, J"),
    }, ("index", "modal_energy_J", "kinetic_J", "potential_linear_J", "potential_nonlinear_J", "dissipated_J",
        "input_work_J"))  # fmt: skip


@dataclass(frozen=True, eq=True)
class PlanRecord(Record):
    """The roving-hammer plan and the operator's progress through it (``/daq/plan``; daq/roving.py).

    ``event``: ``plan`` once at the start (``points``: every hit point with its node, direction, model DOF and
    averages), ``progress`` after each hit the FRF lane judged (the point it counted for and what to hit next),
    ``complete`` when the last point has its averages, ``end`` at the session's end (``missing``: points short
    of their averages). The points' node and direction are the references of the FRF matrix (attachment
    ``frf/matrix.npz``) when it is exported (``gvt export --format uff --frf``)."""

    TOPIC = PLAN_TOPIC
    OMIT_NONE = frozenset({"points", "hit", "verdict", "missing"})
    TUPLES = frozenset({"points", "missing"})
    event: str
    point: str | None
    done: int
    required: int
    next_point: str | None
    message: str
    points: tuple[dict[str, Any], ...] | None = None
    hit: int | None = None
    verdict: str | None = None
    missing: tuple[str, ...] | None = None
    POINT: ClassVar[dict[str, Any]] = {"type": "object", "required": ["name", "node", "direction", "dof", "averages"],
                                       "properties": {"name": {"type": "string"}, "node": {"type": "integer"},
                                                      "direction": {"type": "string"}, "dof": {"type": "string"},
                                                      "sensor": {"type": ["string", "null"]},
                                                      "averages": {"type": "integer"}}}  # fmt: skip
    SCHEMA = _schema("gvtlink.PlanRecord", "A roving-hammer plan and the progress through it", {
        "event": ({"enum": ["plan", "progress", "complete", "end"]}, "what happened"),
        "point": (OPT_STR, "the hit point concerned (progress: the one the hit counted for), or null"),
        "done": ("integer", "accepted averages of that point"),
        "required": ("integer", "averages that point needs"),
        "next_point": (OPT_STR, "the point to hit next, or null when the plan is complete"),
        "message": ("string", "the operator's prompt, one line"),
        "points": ({"type": "array", "items": POINT}, "plan only: every hit point (node: UFF node id, direction +X..-Z)"),
        "hit": ("integer", "progress only: hit number in /daq/hits"),
        "verdict": ({"enum": ["accepted", "refused"]}, "progress only: the FRF lane's verdict on the hit"),
        "missing": ({"type": "array", "items": {"type": "string"}}, "end only: points short of their averages"),
    }, ("event", "point", "done", "required", "next_point", "message"))  # fmt: skip


# --- the table -----------------------------------------------------------------------------------------
ANY_SCHEMA: dict[str, Any] = {"$schema": SCHEMA_DIALECT, "title": ANY_TITLE, "type": "object",
                              "description": "a JSON record of a topic gvtlink has no typed record for"}  # fmt: skip

#: every JSON topic gvtlink writes: its record class and the schema stored with it in the log
RECORDS: tuple[type[Record], ...] = (RQWindow, ModalWindow, IREventRecord, RQSpike, AnalysisWarning, Confirmation, Hit,
                                     Event, TimelineMessage, SimEnergy, FRFUpdate, PlanRecord)  # fmt: skip
TOPICS: dict[str, tuple[type[Record], dict[str, Any]]] = {cls.TOPIC: (cls, cls.SCHEMA) for cls in RECORDS}
TOPICS[SIM_HITS_TOPIC] = (Hit, Hit.SCHEMA)


def schema_for(topic: str) -> dict[str, Any]:
    """The JSON schema of ``topic``; a topic without a record gets a permissive schema, still titled."""
    return TOPICS[topic][1] if topic in TOPICS else ANY_SCHEMA


def decode(topic: str, obj: Mapping[str, Any]) -> Record | dict[str, Any]:
    """The typed record of a JSON message of ``topic`` (a plain dict for a topic without a record)."""
    return TOPICS[topic][0].from_json(obj) if topic in TOPICS else dict(obj)


def encode(obj: Mapping[str, Any]) -> dict[str, Any]:
    """The JSON dict of a record or of a plain mapping: what a collector of results keeps, as the log does."""
    return obj.to_json() if isinstance(obj, Record) else dict(obj)
