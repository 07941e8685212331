"""The record an impact test's FRF is built on: band of interest, pre-trigger, hammer full scale, decay rate.

``gvt frf`` (the offline study) and the live FRF lane of a session make the same choices from the same rig
and sample rate, so the choices live here, below both (docs/frf.md, "Record and window").
"""

from __future__ import annotations

import numpy as np

from analysis.model.rig import Rig

PRE_TRIGGER_S = 0.01  # s of record before the hit's index: the pulse's rising edge is before the trigger
DEFAULT_BAND_HZ = 1000.0  # the band of interest when the sample rate allows it (default_band)


def default_band(fs: float) -> float:
    """The 1000 Hz band, or fs / 2.56 when that is lower: the usable band below Nyquist (an analyser's
    anti-alias convention). Why: at 2048 Hz a 1000 Hz band is above what the hammer spectrum can show — every
    hit was refused as 'bandwidth below band: -10 dB at 827 Hz < 1000 Hz'."""
    return min(DEFAULT_BAND_HZ, fs / 2.56)


def lowest_decay_rate(rig: Rig) -> float:
    """``zeta_1 omega_1`` (1/s) of the rig's lowest elastic mode (its linear model and modal damping)."""
    om = rig.modes.omega
    c = rig.structure.damping.modal_coefficients(om)
    k = int(np.flatnonzero(om > 0)[0])
    return float(c[k] / 2.0)


def force_full_scale(rig: Rig) -> float:
    """The hammer channel's full scale, N: its sensor range or the ADC's range, whichever is lower."""
    h = rig.hammer.props
    adc = rig.config.daq.input_range_volts / (h.sensitivity_mv_per_unit * 1e-3)
    return min(adc, h.range) if h.range else adc
