"""Wavelet-bounded EMD (WBEMD, seed Ch. 3, eqs. 3.4–3.11, flow chart Fig. 3.2, L767–L839).

Why: plain EMD mixes modes whose frequencies are within a factor 2 (Rilling 2003, seed L483) and a
masking signal fixes that only if the analyst guesses the mask (L485–L488). WBEMD picks the mask: for
each characteristic frequency ω_i, from high to low (L769), it extracts c_i from z_i = u − Σ_{q<i} c_q
(eq. 3.5, printed upper limit "i=1" read as i−1) by masked EMD, with

- a fixed mask s = max|z_i|·sin(ω_i t) (eq. 3.6) when ω_i/ω_{i+1} > 2 (well separated, L777–L781);
- an optimised mask s = max|z_i|·α·sin(β ω_i t) (eq. 3.7) when the ratio is ≤ 2: (α, β) minimise the
  area B of the pseudo-Gaussian bound b(ω) = max(η Z̃_i(ω_i) e^{−φ x²}, ε Z̃_i(ω_i)), x = (ω − ω_i)/(ω_i − ω_{i+1})
  (eqs. 3.8–3.10), under c1: C̃_i(ω_i) ≥ γ Z̃_i(ω_i), c2: C̃_i ≤ δ Z̃_i on (0, ω_{i+1}], c4: b ≥ C̃_i.

Z̃ = MWT{z_i}, C̃ = MWT{c_i} (eq. 3.3, max_t |Z|, "amplitude"-normalised Morlet of eq. 3.2 — the same
transform as :func:`analysis.wavelet.morlet_cwt`). φ is not a free variable: it is the largest width
exponent for which b ≥ C̃ on the whole grid (method-wbemd-slowflow.md §3.3 [DERIVED]),
φ* = min_{ω≠ω_i, C̃(ω) > εZ̃_i(ω_i)} ln(ηZ̃_i(ω_i)/C̃(ω)) / x(ω)², and B decreases strictly in φ, so minimising B
is maximising φ*. B itself is the trapezoid area of eq. 3.10 with the floor (L828).

Speed: each objective evaluation is two first-IMF EMDs plus one MWT of the trial IMF. The MWT here is
a "zoom" evaluation of the same linear-convolution CWT: one real FFT of the zero-padded trial IMF, then
per analysing frequency only the spectral bins inside ±6 kernel standard deviations are inverse-FFT'd
(the kernel is < 2e-8 outside) on a coarser, 4×-oversampled time grid. |Z| does not change under the
baseband shift; the decimated maximum agrees with the full transform to ≤ 2e-3 relative (noise or tones;
the largest errors sit in bins dominated by the record's end transients; ``oversample=8``: 4e-4 at twice the
cost), tested against analysis.wavelet, ~20× faster. Since issue 21 the default evaluator is :class:`_BandedMwt`
(the same zoom with the zero padding sized per band of the grid and rows batched; ~4× faster again, same error).

Ordering: extraction is high → low (L769); the result is relabelled ascending, IMF 1 = lowest (L935).
The last (lowest) component is the remaining residual z_N (the text does not say; §3.2 [CHOICE]).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import scipy.fft
from numpy.typing import ArrayLike, NDArray
from scipy import optimize, signal

from analysis.emd import _check_signal, first_imf, masked_first_imf, orthogonality_index
from analysis.wavelet import OMEGA0_DEFAULT, morlet_cwt, mwt, padded_length

_KERNEL_SIGMAS = 6.0
"""Half-width of the per-frequency spectral window, in kernel standard deviations (exp(−18) ≈ 1.5e-8)."""


@dataclass(frozen=True)
class WbemdParams:
    """WBEMD settings. Text values: η 1.1 (L799), ε 0.05 (L807), γ 0.85 (L813), δ 0.15 (L814; §3.4.1 uses
    0.25, L859), ω0 = 2π (L398), ratio switch 2 (L777). Everything else is an implementation choice
    documented in docs/wbemd.md."""

    eta: float = 1.1
    epsilon: float = 0.05
    gamma: float = 0.85
    delta: float = 0.15
    omega0: float = OMEGA0_DEFAULT
    n_freq_bins: int = 300
    """Uniform bins between grid_low_ratio·min(f) and grid_high_ratio·max(f); the ω_i are added exactly."""
    grid_low_ratio: float = 0.25
    grid_high_ratio: float = 1.5
    ratio_switch: float = 2.0
    alpha_bounds: tuple[float, float] = (0.05, 5.0)
    beta_bounds: tuple[float, float] = (0.5, 3.0)
    optimizer: Literal["nelder-mead", "direct", "grid"] = "nelder-mead"
    max_evals: int = 60
    """Objective evaluations per optimised IMF (each = 2 first-IMF EMDs + 1 MWT)."""
    delta_abs_tol: float = 0.02
    """Absolute slack in c2, as a fraction of Z̃_i(ω_i), for bins where Z̃_i ≈ 0 (§3.4 [CHOICE])."""
    phi_cap: float = 1e6
    last: Literal["residual", "mask"] = "residual"
    mirror: int = 0
    """Samples mirror-imaged at each end before every EMD (0: only emd.m's extrema mirroring)."""
    trim_s: float = 0.0
    """Seconds skipped at each end in every MWT (0 = the text's definition)."""
    oversample: int = 4
    mwt: Literal["banded", "zoom"] = "banded"
    """How the bound test's MWTs are evaluated: ``"banded"`` (:class:`_BandedMwt`, per-band padding and batched
    rows, ~4× faster; issue 21) or ``"zoom"`` (:class:`_ZoomMwt`, one padding for the whole grid, the evaluator
    before issue 21). Both approximate eq. 3.3 within the 4×-oversampling error (docs/wbemd.md §6)."""
    unmasked_candidate: bool = True
    """Also offer the unmasked first IMF (α = 0, the edge of eq. 3.7's family) to the bound test at every step, fixed
    or optimised; it is accepted only if it satisfies the constraints with a smaller B than every masked trial
    (docs/wbemd.md §5.1). False: the text's Fig. 3.2 exactly (fixed steps take eq. 3.6's IMF unconditionally)."""
    omega0_spacing: float | None = None
    """Not in the text. If set, step i uses ω0_i = max(ω0, omega0_spacing·ω_i/(ω_i − ω_{i+1})) for Z̃_i and C̃_i, so
    ω_{i+1} lies ≥ omega0_spacing kernel standard deviations from ω_i (None: ω0 for every step, as the text)."""


@dataclass(frozen=True)
class ImfDiagnostics:
    """Per-component record: the bound's area B (eq. 3.10) and exponent φ, the mask multipliers, C̃/Z̃ at ω_i
    (c1), the largest leakage ratio C̃/Z̃ on (0, ω_{i+1}] (c2), EMD calls spent and whether c1, c2 and the
    bound's feasibility hold for the accepted IMF. ``alpha == 0``: the unmasked IMF was accepted (``mask`` still
    names the step's kind)."""

    freq_hz: float
    B: float
    phi: float
    alpha: float
    beta: float
    gain_at_freq: float
    leakage: float
    emd_calls: int
    converged: bool
    mask: Literal["fixed", "optimised", "residual"]


@dataclass(frozen=True)
class WbemdResult:
    """Components in ascending frequency (IMF 1 = lowest, seed L935); ``imfs.sum(0) + residual == x``."""

    imfs: NDArray[np.float64]
    residual: NDArray[np.float64]
    char_freqs_hz: NDArray[np.float64]
    diagnostics: tuple[ImfDiagnostics, ...]
    orthogonality_index: float
    freq_grid_hz: NDArray[np.float64] = field(repr=False, default_factory=lambda: np.empty(0))


class _ZoomMwt:
    """MWT of many signals of one length on one frequency grid (eqs. 3.2–3.3, amplitude normalisation)."""

    def __init__(self, n: int, fs: float, freqs_hz: NDArray[np.float64], omega0: float, oversample: int, trim_s: float):
        self.n = n
        self.nfft = padded_length(n, fs, float(freqs_hz.min()), omega0)
        df = fs / self.nfft
        self.bins: list[tuple[int, int, NDArray[np.float64], int, int, int]] = []
        trim = round(trim_s * fs)
        if 2 * trim >= n:
            raise ValueError(f"wbemd: trim_s={trim_s} s leaves no samples of a {n / fs} s record")
        for f in freqs_hz:
            sigma = f / omega0  # kernel std in Hz: std(λ) = ω/ω0 rad/s
            k0 = max(0, int(np.floor((f - _KERNEL_SIGMAS * sigma) / df)))
            k1 = min(self.nfft // 2 + 1, int(np.ceil((f + _KERNEL_SIGMAS * sigma) / df)) + 1)
            lam = np.arange(k0, k1) * df
            kern = 2.0 * np.exp(-0.5 * (omega0 / f) ** 2 * (lam - f) ** 2)
            m = k1 - k0
            length = int(scipy.fft.next_fast_len(max(oversample * m, 8)))
            lo = int(np.ceil(trim * length / self.nfft))
            hi = int(np.ceil((n - trim) * length / self.nfft))
            self.bins.append((k0, k1, kern, length, lo, max(hi, lo + 1)))

    def __call__(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        spec = scipy.fft.rfft(x, n=self.nfft)
        out = np.empty(len(self.bins))
        for j, (k0, k1, kern, length, lo, hi) in enumerate(self.bins):
            z = scipy.fft.ifft(spec[k0:k1] * kern, n=length)
            out[j] = np.abs(z[lo:hi]).max() * (length / self.nfft)
        return out


class _BandedMwt:
    """The same MWT as :class:`_ZoomMwt` (eqs. 3.2–3.3, amplitude normalisation, ±6σ spectral windows, ≥ 4×
    oversampled baseband), organised for speed (issue 21, item 6): it was 2/3 of a confirmation's CPU.

    Two changes of numerics, both within the zoom's own error against the full transform (tested):

    * padding per band, not per grid: the zero padding that makes the correlation linear is 9 kernel standard
      deviations of the *lowest* frequency (3 s at 3 Hz), and one FFT length for the whole grid made every
      bin's inverse FFT span that padding, mostly wasted at high frequency where the kernel lasts ~1/f. Bins
      are grouped into bands whose padded length is within ``pad_ratio`` of what their lowest bin needs;
      each band has its own forward FFT, so a bin's padding is still ≥ 9 of its own kernel deviations;
    * rows batched: up to ``rows`` neighbouring bins share one inverse-FFT length (the largest any of them
      needs for ``oversample``×, so every bin is at least as finely sampled in time as in the zoom) and run
      as one 2-D FFT, in single precision (1e-7 relative, far below the 4×-oversampling error of ~4e-3).

    The time grid of each bin therefore differs from the zoom's, so the decimated maxima differ by up to the
    decimation error (measured on a beam displacement: 3.6e-3 relative to the full transform against the
    zoom's 4.6e-3; docs/wbemd.md §6)."""

    def __init__(self, n: int, fs: float, freqs_hz: NDArray[np.float64], omega0: float, oversample: int, trim_s: float,
                 pad_ratio: float = 1.25, rows: int = 32):  # fmt: skip
        trim = round(trim_s * fs)
        if 2 * trim >= n:
            raise ValueError(f"wbemd: trim_s={trim_s} s leaves no samples of a {n / fs} s record")
        self.n_bins = len(freqs_hz)
        order = np.argsort(freqs_hz)
        need = np.array([padded_length(n, fs, float(f), omega0) for f in freqs_hz[order]])
        self.bands: list[tuple[int, list[tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.float32], int, int, int]]]] = []
        i = 0
        while i < order.size:
            nfft = int(need[i])
            j = i + 1
            while j < order.size and need[j] * pad_ratio >= nfft:
                j += 1
            df = fs / nfft
            spans = []
            for b in order[i:j]:
                f = float(freqs_hz[b])
                sigma = f / omega0
                k0 = max(0, int(np.floor((f - _KERNEL_SIGMAS * sigma) / df)))
                k1 = min(nfft // 2 + 1, int(np.ceil((f + _KERNEL_SIGMAS * sigma) / df)) + 1)
                lam = np.arange(k0, k1) * df
                spans.append((int(b), k0, k1, 2.0 * np.exp(-0.5 * (omega0 / f) ** 2 * (lam - f) ** 2)))
            chunks = []
            for c in range(0, len(spans), rows):
                part = spans[c : c + rows]
                width = max(k1 - k0 for _, k0, k1, _ in part)
                length = int(scipy.fft.next_fast_len(max(oversample * width, 8)))
                idx = np.zeros((len(part), width), np.intp)
                ker = np.zeros((len(part), width), np.float32)  # zero beyond a row's window: the zoom's zero fill
                for r, (_, k0, k1, kern) in enumerate(part):
                    idx[r, : k1 - k0] = np.arange(k0, k1)
                    ker[r, : k1 - k0] = kern
                lo = int(np.ceil(trim * length / nfft))
                hi = int(np.ceil((n - trim) * length / nfft))
                chunks.append((np.array([p[0] for p in part], np.intp), idx, ker, length, lo, max(hi, lo + 1)))
            self.bands.append((nfft, chunks))
            i = j

    def __call__(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        out = np.empty(self.n_bins)
        for nfft, chunks in self.bands:
            spec = scipy.fft.rfft(x, n=nfft).astype(np.complex64)
            for rows, idx, ker, length, lo, hi in chunks:
                z = scipy.fft.ifft(spec[idx] * ker, n=length, axis=-1)
                out[rows] = np.abs(z[:, lo:hi]).max(axis=1) * (length / nfft)
        return out


def _mwt_engine(p: WbemdParams, n: int, fs: float, grid: NDArray[np.float64], omega0: float) -> _ZoomMwt | _BandedMwt:
    """The MWT evaluator ``p.mwt`` names (``"banded"``, default since issue 21; ``"zoom"``: the one before)."""
    if p.mwt == "zoom":
        return _ZoomMwt(n, fs, grid, omega0, p.oversample, p.trim_s)
    return _BandedMwt(n, fs, grid, omega0, p.oversample, p.trim_s)


def _check_freqs(f: ArrayLike, fs: float, where: str) -> NDArray[np.float64]:
    f = np.atleast_1d(np.asarray(f, dtype=np.float64))
    if f.ndim != 1 or f.size == 0:
        raise ValueError(f"{where}: char_freqs_hz must be a non-empty 1-D list of frequencies in Hz")
    if not np.all(np.isfinite(f)) or np.any(f <= 0) or np.any(f >= fs / 2):
        raise ValueError(f"{where}: char_freqs_hz {f.tolist()} must lie in (0, fs/2 = {fs / 2}) Hz")
    fa = np.sort(f)
    if np.any(np.diff(fa) <= 0):
        raise ValueError(f"{where}: char_freqs_hz {f.tolist()} contain duplicates; give distinct frequencies")
    return fa


def frequency_grid(char_freqs_hz: ArrayLike, fs: float, params: WbemdParams = WbemdParams()) -> NDArray[np.float64]:
    """The MWT grid (Hz): ``n_freq_bins`` uniform bins on [low·min f, high·max f] (capped at 0.45 fs) plus the
    characteristic frequencies themselves, so Z̃(ω_i) and C̃(ω_i) are evaluated exactly. The bound test
    needs bins between ω_{i+1} and ω_i and above ω_i (§1.1 [CHOICE])."""
    f = np.asarray(char_freqs_hz, dtype=np.float64)
    lo = params.grid_low_ratio * f.min()
    hi = min(params.grid_high_ratio * f.max(), 0.45 * fs)
    return np.unique(np.concatenate([np.linspace(lo, hi, params.n_freq_bins), f]))


def characteristic_frequencies(x: ArrayLike, fs: float, n: int, f_min_hz: float, f_max_hz: float, *, n_freq_bins: int = 400,
                               omega0: float = OMEGA0_DEFAULT, trim_s: float = 0.0, at_most: bool = False,
                               engine: Literal["cwt", "banded"] = "cwt") -> NDArray[np.float64]:
    """The ``n`` most prominent peaks of MWT{x} (eq. 3.3) on a uniform grid in [f_min_hz, f_max_hz], ascending.

    With fewer peaks than ``n``: ValueError, or (``at_most=True``) all the peaks there are, possibly none.

    The seed's analyst reads the characteristic frequencies off the MWT (L769, L478); this automates it by
    peak prominence (scipy.signal.find_peaks). Peaks are refined by a parabola through the three bins.

    ``engine``: ``"cwt"`` takes max_t over the full transform (:func:`analysis.wavelet.morlet_cwt`, single
    precision); ``"banded"`` evaluates the same maxima with :class:`_BandedMwt` at 8× oversampling (≤ ~1e-3
    relative, ~10× faster; the confirmation's default since issue 21 — this was a quarter of its CPU).
    """
    x = _check_signal(x, fs, "characteristic_frequencies")
    if not 0 < f_min_hz < f_max_hz < fs / 2:
        raise ValueError(f"characteristic_frequencies: need 0 < f_min_hz < f_max_hz < fs/2, got {f_min_hz}, {f_max_hz}")
    if n < 1:
        raise ValueError(f"characteristic_frequencies: n must be >= 1, got {n}")
    grid = np.linspace(f_min_hz, f_max_hz, n_freq_bins)
    if engine == "banded":
        m = _BandedMwt(x.size, fs, grid, omega0, 8, trim_s)(x)
    elif engine == "cwt":
        m = mwt(morlet_cwt(x, fs, grid, omega0=omega0, dtype=np.complex64), fs, trim_s)
    else:
        raise ValueError(f"characteristic_frequencies: engine must be 'cwt' or 'banded', not {engine!r}")
    peaks, props = signal.find_peaks(m, prominence=0)  # interior maxima only: a band edge is not a peak
    if peaks.size < n and not at_most:
        raise ValueError(f"characteristic_frequencies: MWT has {peaks.size} peaks in [{f_min_hz}, {f_max_hz}] Hz, need {n}")
    best = peaks[np.argsort(props["prominences"])[::-1][:n]]
    out = []
    step = grid[1] - grid[0]
    for p in best:
        if 0 < p < m.size - 1:
            a, b, c = m[p - 1], m[p], m[p + 1]
            den = a - 2 * b + c
            out.append(grid[p] + (0.5 * (a - c) / den * step if den != 0 else 0.0))
        else:
            out.append(grid[p])
    return np.sort(np.asarray(out))


@dataclass(frozen=True)
class _Eval:
    objective: float
    B: float
    phi: float
    gain: float
    leakage: float
    feasible: bool
    imf: NDArray[np.float64]


def bound_exponent(c_mwt: NDArray[np.float64], z_at: float, w: NDArray[np.float64], wi: float, wnext: float,
                   eta: float, epsilon: float, phi_cap: float) -> float:
    """φ* of the derived closed form (§3.3): the largest φ with b(ω) ≥ C̃(ω) on the grid, given C̃ ≤ ηZ̃_i(ω_i).

    Bins at or below the floor εZ̃_i(ω_i) impose nothing; ω = ω_i imposes nothing on φ (x = 0).
    """
    x2 = ((w - wi) / (wi - wnext)) ** 2
    sel = (c_mwt > epsilon * z_at) & (x2 > 0)
    if not np.any(sel):
        return phi_cap
    ratio = np.maximum(eta * z_at / c_mwt[sel], 1.0)
    return float(min(phi_cap, np.min(np.log(ratio) / x2[sel])))


def bound_area(phi: float, z_at: float, wi: float, wnext: float, eta: float, epsilon: float, n: int = 2001) -> float:
    """B = 2∫_0^{ω_i} b(ω) dω of eq. 3.10 with the floor of eq. 3.9, trapezoid rule (L828)."""
    w = np.linspace(0.0, wi, n)
    b = np.maximum(eta * z_at * np.exp(-phi * ((w - wi) / (wi - wnext)) ** 2), epsilon * z_at)
    return float(2.0 * np.trapezoid(b, w))


def _evaluate(imf: NDArray[np.float64], zoom: _ZoomMwt | _BandedMwt, z_mwt: NDArray[np.float64], w: NDArray[np.float64],
              i_at: int, wi: float, wnext: float, p: WbemdParams) -> _Eval:
    c = zoom(imf)
    z_at = float(z_mwt[i_at])
    gain = float(c[i_at] / z_at)
    low = (w > 0) & (w <= wnext * (1 + 1e-9))
    leak_excess = (c[low] - p.delta * z_mwt[low]) / z_at - p.delta_abs_tol
    leakage = float(np.max(c[low] / np.maximum(z_mwt[low], 1e-300))) if np.any(low) else 0.0
    v_c1 = max(0.0, p.gamma - gain) / p.gamma
    v_c2 = max(0.0, float(leak_excess.max())) if leak_excess.size else 0.0
    v_top = max(0.0, float(c.max() / (p.eta * z_at)) - 1.0)
    b0 = 2.0 * p.eta * z_at * wi  # B at φ = 0: the largest area any feasible bound can have
    phi = bound_exponent(np.minimum(c, p.eta * z_at), z_at, w, wi, wnext, p.eta, p.epsilon, p.phi_cap)
    B = bound_area(phi, z_at, wi, wnext, p.eta, p.epsilon)
    viol = v_c1 + v_c2 + v_top
    feasible = viol == 0.0
    obj = B / b0 if feasible else 1.0 + viol
    return _Eval(obj, B, phi, gain, leakage, feasible, imf)


def _optimise(fun, p: WbemdParams) -> None:
    """Drive ``fun(α, β)`` (which records every evaluation); the caller picks the best feasible one.

    Default Nelder–Mead from the seed's start (1, 1) (a local direct search, like patternsearch's GPS poll),
    bounded, first simplex (1,1), (2,1), (1,1.5). Measured on 12 §3.4.1 points it reached the best PCC with the
    fewest infeasible results and EMD calls of DIRECT (global, bounded), a 7×8 grid, and 120-evaluation
    budgets (docs/wbemd.md §Optimiser).
    """
    bounds = [p.alpha_bounds, p.beta_bounds]
    fun(1.0, 1.0)  # the seed's initial guess (L828)
    budget = max(p.max_evals - 1, 1)
    if p.optimizer == "direct":
        optimize.direct(lambda v: fun(v[0], v[1]), bounds, maxfun=budget, locally_biased=True)
    elif p.optimizer == "nelder-mead":
        optimize.minimize(lambda v: fun(v[0], v[1]), x0=[1.0, 1.0], method="Nelder-Mead", bounds=bounds,
                          options={"maxfev": budget, "initial_simplex": [[1.0, 1.0], [2.0, 1.0], [1.0, 1.5]],
                                   "xatol": 1e-3, "fatol": 1e-6})
    elif p.optimizer == "grid":
        na = max(2, int(np.sqrt(budget)))
        for a in np.geomspace(*p.alpha_bounds, na):
            for b in np.linspace(*p.beta_bounds, max(2, budget // na)):
                fun(a, b)
    else:
        raise ValueError(f"wbemd: optimizer must be 'direct', 'nelder-mead' or 'grid', not {p.optimizer!r}")


def _validate_params(p: WbemdParams) -> None:
    if not (p.eta >= 1 and 0 <= p.epsilon < 1 and 0 < p.gamma <= p.eta and p.delta >= 0):
        raise ValueError(f"wbemd: need η ≥ 1, 0 ≤ ε < 1, 0 < γ ≤ η, δ ≥ 0; got η={p.eta}, ε={p.epsilon}, γ={p.gamma}, "
                         f"δ={p.delta}")
    if p.mwt not in ("banded", "zoom"):
        raise ValueError(f"wbemd: mwt must be 'banded' or 'zoom', not {p.mwt!r}")
    if p.n_freq_bins < 16 or p.max_evals < 1 or p.ratio_switch <= 1:
        raise ValueError("wbemd: n_freq_bins must be >= 16, max_evals >= 1 and ratio_switch > 1")
    for lo, hi in (p.alpha_bounds, p.beta_bounds):
        if not 0 < lo < hi:
            raise ValueError(f"wbemd: bounds must satisfy 0 < low < high, got ({lo}, {hi}); α = 0 or β = 0 kill the mask")


def _extract_step(z: NDArray[np.float64], fs: float, t: NDArray[np.float64], wi: float, wnext: float, zoom: _ZoomMwt | _BandedMwt,
                  z_mwt: NDArray[np.float64], w: NDArray[np.float64], i_at: int,
                  p: WbemdParams, fixed: bool = False) -> tuple[float, float, _Eval, int, str]:
    """One box of Fig. 3.2: fixed mask (eq. 3.6) if ω_i/ω_{i+1} > ratio_switch, else optimised mask (eq. 3.7).

    Returns (α, β, evaluation, number of EMD calls, mask kind) of the accepted IMF: the feasible trial with
    the least B, or — if no trial is feasible — the one with the least constraint violation. With
    ``unmasked_candidate`` the unmasked first IMF (α = 0) is one of the trials.
    """
    zmax = float(np.max(np.abs(z)))  # "max[z_i(t)]" of eqs. 3.6–3.7 read as max|z_i| (§3.2 [CHOICE])
    evals: list[tuple[float, float, _Eval]] = []
    cache: dict[tuple[float, float], float] = {}

    calls = [0]

    def fun(a: float, b: float) -> float:
        key = (round(float(a), 6), round(float(b), 6))
        if key not in cache and len(evals) >= p.max_evals + int(p.unmasked_candidate):
            return 1e9  # budget spent (scipy's DIRECT may overshoot maxfun): refuse further EMDs
        if key not in cache:
            if key[0] == 0.0:  # α = 0: no mask, plain EMD's first IMF (one EMD, not two)
                imf = first_imf(z, p.mirror)
                calls[0] += 1
            else:
                imf = masked_first_imf(z, fs, zmax * key[0] * np.sin(key[1] * wi * t), mirror=p.mirror)
                calls[0] += 2
            ev = _evaluate(imf, zoom, z_mwt, w, i_at, wi, wnext, p)
            evals.append((key[0], key[1], ev))
            cache[key] = ev.objective
        return cache[key]

    if p.unmasked_candidate:
        fun(0.0, 1.0)
    if fixed or wi / wnext > p.ratio_switch:
        fun(1.0, 1.0)
        kind = "fixed"
    else:
        _optimise(fun, p)
        kind = "optimised"
    a, b, ev = min(evals, key=lambda r: r[2].objective)  # ties: the earlier trial (the unmasked one first)
    return a, b, ev, calls[0], kind


def wbemd(x: ArrayLike, fs: float, char_freqs_hz: ArrayLike | None = None, *, n_imfs: int | None = None,
          params: WbemdParams = WbemdParams()) -> WbemdResult:
    """Wavelet-bounded EMD of ``x`` into one component per characteristic frequency (Fig. 3.2).

    ``char_freqs_hz`` (any order) are the ω_i/2π; if None, ``n_imfs`` MWT peaks in [4/T, 0.45 fs] are used
    (:func:`characteristic_frequencies`). Raises ValueError for NaN/inf, records shorter than two periods of
    the lowest frequency, or frequencies outside (0, fs/2).
    """
    x = _check_signal(x, fs, "wbemd", min_len=64)
    _validate_params(params)
    n = x.size
    if char_freqs_hz is None:
        if n_imfs is None:
            raise ValueError("wbemd: give char_freqs_hz or n_imfs")
        char_freqs_hz = characteristic_frequencies(x, fs, n_imfs, 4.0 * fs / n, 0.45 * fs, omega0=params.omega0)
    f_asc = _check_freqs(char_freqs_hz, fs, "wbemd")
    if n_imfs is not None and n_imfs != f_asc.size:
        raise ValueError(f"wbemd: n_imfs={n_imfs} but {f_asc.size} characteristic frequencies were given")
    if n < 2 * fs / f_asc[0]:
        raise ValueError(f"wbemd: record of {n / fs:.4g} s is shorter than 2 periods of {f_asc[0]:.4g} Hz; lengthen it")
    grid = frequency_grid(f_asc, fs, params)
    w = 2.0 * np.pi * grid
    zoom = _mwt_engine(params, n, fs, grid, params.omega0)
    t = np.arange(n) / fs
    f_desc = f_asc[::-1]
    z = x.copy()
    comps: list[NDArray[np.float64]] = []
    diags: list[ImfDiagnostics] = []
    for i, fi in enumerate(f_desc):
        wi = 2.0 * np.pi * fi
        last = i == f_desc.size - 1
        if last and params.last == "residual":
            comps.append(z.copy())
            diags.append(ImfDiagnostics(float(fi), np.nan, np.nan, np.nan, np.nan, np.nan, np.nan, 0, True, "residual"))
            z = np.zeros(n)
            break
        # last="mask": no ω_{i+1} exists; fixed mask at ω_N, diagnostics use ω_{i+1} := ω_N/ratio_switch.
        wnext = 2.0 * np.pi * f_desc[i + 1] if not last else wi / params.ratio_switch
        if params.omega0_spacing is not None and not last:
            w0_i = max(params.omega0, params.omega0_spacing * wi / (wi - wnext))
            zoom = _mwt_engine(params, n, fs, grid, w0_i)
        z_mwt = zoom(z)
        i_at = int(np.argmin(np.abs(grid - fi)))
        if z_mwt[i_at] <= 0:
            raise ValueError(f"wbemd: z_{i + 1} has no content at {fi:.4g} Hz; check char_freqs_hz")
        a, b, ev, n_calls, kind = _extract_step(z, fs, t, wi, wnext, zoom, z_mwt, w, i_at, params, fixed=last)
        comps.append(ev.imf)
        diags.append(ImfDiagnostics(float(fi), ev.B, ev.phi, a, b, ev.gain, ev.leakage, n_calls, ev.feasible, kind))
        z = z - ev.imf  # eq. 3.11
    imfs = np.asarray(comps[::-1])
    return WbemdResult(imfs=imfs, residual=z, char_freqs_hz=f_asc, diagnostics=tuple(diags[::-1]),
                       orthogonality_index=orthogonality_index(np.vstack([imfs, z[None, :]]), x), freq_grid_hz=grid)
