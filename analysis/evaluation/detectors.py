"""The detectors scored by ``bench/eval_detection.py``, each a ``CaseData -> events`` callable.

* ``seed_literal_acc`` / ``seed_literal_disp`` — the seed's method as printed and read literally
  (detection-findings.md): displacements (the §4.3 zero-phase 18/10 Hz chain for the acceleration
  path), 0.0216 s non-overlapping windows from the end of the pulse, POD + RQ with the Guyan matrices,
  the partnered spike rule of analysis/seed_detector.py; an event per spike interval, labelled with the
  RQ ratio NNM2/NNM1 of the windows just before it (the seed reads the ratio off the curves, L1298).
* ``modal_exchange_acc`` / ``modal_exchange_disp`` — gvtlink's detector (analysis/exchange.py) on the
  same data through the same streaming code a session runs (causal modal filter).
* ``robust_rq_acc`` — the window-robust RQ spikes alone (analysis/rq_spikes.py), to show what the
  robustness costs and buys on the seed's own evidence.
"""

from __future__ import annotations

import numpy as np

from analysis.evaluation.grid import CaseData, GridCase, case_rig
from analysis.evaluation.score import DetectedEvent
from analysis.exchange import ExchangeSettings, detect_exchanges, nearest_ratio
from analysis.modal_filter import ModalBasis, ModalFilterSettings, modal_basis
from analysis.model.rig import Rig
from analysis.operator import window_rq
from analysis.preprocess import PreprocessSettings, acc_to_disp
from analysis.rq_spikes import CausalSpikeRule, RobustSpikeSettings, robust_spike_intervals
from analysis.seed_detector import seed_spikes

WINDOW_S = 0.0216


_MODELS: dict[int, tuple[Rig, tuple]] = {}


def rig_model(rig: Rig) -> tuple[np.ndarray, np.ndarray, ModalBasis]:
    """Guyan ``M``, ``K`` at the sensors and the 4-mode basis the detectors use, built from ``rig`` (cached per rig).

    The seed's method assumes the detector's linear model is the structure's (an updated model, Ch. 4
    L1367); ``model_rig`` below lets the realistic grid hand the detectors a model that is off.
    """
    hit = _MODELS.get(id(rig))
    if hit is None or hit[0] is not rig:
        g = rig.guyan([s.dof for s in rig.sensors])
        hit = _MODELS[id(rig)] = (rig, (g.M, g.K, modal_basis(g.M, g.K, 4)))
    return hit[1]


def _model(case: CaseData, model_rig: Rig | None = None) -> tuple[np.ndarray, np.ndarray, ModalBasis]:
    """The detector's model: ``model_rig``'s when given, else the case's own rig (the default: a perfect model)."""
    if model_rig is not None:
        return rig_model(model_rig)
    c = case.case
    return rig_model(case_rig(GridCase(1.0, c.zeta, c.cubic, 0, c.rig)))


def _seed_events(case: CaseData, disp: np.ndarray, model_rig: Rig | None = None) -> list[DetectedEvent]:
    M, K, _ = _model(case, model_rig)
    fs = case.fs
    L = round(WINDOW_S * fs)
    first = int(np.ceil(case.pulse_end_s * fs))
    starts = np.arange(first, disp.shape[0] - L + 1, L)
    f, _ = window_rq(np.stack([disp[s : s + L] for s in starts]), M, K, 2)
    res = seed_spikes(f)
    out = []
    for iv in res.intervals:
        before = f[max(0, iv.start - 3) : max(1, iv.start)]
        r = float(np.median(before[:, 1] / before[:, 0]))
        m, n = nearest_ratio(r)
        out.append(DetectedEvent(starts[iv.start] / fs, (starts[iv.end] + L) / fs, m, n, 1.0))
    return out


def seed_literal_acc(case: CaseData, model_rig: Rig | None = None) -> list[DetectedEvent]:
    _, disp = acc_to_disp(case.acc.astype(np.float64), case.fs, PreprocessSettings())
    return _seed_events(case, disp, model_rig)


def seed_literal_disp(case: CaseData, model_rig: Rig | None = None) -> list[DetectedEvent]:
    return _seed_events(case, case.disp_true.astype(np.float64), model_rig)


def _exchange(case: CaseData, data: np.ndarray, quantity: str, model_rig: Rig | None = None) -> list:
    _, _, basis = _model(case, model_rig)
    inp = case.input_active()
    zeta = case.case.zeta
    events, _ = detect_exchanges(
        data.astype(np.float64), case.fs, basis, ExchangeSettings(window_s=WINDOW_S), ModalFilterSettings(quantity=quantity),
        input_active=inp, damping=[zeta, zeta, case.case.zeta_rest, case.case.zeta_rest],
    )  # fmt: skip
    return events


def modal_exchange_acc(case: CaseData, model_rig: Rig | None = None) -> list:
    return _exchange(case, case.acc, "acceleration", model_rig)


def modal_exchange_disp(case: CaseData, model_rig: Rig | None = None) -> list:
    return _exchange(case, case.disp_true, "displacement", model_rig)


def robust_rq_acc(case: CaseData, model_rig: Rig | None = None) -> list[DetectedEvent]:
    M, K, _ = _model(case, model_rig)
    _, disp = acc_to_disp(case.acc.astype(np.float64), case.fs, PreprocessSettings(mode="causal"))
    fs = case.fs
    L = round(WINDOW_S * fs)
    s = RobustSpikeSettings()
    first = int(np.ceil(case.pulse_end_s * fs))
    grids, ratios = [], []
    for length in s.lengths:
        for off in s.offsets:
            n, o = round(length * L), round(off * L)
            starts = np.arange(first + o, disp.shape[0] - n + 1, n)
            f, _ = window_rq(np.stack([disp[a : a + n] for a in starts]), M, K, 2)
            flags = CausalSpikeRule(s).feed_many(f)
            grids.append([(a / fs, (a + n) / fs) for a in starts[flags]])
            if length == 1.0 and off == 0.0:
                ratios = (starts / fs, f[:, 1] / f[:, 0])
    out = []
    for t0, t1, frac in robust_spike_intervals(grids, s.min_fraction, 0.25 * WINDOW_S):
        ts, r = ratios
        before = r[(ts < t0) & (ts >= t0 - 3 * WINDOW_S)]
        m, n = nearest_ratio(float(np.median(before))) if before.size else (0, 0)
        out.append(DetectedEvent(t0, t1, m, n, frac))
    return out


DETECTORS = {
    "seed literal (acc)": seed_literal_acc,
    "seed literal (disp)": seed_literal_disp,
    "robust RQ spikes (acc)": robust_rq_acc,
    "gvtlink modal exchange (acc)": modal_exchange_acc,
    "gvtlink modal exchange (disp)": modal_exchange_disp,
}
