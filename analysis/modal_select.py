"""One pole per physical mode (issue 29): candidates from the stabilisation chart, spurious poles left out,
duplicates merged, and the quality figures every mode carries.

Why this is more than "the stable poles": a stabilisation chart holds, beside the physical modes, poles the
estimator adds to fit noise, leakage, a record that still rings from the previous hit, or the distortion of a
nonlinear structure -- the *computational* poles of Peeters et al. (*Shock and Vibration* 11, 2004, §3) -- and
many of them are stable over a dozen orders. Stability alone does not separate them (measured on the roving
log of ``configs/sessions/sim_roving.toml``: a spurious pole at 63.3 Hz holds a stable pole in 23 orders, the
physical mode at 20.8 Hz in 20). What separates them is whether the FRFs show the mode: a physical mode
dominates the FRFs at its own resonance, a computational pole does not (it lives on the skirt of a real one, or
in the noise). The same data also show one physical mode fitted by two poles (two references, or a distorted
peak): their modal constants over all FRFs are parallel.

The rule, stated so a reader can redo it (:class:`Rules` holds the numbers):

1. **candidates**: the ``s`` poles (:mod:`analysis.modal_id`), sorted by frequency and cut into clusters at
   gaps > ``cluster_tol`` (0.25 %); a cluster in which most orders hold k >= 2 poles is split into k by rank
   within each order (close modes); a cluster is a candidate when ``n_min`` (6) orders hold one of its poles.
   Its pole is the cluster's median-frequency pole; its **stability count** the number of those orders.
2. **contribution**: LSFD with every candidate; a mode's contribution is ``||H_r(w)|| / ||H(w)||`` (Frobenius
   norm over all FRFs) at the line nearest its damped frequency, ``H_r`` its own term (pole and conjugate).
   A candidate below ``min_contribution`` (0.5: the mode explains less than half of what was measured at its
   own resonance) is **spurious**: left out, and listed with its figures.
3. **duplicates**: two remaining candidates within ``dup_freq`` (3 %) whose modal-constant vectors over all
   FRFs have MAC >= ``dup_mac`` (0.8; only with >= 3 FRFs, a MAC of fewer numbers says nothing) are one
   physical mode: the one whose cluster scatters least in frequency across the orders stays (on the roving
   log: 20.83 Hz, 0.23 % scatter, stays; 21.09 Hz, 1.3 %, the hardening spring's large-amplitude start, goes).
4. **flags** on the modes kept (they stay in the table, marked): ``stability`` (stable in fewer than
   ``stab_frac`` (20 %) of the orders), ``mpc`` (MPC < 0.9 with >= 3 responses: a proportionally damped
   structure has real modes, Pappa et al. 1993), ``damping`` (zeta <= 0, > 10 %, or > 5x the median of the
   modes kept: the window correction or the data went wrong), ``no peak`` (below: the data do not show it).
5. **the data show the mode** (:func:`peak_flags`, issue 31's "no spurious mode vouched for"): a pole can pass
   steps 1-3 and still stand where the measured FRFs have no peak -- measured hammer hits (pyFRF's) gave one in the
   antiresonance between two modes (856 Hz between 810 and 900 Hz) and one at the band's upper edge fitting the
   skirt of a peak just outside (3000 Hz, the peak at 3007.5 Hz). Two tests, either flags the mode ``no peak``:

   * **cancelled** (anywhere in the band): its share (step 2) is above ``max_contribution`` (3). At its own
     resonance a mode's term is in quadrature with its modal constant (``-j P``); another mode's term there has
     real part ``x`` times its imaginary part, ``x = |f_s - f| / (zeta_s f_s)`` (the distance in the neighbour's
     half-power half-widths), and only the imaginary part can cancel ``P``: ``|H| >= P x / sqrt(1 + x^2)``, so
     one neighbour raises the share to 1.4 at ``x = 1`` and to 3 only within ``x = 0.35`` (a sixth of its
     half-power band: modes no FRF separates). The antiresonance pole: share 9.6; every mode of the data sets in
     the tests: 0.5-1.1.
   * **peak outside the band** (a pole whose half-power band ``f -+ |Re s| / 2 pi`` crosses an end of the fitted
     band): no measured ``|H_ij|`` nor ``sum |H|`` has a local maximum (against the lines either side, the data
     past the band included) on a line of the band within that half-width (at least one line). The pole then
     fits the skirt of a resonance outside the band, which the constant upper (or the lower) residual cannot.
     Inside the band this test is not made: a real weak mode beside a stronger one whose modal constant has the
     other sign can show as a shoulder with no local maximum of ``|H|`` in a single FRF (a two-mode model: the
     weak mode 5 half-widths from a 5x stronger one keeps a share of 0.8 and no maximum of ``|H|`` within 2.5
     half-widths), and flagging it would be wrong.

   Both are flags (the mode stays, marked, its warning says why), not removals: the other modes' fit stays as it
   was.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np

from analysis.lsfd import LSFDResult, lsfd_basis
from analysis.mac import mac


@dataclass(frozen=True)
class Rules:
    """The numbers of the module docstring's rule."""

    cluster_tol: float = 0.0025
    n_min: int = 6
    min_contribution: float = 0.5
    dup_freq: float = 0.03
    dup_mac: float = 0.8
    stab_frac: float = 0.2
    mpc_min: float = 0.9
    zeta_max: float = 0.10
    zeta_ratio: float = 5.0
    max_contribution: float = 3.0


def _split_close(idx: np.ndarray, order: np.ndarray, freq: np.ndarray) -> list[np.ndarray]:
    """A cluster where most orders hold k >= 2 poles is k modes: split by frequency rank within each order."""
    counts = Counter(order[idx].tolist())
    k = Counter(counts.values()).most_common(1)[0][0]
    if k < 2:
        return [idx]
    parts: list[list[int]] = [[] for _ in range(k)]
    for o, n in counts.items():
        if n == k:
            members = idx[order[idx] == o]
            for rank, i in enumerate(members[np.argsort(freq[members])]):
                parts[rank].append(int(i))
    return [np.array(p, dtype=int) for p in parts]


@dataclass(frozen=True)
class Candidates:
    """Step 1's result, ascending frequency: ``index`` into the stabilisation table, ``stability`` (orders holding
    a pole of the cluster) and ``scatter`` (relative standard deviation of the cluster's frequencies)."""

    index: np.ndarray
    stability: np.ndarray
    scatter: np.ndarray

    def take(self, k) -> Candidates:
        return Candidates(self.index[k], self.stability[k], self.scatter[k])


def candidates(freq: np.ndarray, order: np.ndarray, stable: np.ndarray, rules: Rules = Rules()) -> Candidates:
    """Step 1: the candidate poles. ``freq``/``order`` are every pole's, ``stable`` the indices of the ``s`` poles."""
    stable = stable[np.argsort(freq[stable])]
    chosen, counts, spread = [], [], []
    cut = np.flatnonzero(np.diff(freq[stable]) > rules.cluster_tol * freq[stable][1:]) + 1 if stable.size else []
    for cluster in np.split(stable, cut) if stable.size else []:
        for part in _split_close(cluster, order, freq):
            n = np.unique(order[part]).size
            if n >= rules.n_min:
                chosen.append(int(part[np.argsort(freq[part])][part.size // 2]))
                counts.append(n)
                spread.append(float(np.std(freq[part]) / np.mean(freq[part])))
    k = np.argsort(freq[chosen]) if chosen else np.zeros(0, dtype=int)
    return Candidates(np.asarray(chosen, dtype=int)[k], np.asarray(counts, dtype=int)[k], np.asarray(spread, dtype=float)[k])


def contributions(freq: np.ndarray, H: np.ndarray, fit: LSFDResult, quantity: str) -> np.ndarray:
    """Step 2: each fitted mode's share of the measured FRFs at its own damped frequency (Frobenius norm over all
    FRFs; 1 for a mode that alone makes its peak, about 0 for a pole the data do not show)."""
    s = fit.s
    band = fit.band
    line = band[np.argmin(np.abs(freq[band][None, :] - s.imag[:, None] / (2 * np.pi)), axis=1)]
    out = np.empty(s.size)
    n = s.size
    for r in range(n):
        B = lsfd_basis(freq[[line[r]]], s, quantity, lower=False, upper=False)[0]  # (2 n,)
        term = fit.residues[..., r].real * B[r] + fit.residues[..., r].imag * B[n + r]
        meas = np.linalg.norm(H[:, :, line[r]])
        out[r] = np.linalg.norm(term) / meas if meas > 0 else 0.0
    return out


def duplicate_groups(f_hz: np.ndarray, constants: np.ndarray, rules: Rules = Rules()) -> list[list[int]]:
    """Step 3's groups: modes (indices) linked by "within ``dup_freq`` and MAC >= ``dup_mac``" (chains joined).

    ``constants`` ``(n_out, n_ref, n)``: the modal constants; with fewer than 3 FRFs no group is formed."""
    n = f_hz.size
    A = constants.reshape(-1, n)
    if A.shape[0] < 3 or n < 2:
        return []
    m = mac(A, A)
    near = np.abs(f_hz[:, None] / f_hz[None, :] - 1.0) <= rules.dup_freq
    link = near & (m >= rules.dup_mac) & ~np.eye(n, dtype=bool)
    groups, seen = [], set()
    for i in range(n):
        if i in seen or not link[i].any():
            continue
        stack, g = [i], set()
        while stack:
            j = stack.pop()
            if j not in g:
                g.add(j)
                stack.extend(np.flatnonzero(link[j]).tolist())
        seen |= g
        groups.append(sorted(g))
    return groups


def resolve_duplicates(scatter: np.ndarray, groups: list[list[int]]) -> tuple[np.ndarray, dict[int, int]]:
    """Step 3: in each group keep the member whose cluster scatters least in frequency across the model orders: a
    physical pole is the same pole at every order, one that fits distortion or noise moves with the order (the
    spread of a cluster is the quality measure of automated modal analysis: Reynders, Houbrechts & De Roeck,
    *MSSP* 29, 2012, §4). Returns the kept indices and, for each dropped one, the index it duplicates."""
    drop: dict[int, int] = {}
    for g in groups:
        best = g[int(np.argmin(scatter[g]))]
        drop.update({i: best for i in g if i != best})
    kept = np.array([i for i in range(scatter.size) if i not in drop], dtype=int)
    return kept, drop


def quality_flags(zeta: np.ndarray, mpc: np.ndarray, stability: np.ndarray, n_outputs: int, n_orders: int,
                  rules: Rules = Rules()) -> list[list[str]]:  # fmt: skip
    """Step 4: per mode, the checks it fails, each a short phrase the table prints."""
    med = float(np.median(zeta)) if zeta.size >= 3 else np.nan
    out = []
    for z, c, n in zip(zeta, mpc, stability, strict=True):
        f = []
        if n < max(rules.n_min, rules.stab_frac * n_orders):
            f.append(f"stability: stable in {int(n)} of {n_orders} orders")
        if n_outputs >= 3 and c < rules.mpc_min:
            f.append(f"mpc: {c:.2f} < {rules.mpc_min:g} (complex shape)")
        if z <= 0 or z > rules.zeta_max:
            f.append(f"damping: zeta {100 * z:.2f} % outside 0-{100 * rules.zeta_max:g} %")
        elif np.isfinite(med) and z > rules.zeta_ratio * med:
            f.append(f"damping: zeta {100 * z:.2f} % > {rules.zeta_ratio:g}x the median {100 * med:.2f} %")
        out.append(f)
    return out


def local_maxima(freq: np.ndarray, H: np.ndarray) -> np.ndarray:
    """Lines (bool, ``(n_f,)``) where some measured ``|H_ij|``, or ``sum |H|`` over the FRFs, is at least its two
    neighbours: where the data could hold a resonance. The first and last line never are (one neighbour only)."""
    A = np.abs(H).reshape(-1, freq.size)
    A = np.vstack([A, A.sum(axis=0)])
    out = np.zeros(freq.size, dtype=bool)
    if freq.size >= 3:
        mid = A[:, 1:-1]
        out[1:-1] = ((mid >= A[:, :-2]) & (mid >= A[:, 2:])).any(axis=0)
    return out


def peak_flags(freq: np.ndarray, H: np.ndarray, fit: LSFDResult, share: np.ndarray, rules: Rules = Rules()
               ) -> list[list[str]]:  # fmt: skip
    """Step 5: per fitted mode, the phrase saying why the measured FRFs do not show it (empty when they do).

    ``fit.s`` are the poles as fitted (the windowed FRFs' damping), ``share`` step 2's contributions."""
    peaks = local_maxima(freq, H)
    band = fit.band
    df = float(np.median(np.diff(freq[band]))) if band.size >= 2 else 0.0
    out = []
    for s, c in zip(fit.s, share, strict=True):
        f, half = s.imag / (2 * np.pi), max(-s.real / (2 * np.pi), df)
        lo, hi = freq[band[0]], freq[band[-1]]
        if c > rules.max_contribution:
            out.append([f"no peak: its own term is {c:.1f}x the measured FRFs at its frequency (cancelled by its "
                        "neighbours: an antiresonance, not a mode)"])  # fmt: skip
        elif (f + half > hi or f - half < lo) and not peaks[band[np.abs(freq[band] - f) <= half]].any():
            end = f"ends at {hi:.1f} Hz" if f + half > hi else f"starts at {lo:.1f} Hz"
            out.append([f"no peak: no measured FRF has a maximum within its half-power half-width ({half:.3g} Hz) "
                        f"inside the band, which {end}: it fits a resonance outside; widen the band"])  # fmt: skip
        else:
            out.append([])
    return out


__all__ = ["Candidates", "Rules", "candidates", "contributions", "duplicate_groups", "local_maxima", "peak_flags",
           "quality_flags", "resolve_duplicates"]  # fmt: skip
