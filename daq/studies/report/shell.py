"""The page around the sections: the one-line header (log, health, session, rig, where the results came from),
the inline style, and the figures after the tables. One file, no script and no external asset: it opens
anywhere, offline, and prints as it shows."""

from __future__ import annotations

import html
import json
from typing import Any

STYLE = """body{font-family:sans-serif;margin:1.5em;max-width:1200px} table{border-collapse:collapse;font-size:13px}
td,th{border:1px solid #bbb;padding:2px 6px;text-align:right} th{background:#eee} img{max-width:100%}
.none{color:#666;font-style:italic}"""


def header(log, health: str, session: dict[str, Any], rig_name: str, source: str) -> str:
    """The title and the line that says which log, how healthy, which session and rig, results from where."""
    return (
        f"<h1>gvtlink session report</h1><p>log <code>{html.escape(str(log))}</code> · health: {html.escape(health)} · "
        f"session {html.escape(json.dumps(session.get('session', '')))} · rig {html.escape(rig_name)} · "
        f"analysis results from {source}</p>"
    )


def document(head: str, parts: list[str], figs: list[tuple[str, str]]) -> str:
    """The whole HTML page: ``head``, the sections' ``parts`` in order, then each ``(title, data URI)`` figure."""
    fig_html = "".join(f"<h2>{html.escape(n)}</h2><img alt='{html.escape(n)}' src='{src}'>" for n, src in figs)
    return f"""<!DOCTYPE html><html lang="en"><head><meta charset="utf-8"><title>gvtlink report</title>
<style>{STYLE}</style></head><body>{head}{"".join(parts)}{fig_html}</body></html>"""
