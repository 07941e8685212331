"""Restoring-force surface (RFS) and time-series identification of a grounded attachment (seed §5.3.2, eq. 5.11).

The seed characterised its NES on a clamped base before attaching it to the wing (L1633–1653), with the model

    m x'' + d x' + mu m g sgn(x') + (k + alpha |x|^beta) x = F(t)                                 (eq. 5.11)

in two steps: (1) the RFS method [Masri & Caughey 1979]: the restoring force ``r = F - m x''`` over the (x, x')
plane, a stiffness slice (x' ~ 0) and a damping slice (x ~ 0) "manually" fitted (L1647); (2) an optimisation
that maximises R² between the measured and simulated displacement of the identification hit, the RFS values as
the start, with a penalty keeping the simulated amplitude over the last 0.5 s within 75–125 % of the measured one
(L1652). The seed gives neither the fit nor the optimiser; the choices here (docs/rfs.md):

* signal chain (L1646, method-nsi §1.11): acceleration -> mean removed -> trapezoidal integral -> mean removed ->
  3rd-order 2 Hz Butterworth high-pass, zero-phase (``sosfiltfilt``); the same again for the displacement;
* the slices: ``|x'| < v_frac max|x'|`` and ``|x| < x_frac max|x|`` of the free decay (after the force window);
  stiffness ``k, alpha`` by linear least squares for each ``beta`` of a grid refined by a bounded scalar search,
  damping ``d, F_c = mu m g`` by linear least squares on ``[x', sgn x']``; each slice's fit has the other's model
  subtracted first, alternated a few rounds (the other term is not zero on a slice: the friction is ±F_c at x'
  ~ 0);
* the time series: the model simulated by the project's simulator (:class:`~analysis.model.simulate.ImpactSimulator`
  on a one-DOF structure with a :class:`~analysis.model.nonlinear.Damper`, the same compiled integrator that
  ``gvt simulate`` runs an identified rig with) driven by the measured force; its displacement goes through the
  chain's two high-passes, so the filter acts on both sides alike; ``scipy.optimize.least_squares`` (bounded
  trust-region) on the displacement residuals — minimising their sum of squares is maximising R² — plus one
  penalty residual for the 75–125 % band; parameters in logs (``beta`` plain), ``alpha`` through the stiffness
  at a reference amplitude to decorrelate it from ``beta``;
* uncertainty: the Jacobian at the optimum, ``sigma^2 (J^T J)^-1`` — a lower bound, the residuals are not white;
* the grounded store (eq. 6.13, L2154): the same model without the Coulomb term (``coulomb=False``: F_c fixed at 0,
  not fitted — eq. 6.13 has "only viscous damping"), compared on the **velocity** (``quantity="velocity"``: the
  store's Figs. 6.23–6.24 are velocities, method-nsi §1.12): the chain's velocity (one integral, one high-pass)
  against the model's velocity through the same high-pass.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from analysis.errors import BadInput

G = 9.80665  # m/s^2, standard gravity: mu = F_c / (m g)


@dataclass(frozen=True)
class Eq511:
    """The parameters of eq. 5.11: ``k`` N/m, ``alpha`` N/m^(beta+1), ``beta``, ``d`` N s/m, ``fc = mu m g`` N."""

    k: float
    alpha: float
    beta: float
    d: float
    fc: float

    def mu(self, mass: float) -> float:
        return self.fc / (mass * G)

    def stiffness_force(self, x: np.ndarray) -> np.ndarray:
        return self.k * x + self.alpha * np.abs(x) ** self.beta * x

    def damping_force(self, v: np.ndarray) -> np.ndarray:
        return self.d * v + self.fc * np.sign(v)

    def as_dict(self, mass: float) -> dict[str, float]:
        return {"k": self.k, "alpha": self.alpha, "beta": self.beta, "d": self.d, "mu": self.mu(mass), "fc": self.fc}


# --- signal chain (L1646) -------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Chain:
    """The seed's chain for the NES: 3rd-order Butterworth high-pass at 2 Hz after each integration (L1646)."""

    highpass_hz: float = 2.0
    order: int = 3

    def highpass(self, y: np.ndarray, fs: float) -> np.ndarray:
        """Zero-phase (forward-backward) high-pass: the seed does not say the phase; a causal filter would shift the
        displacement against the (unfiltered) acceleration in ``r = F - m x''``."""
        from scipy.signal import butter, sosfiltfilt

        sos = butter(self.order, self.highpass_hz, btype="highpass", fs=fs, output="sos")
        return sosfiltfilt(sos, y - y.mean())

    def integrate(self, acc: np.ndarray, fs: float) -> tuple[np.ndarray, np.ndarray]:
        """Velocity and displacement from an acceleration: the mean removed before and after each integration (as Ch.
        4, L1323), the high-pass after each."""
        from scipy.integrate import cumulative_trapezoid

        a = np.asarray(acc, dtype=float)
        v = cumulative_trapezoid(a - a.mean(), dx=1.0 / fs, initial=0.0)
        v = self.highpass(v - v.mean(), fs)
        x = cumulative_trapezoid(v - v.mean(), dx=1.0 / fs, initial=0.0)
        x = self.highpass(x - x.mean(), fs)
        return v, x

    def filter_displacement(self, x: np.ndarray, fs: float) -> np.ndarray:
        """What the chain does to an exact displacement (integration is exact there): the two high-passes."""
        return self.highpass(self.highpass(np.asarray(x, dtype=float), fs), fs)


# --- one hit --------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class HitRecord:
    """One hit's record: force (N) and acceleration (m/s²) of the attachment, from before the hit to its end."""

    fs: float
    force: np.ndarray
    acc: np.ndarray
    mass: float
    label: str = ""

    def __post_init__(self) -> None:
        f, a = np.asarray(self.force, dtype=float), np.asarray(self.acc, dtype=float)
        if f.ndim != 1 or f.shape != a.shape or f.size < 16:
            raise BadInput(f"hit {self.label}: force and acceleration must be 1-D of one length (>= 16 samples)")
        if not (np.all(np.isfinite(f)) and np.all(np.isfinite(a))):
            raise BadInput(f"hit {self.label}: non-finite samples in the force or the acceleration")
        if not self.mass > 0:
            raise BadInput(f"hit {self.label}: the mass must be positive")

    @property
    def peak_force(self) -> float:
        return float(np.max(np.abs(self.force)))

    @property
    def duration(self) -> float:
        return self.force.size / self.fs


def force_window(force: np.ndarray, level: float = 0.02, pad: int = 8) -> tuple[np.ndarray, int, int]:
    """The hammer pulse alone (a force window): the contiguous run around the peak where ``|F| > level x peak``,
    ``pad`` samples either side, zero elsewhere — so the force channel's noise over the 2 s record is not fed to
    the model as a random load. Returns (windowed force, first, end) sample indices."""
    f = np.asarray(force, dtype=float)
    ip = int(np.argmax(np.abs(f)))
    thr = level * abs(f[ip])
    if thr <= 0:
        raise BadInput("the force channel is zero: no hit to identify from")
    i0 = ip
    while i0 > 0 and abs(f[i0 - 1]) > thr:
        i0 -= 1
    i1 = ip + 1
    while i1 < f.size and abs(f[i1]) > thr:
        i1 += 1
    i0, i1 = max(0, i0 - pad), min(f.size, i1 + pad)
    out = np.zeros_like(f)
    out[i0:i1] = f[i0:i1]
    return out, i0, i1


@dataclass(frozen=True)
class Processed:
    """A hit after the chain: windowed force, velocity and displacement, the restoring force, the pulse span, and
    the noise floor the chain makes of the acceleration's noise (1-sigma of a, v, x; zeros without a pre-trigger)."""

    record: HitRecord
    force: np.ndarray
    vel: np.ndarray
    disp: np.ndarray
    restoring: np.ndarray
    pulse: tuple[int, int]
    noise: tuple[float, float, float]


#: Samples before the pulse needed to estimate the acceleration's noise (0.1 s at 32768 Hz is 3277).
MIN_NOISE_SAMPLES = 64


#: Independent white-noise realisations averaged for the displacement floor at the record's end (a 0.5 s tail of
#: 2-5 Hz noise has few degrees of freedom: one realisation's RMS scatters by tens of per cent).
NOISE_REALISATIONS = 8


def noise_floor(acc: np.ndarray, pulse_start: int, fs: float, chain: Chain, tail_s: float = 0.5,
                seed: int = 0) -> tuple[float, float, float]:  # fmt: skip
    """1-sigma noise of the acceleration, of the velocity (mid-record) and of the displacement over the last
    ``tail_s`` (where the penalty looks; the zero-phase filters' edge lets more drift through there) after the chain:
    the RMS of the acceleration before the pulse (the pre-trigger: the structure at rest) pushed as white noise
    through the same chain (a fixed seed: reproducible). Without ``MIN_NOISE_SAMPLES`` of pre-trigger: zeros."""
    a = np.asarray(acc, dtype=float)
    if pulse_start < MIN_NOISE_SAMPLES:
        return 0.0, 0.0, 0.0
    sa = float(np.std(a[:pulse_start]))
    rng = np.random.default_rng(seed)
    n_tail = max(1, int(tail_s * fs))
    cut = int(0.5 * fs)
    core = slice(cut, -cut) if a.size > 4 * cut else slice(None)
    sv, sx = [], []
    for _ in range(NOISE_REALISATIONS):
        v, x = chain.integrate(rng.standard_normal(a.size) * sa, fs)
        sv.append(np.mean(v[core] ** 2))
        sx.append(np.mean(x[-n_tail:] ** 2))
    return sa, float(np.sqrt(np.mean(sv))), float(np.sqrt(np.mean(sx)))


def process(record: HitRecord, chain: Chain = Chain()) -> Processed:
    """Chain + restoring force ``r = F - m x''`` (Masri–Caughey; method-nsi §1.11 — not written in the seed)."""
    f, i0, i1 = force_window(record.force)
    v, x = chain.integrate(record.acc, record.fs)
    r = f - record.mass * np.asarray(record.acc, dtype=float)
    return Processed(record, f, v, x, r, (i0, i1), noise_floor(record.acc, i0, record.fs, chain))


def moving_span(p: Processed, trim_s: float = 0.05, k_noise: float = 10.0) -> tuple[int, int]:
    """The free decay while the mass moves: from the pulse's end to the last sample whose |x'| exceeds ``k_noise``
    times the velocity noise floor (after it the friction holds the mass: its samples have x' ~ 0 by noise only, a
    random sgn x' and r = k x_stop, which would corrupt both slices), at most to ``trim_s`` before the end."""
    n = p.disp.size
    end = n - int(trim_s * p.record.fs)
    thr = k_noise * p.noise[1]
    moving = np.nonzero(np.abs(p.vel[: max(end, 0)]) > thr)[0]
    last = int(moving[-1]) + 1 if moving.size else end
    return p.pulse[1], min(end, last)


# --- RFS slices (L1646-1647) ----------------------------------------------------------------------------------------


@dataclass(frozen=True)
class SliceSettings:
    """Slice thresholds (fractions of the free decay's max |x'| and max |x|), β bounds, alternation rounds, and the
    end trimmed off (s) where the zero-phase filters' edge transients sit."""

    v_frac: float = 0.03
    x_frac: float = 0.03
    beta_bounds: tuple[float, float] = (0.5, 4.5)
    rounds: int = 4
    trim_s: float = 0.05
    coulomb: bool = True  # False: the damping slice fits d alone (F_c = 0: eq. 6.13's viscous-only store)


@dataclass(frozen=True)
class RfsEstimate:
    """The RFS step's estimate and the two slices (index arrays into the processed record) with their R²."""

    params: Eq511
    stiffness_idx: np.ndarray
    damping_idx: np.ndarray
    r2_stiffness: float
    r2_damping: float


def _r2(y: np.ndarray, yhat: np.ndarray) -> float:
    ss = float(np.sum((y - y.mean()) ** 2))
    return 1.0 - float(np.sum((y - yhat) ** 2)) / ss if ss > 0 else float("nan")


def fit_stiffness(x: np.ndarray, r: np.ndarray, beta_bounds: tuple[float, float] = (0.5, 4.5)) -> tuple[float, float, float]:
    """``r = k x + alpha |x|^beta x`` by least squares: linear in (k, alpha) for each beta, beta by a grid (step
    0.02) then a bounded scalar search around the best grid point."""
    from scipy.optimize import minimize_scalar

    x, r = np.asarray(x, dtype=float), np.asarray(r, dtype=float)
    scale = float(np.max(np.abs(x)))
    if x.size < 3 or scale == 0:
        raise BadInput("the stiffness slice has fewer than 3 points with x != 0; loosen the slice threshold")
    u = x / scale  # conditioned columns: |u| <= 1

    def solve(beta: float) -> tuple[float, np.ndarray]:
        A = np.column_stack([u, np.abs(u) ** beta * u])
        c, *_ = np.linalg.lstsq(A, r, rcond=None)
        return float(np.sum((A @ c - r) ** 2)), c

    grid = np.arange(beta_bounds[0], beta_bounds[1] + 1e-9, 0.02)
    sse = np.array([solve(b)[0] for b in grid])
    j = int(np.argmin(sse))
    lo, hi = grid[max(j - 1, 0)], grid[min(j + 1, grid.size - 1)]
    beta = float(minimize_scalar(lambda b: solve(b)[0], bounds=(lo, hi), method="bounded", options={"xatol": 1e-5}).x)
    c = solve(beta)[1]
    return float(c[0] / scale), float(c[1] / scale ** (beta + 1.0)), beta


def fit_damping(v: np.ndarray, r: np.ndarray, coulomb: bool = True) -> tuple[float, float]:
    """``r = d x' + F_c sgn(x')`` by linear least squares (both columns are known functions of x'); without
    ``coulomb`` the viscous column alone (F_c = 0)."""
    v, r = np.asarray(v, dtype=float), np.asarray(r, dtype=float)
    if v.size < 3 or np.all(np.sign(v) == np.sign(v[0])):
        raise BadInput("the damping slice needs points of both signs of x'; loosen the slice threshold")
    if not coulomb:
        return float(v @ r / (v @ v)), 0.0
    c, *_ = np.linalg.lstsq(np.column_stack([v, np.sign(v)]), r, rcond=None)
    return float(c[0]), float(c[1])


def rfs_estimate(p: Processed, settings: SliceSettings = SliceSettings()) -> RfsEstimate:
    """Stiffness and damping slices of the free decay and their fits, each with the other's model subtracted."""
    n = p.disp.size
    free = np.zeros(n, dtype=bool)
    i0, i1 = moving_span(p, settings.trim_s)
    free[i0:i1] = True
    if free.sum() < 32:
        raise BadInput(f"hit {p.record.label}: too short a free decay after the pulse for an RFS")
    x, v, r = p.disp, p.vel, p.restoring
    vmax, xmax = float(np.max(np.abs(v[free]))), float(np.max(np.abs(x[free])))
    s_idx = np.nonzero(free & (np.abs(v) < settings.v_frac * vmax))[0]
    d_idx = np.nonzero(free & (np.abs(x) < settings.x_frac * xmax))[0]
    est = Eq511(0.0, 0.0, 2.0, 0.0, 0.0)
    for _ in range(settings.rounds):
        k, a, b = fit_stiffness(x[s_idx], r[s_idx] - est.damping_force(v[s_idx]), settings.beta_bounds)
        est = replace(est, k=k, alpha=a, beta=b)
        d, fc = fit_damping(v[d_idx], r[d_idx] - est.stiffness_force(x[d_idx]), settings.coulomb)
        est = replace(est, d=d, fc=fc)
    r2s = _r2(r[s_idx], est.stiffness_force(x[s_idx]) + est.damping_force(v[s_idx]))
    r2d = _r2(r[d_idx], est.stiffness_force(x[d_idx]) + est.damping_force(v[d_idx]))
    return RfsEstimate(est, s_idx, d_idx, r2s, r2d)


# --- simulation of eq. 5.11 and the time-series optimisation (L1652-1653) ------------------------------------------


def eq511_structure(params: Eq511, mass: float, v_eps: float | None = None):
    """Eq. 5.11 as the model layer's one-DOF structure: mass, grounded spring k, power-law spring ``alpha |x|^beta x``
    (the layer's exponent is beta + 1) and a :class:`Damper` (d, F_c)."""
    from analysis.model.nonlinear import DEFAULT_V_EPS, Damper
    from analysis.model.structure import build_lumped

    s = build_lumped(masses=[mass], springs=[(0, None, params.k)], names=["x"],
                     nonlinear_springs=[(0, "power", params.alpha, params.beta + 1.0)] if params.alpha > 0 else [])  # fmt: skip
    damper = Damper(0, viscous=max(params.d, 0.0), coulomb=max(params.fc, 0.0), v_eps=v_eps or DEFAULT_V_EPS)
    return replace(s, dampers=(damper,) if damper.rows() else ())


def simulate_eq511(params: Eq511, mass: float, force: np.ndarray, fs: float, fs_out: float,
                   quantity: str = "displacement") -> np.ndarray:  # fmt: skip
    """Displacement (or ``quantity="velocity"``) of eq. 5.11 at ``fs_out`` under the sampled ``force`` (at ``fs``,
    linearly interpolated; the simulator integrates it exactly over each step), from rest at the first sample."""
    from analysis.model.forces import ForceSeries
    from analysis.model.simulate import ImpactSimulator

    sim = ImpactSimulator(eq511_structure(params, mass), 0, [0])
    t = np.arange(force.size) / fs
    res = sim.run(ForceSeries(t=t, force=np.asarray(force, dtype=float)), force.size / fs, fs_out)
    return (res.velocity if quantity == "velocity" else res.displacement)[0, :, 0]


@dataclass(frozen=True)
class TimeSeriesSettings:
    """``sim_rate``: the rate the model is simulated and compared at (the record decimated by an integer to at
    least this; 8192 Hz keeps omega dt <= 0.07 at the NES's stiffest, a 4e-4 frequency error of the midpoint rule);
    ``tail_s`` and ``band``: the seed's penalty (L1652); ``max_nfev``: model runs the optimiser may take per
    Jacobian-evaluation round trip (least_squares' own count); ``spread``: the bounds as a factor either side of
    the start (beta: ± ``beta_spread``)."""

    sim_rate: float = 8192.0
    tail_s: float = 0.5
    band: tuple[float, float] = (0.75, 1.25)
    max_nfev: int = 60
    spread: float = 10.0
    beta_spread: float = 1.5
    penalty_weight: float = 10.0
    diff_steps: tuple[float, ...] = (1e-3, 1e-4)
    quantity: str = "displacement"  # or "velocity" (the store, Fig. 6.24): what R² and the tail penalty compare
    coulomb: bool = True  # False: F_c fixed at 0 and not a coordinate (eq. 6.13)

    def __post_init__(self) -> None:
        if self.quantity not in QUANTITIES:
            raise BadInput(f"quantity {self.quantity!r}: use 'velocity' or 'displacement'")


#: What the time series compares: the NES's displacement (Fig. 5.10), the store's velocity (Fig. 6.24).
QUANTITIES = ("displacement", "velocity")


@dataclass(frozen=True)
class Comparison:
    """A hit's measured (chain) against the model's (simulated, high-passed) displacement — or velocity, per
    ``quantity`` — at ``fs``, from the pulse."""

    label: str
    peak_force: float
    fs: float
    t: np.ndarray
    measured: np.ndarray
    simulated: np.ndarray
    r2: float
    tail_ratio: float
    quantity: str = "displacement"


def tail_ratio(measured: np.ndarray, simulated: np.ndarray, fs: float, tail_s: float, noise_x: float = 0.0,
               end: int | None = None) -> float:  # fmt: skip
    """RMS of the simulated over the measured displacement in the ``tail_s`` seconds before sample ``end`` (default:
    the record's end; the penalty's amplitude, L1652), the simulated one with the measurement's noise floor
    ``noise_x`` added in quadrature (a measured tail at the noise floor then matches a model at rest)."""
    end = measured.size if end is None else max(1, min(end, measured.size))
    n = max(1, min(end, round(tail_s * fs)))
    m = float(np.sqrt(np.mean(measured[end - n : end] ** 2)))
    s = math.sqrt(float(np.mean(simulated[end - n : end] ** 2)) + noise_x**2)
    return s / m if m > 0 else float("nan")


class _Target:
    """One hit prepared for the objective: decimation, the measured displacement from the pulse on."""

    def __init__(self, p: Processed, settings: TimeSeriesSettings, chain: Chain) -> None:
        fs = p.record.fs
        self.q = max(1, int(fs // settings.sim_rate)) if fs >= settings.sim_rate else 1
        while self.q > 1 and abs(fs / self.q - round(fs / self.q)) > 1e-9 * fs:
            self.q -= 1
        self.fs_out = fs / self.q
        self.p, self.chain, self.settings = p, chain, settings
        self.n = (p.disp.size // self.q) * self.q  # whole decimation steps: the simulation's samples are these
        self.i0 = p.pulse[0] // self.q
        self.velocity = settings.quantity == "velocity"
        self.measured = (p.vel if self.velocity else p.disp)[: self.n : self.q][self.i0 :]
        self.sst = float(np.sum((self.measured - self.measured.mean()) ** 2))
        # The penalty's "last 0.5 s" (L1652) ends where the measured motion does (moving_span): once the friction
        # has stopped the mass, the record's tail holds only the high-passes' response to its rest offset (random
        # within ±F_c/k) and noise — the exact model scored 1.34 there on a simulated 236 N hit (docs/rfs.md).
        self.tail_end = moving_span(p)[1] // self.q - self.i0

    def simulated(self, params: Eq511) -> np.ndarray:
        q = "velocity" if self.velocity else "displacement"
        y = simulate_eq511(params, self.p.record.mass, self.p.force[: self.n], self.p.record.fs, self.fs_out, q)
        # the chain high-passes the velocity once (after the first integral), the displacement twice
        y = self.chain.highpass(y, self.fs_out) if self.velocity else self.chain.filter_displacement(y, self.fs_out)
        return y[self.i0 :]

    def compare(self, params: Eq511) -> Comparison:
        sim = self.simulated(params)
        m = self.measured
        t = (self.i0 + np.arange(m.size)) / self.fs_out
        return Comparison(self.p.record.label, self.p.record.peak_force, self.fs_out, t, m, sim, _r2(m, sim),
                          self.tail(sim), self.settings.quantity)  # fmt: skip

    def tail(self, sim: np.ndarray) -> float:
        noise = self.p.noise[1] if self.velocity else self.p.noise[2]
        return tail_ratio(self.measured, sim, self.fs_out, self.settings.tail_s, noise, self.tail_end)


@dataclass
class TimeSeriesResult:
    """The optimised parameters, their 1-sigma (Jacobian; None if singular), the identification hit's comparison,
    the optimiser's model runs and wall time."""

    params: Eq511
    start: Eq511
    sigma: dict[str, float] | None
    identification: Comparison
    n_runs: int
    elapsed_s: float
    message: str
    history: list[float] = field(default_factory=list)


class _Coords:
    """Optimiser coordinates ``u = (ln k, ln kappa, beta, ln d, ln F_c)``, ``kappa = alpha x_ref^beta`` the power-law
    stiffness at the reference amplitude (half the measured peak), so a change of beta at fixed kappa keeps the
    stiffness there."""

    def __init__(self, x_ref: float, coulomb: bool = True) -> None:
        self.x_ref, self.coulomb = x_ref, coulomb

    @property
    def n(self) -> int:
        """5 coordinates, or 4 without the Coulomb term (F_c fixed at 0: ln 0 is no coordinate)."""
        return 5 if self.coulomb else 4

    def u(self, p: Eq511) -> np.ndarray:
        tiny = 1e-12
        return np.array([math.log(max(p.k, tiny)), math.log(max(p.alpha * self.x_ref**p.beta, tiny)), p.beta,
                         math.log(max(p.d, tiny)), math.log(max(p.fc, tiny))][: self.n])  # fmt: skip

    def p(self, u: np.ndarray) -> Eq511:
        beta = float(u[2])
        fc = math.exp(u[4]) if self.coulomb else 0.0
        return Eq511(math.exp(u[0]), math.exp(u[1]) / self.x_ref**beta, beta, math.exp(u[3]), fc)


def _positive_start(start: Eq511, p: Processed) -> Eq511:
    """A usable start for the log coordinates: an RFS value <= 0 (noise can give one) becomes a small positive one
    scaled from the record (k from the others' magnitude, d and F_c from the restoring force's size)."""
    rscale = float(np.percentile(np.abs(p.restoring), 90)) or 1.0
    vmax = float(np.max(np.abs(p.vel))) or 1.0
    xmax = float(np.max(np.abs(p.disp))) or 1.0
    return Eq511(
        start.k if start.k > 0 else 0.01 * rscale / xmax,
        start.alpha if start.alpha > 0 else 0.5 * rscale / xmax ** (start.beta + 1.0),
        min(max(start.beta, 0.6), 4.4),
        start.d if start.d > 0 else 0.01 * rscale / vmax,
        start.fc if start.fc > 0 else 0.001 * rscale,
    )


def optimise(p: Processed, start: Eq511, settings: TimeSeriesSettings = TimeSeriesSettings(), chain: Chain = Chain(),
             progress: Callable[[str, float], None] | None = None) -> TimeSeriesResult:  # fmt: skip
    """The §1.12 optimisation: maximise R² of the identification hit's displacement (or velocity: ``settings.quantity``),
    with the 75–125 % tail penalty; without ``settings.coulomb`` F_c is fixed at 0."""
    from scipy.optimize import least_squares

    t0 = time.perf_counter()
    tgt = _Target(p, settings, chain)
    start = _positive_start(start, p)
    if not settings.coulomb:
        start = replace(start, fc=0.0)
    # x_ref: half the measured displacement's peak (also when comparing velocities: kappa is a stiffness)
    coords = _Coords(0.5 * float(np.max(np.abs(p.disp[: tgt.n : tgt.q][tgt.i0 :]))), settings.coulomb)
    u0 = coords.u(start)
    width = np.array([math.log(settings.spread)] * 2 + [settings.beta_spread] + [math.log(settings.spread)] * 2)[: coords.n]
    lo, hi = u0 - width, u0 + width
    lo[2], hi[2] = max(lo[2], 0.5), min(hi[2], 5.0)
    u0[2] = min(max(u0[2], lo[2] + 1e-6), hi[2] - 1e-6)
    norm = math.sqrt(tgt.sst) if tgt.sst > 0 else 1.0
    runs, history = [0], []
    budget = settings.max_nfev * (coords.n + 1) * len(settings.diff_steps)  # max_nfev counts calls, not the FD columns

    def residuals(u: np.ndarray) -> np.ndarray:
        runs[0] += 1
        sim = tgt.simulated(coords.p(u))
        res = (sim - tgt.measured) / norm
        ratio = tgt.tail(sim)
        lo_b, hi_b = settings.band
        pen = 0.0 if not math.isfinite(ratio) else max(0.0, lo_b - ratio, ratio - hi_b)
        history.append(1.0 - float(res @ res))
        if progress:
            progress("time-series optimisation", min(1.0, runs[0] / budget))
        return np.append(res, settings.penalty_weight * pen)

    # Two passes: finite-difference steps of 1e-3 then 1e-4 (relative, in u) from the first pass's optimum. The
    # valley along (k, alpha, beta) is flat (R² changes by ~1e-6 over a few per cent of alpha); one pass at 1e-4
    # stopped on xtol 4.8 % low in k and alpha on a simulated 236 N hit, 1e-3 then 1e-4 reached 2.4 % (docs/rfs.md).
    sol = None
    for step in settings.diff_steps:
        x0 = u0 if sol is None else sol.x
        s = least_squares(residuals, x0, bounds=(lo, hi), x_scale=np.array([1.0, 1.0, 0.1, 1.0, 1.0])[: coords.n],
                          diff_step=step, max_nfev=settings.max_nfev, xtol=1e-8, ftol=1e-10)  # fmt: skip
        sol = s if sol is None or s.cost <= sol.cost else sol
    assert sol is not None
    best = coords.p(sol.x)
    sigma = _jacobian_sigma(sol.jac, sol.fun, coords, sol.x)
    cmp = tgt.compare(best)
    return TimeSeriesResult(best, start, sigma, cmp, runs[0], time.perf_counter() - t0, str(sol.message), history)


def _jacobian_sigma(J: np.ndarray, fun: np.ndarray, coords: _Coords, u: np.ndarray) -> dict[str, float] | None:
    """1-sigma of k, alpha, beta, d, F_c from ``sigma^2 (J^T J)^-1`` in the optimiser's coordinates, mapped by the
    delta method (``d alpha = alpha (d ln kappa - ln x_ref d beta)``)."""
    n, m = J.shape
    if n <= m:
        return None
    s2 = float(fun[:-1] @ fun[:-1]) / (n - 1 - m)
    try:
        cov = s2 * np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        return None
    p = coords.p(u)
    G_ = np.zeros((5, m))  # d(k, alpha, beta, d, fc) / du (F_c's row stays 0 when it is fixed)
    G_[0, 0] = p.k
    G_[1, 1], G_[1, 2] = p.alpha, -p.alpha * math.log(coords.x_ref)
    G_[2, 2] = 1.0
    G_[3, 3] = p.d
    if m > 4:
        G_[4, 4] = p.fc
    c = G_ @ cov @ G_.T
    d = np.sqrt(np.clip(np.diag(c), 0.0, None))
    return dict(zip(("k", "alpha", "beta", "d", "fc"), (float(x) for x in d), strict=True))


def validate(p: Processed, params: Eq511, settings: TimeSeriesSettings = TimeSeriesSettings(),
             chain: Chain = Chain()) -> Comparison:  # fmt: skip
    """A hit not used in the identification, re-simulated with the identified model under its measured force."""
    return _Target(p, settings, chain).compare(params)


__all__ = [
    "QUANTITIES",
    "Chain",
    "Comparison",
    "Eq511",
    "G",
    "HitRecord",
    "Processed",
    "RfsEstimate",
    "SliceSettings",
    "TimeSeriesResult",
    "TimeSeriesSettings",
    "eq511_structure",
    "fit_damping",
    "fit_stiffness",
    "force_window",
    "optimise",
    "process",
    "rfs_estimate",
    "simulate_eq511",
    "tail_ratio",
    "validate",
]
