"""``gvt identify LOG --rig RIG --method rfs``: RFS + time-series identification of a grounded attachment (eq. 5.11).

The seed's grounded-NES procedure (§5.3.2, L1633–1660; the kernels are ``analysis/rfs.py``) on a session log: one
hit (``--hit``, default the first accepted) identifies k, alpha, beta, d and mu of eq. 5.11; the other accepted hits
(``--validate``, default all) are re-simulated with the identified model under their measured force and compared by
R² of the displacement (the quantity the seed compared, Fig. 5.10). The rig names the DOF (the hammer's), its mass
(eq. 5.11's m; one DOF: a grounded attachment) and the accelerometer on it; ``--out`` writes the rig with the
identified values (its comments kept), which ``gvt simulate`` runs.

The grounded store (eq. 6.13, ``configs/rigs/store_grounded_ch6.toml``) is the same model in z = hθ without the
Coulomb term: a rig with no Coulomb friction at the DOF fits F_c = 0 (fixed, not a coordinate: :func:`has_coulomb`),
and ``--quantity`` (default per rig: velocity for a rotational ``[nsi]``, the seed's store figures 6.23–6.24,
displacement otherwise, Fig. 5.10) chooses what R² and the tail penalty compare.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from analysis import rfs
from analysis.errors import BadInput
from analysis.model.rig import Rig
from analysis.records import HITS_TOPIC, Hit

#: Record read before each hit's trigger index: the pulse's rising edge, and the quiet the noise floor is taken from
#: (analysis.rfs.noise_floor; ``gvt simulate`` starts its first hit 0.1 s into the session).
PRE_TRIGGER_S = 0.1


@dataclass
class RfsRun:
    """What ``gvt identify --method rfs`` found: the RFS estimate, the optimised model, the hits' comparisons."""

    log: str
    rig: str
    dof: str
    mass: float
    channels: tuple[str, str]
    id_hit: int
    estimate: rfs.RfsEstimate
    processed: rfs.Processed
    result: rfs.TimeSeriesResult
    validation: list[tuple[int, rfs.Comparison]] = field(default_factory=list)
    elapsed_s: float = 0.0
    quantity: str = "displacement"
    coulomb: bool = True

    @property
    def equation(self) -> str:
        """The seed's model: eq. 5.11 (the NES, with friction) or eq. 6.13 (the store: viscous only, in z = hθ)."""
        return "5.11" if self.coulomb else "6.13 (no Coulomb, in z = h theta)"

    def summary(self) -> dict[str, Any]:
        m = self.mass
        est, res = self.estimate.params, self.result.params
        sig = self.result.sigma
        rows = []
        for name in ("k", "alpha", "beta", "d", "mu")[: 5 if self.coulomb else 4]:
            s = None
            if sig is not None:
                s = sig["fc"] / (m * rfs.G) if name == "mu" else sig[name]
            rows.append({"parameter": name, "rfs": est.as_dict(m)[name], "optimised": res.as_dict(m)[name], "sigma": s})
        idc = self.result.identification
        return {
            "log": self.log, "rig": self.rig, "dof": self.dof, "mass_kg": m, "force_channel": self.channels[0],
            "acceleration_channel": self.channels[1], "identification_hit": self.id_hit, "peak_force_N": idc.peak_force,
            "equation": self.equation, "parameters": rows, "fc_N": res.fc, "quantity": self.quantity,
            "coulomb_fitted": self.coulomb,
            "rfs_slices": {"stiffness_points": int(self.estimate.stiffness_idx.size), "damping_points":
                           int(self.estimate.damping_idx.size), "r2_stiffness": self.estimate.r2_stiffness,
                           "r2_damping": self.estimate.r2_damping},
            "identification": {"hit": self.id_hit, "peak_force_N": idc.peak_force, "r2": idc.r2, "tail_ratio": idc.tail_ratio},
            "validation": [{"hit": h, "peak_force_N": c.peak_force, "r2": c.r2, "tail_ratio": c.tail_ratio}
                           for h, c in self.validation],
            "optimiser": {"model_runs": self.result.n_runs, "seconds": self.result.elapsed_s, "message": self.result.message},
            "sigma_note": "1-sigma from the Jacobian with white residuals: a lower bound (the residuals are correlated)",
            "elapsed_s": self.elapsed_s,
        }  # fmt: skip


def _channels(rig: Rig) -> tuple[int, str, str, float]:
    """The grounded DOF (the hammer's), its force and acceleration channels and its mass."""
    s = rig.structure
    if s.n_dof != 1:
        raise BadInput(f"{rig.name}: --method rfs models one grounded DOF (eq. 5.11); this rig has {s.n_dof} DOFs")
    dof = rig.hammer.dof
    acc = next((c.name for c in rig.sensors if c.dof == dof and c.quantity == "acceleration"), None)
    if acc is None:
        raise BadInput(f"{rig.name}: no accelerometer on the hammer's DOF {rig.hammer.dof_name!r}; the RFS needs one")
    return dof, rig.hammer.name, acc, float(s.M[dof, dof])


def has_coulomb(rig: Rig, dof: int) -> bool:
    """Whether the rig models Coulomb friction at the DOF (a grounded ``[[dampers]]`` entry with ``coulomb`` > 0).
    Without it the rig's model is eq. 6.13 (viscous only) and F_c is fixed at 0: a fitted F_c could only drift above
    its true 0 (log coordinates never reach it) and trade off against d in the decay."""
    return any(d.dof == dof and d.ref is None and d.coulomb > 0 for d in rig.structure.dampers)


def default_quantity(rig: Rig) -> str:
    """What the time series compares by default: the velocity for a rotational ``[nsi]`` (the store, Fig. 6.24),
    the displacement otherwise (the NES, Fig. 5.10) — method-nsi §1.12."""
    spec = rig.config.nsi
    return "velocity" if spec is not None and spec.inertia is not None else "displacement"


def read_hits(path: Path, rig: Rig) -> tuple[dict[int, rfs.HitRecord], tuple[str, str], float]:
    """Every accepted hit of the log as a :class:`~analysis.rfs.HitRecord` (force, acceleration), from
    ``PRE_TRIGGER_S`` before its trigger for the rig's record length (shortened to the next hit's pre-trigger)."""
    from daq.log.reader import LogReader, LogReadError

    _dof, fname, aname, mass = _channels(rig)
    try:
        reader = LogReader(path)
        infos = reader.streams()
    except LogReadError as exc:
        raise BadInput(str(exc)) from None
    stream = next((s for s, i in infos.items() if fname in i.channels and aname in i.channels), None)
    if stream is None:
        raise BadInput(f"{path}: no stream carries both {fname!r} and {aname!r} (the rig's hammer and accelerometer)")
    fs = infos[stream].sample_rate
    hits = [Hit.from_json(h) for h in reader.json_messages(HITS_TOPIC)]
    hits = sorted((h for h in hits if h.verdict == "accepted"), key=lambda h: h.index)
    if not hits:
        raise BadInput(f"{path}: the log has no accepted hits ({HITS_TOPIC}); record or simulate a session with hits")
    pre, n_rec = round(PRE_TRIGGER_S * fs), round(rig.config.daq.record_length * fs)
    out: dict[int, rfs.HitRecord] = {}
    for k, h in enumerate(hits):
        j0 = max(0, h.index - pre)
        n = n_rec + (h.index - j0)
        if k + 1 < len(hits):
            n = min(n, hits[k + 1].index - pre - j0)
        d = reader.read_stream(stream, [fname, aname], start=j0 / fs, end=(j0 + n) / fs, on_damage="skip")
        if d.data.shape[0] < n // 2 or d.gaps or d.damaged:
            continue  # an incomplete record (end of log, gap, damage): not usable
        data = np.asarray(d.data, dtype=float)
        out[h.hit] = rfs.HitRecord(fs, data[:, 0], data[:, 1], mass, label=f"hit {h.hit}")
    if not out:
        raise BadInput(f"{path}: no accepted hit has a complete record of {fname!r} and {aname!r}")
    return out, (fname, aname), fs


def identify_rfs(path: Path, rig: Rig, hit: int | None = None, validate: Sequence[int] | None = None,
                 settings: rfs.TimeSeriesSettings | None = None,
                 progress: Callable[[str, float], None] | None = None, quantity: str | None = None) -> RfsRun:  # fmt: skip
    """RFS estimate + time-series optimisation on hit ``hit`` of the log, validation on the others; the Coulomb term
    fitted only if the rig has one (:func:`has_coulomb`), ``quantity`` (default per rig) compared."""
    t0 = time.perf_counter()
    records, chans, _fs = read_hits(path, rig)
    available = sorted(records)
    hit = available[0] if hit is None else hit
    if hit not in records:
        raise BadInput(f"--hit {hit}: not an accepted hit with a complete record; the log has {available}")
    vals = [h for h in available if h != hit] if validate is None else list(validate)
    bad = [h for h in vals if h not in records]
    if bad:
        raise BadInput(f"--validate {bad}: not accepted hits with a complete record; the log has {available}")
    if progress:
        progress("restoring-force surface", 0.0)
    coulomb = has_coulomb(rig, rig.hammer.dof)
    quantity = quantity or (settings.quantity if settings is not None else default_quantity(rig))
    settings = replace(settings or rfs.TimeSeriesSettings(), quantity=quantity, coulomb=coulomb)
    p = rfs.process(records[hit])
    est = rfs.rfs_estimate(p, rfs.SliceSettings(coulomb=coulomb))
    res = rfs.optimise(p, est.params, settings, progress=progress)
    run = RfsRun(str(path), rig.name, rig.hammer.dof_name, records[hit].mass, chans, hit, est, p, res,
                 quantity=quantity, coulomb=coulomb)  # fmt: skip
    for k, h in enumerate(vals):
        run.validation.append((h, rfs.validate(rfs.process(records[h]), res.params, settings)))
        if progress:
            progress("validation", (k + 1) / len(vals))
    run.elapsed_s = time.perf_counter() - t0
    return run


def print_report(console, run: RfsRun) -> None:
    from rich.table import Table

    s = run.summary()
    t = Table(title=f"{run.rig}: eq. {run.equation} from {Path(run.log).name} hit {run.id_hit} ({s['peak_force_N']:.1f} N), "
                    f"m = {run.mass:g} kg at {run.dof}")  # fmt: skip
    for c in ("parameter", "RFS estimate", "optimised", "1-sigma (Jacobian)"):
        t.add_column(c, justify="right")
    units = {"k": "N/m", "alpha": "N/m^(β+1)", "beta": "", "d": "N·s/m", "mu": ""}
    for r in s["parameters"]:
        sig = "-" if r["sigma"] is None else f"{r['sigma']:.3g}"
        t.add_row(f"{r['parameter']} {units[r['parameter']]}".strip(), f"{r['rfs']:.5g}", f"{r['optimised']:.5g}", sig)
    console.print(t)
    v = Table(title=f"{run.quantity} R² (measured chain vs model)")
    for c in ("hit", "use", "peak force N", "R²", "tail amplitude ratio"):
        v.add_column(c, justify="right")
    i = s["identification"]
    v.add_row(str(i["hit"]), "identification", f"{i['peak_force_N']:.1f}", f"{i['r2']:.4f}", f"{i['tail_ratio']:.2f}")
    for r in s["validation"]:
        v.add_row(str(r["hit"]), "validation", f"{r['peak_force_N']:.1f}", f"{r['r2']:.4f}", f"{r['tail_ratio']:.2f}")
    console.print(v)
    o, sl = s["optimiser"], s["rfs_slices"]
    console.print(f"RFS slices: {sl['stiffness_points']} stiffness points (R² {sl['r2_stiffness']:.3f}), "
                  f"{sl['damping_points']} damping points (R² {sl['r2_damping']:.3f}); "
                  f"optimiser: {o['model_runs']} model runs in {o['seconds']:.1f} s ({o['message']})", markup=False)  # fmt: skip


def summary_json(run: RfsRun) -> str:
    return json.dumps(run.summary(), default=lambda x: x.item() if isinstance(x, np.generic) else str(x))


def plot(run: RfsRun, path: Path) -> None:
    """RFS slices with the fits (seed Fig. 5.9e/f) and the hits' displacements, measured and model (Fig. 5.10)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from daq.outputs import atomic_output

    p, est, res = run.processed, run.estimate, run.result.params
    comps = [("identification", run.id_hit, run.result.identification), *(("validation", h, c) for h, c in run.validation[:3])]
    fig = plt.figure(figsize=(9, 3.2 + 1.7 * len(comps)), dpi=100)
    gs = fig.add_gridspec(1 + len(comps), 2, height_ratios=[2.0] + [1.0] * len(comps))
    ax = fig.add_subplot(gs[0, 0])
    si, di = est.stiffness_idx, est.damping_idx
    ax.plot(p.disp[si], p.restoring[si], ".", ms=1.5, color="0.5", label=f"|ẋ| small ({si.size})")
    xs = np.linspace(p.disp[si].min(), p.disp[si].max(), 200)
    ax.plot(xs, est.params.stiffness_force(xs), "-", color="tab:blue", lw=1, label="RFS fit")
    ax.plot(xs, res.stiffness_force(xs), "--", color="tab:red", lw=1, label="optimised")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("r = F − m ẍ [N]")
    ax.set_title("stiffness slice", fontsize=9)
    ax.legend(fontsize=7)
    ax = fig.add_subplot(gs[0, 1])
    ax.plot(p.vel[di], p.restoring[di] - est.params.stiffness_force(p.disp[di]), ".", ms=1.5, color="0.5",
            label=f"|x| small ({di.size}), stiffness removed")  # fmt: skip
    vs = np.linspace(p.vel[di].min(), p.vel[di].max(), 400)
    ax.plot(vs, est.params.damping_force(vs), "-", color="tab:blue", lw=1, label="RFS fit")
    ax.plot(vs, res.damping_force(vs), "--", color="tab:red", lw=1, label="optimised")
    ax.set_xlabel("ẋ [m/s]")
    ax.set_title("damping slice", fontsize=9)
    ax.legend(fontsize=7)
    for row, (use, h, c) in enumerate(comps, start=1):
        ax = fig.add_subplot(gs[row, :])
        scale, unit = (1.0, "ẋ [m/s]") if c.quantity == "velocity" else (1e3, "x [mm]")
        ax.plot(c.t, scale * c.measured, "-", color="k", lw=0.7, label="measured (chain)")
        ax.plot(c.t, scale * c.simulated, "-", color="tab:red", lw=0.7, alpha=0.8, label="model")
        ax.set_ylabel(unit)
        ax.set_title(f"hit {h} ({use}), {c.peak_force:.1f} N: R² = {c.r2:.4f}", fontsize=8)
        if row == 1:
            ax.legend(fontsize=7, loc="upper right")
    ax.set_xlabel("t [s] (record)")
    fig.suptitle(f"{run.rig}: restoring-force surface and time-series identification (eq. 5.11)", fontsize=9)
    fig.tight_layout()
    with atomic_output(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)


def _entry(aot: Any, dof: str) -> Any | None:
    """The first grounded entry (no ``to``) of an array of tables at ``dof``."""
    for t in aot or []:
        if t.get("dof") == dof and t.get("to") is None:
            return t
    return None


def identified_toml(text: str, run: RfsRun) -> str:
    """The rig's TOML with eq. 5.11's identified values at the DOF (comments and layout kept, tomlkit): the grounded
    linear spring (``structure.springs`` ``i = dof`` or ``[[springs]]``), the power-law spring (exponent beta + 1),
    the damper (viscous d, Coulomb F_c = mu m g); entries the rig lacks are added."""
    import tomlkit

    doc = tomlkit.parse(text)
    p, dof = run.result.params, run.dof
    lumped = doc.get("structure", {}).get("springs", []) or []
    spring = next((sp for sp in lumped if sp.get("i") == dof and sp.get("j") is None), None)
    spring = spring if spring is not None else _entry(doc.get("springs"), dof)
    if spring is not None:
        spring["k"] = float(f"{p.k:.6g}")
    else:
        doc.setdefault("springs", tomlkit.aot()).append(tomlkit.item({"dof": dof, "k": float(f"{p.k:.6g}")}))
    nl = _entry(doc.get("nonlinear_springs"), dof)
    vals = {"law": "power", "coefficient": float(f"{p.alpha:.6g}"), "exponent": float(f"{p.beta + 1.0:.6g}")}
    if nl is not None:
        nl.update(vals)
    else:
        doc.setdefault("nonlinear_springs", tomlkit.aot()).append(tomlkit.item({"dof": dof, **vals}))
    dmp = _entry(doc.get("dampers"), dof)
    vals = {"viscous": float(f"{p.d:.6g}")} | ({"coulomb": float(f"{p.fc:.6g}")} if run.coulomb else {})
    if dmp is not None:
        dmp.update(vals)
    else:
        doc.setdefault("dampers", tomlkit.aot()).append(tomlkit.item({"dof": dof, **vals}))
    doc["name"] = f"{doc.get('name', run.rig)}_identified"
    i = run.result.identification
    head = (f"# Identified by 'gvt identify --method rfs' (eq. {run.equation}) from {Path(run.log).name} hit {run.id_hit} "
            f"({i.peak_force:.1f} N): k {p.k:.5g} N/m, alpha {p.alpha:.5g}, beta {p.beta:.5g}, d {p.d:.5g} N s/m, "
            f"mu {p.mu(run.mass):.4g} (F_c {p.fc:.4g} N{'' if run.coulomb else ', fixed'}); "
            f"{run.quantity} R² {i.r2:.4f}.\n")  # fmt: skip
    return head + tomlkit.dumps(doc)


def problems_of(run: RfsRun) -> list[str]:
    """What makes the RFS identification poor (``analysis.nsi_quality.judge``): the R² of the identification hit's
    time series, and of each validation hit re-simulated (the quantity compared)."""
    from analysis.nsi_quality import judge

    i = run.result.identification
    return judge(fit_r2=i.r2, validation_r2=[(f"hit {h} ({c.peak_force:.4g} N)", c.r2) for h, c in run.validation])


def write_identified(run: RfsRun, rig: Rig, out: Path, problems: Sequence[str] = ()) -> None:
    """Write the identified rig, then load it back: it must be a rig ``gvt simulate`` runs. ``problems`` (written
    with ``--force``) go on top of the file."""
    from analysis.model.rig import load_rig
    from daq.outputs import atomic_output

    text = "".join(f"# WRITTEN WITH --force: {p}\n" for p in problems) + identified_toml(Path(rig.path).read_text(), run)
    with atomic_output(out) as tmp:
        tmp.write_text(text)
    load_rig(out)
