"""Direct (time-domain) evaluation of the Morlet CWT of eq. 3.2 at chosen points — the independent oracle.

Z(ω, t) = Σ_k x[k]·ψ*_{ω,t}(t_k)·Δt with ψ_{ω,t}(τ) = π^{-1/4} exp[jω(τ−t)] exp[−½(ω(τ−t)/ω0)²]: the
seed's integral (eq. 3.1) as a Riemann sum, O(N) per point, no FFT. The Gaussian is smooth and decays
to 1e-30 within the record, so the sum equals the integral of the band-limited signal to rounding.
Used by tests and ``bench/bench_cwt.py`` to judge both :func:`analysis.wavelet.morlet_cwt` and PyWavelets.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray


def cwt_direct(
    x: NDArray[np.float64], fs: float, freqs_hz: NDArray[np.float64], t_idx: NDArray[np.int64], omega0: float = 2.0 * np.pi
) -> NDArray[np.complex128]:
    """Literal eq. 3.2 transform at rows ``freqs_hz`` and sample indices ``t_idx``: shape (n_freq, n_t)."""
    tau = np.arange(x.size) / fs
    out = np.empty((len(freqs_hz), len(t_idx)), dtype=np.complex128)
    for i, f in enumerate(freqs_hz):
        w = 2.0 * np.pi * f
        for j, k in enumerate(t_idx):
            d = tau - tau[k]
            psi_conj = np.pi**-0.25 * np.exp(-1j * w * d) * np.exp(-0.5 * (w * d / omega0) ** 2)
            out[i, j] = np.sum(x * psi_conj) / fs
    return out
