"""Sensor health (issue 21, item 2): each fault found with its reason, healthy data left alone, a dead channel
excluded from the modal filter (events still found) and a dead attachment sensor reported as blind detection."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import scipy.signal

from analysis.evaluation.detectors import modal_exchange_health
from analysis.evaluation.errors import Measured
from analysis.evaluation.grid import GridCase, case_rig, simulate_cases
from analysis.evaluation.score import score_events
from analysis.operator import AnalysisOperator, AnalysisSettings, RigModel
from analysis.records import WARNINGS_TOPIC
from analysis.sensor_health import (
    HealthSettings,
    SensorHealth,
    _bandpass_rows,
    _span_sums_repeats,
    guyan_condense,
    reduced_basis,
    span_sums,
)

FS = 16384.0
NAMES = tuple(f"c{i:02d}" for i in range(8))


def _feed(h: SensorHealth, x: np.ndarray, inp: np.ndarray | None = None, block: int = 1024) -> list:
    out = []
    for a in range(0, x.shape[0], block):
        out += h.feed(x[a : a + block], None if inp is None else inp[a : a + block])
    return out


def _noise(seconds: float, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).standard_normal((round(seconds * FS), len(NAMES))) * 0.02


@pytest.mark.parametrize(
    "fault, make, reason",
    [
        ("dead", lambda x: x[:, 3].__setitem__(slice(None), 0.0), "flat at 0"),
        ("dead", lambda x: x[:, 3].__setitem__(slice(None), x[:, 3] * 1e-3), "level"),
        ("dead", lambda x: x[:, 3].__setitem__(500, np.nan), "non-finite"),
        ("stuck", lambda x: x[:, 3].__setitem__(slice(1000, 2000), 0.7), "constant at 0.7"),
        ("clipping", lambda x: x[:, 3].__setitem__(slice(100, 104), 1.0), "at its ±1 range"),
        ("drifting", lambda x: x[:, 3].__setitem__(slice(None), x[:, 3] + np.linspace(0, 0.5, x.shape[0])), "mean moved"),
        ("noisy", lambda x: x[:, 3].__setitem__(slice(None), x[:, 3] * 30), "pre-hit noise"),
    ],
)
def test_each_fault_on_synthetic_noise(fault, make, reason):
    """Sensor noise on 8 channels with one channel broken: that channel, that fault, that reason; nothing else."""
    x = _noise(3.0)
    make(x)
    h = SensorHealth(NAMES, FS, ranges=[1.0] * len(NAMES))
    got = _feed(h, x, np.zeros(x.shape[0], bool))
    assert [(v.channel, v.fault) for v in got] == [("c03", fault)], got
    assert reason in got[0].reason


def test_whole_block_screen_judges_as_span_by_span():
    """Replay blocks (whole level spans, screened together) and blocks shorter than a span (every span judged alone:
    the scalar path) give the same verdicts at the same samples with the same reasons, every fault at once, on
    quantised data (runs of repeats everywhere) with the pre-input noise judged; and the compiled band-pass is
    scipy's ``sosfilt`` bit for bit."""
    x = np.round(_noise(2.0, seed=4) * 400) / 400  # a coarse ADC: equal neighbours on every channel
    x[3000:, 1] = 0.0  # flat
    x[6000:, 2] = 0.7  # stuck
    x[9000:, 3] *= 1e-3  # dead by level
    x[100:104, 4] = 1.0  # clipping
    x[200, 5] = np.nan  # in the first span: a block's non-finite count is judged at its first span's end
    x[:, 6] *= 30  # noisy before the input
    inp = np.zeros(x.shape[0], bool)
    inp[20000:20016] = True
    runs = []
    for block in (8192, 245):  # a level span is 246 samples
        h = SensorHealth(NAMES, FS, ranges=[1.0] * len(NAMES))
        runs.append([(v.channel, v.fault, v.index, v.reason) for v in _feed(h, x, inp, block)])
    assert runs[0] == runs[1] and {v[:2] for v in runs[0]} == {
        ("c01", "dead"),
        ("c02", "stuck"),
        ("c03", "dead"),
        ("c04", "clipping"),
        ("c05", "dead"),
        ("c06", "noisy"),
    }
    sos = scipy.signal.butter(4, (5.0, 300.0), "bandpass", fs=FS, output="sos")
    z = np.random.default_rng(5).standard_normal((sos.shape[0], 2, 3))
    want, zw = scipy.signal.sosfilt(sos, x[:2000, :3], axis=0, zi=z)
    got = np.empty_like(want)
    z2 = z.copy()
    _bandpass_rows(sos, np.ascontiguousarray(x[:2000, :3]), z, got, 0, 2000)
    assert np.array_equal(got, want) and np.array_equal(z, zw)
    part = np.empty((300, 3))  # only rows 700..999 kept: the same rows, the same end state
    _bandpass_rows(sos, np.ascontiguousarray(x[:2000, :3]), z2, part, 700, 1000)
    assert np.array_equal(part, want[700:1000]) and np.array_equal(z2, zw)
    s1, s2 = span_sums(x[:, :5], 246 * 4)  # spans of 4 level spans, on 5 channels: numpy's sums to the last bit
    spans = x[: s1.shape[0] * 984, :5].reshape(-1, 984, 5)
    assert np.array_equal(s1, spans.sum(axis=1)) and np.array_equal(s2, np.einsum("kij,kij->kj", spans, spans))
    # ... and with the repeats per span in the same pass: np.equal against the sample before, any per span (a stuck run
    # and a NaN planted: NaN equals nothing)
    xr = np.random.default_rng(3).standard_normal((8000, 5))
    xr[3000:3100, 2], xr[5000, 4], xr[5001, 4] = xr[2999, 2], np.nan, np.nan
    last = xr[0] + 1.0
    k = 8000 // 984
    r1, r2, rep = np.empty((k, 5)), np.empty((k, 5)), np.empty((k, 5), bool)
    _span_sums_repeats(xr, 984, last, r1, r2, rep)
    same = np.vstack([xr[:1] == last, xr[1:] == xr[:-1]])[: k * 984].reshape(k, 984, 5).any(axis=1)
    sr = xr[: k * 984].reshape(k, 984, 5)
    assert np.array_equal(rep, same) and rep[3000 // 984, 2] and rep.sum() == 1
    assert np.array_equal(r1, sr.sum(axis=1), equal_nan=True)
    assert np.array_equal(r2, np.einsum("kij,kij->kj", sr, sr), equal_nan=True)
    assert np.array_equal(r2, np.einsum("kij,kij->kj", sr, sr), equal_nan=True)


def test_healthy_noise_and_unknown_range_flag_nothing():
    x = _noise(3.0) * np.linspace(0.3, 1.0, len(NAMES))  # levels 3x apart, as the grid's quietest to median
    assert _feed(SensorHealth(NAMES, FS), x, np.zeros(x.shape[0], bool)) == []
    assert _feed(SensorHealth(NAMES, FS), np.zeros((4096, len(NAMES)))) == []  # all flat: nothing to compare with


def test_guyan_condensation_composes():
    """Condensing the rig's Guyan model onto fewer sensors is the rig's Guyan model at those DOFs (the oracle)."""
    rig = case_rig(GridCase(1000.0, 0.005))
    dofs = [s.dof for s in rig.sensors]
    g = rig.guyan(dofs)
    keep = [i for i in range(len(dofs)) if i != 6]
    M, K = guyan_condense(g.M, g.K, keep)
    g2 = rig.guyan([dofs[i] for i in keep])
    assert np.allclose(K, g2.K, rtol=1e-9, atol=1e-9 * np.abs(g2.K).max())
    assert np.allclose(M, g2.M, rtol=1e-9, atol=1e-9 * np.abs(g2.M).max())
    like = reduced_basis(g.M, g.K, list(range(len(dofs))), 4).shapes[keep]
    b = reduced_basis(g.M, g.K, keep, 4, like)
    assert np.all(np.sum(b.shapes * (M @ like), axis=0) > 0)  # signs follow the old modes


@pytest.fixture(scope="module")
def hits():
    """A strong nonlinear hit with exchanges and its linear twin, beam_ch4_exp, 2 s at 1 % noise (cached)."""
    return simulate_cases([GridCase(2000.0, 0.002, True, 5), GridCase(1300.0, 0.005, False, 8)], 2.0)


def test_healthy_hits_exclude_nothing(hits):
    for d in hits:
        for m in (Measured(0.01), Measured(0.03, 5.0)):
            assert modal_exchange_health(m(d))[1] == []


def test_inconsistent_channel_found_on_a_hit(hits):
    """a05 reads another place's response (a swapped cable): alive, normal level, but off the model's expectation."""
    d = Measured(0.01)(hits[0])
    acc = d.acc.copy()
    acc[:, 4] = d.acc[:, 10]
    warns = modal_exchange_health(type(d)(**{**d.__dict__, "acc": acc}))[1]
    assert [(k, key) for k, key, _ in warns] == [("sensor", "sensor:a05")]
    assert "inconsistent" in warns[0][2] and "neighbours" in warns[0][2]


def test_dead_channel_excluded_events_still_found(hits):
    d = Measured(0.01)(hits[0])
    truth = [d.exchanges]
    base = score_events([modal_exchange_health(d)[0]], truth, d.window_s)
    ev, warns = modal_exchange_health(Measured(0.01, dead=("a07",))(d))
    assert [key for _, key, _ in warns] == ["sensor:a07"] and "dead" in warns[0][2] and "excluded" in warns[0][2]
    s = score_events([ev], truth, d.window_s)
    assert base.tp >= 1 and s.tp >= base.tp - 0 and s.fp == 0
    assert modal_exchange_health(Measured(0.01, dead=("a07",))(hits[1]))[0] == []  # twin: still no false event


def test_dead_attachment_sensor_blind_through_the_operator(hits):
    """a13 (0.700 m, the attachment) dead: the operator fed DAQ blocks warns 'sensor' and 'blind' on /analysis/warnings."""
    d = Measured(0.01, dead=("a13",))(hits[0])
    rig = case_rig(d.case)
    model = RigModel.from_rig(rig)
    assert model.nonlinear_sensors == ("a13",)
    chans = (*d.sensor_names, rig.hammer.name)
    force = np.where(d.input_active(), 500.0, 0.0)
    data = np.column_stack([d.acc, force]).astype(np.float32)
    got = []
    op = AnalysisOperator(model, chans, d.fs, AnalysisSettings(seed_lane=False), emit=lambda t, r: got.append((t, r)))
    for a in range(0, data.shape[0], 512):
        op.feed(SimpleNamespace(first_index=a, data=data[a : a + 512]))
    op.finish()
    warns = [r for t, r in got if t == WARNINGS_TOPIC]
    kinds = [w.kind for w in warns]
    assert "blind" in kinds and kinds.count("sensor") == 1
    assert "a13" in next(w.message for w in warns if w.kind == "blind")
    assert op._mf_cols == [i for i, s in enumerate(model.sensors) if s != "a13"]


def test_settings_validate():
    with pytest.raises(ValueError):
        HealthSettings(dead_rel=0)
