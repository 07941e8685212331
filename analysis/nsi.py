"""Nonlinear system identification of a local attachment from the RQ frequency–displacement plot (seed §5.1).

The seed's second half (L1471–L1505, digest method-nsi.md §1.7–1.10):

1. **Characteristic displacement** of the relative displacement δ across the attachment over a window or a
   whole run, ``δ̄ = (1/N) Σ |δ_n|`` (eq. 5.2, the discrete form of eq. 5.1). δ is the attachment minus the
   mean of its connection points (eq. 5.13, with the "+" the physics needs; eq. 5.12 prints "−"), or the
   attachment DOF itself for a grounded one. Measured data first gets the Ch. 5 extra 3rd-order 6 Hz
   Butterworth high-pass (L1747) that removes a mode which never engages the attachment.
2. **RQ-FDP**: per run/window the pair (δ̄, RQ frequency of the attachment's POM), the POM picked by MAC
   against the attachment's linear mode (eq. 5.6); two POMs that both resemble that mode are the 1:1
   capture signature ("similar POMs", L1555, L1566) and such points are marked and left out of the fit
   (L1747). Pairs are sorted by δ̄ (L1573) and the fit is made to a *filtered* curve (L1608), whose filter
   the seed does not name: here a centred running median over ``smooth_window`` points of the δ̄-sorted,
   capture-free curve (robust to single-run outliers of the POD, which a Savitzky–Golay fit is not).
3. **Law** ``f(δ̄) = (1/2π) sqrt(ω_n² + κ (α/m) δ̄^β)`` — eq. 5.8 with κ = 1 (the seed's secant substitution
   of δ̄ for δ, L1503). ``kappa="hb"`` is the harmonic-balance alternative this module adds: a sinusoid of
   amplitude A has δ̄ = 2A/π, and one harmonic of α|δ|^β δ gives the equivalent stiffness
   α A^β (2/√π) Γ((β+3)/2)/Γ((β+4)/2), so κ(β) = (π/2)^β (2/√π) Γ((β+3)/2)/Γ((β+4)/2) (1.85 at β = 2).
4. **Fit**: where the curve crosses a low-energy linear frequency f_i at δ̄_i (linear interpolation), α is
   pinned by eq. 5.9 and β alone is fitted on eq. 5.10; otherwise α and β together (Ch. 6, L2120). The
   objective is R² (L1608), maximised by ``scipy.optimize.differential_evolution`` (the seed used MATLAB's
   GlobalSearch); the uncertainty is a pairs bootstrap of the capture-free points, each replicate refined
   by a bounded local least-squares from the global optimum (a global search per replicate would cost
   ~100x as much for the same answer on a unimodal problem).

Pure numpy/scipy: arrays in, arrays or frozen dataclasses out.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace
from typing import Literal

import numpy as np

from analysis.errors import BadInput

FloatArray = np.ndarray

#: The Ch. 5 extra high-pass on the relative displacement before δ̄ (L1747): 3rd-order Butterworth, 6 Hz.
SEED_DELTA_HIGHPASS_HZ = 6.0
SEED_DELTA_HIGHPASS_ORDER = 3
#: β bounds of the seed's fits (L1608, L2120) and its α range for the two-parameter fit (N/m^(β+1)).
SEED_BETA_BOUNDS = (0.5, 3.5)
SEED_ALPHA_BOUNDS = (1e3, 1e14)
#: MAC above which a POM "resembles" the attachment's linear mode; two such POMs in one run/window are the
#: seed's similar-POM (1:1 capture) signature (L1555, L1566). The seed gives no number; 0.6 is the MAC where
#: the shape is more that mode than anything else.
SIMILAR_MAC = 0.6


# ------------------------------------------------------------------------------ characteristic displacement
def relative_displacement(disp: FloatArray, attachment: int, relative_to: tuple[int, ...] = ()) -> FloatArray:
    """δ(t) = x_attachment − mean of the connection points (eq. 5.13); the attachment itself when grounded.

    ``disp`` is (n_samples, n_channels) or (runs, n_samples, n_channels); the indices are channel columns.
    """
    d = np.asarray(disp, dtype=float)
    x = d[..., attachment]
    if relative_to:
        x = x - d[..., list(relative_to)].mean(axis=-1)
    return x


def highpass_delta(
    delta: FloatArray, fs: float, corner_hz: float | None = SEED_DELTA_HIGHPASS_HZ, order: int = SEED_DELTA_HIGHPASS_ORDER
) -> FloatArray:
    """The Ch. 5 filter on δ before averaging (L1747): Butterworth high-pass, zero phase along the last axis.

    Zero phase (``sosfiltfilt``) because δ̄ is a magnitude average and the seed states no phase (as for its
    integration chain, method-nsi §1.11). ``corner_hz=None`` returns δ unchanged (the computational studies
    used the raw simulated displacement, L1573)."""
    if corner_hz is None:
        return np.asarray(delta, dtype=float)
    import scipy.signal

    if not 0 < corner_hz < fs / 2:
        raise BadInput(f"δ high-pass corner {corner_hz:g} Hz must lie in (0, fs/2 = {fs / 2:g} Hz)")
    sos = scipy.signal.butter(order, corner_hz, btype="highpass", fs=fs, output="sos")
    return scipy.signal.sosfiltfilt(sos, np.asarray(delta, dtype=float), axis=-1)


def characteristic_displacement(delta: FloatArray, bounds: FloatArray | None = None) -> FloatArray:
    """δ̄ = (1/N) Σ|δ_n| (eq. 5.2) over the whole last axis, or per window ``bounds`` (k, 2) ``[start, stop)``.

    Whole record: returns δ̄ with the leading shape of ``delta`` (a float for a 1-D record). Windows: (k,) for
    a 1-D record — the seed's one value per POD window (42 of them in Ch. 5, L1747)."""
    d = np.abs(np.asarray(delta, dtype=float))
    if bounds is None:
        return d.mean(axis=-1)
    b = np.asarray(bounds, dtype=np.int64).reshape(-1, 2)
    if d.ndim != 1:
        raise BadInput("per-window δ̄ needs one 1-D record")
    if b.size and (b[:, 0].min() < 0 or b[:, 1].max() > d.size or np.any(b[:, 1] <= b[:, 0])):
        raise BadInput(f"window bounds must lie in [0, {d.size}] with start < stop")
    c = np.concatenate([[0.0], np.cumsum(d)])
    return (c[b[:, 1]] - c[b[:, 0]]) / (b[:, 1] - b[:, 0])


# ------------------------------------------------------------------------------------------------ RQ-FDP
@dataclass(frozen=True)
class AttachmentPick:
    """Per run/window: the column of the attachment's POM, its MAC, and whether two POMs resemble the mode."""

    index: np.ndarray  # (k,) POM column
    mac: FloatArray  # (k,) MAC of that POM with the attachment's linear mode
    capture: np.ndarray  # (k,) bool: a second POM with MAC >= similar_mac (1:1 capture, L1566)


def pick_attachment_pom(mac_to_mode: FloatArray, similar_mac: float = SIMILAR_MAC) -> AttachmentPick:
    """The POM with the highest MAC to the attachment's linear mode (eq. 5.6, L1551), per row of
    ``mac_to_mode`` (k, n_poms); a row where two POMs both reach ``similar_mac`` is flagged as capture."""
    m = np.atleast_2d(np.asarray(mac_to_mode, dtype=float))
    idx = np.argmax(m, axis=1)
    best = m[np.arange(m.shape[0]), idx]
    capture = np.sum(m >= similar_mac, axis=1) >= 2
    return AttachmentPick(index=idx, mac=best, capture=capture)


def running_median(y: FloatArray, window: int) -> FloatArray:
    """Centred running median, the window shrinking (still centred) at the ends (no end bias on a monotone
    curve: at the first point the "median" is the point itself)."""
    if window < 1 or window % 2 == 0:
        raise BadInput(f"smoothing window must be a positive odd number of points, got {window}")
    y = np.asarray(y, dtype=float)
    h, n = window // 2, y.size
    out = np.empty_like(y)
    for i in range(n):
        r = min(h, i, n - 1 - i)
        out[i] = np.median(y[i - r : i + r + 1])
    return out


@dataclass(frozen=True)
class RqFdp:
    """The attachment's RQ frequency–displacement curve, sorted by δ̄ (L1573).

    ``order`` maps the sorted points back to the input runs/windows; ``capture`` marks the 1:1 capture points
    (excluded from fits, L1747); ``smooth`` is the running median of the capture-free points (NaN at capture
    points), the "filtered" curve the seed fits (L1608)."""

    dbar: FloatArray
    freq_hz: FloatArray
    capture: np.ndarray
    mac: FloatArray
    smooth: FloatArray
    order: np.ndarray
    smooth_window: int

    @property
    def fit_mask(self) -> np.ndarray:
        return ~self.capture & np.isfinite(self.smooth) & (self.dbar > 0)

    def to_dict(self) -> dict:
        return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in asdict(self).items()}


def rq_fdp(
    dbar: FloatArray,
    freq_hz: FloatArray,
    mac: FloatArray | None = None,
    capture: np.ndarray | None = None,
    smooth_window: int = 5,
) -> RqFdp:
    """Sort (δ̄, f) by δ̄, keep the capture marks, smooth the capture-free curve (see the module docstring)."""
    d = np.asarray(dbar, dtype=float).ravel()
    f = np.asarray(freq_hz, dtype=float).ravel()
    if d.shape != f.shape or d.size == 0:
        raise BadInput(f"δ̄ and frequency need the same non-zero length, got {d.size} and {f.size}")
    if not (np.all(np.isfinite(d)) and np.all(d >= 0)):
        raise BadInput("δ̄ must be finite and non-negative")
    cap = np.zeros(d.size, bool) if capture is None else np.asarray(capture, bool).ravel()
    mc = np.full(d.size, np.nan) if mac is None else np.asarray(mac, dtype=float).ravel()
    cap = cap | ~np.isfinite(f)
    order = np.argsort(d, kind="stable")
    d, f, cap, mc = d[order], f[order], cap[order], mc[order]
    smooth = np.full(d.size, np.nan)
    keep = ~cap
    if keep.any():
        smooth[keep] = running_median(f[keep], min(smooth_window, _odd_at_most(int(keep.sum()))))
    return RqFdp(dbar=d, freq_hz=f, capture=cap, mac=mc, smooth=smooth, order=order, smooth_window=smooth_window)


def _odd_at_most(n: int) -> int:
    return max(1, n if n % 2 else n - 1)


# --------------------------------------------------------------------------------------------------- law
def hb_factor(beta: float | FloatArray) -> FloatArray | float:
    """κ(β) = (π/2)^β (2/√π) Γ((β+3)/2) / Γ((β+4)/2): the one-harmonic equivalent stiffness of α|δ|^β δ at the
    amplitude A = π δ̄ / 2 of a sinusoid with mean |δ| = δ̄ (1 at β = 0, 1.8506 at β = 2)."""
    from scipy.special import gammaln

    b = np.asarray(beta, dtype=float)
    k = (np.pi / 2) ** b * (2 / np.sqrt(np.pi)) * np.exp(gammaln((b + 3) / 2) - gammaln((b + 4) / 2))
    return float(k) if k.ndim == 0 else k


Kappa = Literal["seed", "hb", "exact", "modal", "modal-exact"]
#: The multi-mode laws (:class:`ModalLaw`): they need the rig's modal basis, not only ω_n and m.
MODAL_KINDS = ("modal", "modal-exact")

_GL_X, _GL_W = np.polynomial.legendre.leggauss(48)
_TH = 0.25 * np.pi * (_GL_X + 1.0)  # θ on (0, π/2): x = A sin θ over a quarter period
_TH_W = 0.25 * np.pi * _GL_W


def backbone_ratios(u: FloatArray, beta: float) -> tuple[FloatArray, FloatArray]:
    """Exact free periodic motion of m x'' + k x + α|x|^β x = 0 at amplitude A, u = α A^β / k: (ω/ω_n, δ̄/A).

    With x = A sin θ the quarter period is ∫ A cos θ dθ / v(x), v² = (2/m)(V(A) − V(x)), and the mean |x| over it
    ∫ x dt / (T/4); both integrands are smooth on [0, π/2] (g ∝ cos² θ near π/2), so 48-point Gauss–Legendre is
    exact to ~1e-12 (Duffing x'' + x³ = 0: ω = 0.8472 A, tested). Neither eq. 5.8 (κ = 1) nor one harmonic
    (κ_hb) is this curve: at ω = 1.3 ω_n the harmonic-balance Δω² at a given δ̄ is 2.8 % low (β = 2), enough
    to bias β by +0.8 % and α (×δ̄^−Δβ) by +14 % on lo_store_ch6 (docs/nsi.md)."""
    uu = np.asarray(u, dtype=float)[..., None]
    s, c = np.sin(_TH), np.cos(_TH)
    g = (1.0 - s**2) + 2.0 * uu / (beta + 2.0) * (1.0 - s ** (beta + 2.0))
    q = c / np.sqrt(g)
    t4 = (q * _TH_W).sum(-1)  # ω_n T/4
    m1 = (s * q * _TH_W).sum(-1)  # ω_n ∫x dt / A over a quarter
    return (0.5 * np.pi) / t4, m1 / t4


def exact_law_hz(dbar: FloatArray, omega_n: float, mass: float, alpha: float, beta: float) -> FloatArray:
    """f(δ̄) on the exact backbone of m δ'' + m ω_n² δ + α|δ|^β δ = 0, δ̄ the mean |δ| of that periodic motion
    (eq. 5.2 over whole periods): ω/ω_n and δ̄/A tabulated on u = α A^β/k ∈ [1e-8, 1e4] and interpolated in
    log δ̄ (monotone: both A and ω grow with u)."""
    k = mass * omega_n**2
    if not (alpha > 0 and k > 0 and beta > 0):
        return np.full(np.shape(dbar), np.nan) if np.ndim(dbar) else math.nan  # type: ignore[return-value]
    u = np.logspace(-8.0, 4.0, 300)
    r, s = backbone_ratios(u, beta)
    db = s * (u * k / alpha) ** (1.0 / beta)
    d = np.asarray(dbar, dtype=float)
    lr = np.interp(np.log(np.maximum(d, 1e-300)), np.log(db), np.log(r), left=0.0)
    return omega_n * np.exp(lr) / (2.0 * np.pi)


def _kappa(kind: Kappa, beta: float | FloatArray) -> FloatArray | float:
    if kind == "seed":
        return 1.0
    if kind in ("hb", "exact"):  # exact: the intersection's α by the small-amplitude (HB) limit, refined below
        return hb_factor(beta)
    if kind in MODAL_KINDS:
        raise BadInput(f"law {kind!r} needs the rig's modal basis (FitSettings.modal); it has no one-mass κ")
    raise BadInput(f"law form must be 'seed' (eq. 5.8), 'hb', 'exact', 'modal' or 'modal-exact', got {kind!r}")


def law_hz(dbar: FloatArray, omega_n: float, mass: float, alpha: float, beta: float, kappa: Kappa = "seed") -> FloatArray:
    """Eq. 5.8: f(δ̄) = (1/2π) sqrt(ω_n² + κ (α/m) δ̄^β), ω_n in rad/s (κ = 1 for the seed's form); ``"exact"``:
    :func:`exact_law_hz`, the one-DOF backbone without the one-harmonic approximation."""
    if kappa == "exact":
        return exact_law_hz(dbar, omega_n, mass, alpha, beta)
    d = np.asarray(dbar, dtype=float)
    return np.sqrt(omega_n**2 + _kappa(kappa, beta) * (alpha / mass) * d**beta) / (2.0 * np.pi)


def alpha_from_intersection(f_i: float, dbar_i: float, beta: float, mass: float, omega_n: float, kappa: Kappa = "seed") -> float:
    """Eq. 5.9: α = (m / δ̄_i^β) ((2π f_i)² − ω_n²), the α that puts f(δ̄_i) on the linear frequency f_i."""
    if dbar_i <= 0:
        raise BadInput("the intersection's δ̄ must be positive")
    a = float(mass / dbar_i**beta * ((2.0 * np.pi * f_i) ** 2 - omega_n**2) / _kappa(kappa, beta))
    if kappa == "exact" and a > 0:  # the α whose exact backbone passes through (δ̄_i, f_i): a 1-D root in log α
        import scipy.optimize

        g = lambda la: float(exact_law_hz(dbar_i, omega_n, mass, 10.0**la, beta)) - f_i  # noqa: E731
        lo, hi = math.log10(a) - 2.0, math.log10(a) + 2.0
        if g(lo) < 0 < g(hi):
            a = 10.0 ** scipy.optimize.brentq(g, lo, hi, xtol=1e-12)
    return a


def law_hz_intersection(dbar: FloatArray, omega_n: float, f_i: float, dbar_i: float, beta: float) -> FloatArray:
    """Eq. 5.10: f(δ̄) = (1/2π) sqrt(ω_n² + ((2π f_i)² − ω_n²)(δ̄/δ̄_i)^β), one parameter (β); the same for
    either κ form, since κ is absorbed into α."""
    d = np.asarray(dbar, dtype=float)
    return np.sqrt(omega_n**2 + ((2.0 * np.pi * f_i) ** 2 - omega_n**2) * (d / dbar_i) ** beta) / (2.0 * np.pi)


def find_intersection(dbar: FloatArray, freq_hz: FloatArray, f_linear: float) -> float | None:
    """δ̄ where the (sorted, smoothed) curve first rises through ``f_linear``, by linear interpolation between
    the bracketing points (L1592); None when it never crosses upward."""
    d, f = np.asarray(dbar, float), np.asarray(freq_hz, float)
    ok = np.isfinite(f)
    d, f = d[ok], f[ok]
    s = f - f_linear
    up = np.flatnonzero((s[:-1] < 0) & (s[1:] >= 0))
    if up.size == 0:
        return None
    i = int(up[0])
    return float(d[i] + (d[i + 1] - d[i]) * (-s[i]) / (s[i + 1] - s[i]))


def r_squared(y: FloatArray, yhat: FloatArray) -> float:
    """R² = 1 − Σ(y − ŷ)² / Σ(y − ȳ)² (method-nsi §1.10)."""
    y, yhat = np.asarray(y, float), np.asarray(yhat, float)
    sst = float(np.sum((y - y.mean()) ** 2))
    return 1.0 - float(np.sum((y - yhat) ** 2)) / sst if sst > 0 else float("nan")


# ------------------------------------------------------------------------------------- multi-mode backbone
@dataclass(frozen=True)
class ModalBasis:
    """The rig's linear model truncated to its lowest modes, as the multi-mode law needs it.

    ``omega2`` (n,) the modes' ω² (rad²/s²) of the mass-normalised modes, ``b`` (n,) each mode's value of the
    attachment's stretch δ (``AttachmentModel.phi_delta``), ``mode`` the attachment's linear mode, ``shapes``
    (n_out, n) the modes at the outputs (the MAC of eq. 5.6 is taken there, as for the measured POMs; None:
    in modal coordinates)."""

    omega2: FloatArray
    b: FloatArray
    mode: int
    shapes: FloatArray | None = None


def _exact_over_hb(r: FloatArray, beta: float) -> FloatArray:
    """ρ = Δω²_exact / Δω²_hb of the one-mass backbone at the same δ̄, as a function of r = κ_hb α δ̄^β / k (the HB
    equivalent stiffness over the linear one). Both depend on u = α A^β / k only (:func:`backbone_ratios`), so ρ is
    a function of r and β alone; ρ → 1 as r → 0 (one harmonic is exact in the weakly nonlinear limit)."""
    u = np.logspace(-6.0, 5.0, 300)
    w, s = backbone_ratios(u, beta)
    r_hb = hb_factor(beta) * s**beta * u
    rho = (w**2 - 1.0) / r_hb
    return np.interp(np.log(np.maximum(r, 1e-300)), np.log(r_hb), rho)


class ModalLaw:
    """f(δ̄) of the attachment's mode of the rig's linear model plus the power-law spring's one-harmonic stiffness.

    Every law above is a one-mass law (eq. 5.8). On a beam the mode shape changes as the spring stiffens (the tip
    of beam_ch4_sim tends to a pin: its first mode saturates near the clamped–pinned 16.7 Hz instead of growing
    like the one-mass backbone), on the LO–store the LO moves with the store, on the NES beam the NES mode mixes
    with 1B/2B (docs/nsi.md "Issue 22's 5 %"). Here a sinusoidal stretch of amplitude A = π δ̄ / 2 (δ̄ = 2A/π)
    adds the describing-function stiffness k_eq(A) = α A^β (2/√π) Γ((β+3)/2)/Γ((β+4)/2) = κ_hb(β) α δ̄^β across
    the spring, so in the truncated modal basis K_r = diag(ω²) + k_eq b bᵀ (M_r = I). The attachment's mode is the
    eigenvector with the highest MAC to its linear mode — the same pick eq. 5.6 makes among the measured POMs, so
    the law models the branch the RQ-FDP follows (through a veering it stays with the attachment-like shape).

    The branch's λ(k_eq) depends on k_eq alone, not on α, β or δ̄, so it is tabulated once (``n_grid`` points of
    log k_eq over r = k_eq b_m² / ω_m² ∈ [1e-7, 1e6], 200 a decade) as g(k) = (λ − ω_m²)/k, smooth in log k and → b_m² as k → 0
    (first-order perturbation, the one-mass law with m = 1/b_m²). A fit's evaluation is then one ``np.interp``.
    ``exact=True`` multiplies k_eq by the one-mass exact/HB ratio ρ(r, β) at the same r (:func:`_exact_over_hb`),
    which makes the law the exact backbone on a one-DOF rig; whether that correction is right on a multi-mode rig
    is measured (docs/nsi.md "A multi-mode backbone")."""

    def __init__(self, basis: ModalBasis, exact: bool = False, n_grid: int = 2600):
        w2 = np.asarray(basis.omega2, float)
        b = np.asarray(basis.b, float)
        m = int(basis.mode)
        if w2.ndim != 1 or b.shape != w2.shape or not 0 <= m < w2.size:
            raise BadInput("modal basis: ω² and the stretch need one value per mode, and the mode must be one of them")
        if not b[m] ** 2 > 1e-12 * float(np.max(b**2)):
            raise BadInput(f"modal basis: linear mode {m + 1} does not stretch the spring")
        self.omega2, self.b, self.mode, self.exact = w2, b, m, exact
        self.k_unit = float(max(w2[m], 1e-300) / b[m] ** 2)  # k_eq that doubles ω_m² in the one-mass limit
        k = self.k_unit * np.logspace(-7.0, 6.0, n_grid)
        Kr = np.diag(w2)[None] + k[:, None, None] * np.outer(b, b)[None]
        lam, V = np.linalg.eigh(Kr)  # (n_grid, n), (n_grid, n, n)
        if basis.shapes is not None:
            S = np.asarray(basis.shapes, float)
            X = np.einsum("om,gmj->gjo", S, V)  # each eigenvector at the outputs
            ref = S[:, m]
        else:
            X, ref = np.swapaxes(V, 1, 2), np.eye(w2.size)[m]
        mac = (X @ ref) ** 2 / (np.sum(X**2, axis=-1) * float(ref @ ref))
        # continuation over increasing k: adding stiffness never lowers an eigenvalue, so the followed branch's λ
        # never falls; a higher MAC on a lower branch (the NES locked to the beam at very large k_eq, where its
        # own mode no longer exists) is another branch, not the attachment's
        j = np.empty(k.size, np.int64)
        lam_prev = -np.inf
        for i in range(k.size):
            ok = lam[i] >= lam_prev * (1.0 - 1e-12)
            j[i] = int(np.argmax(np.where(ok, mac[i], -1.0)))
            lam_prev = lam[i, j[i]]
        self.log_k = np.log(k)
        self.g = (lam[np.arange(k.size), j] - w2[m]) / k
        self.mac = mac[np.arange(k.size), j]

    @property
    def omega_n(self) -> float:
        return float(np.sqrt(max(self.omega2[self.mode], 0.0)))

    @property
    def mass(self) -> float:
        """The one-mass law's m = 1/b_m² (:func:`attachment_model`)."""
        return float(1.0 / self.b[self.mode] ** 2)

    def omega2_at(self, k_eq: FloatArray) -> FloatArray:
        """ω² of the attachment's mode with a linear spring k_eq (≥ 0) added across the stretch."""
        k = np.maximum(np.asarray(k_eq, float), 0.0)
        g = np.interp(np.log(np.maximum(k, 1e-300)), self.log_k, self.g)
        return self.omega2[self.mode] + k * g

    def k_eq(self, dbar: FloatArray, alpha: float, beta: float) -> FloatArray:
        """κ_hb(β) α δ̄^β, times ρ(r, β) for ``exact``."""
        k = hb_factor(beta) * alpha * np.asarray(dbar, float) ** beta
        if self.exact:
            k = k * _exact_over_hb(k / self.k_unit, beta)
        return k

    def hz(self, dbar: FloatArray, alpha: float, beta: float) -> FloatArray:
        if not (alpha > 0 and beta > 0):
            return np.full(np.shape(dbar), np.nan)
        return np.sqrt(self.omega2_at(self.k_eq(dbar, alpha, beta))) / (2.0 * np.pi)


# --------------------------------------------------------------------------------------------------- fit
@dataclass(frozen=True)
class FitSettings:
    """How :func:`fit_power_law` searches: bounds (the seed's, L1608/L2120), the κ form, the bootstrap."""

    beta_bounds: tuple[float, float] = SEED_BETA_BOUNDS
    alpha_bounds: tuple[float, float] = SEED_ALPHA_BOUNDS
    kappa: Kappa = "seed"
    use_intersection: bool = True
    n_boot: int = 200
    seed: int = 0
    tol: float = 1e-10
    modal: ModalBasis | None = None  # the rig's truncated modal basis, for kappa "modal" / "modal-exact"


@dataclass(frozen=True)
class PowerLawFit:
    """An identified α|δ|^β δ law with its R², points, intersection (if used) and bootstrap uncertainty.

    ``alpha_ci``/``beta_ci`` are the 2.5/97.5 % percentiles of the pairs bootstrap; ``*_sd`` its standard
    deviations."""

    alpha: float
    beta: float
    r2: float
    n_points: int
    omega_n: float
    mass: float
    kappa: str
    mode: str  # "intersection" (eqs. 5.9–5.10) or "two-parameter"
    intersection: dict | None = None
    alpha_ci: tuple[float, float] = (math.nan, math.nan)
    beta_ci: tuple[float, float] = (math.nan, math.nan)
    alpha_sd: float = math.nan
    beta_sd: float = math.nan
    evaluations: int = 0
    extra: dict = field(default_factory=dict)
    modal_law: ModalLaw | None = field(default=None, repr=False, compare=False)

    def predict_hz(self, dbar: FloatArray) -> FloatArray:
        if self.modal_law is not None:
            return self.modal_law.hz(dbar, self.alpha, self.beta)
        return law_hz(dbar, self.omega_n, self.mass, self.alpha, self.beta, self.kappa)  # type: ignore[arg-type]

    def to_dict(self) -> dict:
        return asdict(replace(self, modal_law=None))


def _model(
    theta: FloatArray,
    d: FloatArray,
    omega_n: float,
    m: float,
    kappa: Kappa,
    inter: tuple[float, float] | None,
    modal: ModalLaw | None = None,
):
    if modal is not None:  # two-parameter only (see fit_power_law)
        return modal.hz(d, 10.0 ** theta[0], float(theta[1]))
    if inter is not None and kappa == "exact":  # eq. 5.9 on the exact backbone (no closed form)
        a = alpha_from_intersection(inter[0], inter[1], float(theta[0]), m, omega_n, kappa)
        return exact_law_hz(d, omega_n, m, a, float(theta[0]))
    if inter is not None:
        return law_hz_intersection(d, omega_n, inter[0], inter[1], theta[0])
    return law_hz(d, omega_n, m, 10.0 ** theta[0], theta[1], kappa)


def fit_power_law(
    dbar: FloatArray,
    freq_hz: FloatArray,
    omega_n: float,
    mass: float,
    f_linear: tuple[float, ...] = (),
    settings: FitSettings = FitSettings(),
) -> PowerLawFit:
    """Fit eq. 5.8 to (δ̄, f) points (already capture-free and smoothed) by maximising R².

    ``f_linear``: low-energy linear frequencies (Hz) the curve may cross; the first one crossed upward pins α
    (eqs. 5.9–5.10, L1505) unless ``settings.use_intersection`` is False. Otherwise log10 α and β are fitted
    together (L2120). Global search: ``differential_evolution`` (seeded, deterministic); uncertainty: pairs
    bootstrap of the points, each replicate a bounded local least-squares from the optimum."""
    d, f = _usable_points(dbar, freq_hz, omega_n, mass)
    law = _FitLaw.of(d, f, omega_n, mass, f_linear, settings)
    theta, nfev = _global_fit(law, d, f, settings)
    alpha, beta = law.params(theta, law.inter)
    boots, boot_nfev = _bootstrap(law, d, f, theta, settings)
    return PowerLawFit(
        alpha=float(alpha),
        beta=float(beta),
        r2=float(r_squared(f, law.hz(theta, d, law.inter))),
        n_points=int(d.size),
        omega_n=float(law.omega_n),
        mass=float(law.mass),
        kappa=settings.kappa,
        mode="intersection" if law.inter is not None else "two-parameter",
        intersection=None if law.inter is None else {"f_hz": law.inter[0], "dbar_m": law.inter[1]},
        evaluations=nfev + boot_nfev,
        extra={} if law.modal is None else {"modal_modes": int(law.modal.omega2.size), "modal_exact": law.modal.exact},
        modal_law=law.modal,
        **_bootstrap_spread(boots),
    )


def _usable_points(dbar: FloatArray, freq_hz: FloatArray, omega_n: float, mass: float) -> tuple[FloatArray, FloatArray]:
    """The finite points with δ̄ > 0; a one-line refusal for fewer than 4 or an impossible attachment."""
    d = np.asarray(dbar, float)
    f = np.asarray(freq_hz, float)
    ok = np.isfinite(d) & np.isfinite(f) & (d > 0)
    d, f = d[ok], f[ok]
    if d.size < 4:
        raise BadInput(f"the RQ-FDP has {d.size} usable points; a fit needs at least 4")
    if mass <= 0 or omega_n < 0:
        raise BadInput("the attachment's mass must be positive and ω_n non-negative")
    return d, f


def _intersection_pin(d: FloatArray, f: FloatArray, f_linear: tuple[float, ...], omega_n: float) -> tuple[float, float] | None:
    """(f_i, δ̄_i) where the curve first crosses a linear frequency above the attachment's own, which pins α by
    eq. 5.9 (L1505); None when it crosses none."""
    for fl in sorted(f_linear):
        if fl > omega_n / (2 * np.pi) * (1 + 1e-9):
            di = find_intersection(d, f, fl)
            if di is not None:
                return (float(fl), di)
    return None


@dataclass(frozen=True)
class _FitLaw:
    """Eq. 5.8 as it is fitted: κ, ω_n and m (a modal law's own when it carries the rig's modes, which takes no
    eq. 5.9 pin: docs/nsi.md), the pin (f_i, δ̄_i) if the curve crosses a linear frequency, and the search box
    over θ = (β) with a pin, else (log10 α, β)."""

    omega_n: float
    mass: float
    kappa: Kappa
    inter: tuple[float, float] | None
    modal: ModalLaw | None
    bounds: list

    @classmethod
    def of(cls, d: FloatArray, f: FloatArray, omega_n: float, mass: float, f_linear: tuple[float, ...],
           s: FitSettings) -> _FitLaw:  # fmt: skip
        modal = None
        if s.kappa in MODAL_KINDS:
            if s.modal is None:
                raise BadInput(f"law {s.kappa!r} needs the rig's modal basis (FitSettings.modal)")
            modal = ModalLaw(s.modal, exact=s.kappa == "modal-exact")
            omega_n, mass = modal.omega_n, modal.mass
        inter = _intersection_pin(d, f, f_linear, omega_n) if s.use_intersection and modal is None else None
        bounds = [s.beta_bounds] if inter is not None else [tuple(np.log10(s.alpha_bounds)), s.beta_bounds]
        return cls(omega_n, mass, s.kappa, inter, modal, bounds)

    def hz(self, theta: FloatArray, d: FloatArray, inter: tuple[float, float] | None) -> FloatArray:
        """The law's f(δ̄) at ``theta``, pinned at ``inter`` (a bootstrap replicate re-locates it)."""
        return _model(theta, d, self.omega_n, self.mass, self.kappa, inter, self.modal)

    def params(self, theta: FloatArray, inter: tuple[float, float] | None) -> tuple[float, float]:
        """(α, β) of ``theta``: α by eq. 5.9 from the pin, else 10^θ₀."""
        if inter is None:
            return 10.0 ** theta[0], float(theta[1])
        return alpha_from_intersection(inter[0], inter[1], float(theta[0]), self.mass, self.omega_n, self.kappa), float(theta[0])


def _global_fit(law: _FitLaw, d: FloatArray, f: FloatArray, s: FitSettings) -> tuple[FloatArray, int]:
    """θ minimising the squared error (maximising R², L1608) by seeded ``differential_evolution`` over the box (the
    seed used MATLAB's GlobalSearch), and its function evaluations."""
    import scipy.optimize

    def sse(theta):
        r = law.hz(np.asarray(theta), d, law.inter) - f
        v = float(r @ r)
        return v if np.isfinite(v) else 1e300

    de = scipy.optimize.differential_evolution(sse, law.bounds, seed=s.seed, tol=s.tol, polish=True, maxiter=2000)
    return np.asarray(de.x, float), int(de.nfev)


def _bootstrap(law: _FitLaw, d: FloatArray, f: FloatArray, theta: FloatArray, s: FitSettings) -> tuple[list, int]:
    """``n_boot`` pairs-bootstrap replicates of (α, β), each a bounded local least-squares from the global optimum
    with the pin re-located on the resampled curve (kept when it no longer crosses), and their evaluations."""
    import scipy.optimize

    boots: list = []
    nfev = 0
    if s.n_boot <= 0:
        return boots, nfev
    rng = np.random.default_rng(s.seed)
    lo, hi = np.array([b[0] for b in law.bounds]), np.array([b[1] for b in law.bounds])
    for _ in range(s.n_boot):
        k = rng.integers(0, d.size, d.size)
        dd, ff = d[k], f[k]
        bi = law.inter
        if law.inter is not None:  # the intersection is re-located on the resampled curve
            o = np.argsort(dd)
            di = find_intersection(dd[o], ff[o], law.inter[0])
            bi = (law.inter[0], di) if di is not None else law.inter
        res = scipy.optimize.least_squares(
            lambda th, dd=dd, ff=ff, bi=bi: law.hz(th, dd, bi) - ff,
            np.clip(theta, lo, hi), bounds=(lo, hi), method="trf",
        )  # fmt: skip
        nfev += int(res.nfev)
        boots.append(law.params(res.x, bi))
    return boots, nfev


def _bootstrap_spread(boots: list) -> dict:
    """The replicates' 2.5/97.5 % percentiles and standard deviations of α and β (none without replicates)."""
    if not boots:
        return {}
    b = np.asarray(boots)
    return {
        "alpha_ci": tuple(float(x) for x in np.percentile(b[:, 0], [2.5, 97.5])),
        "beta_ci": tuple(float(x) for x in np.percentile(b[:, 1], [2.5, 97.5])),
        "alpha_sd": float(np.std(b[:, 0], ddof=1)),
        "beta_sd": float(np.std(b[:, 1], ddof=1)),
    }


def fit_rq_fdp(
    fdp: RqFdp, omega_n: float, mass: float, f_linear: tuple[float, ...] = (), settings: FitSettings = FitSettings()
) -> PowerLawFit:
    """:func:`fit_power_law` on the smoothed, capture-free points of an RQ-FDP (L1608, L1747)."""
    m = fdp.fit_mask
    return fit_power_law(fdp.dbar[m], fdp.smooth[m], omega_n, mass, f_linear, settings)


# ------------------------------------------------------------------------------------- the attachment
@dataclass(frozen=True)
class AttachmentModel:
    """What eq. 5.8 needs of the attachment, from the linear model at the measured DOFs.

    ``mode`` (0-based) is the linear mode the attachment's POM follows at low energy, ``shape`` its mass-
    normalised shape at the DOFs (the MAC reference, eq. 5.6), ``omega_n`` its frequency (rad/s, the low-energy
    linear frequency of L1575), ``mass`` the m of eq. 5.8 and ``f_linear_hz`` the other low-energy linear
    frequencies an intersection may pin α at (eqs. 5.9–5.10)."""

    mode: int
    shape: FloatArray
    omega_n: float
    mass: float
    mass_source: str
    f_linear_hz: tuple[float, ...]
    phi_delta: FloatArray  # δ of every mass-normalised mode kept
    omega2: FloatArray | None = None  # ω² of every mode kept (rad²/s²), for the multi-mode law
    shapes: FloatArray | None = None  # (n_out, n_modes) the mass-normalised modes kept
    inertia: float | None = None  # kg·m²: a rotational attachment ([nsi] inertia), mass = inertia/arm²
    arm: float | None = None  # m: its arm h (δ = hθ)

    def rotational(self, k: float, alpha: float, beta: float) -> dict[str, float] | None:
        """A rotational attachment's law in the seed's eq. 6.13 form: k and α (N/m^(β+1)) act at the arm on δ = hθ,
        so the torsional stiffness is k h² (N·m/rad) and Ω² = (h²/I)(k + α δ̄^β) (eq. 6.12 with h², D3); None for
        a translational one."""
        if self.inertia is None or self.arm is None:
            return None
        h2 = self.arm**2
        return {"inertia_kgm2": self.inertia, "arm_m": self.arm, "k_N_per_m": k, "k_torsional_Nm_per_rad": k * h2,
                "alpha_N_per_m^(beta+1)": alpha, "beta": beta, "h2_over_I": h2 / self.inertia}  # fmt: skip

    def modal_basis(self) -> ModalBasis:
        """The truncated linear model :class:`ModalLaw` adds the spring to (the ``n_modes`` lowest modes)."""
        if self.omega2 is None:
            raise BadInput("this attachment model carries no modal basis; build it with attachment_model")
        return ModalBasis(self.omega2, self.phi_delta, self.mode, self.shapes)


def attachment_model(
    M: FloatArray,
    K: FloatArray,
    attachment: int,
    relative_to: tuple[int, ...] = (),
    mode: int | None = None,
    mass: float | None = None,
    n_modes: int = 12,
    inertia: float | None = None,
    arm: float | None = None,
) -> AttachmentModel:
    """The attachment's linear mode and effective mass from the (Guyan-reduced) M, K at the output DOFs.

    With mass-normalised modes φ_r the relative displacement of mode r is φ_δ,r = φ_r[att] − mean φ_r[refs];
    one mode's Galerkin projection of a spring k_e across the attachment adds k_e φ_δ,r² to ω_r², so
    m = 1/φ_δ,r² is the mass eq. 5.8 divides by: the attachment's own mass for a light NES whose mode is all
    NES, the modal mass at the DOF for a spring grounded on a structure (m_beam/4 at a cantilever's tip).
    Default mode: the lowest whose φ_δ² is at least half the largest among the ``n_modes`` lowest.

    A rotational attachment (``inertia`` I, ``arm`` h; the seed's store, eqs. 6.11–6.13) is the translational law
    in its flexure coordinate δ = hθ: from I θ̈ = −h(k δ + α|δ|^β δ), multiplying by h/I gives
    δ̈ = −(h²/I)(k δ + α|δ|^β δ), i.e. m δ̈ = −(k δ + α|δ|^β δ) with m = I/h² — eq. 5.8 with that m, and
    Ω² = (h²/I)(k + α δ̄^β): eq. 6.12 with h² where the seed prints h (method-nsi D3)."""
    import scipy.linalg

    if inertia is not None or arm is not None:
        if inertia is None or arm is None or not (inertia > 0 and arm > 0):
            raise BadInput("a rotational attachment needs a positive inertia (kg m^2) and arm (m)")
        if mass is not None:
            raise BadInput("give the attachment's mass or its inertia and arm (m = I/h^2), not both")
        mass = inertia / arm**2

    n = M.shape[0]
    k = min(n_modes, n)
    w2, phi = scipy.linalg.eigh(K, M, subset_by_index=[0, k - 1])
    pd = phi[attachment] - (phi[list(relative_to)].mean(axis=0) if relative_to else 0.0)
    if mode is None:
        p2 = pd**2
        mode = int(np.flatnonzero(p2 >= 0.5 * p2.max())[0])
    elif not 0 <= mode < k:
        raise BadInput(f"[nsi] mode {mode + 1} is outside the {k} lowest modes at the outputs")
    if pd[mode] ** 2 < 1e-12 * float(np.max(pd**2)):
        raise BadInput(f"linear mode {mode + 1} does not move the attachment (a node of it); choose another [nsi] mode")
    om = float(np.sqrt(max(w2[mode], 0.0)))
    m_eff = 1.0 / float(pd[mode] ** 2)
    f_lin = tuple(float(np.sqrt(max(w, 0.0)) / (2 * np.pi)) for w in w2[mode + 1 :])
    source = "[nsi] mass" if mass is not None else "1/phi_delta^2 of the linear mode"
    if inertia is not None:
        source = "[nsi] inertia/arm^2 (rotational, eq. 6.11 with h^2/I)"
    return AttachmentModel(
        mode=int(mode),
        shape=phi[:, mode].copy(),
        omega_n=om,
        mass=float(mass) if mass is not None else m_eff,
        mass_source=source,
        f_linear_hz=f_lin,
        phi_delta=pd,
        omega2=np.asarray(w2, float).copy(),
        shapes=phi.copy(),
        inertia=inertia,
        arm=arm,
    )


# ------------------------------------------------------------------------------ frequency of a POM's motion
def pom_frequency_hz(disp: FloatArray, pom: FloatArray, fs: float, trim: float = 0.05) -> float:
    """Mean frequency of a POM's temporal coefficient a(t) = (x(t) − x̄)·ψ: the least-squares slope of the
    unwrapped phase of its analytic signal over the record without ``trim`` at each end (Hilbert end effects).

    Not the seed's estimator (the RQ of the POM's *shape*, eq. 2.18): the RQ uses the linear K, which has no
    term for the nonlinear spring, so a POM's RQ moves only as its shape changes — to second order in the
    spring's secant stiffness for a spring grounded on a structure DOF (docs/nsi.md). This is the frequency
    the structure actually oscillates at in that POM, offered beside the RQ."""
    import scipy.signal

    x = np.asarray(disp, float)
    a = (x - x.mean(axis=0)) @ np.asarray(pom, float)
    ph = np.unwrap(np.angle(scipy.signal.hilbert(a)))
    n = a.size
    i0, i1 = int(trim * n), int((1 - trim) * n)
    t = np.arange(i0, i1) / fs
    slope = np.polyfit(t, ph[i0:i1], 1)[0]
    return float(abs(slope) / (2 * np.pi))


__all__ = [
    "MODAL_KINDS",
    "AttachmentModel",
    "AttachmentPick",
    "CaptureTrack",
    "FitSettings",
    "ModalBasis",
    "ModalLaw",
    "PowerLawFit",
    "RqFdp",
    "alpha_from_intersection",
    "attachment_model",
    "backbone_ratios",
    "capture_track",
    "characteristic_displacement",
    "exact_law_hz",
    "find_intersection",
    "fit_power_law",
    "fit_rq_fdp",
    "hb_factor",
    "highpass_delta",
    "law_hz",
    "law_hz_intersection",
    "pick_attachment_pom",
    "pom_frequency_hz",
    "r_squared",
    "relative_displacement",
    "rq_fdp",
    "running_median",
    "zero_crossing_hz",
]


# ------------------------------------------------------------------------------ 1:1 capture over time
def zero_crossing_hz(x: FloatArray, fs: float) -> float:
    """Mean frequency of a record from its upward zero crossings (mean removed), each located by linear
    interpolation: (crossings − 1) / (last − first). NaN with fewer than two crossings. Robust to the
    record's amplitude decay and to the harmonics a hardening spring adds (they do not add zero crossings
    while the fundamental dominates)."""
    y = np.asarray(x, float) - float(np.mean(x))
    i = np.flatnonzero((y[:-1] < 0) & (y[1:] >= 0))
    if i.size < 2:
        return math.nan
    t = (i + (-y[i]) / (y[i + 1] - y[i])) / fs
    return float((t.size - 1) / (t[-1] - t[0]))


@dataclass(frozen=True)
class CaptureTrack:
    """Per window: the attachment's and the structure's frequencies (zero crossings), their ratio, and whether
    the window is in 1:1 capture (|ratio − 1| <= tol). ``onset_s`` is the start of the first captured window
    (NaN if none)."""

    t_s: FloatArray
    f_attachment_hz: FloatArray
    f_structure_hz: FloatArray
    ratio: FloatArray
    amp_ratio: FloatArray
    captured: np.ndarray
    onset_s: float
    tol: float


def capture_track(
    delta: FloatArray, x_structure: FloatArray, fs: float, window_s: float, tol: float = 0.05, min_amp_ratio: float = 0.0
) -> CaptureTrack:
    """When a 1:1 transient resonance capture holds (seed §6.2.2, L2006–L2009): per non-overlapping window the
    frequency of the attachment's relative displacement δ over that of the structure DOF it is tied to. In
    1:1 capture both oscillate at one frequency (the seed reads it from the beating in the two responses and
    their wavelet spectra); out of it the attachment runs at its own, energy-dependent, frequency. ``tol``:
    the ratio's half-width that counts as 1:1 (5 %: the seed gives no number). A linear attachment also
    follows the structure's frequency (its forced response), so a window counts only if the RMS of δ is at
    least ``min_amp_ratio`` times the structure's as well (the seed: store motion "an order of magnitude
    larger" in capture, L2006; a caller passes e.g. twice the linear forced-response ratio)."""
    d, x = np.asarray(delta, float), np.asarray(x_structure, float)
    n = round(window_s * fs)
    if n < 4 or d.shape != x.shape or d.size < n:
        raise BadInput(f"capture windows need >= 4 samples and equal-length records of at least one window ({n})")
    k = d.size // n
    fa = np.array([zero_crossing_hz(d[j * n : (j + 1) * n], fs) for j in range(k)])
    fx = np.array([zero_crossing_hz(x[j * n : (j + 1) * n], fs) for j in range(k)])
    r = fa / fx
    rms = lambda y: np.sqrt(np.mean(y[: k * n].reshape(k, n) ** 2, axis=1))  # noqa: E731
    ar = rms(d - d.mean()) / rms(x - x.mean())
    cap = (np.abs(r - 1.0) <= tol) & (ar >= min_amp_ratio)
    t = np.arange(k) * n / fs
    onset = float(t[np.flatnonzero(cap)[0]]) if cap.any() else math.nan
    return CaptureTrack(t, fa, fx, r, ar, cap, onset, tol)
