"""Windowed proper orthogonal decomposition and Rayleigh-quotient frequencies (seed §2.2–2.3, §4.3.2).

Per window of the displacement record: remove each DOF's temporal mean (eq. 2.2, L153), take the SVD
(eq. 2.13, L247) of the centred snapshots — POMs are the singular vectors over the DOFs, the POVs
``λ = s²/N_t`` (the 1/n covariance of eq. 2.12; the printed "singular values equal the POVs squared"
of L251 is backwards, method-detection §5.6) — compute each POM's RQ frequency with the Guyan-reduced
matrices (eqs. 2.17–2.18), order the POMs (ascending RQ, Ch4 L1251, or by MAC to the FE modes, Ch5
eq. 5.6 / L1555) and keep the first ``n_keep``. The experiment's windows are non-overlapping,
0.0216 s long, starting 0.0251 s into the record, each tagged at its start (L1371; method-detection
§1.6 derives the tagging from Table 4.3).

Every function takes numpy arrays and returns arrays or a frozen dataclass; a streaming caller applies
:func:`windowed_pod_rq` to each window as it completes (the kernels are the same).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import scipy.optimize

FloatArray = np.ndarray


# --------------------------------------------------------------------------------------------- windows
def window_bounds(
    n_samples: int,
    fs: float,
    length_s: float,
    overlap: float = 0.0,
    offset_s: float = 0.0,
    start_s: float = 0.0,
    keep_partial: bool = False,
) -> np.ndarray:
    """Sample bounds ``[start, stop)`` of each window, shape (k, 2).

    Window k spans ``t0 + k·hop`` to ``t0 + k·hop + length_s`` with ``t0 = start_s + offset_s`` (the
    excluded pre-impact part plus a grid shift) and ``hop = length_s·(1 − overlap)``, each edge rounded to
    the nearest sample. Rounding each edge from continuous time (instead of stepping a rounded window
    length) keeps the grid from drifting: the seed's 0.0216 s is 353.9 samples at 16384 Hz, and a fixed
    354-sample hop would be 0.56 ms late by window 88. With ``overlap = 0`` consecutive windows are
    contiguous (353 or 354 samples). ``keep_partial`` adds one last window cut at the record's end
    (the seed's 92nd window needs it: only 91 full ones fit in 2 s, method-detection §5.4).
    """
    if fs <= 0 or length_s <= 0:
        raise ValueError("fs and length_s must be positive")
    if not 0.0 <= overlap < 1.0:
        raise ValueError("overlap must lie in [0, 1)")
    if start_s < 0 or offset_s < 0:
        raise ValueError("start_s and offset_s must be >= 0")
    t0 = start_s + offset_s
    hop = length_s * (1.0 - overlap)
    k_max = int(np.floor(max(n_samples / fs - t0, 0.0) / hop)) + 2
    k = np.arange(k_max)
    starts = np.rint((t0 + k * hop) * fs).astype(np.int64)
    stops = np.rint((t0 + k * hop + length_s) * fs).astype(np.int64)
    full = stops <= n_samples
    out = np.stack([starts[full], stops[full]], axis=1)
    if keep_partial:
        nxt = int(full.sum())
        if nxt < k_max and starts[nxt] < n_samples - 1:
            out = np.vstack([out, [[starts[nxt], n_samples]]])
    return out.reshape(-1, 2)


# ----------------------------------------------------------------------------------------------- POD
def _normalise(poms: FloatArray) -> FloatArray:
    """Scale each column (axis -2 holds the DOFs) to max|ψ| = 1 with its largest-magnitude entry positive."""
    idx = np.argmax(np.abs(poms), axis=-2)
    peak = np.take_along_axis(poms, idx[..., None, :], axis=-2)
    peak = np.where(peak == 0.0, 1.0, peak)
    return poms / peak


def pod(X: FloatArray, method: Literal["eig", "svd"] = "eig") -> tuple[FloatArray, FloatArray]:
    """POMs (n_dof, n_dof) and POVs (n_dof,) of snapshots ``X`` (N_t, n_dof), descending POV.

    Columns are normalised to max|ψ| = 1 with the largest entry positive (the SVD sign is arbitrary; the
    RQ does not depend on it, plots and MAC do). POVs are ``s²/N_t``, the eigenvalues of the 1/N_t
    covariance (eq. 2.12). Also accepts a batch (k, N_t, n_dof) → (k, n_dof, n_dof), (k, n_dof).

    ``method="eig"`` (default) takes the eigenvectors of the covariance, as the seed computes them
    ("eigenvectors of XXᵀ", L251): 0.06–0.14 ms per 14-channel window against 0.2–40 ms for a batched
    SVD, whose LAPACK path is erratic for some window lengths (38 ms per 819×14 window measured with
    OpenBLAS under load). It squares the condition number, so POMs whose POV is below ~1e-12 of the
    largest are numerically arbitrary (they are noise in any measured record). ``method="svd"`` is
    eq. 2.13 on the centred snapshots, accurate down to ~1e-16 of the largest singular value.
    """
    X = np.asarray(X, dtype=float)
    if X.ndim not in (2, 3):
        raise ValueError("X must be (N_t, n_dof) or (k, N_t, n_dof)")
    n_t, n_dof = X.shape[-2:]
    if n_t < 2:
        raise ValueError("need at least 2 snapshots")
    Xc = X - X.mean(axis=-2, keepdims=True)
    if method == "eig":
        C = np.swapaxes(Xc, -1, -2) @ Xc / n_t  # eq. 2.12
        lam, vec = np.linalg.eigh(C)  # ascending
        povs = np.maximum(lam[..., ::-1], 0.0)
        return _normalise(vec[..., ::-1]), povs
    if method != "svd":
        raise ValueError("method must be 'eig' or 'svd'")
    # full_matrices only when there are fewer snapshots than DOFs, so that n_dof POMs always come back.
    _, s, vt = np.linalg.svd(Xc, full_matrices=n_t < n_dof)
    povs = np.zeros((*X.shape[:-2], n_dof))
    povs[..., : s.shape[-1]] = s**2 / n_t
    return _normalise(np.swapaxes(vt, -1, -2)), povs


def rq_hz(poms: FloatArray, M: FloatArray, K: FloatArray) -> FloatArray:
    """Eq. 2.17–2.18 for every column of ``poms`` (n_dof, m) or (k, n_dof, m); same as
    :func:`analysis.rayleigh.rayleigh_quotient_hz`, batched over windows."""
    num = np.einsum("...im,ij,...jm->...m", poms, K, poms)
    den = np.einsum("...im,ij,...jm->...m", poms, M, poms)
    return np.sqrt(np.maximum(num, 0.0) / den) / (2.0 * np.pi)


def mac(fe_shapes: FloatArray, poms: FloatArray) -> FloatArray:
    """Eq. 5.6 (L1551): ``MAC[i, j] = |φ_iᵀψ_j|² / (φ_iᵀφ_i · ψ_jᵀψ_j)``; (n_fe, m) or (k, n_fe, m)."""
    phi = np.asarray(fe_shapes, dtype=float)
    cross = np.einsum("if,...im->...fm", phi, poms)
    nphi = np.einsum("if,if->f", phi, phi)
    npsi = np.einsum("...im,...im->...m", poms, poms)
    return cross**2 / (nphi[:, None] * npsi[..., None, :])


# ----------------------------------------------------------------------------------------- smoothing
def smooth_poms(poms: FloatArray, x: FloatArray, powers: tuple[int, ...] = (3, 4, 5, 6)) -> FloatArray:
    """Least-squares polynomial ``Σ a_p x^p`` through each POM, evaluated back at ``x`` (L1371, L1387).

    The seed: "a sixth-order polynomial with no constant, linear, or quadratic terms" — powers 3…6 of the
    distance from the clamp. (Without the x² term the fit forces zero root curvature, which a clamp does
    not have, method-detection §1.7; ``powers=(2, 3, 4, 5, 6)`` is the alternative.) The fit is a fixed
    projection ``P = A A⁺``, applied to (n_dof, m) or (k, n_dof, m); columns are re-normalised.
    """
    x = np.asarray(x, dtype=float)
    A = x[:, None] ** np.asarray(powers, dtype=float)[None, :]
    if A.shape[0] != np.shape(poms)[-2]:
        raise ValueError("x must give one coordinate per POM entry")
    P = A @ np.linalg.pinv(A)
    return _normalise(np.einsum("ij,...jm->...im", P, poms))


# ---------------------------------------------------------------------------------------------- order
def order_poms(
    poms: FloatArray,
    freqs: FloatArray,
    method: Literal["rq", "mac"] = "rq",
    fe_shapes: FloatArray | None = None,
) -> np.ndarray:
    """Permutation of the POM columns: (m,) for one window, (k, m) for a batch.

    ``"rq"``: ascending RQ frequency, so POM j is NNM j (Ch4, L1251). ``"mac"``: the Hungarian assignment
    of FE modes to POMs maximising the summed MAC (eq. 5.6), FE mode i's POM in position i; POMs that
    share the same best-MAC FE mode ("similar POMs", two POMs for one FE shape, L1555) are re-sorted among
    their positions by RQ frequency; POMs left unassigned (more POMs than FE modes) follow by ascending RQ.
    """
    freqs = np.asarray(freqs, dtype=float)
    if method == "rq":
        return np.argsort(freqs, axis=-1, kind="stable")
    if method != "mac":
        raise ValueError("method must be 'rq' or 'mac'")
    if fe_shapes is None:
        raise ValueError("order='mac' needs fe_shapes")
    poms = np.asarray(poms, dtype=float)
    if poms.ndim == 3:
        return np.stack([order_poms(p, f, "mac", fe_shapes) for p, f in zip(poms, freqs, strict=True)])
    m = poms.shape[1]
    macm = mac(fe_shapes, poms)  # (n_fe, m)
    rows, cols = scipy.optimize.linear_sum_assignment(-macm)
    order = list(cols[np.argsort(rows)])
    best = np.argmax(macm, axis=0)
    for fe_mode in np.unique(best[order]):
        slots = [i for i, c in enumerate(order) if best[c] == fe_mode]
        if len(slots) > 1:
            pick = sorted((order[i] for i in slots), key=lambda c: freqs[c])
            for i, c in zip(slots, pick, strict=True):
                order[i] = c
    rest = sorted(set(range(m)) - set(order), key=lambda c: freqs[c])
    return np.array(order + rest, dtype=np.int64)


# ------------------------------------------------------------------------------------------- pipeline
@dataclass(frozen=True)
class PodRqSettings:
    """The seed's experimental defaults (L1371): 0.0216 s non-overlapping windows, RQ order, no smoothing.

    ``start_s`` is the excluded pre-impact part (0.0251 s in the seed), ``offset_s`` shifts the window
    grid (for testing whether a feature survives a change of window phase). ``n_keep`` POMs are kept
    per window (the seed plots 2 for the experiment, 4 for the computation).
    """

    window_s: float = 0.0216
    overlap: float = 0.0
    offset_s: float = 0.0
    start_s: float = 0.0
    n_keep: int = 4
    order: Literal["rq", "mac"] = "rq"
    smooth: bool = False
    keep_partial: bool = False
    poly_powers: tuple[int, ...] = (3, 4, 5, 6)
    pod_method: Literal["eig", "svd"] = "eig"


@dataclass(frozen=True)
class PodRqResult:
    """Per window k: bounds, start time, kept POMs in order, their RQ frequencies; POVs of all POMs.

    ``povs`` are in the same order as the POMs (so ``povs[:, :n_keep]`` belong to ``poms``);
    ``svd_rank`` is each kept POM's position in the descending-POV SVD order. ``mac`` is MAC(φ_j, ψ_j)
    of kept POM j with FE mode j, ``mac_matrix`` MAC of every FE mode against each kept POM.
    """

    start: np.ndarray  # (k,) sample index
    stop: np.ndarray  # (k,) exclusive
    t_start_s: FloatArray  # (k,) the window's tag (its start, method-detection §1.6)
    freqs: FloatArray  # (k, n_keep) Hz
    poms: FloatArray  # (k, n_dof, n_keep)
    povs: FloatArray  # (k, n_dof)
    svd_rank: np.ndarray  # (k, n_keep)
    mac: FloatArray | None = None  # (k, n_keep)
    mac_matrix: FloatArray | None = None  # (k, n_fe, n_keep)

    @property
    def n_windows(self) -> int:
        return int(self.start.shape[0])


def windowed_pod_rq(
    disp: FloatArray,
    fs: float,
    M: FloatArray,
    K: FloatArray,
    settings: PodRqSettings = PodRqSettings(),
    fe_shapes: FloatArray | None = None,
    x: FloatArray | None = None,
) -> PodRqResult:
    """POD + RQ of each window of ``disp`` (N, n_dof); ``M``, ``K`` Guyan-reduced to those DOFs.

    ``fe_shapes`` (n_dof, n_fe): linear mode shapes at the same DOFs, for ``order="mac"`` and the MAC
    outputs. ``x`` (n_dof,): distance of each DOF from the clamp, needed when ``smooth``. Windows of
    equal length go through one batched eigensolve (or SVD).
    """
    disp = np.asarray(disp, dtype=float)
    if disp.ndim != 2:
        raise ValueError("disp must be (n_samples, n_dof)")
    n, n_dof = disp.shape
    if M.shape != (n_dof, n_dof) or K.shape != (n_dof, n_dof):
        raise ValueError(f"M and K must be {n_dof}x{n_dof} (the DOFs of disp)")
    s = settings
    if not 1 <= s.n_keep <= n_dof:
        raise ValueError(f"n_keep must lie in [1, {n_dof}]")
    if s.smooth and x is None:
        raise ValueError("smooth=True needs the DOF coordinates x")
    if s.order == "mac" and fe_shapes is None:
        raise ValueError("order='mac' needs fe_shapes")
    b = window_bounds(n, fs, s.window_s, s.overlap, s.offset_s, s.start_s, s.keep_partial)
    k = b.shape[0]
    poms_all = np.empty((k, n_dof, n_dof))
    povs_all = np.empty((k, n_dof))
    lengths = b[:, 1] - b[:, 0]
    for length in np.unique(lengths):
        sel = np.flatnonzero(lengths == length)
        idx = b[sel, 0][:, None] + np.arange(length)[None, :]
        poms_all[sel], povs_all[sel] = pod(disp[idx], s.pod_method)
    if s.smooth:
        assert x is not None
        poms_all = smooth_poms(poms_all, x, s.poly_powers)
    freqs_all = rq_hz(poms_all, M, K)
    order = order_poms(poms_all, freqs_all, s.order, fe_shapes)
    keep = order[:, : s.n_keep]
    poms = np.take_along_axis(poms_all, keep[:, None, :], axis=2)
    freqs = np.take_along_axis(freqs_all, keep, axis=1)
    povs = np.take_along_axis(povs_all, order, axis=1)
    mac_j = mac_m = None
    if fe_shapes is not None:
        mac_m = mac(fe_shapes, poms)
        n_fe = mac_m.shape[1]
        mac_j = np.full((k, s.n_keep), np.nan)
        j = min(n_fe, s.n_keep)
        mac_j[:, :j] = mac_m[:, np.arange(j), np.arange(j)]
    return PodRqResult(
        start=b[:, 0].copy(),
        stop=b[:, 1].copy(),
        t_start_s=b[:, 0] / fs,
        freqs=freqs,
        poms=poms,
        povs=povs,
        svd_rank=keep,
        mac=mac_j,
        mac_matrix=mac_m,
    )
