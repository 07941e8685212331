"""How far to trust an update: parameter uncertainty, the fit against the measurement's uncertainty, one-line notes.

An updated parameter is only as good as (a) the measured frequencies it was fitted to and (b) the model's ability to
reproduce them. The standard figures of a weighted least-squares fit (e.g. Friswell & Mottershead, *Finite Element
Model Updating in Structural Dynamics*, 1995, ch. 7; the GUM's linearised propagation) say both:

* the **measurement uncertainty** of each identified frequency, ``sigma_f`` (from the FRFs' coherence:
  :func:`frequency_std`);
* the **normalised residuals** ``z_n = (f_n^exp - f_n^FE) / sigma_f,n`` at the optimum and the reduced chi-square
  ``chi2_nu = sum z^2 / (m - p)``: about 1 when the model explains the data within their uncertainty; well above 1
  when it cannot (a parameter missing, a wrong pair, hits in the nonlinear regime), judged by the chi-square test
  (:data:`FIT_P`);
* the **parameter covariance** ``(J_w^T J_w)^-1 max(1, chi2_nu)``, ``J_w`` the Jacobian of the residuals divided by
  their uncertainty (the a-priori covariance, inflated by the Birge ratio when the fit is worse than the data:
  a 1-sigma never smaller than the data allow, nor than the misfit shows). Without a measurement uncertainty
  (a modes file of frequencies only) the residuals' own scatter stands in for it: ``s^2 = r^T r / (m - p)``.

Then one line per parameter that cannot be trusted as a number: on a bound of its search box (the data want it
beyond), unidentifiable (the residuals do not change along it: infinite sigma), or barely determined.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

#: A fit is flagged when a right model with right uncertainties would misfit this much less often than this: the
#: chi-square test's p-value ``P(chi2_dof >= sum z^2)`` (3 modes over 3 parameters: sum z^2 > 16.3, i.e. residuals
#: 2.3x their uncertainty rms; 1 degree of freedom: 3.3 sigma).
FIT_P = 1e-3
#: A parameter whose 1-sigma is above this fraction of its value is reported as barely determined.
LOOSE_SIGMA = 0.1
#: ``u`` (the search's log-scaled coordinate, 0..1 between the bounds) within this of 0 or 1: on a bound. 1e-3 of
#: the log range is 0.06 % of the value for bounds x0.7..1.3 (Nelder-Mead's clipped simplex stops short of 0/1).
ON_BOUND_U = 1e-3
#: The frequency uncertainty is never taken below this fraction of the frequency: the pLSCF/LSFD estimates of the
#: project's clean simulated FRFs scatter at ~1e-4 (docs/model-updating.md), whatever the coherence says.
REL_STD_FLOOR = 1e-4


def frequency_std(freq_hz: np.ndarray, zeta: np.ndarray, coherence: np.ndarray, n_averages: np.ndarray | float,
                  df_hz: float) -> np.ndarray:  # fmt: skip
    """1-sigma of each identified natural frequency from the FRFs it was fitted to.

    ``coherence``: ``(n_modes, n_outputs)``, each response's coherence at the mode's peak; ``n_averages`` the hits
    averaged (per output, or one number). The random error of an H1 estimate, as a fraction of ``|H|`` (Bendat &
    Piersol, *Random Data*, eq. 9.90), is ``eps = sqrt(1 - g^2) / (|g| sqrt(2 n))``; a resonance frequency fitted to
    the ``N = 2 zeta f / df`` bins of its half-power band moves by about ``zeta f`` per unit relative change of the
    peak's shape, so ``sigma_f = zeta f / sqrt(N sum_o 1/eps_o^2)`` (the outputs are independent estimates of the
    same pole). Floored at :data:`REL_STD_FLOOR`. With a single average the coherence is 1 by construction and says
    nothing: the floor is all there is (the caller should say so)."""
    f = np.asarray(freq_hz, float)
    z = np.clip(np.asarray(zeta, float), 1e-5, None)
    g2 = np.clip(np.asarray(coherence, float), 1e-6, 1.0 - 1e-9)
    n = np.broadcast_to(np.asarray(n_averages, float), g2.shape[-1:])
    inv_eps2 = (2.0 * n * g2 / (1.0 - g2)).sum(axis=-1)
    bins = np.maximum(2.0 * z * f / df_hz, 1.0)
    return np.maximum(z * f / np.sqrt(bins * inv_eps2), REL_STD_FLOOR * f)


def jacobian(residuals: Callable[[np.ndarray], np.ndarray], p: np.ndarray, rel_step: float = 1e-5) -> np.ndarray:
    """Central-difference Jacobian ``d r / d p`` at ``p`` (steps ``rel_step`` of each value)."""
    r0 = residuals(p)
    J = np.empty((r0.size, p.size))
    for i in range(p.size):
        h = rel_step * p[i]
        up, dn = p.copy(), p.copy()
        up[i] += h
        dn[i] -= h
        J[:, i] = (residuals(up) - residuals(dn)) / (2 * h)
    return J


def _cov_diag(J: np.ndarray) -> np.ndarray:
    """``diag((J^T J)^-1)``, columns scaled first; infinite along a direction ``J`` does not see."""
    k = J.shape[1]
    scale = np.abs(J).max(axis=0)
    scale[scale == 0] = 1.0
    Js = J / scale
    JtJ = Js.T @ Js
    if np.linalg.cond(JtJ) > 1e12:
        w, V = np.linalg.eigh(JtJ)
        ok = w > 1e-12 * w.max() if w.max() > 0 else np.zeros(k, bool)
        d = np.where((V[:, ~ok] ** 2).sum(axis=1) > 1e-6, np.inf, (V[:, ok] ** 2 / np.where(ok, w, 1.0)[ok]).sum(axis=1))
    else:
        d = np.diag(np.linalg.inv(JtJ))
    return d / scale**2


def parameter_sigma(J: np.ndarray, r: np.ndarray, r_std: np.ndarray | None) -> tuple[np.ndarray | None, float | None]:
    """(1-sigma per parameter, chi2_nu) from the Jacobian ``J`` of the residuals ``r`` at the optimum (module
    docstring). ``r_std``: the residuals' measurement uncertainty (same units as ``r``), or None. Without it, sigma
    is undefined (None) when there are no more residuals than parameters, and chi2_nu is None."""
    m, k = J.shape
    if r_std is None:
        if m <= k:
            return None, None
        s2 = float(r @ r) / (m - k)
        return np.sqrt(s2 * _cov_diag(J)), None
    w = 1.0 / np.asarray(r_std, float)
    zz = (r * w) @ (r * w)
    chi2_nu = float(zz / (m - k)) if m > k else None
    inflate = max(1.0, chi2_nu) if chi2_nu is not None else 1.0
    return np.sqrt(inflate * _cov_diag(J * w[:, None])), chi2_nu


def fit_warning(z: np.ndarray, chi2_nu: float | None, modes: Sequence[int], dof: int) -> str | None:
    """One line when the residuals exceed their uncertainty past the chi-square test at :data:`FIT_P`, naming the
    worst mode; None when the fit is within it or cannot be judged (``chi2_nu`` None: no more modes than
    parameters)."""
    from scipy.stats import chi2

    if chi2_nu is None or not np.isfinite(chi2_nu) or dof < 1 or chi2.sf(chi2_nu * dof, dof) >= FIT_P:
        return None
    w = int(np.argmax(np.abs(z)))
    return (f"the updated model misses the measured frequencies by {np.sqrt(chi2_nu):.1f}x their uncertainty (rms over "
            f"{dof} degree(s) of freedom, p = {chi2.sf(chi2_nu * dof, dof):.1g}; worst FE mode {modes[w]}: {z[w]:+.1f} sigma): "
            "the parameters cannot explain the data - a parameter is missing, a mode is mispaired, or hits were in the "
            "nonlinear regime")  # fmt: skip


def parameter_notes(names: Sequence[str], bounds: Sequence[tuple[float, float]], values: np.ndarray, u: np.ndarray,
                    sigma: np.ndarray | None, n_modes: int) -> list[str]:  # fmt: skip
    """One line per parameter on a bound, unidentifiable, or barely determined (module docstring)."""
    out = []
    for i, name in enumerate(names):
        lo, hi = bounds[i]
        if u[i] <= ON_BOUND_U or u[i] >= 1.0 - ON_BOUND_U:
            side = "lower" if u[i] <= ON_BOUND_U else "upper"
            out.append(f"{name} = {values[i]:.6g} is on its {side} bound ([{lo:g}, {hi:g}]): the data want it beyond; "
                       "widen the bounds if that is physical, else a parameter is missing or a mode is mispaired")  # fmt: skip
        if sigma is None:
            continue
        if not np.isfinite(sigma[i]):
            out.append(f"{name} is not identifiable from these {n_modes} mode(s) (infinite sigma: the residuals do not "
                       f"change along it, or only together with another parameter); leave it out (--params) or add modes "
                       "it moves")  # fmt: skip
        elif sigma[i] > LOOSE_SIGMA * abs(values[i]):
            out.append(f"{name} is barely determined: 1-sigma {100 * sigma[i] / abs(values[i]):.0f} % of its value; "
                       "do not use it as a measured value")  # fmt: skip
    return out
