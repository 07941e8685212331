"""Per-hit hammer checks in the frequency domain: force spectrum, bandwidth, double-hit evidence, overload.

What a test engineer checks before a hit joins the average (Brandt, *Noise and Vibration Analysis*, 2011,
§13.6; Avitabile, *Modal Testing: A Practitioner's Guide*, 2017, ch. 4):

* **Bandwidth**: the force spectrum should not fall more than 10–20 dB over the band of interest, or the
  band's top is barely excited and the FRF there is noise. We report the −10 dB and −20 dB frequencies
  (first drop below that level re. the spectrum's DC value, the impulse) and refuse a hit whose −10 dB
  frequency lies below the band's top.
* **Double hit**: a second impact ``a`` times the first, ``dt`` later, multiplies the spectrum by
  ``|1 + a exp(-j omega dt)|``: ripple with notches every ``1 / dt`` Hz. A clean pulse's spectrum falls
  monotonically over its main lobe (a half-sine's first zero is at ``1.5 / T``, beyond its −20 dB point
  ``1.3 / T``, and its side lobes stay below −23 dB). So the evidence is the largest *rise* of the
  spectrum, in dB, over the lowest level below it in frequency, counted below ``1 / T`` for a main
  pulse ``T`` long and where the spectrum is above −20 dB (:func:`spectral_rise`): a clean simulated
  hit's rise is its noise, about 0.2 dB; a second impact of 20 % 2 ms later rises 2.2 dB, of 30 % 20 ms
  later 5.4 dB, of 50 % 3 ms later 8.9 dB. The threshold, ``RISE_DB`` = 2 dB, sits between (numbers: tests/test_frf.py).
  pyFRF's test (ripple of the PSD's own spectrum against a fixed ratio) flagged 20 of 20 clean simulated
  hits; this one leaves them alone.
* **Overload**: a sample at or above ``0.999`` of the channel's full scale (the sensor's range or the ADC's,
  whichever is lower): a clipped force underestimates the input at every frequency.
* **Pulse too short for the sample rate** (a note, not a refusal): a pulse over fewer than ``MIN_PULSE_SAMPLES``
  samples, or whose spectrum is still above −20 dB at the usable band's top ``fs / 2.56``, is not resolved: its
  peak is read low (a half-sine sampled ``k`` times over its width is read up to ``1 - cos(pi / (2 k))`` low:
  29 % at 2 samples, 4.9 % at 5) and its energy above the band aliases or is filtered away. The note names the
  rate that would do: ``MIN_PULSE_SAMPLES`` samples over the pulse, and ``2.56 x`` its −20 dB frequency
  (the pulse measured here, so after an anti-alias filter it is a lower bound).

Arrays in, verdict out; the log and the rig are read by ``daq/studies/frf.py``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

#: a sample at or above this fraction of full scale counts as clipped (as daq/hits.py's CLIP_FRACTION)
CLIP_FRACTION = 0.999
#: double-hit threshold: a rise of the force spectrum by this many dB (a second impact of ~20 % and up)
RISE_DB = 2.0
#: rises are counted only where the spectrum is above this level re. DC (a half-sine's side lobes: < -23 dB)
FLOOR_DB = -20.0
#: the force spectrum of the checks keeps this long after the main pulse (force_spectrum)
KEEP_S = 0.05
#: samples a hammer pulse needs (over its width at 2 % of its peak) to be resolved: its peak read within 5 %
MIN_PULSE_SAMPLES = 5
#: usable band = fs / this (an analyser's anti-alias convention; analysis/frf_setup.py default_band)
BAND_FACTOR = 2.56


def pulse_span(force: np.ndarray, level: float = 0.02) -> tuple[int, int]:
    """``[start, end)`` samples of the main pulse: the run of ``|f| >= level * peak`` around the peak."""
    f = np.abs(np.asarray(force, dtype=float))
    k = int(np.argmax(f))
    above = f >= level * f[k]
    end = k + int(np.argmin(above[k:])) if not above[k:].all() else f.size
    start = k + 1 - int(np.argmin(above[k::-1])) if not above[: k + 1].all() else 0
    return start, end


def force_spectrum(force: np.ndarray, fs: float, keep_s: float | None = KEEP_S) -> tuple[np.ndarray, np.ndarray]:
    """Frequencies (Hz) and ``|F|`` (N s: the DFT times ``1 / fs``) of one hit's force record: its median (the
    offset of a hammer channel at rest) removed, and zero from ``keep_s`` after the main pulse's end on.

    Why cut: after the pulse the hammer channel holds only noise, and over a 2 s record that noise rises
    the spectrum near the main lobe's edge enough to fake a 2 dB ripple (10 % rms noise, measured); a second
    impact later than ``keep_s`` (50 ms) is the time-domain gate's (daq/hits.py), not this check's.
    The record keeps its length, so the frequency resolution is the record's."""
    f = np.asarray(force, dtype=float)
    f = f - np.median(f)
    if keep_s is not None:
        f[pulse_span(f)[1] + round(keep_s * fs) :] = 0.0
    return np.fft.rfftfreq(f.size, 1.0 / fs), np.abs(np.fft.rfft(f)) / fs


def level_db(mag: np.ndarray) -> np.ndarray:
    """The spectrum in dB re. its DC value (the impulse)."""
    with np.errstate(divide="ignore"):
        return 20.0 * np.log10(np.maximum(mag, 1e-300) / max(mag[0], 1e-300))


def bandwidth(freq: np.ndarray, db: np.ndarray, drop_db: float) -> float:
    """The first frequency where the spectrum ``db`` (re. DC) falls below ``-drop_db``, linearly
    interpolated between bins; the last frequency if it never does."""
    below = np.flatnonzero(db < -drop_db)
    if below.size == 0:
        return float(freq[-1])
    k = int(below[0])
    if k == 0:
        return 0.0
    x0, x1, y0, y1 = freq[k - 1], freq[k], db[k - 1], db[k]
    return float(x0 + (x1 - x0) * (-drop_db - y0) / (y1 - y0))


def spectral_rise(freq: np.ndarray, db: np.ndarray, f_stop: float, floor_db: float = FLOOR_DB) -> tuple[float, float]:
    """Largest rise (dB) of the spectrum over the lowest level at a lower frequency, counted below ``f_stop``
    where the spectrum is above ``floor_db``, and the frequency of the notch it rises from (Hz).

    ``f_stop`` is ``1 / T`` for a main pulse ``T`` long: a single non-negative pulse's first zero is at or
    beyond it (rectangle ``1 / T``, clipped half-sine ~``1.3 / T``, half-sine ``1.5 / T``), so its spectrum
    falls there, while a second impact ``dt > T`` later has its first notch at ``1 / (2 dt)`` and its
    rise back by ``1 / dt``, both below ``f_stop``."""
    inside = freq <= f_stop
    run_min = np.minimum.accumulate(db)
    rise = np.where(inside & (db > floor_db), db - run_min, 0.0)
    k = int(np.argmax(rise))
    if rise[k] <= 0.0:
        return 0.0, float("nan")
    notch = int(np.argmin(db[: k + 1]))
    return float(rise[k]), float(freq[notch])


def clipped_samples(x: np.ndarray, full_scale: float, fraction: float = CLIP_FRACTION) -> int:
    """Samples at or above ``fraction`` of ``full_scale`` (the channel's range, SI units)."""
    return int(np.count_nonzero(np.abs(np.asarray(x)) >= fraction * full_scale))


@dataclass(frozen=True)
class HammerCheck:
    """One hit's hammer checks and the verdict they give, with the reason (``accepted`` / ``refused``)."""

    peak_N: float
    bw10_hz: float
    bw20_hz: float
    rise_db: float
    notch_hz: float
    clipped: int
    band_hz: float
    verdict: str
    reason: str
    pulse_samples: int = 0
    rate_needed_hz: float = float("nan")  # NaN: the pulse is resolved at this rate
    note: str = ""  # one line when the pulse is too short for the sample rate

    def as_dict(self) -> dict:
        return {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in asdict(self).items()}


def check_hit(force: np.ndarray, fs: float, band_hz: float, full_scale: float | None = None,
              rise_db: float = RISE_DB) -> HammerCheck:  # fmt: skip
    """All checks on one hit's force record ``force`` (N) against the band of interest ``[0, band_hz]``.

    Refused, each reason listed (order: overload, double hit, bandwidth): ``overload`` when a sample
    reached ``full_scale``; ``double hit`` when the spectrum rises by more than ``rise_db`` dB
    (:func:`spectral_rise`); ``bandwidth below band`` when the −10 dB frequency is below ``band_hz``.
    """
    freq, mag = force_spectrum(force, fs)
    db = level_db(mag)
    bw10, bw20 = bandwidth(freq, db, 10.0), bandwidth(freq, db, 20.0)
    i0, i1 = pulse_span(force)
    rise, notch = spectral_rise(freq, db, fs / max(i1 - i0, 1))
    clipped = 0 if full_scale is None else clipped_samples(force, full_scale)
    reasons = []
    if clipped:
        reasons.append(f"overload: force reached its full scale {full_scale:g} N on {clipped} samples")
    if rise > rise_db:
        reasons.append(f"double hit: force spectrum rises {rise:.1f} dB after a notch at {notch:.0f} Hz "
                       f"(second impact ~{1e3 / (2 * notch):.1f} ms later)")  # fmt: skip
    if bw10 < band_hz:
        reasons.append(f"bandwidth below band: -10 dB at {bw10:.0f} Hz < {band_hz:g} Hz (softer tip than the band needs)")
    need, note = pulse_resolution(i1 - i0, fs, bw20)
    return HammerCheck(
        peak_N=float(np.max(np.abs(force))), bw10_hz=bw10, bw20_hz=bw20, rise_db=rise, notch_hz=notch, clipped=clipped,
        band_hz=float(band_hz), verdict="refused" if reasons else "accepted", reason="; ".join(reasons) or "ok",
        pulse_samples=int(i1 - i0), rate_needed_hz=need, note=note,
    )  # fmt: skip


def pulse_resolution(samples: int, fs: float, bw20_hz: float) -> tuple[float, str]:
    """The sample rate a pulse ``samples`` long (at ``fs``) with its −20 dB point at ``bw20_hz`` needs, and a one-line
    note, when this rate does not resolve it (``(nan, "")`` when it does): fewer than ``MIN_PULSE_SAMPLES`` samples,
    or the spectrum above −20 dB at ``fs / 2.56``. A half-sine's −20 dB point is ``1.3 / T``: when the spectrum never
    gets there below Nyquist, that is the estimate from the pulse's width."""
    top = fs / BAND_FACTOR
    if samples >= MIN_PULSE_SAMPLES and bw20_hz <= top:
        return float("nan"), ""
    width_s = max(samples, 1) / fs
    bw = bw20_hz if bw20_hz < 0.5 * fs * 0.999 else 1.3 / width_s
    need = float(np.ceil(max(MIN_PULSE_SAMPLES / width_s, BAND_FACTOR * bw) / 1024.0) * 1024.0)
    note = (f"hammer pulse too short for {fs:g} Hz: {samples} samples ({1e3 * width_s:.2f} ms), force spectrum above "
            f"-20 dB up to {bw:.0f} Hz; its peak is read low and its content above {top:.0f} Hz is lost: sample at "
            f">= {need:g} Hz or use a softer tip")  # fmt: skip
    return need, note


__all__ = ["BAND_FACTOR", "CLIP_FRACTION", "FLOOR_DB", "KEEP_S", "MIN_PULSE_SAMPLES", "RISE_DB", "HammerCheck",
           "bandwidth", "check_hit", "clipped_samples", "force_spectrum", "level_db", "pulse_resolution", "pulse_span",
           "spectral_rise"]  # fmt: skip
