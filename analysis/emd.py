"""Empirical mode decomposition (seed §2.6, L462–L474), EEMD (L481) and masked EMD (L485) on PyEMD.

Why PyEMD and not an in-house sifter: the sifting itself (extrema, mirrored end extrema, cubic-spline
envelopes, mean removal) is PyEMD's (package ``EMD-signal``); this module only configures it as close
to Rilling & Flandrin's ``emd.m`` — the code the seed used (L836) — as PyEMD's hooks allow, and adds
the two things the seed needs on top: the masking-signal EMD of Deering & Kaiser and the orthogonality
index of Huang (L934).

``emd.m`` defaults → PyEMD configuration used here (method-wbemd-slowflow.md §2.1 [EXT]):

==========================  ==============================  =====================================================
emd.m                       PyEMD here                      difference
==========================  ==============================  =====================================================
cubic spline envelopes      ``spline_kind="cubic"``         none intended
NBSYM = 2 mirrored extrema  ``nbsym=2`` (PyEMD's port of    none intended (same boundary_conditions logic)
                            Rilling's boundary_conditions)
extrema: sign change of     ``extrema_detection="simple"``  none intended
the first difference
stop [θ1, θ2, tol] =        ``_RillingEMD.check_imf``       PyEMD's default test (svar/std/energy ratio) is
[0.05, 0.5, 0.05] and       overrides PyEMD's test with     replaced by Rilling's; PyEMD checks it *after*
abs(#zeros−#extrema) ≤ 1    the same three thresholds;      subtracting the mean, so the returned mode has one
                            PyEMD keeps its own             more (small, below-threshold) mean removed than
                            |#ext − #zero| < 2 test         emd.m's
MAXITERATIONS = 2000        ``MAX_ITERATION = 2000``        none
stop when residual has      PyEMD: residual with ≤ 2        full :func:`emd` also ends, as PyEMD does by
< 3 extrema                 extrema is the trend; plus      default, when the residual is numerically gone
                            ``end_thresholds`` (PyEMD's     (below); the first-IMF sifts under WBEMD and
                            range/total-power test)         :func:`eemd` keep them at 0, as before
==========================  ==============================  =====================================================

The decomposition's end (issue 28). emd.m ends when the residual has < 3 extrema; the seed writes the end as a
tolerance on the residual, max R_{N+1} < τ (eq. 2.34, L468–L474), and gives no τ. On a residual that is a
constant plus floating-point dust (a tone on an offset, resolved exactly by IMF 1) "< 3 extrema" never holds:
the rounding noise has thousands of extrema, and that rule alone sifts it into IMF after IMF (measured here: 660
IMFs after 60 s on 100 Hz + 0.3, stopped by hand; the ``emd`` package with the same rule ran past 30 s too). Full
:func:`emd` therefore keeps PyEMD's default end test, range_thr 0.001 and total_power_thr 0.005
(``PYEMD_END_THRESHOLDS``): it ends once the residual's peak-to-peak is < 0.001 or its Σ|r| < 0.005. They act on
the record divided by std(x), so they are relative (0.1 % of std(x) peak to peak), and the reason they were once
set to 0 — absolute values end early on displacements in metres (PyEMD on bench_wbemd's beam record in metres: 4
IMFs; standardised: 7) — does not apply. Elsewhere they change nothing: on clean two-tone records and on the beam
record the residual that end effects leave is 1–8 % of std(x), far above them, and the rows equal the
zero-threshold run's (bench/bench_emd.py; on the seed's §3.4.1 grid 142 of 143 decompositions are identical and
the other ends one IMF of 0.04 % early, with the same scores). The per-IMF test stays Rilling's (the seed's emd.m),
so full EMD still sifts more IMFs, for longer, than PyEMD's lax default test: docs/wbemd.md §1.1 has the
measurements and why.

Scale: every input is divided by its standard deviation before sifting and the output multiplied back.
Rilling's criterion is scale-free, but PyEMD keeps absolute guards (e.g. Σ imf² < 1e-10, and the end test above),
which would misbehave on displacement records in metres (~1e-5).

Mirror imaging of the record ends (Lee et al. 2009b, seed L487, §2.3 [CHOICE]) is available as
``mirror=`` (number of samples reflected evenly at each end before sifting, then cut off); default 0,
i.e. only emd.m's extrema mirroring.
"""

from __future__ import annotations

import sys

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import PPoly
from scipy.linalg import solve_banded


def _import_pyemd():
    """PyEMD's ``EEMD`` and ``EMD`` without its plotting helper's ``import pylab``: PyEMD/__init__ imports
    ``PyEMD.visualisation``, which imports pylab (all of matplotlib: ~30 MB resident, ~0.25 s) whenever
    matplotlib is installed and carries on without it when the import fails. The decomposition never
    plots, so pylab is made unimportable for that one import (``sys.modules[name] = None`` makes ``import``
    raise ImportError) and restored at once; a program that already imported pylab keeps it."""
    hide = "pylab" not in sys.modules
    if hide:
        sys.modules["pylab"] = None  # type: ignore[assignment]
    try:
        from PyEMD import EEMD, EMD
    finally:
        if hide and sys.modules.get("pylab", 0) is None:
            del sys.modules["pylab"]
    return EEMD, EMD


EEMD, EMD = _import_pyemd()

RILLING_STOP = (0.05, 0.5, 0.05)
"""emd.m's default stop thresholds [θ1, θ2, tol] (Rilling, Flandrin & Gonçalves 2003)."""
MAX_ITERATION = 2000
"""emd.m's MAXITERATIONS."""
PYEMD_END_THRESHOLDS = (0.001, 0.005)
"""PyEMD's default end of decomposition (``range_thr``, ``total_power_thr``; EMD-signal 1.10), used by full
:func:`emd` on the standardised record; ``tests/test_emd_stop.py`` checks they still equal PyEMD's defaults."""
NO_END_THRESHOLDS = (0.0, 0.0)
"""The end test off (emd.m's rule alone): the first-IMF sifts under WBEMD and :func:`eemd`."""


class _RillingEMD(EMD):
    """PyEMD's EMD with emd.m's stop test; only the IMF test and the envelope bookkeeping change.

    ``end_thresholds`` = (range_thr, total_power_thr), PyEMD's end of decomposition: :func:`emd` passes
    ``PYEMD_END_THRESHOLDS``, everything else keeps ``NO_END_THRESHOLDS`` (the configuration before issue 28).
    """

    def __init__(self, stop: tuple[float, float, float] = RILLING_STOP,
                 end_thresholds: tuple[float, float] = NO_END_THRESHOLDS) -> None:
        super().__init__(spline_kind="cubic", nbsym=2, extrema_detection="simple", MAX_ITERATION=MAX_ITERATION,
                         range_thr=float(end_thresholds[0]), total_power_thr=float(end_thresholds[1]))
        self._stop = stop
        self._amp: NDArray[np.float64] | None = None
        self._extrema: tuple | None = None  # (T, S, PyEMD's extrema of S): the last signal asked about

    def find_extrema(self, T, S):  # PyEMD's signature
        """PyEMD's extrema of ``S``, remembered for the last ``S``: PyEMD's sifting loop asks three times an
        iteration (at its top, inside the envelopes, after the mean is removed) about two distinct signals, the
        next iteration's top about the same one as the last. The answer for an equal signal is the same arrays,
        which PyEMD only reads; a third of a sift's extrema searches remain (issue 30, item 5)."""
        last = getattr(self, "_extrema", None)  # a subclass may not run this __init__
        if last is not None and last[0] is T and np.array_equal(last[1], S):
            return last[2]
        out = super().find_extrema(T, S)
        self._extrema = (T, S.copy(), out)
        return out

    def extract_max_min_spline(self, T, S):  # PyEMD's signature
        out = super().extract_max_min_spline(T, S)
        max_env, min_env = out[0], out[1]
        # Envelope half-distance a_e = |e_max − e_min|/2 of the mode being sifted (emd.m's "amp").
        self._amp = None if np.isscalar(max_env) else np.abs(max_env - min_env) / 2.0
        return out

    def spline_points(self, T, extrema):  # PyEMD's signature
        """PyEMD's cubic envelope through ``extrema`` (row 0 positions, row 1 values), evaluated on ``T`` inside
        them: :func:`not_a_knot_spline` for four points or more (what PyEMD builds with scipy's ``CubicSpline``),
        PyEMD's own path otherwise and for input ``CubicSpline`` would refuse (so it refuses it as before)."""
        x, y = extrema[0], extrema[1]
        if x.size < 4 or not (np.all(np.diff(x) > 0) and np.all(np.isfinite(y)) and np.all(np.isfinite(x))):
            return super().spline_points(T, extrema)
        t = T[(T >= x[0]) & (T <= x[-1])]
        return t, not_a_knot_spline(x, y, t)

    def check_imf(self, imf_new, imf_old, eMax, eMin) -> bool:  # PyEMD's signature
        """Rilling's test: fraction(|m|/a_e > θ1) ≤ tol and |m|/a_e ≤ θ2 everywhere (m = imf_old − imf_new)."""
        theta1, theta2, tol = self._stop
        if self._amp is None:
            return True
        mean = np.abs(imf_old - imf_new)
        amp = self._amp
        sx = mean / np.where(amp > 0, amp, np.inf)
        return bool(np.mean(sx > theta1) <= tol and not np.any(sx > theta2))


def not_a_knot_spline(x: NDArray[np.float64], y: NDArray[np.float64], t: NDArray[np.float64]) -> NDArray[np.float64]:
    """``scipy.interpolate.CubicSpline(x, y)(t)`` for strictly increasing, finite ``x`` (n >= 4) and finite ``y``:
    the same arithmetic in the same order (scipy's not-a-knot system, its banded solve, the Hermite coefficients,
    the piecewise-polynomial evaluation), bit for bit, without the input checks and the generic set-up.

    Why: the sifts under WBEMD build two envelopes a sifting iteration, ~6300 a 20 s session's confirmations, and
    on a few hundred extrema most of CubicSpline's time was its checks (issue 30, item 5). The caller
    (:meth:`_RillingEMD.spline_points`) guarantees the input; ``tests/test_confirm_shared.py`` checks the identity.
    """
    n = x.size
    dx = np.diff(x)
    slope = np.diff(y) / dx
    A = np.zeros((3, n))  # banded: upper, diagonal, lower (scipy.interpolate.CubicSpline, bc 'not-a-knot')
    b = np.empty(n)
    A[1, 1:-1] = 2 * (dx[:-1] + dx[1:])
    A[0, 2:] = dx[:-1]
    A[-1, :-2] = dx[1:]
    b[1:-1] = 3 * (dx[1:] * slope[:-1] + dx[:-1] * slope[1:])
    A[1, 0] = dx[1]
    A[0, 1] = x[2] - x[0]
    d = x[2] - x[0]
    b[0] = ((dx[0] + 2 * d) * dx[1] * slope[0] + dx[0] ** 2 * slope[1]) / d
    A[1, -1] = dx[-2]
    A[-1, -2] = x[-1] - x[-3]
    d = x[-1] - x[-3]
    b[-1] = (dx[-1] ** 2 * slope[-2] + (2 * d + dx[-1]) * dx[-2] * slope[-1]) / d
    s = solve_banded((1, 1), A, b.reshape(n, 1), overwrite_ab=True, overwrite_b=True, check_finite=False).reshape(n)
    tt = (s[:-1] + s[1:] - 2 * slope) / dx  # scipy.interpolate.CubicHermiteSpline
    c = np.stack((tt / dx, (slope - s[:-1]) / dx - tt, s[:-1], y[:-1]))
    return PPoly.construct_fast(c, np.ascontiguousarray(x, dtype=np.float64))(t)


def _check_signal(x: ArrayLike, fs: float, where: str, min_len: int = 16) -> NDArray[np.float64]:
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 1:
        raise ValueError(f"{where}: x must be 1-D, got shape {x.shape}")
    if x.size < min_len:
        raise ValueError(f"{where}: x has {x.size} samples, need at least {min_len}")
    if not np.all(np.isfinite(x)):
        raise ValueError(f"{where}: x contains NaN or inf; clean or interpolate the record first")
    if not (np.isfinite(fs) and fs > 0):
        raise ValueError(f"{where}: fs must be finite and > 0, got {fs}")
    return x


def _mirror(x: NDArray[np.float64], m: int) -> NDArray[np.float64]:
    if m <= 0:
        return x
    m = min(m, x.size - 1)
    return np.concatenate([x[m:0:-1], x, x[-2:-m - 2:-1]])


def _unmirror(c: NDArray[np.float64], m: int, n: int) -> NDArray[np.float64]:
    if m <= 0:
        return c
    m = min(m, n - 1)
    return c[..., m:m + n]


def emd(x: ArrayLike, fs: float, max_imf: int | None = None, *, mirror: int = 0,
        stop: tuple[float, float, float] = RILLING_STOP,
        end_thresholds: tuple[float, float] = PYEMD_END_THRESHOLDS) -> NDArray[np.float64]:
    """EMD of ``x`` (eq. 2.34): rows = IMFs from highest to lowest frequency, last row the residual.

    ``max_imf`` limits the number of IMFs (None: until the residual has < 3 extrema or is numerically gone).
    The output always has the residual as last row (zeros if PyEMD's IMFs sum exactly to ``x``). ``fs`` is
    only checked: PyEMD sifts on the sample index, which is equivalent for uniform sampling.

    ``end_thresholds`` (range_thr, total_power_thr) end the decomposition once the residual of the record
    divided by std(x) has a peak-to-peak below the first or Σ|r| below the second. Default PyEMD's
    (0.001, 0.005): the seed's residual tolerance τ of eq. 2.34 (L468–L474), which emd.m's "< 3 extrema" rule lacks
    and without which a residual of floating-point dust (a tone on an offset) is sifted without end (module
    docstring). ``NO_END_THRESHOLDS`` gives the configuration before issue 28 (emd.m's rule alone).
    """
    x = _check_signal(x, fs, "emd")
    n = x.size
    scale = float(np.std(x))
    if scale == 0:
        return np.vstack([np.zeros(n), x])
    sifter = _RillingEMD(stop, end_thresholds)
    sifter.emd(_mirror(x / scale, mirror), max_imf=-1 if max_imf is None else int(max_imf))
    imfs, _ = sifter.get_imfs_and_residue()
    imfs = _unmirror(np.atleast_2d(imfs), mirror, n) * scale
    # PyEMD appends the residual only when it is non-zero; here the residual row is unconditional.
    return np.vstack([imfs, (x - imfs.sum(axis=0))[None, :]])


def first_imf(x: NDArray[np.float64], mirror: int = 0, stop: tuple[float, float, float] = RILLING_STOP) -> NDArray[np.float64]:
    """Only the first (highest-frequency) IMF: PyEMD stops after one sifting loop (``max_imf=1``).

    WBEMD's sifts (seed Fig. 3.2, eqs. 3.6–3.7) run here. They keep ``NO_END_THRESHOLDS``, the configuration
    WBEMD's results were produced with; PyEMD consults its end test only after an IMF is complete, so with
    ``max_imf=1`` the thresholds could not change IMF 1 anyway (``tests/test_emd_stop.py`` checks both).
    """
    n = x.size
    scale = float(np.std(x))
    if scale == 0:
        return np.zeros(n)
    out = _RillingEMD(stop, NO_END_THRESHOLDS).emd(_mirror(x / scale, mirror), max_imf=1)
    return _unmirror(out[0], mirror, n) * scale


def masked_first_imf(x: ArrayLike, fs: float, mask: ArrayLike, *, mirror: int = 0,
                     stop: tuple[float, float, float] = RILLING_STOP) -> NDArray[np.float64]:
    """Masking-signal EMD (Deering & Kaiser 2005, seed L485): c = (IMF1(x + s) + IMF1(x − s)) / 2.

    The mask s moves the sifting's frequency threshold; its own content cancels in the average
    (exactly for the part of s that ends up in IMF1 of both runs). Like emd.m's MASK option, but only
    the first IMF is computed, which is all WBEMD needs (eqs. 3.6–3.7).
    """
    x = _check_signal(x, fs, "masked_first_imf")
    s = np.asarray(mask, dtype=np.float64)
    if s.shape != x.shape:
        raise ValueError(f"masked_first_imf: mask shape {s.shape} differs from x shape {x.shape}")
    if not np.all(np.isfinite(s)):
        raise ValueError("masked_first_imf: mask contains NaN or inf")
    return 0.5 * (first_imf(x + s, mirror, stop) + first_imf(x - s, mirror, stop))


def eemd(x: ArrayLike, fs: float, *, trials: int = 100, noise_width: float = 0.2, seed: int = 0,
         max_imf: int | None = None) -> NDArray[np.float64]:
    """Ensemble EMD (seed L481): mean over ``trials`` EMDs of x + white noise; last row residual.

    ``noise_width`` is the noise standard deviation relative to std(x) (Wu & Huang 2009 suggest 0.2,
    method-wbemd-slowflow.md §2.4 [EXT]); PyEMD's own ``noise_width`` is relative to the range
    max(x) − min(x), so it is converted. Serial (``parallel=False``) and seeded, so results repeat.
    The inner EMD is the emd.m-configured one of :func:`emd`, without the end thresholds
    (``NO_END_THRESHOLDS``), so the EEMD baselines of docs/wbemd.md §5 stay as computed; the trials carry white
    noise, which keeps their residuals far from the numerical dust the thresholds are for.
    """
    x = _check_signal(x, fs, "eemd")
    if trials < 1:
        raise ValueError(f"eemd: trials must be >= 1, got {trials}")
    scale = float(np.std(x))
    if scale == 0:
        return np.vstack([np.zeros(x.size), x])
    xs = x / scale
    rng_range = float(np.ptp(xs))
    e = EEMD(trials=trials, noise_width=noise_width / rng_range, ext_EMD=_RillingEMD(RILLING_STOP, NO_END_THRESHOLDS),
             parallel=False)
    e.noise_seed(seed)
    imfs = e.eemd(xs, max_imf=-1 if max_imf is None else int(max_imf)) * scale
    resid = x - imfs.sum(axis=0)
    return np.vstack([imfs, resid[None, :]])


def orthogonality_index(components: ArrayLike, x: ArrayLike | None = None) -> float:
    """Index of orthogonality (Huang 1998; seed L934) in the form of Rilling's ``io()``.

    IO = ½ Σ_{i≠j} |Σ_t c_i c_j| / Σ_t x², with the residual included as the last row of
    ``components`` and x = Σ rows when ``x`` is None. The absolute value per pair (Rilling) keeps
    positive and negative cross terms from cancelling; 0 means orthogonal components.
    """
    c = np.asarray(components, dtype=np.float64)
    if c.ndim != 2 or c.shape[0] < 1:
        raise ValueError(f"orthogonality_index: components must be 2-D (n_comp, n), got shape {c.shape}")
    xv = c.sum(axis=0) if x is None else np.asarray(x, dtype=np.float64)
    if xv.shape != c.shape[1:]:
        raise ValueError(f"orthogonality_index: x shape {xv.shape} differs from component length {c.shape[1]}")
    energy = float(np.dot(xv, xv))
    if energy == 0:
        raise ValueError("orthogonality_index: x has zero energy")
    gram = np.abs(c @ c.T)
    return float(0.5 * (gram.sum() - np.trace(gram)) / energy)


def pcc(a: ArrayLike, b: ArrayLike) -> float:
    """Pearson correlation coefficient (seed L853); 0 if either input is constant."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"pcc: shapes differ {a.shape} vs {b.shape}")
    a = a - a.mean()
    b = b - b.mean()
    den = float(np.sqrt(np.dot(a, a) * np.dot(b, b)))
    return 0.0 if den == 0 else float(np.dot(a, b) / den)
