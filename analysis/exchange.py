"""Internal-resonance events from modal energy exchange and phase locking — gvtlink's detector.

Why not the seed's spikes alone: detection-findings.md measured that a literal RQ spike rule tracks *how
much* of mode 2 is in a window, not energy *flowing* into it, and is fooled by window phase (precision
0.07, recall 0.06 against real exchanges). What defines an internal resonance physically is a transfer
of energy between NNMs while their frequencies are locked near a rational ratio m:n (seed §1.1, eq. 4.2:
``m θ1 − n θ2 ≈ const``). Both are observable with the linear model the method already requires:

1. the modal filter (analysis/modal_filter.py) gives each mode's linear energy and phase, causally;
2. per window (length ``window_s``, hop ``hop_s``) we keep the mean modal energies and the mean
   instantaneous frequencies (phase advance over the window / 2π T);
3. an **event** opens when the receiving mode's windowed energy reaches ``min_gain`` × its lowest value
   since the last input or event (and is above the noise and energy floors), and closes when it falls
   back below ``close_fraction`` × its peak; start = window of the minimum, end = window of the peak;
4. its **ratio** m:n is mean f_recv / mean f_give over the event, rounded to the candidate whose slow phase
   ``m θ_give − n θ_recv`` drifts slowest (:func:`slowest_phase_ratio`, eq. 4.2; before issue 21 the nearest m/n);
5. **evidence scores** in [0, 1]: ``gain`` (how far past the doubling), ``lock`` (fraction of the
   event's windows whose frequency ratio lies within ``lock_tolerance`` of m:n, i.e. the slow phase
   ``n θ_recv − m θ_give`` nearly stops), ``exchange`` (the giving mode lost at least what the receiver
   gained, beyond its own linear damping, when the damping is known), and ``rq`` (a window-robust RQ
   spike nearby, filled in by the operator when that detector runs);
6. ``confidence`` is the *calibrated* probability that the event is a true major exchange (its interval
   matches one, docs/evaluation.md §4), and ``label_confidence`` that it is one *with the right m:n*: a
   monotone logistic map of the gain, lock and exchange scores (:class:`Calibration`, constants fitted by
   bench/calibrate_confidence.py on half of the realistic grid's cases, its reliability measured on the other
   half, docs/evaluation.md §6). Until issue 21 it was the scores' weighted mean, which did not separate false
   from true events (both medians 0.57).

Every threshold is a named field of :class:`ExchangeSettings`, calibrated on the simulator
(bench/eval_detection.py, docs/detection.md).
"""

from __future__ import annotations

import itertools
from collections import deque
from collections.abc import Callable, Sequence
from concurrent.futures import Future
from dataclasses import dataclass, field, replace

import numba
import numpy as np
import scipy.signal

from analysis.modal_filter import ModalBasis, ModalFilterSettings, ModalStateTracker, modal_energy, modal_phase
from analysis.preprocess import butter_sos

FloatArray = np.ndarray

#: the label of a receiving frequency near the giving one's (f_recv / f_give < 1.5, by the nearest rule): a leak of the
#: giving mode into the receiver's coordinate or its band, not an m:n internal resonance (issue 21: such events were
#: labelled 2:1, the nearest of the seed's set). Never confirmed as an m:n IR (analysis/confirm.py); a truth label too
LEAK_RATIO: tuple[int, int] = (1, 1)
#: the seed's candidate ratios 2:1 ... 4:1 (L67, L1255) after :data:`LEAK_RATIO`
DEFAULT_RATIOS: tuple[tuple[int, int], ...] = (LEAK_RATIO, (2, 1), (5, 2), (3, 1), (7, 2), (4, 1))


@dataclass(frozen=True)
class WindowFeatures:
    """What the detector keeps of one window of modal states."""

    index: int  # window number
    start: int  # first sample index (stream index)
    stop: int  # one past the last
    t_start_s: float
    t_end_s: float
    energy: FloatArray  # (r,) mean linear modal energy over the window, J
    freq_hz: FloatArray  # (r,) mean instantaneous frequency over the window
    input_active: bool = False  # the hammer (or another input) acted during this window
    #: (t_s (k,), phase (k, r), band-passed q (k, r)) of the window's first hop, decimated to ~1 kHz: the samples the
    #: phase-lock label (:func:`lock_fit`) needs; consecutive windows' hops tile the stream. None: not kept
    lock: tuple[FloatArray, FloatArray, FloatArray] | None = None
    #: the raw coordinates' energies where ``energy`` is band-limited (the input-jump rule needs the hit's full jump:
    #: a band-pass spreads it over windows); None: ``energy`` is the raw one
    energy_raw: FloatArray | None = None


def lock_fit(
    t: FloatArray,
    y: FloatArray,
    theta_give: FloatArray,
    f_give_hz: float,
    ratios: Sequence[tuple[int, int]],
    min_improvement: float = 0.2,
    min_share: float = 0.02,
    step_hz: float = 0.25,
) -> tuple[int, int] | None:
    """The m:n (m > n) whose component of the receiver ``y`` is phase-locked to ``m/n θ_give``; None if none stands out.

    Each candidate is tried as ``y ≈ a cos(ρθ) + b sin(ρθ) + c cos(2πft) + d sin(2πft)`` plus a component locked at θ
    itself (the cubic force's f1 part, off resonance: a nuisance, not a candidate), least squares over the samples, the
    free frequency ``f`` searched on a ``step_hz`` grid in ``[1.25, 4.75] f_give``; the best candidate wins if it
    removes ``min_improvement`` of the residual without it and ``min_share`` of ``y``'s energy. Why: an exchange on the
    grid rigs is the cubic's locked 3 f1 response beating against mode 2's free oscillation (docs/evaluation.md §8);
    the m:n is the locked one (eq. 4.2), while f2/f1 reads whichever of the two is stronger. Used by the truth on exact
    coordinates (:func:`analysis.evaluation.truth.locked_ratio`) and by the detector on its band-passed modal states."""
    t, y, th = (np.asarray(a, dtype=float) for a in (t, y, theta_give))
    yy = float(y @ y)
    cands = [mn for mn in ratios if mn[0] > mn[1]]
    if y.size < 16 or yy <= 0 or not cands or not (np.isfinite(f_give_hz) and f_give_hz > 0):
        return None
    r0, res = lock_residuals(t, y, th, f_give_hz, cands, step_hz)
    k = int(np.argmin(res))
    gain = r0 - float(res[k])
    return tuple(cands[k]) if gain >= min_improvement * r0 and gain >= min_share * yy else None


def lock_residuals(
    t: FloatArray, y: FloatArray, th: FloatArray, f_give_hz: float, cands: Sequence[tuple[int, int]], step_hz: float
) -> tuple[float, FloatArray]:
    """:func:`lock_fit`'s least-squares residuals, each the smallest over the free frequency grid: θ's own pair with the
    free sinusoid (``r0``), and θ's pair with each candidate's pair and the free sinusoid (one per candidate).

    The fit at each free frequency ``f`` is one linear least squares with the locked columns ``Z`` and the free pair
    ``F_f``. Solved by blocks (the Schur complement of ``ZᵀZ``): ``r = yy − ζᵀA⁻¹ζ − uᵀS⁻¹u`` with ``A = ZᵀZ``,
    ``ζ = Zᵀy``, ``S = F_fᵀF_f − F_fᵀZ A⁻¹ ZᵀF_f`` (2 × 2, inverted in closed form) and ``u = F_fᵀy − F_fᵀZ A⁻¹ζ``:
    one small solve per column set for every frequency at once, where the full normal equations were one
    ``(frequencies, 6, 6)`` solve per candidate (issue 30: 3.6 → 2.6 ms an event on beam_ch4_exp, the same residuals
    within 1e-15 yy, tests/test_detection.py). The ridge ``1e-12 yy`` on the diagonal is the one the full system had."""
    fb = np.arange(1.25 * f_give_hz, 4.75 * f_give_hz, step_hz)
    nf = fb.size
    # the free sinusoids exp(i 2π f t) on the frequency grid by one complex recurrence along it (×exp(i 2π step t) a row:
    # ~280 rows of rounding, 1e-13, against 2 transcendental calls per element, ~1.5 ms an event)
    cos_f, sin_f = np.empty((nf, t.size)), np.empty((nf, t.size))
    _rows_by_recurrence(np.exp(2j * np.pi * fb[0] * t), np.exp(2j * np.pi * step_hz * t), cos_f, sin_f)
    # every locked column (θ's own pair, then each candidate's) and y: their projections on the free sinusoids, two
    # real BLAS products (the recurrence writes the cos and sin rows apart: half the flops of the complex product of
    # the rows with a complex copy of Z, issue 30)
    Z = np.column_stack([np.cos(th), np.sin(th), *(f(m / n * th) for m, n in cands for f in (np.cos, np.sin)), y])
    FC, FS = cos_f @ Z, sin_f @ Z
    P, b_f = np.stack([FC[:, :-1], FS[:, :-1]], axis=1), np.stack([FC[:, -1], FS[:, -1]], axis=1)
    g = _free_gram(t, fb, cos_f, sin_f)
    Zl = Z[:, :-1]
    ZZ, Zy = Zl.T @ Zl, Zl.T @ y
    yy, eps = float(y @ y), 1e-12 * float(y @ y)
    r0 = float(_schur_min(yy, ZZ, Zy, P, b_f, g, np.array([[0, 1]]), eps)[0])
    sets = np.array([[0, 1, 2 + 2 * i, 3 + 2 * i] for i in range(len(cands))])
    return r0, _schur_min(yy, ZZ, Zy, P, b_f, g, sets, eps)


def _free_gram(t: FloatArray, fb: FloatArray, c: FloatArray, s: FloatArray) -> FloatArray:
    """The free pair's Gram matrix at every free frequency, ``(f, 2, 2)``: ``Σcos²``, ``Σcos·sin``, ``Σsin²`` of
    ``2πft`` over the samples (``c``, ``s``: their cos and sin rows).

    With ``cos² = (1 + cos 2x)/2``, ``sin² = (1 − cos 2x)/2`` and ``cos·sin = (sin 2x)/2`` all three come from
    ``S = Σ exp(i4πf t_n)``, and on a uniform lattice (the detector's lock tiles always are one: every ``stride``-th
    stream sample) that sum is a geometric series, ``S = exp(i4πf t_0) (1 − zᴺ)/(1 − z)`` with ``z = exp(i4πf Δt)``:
    O(1) a frequency where the three sums over ``ez`` were three strided passes (0.38 of ~1.4 ms an event, issue 30).
    Equal to the sums within rounding (~1e-13 of N; tests/test_detection.py's least-squares oracle). Samples off a
    lattice, and the frequencies where ``z`` is within 1e-6 of 1 (2f Δt an integer: the series' 0/0), take the sums."""
    n = t.size
    dt = (t[-1] - t[0]) / (n - 1) if n > 1 else 0.0
    lattice = n > 1 and dt > 0 and bool(np.all(np.abs(np.diff(t) - dt) <= 1e-9 * dt))
    g = np.empty((fb.size, 2, 2))
    if lattice:
        z = np.exp(4j * np.pi * fb * dt)
        near = np.abs(1.0 - z) < 1e-6
        S = np.exp(4j * np.pi * fb * t[0]) * (1.0 - np.exp(4j * np.pi * fb * dt * n)) / np.where(near, 1.0, 1.0 - z)
        if near.any():  # Σ exp(i2x) = Σ (cos² − sin²) + i Σ 2 cos·sin
            cn, sn = c[near], s[near]
            S[near] = np.einsum("fn,fn->f", cn, cn) - np.einsum("fn,fn->f", sn, sn) + 2j * np.einsum("fn,fn->f", cn, sn)
        g[:, 0, 0], g[:, 1, 1] = 0.5 * (n + S.real), 0.5 * (n - S.real)
        g[:, 0, 1] = g[:, 1, 0] = 0.5 * S.imag
        return g
    g[:, 0, 0], g[:, 1, 1] = np.einsum("fn,fn->f", c, c), np.einsum("fn,fn->f", s, s)
    g[:, 0, 1] = g[:, 1, 0] = np.einsum("fn,fn->f", c, s)
    return g


@numba.njit(cache=True, nogil=True)
def _rows_by_recurrence(first, step, re, im):  # pragma: no cover - compiled
    """``z[0] = first``, ``z[k] = z[k-1] * step``: ``np.cumprod`` of ``[first, step, step, ...]`` along the rows, one
    complex product an element as numpy's, in one pass without numpy's strided accumulate (0.36 of ~1.35 ms an event's
    lock fit); the real parts into ``re``, the imaginary into ``im`` (the rows the lock fit's real products read)."""
    n = first.shape[0]
    row = first.copy()
    for k in range(re.shape[0]):
        if k:
            for j in range(n):
                row[j] = row[j] * step[j]
        for j in range(n):
            re[k, j] = row[j].real
            im[k, j] = row[j].imag


def _schur_min(
    yy: float, ZZ: FloatArray, Zy: FloatArray, P: FloatArray, b_f: FloatArray, g: FloatArray, idx: FloatArray, eps: float
) -> FloatArray:
    """Per column set (rows of ``idx``, ``(sets, pc)``): the smallest residual over the free frequencies of ``y`` fitted
    by the set's locked columns and the free pair (:func:`lock_residuals`). ``P`` (f, 2, columns): the free pair's
    products with every locked column, ``b_f`` (f, 2) with y, ``g`` (f, 2, 2) with itself."""
    n_set, pc = idx.shape
    A = ZZ[idx[:, :, None], idx[:, None, :]] + eps * np.eye(pc)  # (sets, pc, pc)
    Ainv = np.linalg.inv(A)  # a pc × pc inverse per set, applied to every frequency's columns in the pass below
    zy = Zy[idx]  # (sets, pc)
    w0 = np.einsum("spq,sq->sp", Ainv, zy)  # A⁻¹ζ
    base = yy - np.einsum("sp,sp->s", zy, w0)
    out = np.empty(n_set)
    _schur_rest(P, np.ascontiguousarray(idx, dtype=np.int64), Ainv, w0, g, b_f, base, eps, out)
    return out


@numba.njit(cache=True, nogil=True)
def _schur_rest(P, idx, Ainv, w0, g, b_f, base, eps, out):  # pragma: no cover - compiled
    """:func:`_schur_min` after the set's inverse, per set and free frequency: the free pair's columns of the set
    ``P_f`` (2 × pc), ``S = g − P_f A⁻¹ P_fᵀ`` (2 × 2), ``u = b − P_f A⁻¹ ζ``, ``q = uᵀ S⁻¹ u`` (with the ridge on S's
    diagonal), and the smallest ``base − q``. In one pass: as numpy (a solve with 1 + 2f right-hand sides, 1,470 tiny
    stacked matmuls and an einsum) it was ~0.5 of ~1.1 ms an event's lock fit (issue 30). The residuals may move at
    the 1e-15 level (D97: the lock fit is held to its label and to the lstsq oracle)."""
    n_set, pc = idx.shape
    nf = P.shape[0]
    pf = np.empty((2, pc))
    wf = np.empty((pc, 2))
    for s in range(n_set):
        best = np.inf
        for f in range(nf):
            for a in range(2):
                for p in range(pc):
                    pf[a, p] = P[f, a, idx[s, p]]
            for p in range(pc):
                for b in range(2):
                    acc = 0.0
                    for q in range(pc):
                        acc += Ainv[s, p, q] * pf[b, q]
                    wf[p, b] = acc
            s00, s01, s10, s11 = g[f, 0, 0], g[f, 0, 1], g[f, 1, 0], g[f, 1, 1]
            u0, u1 = b_f[f, 0], b_f[f, 1]
            for p in range(pc):
                a0, a1 = pf[0, p], pf[1, p]
                s00 -= a0 * wf[p, 0]
                s01 -= a0 * wf[p, 1]
                s10 -= a1 * wf[p, 0]
                s11 -= a1 * wf[p, 1]
                u0 -= a0 * w0[s, p]
                u1 -= a1 * w0[s, p]
            s00 += eps
            s11 += eps
            q = (s11 * u0 * u0 - (s01 + s10) * u0 * u1 + s00 * u1 * u1) / (s00 * s11 - s01 * s10)
            r = base[s] - q
            if r < best or f == 0:
                best = r
        out[s] = best


def phase_bands(freqs_hz: FloatArray, fs: float) -> list[tuple[float, float]]:
    """Pass band of each mode for its phase: from the geometric mean with the mode below (half of f1 for
    mode 1) to the geometric mean with the mode above (1.5 f_r for the last), capped below Nyquist."""
    f = np.asarray(freqs_hz, float)
    out = []
    for j in range(f.size):
        lo = 0.5 * f[0] if j == 0 else float(np.sqrt(f[j - 1] * f[j]))
        hi = 1.5 * f[j] if j == f.size - 1 else float(np.sqrt(f[j] * f[j + 1]))
        out.append((lo, min(hi, 0.45 * fs)))
    return out


def band_noise_energy(
    basis: ModalBasis, noise_std: Sequence[float] | FloatArray, fs: float, highpass_hz: float = 5.0, order: int = 3
) -> FloatArray:
    """Expected band-limited modal energy (J, per mode) that white sensor noise of ``noise_std`` (per channel,
    acceleration) puts into each mode's windowed energy: the noise a receiver's rise must stand above.

    Computed in the frequency domain, independently of the streaming code: the modal acceleration noise
    ``Σ_i P_ji² σ_i²`` (the projector's row j), flat one-sided PSD ``2 s_j² / fs``, through ideal integrators
    ``1/(i2πf)`` each followed by the modal filter's Butterworth high-pass (``highpass_hz``, ``order``: velocity once,
    displacement twice) and the mode's band-pass (:func:`phase_bands`), into ``(q̇² + ω² q²) / 2``."""
    sig = np.asarray(noise_std, float)
    if sig.shape != (basis.projector.shape[1],):
        raise ValueError(f"one noise standard deviation per channel ({basis.projector.shape[1]}), got {sig.shape}")
    # a geometric grid: the integrand spans 1/f^4 below the high-pass to the band-pass's skirt; 4001 points agree with a
    # 200001-point linear grid within 2e-6 (relative) on both grid rigs, in ~3 ms instead of ~100 ms (the operator
    # computes this at every start and sensor exclusion)
    f = np.geomspace(0.05, 0.5 * fs, 4001)
    w = 2 * np.pi * f
    _, hp = scipy.signal.sosfreqz(butter_sos(order, highpass_hz, "highpass", fs), worN=f, fs=fs)
    hv2, hx2 = np.abs(hp) ** 2 / w**2, np.abs(hp) ** 4 / w**4
    out = np.empty(basis.n_modes)
    for j, (lo, hi) in enumerate(phase_bands(basis.freqs_hz, fs)):
        _, bp = scipy.signal.sosfreqz(butter_sos(2, (lo, hi), "bandpass", fs), worN=f, fs=fs)
        psd = 2.0 * float(np.sum(basis.projector[j] ** 2 * sig**2)) / fs
        out[j] = 0.5 * np.trapezoid(psd * np.abs(bp) ** 2 * (hv2 + basis.omega[j] ** 2 * hx2), f)
    return out


class ModalWindower:
    """Cut a stream of modal states into windows of ``length`` samples every ``hop`` samples; causal.

    Energies come from the modal states as they are. The *phase* of each mode is taken after a causal
    band-pass around that mode (:func:`phase_bands`, 2nd-order Butterworth, state carried): late in a
    decay mode 2 can hold 1e-3 of mode 1's energy, and the little of mode 1 that any modal filter leaks
    into coordinate 2 would otherwise pull its measured frequency towards f1 (it biased the m:n labels
    of weak hits by up to 15 % before this filter, docs/detection.md). A constant filter delay cancels
    in the phase advance over a window. Holds at most one window of samples (bounded).
    """

    def __init__(
        self,
        basis: ModalBasis,
        sample_rate: float,
        length: int,
        hop: int,
        first_index: int = 0,
        phase_bandpass: bool = True,
        energy_bandpass: bool = False,
    ) -> None:
        if length < 2 or hop < 1:
            raise ValueError("window length must be >= 2 samples and hop >= 1")
        self.basis = basis
        self.fs = float(sample_rate)
        self.length = int(length)
        self.hop = int(hop)
        self.energy_bandpass = bool(energy_bandpass) and phase_bandpass
        r = basis.n_modes
        self._sos: FloatArray | None = None  # (modes, sections, 6): mode j's band-pass
        self._zi: FloatArray | None = None  # (modes, sections, 2 states, 2 columns q | q̇), carried
        if phase_bandpass:
            bands = [butter_sos(2, (lo, hi), "bandpass", self.fs) for lo, hi in phase_bands(basis.freqs_hz, self.fs)]
            if bands:
                self._sos = np.ascontiguousarray(np.stack(bands))
                self._zi = np.zeros((len(bands), bands[0].shape[0], 2, 2))
        self.energy_bandpass = self.energy_bandpass and self._sos is not None
        self._e = np.zeros((0, 2 * r if self.energy_bandpass else r))  # band-limited energies, then raw
        self._dphi = np.zeros((0, r))
        self._th = np.zeros((0, r))  # phase and band-passed q per sample, for WindowFeatures.lock
        self._qb = np.zeros((0, r))
        self._stride = max(1, int(self.fs // 1024))
        self._inp = np.zeros(0, bool)
        self._buf_start = int(first_index)  # stream index of the buffer's first sample
        self._next_start = int(first_index)
        self._last_theta: FloatArray | None = None
        self._count = 0

    def feed(self, q: FloatArray, qdot: FloatArray, input_active: FloatArray | None = None) -> list[WindowFeatures]:
        q, qdot = np.asarray(q), np.asarray(qdot)
        n, tail = q.shape[0], self._e.shape[0]
        # the block's features go straight into buffers that already hold the samples kept from the block before (a
        # block's worth of copies fewer: five concatenations, ~1 ms a 1 s block at 14 ch x 16384 Hz, issue 30)
        bufs = [np.empty((tail + n, *b.shape[1:]), b.dtype) for b in (self._e, self._dphi, self._th, self._qb, self._inp)]
        for buf, old in zip(bufs, (self._e, self._dphi, self._th, self._qb, self._inp), strict=True):
            buf[:tail] = old
        self._e, self._dphi, self._th, self._qb, self._inp = bufs
        self._features(q, qdot, tail)
        self._inp[tail:] = False if input_active is None else np.asarray(input_active, bool)
        starts = []
        while self._next_start + self.length <= self._buf_start + self._e.shape[0]:
            starts.append(self._next_start)
            self._next_start += self.hop
        out = []
        if starts:
            # per-window sums by one reduceat over interleaved (a, b) pairs: sequential, so the numbers do
            # not depend on how the stream was cut into blocks
            idx = np.array([(st - self._buf_start, st - self._buf_start + self.length) for st in starts]).ravel()
            # (a window ending at the buffer's end: its last index dropped, so its sum runs to the end; no padded copy)
            cut = idx if idx[-1] < self._e.shape[0] else idx[:-1]
            e_sum = np.add.reduceat(self._e, cut, axis=0)[::2]
            d_sum = np.add.reduceat(self._dphi, cut, axis=0)[::2]
            inp_any = np.logical_or.reduceat(self._inp, cut)[::2]
            r = self._dphi.shape[1]
            energy, freq = e_sum[:, :r] / self.length, d_sum * self.fs / (2 * np.pi * self.length)
            raw = e_sum[:, r:] / self.length if e_sum.shape[1] > r else None
            inp_any = inp_any.tolist()
            for k, (st, lock) in enumerate(zip(starts, self._lock_tiles(starts), strict=True)):
                out.append(
                    WindowFeatures(
                        index=self._count, start=st, stop=st + self.length, t_start_s=st / self.fs,
                        t_end_s=(st + self.length) / self.fs, energy=energy[k], freq_hz=freq[k], input_active=inp_any[k],
                        lock=lock, energy_raw=None if raw is None else raw[k],
                    )
                )  # fmt: skip
                self._count += 1
        drop = max(0, min(self._next_start - self._buf_start, self._e.shape[0]))
        if drop:
            self._e, self._dphi, self._inp = self._e[drop:], self._dphi[drop:], self._inp[drop:]
            self._th, self._qb = self._th[drop:], self._qb[drop:]
            self._buf_start += drop
        return out

    def _features(self, q: FloatArray, qdot: FloatArray, at: int) -> None:
        """The block's energies, phase steps, phases and band-passed ``q`` into the buffers from row ``at`` on."""
        w = self.basis.omega
        e, dphi, theta, qb = self._e[at:], self._dphi[at:], self._th[at:], self._qb[at:]
        if self._sos is not None and q.shape[0] and q.dtype == qdot.dtype == w.dtype == np.float64:
            # the band-pass and the energies (band-limited, then raw) in one compiled pass: the arithmetic of
            # _bandpass_pairs and modal_energy, so the same numbers (three passes and a concatenation before)
            qdf = np.empty(qdot.shape)
            _bandpass_energies(np.ascontiguousarray(q), np.ascontiguousarray(qdot), self._sos, self._zi, w, qb, qdf, e,
                               self.energy_bandpass)  # fmt: skip
            np.arctan2(-qdf / w, qb, out=theta)  # modal_phase: numpy's atan2 (its SIMD one differs from libm's by an ulp)
        elif self._sos is not None and q.shape[0]:
            raw = modal_energy(q, qdot, w)
            q64, qd64 = np.ascontiguousarray(q, np.float64), np.ascontiguousarray(qdot, np.float64)
            qdf = np.empty_like(qd64)
            _bandpass_pairs(q64, qd64, self._sos, self._zi, qb, qdf)
            theta[:] = modal_phase(qb, qdf, w)
            e[:] = np.concatenate([modal_energy(qb, qdf, w), raw], axis=1) if self.energy_bandpass else raw
        else:
            e[:] = modal_energy(q, qdot, w)
            theta[:] = modal_phase(q, qdot, w)
            qb[:] = q
        if not theta.shape[0]:
            return
        prev = theta[0] if self._last_theta is None else self._last_theta
        _phase_steps(theta, prev, dphi)
        self._last_theta = theta[-1].copy()

    def _lock_tiles(self, starts: list[int]) -> list[tuple[FloatArray, FloatArray, FloatArray]]:
        """Each window's first hop (stream samples ``[st, st + hop)``), every ``stride``-th stream index: the tiles do
        not depend on how the stream was cut into blocks, and θ is unwrapped across them by the detector. Consecutive
        windows' hops tile ``[starts[0], starts[-1] + hop)``, so the lattice is taken once and split at the starts."""
        first = starts[0] + (-starts[0]) % self._stride
        idx = np.arange(first, starts[-1] + self.hop, self._stride) - self._buf_start
        cut = [0, *np.searchsorted(idx, np.asarray(starts[1:]) - self._buf_start).tolist(), idx.size]
        t, th, qb = idx / self.fs + self._buf_start / self.fs, self._th[idx], self._qb[idx]
        return [(t[a:b], th[a:b], qb[a:b]) for a, b in itertools.pairwise(cut)]  # slices (np.split: ~0.3 ms a block)


@numba.njit(cache=True, nogil=True, inline="always")
def _biquads(sos, z, j, x0, x1):  # pragma: no cover - compiled
    """Mode j's cascade of sections (``sos[j]``, state ``z[j]``) on one sample of the pair (q_j, q̇_j): scipy's
    direct-form-II-transposed section, the same operations in the same order as ``sosfilt``. Inlined into both
    kernels below (numba's IR inlining), so each keeps its single pass over the block."""
    for s in range(sos.shape[1]):
        b0, b1, b2, a1, a2 = sos[j, s, 0], sos[j, s, 1], sos[j, s, 2], sos[j, s, 4], sos[j, s, 5]
        y0 = b0 * x0 + z[j, s, 0, 0]
        z[j, s, 0, 0] = b1 * x0 - a1 * y0 + z[j, s, 1, 0]
        z[j, s, 1, 0] = b2 * x0 - a2 * y0
        y1 = b0 * x1 + z[j, s, 0, 1]
        z[j, s, 0, 1] = b1 * x1 - a1 * y1 + z[j, s, 1, 1]
        z[j, s, 1, 1] = b2 * x1 - a2 * y1
        x0 = y0
        x1 = y1
    return x0, x1


@numba.njit(cache=True, nogil=True)
def _bandpass_pairs(q, qd, sos, z, qf, qdf):  # pragma: no cover - compiled
    """Mode j's band-pass (``sos[j]``, state ``z[j]``) over the pair (q_j, q̇_j), in place of
    ``scipy.signal.sosfilt(sos[j], column_stack([q_j, q̇_j]), axis=0, zi=z[j])`` per mode — the same
    operations in the same order (scipy's direct-form-II-transposed sections), bit-identical
    (tests/test_detection.py), in one pass over the block instead of 2·r filter calls and copies."""
    n, r = q.shape
    for k in range(n):
        for j in range(r):
            qf[k, j], qdf[k, j] = _biquads(sos, z, j, q[k, j], qd[k, j])


@numba.njit(cache=True, nogil=True)
def _bandpass_energies(q, qd, sos, z, omega, qf, qdf, e, band):  # pragma: no cover - compiled
    """:func:`_bandpass_pairs` and, in the same pass, the linear modal energies of every sample
    (:func:`analysis.modal_filter.modal_energy`'s products in its order): with ``band`` the band-passed pair's in
    ``e[:, :r]`` and the raw pair's in ``e[:, r:]``, else the raw pair's only. One pass over the block instead of three
    and a concatenation (the modal lane's windower, on the caller's thread: issue 30)."""
    n, r = q.shape
    w2 = omega * omega
    for k in range(n):
        for j in range(r):
            x0 = q[k, j]
            x1 = qd[k, j]
            raw = 0.5 * (x1 * x1 + w2[j] * (x0 * x0))
            x0, x1 = _biquads(sos, z, j, x0, x1)
            qf[k, j] = x0
            qdf[k, j] = x1
            if band:
                e[k, j] = 0.5 * (x1 * x1 + w2[j] * (x0 * x0))
                e[k, r + j] = raw
            else:
                e[k, j] = raw


@numba.njit(cache=True, nogil=True)
def _phase_steps(theta, prev, out):  # pragma: no cover - compiled
    """The phase step of every sample from the one before (``prev``: the sample before the block), wrapped to
    [−π, π]: θ is an atan2 angle, so a step is off by 2π only where θ crossed ±π. Arithmetic, not
    ``np.angle(np.exp(1j·d))`` (three transcendental calls per sample and mode, ~1.5 ms per data-s at 14 ch), equal to
    it within rounding (1e-16 rad a sample); ``np.diff`` and ``d − 2π·round(d/2π)`` in one pass, the same numbers."""
    n, r = theta.shape
    for k in range(n):
        for j in range(r):
            d = theta[k, j] - (prev[j] if k == 0 else theta[k - 1, j])
            out[k, j] = d - (2 * np.pi) * np.round(d / (2 * np.pi))


@dataclass(frozen=True)
class ExchangeSettings:
    """Named thresholds of the exchange detector (docs/detection.md says how each was chosen)."""

    window_s: float = 0.0216  # the seed's experimental window (L1371)
    hop_s: float | None = None  # None: half a window
    pairs: tuple[tuple[int, int], ...] = ((1, 2),)  # (giving, receiving) mode numbers, 1-based
    min_gain: float = 2.0  # the receiving mode's energy at least doubles (the "major exchange")
    close_fraction: float = 0.8  # the event ends once the receiver fell below this fraction of its peak
    #: receiver peak must exceed this fraction of the peak total modal energy. 1e-4 was set on the raw mode-2
    #: coordinate (its noise "rose" x108 late in a decay); in mode 2's band the noise is flat and 2e-5 keeps every
    #: linear twin of the realistic grid free of false events (1e-5 lets 5 through in the 3 %-noise sessions, so 2x
    #: margin, the rule 1e-4 was set by). At 1e-4 it missed 220 of 246 missed exchanges in the 8 s and beam_al_mid
    #: classes, every one standing 3-3000x above the sensor noise in mode 2's band (docs/detection.md §7)
    floor_fraction: float = 2e-5
    noise_factor: float = 10.0  # ... and this multiple of its pre-input noise energy, when known
    #: where the band noise is known (measured before the input, or the sensors' noise through
    #: :func:`band_noise_energy`), the physical gate is ``noise_factor`` x that noise and the relative floor only a
    #: backstop against the modal filter's leakage, at this lower fraction: 5e-6 let false events through on three
    #: linear twins (up to 0.46 a hit, 8 s records at 3 % noise), 1e-5 none in any class: 2x margin (§3's rule;
    #: docs/detection.md §9)
    known_floor_fraction: float = 1e-5
    ratios: tuple[tuple[int, int], ...] = DEFAULT_RATIOS
    lock_tolerance: float = 0.04  # relative detuning |r − m/n| / (m/n) that counts as locked
    #: gain, lock, exchange, rq weights of :func:`evidence`, the scores' weighted mean that was the confidence before
    #: issue 21; the confidence is now calibrated (:data:`INTERVAL_CALIBRATION`) and does not use them
    weights: tuple[float, float, float, float] = (0.4, 0.3, 0.15, 0.15)
    #: events whose calibrated confidence is below this are dropped. 0.5: reported only when more likely a true
    #: exchange than not; on the realistic grid's held-out half this costs no recall (every true exchange found
    #: is at >= 0.54) and keeps precision 0.99 — the table in docs/evaluation.md §6. 0 reports every event
    min_confidence: float = 0.5
    #: search only after an input (a hit) was seen: before it the windows hold the noise floor, which
    #: is measured instead (a stream that starts mid-decay has no input and gets no events — by design)
    after_input_only: bool = True
    #: modal energies from each mode's band-passed states (:func:`phase_bands`) instead of the raw coordinates:
    #: late in a decay the raw mode-2 coordinate is mostly mode-1 leakage and integrated low-frequency noise,
    #: swinging x10-x100 between windows (issue 21); in its own band it is mode 2 and the noise in that band
    band_limited_energy: bool = True
    #: the noise floor is measured only on windows this long after the stream's start (the modal filter's
    #: 5 Hz high-passes and the band-passes settle; measured 6-10x too low in the first 0.1 s), and again
    #: before every input: the lower quartile of the quiet windows of the last ``noise_span_s``
    settle_s: float = 0.5
    noise_span_s: float = 1.0
    noise_decayed: float = 1e-4  # ... between hits only once the last hit's total modal energy fell below this of its peak
    #: label an event by the m:n locked to the giving mode's phase over the last ``lock_span_s`` (:func:`lock_fit`, the
    #: truth's test on the detector's band-passed states; docs/detection.md §8), falling back to
    #: :func:`slowest_phase_ratio` of the mean frequencies where nothing is locked or the windows carry no samples
    lock_label: bool = True
    lock_span_s: float = 0.3

    def __post_init__(self) -> None:
        if self.window_s <= 0 or (self.hop_s is not None and self.hop_s <= 0):
            raise ValueError("exchange: window_s and hop_s must be > 0")
        if self.min_gain <= 1 or not 0 < self.close_fraction < 1:
            raise ValueError("exchange: min_gain must be > 1 and 0 < close_fraction < 1")
        for g, r in self.pairs:
            if not 1 <= g < r:
                raise ValueError("exchange: pairs are (giving, receiving) mode numbers with giving < receiving")

    @property
    def hop(self) -> float:
        return self.hop_s if self.hop_s is not None else 0.5 * self.window_s


@dataclass(frozen=True)
class IREvent:
    """A flagged internal resonance: when, which modes, which ratio, how sure."""

    start_s: float
    end_s: float
    modes: tuple[int, int]  # (giving, receiving), 1-based
    m: int  # f_recv / f_give ≈ m / n
    n: int
    f_give_hz: float
    f_recv_hz: float
    gain: float  # receiver energy peak / minimum
    scores: dict[str, float] = field(default_factory=dict)
    confidence: float = 0.0  # calibrated P(a true major exchange), :data:`INTERVAL_CALIBRATION`
    source: str = "modal-exchange"
    label_confidence: float = 0.0  # calibrated P(a true major exchange with this m:n), :data:`LABEL_CALIBRATION`

    def as_dict(self) -> dict:
        return {
            "start_s": self.start_s, "end_s": self.end_s, "modes": list(self.modes), "ratio": f"{self.m}:{self.n}",
            "m": self.m, "n": self.n, "f_give_hz": self.f_give_hz, "f_recv_hz": self.f_recv_hz, "gain": self.gain,
            "scores": dict(self.scores), "confidence": self.confidence, "source": self.source,
            "label_confidence": self.label_confidence,
        }  # fmt: skip


def nearest_ratio(r: float, ratios: Sequence[tuple[int, int]] = DEFAULT_RATIOS) -> tuple[int, int]:
    """The candidate m:n nearest to the frequency ratio ``r`` — issue 6's "rounded to the nearest": absolute
    difference of m/n, ties to the first listed. The one rule for detector and evaluation truth alike.

    With the default candidates every ``r <= 1.5`` (halfway between 1:1 and 2:1, ties to the first) and every
    ``r`` below 1 is :data:`LEAK_RATIO` 1:1 — its own label, not the nearest of 2:1 ... 4:1 (issue 21)."""
    if not np.isfinite(r):
        raise ValueError("frequency ratio is not finite")
    return min(ratios, key=lambda mn: abs(mn[0] / mn[1] - r))


def slowest_phase_ratio(r: float, ratios: Sequence[tuple[int, int]] = DEFAULT_RATIOS) -> tuple[int, int]:
    """The candidate m:n whose slow phase ``m θ_give − n θ_recv`` (the seed's eq. 4.2, L1275) drifts slowest at the
    frequency ratio ``r = f_recv / f_give``: ``argmin n |r − m/n|`` (its rate is ``f_give n |r − m/n|``), ties to the
    first listed. The detector's label rule since issue 21 (docs/detection.md §8).

    Why not :func:`nearest_ratio` (``argmin |r − m/n|``): an exchange is the slow phase turning, and for the same ratio
    error an n = 2 phase turns twice as fast as an n = 1 phase. On both grid rigs the exchanges are the cubic spring's
    3 f1 response beating against mode 2's free oscillation at 3.1-3.4 f1 (measured, docs/evaluation.md §8): they recur
    at ``1/|f2 − 3 f1|``, the 3:1 phase's period, not the 7:2 phase's, while f2/f1 = 3.29 is nearer 3.5 than 3. The
    boundaries move from the midpoints to ``2.33, 2.67, 3.33, 3.67`` between 2:1 ... 4:1; 1:1 | 2:1 stays 1.5."""
    if not np.isfinite(r):
        raise ValueError("frequency ratio is not finite")
    return min(ratios, key=lambda mn: mn[1] * abs(mn[0] / mn[1] - r))


def _edge(t: FloatArray, i: int) -> float:
    """``t[i]`` (first or last sample time of a lock tile), 0.0 for an empty tile."""
    return float(t[i]) if t.size else 0.0


class _PairState:
    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.lo: WindowFeatures | None = None
        self.hi: WindowFeatures | None = None
        self.open = False
        self.windows: list[WindowFeatures] = []


class ExchangeDetector:
    """Streaming: feed :class:`WindowFeatures` in order, get :class:`IREvent` s when they close."""

    def __init__(
        self,
        settings: ExchangeSettings | None = None,
        damping: Sequence[float] | None = None,
        n_modes: int | None = None,
        noise_prior: Sequence[float] | FloatArray | None = None,
        lock_submit: Callable[..., Future] | None = None,
    ) -> None:
        """``lock_submit(fn, *args) -> Future``: where the phase-lock fits run (a worker's ``submit``); events then come
        out as :class:`PendingEvent` s. None: here, at once."""
        self.s = settings or ExchangeSettings()
        self.lock_submit = lock_submit
        self._prior: FloatArray | None = None
        self.set_noise_prior(noise_prior)
        self.damping = None if damping is None else np.asarray(damping, float)  # ζ per mode, for the exchange score
        self._pairs = {p: _PairState() for p in self.s.pairs}
        self._peak_total = 0.0
        self._noise: FloatArray | None = None  # per mode: noise energy of the quiet windows before the last input
        self._quiet: list[tuple[float, FloatArray]] = []  # (t_end, energy) of settled windows since the last input
        self._t0: float | None = None  # the first window's start: the stream's
        self._seen_input = False
        self._recent: deque[tuple[FloatArray, FloatArray, FloatArray]] = deque()  # WindowFeatures.lock since the input
        if n_modes is not None:
            for g, r in self.s.pairs:
                if r > n_modes:
                    raise ValueError(f"exchange pair {g}-{r} needs {r} modes in the modal filter, it has {n_modes}")

    def set_noise_prior(self, energy: Sequence[float] | FloatArray | None) -> None:
        """The band noise energy per mode known from the sensors (:func:`band_noise_energy` of their noise std
        through the modal filter in use; None: unknown). A measured floor (quiet windows before an input)
        takes precedence where it exists; rebuilt filters (a sensor excluded) need a new prior."""
        self._prior = None if energy is None else np.asarray(energy, float)

    def _measure_noise(self) -> None:
        """At an input: per mode, the lower quartile of the settled quiet windows of the last ``noise_span_s``, taken
        only where they are noise: before the first input, or once the previous hit's decay has died away (total
        modal energy below ``noise_decayed`` of its peak since that input) and the windows are stationary (the first
        half's mean within 2x the second's). A decay's tail, even one beating at a steady level, is the structure,
        not the floor: taken as the floor it gated the next hit's exchanges (recall 0.88 -> 0.53 on the realistic
        grid's 5-hit sessions). At least 8 windows."""
        end = self._quiet[-1][0] if self._quiet else 0.0
        recent = np.array([e for t, e in self._quiet if t >= end - self.s.noise_span_s])
        self._quiet.clear()
        if len(recent) < 8:
            return
        if self._seen_input and float(recent.sum(axis=1).mean()) > self.s.noise_decayed * self._peak_total:
            return
        half = len(recent) // 2
        steady = recent[:half].mean(axis=0) <= 2.0 * recent[half:].mean(axis=0)
        floor = np.quantile(recent, 0.25, axis=0)
        if self._noise is None:
            self._noise = np.where(steady, floor, np.nan)
        else:
            self._noise = np.where(steady, floor, self._noise)

    def clear_quiet(self) -> None:
        """Forget the quiet windows kept so far: what came before held interference now removed (stationary lines,
        analysis/lines.py), so a floor measured on them would be the interference's and gate the exchanges under it."""
        self._quiet.clear()

    def _keep_quiet(self, w: WindowFeatures) -> None:
        if self._t0 is None:
            self._t0 = w.t_start_s
        if w.t_start_s - self._t0 >= self.s.settle_s:
            self._quiet.append((w.t_end_s, w.energy))
            if len(self._quiet) > 256:  # bounded: ~2.8 s of 21.6 ms windows at half-window hops
                self._quiet.pop(0)

    def feed(self, w: WindowFeatures) -> list[IREvent | PendingEvent]:
        out: list[IREvent] = []
        if w.input_active:
            self._measure_noise()
            self._seen_input = True
            for p, st in self._pairs.items():  # an input ends any open event and restarts the search
                if st.open:
                    out.extend(self._close(p, st))
                st.reset()
            self._peak_total = 0.0
            self._recent.clear()
            return out
        self._keep_quiet(w)
        if w.lock is not None and self.s.lock_label:
            self._recent.append(w.lock)
            # the span from the oldest tile's first sample to the newest's last (an empty tile counts as 0 s, as the
            # sums of its empty slices did): scalars, not array reductions, in the per-window path
            while len(self._recent) > 1 and _edge(self._recent[-1][0], -1) - _edge(self._recent[0][0], 0) > self.s.lock_span_s:
                self._recent.popleft()
        if not self._seen_input and self.s.after_input_only:
            return out
        self._peak_total = max(self._peak_total, float(w.energy.sum()))
        for p, st in self._pairs.items():
            e = float(w.energy[p[1] - 1])
            if st.open:
                st.windows.append(w)
                if e > float(st.hi.energy[p[1] - 1]):
                    st.hi = w
                elif e < self.s.close_fraction * float(st.hi.energy[p[1] - 1]):
                    out.extend(self._close(p, st))
                    st.lo = w
                continue
            if st.lo is None or e < float(st.lo.energy[p[1] - 1]):
                st.lo, st.windows = w, [w]
                continue
            st.windows.append(w)
            lo = float(st.lo.energy[p[1] - 1])
            if e >= self.s.min_gain * lo and self._above_floor(p, e):
                st.open, st.hi = True, w
        return out

    def finish(self) -> list[IREvent | PendingEvent]:
        out: list = []
        for p, st in self._pairs.items():
            if st.open:
                out.extend(self._close(p, st))
            st.reset()
        return out

    def _above_floor(self, pair: tuple[int, int], e: float) -> bool:
        """The receiver's energy stands ``noise_factor`` x above the band noise where that is known (measured, else
        the sensors' prior) with the relative backstop ``known_floor_fraction``; else above ``floor_fraction`` x the
        peak total, the stand-in for an unknown noise."""
        j = pair[1] - 1
        noise = np.nan if self._noise is None else float(self._noise[j])
        if not np.isfinite(noise) and self._prior is not None:
            noise = float(self._prior[j])
        if np.isfinite(noise) and noise > 0:
            return e >= self.s.known_floor_fraction * self._peak_total and e >= self.s.noise_factor * noise
        return e >= self.s.floor_fraction * self._peak_total

    def _lock_args(self, g: int, r: int, f_give: float) -> tuple | None:
        """:func:`lock_fit`'s arguments over the last ``lock_span_s`` of samples (after the last input), up to the window
        now; None without samples."""
        t = np.concatenate([x[0] for x in self._recent])
        if t.size == 0:
            return None
        ok = t >= t[-1] - self.s.lock_span_s
        th = np.unwrap(np.concatenate([x[1][:, g] for x in self._recent]))
        y = np.concatenate([x[2][:, r] for x in self._recent])
        return t[ok], y[ok], th[ok], f_give, self.s.ratios

    def _close(self, pair: tuple[int, int], st: _PairState) -> list[IREvent] | list[PendingEvent]:
        """The event of ``pair`` (none below ``min_confidence``). With a ``lock_submit``, its phase-lock fit runs there
        and a :class:`PendingEvent` stands for it until resolved."""
        g, r = pair[0] - 1, pair[1] - 1
        lo, hi = st.lo, st.hi
        assert lo is not None and hi is not None
        span = [w for w in st.windows if lo.index <= w.index <= hi.index]
        st.reset()
        f_give = float(np.mean(_column(span, g)))
        args = self._lock_args(g, r, f_give) if self.s.lock_label and self._recent else None
        if args is not None and self.lock_submit is not None:
            return [PendingEvent(lo.t_start_s, hi.t_end_s, self.lock_submit(lock_fit, *args),
                                 lambda locked: self._event(pair, lo, hi, span, f_give, locked))]  # fmt: skip
        return self._event(pair, lo, hi, span, f_give, None if args is None else lock_fit(*args))

    def _event(self, pair: tuple[int, int], lo: WindowFeatures, hi: WindowFeatures, span: list[WindowFeatures],
               f_give: float, locked: tuple[int, int] | None) -> list[IREvent]:  # fmt: skip
        """The event from its windows ``lo`` .. ``hi`` and the phase-lock fit's m:n (None: none stood out, or no
        samples), with its scores and confidences; none below ``min_confidence``."""
        g, r = pair[0] - 1, pair[1] - 1
        fg, fr = _column(span, g), _column(span, r)
        f_recv = float(np.mean(fr))
        ratios = fr[fg > 0] / fg[fg > 0]
        ratio = f_recv / f_give if f_give > 0 else float("nan")
        m, n = slowest_phase_ratio(ratio, self.s.ratios) if np.isfinite(ratio) else (0, 0)
        m, n = locked if locked is not None else (m, n)
        e_lo, e_hi = float(lo.energy[r]), float(hi.energy[r])
        gain = e_hi / e_lo if e_lo > 0 else float("inf")
        lock = float(np.mean(np.abs(ratios / (m / n) - 1) <= self.s.lock_tolerance)) if ratios.size and n else 0.0
        gained = e_hi - e_lo
        lost = float(lo.energy[g] - hi.energy[g])
        if self.damping is not None and self.damping.size > g:
            # what mode g would have lost on its own by linear damping over the interval: E e^{-2ζωΔt}
            dt = hi.t_end_s - lo.t_start_s
            omega = 2 * np.pi * float(np.mean(fg))
            lost -= float(lo.energy[g]) * (1 - np.exp(-2 * self.damping[g] * omega * dt))
        exchange = float(np.clip(lost / gained, 0.0, 1.0)) if gained > 0 else 0.0
        scores = {"gain": float(np.clip((np.log2(gain) if np.isfinite(gain) else 4.0) / 2.0, 0.0, 1.0)), "lock": lock,
                  "exchange": exchange, "rq": 0.0}  # fmt: skip
        ev = IREvent(
            start_s=lo.t_start_s, end_s=hi.t_end_s, modes=(pair[0], pair[1]), m=m, n=n,
            f_give_hz=f_give, f_recv_hz=f_recv,
            gain=gain, scores=scores, confidence=confidence(scores), label_confidence=label_confidence(scores),
        )  # fmt: skip
        return [ev] if ev.confidence >= self.s.min_confidence else []


def _column(span: list[WindowFeatures], j: int) -> FloatArray:
    """Mode ``j``'s measured frequency over the windows ``span``, one contiguous array: an event's means and ratios
    read it five times, and a list of numpy scalars is converted element by element each time (a long event holds
    hundreds of windows). The same values in the same order, so the same means (numpy's pairwise sum)."""
    return np.array([w.freq_hz[j] for w in span])


@dataclass(frozen=True)
class PendingEvent:
    """An event whose phase-lock fit is running elsewhere (:class:`ExchangeDetector`'s ``lock_submit``): its interval
    is known, its m:n, scores and confidence once :meth:`resolve` has the fit (waiting for it). ``resolve`` gives what
    the detector would have returned without the worker: the event, or nothing below ``min_confidence``."""

    start_s: float
    end_s: float
    future: Future
    finish: Callable[[tuple[int, int] | None], list[IREvent]]

    def resolve(self) -> list[IREvent]:
        return self.finish(self.future.result())


@dataclass(frozen=True)
class Calibration:
    """``P = 1 / (1 + exp(-(intercept + Σ_k coef_k · score_k)))`` over the named evidence scores.

    Why logistic with non-negative slopes: each score is evidence *for* an exchange, so the probability must not
    fall when one rises (monotone, checked in tests/test_confidence.py), and with three scores and a few hundred
    false or mislabelled events a two-to-four-parameter model is what the data can hold (isotonic maps on the
    weighted mean overfit the few false events, docs/evaluation.md §6). ``rq`` is not among the keys: the
    evaluation runs no seed lane, and the window-robust RQ spikes alone score 0 TP / 12 FP (docs/detection.md §4),
    so they carry no measured weight; the operator still records the score."""

    intercept: float
    coef: tuple[float, ...]
    keys: tuple[str, ...] = ("gain", "lock", "exchange")

    def __post_init__(self) -> None:
        if len(self.coef) != len(self.keys) or any(c < 0 or not np.isfinite(c) for c in self.coef):
            raise ValueError("calibration: one finite, non-negative coefficient per score")

    def __call__(self, scores: dict[str, float]) -> float:
        z = self.intercept + sum(c * float(scores.get(k, 0.0)) for c, k in zip(self.coef, self.keys, strict=True))
        return float(0.5 * (1.0 + np.tanh(0.5 * z)))  # the logistic, without overflow at large |z|


# Fitted by `python bench/calibrate_confidence.py` (the JSON: bench/results/calibrate_confidence.json) on the fit
# half of the realistic grid's cases (crc32 of the case name even), 2026-11-26, refitted after issue 21's phase-lock
# labels (truth and detector, docs/evaluation.md §8: labels right on 99 % of matched events, so the label map is
# nearly the interval map); the reliability of both on the held-out half is docs/evaluation.md §6 and §8. Refit when
# the detector or its scores change.
#: P(the event's interval matches a true major exchange)
INTERVAL_CALIBRATION = Calibration(-9.323, (18.328, 0.361, 2.438))
#: P(it matches one and its m:n is the truth's)
LABEL_CALIBRATION = Calibration(-12.414, (19.603, 0.0, 5.84))


def confidence(scores: dict[str, float], weights: Sequence[float] | None = None) -> float:
    """The event's calibrated confidence (:data:`INTERVAL_CALIBRATION`). ``weights`` is accepted for the callers of
    the weighted mean it replaced and ignored (that mean is :func:`evidence`)."""
    return INTERVAL_CALIBRATION(scores)


def label_confidence(scores: dict[str, float]) -> float:
    """The calibrated probability that the event is a true exchange *and* its m:n is right (:data:`LABEL_CALIBRATION`)."""
    return LABEL_CALIBRATION(scores)


def evidence(scores: dict[str, float], weights: Sequence[float]) -> float:
    """The scores' weighted mean (gain, lock, exchange, rq): the confidence before issue 21, not a probability."""
    keys = ("gain", "lock", "exchange", "rq")
    w = np.asarray(weights, float)
    return float(np.dot(w, [scores.get(k, 0.0) for k in keys]) / w.sum())


def with_rq_score(event: IREvent, rq_score: float, weights: Sequence[float] | None = None) -> IREvent:
    """The event with the seed lane's ``rq`` score recorded; its calibrated confidences do not use ``rq``
    (:class:`Calibration`), so they stay as they are (``weights`` is ignored, as in :func:`confidence`)."""
    return replace(event, scores={**event.scores, "rq": float(rq_score)})


def detect_exchanges(
    data: FloatArray,
    sample_rate: float,
    basis: ModalBasis,
    settings: ExchangeSettings | None = None,
    filter_settings: ModalFilterSettings | None = None,
    input_active: FloatArray | None = None,
    damping: Sequence[float] | None = None,
    first_index: int = 0,
) -> tuple[list[IREvent], list[WindowFeatures]]:
    """Batch: the streaming chain on one block (``data``: sensor acceleration or displacement, (N, n_dof))."""
    s = settings or ExchangeSettings()
    fs = float(sample_rate)
    tracker = ModalStateTracker(basis, fs, filter_settings)
    windower = ModalWindower(basis, fs, round(s.window_s * fs), max(1, round(s.hop * fs)), first_index,
                             energy_bandpass=s.band_limited_energy)  # fmt: skip
    det = ExchangeDetector(s, damping, basis.n_modes)
    q, qd = tracker.feed(data)
    windows = windower.feed(q, qd, input_active)
    events = [ev for w in windows for ev in det.feed(w)]
    events.extend(det.finish())
    return events, windows
