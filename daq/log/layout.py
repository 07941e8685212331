"""Names that define a gvtlink MCAP log (docs/log-format.md): topics, schemas, metadata records."""

from __future__ import annotations

PROFILE = "gvtlink"
FORMAT_VERSION = "1"

SAMPLES_TOPIC = "/daq/{stream}/samples"
HITS_TOPIC = "/daq/hits"
EVENTS_TOPIC = "/daq/events"
ANALYSIS_PREFIX = "/analysis/"
SIM_PREFIX = "/sim/"

SAMPLE_BLOCK_SCHEMA = "gvtlink.SampleBlock"

META_SESSION = "gvtlink.session"  # software version, format version, start time, host
META_CALIBRATION = "gvtlink.calibration.{stream}"  # per-channel calibration as JSON strings
META_CONFIG = "gvtlink.config"


def samples_topic(stream: str) -> str:
    return SAMPLES_TOPIC.format(stream=stream)


def stream_of(topic: str) -> str | None:
    if topic.startswith("/daq/") and topic.endswith("/samples"):
        return topic[len("/daq/") : -len("/samples")]
    return None
