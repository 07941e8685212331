"""Sensor health from the data: which channels the modal filter may trust (issue 21, item 2).

The modal filter ``q = Φᵀ M x`` (analysis/modal_filter.py) weighs every sensor: one dead channel leaks
~3 % of mode 1's energy into mode 2, a dead attachment sensor 46 % (issue 21's diagnosis), which is
enough to open false events and hide true ones. The seed assumes working sensors at the model's DOFs
(assumptions 5-7, L63-L65) and one on the nonlinear element (assumption 11, L69); nothing in its chain
checks either. :class:`SensorHealth` judges each channel from the stream itself, causally, block by
block, and names the fault with its reason:

* **dead** — non-finite samples; flat at zero; or a level far below the other channels' (a
  disconnected IEPE input reads the ADC's own noise, ~1e-3 of a live sensor's);
* **stuck** — the same value for ``stuck_s`` on end while the other channels move;
* **clipping** — samples at the channel's stated range (when the rig states one) and none beyond it (a
  saturated chain reads full scale, never more);
* **drifting** — the mean of a ``drift_window_s`` window wandering from the first window's by more
  than ``drift_factor`` × that window's own standard deviation (a vibration's partial-cycle mean over
  >= 20 periods is < 1 % of its std; a ramp or an offset step is not);
* **noisy** — before the first input (the quiet, pre-hit record), a noise level ``noisy_factor`` × the
  median channel's, in volts when the sensitivities are known (a sensor's noise is an electrical
  property: a less sensitive sensor legitimately shows more noise in m/s²);
* **inconsistent** — during a hit, the channel's band-limited response against the model's expectation
  from its neighbours: leave-one-out, the modes of the model condensed to the other healthy channels
  predict this one (``x̂_k = Φ_k Φ_{-k}⁺ x_{-k}``); a residual beyond ``inconsistent`` of the channel's
  level and ``inconsistent_over_median`` × the median channel's residual flags it. With one bad channel
  among 14 the others' predictions use it too, so only the worst channel is judged at a time, removed,
  and the rest judged again (the leave-one-out of the bad channel itself is clean).

Thresholds, measured on the evaluation grid (analysis/evaluation, 24 + 24 hits of beam_ch4_exp and of
beam_al_mid at 1-3 % noise and ±5 % sensitivity errors, docs/detection.md "Sensor health"):

* healthy channels' level is >= 0.31 × the median's (the quietest sensor, near the clamp, over whole
  records; >= 0.47 over the first 1024 samples); a dead channel is ~1e-5: ``dead_rel`` = 0.02 sits
  15× below the quietest healthy channel and 2000× above a dead one;
* the leave-one-out residual of a healthy channel (4 modes, 5 Hz to between modes 4 and 5) is <= 0.17
  of its level, of a dead one 1.0: ``inconsistent`` = 0.5 is 3× above the healthy worst;
* a drift of 3 window stds cannot come from vibration (< 0.02) or noise (~1/√N);
* ``noisy_factor`` = 10: in the grid the noise is sized per channel (1 % of its RMS), so a healthy
  channel's noise is within 3.2× of the median's.

Pure and bounded: a few accumulators per channel, a (n, n) covariance for the hit check, ``drift``
window means; verdicts are final (a bad channel stays bad for the stream).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numba
import numpy as np

from analysis.lines import LineCanceller, LineFound, LineSettings
from analysis.modal_filter import ModalBasis, modal_basis
from analysis.preprocess import _sections, butter_sos

#: the fewest samples a level span holds (a stuck run: half of it), at any sample rate
MIN_SPAN_SAMPLES = 32

Fault = Literal["dead", "stuck", "clipping", "drifting", "noisy", "inconsistent", "polarity"]

#: a sample at or above this fraction of the stated range counts as clipped (daq/hits.py's CLIP_FRACTION)
CLIP_FRACTION = 0.999
#: ... but a saturated channel never reads beyond its full scale: a value past this fraction of the stated range
#: means the range is not where the chain saturates (a simulator, or a DAQ range wider than the sensor's rating),
#: and the samples near it are signal, not clipping (the evaluation grid's hardest hits exceed the ±4905 m/s²
#: rating of beam_ch4_exp's accelerometers unclipped)
OVER_RANGE = 1.001


@dataclass(frozen=True)
class HealthSettings:
    """Named thresholds (the module docstring says how each was chosen)."""

    level_min_s: float = 0.015  # level, flat, stuck and clipping are judged on spans this long (256 samples at 16 kHz)
    dead_rel: float = 0.02  # level below this fraction of the median channel's: dead
    stuck_s: float = 0.02  # identical consecutive samples for this long (328 at 16 kHz) while others move: stuck
    clip_samples: int = 2  # samples at the range within one judgement: clipping
    drift_window_s: float = 1.0  # at least 20 periods of NNM1 for f1 >= 20 Hz
    drift_factor: float = 3.0
    noisy_factor: float = 10.0
    quiet_min_s: float = 0.25  # pre-input data needed before the noise is judged
    hit_settle_s: float = 0.03  # after the pulse: the band-pass and the impact's broadband kick settle
    hit_span_s: float = 0.27  # response judged over this span
    inconsistent: float = 0.5
    inconsistent_over_median: float = 3.0
    band_lo_hz: float = 5.0  # the modal filter's high-pass corner
    max_excluded_per_hit: int = 2
    #: polarity is judged on the hit's first response, right after the pulse (a flipped sensor must leave before the
    #: exchange windows start, not ``hit_span_s`` later): the correlation of each channel with its neighbours'
    #: leave-one-out prediction over this span; a flipped sensor reads its prediction's negative (-0.9 ... -1 on
    #: both grid rigs), a healthy one >= 0.6 (docs/detection.md "Sensor health")
    polarity_settle_s: float = 0.002
    polarity_span_s: float = 0.02
    polarity_corr: float = -0.5

    def __post_init__(self) -> None:
        if min(self.level_min_s, self.stuck_s, self.drift_window_s, self.hit_span_s) <= 0 or self.dead_rel <= 0:
            raise ValueError("sensor health: spans and dead_rel must be > 0")


@dataclass(frozen=True)
class Verdict:
    """One channel judged bad: which, what, why, when (s on the stream's clock)."""

    channel: str
    fault: Fault
    reason: str
    t_s: float
    index: int = 0  # the stream sample (counted from the first fed) at which it was judged: the filter switches there

    def line(self) -> str:
        return f"sensor {self.channel} {self.fault}: {self.reason}"


def _median(a: np.ndarray) -> float:
    """Median of a short vector (one per channel) without np.median's overhead; 0 for none."""
    if a.size == 0:
        return 0.0
    b = np.sort(a)
    h = b.size // 2
    return float(b[h]) if b.size % 2 else 0.5 * float(b[h - 1] + b[h])


def guyan_condense(M: np.ndarray, K: np.ndarray, keep: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
    """Static (Guyan) condensation of ``(M, K)`` onto the DOFs ``keep`` (eqs. 2.19-2.22).

    Condensing a Guyan model again is the Guyan model at the fewer DOFs (static condensation is exact
    for statics and composes), so the modal filter without a sensor needs only the operator's matrices.
    """
    keep = list(keep)
    drop = [i for i in range(M.shape[0]) if i not in keep]
    if not drop:
        return M.copy(), K.copy()
    T = np.zeros((M.shape[0], len(keep)))
    T[keep, np.arange(len(keep))] = 1.0
    T[drop] = -np.linalg.solve(K[np.ix_(drop, drop)], K[np.ix_(drop, keep)])
    return T.T @ M @ T, T.T @ K @ T


def reduced_basis(M: np.ndarray, K: np.ndarray, keep: Sequence[int], n_modes: int, like: np.ndarray | None = None) -> ModalBasis:
    """The modal basis of the model condensed to ``keep``. ``like``: the previous basis's shapes at the DOFs
    ``keep`` (rows in ``keep``'s order); each new mode takes the sign that agrees with it, so that the modal
    coordinates stay continuous when a filter swaps bases mid-stream."""
    Mr, Kr = guyan_condense(M, K, keep)
    b = modal_basis(Mr, Kr, min(n_modes, len(keep)))
    if like is None or like.shape != (len(keep), b.n_modes):
        return b
    sign = np.where(np.sum(b.shapes * (Mr @ like), axis=0) < 0, -1.0, 1.0)
    shapes = b.shapes * sign
    return ModalBasis(omega=b.omega, shapes=shapes, projector=shapes.T @ Mr)


def _loo_weights(shapes: np.ndarray) -> np.ndarray:
    """Row k: the weights ``u`` with ``u_k = 0`` that predict channel k from the others through the modes,
    ``u_{-k} = Φ_k Φ_{-k}⁺``. The n pseudo-inverses as one stacked call (the same LAPACK call per matrix, the same
    numbers as one at a time, ~3x faster at 14 channels)."""
    n = shapes.shape[0]
    others = np.array([[j for j in range(n) if j != k] for k in range(n)], np.int64).reshape(n, n - 1)
    pinvs = np.linalg.pinv(shapes[others])  # (n, modes, n - 1)
    U = np.zeros((n, n))
    for k in range(n):
        U[k, others[k]] = shapes[k] @ pinvs[k]
    return U


def loo_residuals(S: np.ndarray, shapes: np.ndarray, U: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Leave-one-out: for each channel k, the RMS of ``x_k − Φ_k Φ_{-k}⁺ x_{-k}`` relative to the larger of the
    channel's and the prediction's RMS, and the prediction's RMS over the channel's; from the channels'
    (band-passed) covariance ``S`` alone. ``U``: :func:`_loo_weights` of ``shapes`` if already at hand."""
    n = S.shape[0]
    rel, pred_over = np.zeros(n), np.zeros(n)
    U = _loo_weights(shapes) if U is None else U
    for k in range(n):
        u = U[k].copy()
        own, pred = float(S[k, k]), float(u @ S @ u)
        v = -u
        v[k] = 1.0
        res = max(float(v @ S @ v), 0.0)
        rel[k] = np.sqrt(res / max(own, pred, 1e-300))
        pred_over[k] = np.sqrt(pred / max(own, 1e-300))
    return rel, pred_over


def loo_correlations(S: np.ndarray, shapes: np.ndarray, U: np.ndarray | None = None) -> np.ndarray:
    """Leave-one-out: for each channel k, the correlation of ``x_k`` with ``Φ_k Φ_{-k}⁺ x_{-k}`` (its neighbours'
    prediction through the modes), from the channels' covariance ``S`` alone; 0 where either is silent. ``U``:
    :func:`_loo_weights` of ``shapes`` if already at hand."""
    n = S.shape[0]
    out = np.zeros(n)
    U = _loo_weights(shapes) if U is None else U
    for k in range(n):
        u = U[k]
        den = float(S[k, k]) * float(u @ S @ u)
        out[k] = float(S[k] @ u) / np.sqrt(den) if den > 0 else 0.0
    return out


def _near_range(x: np.ndarray, ranges: np.ndarray) -> bool:
    """Whether any sample of ``x`` (rows x channels) reaches ``CLIP_FRACTION`` of its channel's range: the block's
    column extrema (daq/hits.py's grouping trick: a reduction along the rows of a narrow array, reshaped to rows of
    64 x channels, runs ~20x faster), instead of the comparison of every sample."""
    n, c = x.shape
    m = n - n % 64
    head = x[:m].reshape(-1, 64 * c)
    hi = np.maximum(head.max(axis=0, initial=-np.inf).reshape(64, c).max(axis=0), x[m:].max(axis=0, initial=-np.inf))
    lo = np.minimum(head.min(axis=0, initial=np.inf).reshape(64, c).min(axis=0), x[m:].min(axis=0, initial=np.inf))
    return bool((np.maximum(hi, -lo) >= CLIP_FRACTION * ranges).any())


def span_sums(x: np.ndarray, L: int) -> tuple[np.ndarray, np.ndarray]:
    """Σx and Σx² per channel over each span of ``L`` rows of ``x`` (rows a multiple of ``L``): ``(spans, channels)``
    each, added in row order, the order numpy's ``sum(axis=0)`` and ``einsum("ij,ij->j")`` add a C-ordered
    ``(rows, channels)`` array in (the same numbers, tested), in one pass instead of two (~0.8 → 0.1 ms a 0.5 s block
    of 14 channels)."""
    k = x.shape[0] // L
    s1, s2 = np.empty((k, x.shape[1])), np.empty((k, x.shape[1]))
    _span_sums(np.ascontiguousarray(x, dtype=np.float64), L, s1, s2)
    return s1, s2


@numba.njit(cache=True, nogil=True)
def _span_sums(x, L, s1, s2):  # pragma: no cover - compiled
    c = x.shape[1]
    for k in range(s1.shape[0]):
        for j in range(c):
            s1[k, j] = 0.0
            s2[k, j] = 0.0
        for i in range(k * L, (k + 1) * L):
            for j in range(c):
                v = x[i, j]
                s1[k, j] += v
                s2[k, j] += v * v


@numba.njit(cache=True, nogil=True)
def _span_sums_repeats(x, L, last, s1, s2, rep):  # pragma: no cover - compiled
    """:func:`_span_sums` and, in the same pass, ``rep[k, j]``: whether any sample of channel j in span k equals the
    one before it (``last`` before the first row), as ``np.equal`` of the block against itself shifted and ``any`` per
    span did in two more passes over a block-sized mask (issue 30). NaN equals nothing, as in ``np.equal``."""
    c = x.shape[1]
    prev = last.copy()
    for k in range(s1.shape[0]):
        for j in range(c):
            s1[k, j] = 0.0
            s2[k, j] = 0.0
            rep[k, j] = False
        for i in range(k * L, (k + 1) * L):
            for j in range(c):
                v = x[i, j]
                s1[k, j] += v
                s2[k, j] += v * v
                rep[k, j] |= v == prev[j]
                prev[j] = v


@numba.njit(cache=True, nogil=True)
def _bandpass_rows(sos, x, z, y, lo, hi):  # pragma: no cover - compiled
    """``out, z = scipy.signal.sosfilt(sos, x, axis=0, zi=z)`` (``z`` updated in place), bit for bit, with only the
    rows ``out[lo:hi]`` kept (in ``y``, ``hi − lo`` rows): the sections of the causal §4.3 chain (analysis/preprocess.py
    ``_sections``, the library's arithmetic operation for operation), with the channels innermost. The library copies
    an ``(n, channels)`` block to channel-major order and back (~1.9 ms a 0.5 s block of 14 channels); this runs in
    place (~0.4 ms). Every row goes through the filter (its state must), but the hit check reads only the rows of its
    spans, a few hundred ms after each input: the rest are not written (a block-sized array fewer, issue 30)."""
    n, c = x.shape
    buf = np.empty(c)
    for k in range(n):
        for j in range(c):
            buf[j] = x[k, j]
        _sections(buf, sos, z)
        if lo <= k < hi:
            for j in range(c):
                y[k - lo, j] = buf[j]


def _row_median(a: np.ndarray) -> np.ndarray:
    """:func:`_median` of every row of ``a`` (spans x channels) at once: the same sort and the same formula."""
    b = np.sort(a, axis=1)
    h = b.shape[1] // 2
    return b[:, h] if b.shape[1] % 2 else 0.5 * (b[:, h - 1] + b[:, h])


class _SpanStats:
    """One block's level spans ``(k, L, channels)`` reduced at once: Σx and Σx² per span, the samples at and beyond
    the stated range, whether the input was active, and the runs of identical consecutive samples — the longest per
    span and the run carried into each span's start (``carry``: ``k + 1`` rows), counted as ``_stuck`` counts them
    (equal pairs, continued from ``carry0`` across the block's start against ``last``)."""

    def __init__(self, spans: np.ndarray, ranges: np.ndarray, last: np.ndarray, carry0: np.ndarray,
                 inp: np.ndarray | None, at: int) -> None:  # fmt: skip
        k, L, c = spans.shape
        x = spans.reshape(k * L, c)
        self.at = at
        self.s1, self.s2, self.repeats = np.empty((k, c)), np.empty((k, c)), np.empty((k, c), bool)
        _span_sums_repeats(np.ascontiguousarray(x, dtype=np.float64), L, np.asarray(last, np.float64), self.s1, self.s2,
                           self.repeats)  # fmt: skip
        self.inp = np.zeros(k, bool) if inp is None else inp[at : at + k * L].reshape(k, L).any(axis=1)
        if np.isfinite(ranges).any() and _near_range(x, ranges):  # a block far from every range clips nowhere
            a = np.abs(spans)
            self.clips = np.count_nonzero(a >= CLIP_FRACTION * ranges, axis=1)
            self.beyond = np.count_nonzero(a > OVER_RANGE * ranges, axis=1)
        else:
            self.clips = self.beyond = np.zeros((k, c), np.int64)
        self.runs = np.zeros((k, c), np.int64)
        self.carry = np.zeros((k + 1, c), np.int64)
        self.carry[0] = carry0
        cols = np.flatnonzero(self.repeats.any(axis=0))
        if cols.size:  # run length at each sample: equal pairs since the last sample that differed (or the carry)
            same = np.empty(x.shape, bool)
            same[0] = x[0] == last
            np.equal(x[1:], x[:-1], out=same[1:])
            sc = same[:, cols]
            idx = np.arange(k * L)[:, None]
            brk = np.maximum.accumulate(np.where(sc, -1, idx), axis=0)
            r = np.where(brk < 0, idx + 1 + carry0[cols], idx - brk)
            self.runs[:, cols] = r.reshape(k, L, cols.size).max(axis=1)
            self.carry[1:, cols] = r[L - 1 :: L]


class SensorHealth:
    """Feed blocks ``(n_samples, n_channels)`` of one stream in order (with the hammer's input mask, when known);
    get the channels newly judged bad. ``M``, ``K``: the reduced model at the channels (their order) for the
    hit check; ``ranges`` (SI, None: unknown) and ``sensitivities`` (mV per SI unit) per channel, optional."""

    def __init__(
        self, channels: Sequence[str], sample_rate: float, M: np.ndarray | None = None, K: np.ndarray | None = None,
        n_modes: int = 4, ranges: Sequence[float | None] | None = None, sensitivities: Sequence[float] | None = None,
        settings: HealthSettings | None = None,
    ) -> None:  # fmt: skip
        self.channels = tuple(channels)
        n = len(self.channels)
        self.fs = float(sample_rate)
        self.s = settings or HealthSettings()
        self.M, self.K, self.n_modes = M, K, int(n_modes)
        self._range = np.array([np.inf if r is None else float(r) for r in (ranges or [None] * n)])
        self._volts = np.ones(n) if sensitivities is None else np.asarray(sensitivities, float)
        if self._range.shape != (n,) or self._volts.shape != (n,):
            raise ValueError("sensor health: one range and one sensitivity per channel")
        self.bad: dict[str, Verdict] = {}
        self._index = 0  # samples seen
        self._at = 0  # the sample a verdict being made is judged at
        # spans in seconds are tuned at 16 kHz; at the low end of lab rates (256 Hz: 4 samples) a span that short
        # calls a sensor still at rest a few samples after the hit "flat at 0" (the seed's 2-DOF log at 50 Hz):
        # a judgment needs a few dozen samples whatever the rate
        self._level_n = max(MIN_SPAN_SAMPLES, round(self.s.level_min_s * self.fs))
        self._stuck_n = max(MIN_SPAN_SAMPLES // 2, round(self.s.stuck_s * self.fs))
        self._drift_n = max(2, round(self.s.drift_window_s * self.fs))
        self._reset_level()
        self._last = np.full(n, np.nan)
        self._carry = np.zeros(n, np.int64)  # current run of identical samples, carried across blocks
        self._drift = [0, np.zeros(n), np.zeros(n)]  # samples, Σx, Σx² of the current drift window
        self._drift_ref: np.ndarray | None = None
        self._quiet = [0, np.zeros(n)]  # pre-input samples and Σ(x − mean)² per channel (via level judgements)
        #: the pre-input noise counts only from this stream sample on: a line canceller in front (HealthGuard) needs its
        #: ``n_spans`` to find hum, and a channel's pickup is hum (named as such), not a noisy sensor
        self.quiet_from = 0
        self._seen_input = False
        self._in_input = False
        self._hit: list | None = None  # [start index, stop index, n, Σ xxᵀ] of the response being judged
        self._pol: list | None = None  # the same for the first response after the pulse (polarity)
        self._sos: np.ndarray | None = None
        self._zi: np.ndarray | None = None
        self._loo_cache: dict[tuple[int, ...], tuple[np.ndarray, np.ndarray]] = {}  # good channels -> (shapes, U)
        if M is not None and K is not None:
            b = modal_basis(M, K, min(self.n_modes + 1, n))
            f = b.freqs_hz
            hi = float(np.sqrt(f[self.n_modes - 1] * f[self.n_modes])) if f.size > self.n_modes else 1.5 * float(f[-1])
            # the high-pass corner stays below the first mode: a structure whose modes lie under band_lo_hz (the
            # seed's 2-DOF system at 0.16 and 0.28 Hz) keeps its band instead of an inverted one
            lo = min(self.s.band_lo_hz, 0.5 * float(f[0]))
            self._sos = butter_sos(4, (lo, min(hi, 0.45 * self.fs)), "bandpass", self.fs)
            # a drift window holds at least 20 periods of the first mode (the default's rationale, above): a mean
            # over less than a period moves with the oscillation itself (the 2-DOF log's 0.16 Hz mode)
            self._drift_n = max(self._drift_n, round(20 * self.fs / float(f[0])))
            self._zi = np.zeros((self._sos.shape[0], 2, n))

    # --- public ---------------------------------------------------------------------------------
    @property
    def good(self) -> list[int]:
        """Indices of the channels not judged bad."""
        return [i for i, c in enumerate(self.channels) if c not in self.bad]

    def feed(self, block: np.ndarray, input_active: np.ndarray | None = None) -> list[Verdict]:
        """The block's new verdicts, in stream order. Every check is judged at a fixed sample of the stream
        (the end of a ``level_min_s`` span, of a drift window, of a hit's response span: ``Verdict.index``),
        whatever the block split, so a filter that switches there gives the same numbers live and in replay."""
        x = np.asarray(block, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != len(self.channels):
            raise ValueError(f"sensor health: blocks of (n, {len(self.channels)}) samples, got {x.shape}")
        out: list[Verdict] = []
        if x.shape[0] == 0:
            return out
        if not np.isfinite(x.sum()):  # one reduction; only a non-finite sum (or an overflow) is looked at closely
            finite = np.isfinite(x)
            if not finite.all():
                self._nonfinite += np.count_nonzero(~finite, axis=0)
                x = np.where(finite, x, 0.0)
        inp = None if input_active is None else np.asarray(input_active, bool)
        i = 0
        while i < x.shape[0]:  # level spans on the stream's lattice
            if self._level_acc[0] == 0 and x.shape[0] - i >= self._level_n:  # whole spans at once: same numbers
                k = (x.shape[0] - i) // self._level_n
                out += self._level_spans(x[i : i + k * self._level_n], inp, i)
                i += k * self._level_n
                continue
            take = min(x.shape[0] - i, self._level_n - self._level_acc[0])
            seg = x[i : i + take]
            self._level(seg)
            self._stuck(seg)
            self._clip(seg)
            if inp is not None and inp[i : i + take].any():
                self._seen_input = True
            i += take
            if self._level_acc[0] == self._level_n:
                self._at = self._index + i
                out += self._judge_level(inp is not None)
        out += self._drift_feed(x)
        if self._sos is not None and inp is not None:
            out += self._hit_feed(x, inp)
        self._index += x.shape[0]
        return sorted(out, key=lambda v: v.index)

    def restart_quiet(self, at: int) -> None:
        """The pre-input noise is measured again from stream sample ``at`` (what came before held removed lines)."""
        self._quiet = [0, np.zeros(len(self.channels))]
        self.quiet_from = int(at)

    def restart(self) -> None:
        """A gap in the stream: drop partial accumulations (verdicts stay)."""
        self._reset_level()
        self._carry[:] = 0
        self._last[:] = np.nan
        self._drift = [0, np.zeros(len(self.channels)), np.zeros(len(self.channels))]
        self._hit = self._pol = None
        if self._zi is not None:
            self._zi[:] = 0.0

    # --- checks ---------------------------------------------------------------------------------
    def _judge(self, k: int, fault: Fault, reason: str) -> list[Verdict]:
        name = self.channels[k]
        if name in self.bad:
            return []
        v = Verdict(name, fault, reason, round(self._at / self.fs, 4), self._at)
        self.bad[name] = v
        return [v]

    def _reset_level(self) -> None:
        n = len(self.channels)
        self._level_acc = [0, np.zeros(n), np.zeros(n)]
        self._run_max = np.zeros(n, np.int64)
        self._run_val = np.zeros(n)
        self._clips = np.zeros(n, np.int64)
        self._beyond = np.zeros(n, np.int64)
        self._nonfinite = np.zeros(n, np.int64)

    def _level_spans(self, x: np.ndarray, inp: np.ndarray | None, at: int) -> list[Verdict]:
        """``x`` (whole level spans, the first starting on the lattice at block offset ``at``): every span judged as
        :meth:`_judge_level` judges it, as whole-block array operations. Per span the scalar judgment costs ~50 µs of
        calls for 14 channels (a replay block holds ~30 spans); almost every span of a session finds nothing, so the
        spans are first screened together (:meth:`_screen`) and only those that could return a verdict, or that
        would add to the pre-input noise past ``quiet_min_s``, are judged one by one, with the same state the
        span-by-span loop had there. The screen is a superset of the scalar conditions: same verdicts, same numbers."""
        L = self._level_n
        k = x.shape[0] // L
        spans = x.reshape(k, L, x.shape[1])
        blk = _SpanStats(spans, self._range, self._last, self._carry, inp, at)
        std = np.sqrt(np.maximum(blk.s2 / L - (blk.s1 / L) ** 2, 0.0))
        out: list[Verdict] = []
        j = 0
        while j < k:
            f, quiet = self._screen(blk, std, j, inp is not None)
            if f > j:  # spans j .. f-1: nothing to say; their state as the loop would leave it
                self._seen_input |= bool(blk.inp[j:f].any())
                self._quiet = quiet
                self._nonfinite[:] = 0
                self._at = self._index + at + f * L
            if f == k:
                break
            self._carry = blk.carry[f].copy()  # the state at span f's start, then span f as the loop judged it
            self._last = x[f * L - 1].copy() if f else self._last
            self._level_acc = [L, blk.s1[f].copy(), blk.s2[f].copy()]
            if blk.repeats[f].any():
                self._stuck(spans[f])
            else:  # every sample differs from the one before: no run (the fast path of _stuck)
                self._carry[:] = 0
                self._last = spans[f, -1].copy()
            self._clips += blk.clips[f]
            self._beyond += blk.beyond[f]
            self._seen_input |= bool(blk.inp[f])
            self._at = self._index + at + (f + 1) * L
            out += self._judge_level(inp is not None)
            j = f + 1
        self._carry = blk.carry[k].copy()
        self._last = x[-1].copy()
        self._reset_level()
        return out

    def _screen(self, blk: _SpanStats, std: np.ndarray, j: int, hammer_known: bool) -> tuple[int, list]:
        """The first span from ``j`` on that :meth:`_judge_level` must judge (``k``: none), and the pre-input noise
        accumulators after the spans before it. A span is judged when, on a channel still good, it holds non-finite
        samples (the first), clips, a run of ``stuck_s``, a constant, a level below ``dead_rel`` of the median
        channel's (with a 1e-9 margin), or when the pre-input noise is judged there and a channel is near
        ``noisy_factor`` × the median. The noise sums add span by span, in order (as the loop adds them)."""
        L, k = self._level_n, std.shape[0]
        g = np.array(self.good, np.int64)
        quiet = [self._quiet[0], self._quiet[1].copy()]
        if g.size == 0:
            return k, quiet
        sg, lg = std[j:, g], std[j:, g] * self._volts[g]
        med = _row_median(lg)
        flag = ((blk.clips[j:, g] >= self.s.clip_samples) & (blk.beyond[j:, g] == 0)).any(axis=1)
        flag |= (blk.runs[j:, g] >= self._stuck_n).any(axis=1) | ((sg == 0) & (med[:, None] > 0)).any(axis=1)
        flag |= (lg < self.s.dead_rel * med[:, None] * (1 + 1e-9)).any(axis=1)
        if self._nonfinite[g].any():
            flag[0] = True
        if hammer_known:  # the pre-input noise: the spans before the first input, from quiet_from on
            ends = self._index + blk.at + (np.arange(j, k) + 1) * L
            seen = self._seen_input | np.logical_or.accumulate(blk.inp[j:])
            adds = ~seen & (ends - L >= self.quiet_from)
            n_q = quiet[0] + L * np.cumsum(adds)
            terms = np.where(adds[:, None], std[j:] ** 2 * L, 0.0)
            s_q = np.cumsum(np.vstack([quiet[1][None], terms]), axis=0)[1:]  # sequential, as += span by span
            judged = adds & (n_q >= self.s.quiet_min_s * self.fs)
            if judged.any():
                noise = np.sqrt(s_q[:, g] / np.maximum(n_q, 1)[:, None]) * self._volts[g]
                med_n = _row_median(noise)
                flag |= judged & (noise > self.s.noisy_factor * med_n[:, None] * (1 - 1e-9)).any(axis=1)
        f = j + int(np.argmax(flag)) if flag.any() else k
        if hammer_known and f > j:
            quiet = [int(n_q[f - j - 1]), s_q[f - j - 1].copy()]
        return f, quiet

    def _level(self, x: np.ndarray) -> None:
        a = self._level_acc
        a[0] += x.shape[0]
        s1, s2 = span_sums(x, x.shape[0])
        a[1] += s1[0]
        a[2] += s2[0]

    def _stuck(self, x: np.ndarray) -> None:
        """Longest run of identical consecutive samples per channel (counted in equal pairs), carried across blocks."""
        same = np.concatenate([self._last[None], x])
        same = same[1:] == same[:-1]
        n = x.shape[0]
        repeats = same.any(axis=0)
        self._carry[~repeats] = 0  # every sample differs from the one before (live noise): no run, the fast path
        for c in np.flatnonzero(repeats):
            br = np.flatnonzero(~same[:, c])  # samples that differ from the one before: a run starts there
            if br.size == 0:
                self._carry[c] += n
                run, val = int(self._carry[c]), x[0, c]
            else:
                starts = np.concatenate([br, [n]])
                lengths = np.diff(starts) - 1  # equal pairs after each start
                i = int(np.argmax(lengths))
                run, val = int(lengths[i]), x[br[i], c]
                if self._carry[c] + br[0] > run:
                    run, val = int(self._carry[c] + br[0]), x[0, c]
                self._carry[c] = lengths[-1]
            if run > self._run_max[c]:
                self._run_max[c], self._run_val[c] = run, val
        self._last = x[-1].copy()

    def _clip(self, x: np.ndarray) -> None:
        if np.isfinite(self._range).any():
            a = np.abs(x)
            self._clips += np.count_nonzero(a >= CLIP_FRACTION * self._range, axis=0)
            self._beyond += np.count_nonzero(a > OVER_RANGE * self._range, axis=0)

    def _judge_level(self, hammer_known: bool) -> list[Verdict]:
        n, s1, s2 = self._level_acc
        std = np.sqrt(np.maximum(s2 / n - (s1 / n) ** 2, 0.0))
        level = std * self._volts
        good = self.good
        out: list[Verdict] = []
        med = _median(level[good])
        # the median channel moves (is not itself stuck): only asked when some channel has a long run
        moving = bool(good) and (int(self._run_max.max()) < self._stuck_n or _median(self._run_max[good]) < self._stuck_n)
        for k in good:
            if self._nonfinite[k]:
                out += self._judge(k, "dead", f"{int(self._nonfinite[k])} non-finite samples")
            elif self._clips[k] >= self.s.clip_samples and self._beyond[k] == 0:
                out += self._judge(k, "clipping", f"{int(self._clips[k])} samples at its ±{self._range[k]:g} range")
            elif moving and self._run_max[k] >= self._stuck_n:
                v = float(self._run_val[k])
                ms = 1e3 * self._run_max[k] / self.fs
                out += (self._judge(k, "dead", f"flat at 0 for {ms:.0f} ms while the others move") if v == 0 else
                        self._judge(k, "stuck", f"constant at {v:.4g} for {ms:.0f} ms while the others move"))  # fmt: skip
            elif med > 0 and std[k] == 0 and s1[k] == 0:
                out += self._judge(k, "dead", "flat at 0 while the others move")
            elif med > 0 and std[k] == 0:  # one value, not zero, over a whole span: a frozen reading, not a dead input
                ms = 1e3 * n / self.fs
                out += self._judge(k, "stuck", f"constant at {s1[k] / n:.4g} for {ms:.0f} ms while the others move")
            elif med > 0 and level[k] < self.s.dead_rel * med:
                out += self._judge(k, "dead", f"level {level[k] / med:.1e} of the median channel's (below {self.s.dead_rel:g})")
        if hammer_known and not self._seen_input and self._at - n >= self.quiet_from:
            self._quiet[0] += n
            self._quiet[1] += std**2 * n
            if self._quiet[0] >= self.s.quiet_min_s * self.fs:
                noise = np.sqrt(self._quiet[1] / self._quiet[0]) * self._volts
                good = self.good
                med_n = float(np.median(noise[good])) if good else 0.0
                for k in good:
                    if med_n > 0 and noise[k] > self.s.noisy_factor * med_n:
                        out += self._judge(k, "noisy", f"pre-hit noise {noise[k] / med_n:.0f}x the median channel's")
        self._reset_level()
        return out

    def _drift_feed(self, x: np.ndarray) -> list[Verdict]:
        out: list[Verdict] = []
        i = 0
        while i < x.shape[0]:
            d = self._drift
            take = min(x.shape[0] - i, self._drift_n - d[0])
            seg = x[i : i + take]
            d[0] += take
            s1, s2 = span_sums(seg, take)
            d[1] += s1[0]
            d[2] += s2[0]
            i += take
            if d[0] < self._drift_n:
                break
            self._at = self._index + i
            mean = d[1] / d[0]
            std = np.sqrt(np.maximum(d[2] / d[0] - mean**2, 0.0))
            if self._drift_ref is None:
                self._drift_ref = mean
            else:
                for k in self.good:
                    if std[k] > 0 and abs(mean[k] - self._drift_ref[k]) > self.s.drift_factor * std[k]:
                        out += self._judge(k, "drifting", f"mean moved {abs(mean[k] - self._drift_ref[k]):.3g} "
                                                          f"({abs(mean[k] - self._drift_ref[k]) / std[k]:.0f}x its std) "
                                                          f"since the first {self._drift_n / self.fs:g} s")  # fmt: skip
            self._drift = [0, np.zeros(x.shape[1]), np.zeros(x.shape[1])]
        return out

    def _hit_feed(self, x: np.ndarray, inp: np.ndarray) -> list[Verdict]:
        """The band-passed response after each input, over two spans: the first ``polarity_span_s`` (polarity, judged
        at once) and ``hit_span_s`` after ``hit_settle_s`` (consistency with the model)."""
        out: list[Verdict] = []
        on = np.flatnonzero(inp)
        if on.size:
            self._seen_input = True
            last = self._index + int(on[-1]) + 1  # one past the input's last sample
            settle, pol = round(self.s.hit_settle_s * self.fs), round(self.s.polarity_settle_s * self.fs)
            zero = np.zeros((x.shape[1],) * 2)
            self._hit = [last + settle, last + settle + round(self.s.hit_span_s * self.fs), 0, zero.copy()]
            self._pol = [last + pol, last + pol + max(2, round(self.s.polarity_span_s * self.fs)), 0, zero.copy()]
        # the block's rows the spans read: the band-passed response is kept for those alone
        rows = [(max(sp[0] - self._index, 0), min(sp[1] - self._index, x.shape[0])) for sp in (self._pol, self._hit)
                if sp is not None]  # fmt: skip
        rows = [(a, b) for a, b in rows if b > a]
        lo, hi = (min(a for a, _ in rows), max(b for _, b in rows)) if rows else (0, 0)
        y = np.empty((hi - lo, x.shape[1]))
        _bandpass_rows(self._sos, x, self._zi, y, lo, hi)
        for span, judge in ((self._pol, self._judge_polarity), (self._hit, self._judge_hit)):
            if span is None:
                continue
            a, b = max(span[0] - self._index, 0), min(span[1] - self._index, x.shape[0])
            if b > a:
                seg = y[a - lo : b - lo]
                span[2] += b - a
                span[3] += seg.T @ seg
            if self._index + x.shape[0] >= span[1]:
                self._at = span[1]
                out += judge(span[3] / max(span[2], 1))
                if span is self._pol:
                    self._pol = None
                else:
                    self._hit = None
        return out

    def _loo(self, good: list[int]) -> tuple[np.ndarray, np.ndarray]:
        """The modal shapes of the model condensed to the channels ``good`` and their leave-one-out weights
        (:func:`_loo_weights`): both depend on the set of good channels alone, and every hit judges polarity and
        consistency with them, so they are computed once per set (a Guyan condensation, an ``eigh`` and n stacked
        pseudo-inverses, ~1.5 ms, were two per hit)."""
        key = tuple(good)
        if key not in self._loo_cache:
            shapes = reduced_basis(self.M, self.K, good, self.n_modes).shapes
            self._loo_cache[key] = (shapes, _loo_weights(shapes))
        return self._loo_cache[key]

    def _judge_polarity(self, S: np.ndarray) -> list[Verdict]:
        """A sensor wired or mounted the wrong way round reads the negative of what its neighbours predict for it."""
        assert self.M is not None and self.K is not None
        out: list[Verdict] = []
        for _ in range(self.s.max_excluded_per_hit):
            good = self.good
            if len(good) < self.n_modes + 3:
                break
            corr = loo_correlations(S[np.ix_(good, good)], *self._loo(good))
            w = int(np.argmin(corr))
            if not (corr[w] < self.s.polarity_corr and _median(corr) > -self.s.polarity_corr):
                break
            why = f"correlation {corr[w]:+.2f} with what its neighbours predict in the hit's first response"
            out += self._judge(good[w], "polarity", f"{why} (sign reversed: cable, mounting or channel setup)")
        return out

    def _judge_hit(self, S: np.ndarray) -> list[Verdict]:
        assert self.M is not None and self.K is not None
        out: list[Verdict] = []
        for _ in range(self.s.max_excluded_per_hit):
            good = self.good
            if len(good) < self.n_modes + 3:
                break
            Sg = S[np.ix_(good, good)]
            rel, pred_over = loo_residuals(Sg, *self._loo(good))
            w = int(np.argmax(rel))
            med = float(np.median(rel))
            if not (rel[w] > self.s.inconsistent and rel[w] > self.s.inconsistent_over_median * med):
                break
            k = good[w]
            if pred_over[w] > 1.0 / self.s.dead_rel:
                out += self._judge(k, "dead", f"no response to the hit (the neighbours predict {pred_over[w]:.0f}x its level)")
            else:
                why = f"{rel[w]:.2f} of its level ({rel[w] / max(med, 1e-12):.0f}x the median channel's)"
                out += self._judge(k, "inconsistent", f"hit response off the model's expectation from its neighbours by {why}")
        return out


#: the line canceller a guard runs unless told otherwise (``lines=None``: off, the guard before issue 29)
DEFAULT_LINES = LineSettings()


@dataclass(frozen=True)
class Switch:
    """The modal filter changes ``offset`` samples into a block: new basis (None: kept) on the channels ``keep``."""

    offset: int
    warnings: list[tuple[str, str, str]]  # (kind, key, message)
    basis: ModalBasis | None
    keep: list[int]
    #: stationary lines were newly found and are removed from here on: the samples before held them, so a noise floor
    #: measured on them is the lines' (the exchange detector measures it again)
    lines: bool = False


class HealthGuard:
    """Sensor health in front of a modal filter: the channels judged bad leave it, and the basis is rebuilt on the
    rest (Guyan at their DOFs, :func:`guyan_condense`). One object for a session's operator and the evaluation's
    detectors, so that the grid measures what a session does.

    ``feed`` each block *before* the modal filter sees it; it returns the :class:`Switch` es inside the block: the
    filter runs the samples before each switch on the old basis and the rest on the new one (a dead channel
    leaves at the end of the stream's first ``level_min_s`` span). Switching at stream samples, not at block
    edges, keeps live and replay identical. ``keep`` are the channels the filter uses (indices into ``channels``).
    ``nonlinear``: the channels on the nonlinear elements' DOFs, whose loss makes detection blind there (L69).
    """

    def __init__(
        self, M: np.ndarray, K: np.ndarray, channels: Sequence[str], sample_rate: float, n_modes: int,
        settings: HealthSettings | None = None, ranges: Sequence[float | None] | None = None,
        sensitivities: Sequence[float] | None = None, nonlinear: Sequence[str] = (),
        lines: LineSettings | None = DEFAULT_LINES,
    ) -> None:  # fmt: skip
        self.M, self.K, self.n_modes = M, K, int(n_modes)
        self.channels = tuple(channels)
        self.health = SensorHealth(channels, sample_rate, M, K, self.n_modes, ranges, sensitivities, settings)
        #: stationary lines (mains hum) found and removed before every check and the modal filter (analysis/lines.py)
        self.lines = None if lines is None else LineCanceller(len(self.channels), sample_rate, lines)
        if lines is not None:  # noise is judged once the canceller could have found the lines
            self.health.quiet_from = lines.n_spans * self.lines.L
        self.hum: dict[str, list[float]] = {}  # channel -> the line frequencies found on it (Hz)
        self.nonlinear = tuple(nonlinear)
        self.keep = list(range(len(self.channels)))
        self.basis = modal_basis(M, K, min(self.n_modes, len(self.channels)))
        self.verdicts: list[Verdict] = []

    def feed_clean(self, block: np.ndarray, input_active: np.ndarray | None = None) -> tuple[np.ndarray, list[Switch]]:
        """One block: its samples with the stationary lines removed (what the modal filter and the seed lane should
        read), and the switches of :meth:`feed` on them, with a ``hum`` warning where lines were newly found."""
        return self.check(self.clean(block), input_active)

    def clean(self, block: np.ndarray) -> np.ndarray:
        """:meth:`feed_clean`'s first half: the block with the stationary lines removed. A caller that hands the cleaned
        block on (the seed lane's worker process) can do so before :meth:`check` judges it."""
        return block if self.lines is None else self.lines.feed(block)

    def check(self, x: np.ndarray, input_active: np.ndarray | None = None) -> tuple[np.ndarray, list[Switch]]:
        """:meth:`feed_clean`'s second half, on the block :meth:`clean` returned."""
        start = self.health._index
        switches = self.feed(x, input_active)
        if self.lines is not None and self.lines.found:
            hum = self._hum_switch(self.lines.found, start, x.shape[0])
            self.lines.found = []
            switches = sorted([*switches, hum], key=lambda sw: sw.offset)
        return x, switches

    def _hum_switch(self, found: list[LineFound], start: int, n: int) -> Switch:
        """One ``hum`` warning naming the channels and the frequencies newly found in this block (a line found later on a
        channel already named is removed without a new warning)."""
        by: dict[str, list[LineFound]] = {}
        for f in found:
            name = self.channels[f.channel]
            if name not in self.hum or name in by:
                by.setdefault(name, []).append(f)
        for f in found:
            self.hum.setdefault(self.channels[f.channel], []).append(f.freq_hz)
        at = max(f.index for f in found)
        self.health.restart_quiet(at)
        if not by:
            return Switch(min(max(at - start, 0), n), [], None, list(self.keep), True)
        parts = []
        for name, fs in by.items():
            fs = sorted(fs, key=lambda f: f.freq_hz)
            parts.append(f"{name} " + "/".join(f"{f.freq_hz:.1f}" for f in fs) + f" Hz ({max(f.amplitude for f in fs):.2g} peak)")
        msg = (f"hum: stationary lines on {len(by)} sensor(s) at {at / self.health.fs:.3f} s: {'; '.join(parts)}; removed "
               "before the modal filter (mains pickup: check the sensor cables' shields and grounding)")  # fmt: skip
        return Switch(min(max(at - start, 0), n), [("hum", "hum:" + ",".join(by), msg)], None, list(self.keep), True)

    def feed(self, block: np.ndarray, input_active: np.ndarray | None = None) -> list[Switch]:
        """One block: where in it (sample offset) the modal filter changes, with the warnings to raise there."""
        start = self.health._index
        out: list[Switch] = []
        for v in self.health.feed(block, input_active):
            self.verdicts.append(v)
            good = [i for i in self.keep if self.channels[i] != v.channel]
            rebuilt = len(good) >= self.n_modes + 1
            tail = (f"excluded from the modal filter (rebuilt on {len(good)} sensors)" if rebuilt else
                    f"NOT excluded: {len(good)} healthy sensors cannot carry {self.n_modes} modes")  # fmt: skip
            warns = [("sensor", f"sensor:{v.channel}", f"{v.line()} at {v.t_s:.3f} s; {tail}")]
            if v.channel in self.nonlinear:
                what = "has its polarity reversed" if v.fault == "polarity" else f"is {v.fault}"
                why = f"its sensor {v.channel} {what} (the seed's assumption 11, L69)"
                warns.append(("blind", f"blind:{v.channel}", f"detection is blind at the nonlinear element: {why}"))
            basis = None
            if rebuilt:
                pos = {c: i for i, c in enumerate(self.keep)}
                like = self.basis.shapes[[pos[c] for c in good]]
                self.basis = basis = reduced_basis(self.M, self.K, good, self.n_modes, like)
                self.keep = good
            out.append(Switch(min(max(v.index - start, 0), block.shape[0]), warns, basis, list(self.keep)))
        return out

    def pieces(self, n: int, switches: list[Switch]) -> list[tuple[int, int, Switch | None]]:
        """The block's sample ranges ``[a, b)`` and the switch to apply after each (None after the last)."""
        out, a = [], 0
        for sw in switches:
            out.append((a, sw.offset, sw))
            a = sw.offset
        out.append((a, n, None))
        return out

    def restart(self) -> None:
        self.health.restart()
        if self.lines is not None:
            self.lines.restart()
