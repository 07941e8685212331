"""analysis/symeig.py: the compiled small symmetric eigensolver the seed lane's POD uses instead of LAPACK's ``eigh``
(D131). Oracle: ``np.linalg.eigh`` itself, and the defining identities (A V = V Λ, VᵀV = I), on matrices built to be
hard: repeated and zero eigenvalues, rank one, badly scaled, already diagonal, the POD's own covariances."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.symeig import sym_eig

TOL = 64 * np.finfo(float).eps  # backward-stable methods: errors of a few eps of ||A|| (n <= 40 here)


def _check(A: np.ndarray) -> None:
    lam, V = sym_eig(A)
    want = np.linalg.eigh(A)[0]
    scale = np.maximum(np.abs(want).max(axis=1, keepdims=True), np.finfo(float).tiny)
    assert np.all(np.diff(lam, axis=1) >= 0)  # ascending, as eigh
    assert np.max(np.abs(lam - want) / scale) <= TOL * A.shape[1]
    n = A.shape[1]
    assert np.max(np.abs(np.swapaxes(V, 1, 2) @ V - np.eye(n))) <= TOL * n
    assert np.max(np.abs(A @ V - V * lam[:, None, :]) / scale[:, :, None]) <= TOL * n


@pytest.mark.parametrize("n", [1, 2, 3, 5, 14, 40])
def test_random_symmetric_and_pod_covariances_match_eigh(n):
    rng = np.random.default_rng(n)
    B = rng.standard_normal((50, n, n))
    _check(B + np.swapaxes(B, 1, 2))
    X = rng.standard_normal((50, 300, n)) * np.geomspace(1.0, 1e-6, n)  # covariances with POVs over 12 decades
    _check(np.swapaxes(X, 1, 2) @ X / 300)


def test_degenerate_rank_deficient_scaled_and_diagonal_matrices():
    rng = np.random.default_rng(0)
    n = 14
    Q = np.linalg.qr(rng.standard_normal((n, n)))[0]
    cases = [
        np.zeros((n, n)), np.eye(n), 3.0 * np.eye(n),
        Q @ np.diag([1.0] * 5 + [2.0] * 5 + [0.0] * 4) @ Q.T,  # repeated and zero eigenvalues
        np.outer(Q[:, 0], Q[:, 0]),  # rank one
        np.diag(np.arange(n, 0, -1.0)),  # diagonal, descending
        np.diag(np.ones(n - 1), 1) + np.diag(np.ones(n - 1), -1),  # already tridiagonal
    ]
    for scale in (1e-150, 1e-12, 1.0, 1e150):  # neither the squares of 1e-150 nor of 1e150 may underflow or overflow
        _check(np.stack(cases) * scale)


def test_reads_the_lower_triangle_and_refuses_what_eigh_refuses():
    A = np.array([[[2.0, 99.0], [1.0, 2.0]]])  # eigh's default UPLO="L": the 99 is not read
    lam, _ = sym_eig(A)
    np.testing.assert_allclose(lam, [[1.0, 3.0]], rtol=1e-15)
    for bad in (np.nan, np.inf):
        A = np.eye(3)[None].copy()
        A[0, 2, 1] = bad
        with pytest.raises(np.linalg.LinAlgError):
            sym_eig(A)
    with pytest.raises(ValueError, match="stack of square matrices"):
        sym_eig(np.eye(3))
    assert sym_eig(np.zeros((0, 4, 4)))[0].shape == (0, 4)
