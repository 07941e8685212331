"""``gvt modal``: modal parameters of a session (or of an FRF file), checked against the rig's FE modes.

The chain the issue asks for, end to end: FRFs of the accepted hits (``daq/studies/frf.py``, or an ``FRFSet`` saved
by ``gvt frf --out``) → pLSCF stabilisation and automatic or manual pole selection → LSFD shapes, MPC/MPD
(``analysis/modal_id.py``) → the exponential window's added damping removed → each mode paired with the FE
mode of highest MAC at the sensor DOFs. Its modes file is what ``gvt export --format uff --modes`` writes as
UFF 55 (``daq/studies/uff/export.py::load_modes_json``) and what model updating (issue 21) will read.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from analysis.errors import BadInput
from analysis.frf import FRFSet
from analysis.modal_id import ModalResult, Target, fe_modes_at_sensors, identify, pair_with_fe
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


def driving_points(rig: Rig | None, frf: FRFSet) -> dict[str, str]:
    """Reference → the response measured at the same DOF (mass-normalised shapes need one); none if absent."""
    if rig is None:
        return {}
    at = {s.dof: s.name for s in rig.sensors if s.name in frf.outputs}
    return {rig.hammer.name: at[rig.hammer.dof]} if rig.hammer.name in frf.references and rig.hammer.dof in at else {}


def mode_rows(res: ModalResult, rig: Rig | None, outputs: list[str]) -> list[dict]:
    """Frequency, damping, MPC, MPD per mode; with a rig, the FE mode of highest MAC and the differences."""
    rows = [{"mode": i + 1, "freq_hz": float(f), "zeta": float(z), "mpc": float(c), "mpd_deg": float(d)}
            for i, (f, z, c, d) in enumerate(zip(res.freq_hz, res.zeta, res.mpc, res.mpd, strict=True))]  # fmt: skip
    if rig is None or not rows:
        return rows
    sensors = [s.name for s in rig.sensors]
    if any(o not in sensors for o in outputs):
        return rows  # responses that are not the rig's sensors: no FE shapes to compare with
    n_fe = min(len(rig.modes.frequencies_hz), max(2 * len(rows), 10))
    f_fe, z_fe, phi = fe_modes_at_sensors(rig, n_fe)
    phi = phi[[sensors.index(o) for o in outputs], :]
    j, m = pair_with_fe(res.shapes, phi)
    for r, k, mac in zip(rows, j, m, strict=True):
        r.update(fe_mode=int(k) + 1, fe_freq_hz=float(f_fe[k]), fe_zeta=float(z_fe[k]), mac=float(mac),
                 freq_error=r["freq_hz"] / float(f_fe[k]) - 1, zeta_error=r["zeta"] / float(z_fe[k]) - 1)  # fmt: skip
    return rows


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
    return ModalRun(source, frf, res, f_lo, f_hi, mode_rows(res, rig, list(frf.outputs)))


def modes_json(run: ModalRun) -> dict:
    """The modes file: ``daq/studies/uff/export.py::load_modes_json``'s format plus the quality and FE columns."""
    shapes = run.result.shapes
    return {
        "source": run.source, "band_hz": [run.f_lo, run.f_hi], "references": list(run.frf.references),
        "freq_hz": [r["freq_hz"] for r in run.rows], "zeta": [r["zeta"] for r in run.rows],
        "outputs": list(run.frf.outputs), "shapes_re": shapes.real.tolist(), "shapes_im": shapes.imag.tolist(),
        "window_sigma_added": run.result.sigma_added, "modes": run.rows,
    }  # fmt: skip


def write_modes(run: ModalRun, path: Path) -> None:
    Path(path).write_text(json.dumps(modes_json(run), indent=1, default=float))


def table_text(run: ModalRun) -> str:
    """One line per mode; FE columns when the modes were paired with a rig."""
    fe = bool(run.rows) and "mac" in run.rows[0]
    head = f"{'mode':>4} {'f [Hz]':>10} {'ζ [%]':>7} {'MPC':>6} {'MPD [°]':>8}"
    head += f" {'FE':>3} {'f_FE [Hz]':>10} {'Δf [%]':>7} {'ζ_FE [%]':>8} {'MAC':>6}" if fe else ""
    lines = [head]
    for r in run.rows:
        line = f"{r['mode']:>4} {r['freq_hz']:>10.3f} {100 * r['zeta']:>7.3f} {r['mpc']:>6.3f} {r['mpd_deg']:>8.2f}"
        if fe:
            line += (f" {r['fe_mode']:>3} {r['fe_freq_hz']:>10.3f} {100 * r['freq_error']:>+7.3f} "
                     f"{100 * r['fe_zeta']:>8.3f} {r['mac']:>6.3f}")  # fmt: skip
        lines.append(line)
    return "\n".join(lines)


def load_frf_source(path: Path) -> FRFSet:
    try:
        return FRFSet.from_npz(path)
    except (OSError, KeyError, ValueError) as exc:
        raise BadInput(f"{path}: not an FRF file written by `gvt frf --out` ({type(exc).__name__}: {exc})") from None


def rows_summary(run: ModalRun) -> dict:
    return {"source": run.source, "band_hz": [run.f_lo, run.f_hi], "references": list(run.frf.references),
            "averages": np.asarray(run.frf.n_averages).tolist(), "window_sigma_added": run.result.sigma_added,
            "modes": run.rows, "refused_hits": run.refused_hits}  # fmt: skip
