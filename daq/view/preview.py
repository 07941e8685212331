"""A rerun blueprint that plots a log's preview topics, for the log opened in rerun as it is (docs/log-format.md,
"Preview topic").

Why a blueprint: rerun 0.41's MCAP loader decodes a ``/preview/<stream>`` message by schema reflection into one
Arrow struct per message (``gvtlink.Preview_<stream>:message``), whose float fields its Time series view plots
("Plot any scalar": a SeriesLines visualizer whose ``Scalars:scalars`` input is mapped to a struct field with a
jq-like selector). It does not pick such fields by itself: opened without a blueprint the viewport is empty. This
blueprint puts one Time series view per stream and one line per channel and statistic in it.

A blueprint applies to recordings of its application id: convert with ``rerun mcap convert LOG --application-id
gvtlink -o LOG.rrd`` (or pass the id the viewer shows) and open both, ``rerun LOG.rrd preview.rbl``.
"""

from __future__ import annotations

import json
from pathlib import Path

APP_ID = "gvtlink"


def preview_topics(log: str | Path) -> dict[str, tuple[str, list[str], list[str], list[str]]]:
    """Per preview topic of ``log``: (schema name, channel names, field names, statistics) from its channel metadata."""
    from daq.log import layout
    from daq.log.reader import LogReader

    r = LogReader(log)
    schemas = r.schemas()
    out = {}
    for ch in r.channels():
        if ch.topic.startswith(layout.PREVIEW_PREFIX) and ch.schema_id in schemas:
            md = ch.metadata
            out[ch.topic] = (schemas[ch.schema_id].name, json.loads(md["channels"]), json.loads(md["fields"]),
                             md.get("stats", "min,max").split(","))  # fmt: skip
    return out


def preview_blueprint(log: str | Path, out: str | Path, application_id: str = APP_ID):
    """Write ``out`` (.rbl): a Time series view per preview topic of ``log``, a line per channel and statistic (the
    min/max envelope). Returns the blueprint."""
    import rerun as rr
    import rerun.blueprint as rrb
    from rerun.blueprint.encodings import VisualizerComponentMapping

    views = []
    for topic, (schema, channels, fields, stats) in sorted(preview_topics(log).items()):
        lines = []
        for k, name in enumerate(channels):
            for j, stat in enumerate(stats):
                mapping = VisualizerComponentMapping(
                    target="Scalars:scalars", source_kind="SourceComponent", source_component=f"{schema}:message",
                    selector=f".{fields[len(stats) * k + j]}",
                )  # fmt: skip
                lines.append(rr.SeriesLines(names=f"{name} {stat}").visualizer(mappings=[mapping]))
        views.append(rrb.TimeSeriesView(origin=topic, name=f"{topic} (min/max per bucket)", overrides={topic: lines}))
    bp = rrb.Blueprint(rrb.Vertical(*views) if views else rrb.Vertical(), collapse_panels=True)
    bp.save(application_id, str(out))
    return bp
