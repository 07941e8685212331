"""Modal parameter estimation from an FRF matrix: stabilisation, pole selection, shapes (issue 20 item 4).

The chain is the one commercial tools run (Peeters et al., "The PolyMAX frequency-domain method",
*Shock and Vibration* 11, 2004, §3):

1. poles of every model order 1..60 by pLSCF (:mod:`analysis.plscf`);
2. **stabilisation**: each pole is compared with the nearest-frequency pole of the order below and labelled
   ``o`` new, ``f`` frequency stable (< 1 %), ``d`` frequency and damping stable (< 5 %), ``v`` frequency
   and participation vector stable (1 - MAC < 2 %) or ``s`` all three (the usual PolyMAX defaults);
3. **selection**, automatic (:func:`auto_select`, rule below) or from a TOML of target frequencies
   (:func:`load_targets` / :func:`select_targets`);
4. residues, residuals and shapes by LSFD (:mod:`analysis.lsfd`), MPC / MPD per mode and MAC against the
   rig's FE modes (:mod:`analysis.mac`).

Automatic rule (stated, so a reader can redo it by eye on the chart): take the ``s`` poles; sort by
frequency and cut into clusters wherever neighbours are more than ``cluster_tol`` (0.25 %) apart; a
cluster in which most orders hold k >= 2 poles is k close modes, split by rank within each order; a
cluster is a mode when its orders include a run of ``n_consecutive`` (6) consecutive orders; the mode's
pole is the cluster's median-frequency pole (a real pole of one order, so its participation vector is
consistent with it).

The exponential window of the FRF estimator adds a known decay rate ``sigma_added`` (1/s) to every pole
(Ewins §4.3.2; Fladung & Rost, *MSSP* 1997): the identified poles fit the windowed FRFs, the reported
frequency and damping are those of ``s + sigma_added``.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from analysis.errors import BadInput
from analysis.lsfd import LSFDResult, lsfd, shapes_from_constants
from analysis.mac import mac, mpc, mpd
from analysis.modal_select import (
    Rules,
    candidates,
    contributions,
    duplicate_groups,
    peak_flags,
    quality_flags,
    resolve_duplicates,
)
from analysis.plscf import PoleSet, one_blas_thread, plscf, pole_freq_hz, pole_zeta

LABELS = ("o", "f", "d", "v", "s")  # status codes 0..4


@dataclass(frozen=True)
class Criteria:
    """Stability tolerances between consecutive orders: relative frequency, relative damping, 1 - MAC(L)."""

    freq: float = 0.01
    damping: float = 0.05
    vector: float = 0.02


@dataclass(frozen=True)
class StabTable:
    """Every pole of every order, flat: ``order``, ``s`` (rad/s), ``L`` (n_ref, n) and ``status`` (0..4)."""

    order: np.ndarray
    s: np.ndarray
    L: np.ndarray
    status: np.ndarray

    @property
    def freq_hz(self) -> np.ndarray:
        return pole_freq_hz(self.s)

    @property
    def zeta(self) -> np.ndarray:
        return pole_zeta(self.s)


def _vec_mac(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """MAC between matching columns of ``a`` and ``b``."""
    num = np.abs(np.sum(a.conj() * b, axis=0)) ** 2
    return num / (np.sum(np.abs(a) ** 2, axis=0) * np.sum(np.abs(b) ** 2, axis=0))


def stabilisation(sets: list[PoleSet], crit: Criteria = Criteria()) -> StabTable:
    """Label each pole against the nearest-frequency pole of the previous order (the first order: all new)."""
    status = []
    for k, ps in enumerate(sets):
        st = np.zeros(ps.s.size, dtype=int)
        prev = sets[k - 1] if k > 0 else None
        if prev is not None and prev.s.size and ps.s.size:
            j = np.argmin(np.abs(ps.freq_hz[:, None] - prev.freq_hz[None, :]), axis=1)
            f_ok = np.abs(ps.freq_hz - prev.freq_hz[j]) <= crit.freq * ps.freq_hz
            d_ok = np.abs(ps.zeta - prev.zeta[j]) <= crit.damping * np.abs(ps.zeta)
            v_ok = 1.0 - _vec_mac(ps.L, prev.L[:, j]) <= crit.vector
            st = np.where(f_ok, 1 + d_ok + 2 * v_ok, 0)
        status.append(st)
    return StabTable(
        order=np.concatenate([np.full(ps.s.size, ps.order) for ps in sets]),
        s=np.concatenate([ps.s for ps in sets]),
        L=np.hstack([ps.L for ps in sets]),
        status=np.concatenate(status),
    )


def auto_select(table: StabTable, n_consecutive: int = 6, cluster_tol: float = 0.0025) -> np.ndarray:
    """Indices into ``table`` of the candidate poles (:func:`analysis.modal_select.candidates`: clusters of ``s``
    poles holding one in ``n_consecutive`` orders or more), ascending frequency; no spurious-pole check."""
    stable = np.flatnonzero(table.status == LABELS.index("s"))
    return candidates(table.freq_hz, table.order, stable, Rules(cluster_tol=cluster_tol, n_min=n_consecutive)).index


def stability_at(table: StabTable, poles: np.ndarray, tol: float = Rules.cluster_tol) -> np.ndarray:
    """Per pole (index into ``table``): how many orders hold an ``s`` pole within ``tol`` (relative) of it."""
    stable = table.status == LABELS.index("s")
    f = table.freq_hz
    return np.array([np.unique(table.order[stable & (np.abs(f / f[i] - 1) <= tol)]).size for i in poles], dtype=int)


@dataclass(frozen=True)
class Target:
    """A manual pick: the pole nearest ``freq_hz`` within ``tol`` (relative); ``order`` pins the model order."""

    freq_hz: float
    tol: float = 0.01
    order: int | None = None


def load_targets(path: str | Path) -> list[Target]:
    """``[[poles]] freq_hz = 68.4`` (``tol = 0.01`` relative, ``order = 40`` optional) from a TOML file."""
    try:
        data = tomllib.loads(Path(path).read_text())
        out = [Target(float(p["freq_hz"]), float(p.get("tol", 0.01)), p.get("order")) for p in data["poles"]]
    except FileNotFoundError:
        raise BadInput(f"{path}: no such pole file") from None
    except (tomllib.TOMLDecodeError, KeyError, TypeError, ValueError) as exc:
        raise BadInput(f"{path}: expected [[poles]] tables with freq_hz (and optional tol, order): {exc}") from None
    if not out or any(t.freq_hz <= 0 or t.tol <= 0 for t in out):
        raise BadInput(f"{path}: every [[poles]] needs freq_hz > 0 and tol > 0")
    return out


def select_targets(table: StabTable, targets: list[Target]) -> np.ndarray:
    """For each target, the median-frequency pole among the most stable ones within its tolerance."""
    freq = table.freq_hz
    chosen = []
    for t in targets:
        near = np.abs(freq - t.freq_hz) <= t.tol * t.freq_hz
        if t.order is not None:
            near &= table.order == t.order
        if not near.any():
            raise BadInput(f"no pole within {100 * t.tol:g} % of {t.freq_hz:g} Hz; widen tol or pick from the chart")
        best = np.flatnonzero(near & (table.status == table.status[near].max()))
        chosen.append(best[np.argsort(freq[best])][best.size // 2])
    return np.array(chosen, dtype=int)


@dataclass(frozen=True)
class ModalResult:
    """Selected modes: ``freq_hz``, ``zeta`` (window damping removed), shapes ``(n_out, n)``, and per mode its
    quality: MPC, MPD, ``stability`` (orders holding a stable pole there), ``contribution`` (its share of the
    FRFs at its own resonance) and ``flags`` (the checks of :func:`analysis.modal_select.quality_flags` it
    fails). ``rejected``: the poles left out as spurious or as duplicates, each with its figures and reason."""

    s: np.ndarray  # poles as fitted (with the window's damping)
    freq_hz: np.ndarray
    zeta: np.ndarray
    shapes: np.ndarray
    mpc: np.ndarray
    mpd: np.ndarray
    fit: LSFDResult
    table: StabTable
    selected: np.ndarray
    sigma_added: float = 0.0
    outputs: list[str] = field(default_factory=list)
    stability: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    contribution: np.ndarray = field(default_factory=lambda: np.zeros(0))
    flags: list[list[str]] = field(default_factory=list)
    rejected: list[dict] = field(default_factory=list)


def modes_from_poles(
    freq: np.ndarray, H: np.ndarray, quantity: str, table: StabTable, selected: np.ndarray,
    f_lo: float, f_hi: float, driving: list[int | None] | None = None, sigma_added: float = 0.0,
) -> ModalResult:
    """LSFD on the selected poles, shapes, MPC / MPD, and window-corrected frequency and damping."""
    s = table.s[selected]
    fit = lsfd(freq, H, s, quantity, f_lo, f_hi)
    shapes = shapes_from_constants(fit.modal_constants, driving)
    true = s + sigma_added
    return ModalResult(
        s=s, freq_hz=pole_freq_hz(true), zeta=pole_zeta(true), shapes=shapes,
        mpc=mpc(shapes), mpd=mpd(shapes), fit=fit, table=table, selected=np.asarray(selected), sigma_added=sigma_added,
    )


def _rejected_row(table: StabTable, i: int, stability: int, contribution: float, reason: str, sigma: float) -> dict:
    s = table.s[i] + sigma
    return {"freq_hz": float(pole_freq_hz(s)), "zeta": float(pole_zeta(s)), "stability": int(stability),
            "contribution": float(contribution), "reason": reason}  # fmt: skip


def pick_modes(freq, H, quantity, table: StabTable, f_lo, f_hi, rules: Rules | None = None, sigma_added: float = 0.0):
    """Steps 1-3 of :mod:`analysis.modal_select`: (selected pole indices, their stability counts, rejected rows)."""
    rules = rules or Rules()
    cand = candidates(table.freq_hz, table.order, np.flatnonzero(table.status == LABELS.index("s")), rules)
    if cand.index.size == 0:
        return cand.index, cand.stability, []
    share = contributions(freq, H, lsfd(freq, H, table.s[cand.index], quantity, f_lo, f_hi), quantity)
    ok = share >= rules.min_contribution
    rejected = [_rejected_row(table, i, n, c, f"spurious: explains {100 * c:.0f} % of the FRFs at its frequency", sigma_added)
                for i, n, c in zip(cand.index[~ok], cand.stability[~ok], share[~ok], strict=True)]  # fmt: skip
    cand, share = cand.take(ok), share[ok]
    if cand.index.size >= 2:
        fit = lsfd(freq, H, table.s[cand.index], quantity, f_lo, f_hi)
        kept, dup = resolve_duplicates(cand.scatter, duplicate_groups(table.freq_hz[cand.index], fit.modal_constants, rules))
        f_keep = pole_freq_hz(table.s[cand.index] + sigma_added)
        why = [f"duplicate of the mode at {f_keep[j]:.3f} Hz (same shape, scatters {100 * cand.scatter[i]:.2g} % "
               f"across orders against {100 * cand.scatter[j]:.2g} %)" for i, j in dup.items()]  # fmt: skip
        rejected += [_rejected_row(table, cand.index[i], cand.stability[i], share[i], w, sigma_added)
                     for i, w in zip(dup, why, strict=True)]  # fmt: skip
        cand = cand.take(kept)
    return cand.index, cand.stability, sorted(rejected, key=lambda r: r["freq_hz"])


def identify_arrays(
    freq: np.ndarray, H: np.ndarray, quantity: str, f_lo: float, f_hi: float, max_order: int = 60,
    crit: Criteria = Criteria(), targets: list[Target] | None = None, driving: list[int | None] | None = None,
    sigma_added: float = 0.0, n_consecutive: int = 6, rules: Rules | None = None,
) -> ModalResult:
    """The whole chain on arrays: pLSCF to ``max_order``, stabilisation, automatic pick (one pole per physical
    mode, :mod:`analysis.modal_select`) or manual pick, LSFD, and each mode's quality figures and flags."""
    if not np.isfinite(H).all():  # LAPACK would fail deep inside with "illegal value"
        raise BadInput("modal identification: the FRFs hold NaN or inf (a response with no average?); leave it out")
    rules = rules or Rules(n_min=n_consecutive)
    table = stabilisation(plscf(freq, H, f_lo, f_hi, max_order), crit)
    rejected: list[dict] = []
    with one_blas_thread():  # small least-squares fits: a second BLAS thread only spins (plscf.one_blas_thread)
        if targets is None:
            sel, count, rejected = pick_modes(freq, H, quantity, table, f_lo, f_hi, rules, sigma_added)
        else:
            sel = select_targets(table, targets)
            count = stability_at(table, sel, rules.cluster_tol)
        if sel.size == 0:
            why = f"; {len(rejected)} stable pole(s) left out as spurious" if rejected else ""
            raise BadInput(f"no pole stable over {rules.n_min} orders in {f_lo:g}..{f_hi:g} Hz{why}; "
                           "pick poles from a file (--poles)")  # fmt: skip
        res = modes_from_poles(freq, H, quantity, table, sel, f_lo, f_hi, driving, sigma_added)
        share = contributions(freq, H, res.fit, quantity)
    flags = quality_flags(res.zeta, res.mpc, count, H.shape[0], max_order, rules)
    flags = [a + b for a, b in zip(flags, peak_flags(freq, H, res.fit, share, rules), strict=True)]
    return replace(res, stability=count, contribution=share, flags=flags, rejected=rejected)


def identify(frfs, f_lo: float, f_hi: float, driving: dict[str, str] | None = None, **kw) -> ModalResult:
    """:func:`identify_arrays` on an :class:`analysis.frf.FRFSet`; ``driving`` maps reference -> output name.

    The exponential window's added decay (``frfs.window["sigma_added"]``, 1/s) is removed from the damping."""
    drive = None
    if driving:
        drive = [frfs.outputs.index(driving[r]) if r in driving else None for r in frfs.references]
    sigma = float(frfs.window.get("sigma_added") or 0.0)
    res = identify_arrays(frfs.freq, frfs.H, frfs.quantity, f_lo, f_hi, driving=drive, sigma_added=sigma, **kw)
    return ModalResult(**{**res.__dict__, "outputs": list(frfs.outputs)})


def fe_modes_at_sensors(rig, n_modes: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rig model's first ``n_modes``: frequency (Hz), damping ratio and mass-normalised shapes at the
    sensor DOFs ``(n_sensors, n_modes)`` -- what identified modes are checked against."""
    modes = rig.modes
    zeta = rig.structure.damping.ratios(len(modes))
    return modes.frequencies_hz[:n_modes], zeta[:n_modes], modes.shapes[rig.sensor_dofs, :n_modes]


def pair_with_fe(shapes: np.ndarray, fe_shapes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each identified mode, the FE mode of highest MAC and that MAC: a lookup, not a pairing (two modes may
    name the same FE mode, and frequency plays no part); pairing is :func:`analysis.modal_pairing.pair_modes`."""
    m = mac(shapes, fe_shapes)
    j = np.argmax(m, axis=1)
    return j, m[np.arange(m.shape[0]), j]


__all__ = [
    "LABELS",
    "Criteria",
    "ModalResult",
    "StabTable",
    "Target",
    "auto_select",
    "fe_modes_at_sensors",
    "identify",
    "identify_arrays",
    "load_targets",
    "modes_from_poles",
    "pair_with_fe",
    "pick_modes",
    "select_targets",
    "stabilisation",
    "stability_at",
]
