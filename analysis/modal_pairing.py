"""Identified modes paired with FE modes one to one, on shape and frequency (issue 29).

Why: pairing each identified mode with the FE mode of highest MAC (what ``gvt modal`` did) lets several
identified modes claim one FE mode and a 148 Hz pole claim a 1339 Hz FE mode because the few sensors cannot tell
their shapes apart (MAC 0.957 on the roving log). A correlation table a test engineer puts in a report pairs
each mode at most once and shows the frequency error beside the MAC (Allemang, *Sound and Vibration* 37(8),
2003: MAC alone is "necessary but not sufficient"; Friswell & Mottershead, *Finite Element Model Updating in
Structural Dynamics*, 1995, §7: pairs by MAC *and* frequency, one to one).

The rule (:class:`PairRules` holds the numbers): a pair is admissible when MAC >= ``mac_min`` (0.5) and
``|f / f_FE - 1| <= df_max`` (30 %); among admissible pairs the assignment (:func:`assign`, the minimum-weight
full bipartite matching) minimises the sum of ``(1 - MAC) + |f / f_FE - 1| / df_scale`` (``df_scale`` 10 %: a 10 %
frequency error weighs as much as a MAC of 0). A mode or FE mode left without an admissible partner is unpaired;
a pair past ``df_warn`` (5 %) or below ``mac_warn`` (0.8) is paired but warned about.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from analysis.mac import mac


@dataclass(frozen=True)
class PairRules:
    mac_min: float = 0.5
    df_max: float = 0.30
    df_scale: float = 0.10
    df_warn: float = 0.05
    mac_warn: float = 0.8


@dataclass(frozen=True)
class Pairing:
    """``fe[i]``: the FE mode (0-based) paired with identified mode ``i``, or -1; ``mac``/``df`` of each pair (NaN when
    unpaired). ``nearest[i]``/``nearest_mac[i]``: the FE mode of highest MAC, paired or not (what explains an
    unpaired mode). ``mac_matrix`` (n_id, n_fe)."""

    fe: np.ndarray
    mac: np.ndarray
    df: np.ndarray
    nearest: np.ndarray
    nearest_mac: np.ndarray
    mac_matrix: np.ndarray

    def unpaired_fe(self, n_fe: int) -> list[int]:
        return sorted(set(range(n_fe)) - set(self.fe[self.fe >= 0].tolist()))


def assign(cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns of the minimum-cost one-to-one assignment of a dense ``cost`` matrix (min(n, m) pairs,
    rows ascending): what ``scipy.optimize.linear_sum_assignment`` returns (tests/test_modal_quality.py compares
    the costs), by scipy.sparse.csgraph's LAPJVsp on the complete bipartite graph.

    Why not scipy.optimize: importing it costs ~120 ms, 12 % of a whole `gvt modal` on the demo log
    (bench/bench_quality.py); csgraph costs ~20 ms after scipy.linalg, which identification loads anyway. The
    costs are shifted by +1 so that no pair is a zero, which a sparse matrix would drop as "no edge"; a constant
    shift does not move the optimum of a matching of fixed size."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import min_weight_full_bipartite_matching

    c = np.asarray(cost, dtype=float)
    if c.size == 0:
        return np.empty(0, int), np.empty(0, int)
    if c.shape[0] <= c.shape[1]:
        cols = min_weight_full_bipartite_matching(csr_matrix(c - c.min() + 1.0))[1]
        return np.arange(c.shape[0]), cols
    rows = min_weight_full_bipartite_matching(csr_matrix(c.T - c.min() + 1.0))[1]
    order = np.argsort(rows)
    return rows[order], order


def pair_modes(f_id: np.ndarray, shapes: np.ndarray, f_fe: np.ndarray, fe_shapes: np.ndarray,
               rules: PairRules = PairRules()) -> Pairing:  # fmt: skip
    """One-to-one pairs of identified modes (``f_id``, ``shapes (n_dof, n_id)``) with FE modes (``f_fe``,
    ``fe_shapes (n_dof, n_fe)``), by the rule of the module docstring."""
    f_id, f_fe = np.asarray(f_id, dtype=float), np.asarray(f_fe, dtype=float)
    m = mac(shapes, fe_shapes) if f_id.size and f_fe.size else np.zeros((f_id.size, f_fe.size))
    df = f_id[:, None] / f_fe[None, :] - 1.0
    ok = (m >= rules.mac_min) & (np.abs(df) <= rules.df_max)
    cost = np.where(ok, (1.0 - m) + np.abs(df) / rules.df_scale, 1e6)  # inadmissible: dropped after the assignment
    fe = np.full(f_id.size, -1, dtype=int)
    if ok.any():
        rows, cols = assign(cost)
        keep = ok[rows, cols]
        fe[rows[keep]] = cols[keep]
    paired = fe >= 0
    idx = np.arange(f_id.size)
    pm = np.where(paired, m[idx, np.maximum(fe, 0)], np.nan) if f_fe.size else np.full(f_id.size, np.nan)
    pdf = np.where(paired, df[idx, np.maximum(fe, 0)], np.nan) if f_fe.size else np.full(f_id.size, np.nan)
    nearest = np.argmax(m, axis=1) if f_fe.size else np.full(f_id.size, -1)
    nmac = m[idx, nearest] if f_fe.size else np.full(f_id.size, np.nan)
    return Pairing(fe, pm, pdf, nearest, nmac, m)


def pair_flags(pairing: Pairing, f_id: np.ndarray, f_fe: np.ndarray, rules: PairRules = PairRules()
               ) -> tuple[list[list[str]], list[str]]:  # fmt: skip
    """Per identified mode, the pairing's flags (a phrase each: past ``df_warn``, below ``mac_warn``, unpaired with
    its nearest shape); and one line per FE mode below the top identified frequency that nothing pairs with."""
    flags: list[list[str]] = []
    for i, (k, m, d) in enumerate(zip(pairing.fe, pairing.mac, pairing.df, strict=True)):
        f = []
        if k >= 0 and abs(d) > rules.df_warn:
            f.append(f"Δf: {100 * d:+.1f} % from FE mode {k + 1} ({f_fe[k]:.2f} Hz), past {100 * rules.df_warn:g} %")
        if k >= 0 and m < rules.mac_warn:
            f.append(f"mac: {m:.2f} with FE mode {k + 1}, below {rules.mac_warn:g}")
        if k < 0:
            j = int(pairing.nearest[i])
            near = (f" (closest shape: FE mode {j + 1}, {f_fe[j]:.2f} Hz, MAC {pairing.nearest_mac[i]:.2f}, "
                    f"Δf {100 * (f_id[i] / f_fe[j] - 1):+.1f} %)") if j >= 0 else ""  # fmt: skip
            f.append(f"unpaired: no FE mode within Δf {100 * rules.df_max:g} % and MAC {rules.mac_min:g}{near}")
        flags.append(f)
    top = float(np.max(f_id)) if f_id.size else 0.0
    missing = [f"FE mode {k + 1} ({f_fe[k]:.2f} Hz) has no identified partner" for k in pairing.unpaired_fe(f_fe.size)
               if f_fe[k] <= top]  # fmt: skip
    return flags, missing


__all__ = ["PairRules", "Pairing", "pair_flags", "pair_modes"]
