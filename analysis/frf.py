"""Frequency response functions from impact-hammer hits: H1, H2, Hv, coherence, windows (issue 20).

The estimators are the textbook ones (Bendat & Piersol, *Random Data*, 4th ed., ch. 9; Ewins, *Modal
Testing*, 2nd ed., §3.9; Shin & Hammond, *Fundamentals of Signal Processing*, ch. 9):

* ``H1 = Gfx / Gff``: unbiased by noise on the response, biased low by noise on the force.
* ``H2 = Gxx / Gxf``: unbiased by noise on the force, biased high by noise on the response.
* ``Hv``: the total-least-squares estimate (equal noise weighting); for one reference the principal
  eigenvector of the 2x2 matrix ``[[Gff, Gfx*], [Gfx, Gxx]]``; lies between H1 and H2.
* ordinary coherence ``gamma^2 = |Gfx|^2 / (Gff Gxx) = H1 / H2``.

This module holds the :class:`FRFSet` container (the contract modal identification and UFF export are
written against) first; the estimators follow.
"""

from __future__ import annotations

import copy
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from analysis.errors import BadInput

KINDS = ("H1", "H2", "Hv")
QUANTITIES = {"accelerance": "m/s^2/N", "mobility": "m/s/N", "receptance": "m/N"}


@dataclass(frozen=True)
class FRFSet:
    """A set of FRFs ``H[o, r, k]`` = output ``o`` / reference ``r`` at ``freq[k]``.

    ``freq`` (n_f,) Hz; ``H`` complex (n_out, n_ref, n_f); ``coherence`` (n_out, n_ref, n_f) ordinary
    coherence in [0, 1]; ``outputs`` / ``references`` channel names; ``kind`` "H1" | "H2" | "Hv";
    ``quantity`` "accelerance" | "mobility" | "receptance"; ``units`` e.g. "m/s^2/N"; ``n_averages``
    (n_ref,) hits averaged per reference; ``window`` the windows used, with at least ``force`` (name of the
    force window), ``tau_s`` (exponential decay constant of the response window, s; ``None`` if none)
    and ``sigma_added`` (= 1/tau, 1/s: the decay rate every pole gained; see :func:`remove_window_damping`);
    ``quality`` how far to trust them, as ``gvt frf`` judged it (docs/frf.md, "Quality"): the force ``levels`` and
    which was averaged, the ``linearity`` check between levels, the coherence at each mode (``mode_coherence``),
    hammer ``pulse`` notes and the one-line ``warnings`` (empty: not judged, e.g. an older file).
    """

    freq: np.ndarray
    H: np.ndarray
    coherence: np.ndarray
    outputs: list[str]
    references: list[str]
    kind: str = "H1"
    quantity: str = "accelerance"
    units: str = "m/s^2/N"
    n_averages: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    window: dict = field(default_factory=dict)
    quality: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        n_out, n_ref, n_f = np.shape(self.H)
        if np.shape(self.freq) != (n_f,) or np.shape(self.coherence) != (n_out, n_ref, n_f):
            raise BadInput(
                f"FRFSet: freq {np.shape(self.freq)}, H {np.shape(self.H)} and coherence "
                f"{np.shape(self.coherence)} disagree in shape"
            )
        if len(self.outputs) != n_out or len(self.references) != n_ref:
            raise BadInput(
                f"FRFSet: {len(self.outputs)} outputs / {len(self.references)} references for H of shape {np.shape(self.H)}"
            )
        if self.kind not in KINDS or self.quantity not in QUANTITIES:
            raise BadInput(f"FRFSet: kind {self.kind!r} / quantity {self.quantity!r} unknown")

    def to_npz(self, path: str | Path) -> None:
        """Write to ``path`` (numpy ``.npz``; the metadata as one JSON string)."""
        meta = {
            "outputs": list(self.outputs),
            "references": list(self.references),
            "kind": self.kind,
            "quantity": self.quantity,
            "units": self.units,
            "window": self.window,
            "quality": self.quality,
        }
        with open(path, "wb") as fh:
            np.savez(
                fh,
                freq=self.freq,
                H=self.H,
                coherence=self.coherence,
                n_averages=np.asarray(self.n_averages, dtype=int),
                meta=np.array(json.dumps(meta)),
            )

    @classmethod
    def from_npz(cls, path: str | Path) -> FRFSet:
        """Read what :meth:`to_npz` wrote."""
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            return cls(freq=z["freq"], H=z["H"], coherence=z["coherence"], n_averages=z["n_averages"], **meta)

    def peaks(self, n: int = 6, f_min: float = 1.0) -> np.ndarray:
        """Indices of the ``n`` largest peaks of the mode indicator ``sum |H|`` over all pairs, ascending in frequency.

        Why the sum: a response near a node of a mode hardly shows that mode's peak; summed over every
        output the mode shows wherever it moves the structure (the CMIF idea of Shih et al. 1988, in its
        cheapest, single-reference form). Peaks below ``f_min`` Hz (DC, window leakage) are ignored.
        """
        from analysis.frf_levels import prominent_peaks  # scipy.signal.find_peaks' prominences, without its import

        mif = np.abs(self.H).sum(axis=(0, 1))
        idx, prom = prominent_peaks(np.where(self.freq >= f_min, mif, 0.0), top=n)
        if idx.size == 0:
            return idx
        keep = idx[np.argsort(prom, kind="stable")[::-1][:n]]
        return np.sort(keep)


# --- windows ---------------------------------------------------------------------------------------------
def exponential_window(n: int, fs: float, tau: float | None, t0: float = 0.0) -> np.ndarray:
    """``exp(-(t - t0) / tau)`` at ``t = k / fs``, ``k < n`` (ones when ``tau`` is None).

    Applied to the force *and* the responses it is exact, not approximate: ``w(t) (h * f)(t) =
    ((h w) * (f w))(t)`` for a pure exponential, so the windowed FRF is the FRF of the structure with
    every pole moved left by ``sigma_added = 1 / tau`` (added damping ``zeta_added = 1 / (omega tau)`` at
    ``omega``), whatever the force's shape (Fladung & Rost, *Application and correction of the exponential
    window for frequency response functions*, MSSP 11(1), 1997). The value above 1 before ``t0`` (the
    pre-trigger) is part of that identity.
    """
    if tau is None:
        return np.ones(n)
    if tau <= 0:
        raise BadInput(f"exponential window: tau must be positive, got {tau:g} s")
    return np.exp(-(np.arange(n) / fs - t0) / tau)


def force_window(force: np.ndarray, fs: float, level: float = 0.02, taper: float = 1.0) -> np.ndarray:
    """Transient (force) window for the hammer channel: 1 from the record start to the end of the pulse
    plus one pulse width, then a half-cosine taper one pulse width long, 0 after.

    Why: the force after the pulse is only the hammer's noise, and over a 2 s record it would add more
    noise to ``Gff`` than the pulse has signal at high frequency (Brandt, *Noise and Vibration Analysis*,
    2011, §13.6). The pulse is where ``|f|`` is above ``level`` of its peak around the peak; the taper
    (``taper`` pulse widths) avoids a step in the windowed force.
    """
    from analysis.hammer import pulse_span

    n = np.size(force)
    start, end = pulse_span(force, level)
    width = max(end - start, 1)
    flat_end = min(n, end + width)
    w = np.zeros(n)
    w[:flat_end] = 1.0
    m = min(n - flat_end, max(1, round(taper * width)))
    w[flat_end : flat_end + m] = 0.5 * (1.0 + np.cos(np.pi * (np.arange(m) + 1) / (m + 1)))
    return w


def choose_tau(sigma_lowest: float, record_s: float, end_level: float = 1e-3) -> float | None:
    """Decay constant of the exponential response window so that the lowest mode (decay rate
    ``sigma_lowest = zeta_1 omega_1``, 1/s) has fallen to ``end_level`` at the end of a ``record_s`` record.

    Why: a record that ends while the response still rings is a truncated transient; its DFT leaks,
    and the leakage error at a peak is of the order of the level left at the end. At ``end_level = 1e-3``
    (-60 dB) that error is below 0.1 %. ``None``: the structure alone decays that far, no window needed.
    The price is damping: every pole gets ``sigma_added = 1 / tau`` (see :func:`remove_window_damping`).
    """
    need = np.log(1.0 / end_level) / record_s  # total decay rate needed, 1/s
    if sigma_lowest >= need:
        return None
    return 1.0 / (need - sigma_lowest)


def window_info(force: str, tau: float | None, end_level: float | None = None) -> dict:
    """The ``FRFSet.window`` dict: force window name, ``tau_s``, ``sigma_added`` (1/s) and the rule."""
    return {"force": force, "tau_s": tau, "sigma_added": 0.0 if tau is None else 1.0 / tau, "end_level": end_level,
            "zeta_added": "sigma_added / omega (at omega, rad/s)"}  # fmt: skip


def remove_window_damping(freq_hz: np.ndarray, zeta: np.ndarray, sigma_added: float) -> tuple[np.ndarray, np.ndarray]:
    """Natural frequency (Hz) and damping ratio of poles identified on exponentially windowed FRFs, with the
    window's decay ``sigma_added = 1 / tau`` (1/s) taken out.

    The window moves each pole ``p = -sigma + j omega_d`` to ``p - sigma_added``: the damped frequency is
    unchanged, the decay rate grows by exactly ``sigma_added`` (:func:`exponential_window`). So
    ``sigma = zeta' omega_n' - sigma_added``, ``omega_d = omega_n' sqrt(1 - zeta'^2)``, and the structure's
    ``omega_n = |p|``, ``zeta = sigma / omega_n``.
    """
    wn_w = 2.0 * np.pi * np.asarray(freq_hz, dtype=float)
    zw = np.asarray(zeta, dtype=float)
    sigma = zw * wn_w - sigma_added
    wd = wn_w * np.sqrt(np.clip(1.0 - zw**2, 0.0, None))
    wn = np.hypot(sigma, wd)
    return wn / (2.0 * np.pi), sigma / wn


# --- spectra, estimators ---------------------------------------------------------------------------------
def h1(gff: np.ndarray, gfx: np.ndarray) -> np.ndarray:
    """``H1 = Gfx / Gff``: unbiased by output noise, low by input noise (Bendat & Piersol eq. 9.63)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return gfx / gff


def h2(gxx: np.ndarray, gfx: np.ndarray) -> np.ndarray:
    """``H2 = Gxx / Gxf``: unbiased by input noise, high by output noise (``|H2| = |H1| / gamma^2``)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return gxx / np.conj(gfx)


def hv(gff: np.ndarray, gxx: np.ndarray, gfx: np.ndarray) -> np.ndarray:
    """``Hv``, total least squares with equal noise on force and response (Shin & Hammond §9.3, eq. 9.68):
    ``(Gxx - Gff + sqrt((Gff - Gxx)^2 + 4 |Gfx|^2)) / (2 Gxf)``; between H1 and H2, scale dependent."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return (gxx - gff + np.sqrt((gff - gxx) ** 2 + 4.0 * np.abs(gfx) ** 2)) / (2.0 * np.conj(gfx))


def coherence(gff: np.ndarray, gxx: np.ndarray, gfx: np.ndarray) -> np.ndarray:
    """Ordinary coherence ``|Gfx|^2 / (Gff Gxx)`` in [0, 1] (0 where a spectrum is 0)."""
    den = gff * gxx
    with np.errstate(divide="ignore", invalid="ignore"):
        g = np.where(den > 0, (gfx.real**2 + gfx.imag**2) / den, 0.0)
    return np.clip(g, 0.0, 1.0)


_ORDER = {"receptance": 0, "mobility": 1, "accelerance": 2}
_FROM_CHANNEL = {"displacement": "receptance", "velocity": "mobility", "acceleration": "accelerance"}


def convert_quantity(H: np.ndarray, freq: np.ndarray, source: str, target: str) -> np.ndarray:
    """Accelerance / mobility / receptance: multiply by ``(j omega)^(target - source)`` in derivative order
    (divide by ``j omega`` per integration). The DC line of an integrated FRF is undefined (division by
    zero): it is set to 0 rather than inf so that sums and plots stay finite."""
    p = _ORDER[target] - _ORDER[source]
    if p == 0:
        return H
    jw = 2j * np.pi * np.asarray(freq, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = H * jw**p
    return np.where(np.isfinite(out), out, 0.0)


class FRFAccumulator:
    """Linear averaging of hits of one reference (force channel at one point) into auto/cross spectra.

    ``add(force, responses)`` windows one hit's record (force window times the exponential on the force,
    the exponential on every response: :func:`exponential_window` says why both) and adds ``|F|^2``,
    ``F* X`` and ``|X|^2`` to the sums; the sums are all H1, H2, Hv and coherence need, so the FRF after each
    hit costs one real FFT of the record, whatever the number of hits so far. ``frf`` returns an
    :class:`FRFSet`. A response the hit gate left out of a hit (clipped, dead: the hit record's
    ``excluded_channels``) is left out of that output's sums only (``use``): the force auto-spectrum is kept per
    output, so each output is the average of the hits it was good on (``counts``; an output with none is NaN),
    instead of a clipped accelerometer's record going into the average.
    Spectra are DFTs times ``1 / fs`` (N s, m/s) and sums, not densities: scale cancels in
    every estimator, and linear averaging of ``n`` hits is the sum divided by ``n`` in each spectrum.
    """

    def __init__(self, fs: float, n: int, outputs: list[str], reference: str, *, tau: float | None,
                 t0: float = 0.0, f_max: float | None = None, quantities: list[str] | None = None,
                 end_level: float | None = None) -> None:  # fmt: skip
        self.fs, self.n, self.outputs, self.reference = float(fs), int(n), list(outputs), reference
        freq = np.fft.rfftfreq(self.n, 1.0 / self.fs)
        self.n_f = int(np.searchsorted(freq, f_max, side="right")) if f_max is not None else freq.size
        self.freq = freq[: self.n_f]
        self.tau, self.end_level = tau, end_level
        self.exp = exponential_window(self.n, self.fs, tau, t0)
        self.quantities = quantities or ["acceleration"] * len(self.outputs)
        self.gff = np.zeros((len(self.outputs), self.n_f))  # per output: each averages only the hits it was good on
        self.gfx = np.zeros((len(self.outputs), self.n_f), dtype=complex)
        self.gxx = np.zeros((len(self.outputs), self.n_f))
        self.count = 0  # hits added
        self.counts = np.zeros(len(self.outputs), dtype=np.int64)  # hits per output

    def add(self, force: np.ndarray, responses: np.ndarray, use: np.ndarray | None = None) -> None:
        """Add one hit: ``force`` (n,) N, ``responses`` (n, n_out) in the channels' SI units; ``use`` (n_out,) bool:
        the outputs this hit counts for (default all; the others' sums are left as they were)."""
        if np.shape(force) != (self.n,) or np.shape(responses) != (self.n, len(self.outputs)):
            raise BadInput(f"FRF: a hit of {np.shape(force)} / {np.shape(responses)} samples, expected ({self.n},) / "
                           f"({self.n}, {len(self.outputs)})")  # fmt: skip
        from scipy import fft

        f = np.asarray(force, dtype=float)
        fw = f * (force_window(f, self.fs) * self.exp)
        x = np.asarray(responses, dtype=float).T * self.exp
        F = fft.rfft(fw)[: self.n_f] / self.fs
        X = fft.rfft(x, axis=-1, workers=-1)[:, : self.n_f] / self.fs
        m = np.ones(len(self.outputs), bool) if use is None else np.asarray(use, bool)
        self.gff[m] += F.real**2 + F.imag**2
        self.gfx[m] += np.conj(F) * X[m]
        self.gxx[m] += X.real[m] ** 2 + X.imag[m] ** 2
        self.count += 1
        self.counts += m

    def merge(self, other: FRFAccumulator) -> FRFAccumulator:
        """A new accumulator holding this one's hits and ``other``'s (same record, outputs and window): linear
        averaging is a sum, so the hits of several force levels average as if added one by one."""
        if (other.n, other.fs, other.outputs, other.n_f) != (self.n, self.fs, self.outputs, self.n_f):
            raise BadInput("FRF: accumulators of different records or outputs cannot be merged")
        m = copy.copy(self)
        m.gff, m.gfx, m.gxx = self.gff + other.gff, self.gfx + other.gfx, self.gxx + other.gxx
        m.count, m.counts = self.count + other.count, self.counts + other.counts
        return m

    def frf(self, kind: str = "H1", quantity: str = "accelerance") -> FRFSet:
        """The averaged FRFs so far as an :class:`FRFSet` (one reference)."""
        if self.count == 0:
            raise BadInput(f"FRF: no accepted hit for reference {self.reference}")
        est = {"H1": lambda: h1(self.gff, self.gfx), "H2": lambda: h2(self.gxx, self.gfx),
               "Hv": lambda: hv(self.gff, self.gxx, self.gfx)}  # fmt: skip
        if kind not in est:
            raise BadInput(f"FRF: estimator {kind!r} unknown; use one of {KINDS}")
        if quantity not in QUANTITIES:
            raise BadInput(f"FRF: quantity {quantity!r} unknown; use one of {sorted(QUANTITIES)}")
        with np.errstate(invalid="ignore", divide="ignore"):  # an output no hit was good on: 0/0, made NaN below
            H = est[kind]()
            coh = coherence(self.gff, self.gxx, self.gfx)
        H[self.counts == 0], coh[self.counts == 0] = np.nan, np.nan
        H = np.stack([convert_quantity(H[o], self.freq, _FROM_CHANNEL[q], quantity) for o, q in enumerate(self.quantities)])
        window = window_info("transient (pulse + 1 width, cosine taper)", self.tau, self.end_level)
        window["averages_per_output"] = self.counts.tolist()  # fewer than n_averages: excluded on some hits
        return FRFSet(freq=self.freq.copy(), H=H[:, None, :], coherence=coh[:, None, :],
                      outputs=list(self.outputs), references=[self.reference], kind=kind, quantity=quantity,
                      units=QUANTITIES[quantity], n_averages=np.array([self.count]), window=window)  # fmt: skip


def stack_references(sets: list[FRFSet]) -> FRFSet:
    """One FRFSet with every reference of ``sets`` (same outputs, frequencies, kind, quantity and window); the
    window's ``averages_per_output`` becomes the fewest over the references (what a fit using them all rests on)."""
    a = sets[0]
    for s in sets[1:]:
        if s.outputs != a.outputs or not np.array_equal(s.freq, a.freq) or (s.kind, s.quantity) != (a.kind, a.quantity):
            raise BadInput("FRF: references measured with different outputs, frequencies or estimators cannot be stacked")
    return FRFSet(freq=a.freq, H=np.concatenate([s.H for s in sets], axis=1),
                  coherence=np.concatenate([s.coherence for s in sets], axis=1), outputs=a.outputs,
                  references=[r for s in sets for r in s.references], kind=a.kind, quantity=a.quantity, units=a.units,
                  n_averages=np.concatenate([s.n_averages for s in sets]), window=_fewest_averages(sets),
                  quality=a.quality)  # fmt: skip


def _fewest_averages(sets: list[FRFSet]) -> dict:
    per = [s.window.get("averages_per_output") for s in sets]
    if len(sets) == 1 or any(p is None for p in per):
        return sets[0].window
    return {**sets[0].window, "averages_per_output": np.min(np.array(per), axis=0).tolist()}


__all__ = [
    "KINDS",
    "QUANTITIES",
    "FRFAccumulator",
    "FRFSet",
    "choose_tau",
    "coherence",
    "convert_quantity",
    "exponential_window",
    "force_window",
    "h1",
    "h2",
    "hv",
    "remove_window_damping",
    "stack_references",
    "window_info",
]  # fmt: skip
