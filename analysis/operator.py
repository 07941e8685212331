"""The streaming analysis operator: sample blocks in, per-window results and IR events out.

One object serves ``gvt record`` (a fan-out subscriber), ``gvt replay`` and ``gvt analyze`` (the log's
blocks, at full speed): streaming is the batch kernels applied to windows as they complete
(architecture.md), so live and replay give the same numbers when they see the same blocks. Two lanes
run on every block, both causal with state carried across blocks:

* **seed lane** (analysis/preprocess.py, analysis/pod.py; seed §4.3): acceleration → displacement
  (causal Butterworth high-passes, the seed's 18/10 Hz by default), windowed POD + RQ on the base grid
  (the RQ curves and the RQ-FEP) and on the shifted/stretched grids of analysis/rq_spikes.py (spikes
  that survive a change of window phase); the seed's literal spike rule on the base grid is kept as
  the named baseline (``seed_spike`` in each window result).
* **modal lane** (analysis/modal_filter.py, analysis/exchange.py): the modal filter onto the rig's
  Guyan modes, windowed modal energies and frequencies, energy-exchange IR events with their m:n,
  evidence scores and confidence.

Results go to a sink ``emit(topic, record)`` as typed records (analysis/records.py: ``RQWindow``,
``ModalWindow``, ``IREventRecord``, ``RQSpike``, ``AnalysisWarning``): ``/analysis/rq`` and ``/analysis/modal`` per window,
``/analysis/events`` per IR event, ``/analysis/rq_spikes`` per window-robust spike interval,
``/analysis/warnings`` for the seed's assumptions that do not hold. A gap in the stream restarts both
lanes at the first sample after it (filters and windows cannot bridge missing data); the restart is
emitted as a warning.
"""

from __future__ import annotations

import math
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import Protocol

import numba
import numpy as np

from analysis.exchange import (
    ExchangeDetector,
    ExchangeSettings,
    IREvent,
    ModalWindower,
    PendingEvent,
    WindowFeatures,
    band_noise_energy,
    with_rq_score,
)
from analysis.forked_worker import ForkedWorker, Pending, can_fork
from analysis.modal_filter import ModalBasis, ModalFilterSettings, ModalStateTracker, modal_basis
from analysis.preprocess import CausalPreprocessor, PreprocessSettings
from analysis.records import (
    IR_EVENTS_TOPIC,
    MODAL_TOPIC,
    RQ_SPIKES_TOPIC,
    RQ_TOPIC,
    WARNINGS_TOPIC,
    AnalysisWarning,
    IREventRecord,
    ModalWindow,
    Record,
    RQSpike,
    RQWindow,
)
from analysis.rig_model import RigModel
from analysis.rq_spikes import CausalSpikeRule, RobustSpikeSettings, robust_spike_intervals
from analysis.sensor_health import HealthGuard, HealthSettings
from analysis.symeig import sym_eig

#: ``emit(topic, record)``: a typed record of analysis/records.py (a read-only Mapping of its JSON keys)
Emit = Callable[[str, Record], None]


class BlockLike(Protocol):
    """What the operator reads of a block: where it starts on the stream's sample clock and its samples
    ``(n_samples, n_channels)``. ``drivers.blocks.SampleBlock`` is one; the analysis does not import the
    drivers (architecture.md: imports run one way), so any object with these two fields will do."""

    @property
    def first_index(self) -> int: ...

    @property
    def data(self) -> np.ndarray: ...


@dataclass(frozen=True)
class AnalysisSettings:
    #: RQ base grid and exchange windows; None: 0.45 / f1 of the rig's linear model — just under half a
    #: period of NNM1 at its lowest (L1371, method-detection §1.6), which gives the seed's 0.0216 s for
    #: beam_ch4_exp (f1 = 20.81 Hz)
    window_s: float | None = None
    n_keep: int = 4  # POMs kept per window (NNMs of interest)
    n_modes: int = 4  # linear modes in the modal filter
    preprocess: PreprocessSettings = field(default_factory=lambda: PreprocessSettings(mode="causal"))
    modal_filter: ModalFilterSettings = field(default_factory=ModalFilterSettings)
    exchange: ExchangeSettings = field(default_factory=ExchangeSettings)
    spikes: RobustSpikeSettings = field(default_factory=RobustSpikeSettings)
    input_level_n: float = 10.0  # hammer force above which a sample counts as input
    #: without a hammer channel (e.g. the hammer on another device): a window whose total modal energy is
    #: this multiple of the previous window's is an input. Free decay stays <= 1.05 on the evaluation grid's
    #: exact energies and <= 1.13 through the acceleration path; hits on a ringing beam gave >= 1.64
    #: (sim_two_devices session, docs/detection.md)
    input_jump: float = 1.5
    seed_lane: bool = True
    #: sensor health in front of the modal filter (analysis/sensor_health.py): bad channels leave it, with a
    #: warning; None: every sensor is trusted (the behaviour before issue 21)
    health: HealthSettings | None = field(default_factory=HealthSettings)

    def __post_init__(self) -> None:
        if (self.window_s is not None and self.window_s <= 0) or self.n_keep < 1 or self.n_modes < 1:
            raise ValueError("analysis: window_s > 0, n_keep >= 1 and n_modes >= 1 required")


def _per_sensor(values: tuple | None, model: RigModel) -> tuple | None:
    """A per-sensor tuple only if it has one value per sensor (a model cut down by hand keeps the checks it can)."""
    return values if values is not None and len(values) == len(model.sensors) else None


#: modes at or above this fraction of the sample rate are left out of the modal filter: fs / 2.56, the usable band
#: below Nyquist (the analyser's anti-alias convention, as daq/studies/frf.py's default band); each kept mode's phase
#: band-pass then lies below 0.45 fs (analysis/exchange.py phase_bands)
RESOLVABLE_FRACTION = 1 / 2.56


def resolvable_basis(model: RigModel, fs: float, n_modes: int) -> ModalBasis:
    """The first ``n_modes`` modes of the rig's model at its sensors, less those above ``RESOLVABLE_FRACTION`` x fs: at
    256 Hz beam_ch4_exp's modes 3-4 (194, 387 Hz) are above Nyquist, and their band-passes could not be built (the
    operator raised "Wn[0] must be less than Wn[1]"). The exchange detector needs modes 1 and 2: fewer is a ValueError
    that says which sample rate would do."""
    basis = modal_basis(model.M, model.K, n_modes)
    kept = int(np.count_nonzero(basis.freqs_hz < RESOLVABLE_FRACTION * fs))
    if kept >= basis.n_modes:
        return basis
    if kept < 2:
        need = float(basis.freqs_hz[1]) / RESOLVABLE_FRACTION
        raise ValueError(f"at {fs:g} Hz the rig's mode 2 ({basis.freqs_hz[1]:.1f} Hz) lies above fs/2.56 = "
                         f"{RESOLVABLE_FRACTION * fs:.1f} Hz; the modal analysis needs modes 1 and 2: "
                         f"sample at >= {need:.0f} Hz")  # fmt: skip
    return modal_basis(model.M, model.K, kept)


@dataclass
class OperatorStats:
    blocks: int = 0
    samples: int = 0
    rq_windows: int = 0
    modal_windows: int = 0
    events: int = 0
    restarts: int = 0
    latencies_s: list[float] = field(default_factory=list)  # per base-grid window: block arrival → result


#: POMs carrying less than this fraction of a window's variance are not NNM estimates (numerical noise
#: directions of noise-free data); they are never among the kept POMs.
MIN_POV_FRACTION = 1e-12


def rq_from_covariance(C: np.ndarray, M: np.ndarray, K: np.ndarray, n_keep: int) -> tuple[np.ndarray, np.ndarray]:
    """POD + RQ from window covariances ``C`` (k, n, n): the ``n_keep`` lowest RQ frequencies and their POV
    fractions, (k, n_keep) each.

    The POMs are the eigenvectors of the 1/N_t covariance (eq. 2.12 — the seed's own formulation, L251;
    the SVD of eq. 2.13 gives the same vectors, analysis.pod.pod): one symmetric eigenproblem per window, (k, n, n)
    at once, is far cheaper than batched SVDs of (k, N_t, n); solved by analysis/symeig.py (compiled, for small
    matrices: LAPACK's ``eigh`` up to rounding, in ~55 % of its time at 14 × 14, D131). RQ of every POM (eqs.
    2.17–2.18), sorted ascending (Ch4 L1251); POMs with a POV fraction below ``MIN_POV_FRACTION`` are never kept.
    """
    lam, V = sym_eig(C)
    lam = np.maximum(lam, 0.0)
    frac = lam / np.maximum(lam.sum(axis=1, keepdims=True), 1e-300)
    # eqs. 2.17–2.18 as analysis.pod.rq_hz, with matmul instead of einsum: the per-window hot path
    num = np.sum(V * np.matmul(K, V), axis=-2)
    den = np.sum(V * np.matmul(M, V), axis=-2)
    f = np.sqrt(np.maximum(num, 0.0) / den) / (2.0 * np.pi)
    f = np.where(frac >= MIN_POV_FRACTION, f, np.inf)
    order = np.argsort(f, axis=1, kind="stable")[:, :n_keep]
    return np.take_along_axis(f, order, axis=1), np.take_along_axis(frac, order, axis=1)


def window_rq(X: np.ndarray, M: np.ndarray, K: np.ndarray, n_keep: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`rq_from_covariance` of a stack of windows ``X`` (k, N_t, n_dof)."""
    Xc = X - X.mean(axis=1, keepdims=True)
    return rq_from_covariance(np.matmul(np.swapaxes(Xc, 1, 2), Xc) / X.shape[1], M, K, n_keep)


def window_covariances(buf: np.ndarray, windows: list[tuple[int, int]], edges: np.ndarray) -> np.ndarray:
    """1/N covariances of ``buf[a:b]`` for every ``(a, b)`` in ``windows`` (indices into ``buf``).

    The window grids overlap (4 offsets × 2 lengths), so each sample would enter ~10 products. Instead
    the span is cut at ``edges`` — every window edge of every grid, a fixed lattice — and each segment's
    ``Σx`` and ``Σxxᵀ`` are formed once; a window's covariance is ``(S2 − S1 S1ᵀ/N)/N`` with its
    segments' sums added in order. Because the lattice does not depend on how the stream was cut into
    blocks, live and replay add the same numbers in the same order (bit-identical results). The inputs are
    high-passed displacements with ~zero mean, so the one-pass form loses nothing that matters
    (tests/test_detection.py compares it with the two-pass SVD POD).

    The segment products stay library calls (``segᵀ seg``, BLAS ``syrk``): the POMs of the smallest POVs
    are ill-conditioned, and summing the same products in another order moves the 4th RQ frequency by
    ~2e-6 relative (docs/detection.md, speed). Everything else — ``Σx`` per segment, the in-order window
    sums, the formula — is one compiled pass doing the additions ``np.add.reduceat`` did, in its order
    (~2× less time for the whole function).
    """
    edges = np.asarray(edges, dtype=np.int64)
    buf = np.ascontiguousarray(buf, dtype=np.float64)
    if len(windows) == 0 or edges.size < 2:
        return np.empty((0, buf.shape[1], buf.shape[1]))
    seg_s2 = np.empty((edges.size - 1, buf.shape[1], buf.shape[1]))
    for i in range(edges.size - 1):
        seg = buf[edges[i] : edges[i + 1]]
        np.matmul(seg.T, seg, out=seg_s2[i])
    w = np.asarray(windows, dtype=np.int64).reshape(-1, 2)
    return _lattice_covariances(buf, edges, seg_s2, np.searchsorted(edges, w), (w[:, 1] - w[:, 0]).astype(float))


@numba.njit(cache=True, nogil=True)
def _pairwise_rows(a, lo, n, out, scratch):  # pragma: no cover - compiled
    """``out[c] = Σ a[lo:lo+n, c]`` for every column, each column summed as numpy's reductions sum floats
    (``pairwise_sum`` of numpy/_core/src/umath/loops_utils.h.src: sequential below 8 terms, 8 accumulators
    up to 128, halves above), so that the compiled sums equal the ``np.add.reduceat`` ones bit for bit.
    The columns are innermost (vectorised); ``scratch`` (≥ 8·log₂(n/128)+8 rows, a's columns) holds the
    accumulators."""
    ncol = a.shape[1]
    if n < 8:
        for c in range(ncol):
            out[c] = 0.0
        for i in range(n):
            for c in range(ncol):
                out[c] += a[lo + i, c]
        return
    if n <= 128:
        r = scratch[:8]
        for u in range(8):
            for c in range(ncol):
                r[u, c] = a[lo + u, c]
        i = 8
        while i < n - (n % 8):
            for u in range(8):
                for c in range(ncol):
                    r[u, c] += a[lo + i + u, c]
            i += 8
        for c in range(ncol):
            out[c] = ((r[0, c] + r[1, c]) + (r[2, c] + r[3, c])) + ((r[4, c] + r[5, c]) + (r[6, c] + r[7, c]))
        while i < n:
            for c in range(ncol):
                out[c] += a[lo + i, c]
            i += 1
        return
    n2 = n // 2
    n2 -= n2 % 8
    left = scratch[8]
    _pairwise_rows(a, lo, n2, left, scratch[9:])
    _pairwise_rows(a, lo + n2, n - n2, out, scratch[9:])
    for c in range(ncol):
        out[c] = left[c] + out[c]


@numba.njit(cache=True, nogil=True)
def _scratch_rows(n):  # pragma: no cover - compiled
    """Rows of scratch :func:`_pairwise_rows` needs for ``n`` terms: 8 accumulators plus 9 per halving."""
    rows = 8
    while n > 128:
        n -= n // 2 - (n // 2) % 8  # the larger (right) half recurses deepest
        rows += 9
    return rows


@numba.njit(cache=True, nogil=True)
def _lattice_covariances(buf, edges, seg_s2, seg_idx, n):  # pragma: no cover - compiled
    """:func:`window_covariances` after the segment products: ``Σx`` per segment, window ``w``'s segments
    ``[seg_idx[w, 0], seg_idx[w, 1])`` added up, each sum as ``np.add.reduceat`` forms it (first term plus
    the pairwise sum of the rest), then ``(S2 − S1 S1ᵀ/N)/N`` with ``N = n[w]``."""
    c = buf.shape[1]
    n_seg = edges.shape[0] - 1
    s1 = np.empty((n_seg, c))
    rest = np.empty(c)
    longest = max(np.max(edges[1:] - edges[:-1]), n_seg)
    scratch1 = np.empty((_scratch_rows(longest), c))
    for g in range(n_seg):
        _pairwise_rows(buf, edges[g] + 1, edges[g + 1] - edges[g] - 1, rest, scratch1)
        for i in range(c):
            s1[g, i] = buf[edges[g], i] + rest[i]
    s2 = seg_s2.reshape(n_seg, c * c)
    out = np.empty((seg_idx.shape[0], c, c))
    t1 = np.empty(c)
    t2 = np.empty(c * c)
    scratch2 = np.empty((_scratch_rows(n_seg), c * c))
    for w in range(seg_idx.shape[0]):
        a, b = seg_idx[w, 0], seg_idx[w, 1]
        nw = n[w]
        _pairwise_rows(s1, a + 1, b - a - 1, t1, scratch1)
        _pairwise_rows(s2, a + 1, b - a - 1, t2, scratch2)
        for i in range(c):
            t1[i] = s1[a, i] + t1[i]
        for i in range(c):
            for j in range(c):
                out[w, i, j] = (s2[a, i * c + j] + t2[i * c + j] - t1[i] * t1[j] / nw) / nw
    return out


def compiled_kernels() -> list:
    """The operator's cached numba kernels, its own and those of the modules it runs (analysis/jit_cache.py): what a
    cold cache compiles on the first block (~5 s), and a warm one loads in well under a second."""
    import analysis.exchange
    import analysis.modal_filter
    import analysis.preprocess
    import analysis.rq_spikes
    import analysis.sensor_health
    import analysis.symeig
    from analysis.jit_cache import kernels

    return kernels(sys.modules[__name__], analysis.exchange, analysis.modal_filter, analysis.preprocess,
                   analysis.rq_spikes, analysis.sensor_health, analysis.symeig)  # fmt: skip


_seed_kernels_loaded = False


def _warm_seed_kernels(fs: float, n_acc: int, s: AnalysisSettings) -> None:
    """Load the seed lane's compiled kernels into this process, once, with the argument types the lane passes them,
    before a forked seed worker starts: a child that loaded them itself would lose them when it ends, and each
    operator of a process (the bench's runs, a campaign's logs) would pay the load again (~10 ms a kernel)."""
    global _seed_kernels_loaded
    if _seed_kernels_loaded:
        return
    pre = CausalPreprocessor(fs, n_acc, replace(s.preprocess, causal_baseline_s=0.0))
    disp = pre.feed(np.zeros((8, n_acc)))[1]  # preprocess._causal_chain
    window_covariances(disp, [(0, 4), (2, 6)], np.array([0, 2, 4, 6, 8]))  # _lattice_covariances
    CausalSpikeRule(s.spikes).feed_many(np.ones((4, max(s.spikes.curves) + 1)))  # rq_spikes._spike_flags
    sym_eig(np.eye(n_acc)[None])  # symeig._sym_eig_stack
    _seed_kernels_loaded = True


#: without a hammer channel, an energy jump counts as an input only this far above the quietest window
#: seen: the noise floor's own window-to-window fluctuations exceed ×1.5 but never ×100
INPUT_OVER_FLOOR = 100.0

#: the drift check (assumption 10) starts this long after an input: the phase band-passes and the modal
#: high-pass need ~0.1 s to settle after the hammer pulse, and their start-up is not the structure's
DRIFT_SETTLE_S = 0.15


#: the interpreter's thread switch interval while a pipelined operator runs (the default is 5 ms). The seed lane's worker
#: gives up the GIL in every compiled kernel and LAPACK call and needs it back after each; with the main thread busy
#: in the modal lane's Python, each re-acquisition waited out the whole interval, and the pipelined replay was no
#: faster than the serial one (issue 30: 30x against 31x real time; 43x with 1 ms). Restored by ``close``.
PIPELINE_SWITCH_S = 0.001
_switch_lock = threading.Lock()
_switch_users: list = [0, None]  # pipelined operators running, the interval before the first


def _pipeline_switch(delta: int) -> None:
    """Count a pipelined operator in (+1) or out (-1): the first one in lowers the switch interval to
    :data:`PIPELINE_SWITCH_S`, the last one out restores the one it found."""
    with _switch_lock:
        if delta > 0 and _switch_users[0] == 0:
            _switch_users[1] = sys.getswitchinterval()
            sys.setswitchinterval(min(_switch_users[1], PIPELINE_SWITCH_S))
        _switch_users[0] += delta
        if delta < 0 and _switch_users[0] == 0:
            sys.setswitchinterval(_switch_users[1])


class _Grid:
    def __init__(self, offset: int, length: int, first: int, rule: CausalSpikeRule) -> None:
        self.offset, self.length = offset, length
        self.origin = first + offset  # the grid's lattice: origin + k·length
        self.next = self.origin
        self.rule = rule
        self.flagged: list[tuple[float, float]] = []


class AnalysisOperator:
    """Feed blocks (:class:`BlockLike`: ``first_index`` and ``data``) of one stream in index order; results go to
    ``emit``."""

    def __init__(
        self, model: RigModel, channels: tuple[str, ...], sample_rate: float, settings: AnalysisSettings | None = None,
        emit: Emit | None = None, pipelined: bool = False, seed_process: bool | None = None,
    ) -> None:  # fmt: skip
        """``pipelined``: run sensor health (with the line canceller) on one worker thread and the seed lane's
        numerics (preprocessing, covariances, ``eigh``, spike rules) on another, each a block ahead of this thread,
        which emits and runs the modal lane. The compiled kernels, numpy's array passes and LAPACK release the GIL, so
        batch work (``gvt analyze``, the bench) uses a second core; the emits and their order are those of the serial
        run, one feed later (``finish`` flushes). Live sessions stay serial: there each block's results should go out
        with it. ``seed_process``: the seed lane's worker is a forked process instead of a thread (analysis/forked_worker.py,
        D130: off the interpreter lock); None: where :func:`can_fork` says it is safe, at the first pipelined feed."""
        self.s = settings or AnalysisSettings()
        self.pipelined = pipelined
        if seed_process and not sys.platform.startswith("linux"):
            raise ValueError("seed_process: a forked seed-lane worker needs Linux")
        self._seed_process = seed_process
        self.model = model
        self.fs = float(sample_rate)
        missing = [c for c in model.sensors if c not in channels]
        if missing:
            raise ValueError(f"the stream lacks the rig's sensor channels {missing}")
        self._acc_cols = [channels.index(c) for c in model.sensors]
        # the sensors as one slice when they sit side by side in the stream (the usual layout, hammer first): a slice
        # and one conversion pass, where a list index gathers element by element (~3x the time a block)
        a, n_acc = (self._acc_cols[0] if self._acc_cols else 0), len(self._acc_cols)
        side_by_side = self._acc_cols == list(range(a, a + n_acc))
        self._acc_take: slice | list[int] = slice(a, a + n_acc) if side_by_side else self._acc_cols
        self._ham_col = channels.index(model.hammer) if model.hammer in channels else None
        self.basis: ModalBasis = resolvable_basis(model, self.fs, min(self.s.n_modes, len(model.sensors)))
        self._guard = (None if self.s.health is None else
                       HealthGuard(model.M, model.K, model.sensors, self.fs, self.basis.n_modes, self.s.health,
                                   _per_sensor(model.ranges, model), _per_sensor(model.sensitivities, model),
                                   model.nonlinear_sensors))  # fmt: skip
        self._mf_cols = list(range(len(model.sensors)))  # the sensors (model order) the modal filter uses
        self.window_s = self.s.window_s if self.s.window_s is not None else 0.45 / float(self.basis.freqs_hz[0])
        self.n_keep = min(self.s.n_keep, len(model.sensors))
        self.emit = emit or (lambda topic, obj: None)
        self.stats = OperatorStats()
        self.events: list[IREvent] = []
        self._base_len = max(2, round(self.window_s * self.fs))
        self._warned: set[str] = set()
        self._check_assumptions()
        self._next_index: int | None = None
        self._pool: ThreadPoolExecutor | None = None  # pipelined: the seed lane's worker thread ...
        self._seed_proc: ForkedWorker | None = None  # ... or process (``seed_process``) ...
        self._health_pool: ThreadPoolExecutor | None = None  # ... and sensor health's
        self._inflight: tuple[Future, float] | None = None
        self._ahead: tuple | None = None  # pipelined: (health future, block, input mask, arrival) not yet through the lanes

    # --- public -------------------------------------------------------------------------------
    def feed(self, block: BlockLike, t_arrival: float | None = None) -> None:
        """One block of the stream. ``t_arrival`` (``time.perf_counter()`` clock): when its first sample's block
        arrived, if the caller held it back (a lane that joins blocks into frames); latencies count from it."""
        t_arrival = time.perf_counter() if t_arrival is None else t_arrival
        n = int(block.data.shape[0])
        if self._next_index is None or block.first_index != self._next_index:
            if self._next_index is not None:
                self._finish_lanes()
                self.stats.restarts += 1
                self._warn("gap", f"data gap before sample {block.first_index}: analysis restarted after it", restart=True)
                if self._guard is not None:
                    self._guard.restart()
            self._start(block.first_index)
            if self._seed_proc is not None:  # the worker's copy of the seed lane restarts too; a failure there is raised
                self._seed_proc.submit("_start", block.first_index).result()  # here (its queue is empty after the flush)
        self._next_index = block.first_index + n
        self.stats.blocks += 1
        self.stats.samples += n
        # C order (a column selection is laid out column-major): every kernel downstream reads rows of channels
        acc = block.data[:, self._acc_take].astype(np.float64, order="C")
        inp = None
        if self._ham_col is not None:
            inp = np.abs(block.data[:, self._ham_col]) >= self.s.input_level_n
        if self.s.seed_lane and self.pipelined:
            if self._health_pool is None and self._seed_proc is None:
                self._start_workers(acc.nbytes)
            if self._seed_proc is not None:
                # two stages in two processes: this block's sensor health here, then its seed numerics to the worker
                # process, the previous block's seed results out, this block's modal lane here (the events' lock fits
                # go to the worker too). The emits and their order are the threads' below; ``finish`` flushes
                # (the cleaned block goes to the worker before sensor health judges it: the seed lane does not wait on
                # the judgments, which it does not use, so the worker starts sooner, first block included)
                acc = self._guard.clean(acc) if self._guard is not None else acc
                planned = self._seed_proc.submit("_seed_compute", acc)
                acc, switches = self._check_health(acc, inp, cleaned=True) if self._guard is not None else (acc, None)
                self._drain()
                self._inflight = (planned, t_arrival)
                self._modal_lane(acc, inp, switches)
                return
            # three stages, one block apart: sensor health (and the line canceller) of this block on one worker, while
            # this thread hands the previous block to the seed lane's worker, emits the block before's seed results
            # and runs the previous block's modal lane. The emits and their order are the serial run's (health
            # warnings k, seed k−1, modal k, …), each block's one feed later; ``finish`` flushes
            checked = None if self._guard is None else self._health_pool.submit(self._guard.feed_clean, acc, inp)
            behind, self._ahead = self._ahead, (checked, acc, inp, t_arrival)
            if behind is not None:
                self._lanes_behind(behind)
            return
        acc, switches = self._check_health(acc, inp) if self._guard is not None else (acc, None)
        self._drain()
        self._modal_lane(acc, inp, switches)
        if self.s.seed_lane:
            self._seed_emit(self._seed_compute(acc), t_arrival)

    def _lanes_behind(self, behind: tuple) -> None:
        """Pipelined: a block whose sensor health was checked on the health worker: its warnings, its seed numerics to
        the seed worker, the previous block's seed results out, its modal lane."""
        checked, acc, inp, t_arrival = behind
        switches = None
        if checked is not None:
            acc, switches = checked.result()
            self._health_warnings(switches)
        planned = self._pool.submit(self._seed_compute, acc)
        self._drain()
        self._inflight = (planned, t_arrival)
        self._modal_lane(acc, inp, switches)

    def _lock_submit(self, fn: Callable, *args) -> Future | Pending:
        """Where an event's phase-lock fit runs when pipelined: on the lighter side. With the seed lane's process and
        sensor health on, on whichever process has used less CPU since the fork (``ForkedWorker.balance``: the two
        sides are within a few per cent of each other, and which is heavier depends on the rig and the data; a fixed
        place left one side ~10 ms per 20 s idle, issue 30); the fit is the same computation either side, so the
        results do not depend on where it ran. Here at once without health (the modal lane alone is the lighter side:
        0.12 against the seed lane's ~0.2 s of CPU per 20 s); with the threads, on the health worker."""
        if self._seed_proc is None:
            return self._health_pool.submit(fn, *args)
        if self._guard is not None and self._seed_proc.balance() < 0:  # the worker has used less CPU: it takes the fit
            return self._seed_proc.submit(fn, *args)
        done: Future = Future()
        try:
            done.set_result(fn(*args))
        except Exception as exc:  # raised where the event is resolved, as from a worker
            done.set_exception(exc)
        return done

    def _start_workers(self, block_bytes: int) -> None:
        """Pipelined: the seed lane's worker process, a copy of this operator forked at the stream's first block
        (``seed_process``, analysis/forked_worker.py; its kernels loaded here first, so that the operators of one process
        do not each load them again in a child), or the seed lane's and sensor health's worker threads. The blocks cross
        to the process in two shared slots the size of the first (at least 1 MiB); a larger block goes through the pipe."""
        if self._seed_process or (self._seed_process is None and can_fork()):
            _warm_seed_kernels(self.fs, len(self._acc_cols), self.s)
            self._seed_proc = ForkedWorker(self, "gvt-seed-lane", slot_bytes=max(block_bytes, 1 << 20))
            return
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="gvt-seed-lane")
        self._health_pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="gvt-health")
        _pipeline_switch(+1)

    def _flush_ahead(self) -> None:
        """Pipelined: run the lanes of the block still on the health worker (end of stream, a gap)."""
        if self._ahead is not None:
            behind, self._ahead = self._ahead, None
            self._lanes_behind(behind)

    def _check_health(self, acc: np.ndarray, inp: np.ndarray | None, cleaned: bool = False) -> tuple[np.ndarray, list]:
        """Sensor health on the block before the modal lane sees it (analysis/sensor_health.py): a channel judged bad
        leaves the modal filter, whose basis is rebuilt on the rest with its filter state carried, at the stream
        sample where it was judged; a warning each, and a "blind" one for the sensor at a nonlinear element (L69).
        The seed lane keeps every sensor (its RQ needs the model's DOFs, assumption 7, L65). Stationary lines (mains hum)
        are removed from the block first, for both lanes (analysis/lines.py); the block returned is the cleaned one."""
        assert self._guard is not None
        acc, switches = self._guard.check(acc, inp) if cleaned else self._guard.feed_clean(acc, inp)
        self._health_warnings(switches)
        return acc, switches

    def _health_warnings(self, switches: list) -> None:
        for sw in switches:
            for kind, key, message in sw.warnings:
                self._warn(key, message, kind=kind)

    def _modal_lane(self, acc: np.ndarray, inp: np.ndarray | None, switches: list | None = None) -> None:
        if not np.isfinite(acc).all():
            acc = np.where(np.isfinite(acc), acc, 0.0)  # a non-finite channel leaves at its span's end: no NaN in the filter
        parts = [(0, acc.shape[0], None)] if not switches else self._guard.pieces(acc.shape[0], switches)
        for a, b, sw in parts:
            if b > a:
                x = acc[a:b] if len(self._mf_cols) == acc.shape[1] else acc[a:b, self._mf_cols]
                q, qd = self._tracker.feed(x)
                for w in self._windower.feed(q, qd, None if inp is None else inp[a:b]):
                    self._modal_window(w)
            if sw is not None and sw.lines:
                self._detector.clear_quiet()
            if sw is not None and sw.basis is not None:
                self.basis = sw.basis
                self._mf_cols = list(sw.keep)
                self._tracker.set_basis(sw.basis)
                self._windower.basis = sw.basis
                self._detector.set_noise_prior(self._noise_prior())

    def _drain(self) -> None:
        """Emit the seed results of the block the worker is computing (pipelined feeds), waiting for it."""
        if self._inflight is not None:
            planned, t_arrival = self._inflight
            self._inflight = None
            self._seed_emit(planned.result(), t_arrival)

    def finish(self) -> list[IREvent]:
        """End of stream: close open events, report robust spikes; returns every event of the run."""
        if self._next_index is not None:
            self._finish_lanes()
        self.close()
        return self.events

    def close(self) -> None:
        """Emit the seed results the seed worker still holds and stop the workers (if they were started); a later
        ``feed`` starts new ones. ``finish`` calls this after running every lane; called alone (a run that broke off),
        a block still with the health worker is dropped, not run, so a failure there is not raised a second time; nor is a
        seed worker process's death. With a seed worker process, the next ``feed`` starts the lanes afresh."""
        try:
            self._ahead = None
            if self._seed_proc is not None and self._seed_proc.died:
                self._inflight = None  # its worker process is gone, and that was raised once already
            self._drain()
        finally:
            if self._seed_proc is not None:  # every call was answered (or the worker died): it need not be waited for
                self._seed_proc.close(wait=False)
                self._seed_proc = None
                # the seed lane's state went with the worker (this copy never advanced): a later feed starts the lanes
                # afresh, as at a stream's first block, instead of forking a worker from stale state
                self._next_index = None
            if self._health_pool is not None:
                self._pool.shutdown(wait=True)
                self._health_pool.shutdown(wait=True)
                self._pool = self._health_pool = None
                _pipeline_switch(-1)

    # --- lanes --------------------------------------------------------------------------------
    def _start(self, first: int) -> None:
        fs, s = self.fs, self.s
        self._tracker = ModalStateTracker(self.basis, fs, s.modal_filter)
        ex = s.exchange if s.exchange.window_s == self.window_s else replace(s.exchange, window_s=self.window_s)
        self._ex_settings = ex
        self._windower = ModalWindower(self.basis, fs, round(ex.window_s * fs), max(1, round(ex.hop * fs)), first,
                                       energy_bandpass=ex.band_limited_energy)  # fmt: skip
        # pipelined: the phase-lock fit of a closing event (~2 ms) runs on the health worker while this thread goes on
        # with the modal lane; the event is resolved at the next settling, before anything reads it
        lock_submit = self._lock_submit if self.pipelined and self.s.seed_lane else None
        self._detector = ExchangeDetector(ex, self.model.damping, self.basis.n_modes, self._noise_prior(), lock_submit)
        self._prev_total: float | None = None
        self._min_total = np.inf  # lowest windowed modal energy so far: the noise floor once the rig was quiet
        self._f1_hist: deque[float] = deque(maxlen=7)
        self._last_input_s = -np.inf
        self._peak_e1 = 0.0
        self._pre = CausalPreprocessor(fs, len(self._acc_cols), s.preprocess)
        self._disp = np.zeros((0, len(self._acc_cols)))
        self._disp_start = first  # stream index of self._disp[0]
        self._disp_end = first
        self._grids = [
            _Grid(round(o * self._base_len), max(2, round(L * self._base_len)), first, CausalSpikeRule(s.spikes))
            for L in s.spikes.lengths
            for o in s.spikes.offsets
        ]
        self._base = self._grids[0]  # offset 0, length 1: the seed's grid (RQ curves, RQ-FEP)
        self._max_len = max(g.length for g in self._grids)
        self._pending: list[IREvent | PendingEvent] = []
        self._spikes_until = first / fs
        self._seed_rule = CausalSpikeRule(RobustSpikeSettings(offsets=(0.0,), lengths=(1.0,)))

    def _noise_prior(self) -> np.ndarray | None:
        """The band noise per mode that the sensors' declared noise puts through the modal filter now in use
        (:func:`band_noise_energy`); None where the rig declares none or the filter reads displacements."""
        noise = _per_sensor(self.model.noise_rms, self.model)
        mf = self.s.modal_filter
        if noise is None or mf.quantity != "acceleration":
            return None
        return band_noise_energy(self.basis, np.asarray(noise)[self._mf_cols], self.fs, mf.highpass_hz, mf.order)

    def _finish_lanes(self) -> None:
        self._flush_ahead()
        self._drain()
        if self.s.seed_lane:
            t = time.perf_counter()
            flushed = self._seed_proc.submit("_seed_compute", None).result() if self._seed_proc else self._seed_compute(None)
            self._seed_emit(flushed, t)
        for ev in self._detector.finish():
            self._event(ev)
        self._settle(float("inf"))

    def _modal_window(self, w: WindowFeatures) -> None:
        if self._ham_col is None:  # no hammer: an input is a jump of the total energy (with one, its channel says so)
            total = float((w.energy if w.energy_raw is None else w.energy_raw).sum())
            if (self._prev_total is not None and total > self.s.input_jump * self._prev_total
                    and total > INPUT_OVER_FLOOR * self._min_total):  # fmt: skip
                w = replace(w, input_active=True)
            self._prev_total = total
            self._min_total = min(self._min_total, total) if total > 0 else self._min_total
        if w.input_active:
            self._last_input_s = w.t_end_s
            self._f1_hist.clear()
        elif math.isfinite(self._last_input_s) and w.t_start_s - self._last_input_s > DRIFT_SETTLE_S:  # a hit's decay
            # the seed's "< 10 % frequency change within one half cycle" (assumption 10, L68), on NNM1's
            # measured frequency: medians of 5 windows (robust to one noisy phase estimate), two hops = one
            # window apart
            self._f1_hist.append(float(w.freq_hz[0]))
            if len(self._f1_hist) == self._f1_hist.maxlen and w.energy[0] > 1e-3 * self._peak_e1:
                h = list(self._f1_hist)
                old, new = sorted(h[:5])[2], sorted(h[2:])[2]  # medians of 5
                if old > 0 and abs(new - old) / old > 0.1:
                    self._warn("drift", f"NNM1's frequency moved {100 * abs(new - old) / old:.0f} % within one window at "
                                        f"{w.t_start_s:.3f} s: windows too long for the seed's assumption 10 (L68)")  # fmt: skip
        self._peak_e1 = max(self._peak_e1, float(w.energy[0]))
        self.stats.modal_windows += 1
        self.emit(MODAL_TOPIC, ModalWindow(w.index, w.start, w.stop, w.t_start_s, w.t_end_s, tuple(w.energy.tolist()),
                                           tuple(w.freq_hz.tolist()), w.input_active))  # fmt: skip
        for ev in self._detector.feed(w):
            self._event(ev)

    def _event(self, ev: IREvent | PendingEvent) -> None:
        """An event waits until every window grid has passed its end (+ one window), so its ``rq`` score
        sees the same windows whatever the block split; without the seed lane it goes out at once."""
        self._pending.append(ev)
        if not self.s.seed_lane:
            self._settle(float("inf"))

    def _settle(self, until: float) -> None:
        """Emit pending events and window-robust spike intervals that lie wholly before ``until`` (s):
        every grid has computed all windows that overlap them."""
        if any(isinstance(ev, PendingEvent) for ev in self._pending):  # the serial run's pending list, in its order
            self._pending = [x for ev in self._pending for x in (ev.resolve() if isinstance(ev, PendingEvent) else [ev])]
        keep = []
        for ev in self._pending:
            lo, hi = ev.start_s - self.window_s, ev.end_s + self.window_s
            if hi > until:
                keep.append(ev)
                continue
            votes = [any(t1 >= lo and t0 <= hi for t0, t1 in g.flagged) for g in self._grids] if self.s.seed_lane else []
            ev = with_rq_score(ev, float(np.mean(votes)) if votes else 0.0, self._ex_settings.weights)
            self.events.append(ev)
            self.stats.events += 1
            self.emit(IR_EVENTS_TOPIC, IREventRecord.of(len(self.events) - 1, ev))  # a typed record through to the log
        self._pending = keep
        if not self.s.seed_lane:
            return
        res = 0.25 * self.window_s
        for t0, t1, frac in robust_spike_intervals([g.flagged for g in self._grids], self.s.spikes.min_fraction, res):
            if t1 < until - res and t0 >= self._spikes_until:
                self.emit(RQ_SPIKES_TOPIC, RQSpike(t0, t1, frac))
                self._spikes_until = t1 + res
        # bounded memory: forget flagged windows that no pending event and no future interval can touch
        horizon = min([until - 4 * self._max_len / self.fs, self._spikes_until - 4 * self._max_len / self.fs,
                       *[ev.start_s - 2 * self.window_s for ev in self._pending]])  # fmt: skip
        for g in self._grids:
            g.flagged = [w for w in g.flagged if w[1] >= horizon]

    def _seed_compute(self, acc: np.ndarray | None) -> tuple | None:
        """The seed lane's numerics for one block (``None``: flush the filters at the end of the stream):
        displacement, the windows every grid completes, their covariances, POD + RQ and spike flags. Touches only
        seed-lane state, so it may run on the worker (a thread, or a forked copy of this operator) while the modal lane
        runs (``feed``)."""
        if acc is not None:  # the block's displacement written after the kept tail: one buffer, no concatenation
            joined, new = self._pre.feed_after(self._disp, acc)
        else:
            flushed = self._pre.flush()[1]
            joined, new = np.concatenate([self._disp, flushed]), flushed.shape[0]
        if new == 0:
            return None
        self._disp = joined
        self._disp_end += new
        # grids by their index in self._grids (the result may cross to the parent process, whose grids are its own)
        ready: list[tuple[int, int]] = []
        runs: list[tuple[int, int, int]] = []  # each grid's windows of this feed: ready[i0:i1], in order
        for gi, g in enumerate(self._grids):
            i0 = len(ready)
            while g.next + g.length <= self._disp_end:
                ready.append((gi, g.next))
                g.next += g.length
            if len(ready) > i0:
                runs.append((gi, i0, len(ready)))
        if not ready:
            empty = np.empty((0, self.n_keep))
            return ready, runs, empty, empty, np.zeros(0, bool), np.zeros(0, bool), self._keep_disp()
        lo = min(st for _, st in ready)
        hi = max(st + self._grids[gi].length for gi, st in ready)
        # every grid's edges in [lo, hi]: origin + k·length with k = ceil((lo − origin) / length) onwards
        lattice = [np.arange(g.origin + max(0, -((g.origin - lo) // g.length)) * g.length, hi + 1, g.length)
                   for g in self._grids]  # fmt: skip
        edges = np.unique(np.concatenate(lattice)) - self._disp_start
        spans = [(st - self._disp_start, st - self._disp_start + self._grids[gi].length) for gi, st in ready]
        C = window_covariances(self._disp, spans, edges)
        f, pv = rq_from_covariance(C, self.model.M, self.model.K, self.n_keep)
        # the spike rules (compiled, seed-lane state only) see each grid's windows in order; the seed's literal rule the
        # base grid's
        flags, seed = np.zeros(len(ready), bool), np.zeros(0, bool)
        for gi, i0, i1 in runs:
            flags[i0:i1] = self._grids[gi].rule.feed_many(f[i0:i1])
            if gi == 0:  # self._base
                seed = self._seed_rule.feed_many(f[i0:i1])
        return ready, runs, f, pv, flags, seed, self._keep_disp()

    def _keep_disp(self) -> int:
        """Drop displacement no grid needs any more; returns the first stream index still needed (every grid
        has computed all windows that end before it)."""
        keep_from = min(g.next for g in self._grids)
        drop = keep_from - self._disp_start
        if drop > 0:
            self._disp = self._disp[drop:]
            self._disp_start = keep_from
        return keep_from

    def _seed_emit(self, planned: tuple | None, t_arrival: float) -> None:
        """The seed lane's bookkeeping on the caller's thread: flagged windows per grid, ``/analysis/rq`` emits, settling
        pending events up to the block's ``keep_from``."""
        if planned is None:
            return
        ready, runs, f, pv, flags, seed, keep_from = planned
        if ready:
            for gi, i0, i1 in runs:
                g = self._grids[gi]
                if g is not self._base:
                    for i in np.flatnonzero(flags[i0:i1]) + i0:
                        g.flagged.append((ready[i][1] / self.fs, (ready[i][1] + g.length) / self.fs))
                    continue
                rq_rows, pov_rows = f[i0:i1].tolist(), pv[i0:i1].tolist()
                for k in range(i1 - i0):
                    start = ready[i0 + k][1]
                    t0, t1 = start / self.fs, (start + g.length) / self.fs
                    if flags[i0 + k]:
                        g.flagged.append((t0, t1))
                    self.stats.rq_windows += 1
                    self.emit(RQ_TOPIC, RQWindow(start, start + g.length, t0, t1, tuple(rq_rows[k]), tuple(pov_rows[k]),
                                                 bool(seed[k])))  # fmt: skip
                    self.stats.latencies_s.append(time.perf_counter() - t_arrival)
                if len(self.stats.latencies_s) > 100_000:
                    del self.stats.latencies_s[:50_000]
        self._settle(keep_from / self.fs)  # every grid has computed all windows ending before this

    def _check_assumptions(self) -> None:
        if self.model.nonlinearity_measured is False:
            self._warn("nonlinearity", "no sensor sits on the nonlinear element's DOF: the seed's method assumes its location "
                                       "is measured (assumption 11, L69)")  # fmt: skip
        n_sens = len(self.model.sensors)
        if n_sens < 2 * self.n_keep:
            self._warn("sensors", f"{n_sens} sensors for {self.n_keep} NNMs of interest: the seed asks for at least twice "
                                  "as many sensors as modes (assumption 3, L61)")  # fmt: skip
        f1 = float(self.basis.freqs_hz[0])
        if self.window_s < 0.5 / (1.5 * f1):
            self._warn("window", f"window {self.window_s:g} s is shorter than half a period of NNM1 even 50 % above "
                                 f"its linear {f1:.1f} Hz (L1371)")  # fmt: skip

    def _warn(self, key: str, message: str, restart: bool = False, kind: str | None = None) -> None:
        if key in self._warned and not restart:
            return
        self._warned.add(key)
        self.emit(WARNINGS_TOPIC, AnalysisWarning(kind or key, message))
