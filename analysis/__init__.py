"""gvtlink analysis: the rig model and simulator, and the near-live detection kernels.

BLAS threads default to one (docs/decisions.md D19): the analysis works on small matrices (≤ 64 × 64
covariances, many of them) where OpenBLAS' thread pool only adds spinning and oversubscribes a machine
that already runs the drivers, the writer and Dask workers — measured: 64 ch × 51.2 kHz analysis went
from 0.2× to 3× real time on 2 busy cores. Set ``OPENBLAS_NUM_THREADS`` yourself to override; this only
takes effect if numpy was not imported before gvtlink.

numba's cache directory is chosen here too, before any kernel module imports numba (analysis/jit_cache.py).
"""

import os as _os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_var, "1")

from analysis.jit_cache import configure as _configure_jit_cache  # noqa: E402 (after the thread defaults, as they are)

_configure_jit_cache()  # one numba cache for make, the tests and gvt (analysis/jit_cache.py, D70)
