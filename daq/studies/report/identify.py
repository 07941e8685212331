"""``gvt report LOG --identify SUMMARY.json``: the "Identification" section of the session report (issue 22 item 7).

Fed by the JSON summaries ``gvt identify --json`` prints (one file per ``--identify``, repeatable): an NSI summary
(``daq.studies.identify.sweep`` / ``daq.studies.identify.log``: the eq. 5.8 law, α and β with their bootstrap
intervals, R², the validation table of ``daq.studies.identify.validate``) or an RFS one (``daq.studies.identify.rfs``:
eq. 5.11's parameters, the hits' displacement R²). A PNG the summary names (``png``: the RQ-FDP, ``validation_png``:
the overlays) is embedded when the file is found as written or beside the summary. The summaries are read before
the report is drawn, so a bad one is one line, exit 2, and no half-written report.
"""

from __future__ import annotations

import base64
import html
import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from analysis.errors import BadInput

Table = Callable[..., str]


def kind(doc: dict[str, Any]) -> str:
    """``nsi`` (has ``fit``) or ``rfs`` (has ``parameters``); anything else is not an identification summary."""
    if isinstance(doc.get("fit"), dict) and "alpha" in doc["fit"]:
        return "nsi"
    if isinstance(doc.get("parameters"), list):
        return "rfs"
    return ""


def load_summaries(paths: Sequence[Path]) -> list[tuple[Path, dict[str, Any]]]:
    """Each ``--identify`` file as (path, summary); a missing, non-JSON or foreign file raises :class:`BadInput`."""
    out = []
    for p in paths:
        p = Path(p)
        try:
            doc = json.loads(p.read_text())
        except FileNotFoundError:
            raise BadInput(f"--identify {p}: no such file") from None
        except (OSError, ValueError) as exc:
            raise BadInput(f"--identify {p}: not a JSON file ({exc})") from None
        if not isinstance(doc, dict) or not kind(doc):
            raise BadInput(f"--identify {p}: not a 'gvt identify --json' summary (no 'fit' nor 'parameters')")
        out.append((p, doc))
    return out


def _png(name: str | None, beside: Path) -> str | None:
    """The PNG as a data URI, found as written or relative to the summary's directory; None if absent."""
    if not name:
        return None
    for p in (Path(name), beside.parent / name):
        if p.is_file() and p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n":
            return "data:image/png;base64," + base64.b64encode(p.read_bytes()).decode()
    return None


def _g(x: Any, fmt: str = ".5g") -> str:
    try:
        return format(float(x), fmt)
    except (TypeError, ValueError):
        return "-"


def _validation(doc: dict[str, Any], table: Table) -> list[str]:
    v = doc.get("validation")
    if not isinstance(v, dict):
        return [table("validation by re-simulation", [], [], "not run (gvt identify --out / --validation-png)")]
    rows = [[r.get("hit") if r.get("hit") is not None else "-", _g(r.get("force_N"), ".4g"), _g(r.get("r2_displacement"), ".5f"),
             _g(r.get("r2_velocity"), ".5f"), _g(r.get("peak_ratio"), ".4f")] for r in v.get("rows", [])]  # fmt: skip
    return [table(f"validation by re-simulation against {v.get('reference', '?')}",
                  ["hit", "force [N]", "R² displacement", "R² velocity", "peak ratio"], rows),
            f"<p class='note'>{html.escape(str(v.get('quantity', '')))}</p>"]  # fmt: skip


def _nsi(path: Path, doc: dict[str, Any], table: Table) -> list[str]:
    f = doc["fit"]
    ca, cb = f.get("alpha_ci") or ["-", "-"], f.get("beta_ci") or ["-", "-"]
    rows = [["α [N/m^(β+1)]", _g(f.get("alpha")), f"{_g(ca[0], '.4g')} – {_g(ca[1], '.4g')}", _g(f.get("alpha_sd"), ".3g")],
            ["β", _g(f.get("beta"), ".5f"), f"{_g(cb[0], '.4f')} – {_g(cb[1], '.4f')}", _g(f.get("beta_sd"), ".3g")],
            ["R²", _g(f.get("r2"), ".5f"), "", ""]]  # fmt: skip
    title = f"identification (NSI, eq. 5.8) of {doc.get('rig', '?')}: {doc.get('attachment', '?')} — {path.name}"
    parts = [table(title, ["parameter", "value", "95 % bootstrap", "sd"], rows)]
    facts = (f"law: {doc.get('law', '?')}; frequency: {doc.get('frequency', '?')}; fit: {f.get('mode', '?')} on "
             f"{f.get('n_points', '?')} points; linear mode {doc.get('linear_mode', '?')}, f_n {_g(doc.get('f_n_hz'), '.4f')} "
             f"Hz, m {_g(doc.get('mass_kg'))} kg; source: {doc.get('source', '?')}")  # fmt: skip
    if doc.get("identified_toml"):
        facts += f"; identified rig: {doc['identified_toml']}"
    parts.append(f"<p class='note'>{html.escape(facts)}</p>")
    return parts + _validation(doc, table)


def _rfs(path: Path, doc: dict[str, Any], table: Table) -> list[str]:
    rows = [[r.get("parameter"), _g(r.get("rfs")), _g(r.get("optimised")), _g(r.get("sigma"), ".3g")] for r in doc["parameters"]]
    title = f"identification (RFS, eq. 5.11) of {doc.get('rig', '?')} at {doc.get('dof', '?')} — {path.name}"
    parts = [table(title, ["parameter", "RFS estimate", "optimised", "1-sigma (Jacobian)"], rows)]
    i = doc.get("identification") or {}

    def row(r: dict[str, Any], use: str) -> list:
        return [r.get("hit"), use, _g(r.get("peak_force_N"), ".1f"), _g(r.get("r2"), ".4f"), _g(r.get("tail_ratio"), ".2f")]

    hits = [row(i, "identification")] + [row(r, "validation") for r in doc.get("validation") or []]
    parts.append(table("RFS hits: displacement R² (measured chain vs model)", ["hit", "use", "peak force [N]", "R²",
                                                                              "tail amplitude ratio"], hits))  # fmt: skip
    return parts


def identify_section(summaries: Sequence[tuple[Path, dict[str, Any]]], table: Table) -> tuple[list[str], list[str]]:
    """HTML parts (tables, notes, embedded PNGs) of the "Identification" section and the names of its figures."""
    parts: list[str] = []
    figs: list[str] = []
    for path, doc in summaries:
        parts += _nsi(path, doc, table) if kind(doc) == "nsi" else _rfs(path, doc, table)
        for key, what in (("png", "RQ-FDP / RFS plot"), ("validation_png", "validation overlays")):
            src = _png(doc.get(key), path)
            if src is not None:
                name = f"{what} ({path.name})"
                parts.append(f"<h3>{html.escape(name)}</h3><img alt='{html.escape(name)}' src='{src}'>")
                figs.append(name)
            elif doc.get(key):
                parts.append(f"<p class='none'>{html.escape(what)} {html.escape(str(doc[key]))}: file not found</p>")
    return parts, figs
