"""Issue 29, item 6: IR detection under mains hum — the full grid (docs/evaluation.md §10).

Mains hum (50 or 60 Hz and 3 harmonics, ``analysis.evaluation.errors.with_hum``) at 0.5, 1, 2 and 5 % of each
channel's RMS, on every channel or on one (the one at the hammer's point), added to the realistic grid's hits after
1 s of the structure at rest (``with_pretrigger``: what a session's analysis lane sees before its first hit). Rigs:
beam_ch4_exp and beam_al_mid (24 nonlinear hits and their 24 linear twins each) and strip_steel_ch8 (24 linear hits).
Per condition: false events per hit on the linear twins and how many reach confidence 0.9, the hits whose warnings
name hum on the right channels, and on the nonlinear hits precision, recall and label accuracy against the hum-free
run. ``--before`` adds the same with the line canceller off (the detector before issue 29); ``--no-pretrigger`` runs
the records as the grid makes them (the hit at the first sample: nothing to find the lines on before it).

    python bench/eval_hum.py [--before] [--no-pretrigger] [--rig NAME ...] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from analysis.evaluation.detectors import LINES, modal_exchange_health  # noqa: E402
from analysis.evaluation.errors import with_hum, with_pretrigger  # noqa: E402
from analysis.evaluation.grid import CaseData, default_grid, simulate_cases  # noqa: E402
from analysis.evaluation.score import markdown_table, score_events  # noqa: E402
from analysis.evaluation.truth import DEFAULT_WINDOW_S  # noqa: E402

RESULTS = ROOT / "bench" / "results"
#: rig -> the channel at the hammer's point (the one-channel condition)
RIGS = {"beam_ch4_exp": "a13", "beam_al_mid": "s06", "strip_steel_ch8": "b7"}
LEVELS = (0.005, 0.01, 0.02, 0.05)


def _named(warns: list, channels: Sequence[str]) -> bool:
    text = " ".join(m for kind, _, m in warns if kind == "hum")
    return bool(text) and all(f" {c} " in text for c in channels)


def condition(nl: list[CaseData], lin: list[CaseData], f0: float, level: float, one: str | None, lines) -> dict:
    chans = None if one is None else [one]

    def run(d: CaseData):
        return modal_exchange_health(with_hum(d, level, f0, chans) if level else d, lines=lines)

    out_lin = [run(d) for d in lin]
    false = [e for ev, _ in out_lin for e in ev]
    row = {
        "f0": f0, "level": level, "channels": "all" if one is None else one, "lines": lines is not None,
        "linear_hits": len(lin), "linear_false_per_hit": len(false) / max(len(lin), 1),
        "linear_false_conf_0.9": sum(e.confidence >= 0.9 for e in false),
        "hits_named": sum(_named(w, chans or d.sensor_names) for d, (_, w) in zip(lin, out_lin, strict=True)),
        "sensor_faults_claimed": sum(any(k in ("sensor", "blind") for k, _, _ in w) for _, w in out_lin),
    }  # fmt: skip
    if nl:
        s = score_events([run(d)[0] for d in nl], [d.exchanges for d in nl], DEFAULT_WINDOW_S)
        row.update(precision=s.precision, recall=s.recall, label_accuracy=s.label_accuracy, tp=s.tp, fp=s.fp, fn=s.fn)
    return row


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--before", action="store_true", help="also run with the line canceller off")
    ap.add_argument("--no-pretrigger", action="store_true", help="records start at the hit (no quiet time before it)")
    ap.add_argument("--rig", action="append", default=[], help="only these rigs (repeatable)")
    ap.add_argument("--json", type=Path, default=RESULTS / "eval_hum.json")
    args = ap.parse_args(argv)
    pre = 0.0 if args.no_pretrigger else 1.0
    t0 = time.perf_counter()
    rows = []
    for rig, one in RIGS.items():
        if args.rig and rig not in args.rig:
            continue
        data = [with_pretrigger(d, pre) for d in simulate_cases(default_grid(rig="" if rig == "beam_ch4_exp" else rig))]
        nl = [d for d in data if d.case.cubic] if rig != "strip_steel_ch8" else []  # the strip has no nonlinear element
        lin = [d for d in data if not d.case.cubic]
        for lines in (None, LINES) if args.before else (LINES,):
            base = condition(nl, lin, 50.0, 0.0, None, lines)
            rows.append({"rig": rig, **base})
            for f0 in (50.0, 60.0):
                for level in LEVELS:
                    for ch in (None, one):
                        r = {"rig": rig, **condition(nl, lin, f0, level, ch, lines)}
                        if nl:
                            r["recall_drop"] = base["recall"] - r["recall"]
                        rows.append(r)
                        rec = f", recall {r['recall']:.2f} (hum-free {base['recall']:.2f})" if nl else ""
                        on = "on" if lines else "off"
                        print(f"{rig} {f0:g} Hz {100 * level:g} % {r['channels']} lines={on}: "
                              f"{r['linear_false_per_hit']:.2f} false/hit, named {r['hits_named']}/{len(lin)}{rec}",
                              flush=True)  # fmt: skip
    header = ("rig", "lines", "f0", "level %", "channels", "lin. false/hit", "conf>=0.9", "named", "P", "R", "R drop", "label")
    table = [
        (r["rig"], "on" if r["lines"] else "off", f"{r['f0']:g}", f"{100 * r['level']:g}", r["channels"],
         f"{r['linear_false_per_hit']:.2f}", str(r["linear_false_conf_0.9"]), f"{r['hits_named']}/{r['linear_hits']}",
         f"{r.get('precision', float('nan')):.2f}", f"{r.get('recall', float('nan')):.2f}",
         f"{r.get('recall_drop', float('nan')):+.2f}", f"{r.get('label_accuracy', float('nan')):.2f}")
        for r in rows
    ]  # fmt: skip
    md = markdown_table(header, table)
    print(md)
    out = {"benchmark": "eval_hum", "pretrigger_s": pre, "seconds": time.perf_counter() - t0, "rows": rows, "markdown": md}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(out, indent=2, default=float))
    print(f"wrote {args.json} ({out['seconds']:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
