"""FE model updating against measured modes: the seed's eq. 4.5, a seeded global search, and an updated rig.

The seed's Ch. 4 experiment updated the beam's Young's modulus and the attachment's linear stiffness so that
the FE model's first six bending frequencies matched the measured ones (L1359-L1367, MATLAB GlobalSearch),
minimising eq. 4.5 (L1363, typo ``n-1`` read as ``n=1``; docs/model-updating.md)::

    eps = sum_n |omega_n^exp - omega_n^FE| / (n omega_n^exp)

Ch. 5 and 6 updated thickness, masses and coupling stiffness the same way. Here the parameters and their
bounds are declared in the rig TOML (``[[update.parameters]]``: a ``target`` such as
``structure.youngs_modulus``, ``springs[0].k``, ``point_masses[0].mass``); without a declaration every
Young's modulus, point mass and linear spring of the rig is a candidate (:func:`default_parameters`).

How (docs/model-updating.md):

* measured and FE modes are paired once, at the nominal model: by MAC when the measured shapes are given
  (each measured mode to the FE mode of highest MAC, at least :data:`MIN_PAIR_MAC`), else by order; the pairs
  are checked again at the optimum and the search is repeated if they changed;
* ``n`` of eq. 4.5 is the FE mode number of the pair (the seed's modes 1..6 were the first six);
* the ``eq45+mac`` objective adds ``mac_weight * sum_n (1 - MAC_n) / n``;
* the search runs in ``u = log(p / lo) / log(hi / lo)`` (each bound maps to 0 or 1, a factor is a factor
  anywhere in the range): :func:`scipy.optimize.differential_evolution` (seeded, the analogue of the seed's
  GlobalSearch) or a multi-start :func:`scipy.optimize.least_squares`, then Nelder-Mead on eq. 4.5 itself
  (eq. 4.5 is an L1 norm: its optimum is not least-squares');
* uncertainty: ``cov = s^2 (J^T J)^-1`` with ``J`` the Jacobian of the weighted frequency residuals
  ``r_n = (f_n^exp - f_n^FE) / (n f_n^exp)`` (and MAC terms) in the parameters at the optimum (central
  differences) and ``s^2 = r^T r / (m - p)``: the linearised least-squares standard error, undefined when
  there are no more residuals than parameters.

Mass and stiffness are affine in most parameters (a Young's modulus, a density, a point mass, a spring), so
the model is assembled once and each evaluation is ``M0 + sum (p_i/p0_i - 1) dM_i`` plus one partial
eigensolution (~1.5 ms for beam_ch4_exp's 214 DOFs); a parameter that is not affine (a thickness) rebuilds
the rig from its config each time.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from analysis.errors import BadInput
from analysis.model.update_targets import get_target, set_target

if TYPE_CHECKING:
    from analysis.model.config import RigConfig, UpdateParameter

#: A measured mode whose best FE partner has a lower MAC is left out (a spurious or badly measured mode); 0.6 is
#: well below the 0.99 of the project's measured modes (tests/test_modal_cmd.py) and above any cross-MAC of
#: beam_ch4_exp's FE modes at its 14 sensors (at most 0.3).
MIN_PAIR_MAC = 0.6
OBJECTIVES = ("eq45", "eq45+mac")
#: Eq. 4.5 below this is an exact fit: the eigensolver's own error on beam_ch4_exp's low frequencies is ~1e-8
#: relative (LAPACK's eps x the largest eigenvalue, ~1e11 times the first), and measured frequencies are good to
#: ~1e-4 (tests/test_modal_cmd.py), so nothing below 1e-6 is worth a model solve.
EXACT = 1e-6
OPTIMISERS = ("de", "multistart")

Progress = Callable[[str, float], None]


def default_parameters(cfg: RigConfig) -> list[UpdateParameter]:
    """Without ``[[update.parameters]]``: the beam's Young's modulus (``E``, x0.7..1.3), each point mass
    (``m1``...) and grounded linear spring (``k1``...) within x0.5..2; a lumped rig's masses and springs."""
    from analysis.model.config import BeamSpec, UpdateParameter

    def par(name: str, target: str, v: float, lo: float, hi: float) -> UpdateParameter:
        return UpdateParameter(name=name, target=target, bounds=(lo * v, hi * v))

    out: list[UpdateParameter] = []
    s = cfg.structure
    if isinstance(s, BeamSpec):
        out.append(par("E", "structure.youngs_modulus", s.youngs_modulus, 0.7, 1.3))
    else:
        out += [par(f"mass{i + 1}", f"structure.masses[{i}]", m, 0.5, 2.0) for i, m in enumerate(s.masses)]
        out += [par(f"spring{i + 1}", f"structure.springs[{i}].k", sp.k, 0.5, 2.0) for i, sp in enumerate(s.springs)]
    out += [par(f"m{i + 1}", f"point_masses[{i}].mass", p.mass, 0.5, 2.0) for i, p in enumerate(cfg.point_masses)]
    out += [par(f"k{i + 1}", f"springs[{i}].k", p.k, 0.5, 2.0) for i, p in enumerate(cfg.springs)]
    return out


def select_parameters(cfg: RigConfig, names: Sequence[str] | None = None) -> list[UpdateParameter]:
    """The rig's declared parameters (or :func:`default_parameters`), the ``names`` among them if given."""
    declared = list(cfg.update.parameters) if cfg.update is not None and cfg.update.parameters else default_parameters(cfg)
    if not names:
        return declared
    by_name = {p.name: p for p in declared}
    unknown = [n for n in names if n not in by_name]
    if unknown:
        raise BadInput(f"--params {','.join(unknown)}: not a parameter of this rig; it has {', '.join(by_name)}")
    if len(set(names)) != len(names):
        raise BadInput(f"--params {','.join(names)}: a parameter is named twice")
    return [by_name[n] for n in names]


# --- measured modes -----------------------------------------------------------------------------------
@dataclass(frozen=True)
class MeasuredModes:
    """Identified modes: frequencies (Hz) and, optionally, shapes ``(n_outputs, n_modes)`` at named sensors."""

    freq_hz: np.ndarray
    shapes: np.ndarray | None = None
    outputs: tuple[str, ...] = ()
    source: str = ""
    freq_std_hz: np.ndarray | None = None  # 1-sigma per mode (analysis/model/update_quality.py), None: unknown

    @classmethod
    def from_json(cls, doc: dict, source: str = "") -> MeasuredModes:
        """``gvt modal --modes-out``'s file (daq/studies/modal.py modes_json), or just ``{"freq_hz": [...]}``."""
        try:
            f = np.asarray(doc["freq_hz"], dtype=float)
            shapes = None
            if doc.get("shapes_re") is not None:
                shapes = np.asarray(doc["shapes_re"], dtype=float) + 1j * np.asarray(doc.get("shapes_im") or 0.0, dtype=float)
                shapes = shapes.reshape(len(doc["outputs"]), f.size)
            outputs = tuple(str(o) for o in doc.get("outputs") or ())
            std = None if doc.get("freq_std_hz") is None else np.asarray(doc["freq_std_hz"], dtype=float)
        except (KeyError, TypeError, ValueError) as exc:
            raise BadInput(f"{source}: not a modes file of `gvt modal --modes-out` ({type(exc).__name__}: {exc})") from None
        if f.ndim != 1 or f.size == 0 or not np.all(np.isfinite(f)) or np.any(f <= 0):
            raise BadInput(f"{source}: freq_hz must be a non-empty list of positive frequencies")
        if shapes is not None and not np.all(np.isfinite(shapes)):
            raise BadInput(f"{source}: the mode shapes have non-finite values")
        if std is not None and (std.shape != f.shape or not np.all(std > 0)):
            raise BadInput(f"{source}: freq_std_hz must give one positive 1-sigma per frequency")
        return cls(f, shapes, outputs, source, std)


# --- the parametrised model ----------------------------------------------------------------------------
class ParametricModel:
    """Modes of the rig's linear structure as a function of the parameter values ``p`` (physical units)."""

    def __init__(self, cfg: RigConfig, params: Sequence[UpdateParameter], path: str | Path = "<config>") -> None:
        """``path``: the rig file, whose folder an imported rig's matrix files are relative to."""
        from analysis.model.rig import build_rig

        self.cfg = cfg
        self.path = path
        self.params = list(params)
        self.data = cfg.model_dump()
        self.p0 = np.array([get_target(self.data, p.target) for p in self.params])
        rig = build_rig(cfg, path)
        self.sensor_names = [s.name for s in rig.sensors]
        self.sensor_dofs = np.array(rig.sensor_dofs)
        self.M0, self.K0 = rig.structure.M, rig.structure.K
        self.dM: list[np.ndarray] = []
        self.dK: list[np.ndarray] = []
        for i in range(len(self.params)):
            M, K = self._assemble(self.p0 * np.where(np.arange(len(self.p0)) == i, 2.0, 1.0))
            self.dM.append(M - self.M0)
            self.dK.append(K - self.K0)
        probe = self.p0 * np.linspace(0.8, 1.25, len(self.p0))  # every parameter moved at once: cross terms show
        Mp, Kp = self._assemble(probe)
        Ma, Ka = self._affine(probe)
        scale_m, scale_k = np.abs(self.M0).max(), np.abs(self.K0).max()
        self.affine = bool(np.abs(Mp - Ma).max() <= 1e-10 * scale_m and np.abs(Kp - Ka).max() <= 1e-10 * scale_k)
        self.evaluations = 0

    def _assemble(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        from analysis.model.config import RigConfig
        from analysis.model.rig import build_rig

        data = self.cfg.model_dump()
        for par, v in zip(self.params, p, strict=True):
            set_target(data, par.target, float(v))
        s = build_rig(RigConfig.model_validate(data), self.path).structure
        return s.M, s.K

    def _affine(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        a = p / self.p0 - 1.0
        M, K = self.M0.copy(), self.K0.copy()
        for ai, dM, dK in zip(a, self.dM, self.dK, strict=True):
            if ai != 0.0:
                M += ai * dM
                K += ai * dK
        return M, K

    def matrices(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self._affine(p) if self.affine else self._assemble(p)

    def modes(self, p: np.ndarray, n: int, shapes: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """The first ``n`` frequencies (Hz, rigid-body modes at 0) and, if asked, shapes at the sensor DOFs."""
        import scipy.linalg

        M, K = self.matrices(np.asarray(p, dtype=float))
        n = min(n, M.shape[0])
        self.evaluations += 1
        if shapes:
            lam, phi = scipy.linalg.eigh(K, M, subset_by_index=[0, n - 1])
        else:
            lam, phi = scipy.linalg.eigh(K, M, subset_by_index=[0, n - 1], eigvals_only=True), None
        scale = max(float(np.abs(lam).max()), 1.0)
        f = np.sqrt(np.where(lam < 1e-12 * scale, 0.0, lam)) / (2.0 * np.pi)
        return f, (None if phi is None else phi[self.sensor_dofs, :])


# --- pairing and objective -----------------------------------------------------------------------------
@dataclass(frozen=True)
class Pair:
    measured: int  # index into MeasuredModes.freq_hz
    fe: int  # index into the FE modes (0-based, rigid-body modes included)
    n: int  # elastic mode number, eq. 4.5's n (1-based)
    mac: float | None


def _measured_rows(measured: MeasuredModes, sensor_names: Sequence[str]) -> np.ndarray:
    missing = [o for o in measured.outputs if o not in sensor_names]
    if missing:
        raise BadInput(f"{measured.source}: the mode shapes are at {', '.join(missing[:3])}, not sensors of this rig")
    return np.array([list(sensor_names).index(o) for o in measured.outputs])


def pair_modes(measured: MeasuredModes, f_fe: np.ndarray, phi_fe: np.ndarray | None, n_use: int,
               rows: np.ndarray | None) -> list[Pair]:  # fmt: skip
    """Measured mode -> FE mode among the first ``n_use`` elastic ones: by MAC when shapes are given (the best
    partner, MAC >= :data:`MIN_PAIR_MAC`, one measured mode an FE mode: the higher MAC), else by order."""
    elastic = np.flatnonzero(f_fe > 0)
    if measured.shapes is None or phi_fe is None or rows is None:
        order = np.argsort(measured.freq_hz)[:n_use]
        return [Pair(int(i), int(elastic[k]), k + 1, None) for k, i in enumerate(order) if k < elastic.size]
    from analysis.mac import mac

    m = mac(measured.shapes, phi_fe[rows][:, elastic])
    best: dict[int, Pair] = {}
    for i in range(m.shape[0]):
        k = int(np.argmax(m[i]))
        if m[i, k] < MIN_PAIR_MAC or k >= n_use:
            continue
        if k not in best or (best[k].mac or 0.0) < m[i, k]:
            best[k] = Pair(i, int(elastic[k]), k + 1, float(m[i, k]))
    return [best[k] for k in sorted(best)]


@dataclass
class Problem:
    """Eq. 4.5 (+ MAC terms) over fixed pairs, as a function of the parameter values."""

    model: ParametricModel
    measured: MeasuredModes
    pairs: list[Pair]
    objective: str = "eq45"
    mac_weight: float = 1.0
    rows: np.ndarray | None = None

    @property
    def n_fe(self) -> int:
        return max(p.fe for p in self.pairs) + 1

    @property
    def use_mac(self) -> bool:
        return self.objective == "eq45+mac" and self.rows is not None and self.measured.shapes is not None

    def residuals(self, p: np.ndarray) -> np.ndarray:
        """``(f_exp - f_FE) / (n f_exp)`` per pair, then ``mac_weight (1 - MAC) / n`` per pair with eq45+mac."""
        f, phi = self.model.modes(p, self.n_fe, shapes=self.use_mac)
        fe = np.array([self.measured.freq_hz[q.measured] for q in self.pairs])
        fm = np.array([f[q.fe] for q in self.pairs])
        n = np.array([q.n for q in self.pairs], dtype=float)
        r = (fe - fm) / (n * fe)
        if not self.use_mac:
            return r
        from analysis.mac import mac

        assert phi is not None and self.measured.shapes is not None and self.rows is not None
        macs = np.array([mac(self.measured.shapes[:, q.measured], phi[self.rows, q.fe])[0, 0] for q in self.pairs])
        return np.concatenate([r, self.mac_weight * (1.0 - macs) / n])

    def value(self, p: np.ndarray) -> float:
        """Eq. 4.5 (L1363, n-1 read as n=1), plus the MAC terms: the sum of the residuals' magnitudes."""
        return float(np.abs(self.residuals(p)).sum())

    def residual_std(self) -> np.ndarray | None:
        """The measurement uncertainty of :meth:`residuals`: ``sigma_f / (n f_exp)`` per pair; None when the measured
        frequencies carry none, or with MAC terms (a MAC has no measurement uncertainty here)."""
        if self.measured.freq_std_hz is None or self.use_mac:
            return None
        fe = np.array([self.measured.freq_hz[q.measured] for q in self.pairs])
        n = np.array([q.n for q in self.pairs], dtype=float)
        return np.array([self.measured.freq_std_hz[q.measured] for q in self.pairs]) / (n * fe)


# --- search ---------------------------------------------------------------------------------------------
class Box:
    """``u`` in [0, 1] per parameter <-> ``p = lo (hi / lo)^u``: a factor is the same step anywhere."""

    def __init__(self, params: Sequence[UpdateParameter]) -> None:
        self.lo = np.array([p.bounds[0] for p in params], dtype=float)
        self.hi = np.array([p.bounds[1] for p in params], dtype=float)
        self.span = np.log(self.hi / self.lo)

    def p(self, u: np.ndarray) -> np.ndarray:
        return self.lo * np.exp(np.clip(u, 0.0, 1.0) * self.span)

    def u(self, p: np.ndarray) -> np.ndarray:
        return np.log(np.asarray(p) / self.lo) / self.span


def _search_de(f: Callable[[np.ndarray], float], dim: int, seed: int, progress: Progress | None) -> np.ndarray:
    from scipy.optimize import differential_evolution

    maxiter = 200
    gen = [0]

    def cb(intermediate_result=None) -> None:
        gen[0] += 1
        if progress is not None:
            progress("global search (differential evolution)", min(gen[0] / maxiter, 1.0))

    # a loose stop (population within 1 % or 1e-5 of eq. 4.5): the search only has to find the basin; Nelder-Mead
    # then converges in it (_refine), ~10x cheaper than DE's own endgame
    res = differential_evolution(f, [(0.0, 1.0)] * dim, seed=seed, popsize=10, maxiter=maxiter, tol=1e-2, atol=1e-5,
                                 mutation=(0.5, 1.0), recombination=0.9, init="sobol", polish=False, callback=cb)  # fmt: skip
    return np.asarray(res.x)


def _search_multistart(residuals: Callable[[np.ndarray], np.ndarray], dim: int, seed: int, progress: Progress | None,
                       starts: int = 8) -> np.ndarray:  # fmt: skip
    from scipy.optimize import least_squares
    from scipy.stats import qmc

    u0 = qmc.Sobol(dim, seed=seed).random(starts)
    best, best_cost = None, np.inf
    for i, u in enumerate(u0):
        r = least_squares(residuals, u, bounds=(0.0, 1.0), x_scale=1.0, diff_step=1e-6, xtol=1e-12, ftol=1e-12)
        if r.cost < best_cost:
            best, best_cost = r.x, r.cost
        if progress is not None:
            progress("multi-start local search (least_squares)", (i + 1) / starts)
    assert best is not None
    return np.asarray(best)


def _refine(f: Callable[[np.ndarray], float], residuals: Callable[[np.ndarray], np.ndarray], u: np.ndarray) -> np.ndarray:
    """From the search's best: least_squares on the residuals (quadratic convergence where the model can match
    the data exactly), then Nelder-Mead on eq. 4.5 itself from the better of the two (an L1 norm: its optimum is
    a kink where some residuals vanish, which a gradient method does not settle on, and not the least-squares
    point)."""
    from scipy.optimize import least_squares, minimize

    dim = u.size
    ls = least_squares(residuals, u, bounds=(0.0, 1.0), diff_step=1e-6)
    best = min((u, np.clip(ls.x, 0.0, 1.0)), key=f)
    if f(best) < EXACT:  # an exact fit: nothing for Nelder-Mead to add
        return best
    step = 0.005
    for _ in range(3):  # restarts: a collapsed simplex on a kinked surface stops early
        simplex = np.vstack([best] + [best + np.where(best[i] > 0.5, -step, step) * np.eye(dim)[i] for i in range(dim)])
        r = minimize(f, best, method="Nelder-Mead", bounds=[(0.0, 1.0)] * dim,
                     options={"xatol": 1e-6, "fatol": 0.1 * EXACT, "maxfev": 1000 * dim, "initial_simplex": simplex})  # fmt: skip
        moved = np.abs(r.x - best).max()
        best = np.clip(r.x, 0.0, 1.0)
        step = 0.0005
        if moved < 1e-6:
            break
    return best


@dataclass
class UpdateResult:
    params: list[UpdateParameter]
    nominal: np.ndarray
    values: np.ndarray
    sigma: np.ndarray | None  # 1-sigma per parameter (physical units); None with no more residuals than parameters
    pairs: list[Pair]
    measured_hz: np.ndarray
    model_hz: np.ndarray  # per pair, at the optimum
    residuals: np.ndarray  # eq. 4.5's signed terms per pair
    macs: list[float | None]
    objective: str
    objective_value: float
    nominal_value: float
    optimiser: str
    evaluations: int
    seconds: float
    affine: bool
    notes: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)  # one line each: a value or the fit not to be trusted as is
    chi2_nu: float | None = None  # reduced chi-square of the frequency residuals against their uncertainty
    freq_std_hz: np.ndarray | None = None  # the measured frequencies' 1-sigma per pair, None: unknown

    def rows(self) -> list[dict]:
        """Per pair: FE mode, measured and model frequency, eq. 4.5 term, MAC; with a measurement uncertainty its
        1-sigma and the residual in sigmas (``z``)."""
        out = []
        for i, (q, fe, fm, r, m) in enumerate(zip(self.pairs, self.measured_hz, self.model_hz, self.residuals, self.macs,
                                                  strict=True)):  # fmt: skip
            row = {"mode": i + 1, "fe_mode": q.n, "measured_hz": float(fe), "model_hz": float(fm), "residual": float(r)}
            if m is not None:
                row["mac"] = float(m)
            if self.freq_std_hz is not None:
                row["std_hz"] = float(self.freq_std_hz[i])
                row["z"] = float((fe - fm) / self.freq_std_hz[i])
            out.append(row)
        return out

    def value_rows(self) -> list[dict]:
        out = []
        for i, p in enumerate(self.params):
            row = {"name": p.name, "target": p.target, "nominal": float(self.nominal[i]), "value": float(self.values[i])}
            if self.sigma is not None:
                row["identifiable"] = bool(np.isfinite(self.sigma[i]))
                if np.isfinite(self.sigma[i]):
                    row["sigma"] = float(self.sigma[i])
            out.append(row)
        return out

    def provenance(self, rig: str, source: str, date: str) -> dict:
        return {
            "rig": rig, "source": source, "date": date, "objective": self.objective,
            "objective_value": self.objective_value, "optimiser": self.optimiser, "evaluations": self.evaluations,
            "uncertainty": UNCERTAINTY, **({"chi2_nu": self.chi2_nu} if self.chi2_nu is not None else {}),
            "warnings": list(self.warnings), "modes": self.rows(), "values": self.value_rows(),
        }  # fmt: skip


UNCERTAINTY = (
    "1-sigma = sqrt(diag((J_w^T J_w)^-1) max(1, chi2_nu)), J_w = d(residuals / their measurement sigma)/"
    "d(parameters) at the optimum; without a measurement sigma: sqrt(diag(s^2 (J^T J)^-1)), s^2 = r^T r / (m - p)"
)


def jacobian_sigma(problem: Problem, p: np.ndarray) -> tuple[np.ndarray | None, float | None]:
    """(1-sigma per parameter, chi2_nu) at ``p`` (analysis/model/update_quality.py): weighted by the measured
    frequencies' uncertainty when they carry one. A direction the residuals do not see (e.g. E and density together)
    gives an infinite sigma."""
    from analysis.model.update_quality import jacobian, parameter_sigma

    return parameter_sigma(jacobian(problem.residuals, p), problem.residuals(p), problem.residual_std())


def update(cfg: RigConfig, measured: MeasuredModes, params: Sequence[UpdateParameter], *, objective: str | None = None,
           n_modes: int | None = None, optimiser: str = "de", seed: int | None = None, mac_weight: float | None = None,
           progress: Progress | None = None, path: str | Path = "<config>") -> UpdateResult:  # fmt: skip
    """Update ``params`` of the rig ``cfg`` so that its modes match ``measured`` (module docstring).

    ``objective``, ``n_modes``, ``seed`` and ``mac_weight`` default to the rig's ``[update]`` table. BLAS runs
    one thread: a 214-DOF eigenproblem is too small to share (measured 4.6 ms a solve on one thread, 6.5 ms on
    two, on the 2-core machine), as in analysis/plscf.py."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1):
        return _update(cfg, measured, params, objective=objective, n_modes=n_modes, optimiser=optimiser, seed=seed,
                       mac_weight=mac_weight, progress=progress, path=path)  # fmt: skip


def _update(cfg: RigConfig, measured: MeasuredModes, params: Sequence[UpdateParameter], *, objective: str | None,
            n_modes: int | None, optimiser: str, seed: int | None, mac_weight: float | None,
            progress: Progress | None, path: str | Path = "<config>") -> UpdateResult:  # fmt: skip
    from analysis.model.config import UpdateSpec

    spec = cfg.update or UpdateSpec()
    objective = objective or spec.objective
    n_use = n_modes or spec.modes
    seed = spec.seed if seed is None else seed
    mac_weight = spec.mac_weight if mac_weight is None else mac_weight
    _check_request(measured, params, objective, optimiser)
    t0 = time.perf_counter()
    model = ParametricModel(cfg, params, path)
    rows = _measured_rows(measured, model.sensor_names) if measured.shapes is not None else None
    n_fe = min(max(2 * n_use, n_use + 4), model.M0.shape[0])
    p, pairs, prob, nominal_value, notes = _search(model, measured, params, n_use, n_fe, rows, objective, mac_weight,
                                                   optimiser, seed, progress)  # fmt: skip
    sigma, chi2_nu = jacobian_sigma(prob, p)
    res = prob.residuals(p)
    fm, phi = model.modes(p, n_fe)
    macs: list[float | None] = [q.mac for q in pairs]
    if rows is not None and measured.shapes is not None and phi is not None:
        from analysis.mac import mac

        macs = [float(mac(measured.shapes[:, q.measured], phi[rows, q.fe])[0, 0]) for q in pairs]
    std = prob.residual_std()
    warnings = _warnings(params, p, prob, sigma, chi2_nu)
    if std is None:
        notes.append("the measured frequencies carry no uncertainty: the 1-sigma comes from the residuals' own scatter"
                     + ("" if len(pairs) > len(params) else " and is undefined with no more modes than parameters"))  # fmt: skip
    if progress is not None:
        progress("done", 1.0)
    f_exp = np.array([measured.freq_hz[q.measured] for q in pairs])
    return UpdateResult(
        params=list(params), nominal=model.p0, values=p, sigma=sigma, pairs=pairs, measured_hz=f_exp,
        model_hz=np.array([fm[q.fe] for q in pairs]), residuals=res[: len(pairs)], macs=macs, objective=objective,
        objective_value=prob.value(p), nominal_value=nominal_value, optimiser=optimiser, evaluations=model.evaluations,
        seconds=time.perf_counter() - t0, affine=model.affine, notes=notes, warnings=warnings, chi2_nu=chi2_nu,
        freq_std_hz=None if std is None else std * np.array([q.n for q in pairs]) * f_exp,
    )  # fmt: skip


def _warnings(params: Sequence[UpdateParameter], p: np.ndarray, prob: Problem, sigma: np.ndarray | None,
              chi2_nu: float | None) -> list[str]:  # fmt: skip
    """One line per thing that makes a value untrustworthy: the fit worse than the data's uncertainty, a parameter
    on a bound, unidentifiable or barely determined (analysis/model/update_quality.py)."""
    from analysis.model.update_quality import fit_warning, parameter_notes

    out = []
    std = prob.residual_std()
    if std is not None:
        z = prob.residuals(p)[: len(prob.pairs)] / std
        w = fit_warning(z, chi2_nu, [q.n for q in prob.pairs], len(prob.pairs) - len(params))
        if w:
            out.append(w)
    out += parameter_notes([q.name for q in params], [tuple(q.bounds) for q in params], p, Box(params).u(p), sigma,
                           len(prob.pairs))  # fmt: skip
    return out


def _check_request(measured: MeasuredModes, params: Sequence[UpdateParameter], objective: str, optimiser: str) -> None:
    """One line for a request that cannot run: unknown objective or optimiser, nothing to update, MAC without shapes."""
    if objective not in OBJECTIVES:
        raise BadInput(f"--objective {objective}: use one of {', '.join(OBJECTIVES)}")
    if optimiser not in OPTIMISERS:
        raise BadInput(f"--optimiser {optimiser}: use one of {', '.join(OPTIMISERS)}")
    if not params:
        raise BadInput("no parameter to update: declare [[update.parameters]] in the rig or give --params")
    if objective == "eq45+mac" and measured.shapes is None:
        raise BadInput(f"{measured.source}: --objective eq45+mac needs mode shapes, and the modes file has none")


def _search(model: ParametricModel, measured: MeasuredModes, params: Sequence[UpdateParameter], n_use: int, n_fe: int,
            rows, objective: str, mac_weight: float, optimiser: str, seed: int | None,
            progress: Progress | None) -> tuple[np.ndarray, list, Problem, float, list[str]]:  # fmt: skip
    """Global search then local refinement, repeated (at most 3 times) while the measured/FE mode pairs at the optimum
    differ from those it was searched with: (values, pairs, problem, the objective at the nominal values, notes)."""
    box = Box(params)
    p = model.p0.copy()
    notes: list[str] = []
    nominal_value = float("nan")
    for _round in range(3):
        f, phi = model.modes(p, n_fe)
        pairs = pair_modes(measured, f, phi, n_use, rows)
        if len(pairs) < len(params):
            raise BadInput(
                f"{measured.source}: {len(pairs)} measured mode(s) pair with the rig's first {n_use} FE modes, fewer than the "
                f"{len(params)} parameters; give more modes or fewer --params"
            )
        prob = Problem(model, measured, pairs, objective, mac_weight, rows)
        if _round == 0:
            nominal_value = prob.value(model.p0)

        def fu(u: np.ndarray, prob: Problem = prob) -> float:
            return prob.value(box.p(u))

        def ru(u: np.ndarray, prob: Problem = prob) -> np.ndarray:
            return prob.residuals(box.p(u))

        if optimiser == "de":
            u = _search_de(fu, len(params), seed, progress)
        else:
            u = _search_multistart(ru, len(params), seed, progress)
        if progress is not None:
            progress("local refinement (least_squares, Nelder-Mead on eq. 4.5)", 0.0)
        p = box.p(_refine(fu, ru, u))
        f, phi = model.modes(p, n_fe)
        again = pair_modes(measured, f, phi, n_use, rows)
        if [(q.measured, q.fe) for q in again] == [(q.measured, q.fe) for q in pairs]:
            break
        notes.append("the mode pairs changed at the optimum; searched again with the new pairs")
    return p, pairs, prob, nominal_value, notes


# --- the updated rig file -------------------------------------------------------------------------------
def _sig(v: float) -> float:
    return float(f"{v:.9g}")


def updated_toml(text: str, result: UpdateResult, provenance: dict) -> str:
    """The rig file ``text`` with the updated values and an ``[update.provenance]`` table (comments kept: tomlkit)."""
    import tomlkit

    doc = tomlkit.parse(text)
    for par, v in zip(result.params, result.values, strict=True):
        set_target(doc, par.target, _sig(float(v)))
    upd = doc.get("update")
    if upd is None:
        upd = tomlkit.table()
        doc["update"] = upd
    if "provenance" in upd:
        del upd["provenance"]
    prov = tomlkit.table()
    for k, v in provenance.items():
        if k in ("modes", "values"):
            continue
        prov[k] = _sig(v) if isinstance(v, float) else v
    for key in ("modes", "values"):
        aot = tomlkit.aot()
        for row in provenance[key]:
            t = tomlkit.table()
            for k, v in row.items():
                t[k] = _sig(v) if isinstance(v, float) else v
            aot.append(t)
        prov[key] = aot
    upd["provenance"] = prov
    return tomlkit.dumps(doc)
