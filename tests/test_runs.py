"""analysis.runs.true_runs, the run finder the detectors share, against a plain loop over the mask."""

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from analysis.runs import true_runs


def _loop_runs(mask: list[bool], gap: int) -> list[tuple[int, int]]:
    """The definition, one index at a time: a True at most ``gap`` after the current run's last True extends it."""
    runs: list[tuple[int, int]] = []
    for i, m in enumerate(mask):
        if not m:
            continue
        if runs and i - runs[-1][1] <= gap:
            runs[-1] = (runs[-1][0], i)
        else:
            runs.append((i, i))
    return runs


@given(st.lists(st.booleans(), max_size=200), st.integers(min_value=1, max_value=6))
def test_true_runs_property_matches_the_loop_definition(mask, gap):
    assert true_runs(np.array(mask, dtype=bool), gap) == _loop_runs(mask, gap)


def test_true_runs_examples():
    m = np.array([0, 1, 1, 0, 0, 1, 0, 1, 1, 1], bool)
    assert true_runs(m) == [(1, 2), (5, 5), (7, 9)]
    assert true_runs(m, gap=2) == [(1, 2), (5, 9)]  # one False bridged, two not
    assert true_runs(m, gap=3) == [(1, 9)]
    assert true_runs(np.zeros(5, bool)) == [] and true_runs(np.zeros(0, bool)) == []
    assert all(isinstance(v, int) for run in true_runs(m) for v in run)  # plain ints (JSON, slicing)
