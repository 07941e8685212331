"""Reference solutions with scipy's ``solve_ivp``: the baseline the compiled simulator is checked against.

Two references, both restarted exactly at the pulse edge (a sampled state handed across the force
discontinuity in slope gave a false 2.8 % error in the prototype, detection-findings.md):

* :func:`reference_reduced` — the *same* reduced model (modes + residual vectors) in first-order form,
  any explicit/implicit ``solve_ivp`` method. Isolates the time-stepping error.
* :func:`reference_full` — the *full* FE model (every DOF, physical modal damping matrix) with an
  implicit method (Radau/BDF/LSODA) and its exact Jacobian. Measures truncation + stepping together.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import numpy as np
import scipy.integrate
import scipy.linalg

from analysis.model.beam import FloatArray
from analysis.model.forces import HalfSine
from analysis.model.modal import modal_damping_matrix, structure_modes
from analysis.model.nonlinear import incidence
from analysis.model.simulate import ImpactSimulator
from analysis.model.structure import Structure


def _segments(force: HalfSine, duration: float) -> list[tuple[float, float]]:
    edges = sorted({0.0, *(e for e in (force.start, force.end) if 0.0 < e < duration), duration})
    return list(itertools.pairwise(edges))


def _integrate(rhs, jac, y0, force: HalfSine, t_eval: FloatArray, method: str, rtol: float, atol):
    duration = float(t_eval[-1])
    y = np.asarray(y0, dtype=float)
    out = np.zeros((len(t_eval), len(y)))
    for a, b in _segments(force, duration):
        sel = (t_eval >= a) & ((t_eval < b) | (b == duration))
        kw = {"jac": jac} if jac is not None and method in ("Radau", "BDF", "LSODA") else {}
        ts = t_eval[sel]
        with_end = ts.size == 0 or ts[-1] != b  # one pass gives the samples and the state at the segment end
        sol = scipy.integrate.solve_ivp(
            rhs, (a, b), y, method=method, t_eval=np.append(ts, b) if with_end else ts, rtol=rtol, atol=atol, **kw
        )
        if not sol.success:
            raise RuntimeError(f"solve_ivp ({method}) failed on [{a}, {b}]: {sol.message}")
        out[sel] = (sol.y[:, :-1] if with_end else sol.y).T
        y = sol.y[:, -1]
    return out


def reference_reduced(
    sim: ImpactSimulator,
    force: HalfSine,
    duration: float,
    sample_rate: float,
    method: str = "DOP853",
    rtol: float = 1e-10,
) -> FloatArray:
    """Output displacements (n_samples, n_out) of ``sim``'s reduced model, solved by ``solve_ivp``."""
    red = sim.reduced
    n_r = red.n_basis
    om2, c, phi_f = red.omega**2, red.damping, red.basis[sim.force_dof]
    B = (incidence(red.nonlinear, red.basis.shape[0]) @ red.basis).reshape(len(red.nonlinear), n_r)
    springs = red.nonlinear

    def rhs(t, y):
        q, v = y[:n_r], y[n_r:]
        acc = phi_f * float(force.peak * force.shape_at(t)) - c * v - om2 * q
        if springs:
            w = B @ q
            acc -= B.T @ np.array([s.force(w[i]) for i, s in enumerate(springs)])
        return np.concatenate([v, acc])

    def jac(t, y):
        q = y[:n_r]
        Kt = np.diag(om2)
        if springs:
            w = B @ q
            Kt = Kt + B.T @ np.diag([s.tangent_stiffness(w[i]) for i, s in enumerate(springs)]) @ B
        return np.block([[np.zeros((n_r, n_r)), np.eye(n_r)], [-Kt, -np.diag(c)]])

    t_eval = np.arange(max(2, round(duration * sample_rate))) / sample_rate
    scale = max(float(np.max(np.abs(phi_f))), 1.0) * 1e-14
    y = _integrate(rhs, jac, np.zeros(2 * n_r), force, t_eval, method, rtol, scale)
    return y[:, :n_r] @ red.rows(sim.output_dofs).T


def reference_full(
    structure: Structure,
    force_dof: int,
    output_dofs: Sequence[int],
    force: HalfSine,
    duration: float,
    sample_rate: float,
    method: str = "Radau",
    rtol: float = 1e-8,
    atol: float = 1e-12,
) -> FloatArray:
    """Output displacements of the full FE model (all DOFs), solved by an implicit ``solve_ivp`` method."""
    M, K = structure.M, structure.K
    D = modal_damping_matrix(M, structure_modes(structure), structure.damping)
    n = M.shape[0]
    Minv = scipy.linalg.inv(M)
    MK, MD = Minv @ K, Minv @ D
    mf = Minv[:, force_dof]
    springs = structure.nonlinear
    E = incidence(springs, n)  # stretches w = E x (grounded or between two DOFs)
    ME = Minv @ E.T

    def rhs(t, y):
        x, v = y[:n], y[n:]
        acc = mf * float(force.peak * force.shape_at(t)) - MK @ x - MD @ v
        if springs:
            w = E @ x
            acc -= ME @ np.array([float(s.force(w[i])) for i, s in enumerate(springs)])
        return np.concatenate([v, acc])

    def jac(t, y):
        x = y[:n]
        Kt = MK.copy()
        if springs:
            w = E @ x
            Kt += ME @ np.diag([float(s.tangent_stiffness(w[i])) for i, s in enumerate(springs)]) @ E
        return np.block([[np.zeros((n, n)), np.eye(n)], [-Kt, -MD]])

    t_eval = np.arange(max(2, round(duration * sample_rate))) / sample_rate
    y = _integrate(rhs, jac, np.zeros(2 * n), force, t_eval, method, rtol, atol)
    return y[:, list(output_dofs)]
