"""Coherence judged at every mode of an FRF set (issue 29, item 1).

Why per mode and not an average: the ordinary coherence is near 1 wherever the response is far above its noise,
which on an impact test is most of the band; an average over the band (or over the responses) hides the one
mode where it is 0.2. Test practice (Avitabile, *Modal Testing: A Practitioner's Guide*, 2017, ch. 4; Brandt,
*Noise and Vibration Analysis*, 2011, §13.7) reads it at the resonances, where a drop means force-level
dependence (nonlinearity, hits of different force averaged), leakage, double hits or too few averages, and
expects it above about 0.9 there. At an antiresonance, or at a mode's node, a low coherence is the noise floor
and says nothing about the test; so a response counts at a mode only where that mode shows in it: its
``|H|`` at the peak at least ``NODE_DB`` (−20 dB) below the largest response's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: the coherence a response should have at a mode's peak (test practice: ~0.9; below it the FRF's random error
#: with a handful of averages is tens of % at that line: Bendat & Piersol eq. 9.90, sqrt((1 - g2) / (2 n g2)))
COHERENCE_MIN = 0.9
#: responses more than this far below the strongest at a mode are at its node there: not judged
NODE_DB = -20.0


@dataclass(frozen=True)
class ModeCoherence:
    """One mode (peak) and reference: the coherence of every judged response at the peak line, the worst, and those
    below ``bound`` (names and values)."""

    freq_hz: float
    reference: str
    worst: float
    judged: int
    low: tuple[tuple[str, float], ...]
    bound: float

    @property
    def ok(self) -> bool:
        return not self.low

    def as_dict(self) -> dict:
        return {"freq_hz": self.freq_hz, "reference": self.reference, "worst": self.worst, "judged": self.judged,
                "low": [{"response": n, "coherence": c} for n, c in self.low], "bound": self.bound, "ok": self.ok}  # fmt: skip


def mode_coherence(coherence: np.ndarray, H: np.ndarray, freq: np.ndarray, peaks: np.ndarray, outputs: list[str],
                   references: list[str], bound: float = COHERENCE_MIN,
                   node_db: float = NODE_DB) -> list[ModeCoherence]:  # fmt: skip
    """Per peak line ``k`` of ``peaks`` and per reference: the coherence (``(n_out, n_ref, n_f)``) of the responses
    whose ``|H|`` there is within ``node_db`` of the largest (NaN pairs skipped), judged against ``bound``."""
    out = []
    floor = 10.0 ** (node_db / 20.0)
    for k in np.asarray(peaks, dtype=int):
        for r, ref in enumerate(references):
            mag, coh = np.abs(H[:, r, k]), coherence[:, r, k]
            ok = np.isfinite(mag) & np.isfinite(coh)
            if not ok.any():
                continue
            judged = ok & (mag >= floor * np.nanmax(mag[ok]))
            c = coh[judged]
            low = tuple((outputs[o], float(coh[o])) for o in np.flatnonzero(judged & (coh < bound)))
            out.append(ModeCoherence(float(freq[k]), ref, float(c.min()), int(judged.sum()), low, bound))
    return out


def coherence_warning(m: ModeCoherence, hint: str) -> str:
    """One line for a mode whose coherence is below its bound: where, which responses, and ``hint`` (what to do)."""
    names = [n for n, _ in m.low]
    vals = [c for _, c in m.low]
    who = ", ".join(names) if len(names) <= 4 else f"{names[0]}..{names[-1]} ({len(names)} of {m.judged} responses)"
    rng = f"{min(vals):.2f}" if len(vals) == 1 else f"{min(vals):.2f}-{max(vals):.2f}"
    return f"coherence {rng} < {m.bound:g} at the {m.freq_hz:.1f} Hz peak ({m.reference} -> {who}): {hint}"


__all__ = ["COHERENCE_MIN", "NODE_DB", "ModeCoherence", "coherence_warning", "mode_coherence"]
