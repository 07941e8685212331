"""Eigenvalues and eigenvectors of many small symmetric matrices, compiled: the seed lane's POD of every window.

Why not ``np.linalg.eigh``: the seed lane decomposes every window's covariance (14 × 14 on the bench's rig, ~6,200
windows per 20 s of data over its eight grids) and ``eigh``, LAPACK's ``dsyevd`` called once per matrix, took ~12 µs
each: ~0.08 s of CPU per 20 s of replay, a third of the seed lane's worker (issue 30 item 5, D131). LAPACK's drivers are
written for large matrices; for a 14 × 14 one their blocking, workspace logic and calls cost more than the arithmetic.
Here each matrix is reduced to tridiagonal form by Householder reflections and diagonalised by the implicit QL method
with Wilkinson-type shifts (Bowdler, Martin, Reinsch and Wilkinson's ``tred2``/``tql2`` (Handbook for Automatic
Computation II, 1971), as in the public-domain JAMA library), one compiled loop over the whole stack.

The results are LAPACK's up to rounding: eigenvalues ascending, orthonormal eigenvectors in the columns, each sign
arbitrary as LAPACK's is (tests/test_symeig.py against ``eigh`` on random, degenerate, rank-deficient and badly scaled
matrices). They are not LAPACK's bit for bit, so the seed lane's RQ frequencies moved in their last bits when this
replaced ``eigh`` (the 4th, of the smallest POV, by up to ~1e-6 relative: that POM is ill-conditioned, as
docs/detection.md says of summation order); live and replay still compute the same numbers, since both call this.
A matrix with a non-finite entry raises ``LinAlgError``, as ``eigh`` does.
"""

from __future__ import annotations

import math

import numba
import numpy as np

#: QL iterations per eigenvalue before giving up (the method converges in 2-3 for almost every matrix; JAMA sets none)
MAX_ITER = 60


def sym_eig(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.linalg.eigh(A)`` for a stack ``A`` (k, n, n) of symmetric matrices (the lower triangle is read): eigenvalues
    (k, n) ascending and eigenvectors (k, n, n) in the columns."""
    A = np.ascontiguousarray(A, dtype=np.float64)
    if A.ndim != 3 or A.shape[1] != A.shape[2]:
        raise ValueError(f"sym_eig: a stack of square matrices (k, n, n), got {A.shape}")
    if not np.isfinite(A).all():
        raise np.linalg.LinAlgError("Eigenvalues did not converge")  # eigh's words for a non-finite matrix
    lam = np.empty(A.shape[:2])
    V = np.empty_like(A)
    if A.shape[1] and not _sym_eig_stack(A, lam, V):
        raise np.linalg.LinAlgError("Eigenvalues did not converge")
    return lam, V


@numba.njit(cache=True, nogil=True)
def _sym_eig_stack(A, lam, V):  # pragma: no cover - compiled
    n = A.shape[1]
    e = np.empty(n)
    W = np.empty((n, n))
    ok = True
    for k in range(A.shape[0]):
        Vk = V[k]
        for i in range(n):
            for j in range(i + 1):  # symmetric from the lower triangle, as eigh's default UPLO="L"
                Vk[i, j] = A[k, i, j]
                Vk[j, i] = A[k, i, j]
        d = lam[k]
        _tred2(Vk, d, e)
        W[:, :] = Vk.T  # the QL rotations combine two vectors at a time: as rows, contiguous (vector operations)
        ok &= _tql2(W, d, e)
        Vk[:, :] = W.T
    return ok


@numba.njit(cache=True, nogil=True, inline="always")
def _hypot(a, b):  # pragma: no cover - compiled
    """``sqrt(a² + b²)`` without overflow or underflow, as in EISPACK's ``pythag``: libm's ``hypot`` (exact to the last
    bit) was half of the QL sweeps' time."""
    a, b = abs(a), abs(b)
    if a < b:
        a, b = b, a
    if a == 0.0:
        return 0.0
    r = b / a
    return a * math.sqrt(1.0 + r * r)


@numba.njit(cache=True, nogil=True)
def _tred2(V, d, e):  # pragma: no cover - compiled
    """Householder reduction of symmetric ``V`` to tridiagonal form: diagonal ``d``, subdiagonal ``e[1:]``, the
    orthogonal transformation accumulated in ``V`` (JAMA's tred2)."""
    n = V.shape[0]
    for j in range(n):
        d[j] = V[n - 1, j]
    for i in range(n - 1, 0, -1):
        scale = 0.0
        h = 0.0
        for k in range(i):
            scale += abs(d[k])
        if scale == 0.0:
            e[i] = d[i - 1]
            for j in range(i):
                d[j] = V[i - 1, j]
                V[i, j] = 0.0
                V[j, i] = 0.0
        else:
            for k in range(i):
                d[k] /= scale
                h += d[k] * d[k]
            f = d[i - 1]
            g = math.sqrt(h)
            if f > 0:
                g = -g
            e[i] = scale * g
            h = h - f * g
            d[i - 1] = f - g
            for j in range(i):
                e[j] = 0.0
            for j in range(i):
                f = d[j]
                V[j, i] = f
                g = e[j] + V[j, j] * f
                for k in range(j + 1, i):
                    g += V[k, j] * d[k]
                    e[k] += V[k, j] * f
                e[j] = g
            f = 0.0
            for j in range(i):
                e[j] /= h
                f += e[j] * d[j]
            hh = f / (h + h)
            for j in range(i):
                e[j] -= hh * d[j]
            for j in range(i):
                f = d[j]
                g = e[j]
                for k in range(j, i):
                    V[k, j] -= f * e[k] + g * d[k]
                d[j] = V[i - 1, j]
                V[i, j] = 0.0
        d[i] = h
    for i in range(n - 1):
        V[n - 1, i] = V[i, i]
        V[i, i] = 1.0
        h = d[i + 1]
        if h != 0.0:
            for k in range(i + 1):
                d[k] = V[k, i + 1] / h
            for j in range(i + 1):
                g = 0.0
                for k in range(i + 1):
                    g += V[k, i + 1] * V[k, j]
                for k in range(i + 1):
                    V[k, j] -= g * d[k]
        for k in range(i + 1):
            V[k, i + 1] = 0.0
    for j in range(n):
        d[j] = V[n - 1, j]
        V[n - 1, j] = 0.0
    V[n - 1, n - 1] = 1.0
    e[0] = 0.0


@numba.njit(cache=True, nogil=True)
def _tql2(W, d, e):  # pragma: no cover - compiled
    """Implicit QL on the tridiagonal ``d``, ``e`` (from :func:`_tred2`): eigenvalues into ``d`` ascending, their vectors
    into ``W``'s rows (``W`` holds the transformation transposed; JAMA's tql2 on columns, with an iteration limit).
    False if an eigenvalue did not converge."""
    n = W.shape[0]
    for i in range(1, n):
        e[i - 1] = e[i]
    e[n - 1] = 0.0
    f = 0.0
    tst1 = 0.0
    eps = 2.0**-52
    for l in range(n):
        tst1 = max(tst1, abs(d[l]) + abs(e[l]))
        m = l
        while m < n - 1:
            if abs(e[m]) <= eps * tst1:
                break
            m += 1
        if m > l:
            it = 0
            while True:
                it += 1
                if it > MAX_ITER:
                    return False
                g = d[l]
                p = (d[l + 1] - g) / (2.0 * e[l])
                r = _hypot(p, 1.0)
                if p < 0:
                    r = -r
                d[l] = e[l] / (p + r)
                d[l + 1] = e[l] * (p + r)
                dl1 = d[l + 1]
                h = g - d[l]
                for i in range(l + 2, n):
                    d[i] -= h
                f = f + h
                p = d[m]
                c = 1.0
                c2 = c
                c3 = c
                el1 = e[l + 1]
                s = 0.0
                s2 = 0.0
                for i in range(m - 1, l - 1, -1):
                    c3 = c2
                    c2 = c
                    s2 = s
                    g = c * e[i]
                    h = c * p
                    r = _hypot(p, e[i])
                    e[i + 1] = s * r
                    s = e[i] / r
                    c = p / r
                    p = c * d[i] - s * g
                    d[i + 1] = h + s * (c * g + s * d[i])
                    for k in range(n):
                        h = W[i + 1, k]
                        W[i + 1, k] = s * W[i, k] + c * h
                        W[i, k] = c * W[i, k] - s * h
                p = -s * s2 * c3 * el1 * e[l] / dl1
                e[l] = s * p
                d[l] = c * p
                if abs(e[l]) <= eps * tst1:
                    break
        d[l] = d[l] + f
        e[l] = 0.0
    for i in range(n - 1):  # ascending, vectors with them
        k = i
        p = d[i]
        for j in range(i + 1, n):
            if d[j] < p:
                k = j
                p = d[j]
        if k != i:
            d[k] = d[i]
            d[i] = p
            for j in range(n):
                p = W[i, j]
                W[i, j] = W[k, j]
                W[k, j] = p
    return True
