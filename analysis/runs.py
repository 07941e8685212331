"""Runs of True in a boolean mask: the one run finder the detectors share (RQ-FEP spikes and bands, the
seed's spike rule, slow-flow reversal chains, the sweep's capture passages)."""

from __future__ import annotations

import numpy as np


def true_runs(mask: np.ndarray, gap: int = 1) -> list[tuple[int, int]]:
    """(first, last) index of each run of True in ``mask`` (1-D). A True at most ``gap`` after a run extends
    it: ``gap`` = 1 joins consecutive points only, ``gap`` = 2 bridges one False, and so on."""
    idx = np.flatnonzero(np.asarray(mask, dtype=bool))
    if idx.size == 0:
        return []
    cuts = np.flatnonzero(np.diff(idx) > gap)
    starts = np.r_[idx[0], idx[cuts + 1]]
    ends = np.r_[idx[cuts], idx[-1]]
    return list(zip(starts.tolist(), ends.tolist(), strict=True))
