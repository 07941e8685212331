"""POD → Rayleigh quotient → RQ frequency–energy plot (RQ-FEP) kernels for the seed's computational sweep.

Pure numpy: no I/O, no simulator. ``gvt sweep`` (``daq/studies/sweep.py``) feeds them the per-run output
covariances of :func:`analysis.model.sweep.sweep_moments`.

* POD of a whole record per run (seed §4.2, L1251) is the eigendecomposition of the 1/n covariance of the
  mean-removed displacements (eq. 2.12, L234): its eigenvectors are the left singular vectors of the
  centred data matrix (eq. 2.13, L247–L251), its eigenvalues the POVs ``s_i² / N_t``.
* Each POM is used on its own as a Rayleigh-quotient trial vector with the Guyan-reduced ``K`` and ``M``
  (eqs. 2.17–2.18, L286–L294), and the POMs are re-sorted by that frequency, ascending (L1251).
* Interactions are "non-smooth perturbations (spikes)" of the RQ curves against energy (L1253) that have a
  partner on another curve (L1393); the m:n label comes from the ratio of the NNM2 and NNM1 frequencies
  just outside the spike (L1298, L1313). The seed gives no numeric thresholds (method-detection.md
  §1.10), so they are the named fields of :class:`SpikeSettings`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from analysis.model.beam import FloatArray
from analysis.pod import rq_hz
from analysis.runs import true_runs

# Ratios f2/f1 the labeller chooses from (the seed reports 4:1 and 3:1 in the computation, 5:2 in the
# experiment, L1255, L1389; the analyst "knows the likely IR ratios", L67).
DEFAULT_RATIOS: tuple[tuple[int, int], ...] = ((2, 1), (5, 2), (3, 1), (7, 2), (4, 1), (9, 2), (5, 1))


def pod_from_covariance(cov: FloatArray) -> tuple[FloatArray, FloatArray]:
    """POMs and POVs from 1/n covariance matrices, largest POV first.

    ``cov`` is (runs, n, n) or (n, n). Returns ``poms`` (runs, n, n) whose *columns* are the POMs and
    ``povs`` (runs, n), both ordered by POV descending as an SVD would (eq. 2.13). Rounding can make the
    smallest eigenvalues slightly negative; they are clipped to 0 (a covariance is positive semidefinite).
    """
    c = np.asarray(cov, dtype=float)
    if c.ndim == 2:
        c = c[None]
    if c.ndim != 3 or c.shape[1] != c.shape[2]:
        raise ValueError(f"covariance must be (runs, n, n) or (n, n), got shape {np.shape(cov)}")
    lam, vec = np.linalg.eigh(0.5 * (c + np.swapaxes(c, 1, 2)))
    return vec[:, :, ::-1], np.maximum(lam[:, ::-1], 0.0)


def rq_fep(poms: FloatArray, M: FloatArray, K: FloatArray, n_keep: int = 4) -> FloatArray:
    """RQ frequencies (Hz) of every POM, sorted ascending, the lowest ``n_keep`` per run: (runs, n_keep).

    ``f = sqrt(ψᵀKψ / ψᵀMψ) / 2π`` (eqs. 2.17–2.18) with the Guyan-reduced matrices at the output DOFs;
    the POMs are orthonormal but not mass-orthogonal, so each is used independently (L290). All POMs are
    candidates, and "POM j" is the j-th lowest frequency (L1251: "re-sort the POMs based on estimated
    frequency"), which is the seed's Chapter 4 ordering.
    """
    p = np.asarray(poms, dtype=float)
    if p.ndim == 2:
        p = p[None]
    n = p.shape[1]
    if M.shape != (n, n) or K.shape != (n, n):
        raise ValueError(f"M and K must be {n}x{n} (the POM length), got {M.shape} and {K.shape}")
    if not 1 <= n_keep <= p.shape[2]:
        raise ValueError(f"n_keep must lie in [1, {p.shape[2]}]")
    return np.sort(rq_hz(p, M, K), axis=1)[:, :n_keep]


def pov_gaps(povs: FloatArray, poms: FloatArray, M: FloatArray, K: FloatArray, n_keep: int = 4) -> FloatArray:
    """The POV separation of the POM behind each of :func:`rq_fep`'s RQs: ``min_j |λ_i − λ_j| / λ_i`` over the run's
    other POVs, (runs, n_keep), in :func:`rq_fep`'s order. Why: a POM is an eigenvector of the covariance, and an
    eigenvector whose eigenvalue nearly equals another's is fixed only up to a mix of the two (its perturbation scales
    as the covariance's perturbation over the gap); on a high-energy record a mix of a few per cent moves an RQ by tens
    of per cent (docs/sweep.md). A gap of a few per cent says the RQ is one such draw, not a property of the mode."""
    p = np.asarray(poms, dtype=float)
    lam = np.atleast_2d(np.asarray(povs, dtype=float))
    p = p[None] if p.ndim == 2 else p
    order = np.argsort(rq_hz(p, M, K), axis=1, kind="stable")[:, :n_keep]
    diff = np.abs(lam[:, :, None] - lam[:, None, :])
    diff[:, np.arange(lam.shape[1]), np.arange(lam.shape[1])] = np.inf
    gap = diff.min(axis=2) / np.maximum(lam, 1e-300)
    return np.take_along_axis(gap, order, axis=1)


@dataclass(frozen=True)
class SpikeSettings:
    """Thresholds of the spike/partner detector (the seed gives none: method-detection.md §1.10).

    * ``window``: points in the running median that is each curve's smooth baseline (odd). It must be
      more than twice the widest spike, or a spike "spread out over several points" (L1255) becomes its
      own baseline.
    * ``k_mad``: a point deviates when its relative residual exceeds ``k_mad`` robust standard deviations
      (1.4826·MAD of the curve's relative residuals over the ``scale_window`` points around it; local,
      because the sweep's strongly nonlinear band is noisy where the linear ends are smooth to 1e-5) …
    * ``min_rel``: … and at least this fraction of the baseline, per curve (NNM1, NNM2). NNM2's floor is
      ten times lower: on a spike the NNM1 POM turns into a deformed NNM2 shape and its RQ jumps by tens
      of percent, while the NNM2 POM stays NNM2-like and its RQ dips by tenths of a percent (measured on
      ``beam_ch4_sim``, docs/sweep.md) — the partner is small but, against its local noise, clear.
    * ``partner_gap``: the NNM1 and NNM2 deviations must fall within this many points of each other —
      the seed's partner criterion (L1393): a spike on one curve alone is not an interaction.
    * ``converging``: additionally require the partners to move the two curves *toward* each other
      (NNM1 up, NNM2 down), the signature of "similar POMs" on a spike (L1259): both POMs become the
      deformed NNM2 shape, so their RQs approach each other. With it, an interaction must also close at
      least ``min_closure`` of the baseline gap f2 − f1 at its strongest point.
    * ``n_side``: off-spike points on each side whose median f2/f1 gives the ratios outside the spike.
    * ``ratios``: the m:n labels to choose from (L67: the analyst knows the likely IR ratios).

    Band detector (``band``; :func:`band_windows`). The seed's 4:1 spike is "spread out over several points"
    (L1255); on ``beam_ch4_sim`` the corresponding disturbance (P ≈ 480–610 N, docs/sweep.md) is NNM1's RQ
    alternating by ±2–5 % from point to point with NNM2 moving the opposite way by 0.1–0.3 % — no point
    stands out from its neighbours, so the per-point rule above misses it. A band is a run of points whose
    NNM1 and NNM2 residuals (against the running medians of :func:`deviations`) are strongly
    *anti*-correlated, i.e. the two RQs move toward (and away from) each other together, the "similar POMs"
    signature of L1259, at an NNM1 amplitude far above its quiet level. Measured values quoted below are
    from the 1000-run sweep of docs/sweep.md; the thresholds were set between the 4:1 band and everything
    else in that sweep, not tuned to a wanted label.

    * ``band_window``: points in each sliding window (odd). 9: the measured disturbance spans ~10 points;
      the window must be shorter than the running median's ``window`` (15), or the band shifts its own
      baseline.
    * ``band_corr``: a window qualifies when the Pearson correlation of the NNM1 and NNM2 relative residuals
      is ≤ −``band_corr``. 0.7: for 9 independent points P(r ≤ −0.7) ≈ 2 % (t = −2.6, 7 dof), and
      ``band_min_run`` consecutive windows make chance far rarer; the 4:1 band measures −0.80 … −0.88.
    * ``band_min_rel``: RMS of the relative residual over the window at least this, per curve (NNM1,
      NNM2). NNM1 0.01: half the per-point spike floor ``min_rel[0]`` (an alternation with ±1.4 % peaks
      has a 1 % RMS). NNM2 1e-4: a correlation with residuals at the rounding level means nothing, and
      below 1e4 N the RQs reproduce to ≤ 1e-6 (docs/sweep.md, sensitivity caveat), so 100× that. Measured
      in the 4:1 band: 2.4–2.8 % and 0.16–0.18 % (1000-run sweep), 1.0–2.2 % and 0.06–0.13 % on a
      3.6× finer P spacing, where the 15-point running median follows more of the disturbance; a 0.1 %
      NNM2 floor missed the band there.
    * ``band_k`` / ``band_quiet_window``: NNM1's window RMS must also be ≥ ``band_k`` × its quiet level,
      1.4826·MAD of NNM1's relative residuals over ``band_quiet_window`` points (wider than ``scale_window``
      so that a ~10-point band is < 10 % of it and does not raise its own scale). 5 and 101: the 4:1
      band's windows measure 20–33× (quiet level ≤ 0.12 %); the strongly nonlinear stretch from 0.7 J up,
      where the residuals are anti-correlated almost everywhere (POM mixing), measures ≤ 4.3× (quiet level
      2–11 %) in every window not dominated by one point (``band_max_share``), so it is the baseline there,
      as the spike detector's local scale makes the sensitive band's scatter its baseline.
    * ``band_max_share``: no single point may carry more than this fraction of the window's NNM1 residual
      power. 0.5: a window containing one spike is correlated at ≈ −1 by that point alone (measured share
      0.7–1.0 next to the 1236 N and 2159 N spikes); that is the spike detector's business. The 4:1
      band's windows measure 0.32–0.42.
    * ``band_min_run``: at least this many consecutive qualifying window centres. 3: one or two windows
      is what a single large residual pair sliding through the window produces.

    With ``converging`` a band must also contain one point where NNM1 is up by ≥ ``band_min_rel[0]`` and
    NNM2 is down (the two RQs approach, L1259); an anti-correlated run that only ever diverges is dropped.

    Modal labels and locks (:func:`find_locks`). The RQ uses the linear K, which has no term for the tip
    spring, so the RQ ratio f2/f1 is not the NNMs' frequency ratio (docs/sweep.md, "Which m:n is the
    band?"); the sweep therefore also measures each run's mean frequencies of the two lowest linear modes
    from their modal phase advance (``analysis.model.sweep.ModalProbe``), and labels every flag by that
    *modal* ratio too (``modal_ratio`` of :class:`SweepInteraction`, the same :func:`nearest_ratio` rule on
    the modal ratio at the points just below and above the flag). An internal resonance is a frequency
    *lock*: the seed's m:n IR holds the slow phase m·θ1 − n·θ2 non-time-like (L1296–L1298), i.e. the ratio
    f2/f1 stays at m/n while the energy changes — a plateau of the modal ratio against energy.

    * ``lock``: run the lock detector.
    * ``lock_tol``: a point is on an m:n plateau when |ratio − m/n| ≤ ``lock_tol``·m/n. 0.03: the brief's
      value; the measured 3:1 plateau is 2.99–3.03 (±1 %), so 3 % holds it with margin for the record-mean's
      wobble. It is not a discriminator on its own: a ratio falling steadily at ~1 % per sweep point (the
      sweep's spacing, P × 1.026) stays within ±3 % of any m/n for ~6 points, hence ``lock_flatness``.
    * ``lock_min_points``: at least this many consecutive points (by energy) inside the tolerance. 3: the
      fewest for which a slope inside the run means anything.
    * ``lock_context`` / ``lock_flatness``: the ratio's slope against log10(energy) inside the run (least
      squares over the run) must be ≤ ``lock_flatness`` × the slope on *each* side, measured by least squares
      over the run's edge point and the ``lock_context`` points beyond it (so the entry and exit are in the
      side slopes: a plateau entered or left by a jump has steep sides). 0.5 and 5: a ratio passing m:n at a
      steady slope has the same slope inside and out (ratio ≈ 1); a plateau has ≪ 1. Measured on the 1000-run
      sweep (docs/sweep.md, "Locks"): the 3:1 plateau 0.25; the runs within ±3 % of 5:1, 9:2, 4:1 and 5:2 are
      1.23, 1.71, 0.78 and 1.35 (passages; 4:1's is slowed, not flat). Not tuned to find 4:1: it needs 1.0 here,
      or ``lock_tol`` 0.01.
    * ``lock_ratios``: the candidates (default: the labeller's ``ratios``).
    """

    window: int = 15
    k_mad: float = 4.0
    scale_window: int = 41
    min_rel: tuple[float, float] = (0.02, 0.002)
    partner_gap: int = 1
    converging: bool = True
    min_closure: float = 0.05
    n_side: int = 2
    guard: int = 1
    merge_gap: int = 1
    ratios: tuple[tuple[int, int], ...] = DEFAULT_RATIOS
    band: bool = True
    band_window: int = 9
    band_corr: float = 0.7
    band_min_rel: tuple[float, float] = (0.01, 1e-4)
    band_k: float = 5.0
    band_quiet_window: int = 101
    band_max_share: float = 0.5
    band_min_run: int = 3
    lock: bool = True
    lock_tol: float = 0.03
    lock_min_points: int = 3
    lock_context: int = 5
    lock_flatness: float = 0.5
    lock_ratios: tuple[tuple[int, int], ...] = DEFAULT_RATIOS


@dataclass(frozen=True)
class SweepInteraction:
    """One flagged NNM1–NNM2 interaction: a run of partnered spikes in the RQ-FEP.

    ``ratio`` is the m:n label (f2/f1 ≈ m/n); ``ratio_left``/``ratio_right`` are the measured f2/f1 just
    below and above the spike in energy, ``bracketed`` says whether the label lies between them (the
    ratio passed through m:n across the spike, as the seed reads Fig. 4.5, L1298, L1313). ``score`` is
    the largest fraction of the baseline gap f2 − f1 that the spike closes (1 = the two RQs meet).
    ``kind`` is ``"spike"`` (partnered per-point deviations) or ``"band"`` (a run of anti-correlated
    NNM1/NNM2 residuals, :func:`band_windows`); for a band ``score`` is measured the same way but is small
    (the 4:1 band closes ~1–2 % of the gap: many small moves, not one large one).
    """

    i_lo: int
    i_hi: int
    i_peak: int
    p_lo: float
    p_hi: float
    energy_lo: float
    energy_hi: float
    f1_hz: float
    f2_hz: float
    ratio: tuple[int, int]
    ratio_left: float
    ratio_right: float
    bracketed: bool
    n_points: int
    score: float
    kind: str = "spike"
    modal_ratio: tuple[int, int] | None = None
    modal_ratio_left: float = float("nan")
    modal_ratio_right: float = float("nan")
    modal_ratio_peak: float = float("nan")
    modal_bracketed: bool = False

    @property
    def rq_label(self) -> str:
        """The label from the RQ ratio f2/f1 (``ratio``), kept for comparison."""
        return f"{self.ratio[0]}:{self.ratio[1]}"

    @property
    def modal_label(self) -> str | None:
        return None if self.modal_ratio is None else f"{self.modal_ratio[0]}:{self.modal_ratio[1]}"

    @property
    def label(self) -> str:
        """The flag's m:n: from the modal ratio when the sweep measured it, else from the RQ ratio."""
        return self.modal_label or self.rq_label

    def to_dict(self) -> dict:
        """JSON fields: ``ratio`` is :attr:`label` (modal when measured), ``rq_ratio`` the RQ label,
        ``modal_ratio`` the modal one (or None); ``ratio_left``/``ratio_right`` stay the RQ ratios."""
        d = asdict(self)
        d["ratio"] = self.label
        d["rq_ratio"] = self.rq_label
        d["modal_ratio"] = self.modal_label
        d["label_source"] = "rq" if self.modal_ratio is None else "modal"
        return d


@dataclass(frozen=True)
class RatioLock:
    """A plateau of the modal ratio f2/f1 at one m:n over consecutive sweep points (:func:`find_locks`).

    Indices refer to the input order; ``slope_in`` / ``slope_below`` / ``slope_above`` are |d ratio / d log10 E|
    inside the run and on its low- and high-energy sides (least squares).
    """

    i_lo: int
    i_hi: int
    p_lo: float
    p_hi: float
    energy_lo: float
    energy_hi: float
    ratio: tuple[int, int]
    ratio_mean: float
    ratio_min: float
    ratio_max: float
    n_points: int
    slope_in: float
    slope_below: float
    slope_above: float
    kind: str = "lock"

    @property
    def label(self) -> str:
        return f"{self.ratio[0]}:{self.ratio[1]}"

    def to_dict(self) -> dict:
        d = asdict(self)
        d["ratio"] = self.label
        return d


def running_median(y: FloatArray, window: int) -> FloatArray:
    """Centred running median, the window shrinking (still centred) at the ends."""
    if window < 1 or window % 2 == 0:
        raise ValueError("window must be a positive odd number")
    y = np.asarray(y, dtype=float)
    h = window // 2
    out = np.empty_like(y)
    n = y.size
    for i in range(n):
        r = min(h, i, n - 1 - i)
        out[i] = np.median(y[i - r : i + r + 1])
    return out


def rolling_mad_sigma(r: FloatArray, window: int) -> FloatArray:
    """1.4826·MAD of ``r`` in a centred window (the whole curve when ``window`` <= 0 or >= len(r))."""
    n = r.size
    if window <= 0 or window >= n:
        return np.full(n, 1.4826 * np.median(np.abs(r - np.median(r))))
    h = window // 2
    out = np.empty(n)
    for i in range(n):
        lo = min(max(0, i - h), n - window)
        seg = r[lo : lo + window]
        out[i] = 1.4826 * np.median(np.abs(seg - np.median(seg)))
    return out


def deviations(f: FloatArray, settings: SpikeSettings, curve: int) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(baseline, relative residual, flagged-mask) of one RQ curve ordered by energy."""
    base = running_median(f, settings.window)
    rel = (f - base) / base
    thresh = np.maximum(settings.k_mad * rolling_mad_sigma(rel, settings.scale_window), settings.min_rel[curve])
    return base, rel, np.abs(rel) > thresh


def nearest_ratio(
    left: float, right: float, ratios: tuple[tuple[int, int], ...] = DEFAULT_RATIOS
) -> tuple[tuple[int, int], bool]:
    """The m:n label for a spike whose off-spike f2/f1 are ``left`` and ``right``.

    A candidate between the two (the ratio swept through it across the spike, L1298, L1313) wins, an
    m:1 one before an m:n one ("start with m:1 before m:n", L1296), then the one nearest the geometric
    mean of ``left`` and ``right``. When nothing lies between, the candidate nearest the geometric mean.
    Returns (m, n) and whether it was bracketed.
    """
    mid = float(np.sqrt(left * right))
    lo, hi = min(left, right), max(left, right)
    inside = [r for r in ratios if lo <= r[0] / r[1] <= hi]
    pool = [r for r in inside if r[1] == 1] or inside or list(ratios)
    best = min(pool, key=lambda r: abs(np.log(r[0] / r[1] / mid)))
    return best, bool(inside)


def band_windows(r1: FloatArray, r2: FloatArray, settings: SpikeSettings) -> FloatArray:
    """Per point (centre of a ``band_window``-point window): does the window qualify as part of a band?

    ``r1``, ``r2`` are the NNM1 and NNM2 relative residuals, ordered by energy. A window qualifies when the
    two are anti-correlated (≤ −``band_corr``), both RMS residuals reach ``band_min_rel``, NNM1's RMS is
    ≥ ``band_k`` times its quiet level and no single point carries more than ``band_max_share`` of NNM1's
    residual power (see :class:`SpikeSettings`). Windows that do not fit inside the curve do not qualify.
    Returns a boolean mask over window centres.
    """
    w = settings.band_window
    if w < 3 or w % 2 == 0:
        raise ValueError("band_window must be an odd number >= 3")
    n = r1.size
    h = w // 2
    quiet = rolling_mad_sigma(r1, settings.band_quiet_window)
    ok = np.zeros(n, dtype=bool)
    for i in range(h, n - h):
        a, b = r1[i - h : i + h + 1], r2[i - h : i + h + 1]
        rms1, rms2 = float(np.sqrt(np.mean(a**2))), float(np.sqrt(np.mean(b**2)))
        if rms1 < settings.band_min_rel[0] or rms2 < settings.band_min_rel[1] or rms1 < settings.band_k * quiet[i]:
            continue
        if float(np.max(a**2)) > settings.band_max_share * float(np.sum(a**2)):
            continue
        da, db = a - a.mean(), b - b.mean()
        den = float(np.sqrt(np.sum(da**2) * np.sum(db**2)))
        if den > 0 and float(np.sum(da * db)) / den <= -settings.band_corr:
            ok[i] = True
    return ok


def flag_interactions(
    energy: FloatArray,
    freqs: FloatArray,
    settings: SpikeSettings = SpikeSettings(),
    amplitudes: FloatArray | None = None,
    modal_ratio: FloatArray | None = None,
) -> list[SweepInteraction]:
    """Partnered spikes and anti-correlated bands of the NNM1 and NNM2 RQ curves against energy (seed
    §4.2.2, L1253–L1259).

    ``energy`` (runs,) and ``freqs`` (runs, ≥ 2; columns 0 and 1 are NNM1 and NNM2) are re-ordered by
    energy (the RQ-FEP's axis, L1251). A point is a spike candidate when NNM1 deviates from its
    running-median baseline and NNM2 does too within ``partner_gap`` points (converging, by default);
    adjacent candidates merge into one interaction (the seed's first spike spans several points, L1255).
    A band (``settings.band``) is a run of ≥ ``band_min_run`` qualifying windows (:func:`band_windows`):
    its points are the union of those windows trimmed to the outermost points whose NNM1 residual reaches
    ``band_min_rel[0]``; a band that overlaps a spike interaction is dropped (the spike already reports
    it). Both kinds are labelled the same way, from f2/f1 at the nearest points outside any spike or band.
    ``amplitudes`` (the sweep's P, same order as ``energy``) only labels the result. ``modal_ratio`` (runs,),
    the per-run modal f2/f1 (``analysis.model.sweep``), gives each flag a second label, ``modal_ratio``:
    :func:`nearest_ratio` of the modal ratio at the nearest measured points just below and just above the
    flag (no guard: POD mixing on a spike disturbs the RQs, not the modal phases). Indices in the
    result (``i_lo``, ``i_hi``, ``i_peak``: the point that closes the gap most) refer to the input order.
    The result is ordered by energy.
    """
    sweep = _EnergyOrder.of(energy, freqs, amplitudes, modal_ratio, settings.window)
    if sweep is None:
        return []
    dev = _Deviations.of(sweep.f, settings)
    spikes = _spike_events(dev, settings)
    bands = _band_events(dev, settings, spikes) if settings.band and sweep.n >= settings.band_window else []
    in_band = np.zeros(sweep.n, dtype=bool)
    for lo, hi, _ in bands:
        in_band[lo : hi + 1] = True
    off = ~(dev.m1 | dev.m2 | in_band)
    flags = (_interaction(sweep, dev, off, lo, hi, kind, settings) for lo, hi, kind in sorted(spikes + bands))
    return [fl for fl in flags if fl is not None]


@dataclass(frozen=True)
class _EnergyOrder:
    """The sweep's runs sorted by energy, the RQ-FEP's axis (L1251): energy ``e``, frequencies ``f``, amplitudes
    ``p`` (NaN when not given) and modal ratios ``mr``, with ``order`` mapping each back to its input index."""

    order: np.ndarray
    e: FloatArray
    f: FloatArray
    p: FloatArray
    mr: FloatArray | None

    @property
    def n(self) -> int:
        return self.e.size

    @classmethod
    def of(cls, energy: FloatArray, freqs: FloatArray, amplitudes: FloatArray | None, modal_ratio: FloatArray | None,
           window: int) -> _EnergyOrder | None:  # fmt: skip
        """Checked and sorted; None when the sweep has fewer runs than the running median's ``window``."""
        e = np.asarray(energy, dtype=float)
        f = np.asarray(freqs, dtype=float)
        if e.ndim != 1 or f.ndim != 2 or f.shape[0] != e.size or f.shape[1] < 2:
            raise ValueError("energy must be (runs,) and freqs (runs, >= 2)")
        n = e.size
        p = np.full(n, np.nan) if amplitudes is None else np.asarray(amplitudes, dtype=float)
        if n < window:
            return None
        order = np.argsort(e, kind="stable")
        mr = None if modal_ratio is None else np.asarray(modal_ratio, dtype=float)
        if mr is not None:
            if mr.shape != (n,):
                raise ValueError("modal_ratio must be (runs,), like energy")
            mr = mr[order]
        return cls(order, e[order], f[order], p[order], mr)


@dataclass(frozen=True)
class _Deviations:
    """NNM1's and NNM2's running-median baselines ``b``, relative residuals ``r`` and deviating points ``m``
    (:func:`deviations`), with the frequencies ``f`` they were taken from."""

    f: FloatArray
    b1: FloatArray
    r1: FloatArray
    m1: np.ndarray
    b2: FloatArray
    r2: FloatArray
    m2: np.ndarray

    @classmethod
    def of(cls, f: FloatArray, settings: SpikeSettings) -> _Deviations:
        b1, r1, m1 = deviations(f[:, 0], settings, 0)
        b2, r2, m2 = deviations(f[:, 1], settings, 1)
        return cls(f, b1, r1, m1, b2, r2, m2)

    def closure(self, lo: int, hi: int) -> FloatArray:
        """Fraction of the baseline gap f2 − f1 closed at each point of [lo, hi]."""
        f, b1, b2 = self.f, self.b1, self.b2
        gap = b2[lo : hi + 1] - b1[lo : hi + 1]
        return ((f[lo : hi + 1, 0] - b1[lo : hi + 1]) - (f[lo : hi + 1, 1] - b2[lo : hi + 1])) / gap


def _partner_near(mask: np.ndarray, resid: FloatArray, i: int, gap: int, sign: float | None) -> bool:
    """Does the other curve deviate (``mask``) within ``gap`` points of ``i``, in direction ``sign`` of its
    residual ``resid`` when one is asked for? The seed's partner criterion (L1393)."""
    lo, hi = max(0, i - gap), min(mask.size, i + gap + 1)
    seg = mask[lo:hi] if sign is None else mask[lo:hi] & (np.sign(resid[lo:hi]) == sign)
    return bool(seg.any())


def _spike_candidates(dev: _Deviations, settings: SpikeSettings) -> np.ndarray:
    """Points where one curve deviates and the other has a partner deviation nearby (moving the other way when
    ``converging``), kept, when ``converging``, only where NNM1 is up or NNM2 down: the RQs approach (L1259)."""
    m1, m2, r1, r2, g = dev.m1, dev.m2, dev.r1, dev.r2, settings.partner_gap
    cand = np.zeros(m1.size, dtype=bool)
    for i in range(m1.size):
        if m1[i] and _partner_near(m2, r2, i, g, -np.sign(r1[i]) if settings.converging else None):
            cand[i] = True
        elif m2[i] and _partner_near(m1, r1, i, g, -np.sign(r2[i]) if settings.converging else None):
            cand[i] = True
    if settings.converging:  # NNM1 up / NNM2 down: the RQs approach each other (similar POMs)
        for i in np.flatnonzero(cand):
            if not ((m1[i] and r1[i] > 0) or (m2[i] and r2[i] < 0)):
                cand[i] = False
    return cand


def _spike_events(dev: _Deviations, settings: SpikeSettings) -> list[tuple[int, int, str]]:
    """Adjacent candidates merged into one interaction (the seed's first spike spans several points, L1255),
    each closing at least ``min_closure`` of the gap when ``converging``: (lo, hi, "spike")."""
    return [
        (lo, hi, "spike")
        for lo, hi in true_runs(_spike_candidates(dev, settings), settings.merge_gap)
        if not settings.converging or dev.closure(lo, hi).max() >= settings.min_closure
    ]


def _band_events(dev: _Deviations, settings: SpikeSettings, spikes: list[tuple[int, int, str]]) -> list[tuple[int, int, str]]:
    """Runs of ≥ ``band_min_run`` qualifying windows (:func:`band_windows`), trimmed to the outermost points whose
    NNM1 residual reaches ``band_min_rel[0]``; dropped when only diverging (with ``converging``) or when they
    overlap a spike or an earlier band (already reported): (lo, hi, "band")."""
    r1, r2, h = dev.r1, dev.r2, settings.band_window // 2
    bands: list[tuple[int, int, str]] = []
    for c_lo, c_hi in true_runs(band_windows(r1, r2, settings)):
        if c_hi - c_lo + 1 < settings.band_min_run:
            continue
        pts = [j for j in range(c_lo - h, c_hi + h + 1) if abs(r1[j]) >= settings.band_min_rel[0]]
        lo, hi = pts[0], pts[-1]  # non-empty: a qualifying window has RMS >= the floor
        if settings.converging and not np.any((r1[lo : hi + 1] >= settings.band_min_rel[0]) & (r2[lo : hi + 1] < 0)):
            continue  # anti-correlated but only ever diverging (NNM1 down, NNM2 up): not "similar POMs"
        if any(lo <= s_hi and s_lo <= hi for s_lo, s_hi, _ in (*spikes, *bands)):
            continue
        bands.append((lo, hi, "band"))
    return bands


def _outside_ratios(f: FloatArray, off: np.ndarray, lo: int, hi: int, settings: SpikeSettings) -> tuple[float, float] | None:
    """Median f2/f1 of the ``n_side`` nearest points outside any spike or band, ``guard`` points away, below and
    above [lo, hi] (L1298, L1313); None at the edge of the sweep, where one side has no such point."""
    left = [j for j in range(lo - 1 - settings.guard, -1, -1) if off[j]][: settings.n_side]
    right = [j for j in range(hi + 1 + settings.guard, off.size) if off[j]][: settings.n_side]
    if not left or not right:
        return None
    return float(np.median(f[left, 1] / f[left, 0])), float(np.median(f[right, 1] / f[right, 0]))


def _modal_labels(mr: FloatArray | None, lo: int, hi: int, k: int, settings: SpikeSettings) -> dict:
    """The flag's second label, from the modal f2/f1 at the nearest measured points just below and above it (no
    guard: POD mixing on a spike disturbs the RQs, not the modal phases); empty when either side has none."""
    if mr is None:
        return {}
    below = [j for j in range(lo - 1, -1, -1) if np.isfinite(mr[j])][:1]
    above = [j for j in range(hi + 1, mr.size) if np.isfinite(mr[j])][:1]
    if not (below and above):
        return {}
    ml, mh = float(mr[below[0]]), float(mr[above[0]])
    mlab, mbr = nearest_ratio(ml, mh, settings.ratios)
    return {"modal_ratio": mlab, "modal_ratio_left": ml, "modal_ratio_right": mh,
            "modal_ratio_peak": float(mr[k]), "modal_bracketed": mbr}  # fmt: skip


def _interaction(sweep: _EnergyOrder, dev: _Deviations, off: np.ndarray, lo: int, hi: int, kind: str,
                 settings: SpikeSettings) -> SweepInteraction | None:  # fmt: skip
    """The interaction over sorted points [lo, hi], labelled from the ratios outside it and peaking where it
    closes the gap most; indices mapped back to the input order. None at the edge of the sweep."""
    ratios = _outside_ratios(sweep.f, off, lo, hi, settings)
    if ratios is None:
        return None  # an interaction at the edge of the sweep has no "outside" to read the ratio from
    rl, rr = ratios
    label, bracketed = nearest_ratio(rl, rr, settings.ratios)
    closed = dev.closure(lo, hi)  # a band is many small moves: it is not held to the spike's min_closure
    k = lo + int(np.argmax(closed))
    p, e, f, order = sweep.p[lo : hi + 1], sweep.e, sweep.f, sweep.order
    return SweepInteraction(
        i_lo=int(order[lo]),
        i_hi=int(order[hi]),
        i_peak=int(order[k]),
        p_lo=float(np.nanmin(p)) if np.isfinite(p).any() else float("nan"),
        p_hi=float(np.nanmax(p)) if np.isfinite(p).any() else float("nan"),
        energy_lo=float(e[lo]),
        energy_hi=float(e[hi]),
        f1_hz=float(f[k, 0]),
        f2_hz=float(f[k, 1]),
        ratio=label,
        ratio_left=rl,
        ratio_right=rr,
        bracketed=bracketed,
        n_points=int(hi - lo + 1),
        score=float(np.max(closed)),
        kind=kind,
        **_modal_labels(sweep.mr, lo, hi, k, settings),
    )


def _ls_slope(x: FloatArray, y: FloatArray) -> float:
    """|least-squares slope| of y on x (NaN when x does not vary)."""
    dx = x - x.mean()
    den = float(np.sum(dx * dx))
    return abs(float(np.sum(dx * (y - y.mean()))) / den) if den > 0 else float("nan")


def find_locks(
    energy: FloatArray,
    modal_ratio: FloatArray,
    settings: SpikeSettings = SpikeSettings(),
    amplitudes: FloatArray | None = None,
) -> list[RatioLock]:
    """Plateaus of the per-run modal ratio f2/f1 at a candidate m:n: the sweep's internal resonances as
    frequency locks (the seed's m:n IR keeps m·θ1 − n·θ2 non-time-like, L1296–L1298, so f2/f1 = m/n on it).

    Points are ordered by energy (the RQ-FEP's axis, L1251). For each candidate of ``lock_ratios``, every
    run of ≥ ``lock_min_points`` consecutive points with |ratio − m/n| ≤ ``lock_tol``·m/n is a lock when its
    least-squares slope against log10(energy) is ≤ ``lock_flatness`` × the slope on each side (least squares
    over the run's edge point and ``lock_context`` points beyond it): a ratio passing m:n at a steady slope
    is not a lock. A run without ``lock_context`` points on a side (the sweep's ends) is not judged. NaN
    ratios (no modal measurement) break runs. The result is ordered by energy; indices refer to the input.
    """
    e = np.asarray(energy, dtype=float)
    r0 = np.asarray(modal_ratio, dtype=float)
    if e.ndim != 1 or r0.shape != e.shape:
        raise ValueError("energy and modal_ratio must both be (runs,)")
    if settings.lock_min_points < 2 or settings.lock_context < 1 or settings.lock_tol <= 0:
        raise ValueError("lock_min_points must be >= 2, lock_context >= 1 and lock_tol > 0")
    n = e.size
    p = np.full(n, np.nan) if amplitudes is None else np.asarray(amplitudes, dtype=float)
    order = np.argsort(e, kind="stable")
    x = np.log10(np.maximum(e[order], np.finfo(float).tiny))
    r, pp, ee = r0[order], p[order], e[order]
    c = settings.lock_context
    out: list[RatioLock] = []
    for m, k in settings.lock_ratios:
        target = m / k
        inside = np.isfinite(r) & (np.abs(r - target) <= settings.lock_tol * target)
        for lo, hi in true_runs(inside):
            if hi - lo + 1 < settings.lock_min_points or lo - c < 0 or hi + c >= n:
                continue
            side_lo, side_hi = slice(lo - c, lo + 1), slice(hi, hi + c + 1)
            if not (np.isfinite(r[side_lo]).all() and np.isfinite(r[side_hi]).all()):
                continue
            s_in = _ls_slope(x[lo : hi + 1], r[lo : hi + 1])
            s_b, s_a = _ls_slope(x[side_lo], r[side_lo]), _ls_slope(x[side_hi], r[side_hi])
            if not s_in <= settings.lock_flatness * min(s_b, s_a):  # NaN compares False: not judged a lock
                continue
            seg = r[lo : hi + 1]
            finite_p = np.isfinite(pp[lo : hi + 1]).any()
            out.append(
                RatioLock(
                    i_lo=int(order[lo]),
                    i_hi=int(order[hi]),
                    p_lo=float(np.nanmin(pp[lo : hi + 1])) if finite_p else float("nan"),
                    p_hi=float(np.nanmax(pp[lo : hi + 1])) if finite_p else float("nan"),
                    energy_lo=float(ee[lo]),
                    energy_hi=float(ee[hi]),
                    ratio=(m, k),
                    ratio_mean=float(seg.mean()),
                    ratio_min=float(seg.min()),
                    ratio_max=float(seg.max()),
                    n_points=int(hi - lo + 1),
                    slope_in=s_in,
                    slope_below=s_b,
                    slope_above=s_a,
                )
            )
    out.sort(key=lambda lk: lk.energy_lo)
    return out
