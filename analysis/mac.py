"""Mode-shape comparison and quality indicators: MAC, auto-MAC, MPC and MPD (issue 20 item 4).

Arrays in, arrays out; shapes are columns ``(n_dof, n_modes)`` and may be complex.

* **MAC** (Allemang & Brown, 1982; Allemang, "The Modal Assurance Criterion – Twenty Years of Use and
  Abuse", *Sound and Vibration* 37(8), 2003): ``|a^H b|^2 / ((a^H a)(b^H b))``, 1 for parallel vectors,
  0 for orthogonal ones, blind to scaling and to one common complex factor.
* **MPC**, modal phase collinearity (Pappa, Elliott & Schenk, *J. Guidance* 16(5), 1993): how close a
  complex shape is to a real (normal) one. Written here in the eigenvalue form of the 2x2 covariance of
  its real and imaginary parts (as in Reynders, Houbrechts & De Roeck, *MSSP* 2012, eq. 30):
  ``((l1 - l2) / (l1 + l2))^2`` -- 1 when all components share one phase (mod 180 deg).
* **MPD**, mean phase deviation (Reynders et al. 2012, eq. 31): the amplitude-weighted mean angle (deg)
  between each component and the best straight line through the shape in the complex plane.
"""

from __future__ import annotations

import numpy as np


def _as_columns(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a)
    return a[:, None] if a.ndim == 1 else a


def mac(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """MAC matrix ``(n_modes_a, n_modes_b)`` between the columns of ``a`` and ``b`` (same number of rows).

    A 1-D input is one mode; two 1-D inputs still give a (1, 1) matrix so callers index uniformly."""
    a, b = _as_columns(a), _as_columns(b)
    if a.shape[0] != b.shape[0]:
        raise ValueError(f"MAC needs shapes at the same DOFs: {a.shape[0]} vs {b.shape[0]} rows")
    cross = np.abs(a.conj().T @ b) ** 2
    na = np.real(np.einsum("ij,ij->j", a.conj(), a))
    nb = np.real(np.einsum("ij,ij->j", b.conj(), b))
    return cross / np.outer(na, nb)


def auto_mac(a: np.ndarray) -> np.ndarray:
    """MAC of a set of shapes with itself: off-diagonal terms near 1 mean the sensors cannot tell two modes
    apart (too few or badly placed sensors), or one physical mode was identified twice."""
    return mac(a, a)


def mpc(shapes: np.ndarray) -> np.ndarray:
    """Modal phase collinearity per column, in [0, 1] (1: a real mode up to one complex factor)."""
    shapes = _as_columns(shapes)
    out = np.empty(shapes.shape[1])
    for r in range(shapes.shape[1]):
        re, im = shapes[:, r].real, shapes[:, r].imag
        cov = np.array([[re @ re, re @ im], [re @ im, im @ im]])
        l1, l2 = np.linalg.eigvalsh(cov)[::-1]
        out[r] = ((l1 - l2) / (l1 + l2)) ** 2 if l1 + l2 > 0 else 0.0
    return out


def mpd(shapes: np.ndarray) -> np.ndarray:
    """Mean phase deviation per column (degrees, 0 for a real mode; 90 is the worst possible)."""
    shapes = _as_columns(shapes)
    out = np.empty(shapes.shape[1])
    for r in range(shapes.shape[1]):
        psi = shapes[:, r]
        # principal direction of the points (Re, Im): the best straight line through the shape
        _, _, vt = np.linalg.svd(np.column_stack([psi.real, psi.imag]), full_matrices=False)
        theta0 = np.arctan2(vt[0, 1], vt[0, 0])
        a = np.mod(np.angle(psi) - theta0, np.pi)  # angle to the line, mod 180 deg
        dev = np.minimum(a, np.pi - a)
        w = np.abs(psi)
        out[r] = np.degrees(np.sum(w * dev) / np.sum(w)) if np.sum(w) > 0 else 0.0
    return out


__all__ = ["auto_mac", "mac", "mpc", "mpd"]
