"""The seed's force sweep (§4.2, L1215: P = logspace(1, 12, 1000), 1 s each) in bounded memory, on Dask.

Each run keeps only what an RQ-FEP needs — the mean and 1/n covariance of the output displacements
(POD of the whole record is the eigen-decomposition of that covariance, eq. 2.12–2.13) and the input
work (the energy axis, L1251) — so memory is O(n_out^2) per run however long the record. Chunks of
amplitudes run as Dask tasks: a local cluster by default, any scheduler address to scale out
(architecture.md, "Where it grows").
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from analysis.model.forces import Force
from analysis.model.simulate import ImpactSimulator, MomentResult


def _run_chunk(
    sim: ImpactSimulator, force: Force, duration: float, sample_rate: float, amps: np.ndarray, threads: int
) -> MomentResult:
    import numba

    numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))
    return sim.run_moments(force, duration, sample_rate, amps)


def _concat(parts: Sequence[MomentResult]) -> MomentResult:
    return MomentResult(
        amplitudes=np.concatenate([p.amplitudes for p in parts]),
        mean=np.concatenate([p.mean for p in parts]),
        covariance=np.concatenate([p.covariance for p in parts]),
        input_work=np.concatenate([p.input_work for p in parts]),
        dissipated=np.concatenate([p.dissipated for p in parts]),
        n_samples=parts[0].n_samples,
        output_names=parts[0].output_names,
        steps_per_sample=np.concatenate([p.steps_per_sample for p in parts]),
        substep_cap_hits=np.concatenate([p.substep_cap_hits for p in parts]),
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
) -> MomentResult:
    """Run every amplitude; results come back in the order of ``amplitudes``.

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
            client.submit(_run_chunk, sim_f, force, duration, sample_rate, c, 1, pure=False): i for i, c in enumerate(chunks)
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
