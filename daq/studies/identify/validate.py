"""Validation by re-simulation of an NSI identification (issue 22 item 5; seed §5.2 Fig. 5.7, §6.3 Fig. 6.19).

The identified law α|δ|^β δ goes into the rig's TOML as a ``power`` nonlinear spring (coefficient α, exponent β + 1,
``analysis/model/config.py``), with the rig's other entries, comments and the spring's ``to`` kept (tomlkit, as the
RFS path's ``daq.studies.identify.rfs.identified_toml``). That rig and the reference are then compared at validation hit levels
by R² of the attachment's relative displacement and velocity — the quantities the seed compared (displacement for
the NES beam, Fig. 5.7; velocity for the store, Fig. 6.19; method-nsi §1.10–1.12):

* a sweep's reference is the sweep's own rig (the simulated truth), simulated at forces between the sweep's
  smallest and largest that are not on its grid (:func:`validation_forces`);
* a session log's reference is its logged hits: the measured signals through the identification's own
  displacement chain (``analysis.nsi_windows.to_displacement``), against the identified rig driven by the log's
  measured force history from the log's start (one continuous run, so each hit starts from the previous hits'
  tails as in the session) and its simulated acceleration sent through the same chain.
"""

from __future__ import annotations

import datetime
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from analysis.errors import BadInput
from analysis.model.rig import Rig

#: Where between the sweep's smallest and largest force (fractions of its log range) the default validation
#: forces sit: inside the identified range, away from its ends, and (see :func:`validation_forces`) off its grid.
DEFAULT_FRACTIONS = (0.2, 0.5, 0.8)


# --- the identified rig TOML -------------------------------------------------------------------------------------


def spring_index(rig: Rig, att_dof: int) -> int:
    """The rig's ``[[nonlinear_springs]]`` entry acting at the attachment (structure DOF ``att_dof``): the one whose
    DOF or ``to`` is the attachment, else the only one. The structure's springs are in the TOML's order
    (``analysis.model.rig``'s assembly)."""
    springs = rig.structure.nonlinear
    hit = [i for i, s in enumerate(springs) if s.dof == att_dof or s.ref == att_dof]
    if hit:
        return hit[0]
    if len(springs) == 1:
        return 0
    raise BadInput(f"{rig.name}: none of its {len(springs)} nonlinear springs acts at the attachment; cannot write the law")


def provenance(summary: dict[str, Any], alpha: float, beta: float) -> list[str]:
    """The comment block above the identified rig: where the law came from and how well it fits."""
    f = summary.get("fit", {})
    ci_a, ci_b = f.get("alpha_ci", (np.nan, np.nan)), f.get("beta_ci", (np.nan, np.nan))
    return [
        f"Identified by 'gvt identify' (NSI, seed §5.1 eq. 5.8) on {datetime.date.today().isoformat()}",
        f"source: {summary.get('source', '?')}",
        f"attachment: {summary.get('attachment', '?')}; law: {summary.get('law', '?')}",
        f"frequency estimator: {summary.get('frequency', '?')}; smoothing: {summary.get('smoothing', '?')}",
        f"fit: {f.get('mode', '?')} on {f.get('n_points', '?')} points; R^2 = {f.get('r2', float('nan')):.5f}",
        f"alpha = {alpha:.6g} N/m^(beta+1) (95 % {ci_a[0]:.4g} - {ci_a[1]:.4g}); "
        f"beta = {beta:.5f} (95 % {ci_b[0]:.4f} - {ci_b[1]:.4f})",
        f"written as law = 'power', coefficient = alpha, exponent = beta + 1 = {beta + 1:.6g}",
    ]


def identified_toml(text: str, rig: Rig, att_dof: int, alpha: float, beta: float, comment: Sequence[str]) -> str:
    """The rig's TOML ``text`` with its attachment spring replaced by α|w|^(β+1) sign(w) (position, ``dof`` and
    ``to`` kept), renamed ``<name>_identified``, under the provenance ``comment`` lines."""
    import tomlkit

    if not (np.isfinite(alpha) and alpha > 0 and np.isfinite(beta) and beta + 1 > 0):
        raise BadInput(f"identified alpha {alpha:g}, beta {beta:g}: not a law a rig can hold (alpha > 0, beta > -1)")
    doc = tomlkit.parse(text)
    i = spring_index(rig, att_dof)
    entry = doc["nonlinear_springs"][i]
    entry["law"] = "power"
    for key, value, note in (("coefficient", alpha, "N/m^exponent: identified alpha"), ("exponent", beta + 1.0, "beta + 1")):
        item = tomlkit.item(float(f"{value:.6g}"))
        item.comment(note)  # the rig's own comment on the old value would now be wrong
        entry[key] = item
    doc["name"] = f"{doc.get('name', rig.name)}_identified"
    return "".join(f"# {c}\n" for c in comment) + tomlkit.dumps(doc)


def write_identified(text: str, out: Path) -> Rig:
    """Write the identified rig atomically, then load it back with the project's loader (a rig ``gvt simulate`` runs)."""
    from analysis.model.rig import load_rig
    from daq.outputs import atomic_output

    with atomic_output(out) as tmp:
        Path(tmp).write_text(text)
    return load_rig(out)


def load_identified_text(text: str, beside: Path) -> Rig:
    """The identified rig from its text without a user file: written to a temporary file beside the original rig
    (so its relative paths still resolve), loaded, removed."""
    import os
    import tempfile

    from analysis.model.rig import load_rig

    fd, name = tempfile.mkstemp(suffix=".toml", prefix=".identified-", dir=beside)
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
        return load_rig(name)
    finally:
        os.unlink(name)


# --- comparison ---------------------------------------------------------------------------------------------------


def r2(reference: np.ndarray, model: np.ndarray) -> float:
    """Coefficient of determination of ``model`` against ``reference`` (the seed's validation measure, eq. 5.12's
    R²): 1 − Σ(y − ŷ)² / Σ(y − ȳ)²; 1 is a perfect overlay, 0 the reference's mean, negative worse than that."""
    y, yh = np.asarray(reference, float), np.asarray(model, float)
    ss = float(np.sum((y - y.mean()) ** 2))
    return 1.0 - float(np.sum((y - yh) ** 2)) / ss if ss > 0 else float("nan")


def relative(x: np.ndarray, att: int, refs: Sequence[int]) -> np.ndarray:
    """δ = x_att − mean(x_refs) along the last axis (eq. 5.13; grounded without refs)."""
    d = x[..., att]
    return d - x[..., list(refs)].mean(axis=-1) if len(refs) else d.copy()


@dataclass
class ValidationRow:
    force_N: float
    r2_displacement: float
    r2_velocity: float
    peak_ratio: float  # max |δ| of the identified rig over the reference's
    hit: int | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"force_N": self.force_N, "hit": self.hit, "r2_displacement": self.r2_displacement,
                "r2_velocity": self.r2_velocity, "peak_ratio": self.peak_ratio}  # fmt: skip


@dataclass
class Trace:
    t: np.ndarray
    ref_d: np.ndarray
    sim_d: np.ndarray
    ref_v: np.ndarray
    sim_v: np.ndarray


@dataclass
class Validation:
    reference: str  # what the identified rig was compared with
    quantity: str  # how δ and δ' were formed
    rows: list[ValidationRow] = field(default_factory=list)
    traces: list[Trace] = field(default_factory=list)
    elapsed_s: float = 0.0

    def compare(self, force: float, t: np.ndarray, ref: tuple[np.ndarray, np.ndarray], sim: tuple[np.ndarray, np.ndarray],
                hit: int | None = None) -> ValidationRow:  # fmt: skip
        pk = float(np.max(np.abs(ref[0])))
        row = ValidationRow(float(force), r2(ref[0], sim[0]), r2(ref[1], sim[1]),
                            float(np.max(np.abs(sim[0]))) / pk if pk > 0 else float("nan"), hit)  # fmt: skip
        self.rows.append(row)
        self.traces.append(Trace(t, ref[0], sim[0], ref[1], sim[1]))
        return row

    def to_dict(self) -> dict[str, Any]:
        return {"reference": self.reference, "quantity": self.quantity, "rows": [r.to_dict() for r in self.rows],
                "elapsed_s": self.elapsed_s}  # fmt: skip


# --- sweep: against the sweep's own rig ---------------------------------------------------------------------------


def validation_forces(pmin: float, pmax: float, runs: int, fractions: Sequence[float] = DEFAULT_FRACTIONS,
                      within: tuple[float, float] | None = None) -> np.ndarray:  # fmt: skip
    """Log-spaced forces at ``fractions`` of the log range ``within`` (default [pmin, pmax]: the sweep's; issue 29:
    the forces of the runs the law was fitted on, since the law is claimed only there), each moved by half a grid
    step when it falls on the sweep's own grid (``logspace(pmin, pmax, runs)``), so validation never repeats an
    identification run."""
    if not (0 < pmin < pmax):
        raise BadInput(f"validation forces need 0 < pmin < pmax, got {pmin:g}, {pmax:g}")
    lo, hi = np.log10(pmin), np.log10(pmax)
    a, b = (lo, hi) if within is None else (np.log10(within[0]), np.log10(within[1]))
    u = a + np.asarray(fractions, float) * (b - a)
    if runs > 1:
        step = (hi - lo) / (runs - 1)
        k = np.rint((u - lo) / step)
        on = np.abs(u - (lo + k * step)) < 0.05 * step
        u = np.where(on, u + 0.5 * step * np.where(k < runs - 1, 1, -1), u)
    return 10.0**u


def parse_forces(text: str) -> list[float]:
    """``--validate-forces F,F,F``: positive forces in N."""
    try:
        out = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise BadInput(f"--validate-forces {text!r}: expected comma-separated forces in N, e.g. 3,30,300") from None
    if not out or not all(np.isfinite(f) and f > 0 for f in out):
        raise BadInput(f"--validate-forces {text!r}: give one or more positive forces in N")
    return out


def simulate_relative(rig: Rig, dofs: Sequence[int], att: int, refs: Sequence[int], forces: Sequence[float],
                      duration: float, order: int | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """The rig's hammer pulse at each force: (t, δ (B, n), δ' (B, n)) of the attachment (outputs: its DOFs only)."""
    from analysis.model.rig_sim import rig_simulator

    out = [dofs[att], *(dofs[r] for r in refs)]
    sim = rig_simulator(rig, out, order)
    res = sim.run(rig.hammer_force(), duration, rig.sample_rate, list(forces))
    ref_cols = list(range(1, len(out)))
    return res.t, relative(res.displacement, 0, ref_cols), relative(res.velocity, 0, ref_cols)


def validate_sweep(truth: Rig, identified: Rig, dofs: Sequence[int], att: int, refs: Sequence[int], forces: Sequence[float],
                   duration: float, order: int | None) -> Validation:  # fmt: skip
    """Both rigs at ``forces`` with the sweep's duration and integrator; R² of δ and δ' (module docstring)."""
    import time

    t0 = time.perf_counter()
    t, d_ref, v_ref = simulate_relative(truth, dofs, att, refs, forces, duration, order)
    _, d_sim, v_sim = simulate_relative(identified, dofs, att, refs, forces, duration, order)
    val = Validation(f"the sweep's rig {truth.name} (simulated truth), {duration:g} s runs",
                     "attachment relative displacement and velocity from the simulator")  # fmt: skip
    for b, f in enumerate(forces):
        val.compare(f, t, (d_ref[b], v_ref[b]), (d_sim[b], v_sim[b]))
    val.elapsed_s = time.perf_counter() - t0
    return val


# --- log: against the logged hits ---------------------------------------------------------------------------------


def _pick_hits(run, hits: Sequence[int] | None) -> list[int]:
    """``hits`` checked against the hits that gave windows; default the lowest, middle and highest by force."""
    used = [h for h in run.hits if "windows" in h]
    if hits is None:
        by_force = sorted(used, key=lambda h: h["peak_force_N"])
        pick = sorted({0, len(by_force) // 2, len(by_force) - 1}) if by_force else []
        return [by_force[i]["hit"] for i in pick]
    ok = {h["hit"] for h in used}
    bad = [h for h in hits if h not in ok]
    if bad:
        raise BadInput(f"--validate {bad}: not hits that gave windows; those are {sorted(ok)}")
    return list(hits)


def _measured_force(reader, rig: Rig, infos: dict, end: int, fs: float) -> np.ndarray:
    """The hammer channel of the log from its start to sample ``end``, on the stream's index grid (0 in gaps)."""
    ham = rig.hammer.name
    stream = next(n for n, i in infos.items() if ham in i.channels)
    fd = reader.read_stream(stream, [ham], start=0.0, end=end / fs, on_damage="skip")
    idx = np.asarray(fd.index, np.int64)
    force = np.zeros(end)
    keep = (idx >= 0) & (idx < end)
    force[idx[keep]] = np.asarray(fd.data, float)[keep, 0]
    return force


def _simulate_force(identified: Rig, dofs, force: np.ndarray, fs: float, progress) -> np.ndarray:
    """The identified rig's accelerations at ``dofs`` driven by ``force`` from rest, in segments."""
    from analysis.model.forces import ForceSeries
    from analysis.model.rig_sim import rig_simulator

    end = force.size
    sim = rig_simulator(identified, dofs, None)
    fser = ForceSeries(t=np.arange(end) / fs, force=force, peak=1.0)
    acc = np.empty((end, len(dofs)))
    for seg in sim.run_segments(fser, end / fs, fs, [1.0], segment=65536):
        acc[seg.first_index : seg.first_index + seg.t.size] = seg.acceleration[0]
        if progress:
            progress("re-simulating the log with the identified rig", (seg.first_index + seg.t.size) / end)
    return acc


def validate_log(run, rig: Rig, identified: Rig, log: Path, hits: Sequence[int] | None = None,
                 progress: Callable[[str, float], None] | None = None) -> Validation:  # fmt: skip
    """The log's hits ``hits`` (default: the lowest, middle and highest accepted hit that gave windows) against the
    identified rig driven by the log's measured force from the log's start; both through the identification's
    displacement chain over the same padded span (``daq.studies.identify.log``), the chain's velocity stage for δ'."""
    import time

    import analysis.nsi_windows as nw
    from analysis.preprocess import PreprocessSettings, acc_to_disp
    from analysis.records import HITS_TOPIC, Hit
    from daq.log.reader import LogReader
    from daq.studies.identify.log import INTEGRATION_PAD_PERIODS, PRE_TRIGGER_S, _layout, _read_span

    t0 = time.perf_counter()
    reader = LogReader(log)
    infos = reader.streams()
    sources, outs, dofs, quantity = _layout(reader, rig)
    fs = infos[sources[0].stream].sample_rate
    att, refs = run.ident.target.attachment, run.ident.target.relative_to
    hits = _pick_hits(run, hits)
    recs = {h.hit: h for h in (Hit.from_json(m) for m in reader.json_messages(HITS_TOPIC))}
    s = run.settings
    pre, n_rec = round(PRE_TRIGGER_S * fs), round(rig.config.daq.record_length * fs)
    fc = s.integration_corner_hz
    pad = round(INTEGRATION_PAD_PERIODS / fc * fs) if fc else 0
    spans = {}
    for h in hits:
        i0 = recs[h].index - pre
        got = _read_span(reader, sources, outs, i0 - pad, i0 + n_rec + pad, i0, n_rec, fs)
        if got is None:
            raise BadInput(f"hit {h}: its record is incomplete in {log}")
        spans[h] = got
    end = max(first + data.shape[0] for data, first in spans.values())
    acc = _simulate_force(identified, dofs, _measured_force(reader, rig, infos, end, fs), fs, progress)
    ps = PreprocessSettings(vel_corner_hz=fc, disp_corner_hz=fc, order=s.order, mode="zero_phase")
    val = Validation(f"the logged hits of {Path(log).name} (measured force drives the identified rig from the log's start)",
                     "attachment relative displacement (the identification's chain) and velocity (its first stage)")  # fmt: skip
    for h in hits:
        data, first = spans[h]
        at = recs[h].index - pre - first
        sl = slice(at, at + n_rec)
        if all(q == "acceleration" for q in quantity):
            vm, dm = acc_to_disp(data, fs, ps)
        else:
            dm = nw.to_displacement(data, fs, quantity, s)
            vm = np.gradient(dm, 1.0 / fs, axis=0)
        vs, ds = acc_to_disp(acc[first : first + data.shape[0]], fs, ps)
        t = np.arange(n_rec) / fs - PRE_TRIGGER_S
        val.compare(recs[h].peak_force_N, t, (relative(dm[sl], att, refs), relative(vm[sl], att, refs)),
                    (relative(ds[sl], att, refs), relative(vs[sl], att, refs)), hit=h)  # fmt: skip
    val.elapsed_s = time.perf_counter() - t0
    return val


# --- output -------------------------------------------------------------------------------------------------------


def print_validation(console, val: Validation) -> None:
    from rich.table import Table

    t = Table(title=f"validation by re-simulation against {val.reference}")
    cols = ["hit"] if any(r.hit is not None for r in val.rows) else []
    for c in (*cols, "force N", "R² displacement", "R² velocity", "peak ratio"):
        t.add_column(c, justify="right")
    for r in val.rows:
        t.add_row(*([str(r.hit)] if cols else []), f"{r.force_N:.4g}", f"{r.r2_displacement:.5f}", f"{r.r2_velocity:.5f}",
                  f"{r.peak_ratio:.4f}")  # fmt: skip
    console.print(t)
    console.print(f"quantity: {val.quantity}; {val.elapsed_s:.1f} s", markup=False)


def plot_validation(val: Validation, path: Path, title: str) -> None:
    """Overlays of δ and δ' (reference black, identified red), one row per validation level (seed Figs. 5.7, 6.19)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from daq.outputs import atomic_output

    n = len(val.rows)
    fig, axes = plt.subplots(n, 2, figsize=(10, 1.9 * n + 0.8), dpi=100, squeeze=False)
    for k, (r, tr) in enumerate(zip(val.rows, val.traces, strict=True)):
        lab = (f"hit {r.hit}, " if r.hit is not None else "") + f"{r.force_N:.4g} N"
        for j, (y, yh, name, r2v) in enumerate(((tr.ref_d, tr.sim_d, "δ [m]", r.r2_displacement),
                                                 (tr.ref_v, tr.sim_v, "δ' [m/s]", r.r2_velocity))):  # fmt: skip
            ax = axes[k, j]
            ax.plot(tr.t, y, "-", color="k", lw=0.7, label="reference")
            ax.plot(tr.t, yh, "-", color="tab:red", lw=0.7, alpha=0.8, label="identified rig")
            ax.set_ylabel(name)
            ax.set_title(f"{lab}: R² = {r2v:.4f}", fontsize=8)
            if k == 0 and j == 0:
                ax.legend(fontsize=7, loc="upper right")
    for ax in axes[-1]:
        ax.set_xlabel("t [s]")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    with atomic_output(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)


def dumps(doc: dict[str, Any]) -> str:
    from daq.outputs import jsonable

    return json.dumps(doc, default=jsonable)


# --- the verb's tail: identified rig, validation, files ---------------------------------------------------------


@dataclass
class Outputs:
    """What :func:`finish` adds to ``gvt identify``'s summary and prints."""

    identified_toml: str | None
    validation: Validation | None
    validation_png: str | None
    problems: list[str] = field(default_factory=list)  # the fit's and the validation's (analysis.nsi_quality.judge)
    refused: bool = False  # --out asked for, not written: the fit is poor and --force was not given

    def to_dict(self) -> dict[str, Any]:
        return {"identified_toml": self.identified_toml, "validation_png": self.validation_png,
                "validation": None if self.validation is None else self.validation.to_dict(),
                "quality": {"ok": not self.problems, "problems": self.problems,
                            "identified_toml_refused": self.refused}}  # fmt: skip


def validation_problems(val: Validation | None) -> list[str]:
    """The validation levels whose best R² (displacement or velocity) is poor (``analysis.nsi_quality.judge``)."""
    from analysis.nsi_quality import best_r2, judge

    if val is None:
        return []
    labels = [(f"hit {r.hit}, " if r.hit is not None else "") + f"{r.force_N:.4g} N" for r in val.rows]
    return judge(validation_r2=zip(labels, best_r2([(r.r2_displacement, r.r2_velocity) for r in val.rows]), strict=True))


def finish(ident, rig: Rig, dofs: Sequence[int], out_toml: Path | None, val_png: Path | None,
           validate: Callable[[Rig], Validation] | None, force: bool = False) -> Outputs:  # fmt: skip
    """Validate the identified rig (``validate``; None: no validation) from its text in memory, then write it to
    ``out_toml`` only when neither the fit nor the validation is poor, or ``force`` (issue 29: a rig whose own
    validation failed, R² −654, was written). The problems found are returned either way."""
    f = ident.fit
    att_dof = dofs[ident.target.attachment]
    comment = provenance(ident.summary(), f.alpha, f.beta)
    text = identified_toml(Path(rig.path).read_text(), rig, att_dof, f.alpha, f.beta, comment)
    problems = ident.problems()
    val = None
    if problems and out_toml is not None and not force and val_png is None:
        return Outputs(None, None, None, [*problems, "validation not run: the fit itself is poor"], True)
    if validate is not None:
        val = validate(load_identified_text(text, Path(rig.path).parent))
        problems += validation_problems(val)
        if val_png is not None:
            plot_validation(val, val_png, f"{rig.name}: identified law α = {f.alpha:.4g}, β = {f.beta:.4f} re-simulated")
    written = refused = False
    if out_toml is not None:
        if problems and not force:
            refused = True
        else:
            if problems:
                text = "".join(f"# WRITTEN WITH --force: {p}\n" for p in problems) + text
            write_identified(text, out_toml)
            written = True
    return Outputs(str(out_toml) if written else None, val, str(val_png) if val_png and val else None, problems, refused)


def sweep_validator(
    ident, rig: Rig, sweep_dir: Path, forces: Sequence[float] | None
) -> tuple[list[int], Callable[[Rig], Validation]]:
    """The sweep's output DOFs and the validation against its own rig at ``forces`` (default :func:`validation_forces`
    inside the forces of the runs the law was fitted on)."""
    from analysis.model.rig_sim import output_dofs
    from daq.studies.identify.sweep import read_sweep_spec

    spec = read_sweep_spec(sweep_dir)
    dofs = output_dofs(rig, spec["outputs"])
    p_fit = ident.fitted_forces()
    within = (float(p_fit.min()), float(p_fit.max())) if p_fit.size >= 2 and p_fit.min() < p_fit.max() else None
    fv = list(forces) if forces else list(validation_forces(spec["pmin_N"], spec["pmax_N"], int(spec["runs"]), within=within))
    t = ident.target
    dur, order = float(spec["duration_s"]), spec["order"]
    return dofs, lambda idr: validate_sweep(rig, idr, dofs, t.attachment, t.relative_to, fv, dur, order)


def log_dofs(run, rig: Rig) -> list[int]:
    by_name = {s.name: s.dof for s in rig.sensors}
    return [by_name[c] for c in run.channels]
