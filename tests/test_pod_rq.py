"""POD + Rayleigh quotient kernels (analysis/pod.py), the energy axis and the seed's spike rule.

Oracles: exact discrete orthogonality of whole-period sinusoids (POD of a synthetic 2-mode field), the
eigenvalues of the 1/N covariance (eq. 2.12) by an independent eigensolver, the FE eigenfrequencies of
the rig (RQ of its exact mode shapes, and RQ of POMs from a simulated linear impact), and the seed's
Table 4.3 window start times.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from analysis.energy import energy_percent, input_work, ke_envelope, kinetic_energy, window_energy
from analysis.pod import PodRqSettings, mac, order_poms, pod, rq_hz, smooth_poms, window_bounds, windowed_pod_rq
from analysis.rayleigh import rayleigh_quotient_hz
from analysis.seed_detector import SeedSpikeSettings, check_assumptions, seed_spikes

FS = 16384.0
FE_EXP = (20.81, 68.37)  # beam_ch4_exp linear FE, method-detection §3.2 / docs/decisions.md D6


# ------------------------------------------------------------------------------------------- windows
def test_window_bounds_reproduce_table_4_3_times():
    """Seed: 0.0216 s windows after 0.0251 s (L1371); Table 4.3 times are t_k = 0.0251 + 0.0216 k."""
    b = window_bounds(32768, FS, 0.0216, start_s=0.0251)
    table = {0: 0.0251, 1: 0.0467, 5: 0.1331, 47: 1.040, 58: 1.278, 64: 1.408, 70: 1.538, 77: 1.688, 88: 1.926}
    for k, t in table.items():
        t_k = b[k, 0] / FS
        assert abs(t_k - (0.0251 + 0.0216 * k)) <= 0.5 / FS  # edge rounded to the nearest sample, no drift
        assert abs(t_k - t) <= 1e-3  # the table prints ms for t >= 1 s; k = 70 prints 1.538 where 0.0251 + 0.0216 k = 1.5371
    assert len(b) == 91  # (2 - 0.0251) / 0.0216 = 91.4 full windows (method-detection §5.4)
    assert np.all(b[1:, 0] == b[:-1, 1])  # non-overlapping and contiguous
    assert set(np.diff(b, axis=1).ravel()) <= {353, 354}
    bp = window_bounds(32768, FS, 0.0216, start_s=0.0251, keep_partial=True)
    assert len(bp) == 92 and bp[-1, 1] == 32768  # the seed's 92 segments need a partial last one


def test_window_bounds_overlap_and_offset():
    b = window_bounds(1000, 100.0, 1.0, overlap=0.5, offset_s=0.3, start_s=0.2)
    assert b[0].tolist() == [50, 150] and b[1].tolist() == [100, 200]
    assert b[-1, 1] <= 1000 and b[-1, 1] + 50 > 1000
    assert window_bounds(10, 100.0, 1.0).shape == (0, 2)
    with pytest.raises(ValueError):
        window_bounds(100, 100.0, 0.1, overlap=1.0)


# ----------------------------------------------------------------------------------------------- POD
def _two_mode_field(n_dof=14, n_t=1000, amps=(3.0, 1.0)):
    x = np.linspace(0.05, 1.0, n_dof)
    s1, s2 = np.sin(np.pi * x / 2), np.sin(3 * np.pi * x / 2)
    s2 = s2 - (s2 @ s1) / (s1 @ s1) * s1  # Euclidean-orthogonal shapes: POD recovers them exactly
    t = np.arange(n_t) / n_t
    q1, q2 = amps[0] * np.sin(2 * np.pi * 3 * t), amps[1] * np.sin(2 * np.pi * 7 * t)  # whole periods
    return np.outer(q1, s1) + np.outer(q2, s2) + 0.7, s1, s2  # plus a constant offset (eq. 2.2 mean)


@pytest.mark.parametrize("method", ["eig", "svd"])
def test_pod_recovers_the_shapes_of_a_two_mode_field(method):
    X, s1, s2 = _two_mode_field()
    poms, povs = pod(X, method)
    assert poms.shape == (14, 14) and povs.shape == (14,)
    for k, s in enumerate((s1, s2)):
        ref = s / s[np.argmax(np.abs(s))]
        np.testing.assert_allclose(poms[:, k], ref, atol=1e-10)
    # Whole periods of sines at 3 and 7 cycles are exactly orthogonal: POV_k = amp² |s_k|² / 2 (λ = s²/N_t).
    np.testing.assert_allclose(povs[:2], [9.0 * (s1 @ s1) / 2, 1.0 * (s2 @ s2) / 2], rtol=1e-10)
    assert np.all(povs[2:] < 1e-12 * povs[0])  # rounding: eigh of the covariance resolves ~1e-16 of the largest
    assert np.all(np.abs(poms).max(axis=0) == 1.0) and np.all(poms.max(axis=0) == 1.0)


def test_pod_povs_are_eigenvalues_of_the_sample_covariance():
    rng = np.random.default_rng(1)
    X = rng.standard_normal((354, 14)) @ rng.standard_normal((14, 14))
    poms, povs = pod(X, "svd")
    poms_e, povs_e = pod(X, "eig")
    np.testing.assert_allclose(povs_e, povs, rtol=1e-9)
    np.testing.assert_allclose(poms_e, poms, atol=1e-8)  # same normalisation, so the same vectors
    Xc = X - X.mean(axis=0)
    C = Xc.T @ Xc / X.shape[0]  # eq. 2.12, 1/n normalised
    np.testing.assert_allclose(povs, np.sort(np.linalg.eigvalsh(C))[::-1], rtol=1e-9)
    batch_poms, batch_povs = pod(np.stack([X, 2 * X]))
    np.testing.assert_allclose(batch_povs[1], 4 * povs, rtol=1e-12)
    np.testing.assert_allclose(batch_poms[1], pod(X)[0], atol=1e-10)


@pytest.mark.parametrize("method", ["eig", "svd"])
def test_pod_with_fewer_snapshots_than_dofs(method):
    rng = np.random.default_rng(2)
    poms, povs = pod(rng.standard_normal((5, 14)), method)
    assert poms.shape == (14, 14) and np.count_nonzero(povs > 1e-12) == 4  # 5 centred snapshots have rank 4
    assert np.all(povs >= 0.0)


# ------------------------------------------------------------------------------------------------ RQ
def test_rq_of_exact_mode_shapes_returns_fe_frequencies(rigs):
    rig = rigs("beam_ch4_exp")
    g = rig.guyan()
    phi = rig.modes.shapes[rig.master_dofs(), :4]  # full-model modes at the 14 sensor DOFs
    f_fe = rig.modes.frequencies_hz[:4]
    f = rq_hz(phi, g.M, g.K)
    np.testing.assert_allclose(f, f_fe, rtol=1e-3)  # measured: 7e-7, 9e-6, 8e-5, 3.5e-4
    np.testing.assert_allclose(f, rayleigh_quotient_hz(phi, g.K, g.M), rtol=1e-13)
    np.testing.assert_allclose(f[:2], FE_EXP, rtol=5e-4)


def test_order_poms_rq_and_mac():
    rng = np.random.default_rng(3)
    phi = np.linalg.qr(rng.standard_normal((8, 8)))[0][:, :3]
    perm = np.array([2, 0, 1])
    poms = phi[:, perm] * np.array([1.0, -2.0, 0.5])  # scrambled, rescaled, one sign flipped
    freqs = np.array([30.0, 10.0, 20.0])
    assert order_poms(poms, freqs).tolist() == [1, 2, 0]
    assert order_poms(poms, freqs, "mac", fe_shapes=phi).tolist() == [1, 2, 0]
    assert order_poms(poms[None], freqs[None], "mac", fe_shapes=phi).tolist() == [[1, 2, 0]]
    # Similar POMs (L1555): two POMs that both look like FE mode 1 are sorted by RQ among their slots.
    sim = np.stack([phi[:, 0], phi[:, 0] + 0.3 * phi[:, 1], phi[:, 2]], axis=1)
    macm = mac(phi, sim)
    assert np.argmax(macm[:, 0]) == 0 and np.argmax(macm[:, 1]) == 0
    f_sim = np.array([25.0, 12.0, 40.0])
    assert order_poms(sim, f_sim, "mac", fe_shapes=phi).tolist() == [1, 0, 2]
    with pytest.raises(ValueError):
        order_poms(poms, freqs, "mac")


def test_smooth_poms_keeps_a_polynomial_and_drops_the_rest():
    x = np.linspace(0.05, 0.75, 14)
    p = 2.0 * x**3 - x**5 + 0.4 * x**6
    out = smooth_poms(np.stack([p, np.sin(40 * x)], axis=1), x)
    np.testing.assert_allclose(out[:, 0], p / p[np.argmax(np.abs(p))], atol=1e-10)
    quad = smooth_poms((x**2)[:, None], x)[:, 0]  # no x² term in the seed's fit (L1371)
    assert np.max(np.abs(quad - x**2 / x[-1] ** 2)) > 1e-3


# ---------------------------------------------------------------------- linear rig, simulated impact
@pytest.fixture(scope="module")
def linear_exp_hit():
    """beam_ch4_exp with the cubic spring removed, a 10 N hit (4e-5 J) after a 0.0251 s pre-trigger."""
    from analysis.model.config import RigConfig
    from analysis.model.forces import HalfSine
    from analysis.model.loader import load_config
    from analysis.model.rig import build_rig, channel_signals
    from analysis.model.rigs import resolve_rig_path

    cfg = load_config(RigConfig, resolve_rig_path("beam_ch4_exp")).model_copy(update={"nonlinear_springs": []})
    rig = build_rig(cfg)
    pre = 0.0251
    res = rig.simulator.run(HalfSine(10.0, 0.001, start=pre), 2.0 + pre, rig.sample_rate, amplitudes=[10.0])
    _, sig = channel_signals(rig, res)
    return rig, res, sig[:, 1:], pre


@pytest.fixture(scope="module")
def linear_exp_disp(linear_exp_hit):
    """The hit's displacements through acc_to_disp: seed default (18/10 Hz, zero phase) and causal."""
    from analysis.preprocess import PreprocessSettings, acc_to_disp

    rig, _, acc, pre = linear_exp_hit
    _, d_zp = acc_to_disp(acc, rig.sample_rate, PreprocessSettings())
    _, d_c = acc_to_disp(acc, rig.sample_rate, PreprocessSettings(mode="causal", causal_baseline_s=pre))
    return d_zp, d_c


_GUYAN: dict[int, object] = {}


def _max_rq_error(disp, rig, window_s, start_s, skip_s=0.0):
    if id(rig) not in _GUYAN:
        _GUYAN[id(rig)] = rig.guyan()
    g = _GUYAN[id(rig)]
    r = windowed_pod_rq(disp, rig.sample_rate, g.M, g.K, PodRqSettings(window_s=window_s, start_s=start_s, n_keep=2))
    keep = r.t_start_s >= r.t_start_s[0] + skip_s - 0.5 / rig.sample_rate
    return np.max(np.abs(r.freqs[keep] / rig.modes.frequencies_hz[:2] - 1.0), axis=0)


@pytest.mark.parametrize("window_s", [0.05, 0.075, 0.1])
def test_linear_rig_rq_equals_fe_frequencies(linear_exp_hit, linear_exp_disp, window_s):
    """Every window of a 2 s linear decay: POM1/POM2 RQ = FE 20.81/68.37 Hz within 1 %, both paths."""
    rig, res, _, pre = linear_exp_hit
    d_zp, d_c = linear_exp_disp
    assert res.amplitudes[0] == 10.0 and res.energy.input_work[0, -1] < 1e-4
    assert np.all(_max_rq_error(res.displacement[0], rig, window_s, pre) < 0.01)  # measured <= 0.30 %
    assert np.all(_max_rq_error(d_zp, rig, window_s, pre) < 0.01)  # seed default 18/10 Hz; measured <= 0.64 %
    # The causal 18 Hz high-pass rings for ~0.05 s after the hit (docs/preprocessing.md): skip that.
    assert np.all(_max_rq_error(d_c, rig, window_s, pre, skip_s=0.05) < 0.01)  # measured <= 0.18 %


def test_linear_rig_short_windows_fail(linear_exp_hit, linear_exp_disp):
    """What the 1 % claim does NOT cover: the seed's 0.0216 s window (< half an NNM1 period) and the
    first 0.05 s window of the causal path are off by more than 1 % even on a linear rig."""
    rig, res, _, pre = linear_exp_hit
    _, d_c = linear_exp_disp
    assert _max_rq_error(res.displacement[0], rig, 0.0216, pre)[0] > 0.10  # window-phase artefact, measured 43 %
    assert _max_rq_error(d_c, rig, 0.05, pre)[0] > 0.01  # start-up transient, measured 3.4 %


def test_windowed_pod_rq_outputs(linear_exp_hit):
    rig, res, _, pre = linear_exp_hit
    g = rig.guyan()
    phi = rig.modes.shapes[rig.master_dofs(), :4]
    d = res.displacement[0]
    s = PodRqSettings(window_s=0.1, start_s=pre, n_keep=3, order="mac")
    r = windowed_pod_rq(d, rig.sample_rate, g.M, g.K, s, fe_shapes=phi)
    k = r.n_windows
    assert r.freqs.shape == (k, 3) and r.poms.shape == (k, 14, 3) and r.povs.shape == (k, 14)
    assert r.mac is not None and r.mac_matrix is not None and r.mac_matrix.shape == (k, 4, 3)
    assert np.all(r.mac[:, :2] > 0.99)  # linear decay: POM j is FE mode j
    np.testing.assert_allclose(r.t_start_s, pre + 0.1 * np.arange(k), atol=0.5 / rig.sample_rate)
    # The same kernel on one window reproduces the batch entry (streaming = batch per window).
    a, b = r.start[3], r.stop[3]
    poms, povs = pod(d[a:b])
    np.testing.assert_allclose(np.sort(r.povs[3]), np.sort(povs), rtol=1e-9)  # same POVs, in the MAC order
    f = rq_hz(poms, g.M, g.K)
    np.testing.assert_allclose(r.freqs[3], f[r.svd_rank[3]], rtol=1e-9)
    sm = windowed_pod_rq(d, rig.sample_rate, g.M, g.K, PodRqSettings(window_s=0.1, start_s=pre, smooth=True), x=np.array(
        [c.x_model for c in rig.sensors]))
    assert np.all(np.abs(sm.poms).max(axis=1) == 1.0)
    with pytest.raises(ValueError):
        windowed_pod_rq(d, rig.sample_rate, g.M, g.K, PodRqSettings(smooth=True))


# ------------------------------------------------------------------------------------------- energy
def test_kinetic_energy_envelope_of_a_decaying_mode(linear_exp_hit):
    """Linear decay: PCHIP through KE maxima ≈ the simulator's total mechanical energy (KE max = E)."""
    rig, res, _, pre = linear_exp_hit
    g = rig.guyan()
    fs = rig.sample_rate
    ke = kinetic_energy(res.velocity[0], g.M)
    # KE of NNM1 peaks twice a period; ignore the mode-2 ripples in its troughs (0.8 of that spacing).
    _, env = ke_envelope(ke, fs, min_separation=int(0.8 * fs / (2 * 20.81)))
    b = window_bounds(ke.size, fs, 0.1, start_s=pre + 0.1)
    e = window_energy(env, b)
    truth = res.energy.total[0][b[:, 0]]
    # KE at 14 sensor DOFs with the Guyan mass; peaks of KE are E only when the modes peak together:
    # measured median -1.0 %, worst window 7.0 %.
    np.testing.assert_allclose(e, truth, rtol=0.08)
    assert energy_percent(e)[0] == 100.0 and np.all(np.diff(e) < 0)
    hammer = rig.hammer.dof
    v_h = res.velocity[0][:, rig.sensor_dofs.index(hammer)] if hammer in rig.sensor_dofs else None
    assert v_h is not None
    w = input_work(res.force[0], v_h, fs)
    np.testing.assert_allclose(w, res.energy.input_work[0, -1], rtol=0.02)


# ----------------------------------------------------------------------------------- seed detector
def test_seed_detector_quiet_on_orthogonal_sinusoids():
    """Two steady, orthogonal modes with long windows: smooth RQ curves, no spike anywhere."""
    rng = np.random.default_rng(4)
    K = np.diag([1.0, 4.0, 9.0, 16.0]) * (2 * np.pi * 10) ** 2
    M = np.eye(4)
    t = np.arange(int(4 * FS)) / FS
    X = np.outer(np.sin(2 * np.pi * 10 * t), [1, 0, 0, 0]) + 0.5 * np.outer(np.sin(2 * np.pi * 20 * t + 1), [0, 1, 0, 0])
    X += 1e-6 * rng.standard_normal(X.shape)
    r = windowed_pod_rq(X, FS, M, K, PodRqSettings(window_s=0.2, n_keep=2))
    np.testing.assert_allclose(r.freqs, np.broadcast_to([10.0, 20.0], r.freqs.shape), rtol=1e-3)
    out = seed_spikes(r.freqs)
    assert out.spike_windows.size == 0 and out.intervals == ()


def test_seed_detector_flags_a_planted_partnered_spike():
    rng = np.random.default_rng(5)
    k = np.arange(90)
    f = np.stack([25.0 - 0.04 * k, 70.0 - 0.02 * k], axis=1) + 0.01 * rng.standard_normal((90, 2))
    f[40, 0] += 3.0  # NNM1 jumps up toward NNM2 (L1259) ...
    f[40, 1] -= 4.0  # ... and its partner dips in the same window
    f[70, 0] += 3.0  # a lone NNM1 spike: no partner, a "noise spike" (L1393)
    out = seed_spikes(f)
    assert out.spike_windows.tolist() == [40]
    (iv,) = out.intervals
    assert (iv.start, iv.end, iv.curves, iv.peak_window) == (40, 40, (0, 1), 40)
    assert out.unpartnered_windows.tolist() == [70]
    # A 1.5 % excursion is far beyond 4 sigma of this clean baseline but below the 2 % threshold.
    g = f.copy()
    g[40] = [1.015 * (25.0 - 0.04 * 40), 0.985 * (70.0 - 0.02 * 40)]
    assert seed_spikes(g).spike_windows.size == 0
    assert seed_spikes(g, SeedSpikeSettings(rel_threshold=0.01)).spike_windows.tolist() == [40]
    # Partner one window late: not a partner in the same window, a partner with tolerance 1.
    h = f.copy()
    h[40, 1], h[41, 1] = f[41, 1], f[40, 1]
    assert seed_spikes(h).spike_windows.size == 0
    assert seed_spikes(h, SeedSpikeSettings(partner_tolerance=1)).spike_windows.tolist() == [40, 41]


def test_check_assumptions():
    f_ok = np.stack([np.linspace(30, 22, 50), np.linspace(72, 69, 50)], axis=1)
    assert check_assumptions(14, 2, f_ok, 0.025, True) == []
    w = check_assumptions(3, 2, f_ok, 0.0216, False)
    assert len(w) == 3 and "L61" in w[0] and "L1371" in w[1] and "L69" in w[2]
    jump = f_ok.copy()
    jump[10, 0] *= 1.2
    assert any("L68" in m for m in check_assumptions(14, 2, jump, 0.025, True))


# ------------------------------------------------------------------------------------ causal spike rule
@pytest.mark.parametrize("history", [15, 6])
def test_compiled_spike_rule_equals_the_windowwise_rule(history):
    """``CausalSpikeRule.feed_many`` (one compiled pass) must take exactly the decisions of ``feed`` (numpy
    medians, one window at a time) for any grouping of the windows, including windows without finite
    frequencies, which neither rule counts (exact: medians of the same numbers are the same numbers)."""
    from analysis.rq_spikes import CausalSpikeRule, RobustSpikeSettings

    rng = np.random.default_rng(11)
    F = np.column_stack([21.0 + 0.05 * rng.standard_normal(400), 68.0 + 0.1 * rng.standard_normal(400), np.full(400, 200.0)])
    F[rng.choice(400, 40, replace=False), :2] += rng.choice([-3.0, 3.0], (40, 2))  # partnered jumps: spikes
    F[rng.choice(400, 20, replace=False), 1] += 5.0  # lone jumps: no partner
    F[[0, 1, 50, 51, 52, 300], rng.integers(0, 2, 6)] = np.inf  # silent windows
    s = RobustSpikeSettings(history=history)
    one = CausalSpikeRule(s)
    ref = np.array([one.feed(f) for f in F])
    assert 10 < ref.sum() < 60  # the data exercise both outcomes
    for cuts in ([0, 400], [0, 1, 2, 3, 5, 17, 60, 61, 250, 400], [*range(0, 401, 7), 400]):
        many = CausalSpikeRule(s)
        got = np.concatenate([many.feed_many(F[a:b]) for a, b in itertools.pairwise(cuts)])
        np.testing.assert_array_equal(got, ref)


def test_window_covariances_equal_the_reduceat_form_bit_for_bit():
    """The compiled lattice sums (analysis.operator.window_covariances) must add exactly what the
    ``np.add.reduceat`` formulation added — the POMs of the smallest POVs are ill-conditioned, so any
    other order moves the 4th RQ frequency by ~1e-6 — and equal the two-pass covariance to rounding.
    Two lattices: the operator's (segments < 128 samples) and a coarse one (numpy's pairwise halving)."""
    from analysis.operator import window_covariances

    rng = np.random.default_rng(5)
    buf = rng.standard_normal((3000, 6)) * np.logspace(0, -5, 6) + 1e-3
    fine = np.unique(np.concatenate([np.arange(o, 3001, L) for L in (354, 531) for o in (0, 88, 177, 266)]))
    fine_w = [(a, a + L) for L in (354, 531) for o in (0, 88, 177, 266) for a in range(o, 3001 - L, L)]
    coarse = np.array([0, 7, 300, 1299, 1300, 2999])
    coarse_w = [(0, 300), (7, 1300), (0, 2999), (1299, 1300), (300, 2999)]
    for edges, wins in ((fine, fine_w), (coarse, coarse_w)):
        got = window_covariances(buf, wins, edges)
        # the reference: segment sums by reduceat, window sums by reduceat over interleaved (i, j) pairs
        seg_s1 = np.add.reduceat(buf[edges[0] : edges[-1]], edges[:-1] - edges[0], axis=0)
        seg_s2 = np.stack([buf[a:b].T @ buf[a:b] for a, b in itertools.pairwise(edges)])
        idx = np.array([(np.searchsorted(edges, a), np.searchsorted(edges, b)) for a, b in wins]).ravel()
        s1 = np.add.reduceat(np.concatenate([seg_s1, np.zeros((1, 6))]), idx, axis=0)[::2]
        s2 = np.add.reduceat(np.concatenate([seg_s2, np.zeros((1, 6, 6))]), idx, axis=0)[::2]
        n = np.array([b - a for a, b in wins], float)[:, None, None]
        np.testing.assert_array_equal(got, (s2 - s1[:, :, None] * s1[:, None, :] / n) / n)
        two_pass = np.stack([np.cov(buf[a:b].T, bias=True) for a, b in wins])
        np.testing.assert_allclose(got, two_pass, rtol=1e-6, atol=1e-12 * np.abs(two_pass).max())  # one-pass rounding


def test_modal_energy_compiled_equals_the_formula():
    """analysis.modal_filter.modal_energy: ``(q̇² + ω² q²)/2`` — for q = A cos ωt the energy is ½ω²A² at
    every sample (rounding only), and the compiled block path gives the numpy expression's numbers exactly."""
    from analysis.modal_filter import modal_energy

    w = np.array([2 * np.pi * 20.8, 2 * np.pi * 68.4])
    t = np.arange(4096)[:, None] / FS
    A = np.array([1e-3, 2e-4])
    q, qd = A * np.cos(w * t), -A * w * np.sin(w * t)
    e = modal_energy(q, qd, w)
    np.testing.assert_allclose(e, np.broadcast_to(0.5 * w**2 * A**2, e.shape), rtol=1e-12)
    rng = np.random.default_rng(2)
    q, qd = rng.standard_normal((999, 2)), rng.standard_normal((999, 2)) * 300
    np.testing.assert_array_equal(modal_energy(q, qd, w), 0.5 * (qd**2 + w**2 * q**2))
    np.testing.assert_array_equal(modal_energy(q[5], qd[5], w), 0.5 * (qd[5] ** 2 + w**2 * q[5] ** 2))  # numpy path


def test_robust_spike_intervals_equal_the_per_window_vote():
    """Issue 30: :func:`analysis.rq_spikes.robust_spike_intervals` marks each flagged window's lattice range by two
    binary searches and finds the runs by array operations; before, every window was one comparison over the whole
    lattice and the runs a Python loop. Oracle: that per-window form, written out here, on 400 seeded cases (1-8 grids,
    0-5 windows each, starts at random or exactly on the lattice): equal, interval for interval, bit for bit."""
    from analysis.rq_spikes import robust_spike_intervals

    def per_window(flagged, min_fraction, res):
        if not any(flagged):
            return []
        t_end = max(t1 for g in flagged for _, t1 in g)
        t_start = min(t0 for g in flagged for t0, _ in g)
        ts = np.arange(np.ceil(t_start / res), np.floor(t_end / res) + 1) * res
        votes = np.zeros(ts.size)
        for g in flagged:
            cover = np.zeros(ts.size, bool)
            for t0, t1 in g:
                cover |= (ts >= t0) & (ts <= t1)
            votes += cover
        frac = votes / len(flagged)
        out, k = [], 0
        while k < ts.size:
            if frac[k] >= min_fraction:
                j = k
                while j + 1 < ts.size and frac[j + 1] >= min_fraction:
                    j += 1
                out.append((float(ts[k]), float(ts[j]), float(frac[k : j + 1].max())))
                k = j + 1
            else:
                k += 1
        return out

    rng = np.random.default_rng(30)
    for case in range(400):
        res = (0.0054, 0.01)[case % 2]
        grids = []
        for _ in range(rng.integers(1, 9)):
            n = int(rng.integers(0, 6))
            t0 = np.sort(rng.uniform(0, 2, n)) if case % 3 else np.sort(rng.integers(0, 200, n)) * res
            length = float(rng.choice([0.0216, 0.0324, 4 * res]))
            grids.append([(float(a), float(a + length)) for a in t0])
        mf = float(rng.choice([0.25, 0.5, 0.75, 1.0]))
        assert robust_spike_intervals(grids, mf, res) == per_window(grids, mf, res), (case, grids)
