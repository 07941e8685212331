"""``gvt frf LOG``: FRFs and coherence of a session's hits, each hit checked first (analysis/frf.py, hammer.py).

Per hit of ``/daq/hits``: the record ``[index - pre, index - pre + n)`` of the reference (force) channel
and the responses is read (``LogReader.read_stream``); the hit is refused if the log's gate refused it
(its reason is kept), if the record runs past the log, or by the hammer checks (overload, double hit,
bandwidth below the band: :func:`analysis.hammer.check_hit`); accepted hits are averaged linearly into an
:class:`~analysis.frf.FRFAccumulator`.

Record and window (docs/frf.md): ``n`` is the rig's record length, shortened to the smallest spacing
between hits so no record holds the next hit; the exponential response window's ``tau`` makes the rig's
lowest mode decay to ``end_level`` (1e-3, −60 dB) by the record's end (:func:`analysis.frf.choose_tau`),
or no window if the structure does that alone. Its added decay rate ``1 / tau`` goes with the result.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from analysis.errors import BadInput
from analysis.frf import FRFAccumulator, FRFSet, choose_tau
from analysis.hammer import HammerCheck, check_hit
from analysis.model.rig import Rig
from analysis.records import HITS_TOPIC, Hit
from daq.log.reader import LogReader, LogReadError

PRE_TRIGGER_S = 0.01  # s of record before the hit's index: the pulse's rising edge is before the trigger
QUANTITY_OF_UNIT = {"m/s^2": "acceleration", "m/s": "velocity", "m": "displacement", "N": "force"}


@dataclass
class FRFRun:
    """What ``gvt frf`` computed: the FRFs, every hit's verdict and the record/window choices."""

    log: str
    rig: str
    stream: str
    frf: FRFSet | None
    record_s: float
    pre_s: float
    tau_s: float | None
    band_hz: float
    hits: list[dict] = field(default_factory=list)  # hit, t_s, verdict, reason, checks
    spectra: list[tuple[int, np.ndarray, np.ndarray]] = field(default_factory=list)  # (hit, freq, |F|) for the plot


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


def _stream_for(reader: LogReader, reference: str) -> str:
    for name, info in reader.streams().items():
        if reference in info.channels:
            return name
    raise BadInput(f"{reader.path}: no stream has the reference channel {reference!r}; give it with --reference")


def _record_samples(rig: Rig, hits: Sequence[Hit], fs: float) -> int:
    n = round(rig.config.daq.record_length * fs)
    gaps = np.diff(sorted(h.index for h in hits))
    return int(min(n, gaps.min())) if gaps.size else n


def frf_from_log(path: str | Path, rig: Rig, *, reference: str | None = None, channels: Sequence[str] | None = None,
                 band_hz: float = 1000.0, kind: str = "H1", quantity: str = "accelerance", end_level: float = 1e-3,
                 progress: Callable[[float], None] | None = None) -> FRFRun:  # fmt: skip
    """FRFs of the accepted hits of the log at ``path`` (one reference: the force channel)."""
    try:
        reader = LogReader(path)
    except LogReadError as exc:
        raise BadInput(str(exc)) from None
    ref = reference or rig.hammer.name
    stream = _stream_for(reader, ref)
    info = reader.streams()[stream]
    outs = list(channels) if channels else [c for c, u in zip(info.channels, info.units, strict=True) if u != "N" and c != ref]
    bad = [c for c in outs if c not in info.channels]
    if bad or not outs:
        raise BadInput(f"{path}: stream {stream} has no channel(s) {bad or 'to respond'}; it has {info.channels}")
    units = dict(zip(info.channels, info.units, strict=True))
    quantities = [QUANTITY_OF_UNIT.get(units[c], "acceleration") for c in outs]
    hits = [Hit.from_json(h) for h in reader.json_messages(HITS_TOPIC)]
    if not hits:
        raise BadInput(f"{path}: the log has no hits ({HITS_TOPIC}); record or simulate a session with hits")
    fs = info.sample_rate
    n, pre = _record_samples(rig, hits, fs), round(PRE_TRIGGER_S * fs)
    tau = choose_tau(lowest_decay_rate(rig), n / fs, end_level)
    acc = FRFAccumulator(fs, n, outs, ref, tau=tau, t0=pre / fs, f_max=band_hz, quantities=quantities, end_level=end_level)
    run = FRFRun(str(path), rig.name, stream, None, n / fs, pre / fs, tau, band_hz)
    cols = [ref, *outs]
    for k, hit in enumerate(hits):
        verdict, reason, chk = _judge(reader, stream, cols, hit, n, pre, fs, band_hz, force_full_scale(rig), run)
        if verdict == "accepted":
            d = chk[1]
            acc.add(d[:, 0], d[:, 1:], use=[o not in (hit.excluded_channels or ()) for o in outs])
        run.hits.append({"hit": hit.hit, "t_s": hit.t_s, "peak_force_N": hit.peak_force_N, "verdict": verdict,
                         "reason": reason, "checks": chk[0].as_dict() if chk[0] is not None else None})  # fmt: skip
        if progress:
            progress((k + 1) / len(hits))
    run.frf = acc.frf(kind, quantity) if acc.count else None
    return run


def _judge(reader: LogReader, stream: str, cols: list[str], hit: Hit, n: int, pre: int, fs: float, band: float,
           full_scale: float, run: FRFRun) -> tuple[str, str, tuple[HammerCheck | None, np.ndarray | None]]:  # fmt: skip
    """Verdict, reason and (checks, record) of one hit."""
    if hit.verdict != "accepted":
        return "refused", f"hit gate: {hit.reason or hit.verdict}", (None, None)
    i0 = hit.index - pre
    d = reader.read_stream(stream, cols, start=i0 / fs, end=(i0 + n) / fs, on_damage="skip")
    if d.data.shape[0] != n or d.gaps or d.damaged:
        return "refused", f"record incomplete: {d.data.shape[0]} of {n} samples (end of log, gap or damage)", (None, None)
    data = d.data.astype(float)
    chk = check_hit(data[:, 0], fs, band, full_scale)
    run.spectra.append((hit.hit, *_spectrum(data[:, 0], fs, band)))
    return chk.verdict, chk.reason, (chk, data)


def _spectrum(force: np.ndarray, fs: float, band: float) -> tuple[np.ndarray, np.ndarray]:
    from analysis.hammer import force_spectrum

    f, m = force_spectrum(force, fs)
    k = np.searchsorted(f, 2.0 * band)
    return f[:k], m[:k]


def peak_rows(frf: FRFSet, n_peaks: int = 6) -> list[dict]:
    """Per peak of the mode indicator (:meth:`FRFSet.peaks`) and response: frequency, |H|, phase, coherence."""
    rows = []
    for k in frf.peaks(n_peaks):
        for o, name in enumerate(frf.outputs):
            h = frf.H[o, 0, k]
            rows.append({"freq_hz": float(frf.freq[k]), "response": name, "mag": float(abs(h)),
                         "phase_deg": float(np.degrees(np.angle(h))), "coherence": float(frf.coherence[o, 0, k])})  # fmt: skip
    return rows


def summary(run: FRFRun, n_peaks: int = 6) -> dict:
    """The ``--json`` document."""
    f = run.frf
    return {
        "log": run.log, "rig": run.rig, "stream": run.stream, "band_hz": run.band_hz, "record_s": run.record_s,
        "pre_trigger_s": run.pre_s, "df_hz": 1.0 / run.record_s,
        "window": f.window if f is not None else {"tau_s": run.tau_s, "sigma_added": 1.0 / run.tau_s if run.tau_s else 0.0},
        "kind": f.kind if f else None, "quantity": f.quantity if f else None, "units": f.units if f else None,
        "reference": f.references[0] if f else None, "averages": int(f.n_averages[0]) if f else 0,
        "hits": run.hits, "peaks": peak_rows(f, n_peaks) if f is not None else [],
        # responses the hit gate left out of some hits (clipped, dead): averaged over the hits they were good on
        "fewer_averages": {o: int(c) for o, c in zip(f.outputs, f.window.get("averages_per_output", []), strict=False)
                           if c < f.n_averages[0]} if f is not None else {},
    }  # fmt: skip


def plot(run: FRFRun, path: Path, channel: str | None = None) -> None:
    """Magnitude, phase and coherence of the driving point (the output nearest the reference: the first
    of the rig's order if unknown) and ``channel``, and every checked hit's force spectrum, into a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    f = run.frf
    fig, ax = plt.subplots(4, 1, figsize=(9, 11), sharex=False)
    if f is not None:
        show = [o for o in dict.fromkeys([channel or f.outputs[-1], f.outputs[0]]) if o in f.outputs]
        for name in show:
            o = f.outputs.index(name)
            ax[0].semilogy(f.freq, np.abs(f.H[o, 0]), label=name)
            ax[1].plot(f.freq, np.degrees(np.angle(f.H[o, 0])), label=name)
            ax[2].plot(f.freq, f.coherence[o, 0], label=name)
        ax[0].set_ylabel(f"|{f.kind}| [{f.units}]")
        ax[0].set_title(f"{run.log}: {f.kind} {f.quantity}, {int(f.n_averages[0])} averages, reference {f.references[0]}")
        ax[1].set_ylabel("phase [deg]")
        ax[2].set_ylabel("coherence")
        ax[2].set_ylim(0, 1.05)
        for a in ax[:3]:
            a.legend(loc="best", fontsize=8)
            a.set_xlabel("frequency [Hz]")
    for hit, fr, mag in run.spectra:
        ax[3].plot(fr, 20 * np.log10(np.maximum(mag, 1e-300) / max(mag[0], 1e-300)), lw=0.8, label=f"hit {hit}")
    ax[3].axvline(run.band_hz, color="k", ls="--", lw=0.8)
    ax[3].axhline(-10, color="grey", ls=":", lw=0.8)
    ax[3].axhline(-20, color="grey", ls=":", lw=0.8)
    ax[3].set_ylim(-40, 5)
    ax[3].set_ylabel("force spectrum [dB re DC]")
    ax[3].set_xlabel("frequency [Hz]")
    fig.tight_layout()
    fig.savefig(path, format="png", dpi=90)
    plt.close(fig)


__all__ = ["FRFRun", "force_full_scale", "frf_from_log", "lowest_decay_rate", "peak_rows", "plot", "summary"]
