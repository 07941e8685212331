"""The detectors scored by ``bench/eval_detection.py``, each a ``CaseData -> events`` callable.

* ``seed_literal_acc`` / ``seed_literal_disp`` — the seed's method as printed and read literally
  (detection-findings.md): displacements (the §4.3 zero-phase 18/10 Hz chain for the acceleration
  path), 0.0216 s non-overlapping windows from the end of the pulse, POD + RQ with the Guyan matrices,
  the partnered spike rule of analysis/seed_detector.py; an event per spike interval, labelled with the
  RQ ratio NNM2/NNM1 of the windows just before it (the seed reads the ratio off the curves, L1298).
* ``modal_exchange_acc`` / ``modal_exchange_disp`` — gvtlink's detector (analysis/exchange.py) on the
  same data through the same streaming code a session runs (causal modal filter).
  Sensor health runs in front of its modal filter as in a session (analysis/sensor_health.py's
  :class:`HealthGuard`, the same object the operator uses, fed the record in DAQ-sized blocks):
  :func:`modal_exchange_health` also returns the warnings a session would raise.
* ``robust_rq_acc`` — the window-robust RQ spikes alone (analysis/rq_spikes.py), to show what the
  robustness costs and buys on the seed's own evidence.
"""

from __future__ import annotations

import numpy as np

from analysis.evaluation.grid import CaseData, GridCase, case_rig
from analysis.evaluation.score import DetectedEvent
from analysis.exchange import ExchangeDetector, ExchangeSettings, ModalWindower, band_noise_energy, nearest_ratio
from analysis.lines import LineSettings
from analysis.modal_filter import ModalBasis, ModalFilterSettings, ModalStateTracker, modal_basis
from analysis.model.rig import Rig
from analysis.operator import window_rq
from analysis.preprocess import PreprocessSettings, acc_to_disp
from analysis.rq_spikes import CausalSpikeRule, RobustSpikeSettings, robust_spike_intervals
from analysis.seed_detector import seed_spikes
from analysis.sensor_health import HealthGuard, HealthSettings

WINDOW_S = 0.0216
#: samples per block fed to the health check and the modal filter: the demo/simulated DAQ's block (daq/studies/demo.py)
BLOCK = 1024
HEALTH = HealthSettings()
#: the line canceller in front of the modal filter, as in a session (None: off, the detector before issue 29)
LINES: LineSettings | None = LineSettings()
#: the detector's settings in every evaluation (the defaults a session uses, at the seed's window)
EXCHANGE = ExchangeSettings(window_s=WINDOW_S)
#: hand the detector the band noise the case's sensors put into each mode (their noise std through
#: :func:`band_noise_energy`), as a session does from the rig's ``noise_rms``: the grid's single-hit records start at
#: the pulse, so the detector has no quiet windows to measure it from (docs/detection.md §9)
NOISE_PRIOR = True


def noise_prior(case: CaseData, basis: ModalBasis, cols: list[int], mf: ModalFilterSettings) -> np.ndarray | None:
    """Band noise energy per mode from the case's per-channel noise std on the columns ``cols`` in use."""
    if not NOISE_PRIOR or case.noise_std.size == 0 or mf.quantity != "acceleration":
        return None
    return band_noise_energy(basis, case.noise_std[cols], case.fs, mf.highpass_hz, mf.order)


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


def modal_exchange_health(
    case: CaseData,
    model_rig: Rig | None = None,
    quantity: str = "acceleration",
    health: HealthSettings | None = HEALTH,
    lines: LineSettings | None = LINES,
) -> tuple[list, list[tuple[str, str, str]]]:
    """gvtlink's detector on the case as a session runs it: sensor health, the (rebuilt) modal filter, windows,
    exchange detection, block by block; returns the events and the health warnings ``(kind, key, message)``.
    ``health=None``: every sensor trusted (the detector before issue 21)."""
    M, K, basis = _model(case, model_rig)
    data = (case.acc if quantity == "acceleration" else case.disp_true).astype(np.float64)
    inp = case.input_active()
    zeta = case.case.zeta
    s = EXCHANGE
    fs = case.fs
    c = case.case
    nl_rig = model_rig if model_rig is not None else case_rig(GridCase(1.0, c.zeta, True, 0, c.rig))
    nl_dofs = {sp.dof for sp in nl_rig.structure.nonlinear}
    guard = None
    if health is not None:
        sensors = nl_rig.sensors
        guard = HealthGuard(M, K, case.sensor_names, fs, basis.n_modes, health, [x.props.range for x in sensors],
                            [x.props.sensitivity_mv_per_unit for x in sensors],
                            [x.name for x in sensors if x.dof in nl_dofs], lines)  # fmt: skip
    mf = ModalFilterSettings(quantity=quantity)
    tracker = ModalStateTracker(basis, fs, mf)
    windower = ModalWindower(basis, fs, round(s.window_s * fs), max(1, round(s.hop * fs)), 0,
                             energy_bandpass=s.band_limited_energy)  # fmt: skip
    cols = list(range(data.shape[1]))
    det = ExchangeDetector(s, [zeta, zeta, c.zeta_rest, c.zeta_rest], basis.n_modes, noise_prior(case, basis, cols, mf))
    events, warns = [], []
    for a in range(0, data.shape[0], BLOCK):
        x, i = data[a : a + BLOCK], inp[a : a + BLOCK]
        x, switches = guard.feed_clean(x, i) if guard is not None else (x, [])
        for lo, hi, sw in guard.pieces(x.shape[0], switches) if guard is not None else [(0, x.shape[0], None)]:
            if hi > lo:
                q, qd = tracker.feed(x[lo:hi, cols])
                events += [ev for win in windower.feed(q, qd, i[lo:hi]) for ev in det.feed(win)]
            if sw is not None:
                warns += sw.warnings
                if sw.lines:
                    det.clear_quiet()
                if sw.basis is not None:
                    tracker.set_basis(sw.basis)
                    windower.basis = sw.basis
                    cols = list(sw.keep)
                    det.set_noise_prior(noise_prior(case, sw.basis, cols, mf))
    events.extend(det.finish())
    return events, warns


def modal_exchange_acc(case: CaseData, model_rig: Rig | None = None) -> list:
    return modal_exchange_health(case, model_rig)[0]


def modal_exchange_disp(case: CaseData, model_rig: Rig | None = None) -> list:
    return modal_exchange_health(case, model_rig, "displacement")[0]


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
