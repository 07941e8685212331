"""The seed's force sweep (§4.2, L1215: P = logspace(1, 12, 1000), 1 s each) in bounded memory, on Dask.

Each run keeps only what an RQ-FEP needs — the mean and 1/n covariance of the output displacements
(POD of the whole record is the eigen-decomposition of that covariance, eq. 2.12–2.13) and the input
work (the energy axis, L1251) — so memory is O(n_out^2) per run however long the record. Chunks of
amplitudes run as Dask tasks: a local cluster by default, any scheduler address to scale out
(architecture.md, "Where it grows").

Per run it can also measure the mean frequencies of the two lowest *linear* modes from their phase
advance (``ModalProbe``): the modal filter of :mod:`analysis.modal_filter` (``q = ΦᵀM x`` with the Guyan
modes at the outputs, θ = atan2(−q̇/ω, q)) applied to every output sample, unwrapped, read at window
edges. The RQ uses the linear K, which has no term for the tip spring, so the RQ ratio f2/f1 is not the
NNMs' frequency ratio (docs/sweep.md, "Which m:n is the band?"); the phase advance is. The seed labels an
internal resonance by its slow phase m·θ1 − n·θ2 (L1296–L1298), i.e. by these frequencies. What is
kept per run is still O(n_out² + windows); the probe adds one reused buffer of one run's reduced record
(n_samples × n_basis, ~6 MB for 1 s of beam_ch4_sim) per worker, since the simulator's moment kernel has no
per-sample hook (``analysis.model._integrator``, not changed here).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from analysis.model._integrator import _integrate
from analysis.model.forces import Force
from analysis.model.simulate import ImpactSimulator, MomentResult

FloatArray = np.ndarray

#: windows (start_s, end_s) of the per-run modal phase advance; a negative end counts back from the record's
#: end. "whole": 0.05 s (after the 0.6 ms pulse and the modes' first swing) to 0.05 s before the end, as in
#: bench/eval_sweep_band.py; "early": 0.05–0.3 s, before most of the decay (0.3 s is the seed's end guard, L1426).
MODAL_WINDOWS_S: tuple[tuple[float, float], ...] = ((0.05, -0.05), (0.05, 0.3))
MODAL_WINDOW_NAMES: tuple[str, ...] = ("whole", "early")


@dataclass(frozen=True)
class ModalProbe:
    """What the per-run modal phase needs: the modal filter of the lowest linear modes at the outputs.

    ``projector`` is ``ΦᵀM`` (r, n_out) of the Guyan model at the output DOFs and ``omega`` (r,) its
    natural frequencies in rad/s (``analysis.modal_filter.modal_basis``; eq. 2.15).
    """

    projector: FloatArray
    omega: FloatArray
    windows_s: tuple[tuple[float, float], ...] = MODAL_WINDOWS_S

    @classmethod
    def from_guyan(cls, M: FloatArray, K: FloatArray, n_modes: int = 2,
                   windows_s: tuple[tuple[float, float], ...] = MODAL_WINDOWS_S) -> ModalProbe:  # fmt: skip
        from analysis.modal_filter import modal_basis

        b = modal_basis(M, K, n_modes)
        return cls(projector=np.ascontiguousarray(b.projector), omega=np.ascontiguousarray(b.omega), windows_s=windows_s)

    def marks(self, n_samples: int, sample_rate: float) -> np.ndarray:
        """Sample indices (n_windows, 2) of each window's edges; −1 where the window does not fit the record."""
        out = np.full((len(self.windows_s), 2), -1, dtype=np.int64)
        for k, (a, b) in enumerate(self.windows_s):
            i0 = round(a * sample_rate)
            i1 = round((n_samples / sample_rate + b) * sample_rate) if b < 0 else round(b * sample_rate)
            if 0 <= i0 < i1 <= n_samples - 1:
                out[k] = (i0, i1)
        return out


@dataclass(frozen=True)
class SweepMoments(MomentResult):
    """:class:`MomentResult` plus, with a :class:`ModalProbe`, each run's mean modal frequencies.

    ``modal_freq_hz`` (B, n_windows, r): phase advance of linear mode j over window w divided by 2π·length
    (NaN where the window does not fit the record); ``modal_windows_s`` the windows.
    """

    modal_freq_hz: FloatArray | None = None
    modal_windows_s: tuple[tuple[float, float], ...] = ()
    nsi: FloatArray | None = None  # (B, len(NSI_FIELDS)) with an NsiProbe, else None


#: What :class:`NsiProbe` keeps per run, in this order (``gvt identify`` reads them back, daq/studies/identify/sweep.py).
NSI_FIELDS: tuple[str, ...] = ("dbar_m", "f_rq_hz", "f_pom_hz", "mac", "capture", "pom_index")


@dataclass(frozen=True)
class NsiProbe:
    """What the seed's NSI (§5.1) needs of one run, reduced from the run's reduced record q (x = rows q).

    The whole-record POD (eqs. 2.12–2.13) of the outputs, the attachment's POM by MAC against its linear mode
    ``shape`` (eq. 5.6, 1:1 capture flagged by two similar POMs), the POM's RQ with the linear M, K (eq. 2.18),
    its temporal coefficient's frequency (``nsi.pom_frequency_hz``) and the whole-run δ̄ (eq. 5.2) of
    δ = ``delta_row`` q. The sweep keeps these six numbers per run so ``gvt identify SWEEP_DIR`` need not
    re-simulate (issue 22: a 1000-run sweep identified within 60 s); ``daq.studies.identify.sweep.simulate_runs`` calls the
    same :meth:`reduce`, so both paths give the same table."""

    rows: FloatArray  # (n_out, n_r)
    delta_row: FloatArray  # (n_r,)
    shape: FloatArray  # (n_out,)
    M: FloatArray
    K: FloatArray
    n_poms: int = 8

    @classmethod
    def build(cls, sim: ImpactSimulator, attachment: int, relative_to: tuple[int, ...], shape: FloatArray,
              M: FloatArray, K: FloatArray, n_poms: int = 8) -> NsiProbe:  # fmt: skip
        """``attachment``/``relative_to`` are output columns (eq. 5.13: δ = x_att − mean x_refs)."""
        P = np.ascontiguousarray(sim.reduced.rows(sim.output_dofs))
        row = P[attachment] - (P[list(relative_to)].mean(axis=0) if relative_to else 0.0)
        return cls(P, np.ascontiguousarray(row), np.asarray(shape, float), np.asarray(M, float), np.asarray(K, float), n_poms)

    def reduce(self, q: FloatArray, sample_rate: float) -> FloatArray:
        from analysis import nsi
        from analysis.pod import _normalise, mac, rq_hz

        n = q.shape[0]
        qc = q - q.mean(axis=0)
        cov = self.rows @ (qc.T @ qc / n) @ self.rows.T
        _lam, vec = np.linalg.eigh(0.5 * (cov + cov.T))
        poms = _normalise(vec[:, ::-1][:, : self.n_poms])
        pick = nsi.pick_attachment_pom(mac(self.shape[:, None], poms)[0][None])
        j = int(pick.index[0])
        return np.array([
            float(nsi.characteristic_displacement(q @ self.delta_row)),
            float(rq_hz(poms[:, j : j + 1], self.M, self.K)[0]),
            nsi.pom_frequency_hz(qc, self.rows.T @ poms[:, j], sample_rate),
            float(pick.mac[0]), float(pick.capture[0]), float(j),
        ])  # fmt: skip


@njit(cache=True)
def _moments_and_phase(q, v, A, omega, marks):  # pragma: no cover - compiled
    """One pass over a run's reduced states: Σq and Σqqᵀ in the simulator's own order (bit-identical to
    ``run_moments``), and the unwrapped modal phases θ_j = atan2(−ż_j/ω_j, z_j), z = A q, read at ``marks``."""
    n, n_r = q.shape
    r = A.shape[0]
    sum_q = np.zeros(n_r)
    sum_qq = np.zeros((n_r, n_r))
    theta = np.zeros(r)
    prev = np.zeros(r)
    at = np.full((marks.shape[0], 2, r), np.nan)
    for k in range(n):
        for i in range(n_r):
            sum_q[i] += q[k, i]
            for j in range(n_r):
                sum_qq[i, j] += q[k, i] * q[k, j]
        for m in range(r):
            z = 0.0
            zd = 0.0
            for i in range(n_r):
                z += A[m, i] * q[k, i]
                zd += A[m, i] * v[k, i]
            ph = math.atan2(-zd / omega[m], z)
            if k > 0:
                d = ph - prev[m]
                if d > math.pi:
                    d -= 2.0 * math.pi
                elif d <= -math.pi:
                    d += 2.0 * math.pi
                theta[m] += d
            prev[m] = ph
        for w in range(marks.shape[0]):
            for e in range(2):
                if marks[w, e] == k:
                    for m in range(r):
                        at[w, e, m] = theta[m]
    return sum_q, sum_qq, at


@njit(cache=True, parallel=True)
def _run_record(amp, model, force, stepping, q_out, v_out, g_out, work_out, diss_out):  # pragma: no cover - compiled
    """One amplitude into preallocated record buffers (the simulator's ``_integrate``, ``record=True``), reused
    run after run. Compiled with ``parallel=True`` around a one-item ``prange`` like the simulator's
    ``integrate_batch_moments``: measured on beam_ch4_sim (1 s, one thread) 0.196 s per run this way against
    0.240 s from a plain ``@njit`` wrapper of the same call (numba's parfor pipeline optimises the inlined
    integrator differently); ``integrate_batch_moments`` takes 0.199 s."""
    omega2, cdamp, phi_f, B, law, kc, pe = model
    fkind, fstart, fdur, ftt, fff, fcum = force
    gammas, dt_out, n_min, n_max, om_base2, theta = stepping
    d1 = np.zeros(1)
    d2 = np.zeros((1, 1))
    work = np.zeros(1)
    diss = np.zeros(1)
    steps = np.zeros(1, dtype=np.int64)
    capped = np.zeros(1, dtype=np.int64)
    state = np.zeros((1, 2 * omega2.shape[0] + 2 * B.shape[0] + 2))  # at rest (analysis.model._integrator.state_size)
    for b in prange(1):
        work[b], diss[b], steps[b], capped[b] = _integrate(
            amp, omega2, cdamp, phi_f, B, law, kc, pe, fkind, fstart, fdur, ftt, fff, fcum, gammas, dt_out, n_min, n_max,
            om_base2, theta, q_out.shape[0], q_out, v_out, g_out, work_out, diss_out, d1, d2, True, 0, state[b])  # fmt: skip
    return work[0], diss[0], steps[0], capped[0]


def _record_buffers(sim: ImpactSimulator, probe: ModalProbe, n: int, model: tuple) -> tuple[FloatArray, tuple[FloatArray, ...]]:
    """The probe's modal filter in the simulator's reduced coordinates (``A = ΦᵀM · rows``, z = A q) and the
    record buffers ``_run_record`` fills, reused run after run: q, q̇ (n, n_basis), the nonlinear springs' forces
    (n, springs), and the running input work and dissipation (n,)."""
    A = np.ascontiguousarray(probe.projector @ sim.reduced.rows(sim.output_dofs))
    n_r = model[0].shape[0]
    return A, (np.empty((n, n_r)), np.empty((n, n_r)), np.empty((n, model[3].shape[0])), np.empty(n), np.empty(n))


def run_with_modal_phase(
    sim: ImpactSimulator,
    force: Force,
    duration: float,
    sample_rate: float,
    amps: np.ndarray,
    probe: ModalProbe,
    nsi_probe: NsiProbe | None = None,
) -> SweepMoments:
    """``sim.run_moments`` (same moments, bit for bit) plus each run's mean modal frequencies per window.

    Memory: one run's reduced record (n_samples × n_basis states, ~6 MB for 1 s of ``beam_ch4_sim``), a
    buffer reused for every run of the chunk and reduced to the moments and the phases at the window edges;
    nothing grows with the number of runs. (O(1) in the record length would need the phase accumulated inside
    ``analysis.model._integrator._integrate``.)
    """
    n, model, fdesc, stepping, amps = sim._prepare(force, duration, sample_rate, amps)
    A, bufs = _record_buffers(sim, probe, n, model)
    q, v = bufs[0], bufs[1]
    marks = probe.marks(n, sample_rate)
    n_r = model[0].shape[0]
    B = amps.size
    sq, sqq = np.zeros((B, n_r)), np.zeros((B, n_r, n_r))
    work, diss = np.zeros(B), np.zeros(B)
    steps, capped = np.zeros(B, dtype=np.int64), np.zeros(B, dtype=np.int64)
    fmod = np.full((B, len(probe.windows_s), probe.omega.size), np.nan)
    nsi_cols = None if nsi_probe is None else np.full((B, len(NSI_FIELDS)), np.nan)
    for b in range(B):
        work[b], diss[b], steps[b], capped[b] = _run_record(float(amps[b]), model, fdesc, stepping, *bufs)
        sq[b], sqq[b], at = _moments_and_phase(q, v, A, probe.omega, marks)
        if nsi_probe is not None:
            nsi_cols[b] = nsi_probe.reduce(q, sample_rate)  # type: ignore[index]
        for k, (i0, i1) in enumerate(marks):
            if i0 >= 0:
                fmod[b, k] = (at[k, 1] - at[k, 0]) * sample_rate / (2.0 * math.pi * (i1 - i0))
    return SweepMoments(
        **sim.moment_fields(amps, n, sq, sqq, work, diss, steps, capped),
        modal_freq_hz=fmod,
        modal_windows_s=probe.windows_s,
        nsi=nsi_cols,
    )


def run_modal_phases(
    sim: ImpactSimulator, force: Force, duration: float, sample_rate: float, amp: float, probe: ModalProbe
) -> tuple[float, FloatArray]:
    """One run of the sweep's own simulation at amplitude ``amp`` → (input work J, phases (r, n_samples)).

    The same compiled integrator call as :func:`run_with_modal_phase` (``_run_record``), so the record is the
    one the sweep reduced to its moments and modal frequencies (the input work is bit-identical, tested); here
    the probe's modal phases θ_j = atan2(−ż_j/ω_j, z_j), z = A q (eq. 2.15 basis), are kept at every output
    sample, unwrapped, for the slow-flow test of a candidate capture (``analysis.sweep_capture``). Memory: one
    run's reduced record (~6 MB for 1 s of ``beam_ch4_sim``) plus r × n_samples phases.
    """
    n, model, fdesc, stepping, amps = sim._prepare(force, duration, sample_rate, [float(amp)])
    A, bufs = _record_buffers(sim, probe, n, model)
    work, _, _, _ = _run_record(float(amps[0]), model, fdesc, stepping, *bufs)
    z, zd = bufs[0] @ A.T, bufs[1] @ A.T
    theta = np.unwrap(np.arctan2(-zd / probe.omega[None, :], z), axis=0)
    return float(work), np.ascontiguousarray(theta.T)


def _run_chunk(
    sim: ImpactSimulator,
    force: Force,
    duration: float,
    sample_rate: float,
    amps: np.ndarray,
    threads: int,
    probe: ModalProbe | None = None,
    nsi_probe: NsiProbe | None = None,
) -> MomentResult:
    import numba

    numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))
    if probe is not None:
        return run_with_modal_phase(sim, force, duration, sample_rate, amps, probe, nsi_probe)
    return sim.run_moments(force, duration, sample_rate, amps)


def _concat(parts: Sequence[MomentResult]) -> MomentResult:
    modal = all(isinstance(p, SweepMoments) and p.modal_freq_hz is not None for p in parts)
    with_nsi = all(getattr(p, "nsi", None) is not None for p in parts)
    return SweepMoments(
        amplitudes=np.concatenate([p.amplitudes for p in parts]),
        mean=np.concatenate([p.mean for p in parts]),
        covariance=np.concatenate([p.covariance for p in parts]),
        input_work=np.concatenate([p.input_work for p in parts]),
        dissipated=np.concatenate([p.dissipated for p in parts]),
        n_samples=parts[0].n_samples,
        output_names=parts[0].output_names,
        steps_per_sample=np.concatenate([p.steps_per_sample for p in parts]),
        substep_cap_hits=np.concatenate([p.substep_cap_hits for p in parts]),
        modal_freq_hz=np.concatenate([p.modal_freq_hz for p in parts]) if modal else None,  # type: ignore[attr-defined]
        modal_windows_s=parts[0].modal_windows_s if modal else (),  # type: ignore[attr-defined]
        nsi=np.concatenate([p.nsi for p in parts]) if with_nsi else None,  # type: ignore[attr-defined]
    )


def sweep_moments(
    sim: ImpactSimulator,
    force: Force,
    amplitudes: Sequence[float],
    duration: float,
    sample_rate: float,
    *,
    scheduler: str | None = None,
    n_workers: int = 2,
    chunk_size: int = 20,
    progress: Callable[[int, int], None] | None = None,
    probe: ModalProbe | None = None,
    nsi_probe: NsiProbe | None = None,
) -> SweepMoments:
    """Run every amplitude; results come back in the order of ``amplitudes``.

    With ``nsi_probe`` (and ``probe``) each run also yields its NSI reduction (``SweepMoments.nsi``, :class:`NsiProbe`).

    With ``probe`` each run also yields its mean modal frequencies (``SweepMoments.modal_freq_hz``,
    :func:`run_with_modal_phase`); without, ``modal_freq_hz`` is None.

    ``scheduler=None`` starts a local cluster of ``n_workers`` single-threaded processes bound to
    127.0.0.1 and closes it afterwards; an address connects to an existing scheduler. ``progress`` is
    called with (runs done, runs total) as chunks finish.
    """
    from distributed import Client, LocalCluster, as_completed

    amps = np.asarray(amplitudes, dtype=float)
    if amps.ndim != 1 or amps.size == 0:
        raise ValueError("amplitudes must be a non-empty 1-D sequence")
    chunks = [amps[i : i + chunk_size] for i in range(0, amps.size, chunk_size)]
    cluster = None
    if scheduler is None:
        cluster = LocalCluster(
            n_workers=n_workers, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=None
        )
        client = Client(cluster)
    else:
        client = Client(scheduler)
    try:
        sim_f = client.scatter(sim, broadcast=True)
        futures = {
            client.submit(_run_chunk, sim_f, force, duration, sample_rate, c, 1, probe, nsi_probe, pure=False): i
            for i, c in enumerate(chunks)
        }
        parts: dict[int, MomentResult] = {}
        done = 0
        for fut in as_completed(list(futures)):
            i = futures[fut]
            parts[i] = fut.result()
            done += len(chunks[i])
            if progress:
                progress(done, amps.size)
        return _concat([parts[i] for i in range(len(chunks))])
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def peak_rss_mb_of_workers(client) -> dict[str, float]:  # pragma: no cover - used by the benchmark
    import resource

    def rss() -> float:
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0

    return client.run(rss)
