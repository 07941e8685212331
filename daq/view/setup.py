"""What the view works out before it draws, without rerun: the session's :class:`ViewSetup` (streams, the rig's
sensors in model order and their positions, the hammer and the wavelet channel) and the RQ-FEP points.

Apart from the rerun logging (daq/view/logger.py, daq/view/recording.py, which re-export these) because
``gvt report`` draws the same figures with matplotlib: it needs these and neither rerun nor the detection
kernels (docs/decisions.md D108).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ViewSetup:
    """What the view needs to know of the session: streams, the rig's sensors in model order and their
    positions along the structure, the hammer channel and the channel to show as a wavelet spectrum."""

    streams: dict[str, tuple[str, ...]]
    sample_rate: float
    sensors: tuple[str, ...] = ()
    sensor_x: tuple[float, ...] = ()
    hammer: str | None = None
    wavelet_channel: str | None = None
    n_nnm: int = 4
    n_modes: int = 4
    f_min_hz: float = 5.0  # wavelet frequency range
    f_max_hz: float = 1000.0

    @classmethod
    def from_rig(
        cls, rig, streams: dict[str, tuple[str, ...]], sample_rate: float, wavelet_channel: str | None = None
    ) -> ViewSetup:
        from analysis.modal_basis import modal_basis
        from analysis.rig_model import RigModel

        try:
            m = RigModel.from_rig(rig)
            sensors, x = m.sensors, tuple(float(v) for v in (m.x if m.x is not None else np.arange(len(m.sensors))))
            f1 = float(modal_basis(m.M, m.K, 1).freqs_hz[0])  # the model's first mode (the analysis' own eq. 2.15 basis)
        except (ValueError, np.linalg.LinAlgError):
            sensors, x, f1 = tuple(p.name for p in rig.sensors), tuple(range(len(rig.sensors))), 10.0
        chosen = wavelet_channel or _driving_point(rig, sensors)
        return cls(
            streams=streams, sample_rate=sample_rate, sensors=sensors, sensor_x=x, hammer=rig.hammer.name,
            wavelet_channel=chosen, f_min_hz=max(1.0, 0.5 * f1), f_max_hz=min(0.25 * sample_rate, 2000.0),
        )  # fmt: skip


def _driving_point(rig, sensors: tuple[str, ...]) -> str | None:
    """The sensor on the hammer's DOF (the driving point), else the first sensor."""
    for p in rig.sensors:
        if p.dof == rig.hammer.dof:
            return p.name
    return sensors[0] if sensors else None


def rqfep_points(rq_rows: Sequence[dict], modal_t: np.ndarray, modal_e: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """RQ-FEP pairs (seed Ch. 4: RQ frequency against energy): each RQ window's frequencies against the total
    windowed modal energy of the modal window ending nearest to it. Returns t (n,), log10 E (n,), f (n, k)."""
    if not rq_rows or modal_t.size == 0:
        return np.zeros(0), np.zeros(0), np.zeros((0, 0))
    t = np.array([r["t_end_s"] for r in rq_rows], float)
    f = np.array([r["rq_hz"] for r in rq_rows], float)
    i = np.clip(np.searchsorted(modal_t, t), 0, modal_t.size - 1)
    j = np.clip(i - 1, 0, modal_t.size - 1)
    nearest = np.where(np.abs(modal_t[j] - t) < np.abs(modal_t[i] - t), j, i)
    e = modal_e[nearest]
    ok = e > 0
    return t[ok], np.log10(e[ok]), f[ok]
