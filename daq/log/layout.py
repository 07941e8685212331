"""Names that define a gvtlink MCAP log (docs/log-format.md): topics, schemas, metadata records."""

from __future__ import annotations

from analysis import records as _records

PROFILE = "gvtlink"
FORMAT_VERSION = "2"  # 2: one time base (log_time = origin + session time), streams placed on the reference's timeline

# The topic names live with their records (analysis/records.py, the lowest floor, so the kernels can name
# them too); the log's code names them from here.
ANALYSIS_PREFIX = _records.ANALYSIS_PREFIX
CONFIRMATIONS_TOPIC = _records.CONFIRMATIONS_TOPIC
DAQ_PREFIX = _records.DAQ_PREFIX
EVENTS_TOPIC = _records.EVENTS_TOPIC
HITS_TOPIC = _records.HITS_TOPIC
IR_EVENTS_TOPIC = _records.IR_EVENTS_TOPIC
MODAL_TOPIC = _records.MODAL_TOPIC
RQ_SPIKES_TOPIC = _records.RQ_SPIKES_TOPIC
RQ_TOPIC = _records.RQ_TOPIC
SAMPLES_TOPIC = _records.SAMPLES_TOPIC
SIM_ENERGY_TOPIC = _records.SIM_ENERGY_TOPIC
SIM_HITS_TOPIC = _records.SIM_HITS_TOPIC
SIM_PREFIX = _records.SIM_PREFIX
TIMELINE_TOPIC = _records.TIMELINE_TOPIC
WARNINGS_TOPIC = _records.WARNINGS_TOPIC

#: the result topics a session or ``gvt analyze`` produces, in the order views and reports list them
RESULT_TOPICS = (RQ_TOPIC, MODAL_TOPIC, IR_EVENTS_TOPIC, RQ_SPIKES_TOPIC, WARNINGS_TOPIC, CONFIRMATIONS_TOPIC)

SAMPLE_BLOCK_SCHEMA = "gvtlink.SampleBlock"

META_SESSION = "gvtlink.session"  # software version, format version, start time, host
META_CALIBRATION = "gvtlink.calibration.{stream}"  # per-channel calibration as JSON strings
META_CONFIG = "gvtlink.config"
META_TIME = "gvtlink.time"  # the session's origin: UTC ns of the reference's sample 0 (format 2)
META_EVENTS = "gvtlink.events"  # at close: /daq/events counts by kind and the events themselves (≤ 2000)
META_STREAMS = "gvtlink.streams"  # at close, per stream: counts, gaps, segments, flags, t0_ns, offset_ns (format 2)
#: written by ``gvt log recover`` when data was lost: per stream, the sample ranges the original log had lost (JSON
#: [[start, end, why], ...]); every read of the recovered file reports them as damage (issue 30: a damaged first
#: chunk's place was gone, and an export of the recovered file exited 0)
META_RECOVERED = "gvtlink.recovered"


def samples_topic(stream: str) -> str:
    return SAMPLES_TOPIC.format(stream=stream)


def stream_of(topic: str) -> str | None:
    if topic.startswith(DAQ_PREFIX) and topic.endswith("/samples"):
        return topic[len(DAQ_PREFIX) : -len("/samples")]
    return None


PREVIEW_PREFIX = "/preview/"  # per-stream preview topics (daq/log/preview.py): min/max/mean per bucket, for viewers


def preview_topic(stream: str) -> str:
    return f"{PREVIEW_PREFIX}{stream}"
