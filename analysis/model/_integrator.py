"""Compiled time stepping for :mod:`analysis.model.simulate` (numba).

Scheme: implicit midpoint on the diagonal modal equations
``q'' + c q' + omega^2 q + B^T g = phi_F F`` with the nonlinear spring forces ``g`` taken as the
*discrete gradient* of their potential, ``g = (V(w1) - V(w0)) / (w1 - w0)``. With that choice the
step satisfies the energy identity exactly::

    E(n+1) - E(n) = F_mean * (wF(n+1) - wF(n)) - sum_r c_r (q_r(n+1) - q_r(n))^2 / dt

so an undamped run conserves energy to rounding, the budget of a damped run closes to rounding, and
the scheme is unconditionally stable however stiff a hardening spring becomes (the seed's sweep runs
to 1e12 N). Stability is not accuracy: the frequency error of a mode is ``(omega dt)^2 / 12``, so the
step is chosen per output interval from the current tangent stiffness of the springs (``_integrate``).

Per stage the linear part is diagonal, so only an s-by-s system for the s spring displacements is
solved (Newton; for one spring a safeguarded scalar Newton on a strictly increasing function).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

_TINY = 1e-300


@njit(cache=True, inline="always")
def _dg(law: int, k: float, p: float, w0: float, w1: float, dt: float) -> tuple[float, float]:
    """Discrete gradient g(w0, w1) of one spring's potential and dg/dw1; for a damper row (law 2 viscous, 3
    Coulomb with ``p = v_eps``) its force at the stage's mean stretch rate ``(w1 - w0) / dt`` and its slope, so
    that ``g (w1 - w0) >= 0`` is the work it dissipates over the stage."""
    if law == 2:
        return k * (w1 - w0) / dt, k / dt
    if law == 3:
        th = np.tanh((w1 - w0) / (dt * p))
        return k * th, k * (1.0 - th * th) / (dt * p)
    if law == 0:  # cubic, V = k w^4 / 4
        g = 0.25 * k * (w1 * w1 * w1 + w1 * w1 * w0 + w1 * w0 * w0 + w0 * w0 * w0)
        dg = 0.25 * k * (3.0 * w1 * w1 + 2.0 * w1 * w0 + w0 * w0)
        return g, dg
    # power law, f = k |w|^p sign(w), V = k |w|^(p+1) / (p+1)
    d = w1 - w0
    scale = max(abs(w0), abs(w1))
    if abs(d) > 1e-9 * scale and scale > 0.0:
        v1 = k * abs(w1) ** (p + 1.0) / (p + 1.0)
        v0 = k * abs(w0) ** (p + 1.0) / (p + 1.0)
        g = (v1 - v0) / d
        f1 = k * abs(w1) ** p * np.sign(w1)
        return g, (f1 - g) / d
    m = 0.5 * (w0 + w1)
    g = k * abs(m) ** p * np.sign(m)
    am = abs(m)
    if am > 0.0:
        return g, 0.5 * k * p * am ** (p - 1.0)
    # f'(0) is 0 (p > 1), k (p = 1) or unbounded (p < 1); any finite slope is safe because the
    # solver keeps a bracket.
    return g, 0.5 * k if p == 1.0 else 0.0


@njit(cache=True)
def _solve_scalar(S: float, a: float, w0: float, guess: float, law: int, k: float, p: float, dt: float) -> tuple[float, float]:
    """Root of h(w1) = w1 + S g(w0, w1) - a (h' >= 1): returns (w1, g)."""
    x = guess
    g, dg = _dg(law, k, p, w0, x, dt)
    h = x + S * g - a
    # h' >= 1 puts the root within |h| of x: a bracket for free.
    if h > 0.0:
        lo, hi = x - h, x
    else:
        lo, hi = x, x - h
    for _ in range(200):
        if h == 0.0:
            break
        xn = x - h / (1.0 + S * dg)
        if not (lo <= xn <= hi):
            xn = 0.5 * (lo + hi)
        delta = abs(xn - x)
        x = xn
        g, dg = _dg(law, k, p, w0, x, dt)
        h = x + S * g - a
        if h > 0.0:
            hi = x
        else:
            lo = x
        tol = 4e-16 * (abs(x) + abs(w0)) + _TINY
        if delta <= tol or hi - lo <= tol:
            break
    return x, g


@njit(cache=True)
def _solve_vector(S, a, w0, guess, law, k, p, dt):  # pragma: no cover - exercised via s > 1 rigs
    s = a.shape[0]
    x = guess.copy()
    g = np.empty(s)
    dg = np.empty(s)
    for _ in range(100):
        for i in range(s):
            g[i], dg[i] = _dg(law[i], k[i], p[i], w0[i], x[i], dt)
        h = x + S @ g - a
        J = np.eye(s) + S * dg[None, :]
        dx = np.linalg.solve(J, h)
        x = x - dx
        if np.max(np.abs(dx)) <= 1e-15 * (np.max(np.abs(x)) + np.max(np.abs(w0))) + _TINY:
            break
    for i in range(s):
        g[i], dg[i] = _dg(law[i], k[i], p[i], w0[i], x[i], dt)
    return x, g


@njit(cache=True)
def _force_nl(law, k, p, w, wdot):
    """Each row's force at displacement ``w`` and stretch rate ``wdot`` (a sample instant)."""
    out = np.empty(w.shape[0])
    for i in range(w.shape[0]):
        if law[i] == 2:
            out[i] = k[i] * wdot[i]
        elif law[i] == 3:
            out[i] = k[i] * np.tanh(wdot[i] / p[i])
        elif law[i] == 0:
            out[i] = k[i] * w[i] ** 3
        else:
            out[i] = k[i] * abs(w[i]) ** p[i] * np.sign(w[i])
    return out


@njit(cache=True)
def _antiderivative(kind, start, duration, tt, ff, cum, t):
    """Integral of the unit force up to ``t``: half-sine (kind 0, analytic) or piecewise-linear series."""
    if kind == 0:
        a = min(max(t, start), start + duration)
        return duration / np.pi * (1.0 - np.cos(np.pi * (a - start) / duration))
    x = min(max(t, tt[0]), tt[-1])
    i = np.searchsorted(tt, x, side="right") - 1
    if i < 0:
        i = 0
    if i > tt.shape[0] - 2:
        i = tt.shape[0] - 2
    frac = x - tt[i]
    slope = (ff[i + 1] - ff[i]) / (tt[i + 1] - tt[i])
    return cum[i] + ff[i] * frac + 0.5 * slope * frac * frac


@njit(cache=True)
def _tangent(law, k, p, w):
    if law >= 2:
        return 0.0  # a damper row adds no stiffness
    aw = abs(w)
    if law == 0:
        return 3.0 * k * aw * aw
    if p >= 1.0:
        return k * p * aw ** (p - 1.0)
    return 0.0  # softening at the origin: no extra resolution requested (see simulate.py)


@njit(cache=True)
def _integrate(
    amp,
    omega2,
    cdamp,
    phi_f,
    B,
    law,
    kc,
    pe,
    fkind,
    fstart,
    fdur,
    ftt,
    fff,
    fcum,
    gammas,
    dt_out,
    n_min,
    n_max,
    om_base2,
    theta,
    n_samples,
    q_out,
    v_out,
    g_out,
    work_out,
    diss_out,
    sum_q,
    sum_qq,
    record,
    n_first,
    state,
):
    """Run one amplitude. Writes state at every output sample (``record``) or only moments.

    The run continues from ``state`` (length ``state_size(n_r, s)``: q, v, the spring displacements w and
    their previous stage's w_prev, input work, dissipation — zeros for a structure at rest) at output
    sample ``n_first - 1`` and covers the output samples ``n_first .. n_first + n_samples - 1`` (sample 0 is
    the initial state itself); ``state`` is overwritten with the state at the last of them. Nothing else
    carries over between output intervals (the sub-step count is chosen afresh for each), so a run cut
    into consecutive calls takes exactly the same steps as one call: the same samples, bit for bit.

    Each output interval is split into ``n_sub`` steps, chosen per interval so that
    ``omega_eff * h <= theta`` where ``omega_eff^2 = om_base2 + sum_s k_t(w_s) |b_s|^2`` bounds the
    top frequency of the linearised system at the current spring deflection (plus one interval of
    its motion). Each step is a composition of ``len(gammas)`` midpoint stages of signed lengths
    ``gammas * h`` (one: the 2nd-order rule; three: Yoshida's 4th-order triple jump). Returns
    ``(input work, dissipated, total steps, intervals that hit n_max)``.
    """
    n_r = omega2.shape[0]
    s = B.shape[0]
    n_stage = gammas.shape[0]
    offsets = np.zeros(n_stage + 1)
    for j in range(n_stage):
        offsets[j + 1] = offsets[j] + gammas[j]
    bb = np.zeros(s)
    for i in range(s):
        for k in range(n_r):
            bb[i] += B[i, k] * B[i, k]
    dinv_all = np.empty((n_stage, n_r))
    S_all = np.empty((n_stage, s, s))
    dts = np.empty(n_stage)
    q = state[0:n_r].copy()
    v = state[n_r : 2 * n_r].copy()
    w = state[2 * n_r : 2 * n_r + s].copy()
    w_prev = state[2 * n_r + s : 2 * n_r + 2 * s].copy()
    work = state[2 * n_r + 2 * s]
    diss = state[2 * n_r + 2 * s + 1]
    r = np.empty(n_r)
    u = np.empty(n_r)
    n_cur = -1
    steps = 0
    capped = 0
    for m in range(n_samples):
        n = n_first + m  # the output sample on the run's clock; its row in the outputs is m
        if n > 0:
            om2 = om_base2
            if s > 0:
                wdot = B @ v
                for i in range(s):
                    om2 += _tangent(law[i], kc[i], pe[i], abs(w[i]) + abs(wdot[i]) * dt_out) * bb[i]
            n_sub = int(np.ceil(np.sqrt(om2) * dt_out / theta))
            if n_sub < n_min:
                n_sub = n_min
            if n_sub > n_max:
                n_sub = n_max
                capped += 1
            if n_sub != n_cur:
                n_cur = n_sub
                h = dt_out / n_sub
                for j in range(n_stage):
                    dts[j] = gammas[j] * h
                    for i in range(n_r):
                        dinv_all[j, i] = 1.0 / (2.0 / (dts[j] * dts[j]) + cdamp[i] / dts[j] + 0.5 * omega2[i])
                    S_all[j] = (B * dinv_all[j][None, :]) @ B.T
            h = dt_out / n_cur
            t0 = (n - 1) * dt_out
            for k in range(n_cur):
                tb = t0 + k * h
                i_prev = _antiderivative(fkind, fstart, fdur, ftt, fff, fcum, tb)
                for j in range(n_stage):
                    dt = dts[j]
                    dinv = dinv_all[j]
                    i_next = _antiderivative(fkind, fstart, fdur, ftt, fff, fcum, tb + offsets[j + 1] * h)
                    F = amp * (i_next - i_prev) / dt
                    i_prev = i_next
                    for i in range(n_r):
                        r[i] = phi_f[i] * F - omega2[i] * q[i] + 2.0 * v[i] / dt
                        u[i] = dinv[i] * r[i]
                    if s > 0:
                        a = w + B @ u
                        guess = w + (w - w_prev) * (dt / dts[j - 1] if j > 0 else dt / dts[n_stage - 1])
                        if s == 1:
                            _w1, g1 = _solve_scalar(S_all[j, 0, 0], a[0], w[0], guess[0], law[0], kc[0], pe[0], dt)
                            g = np.empty(1)
                            g[0] = g1
                        else:
                            _wn, g = _solve_vector(S_all[j], a, w, guess, law, kc, pe, dt)
                        corr = B.T @ g
                        for i in range(n_r):
                            u[i] -= dinv[i] * corr[i]
                        w_prev = w
                        w = B @ (q + u)  # recomputed from q to stay consistent with the state
                    w_in = 0.0
                    dd = 0.0
                    for i in range(s):
                        if law[i] >= 2:  # a damper row dissipates g (w1 - w0) over the stage (_dg)
                            dd += g[i] * (w[i] - w_prev[i]) * dt
                    for i in range(n_r):
                        w_in += phi_f[i] * u[i]
                        dd += cdamp[i] * u[i] * u[i]
                        q[i] += u[i]
                        v[i] = 2.0 * u[i] / dt - v[i]
                    work += F * w_in
                    diss += dd / dt
                steps += 1
        if record:
            for i in range(n_r):
                q_out[m, i] = q[i]
                v_out[m, i] = v[i]
            if s > 0:
                gn = _force_nl(law, kc, pe, w, B @ v)
                for i in range(s):
                    g_out[m, i] = gn[i]
            work_out[m] = work
            diss_out[m] = diss
        else:
            for i in range(n_r):
                sum_q[i] += q[i]
                for j in range(n_r):
                    sum_qq[i, j] += q[i] * q[j]
    state[0:n_r] = q
    state[n_r : 2 * n_r] = v
    state[2 * n_r : 2 * n_r + s] = w
    state[2 * n_r + s : 2 * n_r + 2 * s] = w_prev
    state[2 * n_r + 2 * s] = work
    state[2 * n_r + 2 * s + 1] = diss
    return work, diss, steps, capped


def state_size(n_r: int, s: int) -> int:
    """Length of the state vector ``_integrate`` continues from: q, v (n_r each), w, w_prev (s each), work, diss."""
    return 2 * n_r + 2 * s + 2


@njit(cache=True)
def integrate_batch_record(amps, model, force, stepping, n_samples, n_first, state):
    """Full state at every output sample ``n_first .. n_first + n_samples - 1`` for each amplitude, continuing
    from ``state[b]`` (``(n_b, state_size)``, updated in place; see ``_integrate``)."""
    omega2, cdamp, phi_f, B, law, kc, pe = model
    fkind, fstart, fdur, ftt, fff, fcum = force
    gammas, dt_out, n_min, n_max, om_base2, theta = stepping
    n_b = amps.shape[0]
    n_r = omega2.shape[0]
    s = B.shape[0]
    q_out = np.zeros((n_b, n_samples, n_r))
    v_out = np.zeros((n_b, n_samples, n_r))
    g_out = np.zeros((n_b, n_samples, s))
    work_out = np.zeros((n_b, n_samples))
    diss_out = np.zeros((n_b, n_samples))
    steps = np.zeros(n_b, dtype=np.int64)
    capped = np.zeros(n_b, dtype=np.int64)
    dummy1 = np.zeros(1)
    dummy2 = np.zeros((1, 1))
    for b in range(n_b):  # serial: full histories are memory-bound; a parallel kernel compiles 2x slower
        _w, _d, steps[b], capped[b] = _integrate(
            amps[b],
            omega2,
            cdamp,
            phi_f,
            B,
            law,
            kc,
            pe,
            fkind,
            fstart,
            fdur,
            ftt,
            fff,
            fcum,
            gammas,
            dt_out,
            n_min,
            n_max,
            om_base2,
            theta,
            n_samples,
            q_out[b],
            v_out[b],
            g_out[b],
            work_out[b],
            diss_out[b],
            dummy1,
            dummy2,
            True,
            n_first,
            state[b],
        )
    return q_out, v_out, g_out, work_out, diss_out, steps, capped


@njit(cache=True, parallel=True)
def integrate_batch_moments(amps, model, force, stepping, n_samples):
    """Per amplitude: sums of q and q q^T over the output samples, input work, dissipation, step counts."""
    omega2, cdamp, phi_f, B, law, kc, pe = model
    fkind, fstart, fdur, ftt, fff, fcum = force
    gammas, dt_out, n_min, n_max, om_base2, theta = stepping
    n_b = amps.shape[0]
    n_r = omega2.shape[0]
    s = B.shape[0]
    sum_q = np.zeros((n_b, n_r))
    sum_qq = np.zeros((n_b, n_r, n_r))
    work = np.zeros(n_b)
    diss = np.zeros(n_b)
    steps = np.zeros(n_b, dtype=np.int64)
    capped = np.zeros(n_b, dtype=np.int64)
    d2 = np.zeros((1, 1))
    d3 = np.zeros((1, max(s, 1)))
    d1 = np.zeros(1)
    state = np.zeros((n_b, 2 * n_r + 2 * s + 2))  # every run starts at rest
    for b in prange(n_b):
        work[b], diss[b], steps[b], capped[b] = _integrate(
            amps[b],
            omega2,
            cdamp,
            phi_f,
            B,
            law,
            kc,
            pe,
            fkind,
            fstart,
            fdur,
            ftt,
            fff,
            fcum,
            gammas,
            dt_out,
            n_min,
            n_max,
            om_base2,
            theta,
            n_samples,
            d2,
            d2,
            d3,
            d1,
            d1,
            sum_q[b],
            sum_qq[b],
            False,
            0,
            state[b],
        )
    return sum_q, sum_qq, work, diss, steps, capped
