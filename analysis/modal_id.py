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
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from analysis.errors import BadInput
from analysis.lsfd import LSFDResult, lsfd, shapes_from_constants
from analysis.mac import mac, mpc, mpd
from analysis.plscf import PoleSet, plscf, pole_freq_hz, pole_zeta

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


def _longest_run(orders: np.ndarray) -> int:
    u = np.unique(orders)
    if u.size == 0:
        return 0
    breaks = np.flatnonzero(np.diff(u) != 1)
    edges = np.concatenate([[-1], breaks, [u.size - 1]])
    return int(np.max(np.diff(edges)))


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
    return [np.array(p) for p in parts]


def auto_select(table: StabTable, n_consecutive: int = 6, cluster_tol: float = 0.0025) -> np.ndarray:
    """Indices into ``table`` of the selected poles, by the rule in the module docstring, ascending frequency."""
    stable = np.flatnonzero(table.status == LABELS.index("s"))
    freq = table.freq_hz
    stable = stable[np.argsort(freq[stable])]
    if stable.size == 0:
        return np.zeros(0, dtype=int)
    cut = np.flatnonzero(np.diff(freq[stable]) > cluster_tol * freq[stable][1:]) + 1
    chosen = []
    for cluster in np.split(stable, cut):
        for part in _split_close(cluster, table.order, freq):
            if part.size and _longest_run(table.order[part]) >= n_consecutive:
                chosen.append(part[np.argsort(freq[part])][part.size // 2])
    return np.array(sorted(chosen, key=lambda i: freq[i]), dtype=int)


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
    """Selected modes: ``freq_hz``, ``zeta`` (window damping removed), shapes ``(n_out, n)``, quality."""

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


def identify_arrays(
    freq: np.ndarray, H: np.ndarray, quantity: str, f_lo: float, f_hi: float, max_order: int = 60,
    crit: Criteria = Criteria(), targets: list[Target] | None = None, driving: list[int | None] | None = None,
    sigma_added: float = 0.0, n_consecutive: int = 6,
) -> ModalResult:
    """The whole chain on arrays: pLSCF to ``max_order``, stabilisation, auto or manual pick, LSFD."""
    if not np.isfinite(H).all():  # LAPACK would fail deep inside with "illegal value"
        raise BadInput("modal identification: the FRFs hold NaN or inf (a response with no average?); leave it out")
    table = stabilisation(plscf(freq, H, f_lo, f_hi, max_order), crit)
    sel = auto_select(table, n_consecutive) if targets is None else select_targets(table, targets)
    if sel.size == 0:
        raise BadInput(f"no pole stable over {n_consecutive} orders in {f_lo:g}..{f_hi:g} Hz; pick poles from a file")
    return modes_from_poles(freq, H, quantity, table, sel, f_lo, f_hi, driving, sigma_added)


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
    """For each identified mode, the FE mode of highest MAC and that MAC."""
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
    "select_targets",
    "stabilisation",
]
