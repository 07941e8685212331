"""``gvt modal``: modal parameters of a session (or of an FRF file), checked against the rig's FE modes.

The chain the issue asks for, end to end: FRFs of the accepted hits (``daq/studies/frf.py``, or an ``FRFSet`` saved
by ``gvt frf --out``) → pLSCF stabilisation and automatic or manual pole selection → LSFD shapes, MPC/MPD
(``analysis/modal_id.py``) → the exponential window's added damping removed → each mode paired with the FE
mode one to one by an assignment on MAC and frequency (``analysis/modal_pairing.py``), each row with its quality
figures and flags, and one-line warnings where a figure is poor. Its modes file is what
``gvt export --format uff --modes`` writes as UFF 55 (``daq/studies/uff/export.py::load_modes_json``) and what
model updating (issue 21) reads.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from analysis.errors import BadInput
from analysis.frf import FRFSet
from analysis.modal_id import ModalResult, Target, fe_modes_at_sensors, identify
from analysis.modal_pairing import PairRules, pair_flags, pair_modes
from analysis.model.rig import Rig


@dataclass
class ModalRun:
    source: str
    frf: FRFSet
    result: ModalResult
    f_lo: float
    f_hi: float
    rows: list[dict] = field(default_factory=list)  # one per identified mode (see :func:`mode_rows`)
    refused_hits: list[dict] = field(default_factory=list)  # from the FRF stage, with reasons
    warnings: list[str] = field(default_factory=list)  # one line each: what is poor and what to do


def driving_points(rig: Rig | None, frf: FRFSet) -> dict[str, str]:
    """Reference → the response measured at the same DOF (mass-normalised shapes need one); none if absent."""
    if rig is None:
        return {}
    at = {s.dof: s.name for s in rig.sensors if s.name in frf.outputs}
    return {rig.hammer.name: at[rig.hammer.dof]} if rig.hammer.name in frf.references and rig.hammer.dof in at else {}


def mode_rows(res: ModalResult, rig: Rig | None, outputs: list[str],
              rules: PairRules | None = None) -> tuple[list[dict], list[str]]:  # fmt: skip
    """One row per mode with its quality figures (MPC, MPD, stability count, contribution, flags); with a rig, its
    one-to-one FE partner (``fe_mode`` None when unpaired) and the differences. Also a line per FE mode missed."""
    rules = rules or PairRules()
    n = res.freq_hz.size
    stab = res.stability if res.stability.size == n else np.zeros(n, dtype=int)
    share = res.contribution if res.contribution.size == n else np.full(n, np.nan)
    flags = res.flags if len(res.flags) == n else [[] for _ in range(n)]
    rows = [{"mode": i + 1, "freq_hz": float(res.freq_hz[i]), "zeta": float(res.zeta[i]), "mpc": float(res.mpc[i]),
             "mpd_deg": float(res.mpd[i]), "stability": int(stab[i]), "contribution": float(share[i]), "flags": list(flags[i])}
            for i in range(n)]  # fmt: skip
    if rig is None or not rows:
        return rows, []
    sensors = [s.name for s in rig.sensors]
    if any(o not in sensors for o in outputs):
        return rows, []  # responses that are not the rig's sensors: no FE shapes to compare with
    n_fe = min(len(rig.modes.frequencies_hz), max(2 * len(rows), 10))
    f_fe, z_fe, phi = fe_modes_at_sensors(rig, n_fe)
    phi = phi[[sensors.index(o) for o in outputs], :]
    pairing = pair_modes(res.freq_hz, res.shapes, f_fe, phi, rules)
    extra, missing = pair_flags(pairing, res.freq_hz, f_fe, rules)
    for i, r in enumerate(rows):
        k = int(pairing.fe[i])
        r["flags"] += extra[i]
        if k < 0:
            r.update(fe_mode=None, nearest_fe_mode=int(pairing.nearest[i]) + 1, nearest_mac=float(pairing.nearest_mac[i]))
        else:
            r.update(fe_mode=k + 1, fe_freq_hz=float(f_fe[k]), fe_zeta=float(z_fe[k]), mac=float(pairing.mac[i]),
                     freq_error=float(pairing.df[i]), zeta_error=r["zeta"] / float(z_fe[k]) - 1)  # fmt: skip
    return rows, missing


ADVICE = "check coherence and force levels (gvt frf), or pick poles by hand (--poles)"


def quality_warnings(rows: list[dict], missing: list[str]) -> list[str]:
    """One line per flagged mode (all its flags) and per FE mode nothing pairs with, each saying what to do."""
    out = [f"mode {r['mode']} ({r['freq_hz']:.2f} Hz): {'; '.join(r['flags'])}; {ADVICE}" for r in rows if r["flags"]]
    return out + [f"{m}: identified modes may be missing or wrong there; {ADVICE}" for m in missing]


def rejected_note(res: ModalResult) -> str | None:
    """The poles left out, in one line (``--json`` gives each one's figures)."""
    if not res.rejected:
        return None
    dup = sum(x["reason"].startswith("duplicate") for x in res.rejected)
    freqs = ", ".join(f"{x['freq_hz']:.1f}" for x in res.rejected)
    return (f"left out {len(res.rejected)} stable pole(s) as not physical modes ({dup} duplicate(s) of a mode's pole, "
            f"{len(res.rejected) - dup} explaining < 50 % of the FRFs at their frequency): {freqs} Hz")  # fmt: skip


def usable_outputs(frf: FRFSet) -> FRFSet:
    """``frf`` without the responses that have no FRF (NaN: the hit gate left them out of every hit, e.g. a
    clipped accelerometer; analysis/frf.py), which a modal fit cannot take; BadInput if none is left."""
    keep = np.isfinite(frf.H).all(axis=(1, 2))
    if keep.all():
        return frf
    if not keep.any():
        raise BadInput("no response has an FRF: every one was left out of every hit (clipped or dead); see `gvt frf`")
    per = frf.window.get("averages_per_output")
    window = {**frf.window, "averages_per_output": [c for c, k in zip(per, keep, strict=True) if k]} if per else frf.window
    outputs = [o for o, k in zip(frf.outputs, keep, strict=True) if k]
    return replace(frf, H=frf.H[keep], coherence=frf.coherence[keep], outputs=outputs, window=window)


def modal_from_frf(frf: FRFSet, rig: Rig | None, f_lo: float, f_hi: float, targets: list[Target] | None = None,
                   max_order: int = 60, source: str = "", driving: dict[str, str] | None = None) -> ModalRun:  # fmt: skip
    """``driving``: reference -> response at its DOF (``gvt frf``'s, e.g. each roving hit point's sensor); by
    default the sensor at the rig hammer's DOF."""
    frf = usable_outputs(frf)
    if not f_lo < f_hi <= float(frf.freq[-1]):
        raise BadInput(f"--band {f_lo:g} {f_hi:g}: must satisfy 0 <= low < high <= {frf.freq[-1]:g} Hz (the FRFs' range)")
    dp = driving_points(rig, frf) if driving is None else {r: o for r, o in driving.items() if o in frf.outputs}
    res = identify(frf, f_lo, f_hi, driving=dp, targets=targets, max_order=max_order)
    rows, missing = mode_rows(res, rig, list(frf.outputs))
    return ModalRun(source, frf, res, f_lo, f_hi, rows, warnings=quality_warnings(rows, missing))


def modes_json(run: ModalRun) -> dict:
    """The modes file: ``daq/studies/uff/export.py::load_modes_json``'s format plus the quality and FE columns."""
    shapes = run.result.shapes
    return {
        "source": run.source, "band_hz": [run.f_lo, run.f_hi], "references": list(run.frf.references),
        "freq_hz": [r["freq_hz"] for r in run.rows], "zeta": [r["zeta"] for r in run.rows],
        "outputs": list(run.frf.outputs), "shapes_re": shapes.real.tolist(), "shapes_im": shapes.imag.tolist(),
        "window_sigma_added": run.result.sigma_added, "modes": run.rows, "rejected_poles": run.result.rejected,
        "warnings": run.warnings,
    }  # fmt: skip


def write_modes(run: ModalRun, path: Path) -> None:
    Path(path).write_text(json.dumps(modes_json(run), indent=1, default=float))


def _check(r: dict) -> str:
    """The row's quality in a word or a few: ``ok`` or the kinds of its flags (details in the warnings)."""
    kinds = list(dict.fromkeys(f.split(":")[0] for f in r.get("flags", [])))
    return ",".join(kinds) if kinds else "ok"


def table_text(run: ModalRun) -> str:
    """One line per mode with its quality figures; FE columns when the modes were compared with a rig."""
    fe = any("fe_mode" in r for r in run.rows)
    head = f"{'mode':>4} {'f [Hz]':>10} {'ζ [%]':>7} {'MPC':>6} {'MPD [°]':>8} {'stab':>4} {'share':>5}"
    head += f" {'FE':>3} {'f_FE [Hz]':>10} {'Δf [%]':>7} {'ζ_FE [%]':>8} {'MAC':>6}" if fe else ""
    lines = [head + "  check"]
    for r in run.rows:
        line = (f"{r['mode']:>4} {r['freq_hz']:>10.3f} {100 * r['zeta']:>7.3f} {r['mpc']:>6.3f} {r['mpd_deg']:>8.2f} "
                f"{r.get('stability', 0):>4} {r.get('contribution', float('nan')):>5.2f}")  # fmt: skip
        if fe and r.get("fe_mode") is not None:
            line += (f" {r['fe_mode']:>3} {r['fe_freq_hz']:>10.3f} {100 * r['freq_error']:>+7.3f} "
                     f"{100 * r['fe_zeta']:>8.3f} {r['mac']:>6.3f}")  # fmt: skip
        elif fe:
            line += f" {'—':>3} {'unpaired':>10} {'':>7} {'':>8} {'':>6}"
        lines.append(f"{line}  {_check(r)}")
    return "\n".join(lines)


def load_frf_source(path: Path) -> FRFSet:
    try:
        return FRFSet.from_npz(path)
    except (OSError, KeyError, ValueError) as exc:
        raise BadInput(f"{path}: not an FRF file written by `gvt frf --out` ({type(exc).__name__}: {exc})") from None


def rows_summary(run: ModalRun) -> dict:
    return {"source": run.source, "band_hz": [run.f_lo, run.f_hi], "references": list(run.frf.references),
            "averages": np.asarray(run.frf.n_averages).tolist(), "window_sigma_added": run.result.sigma_added,
            "modes": run.rows, "rejected_poles": run.result.rejected, "warnings": run.warnings,
            "refused_hits": run.refused_hits}  # fmt: skip
