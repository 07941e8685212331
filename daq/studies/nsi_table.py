"""``nsi.csv``: the per-run NSI table a sweep writes (``gvt sweep``) and ``gvt identify`` reads back.

Per run: the force P, the input energy, δ̄ (eq. 5.2), the attachment POM's RQ frequency (eq. 2.18) and the
frequency of its temporal coefficient, its MAC (eq. 5.6), whether the run was in resonance capture, and which
POM it was. The file format is shared by the two studies, so it lives here, below both.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from analysis.errors import BadInput
from daq.outputs import atomic_output

NSI_CSV = "nsi.csv"
COLUMNS = ("P_N", "input_energy_J", "dbar_m", "f_rq_hz", "f_pom_hz", "mac", "capture", "pom_index")


@dataclass
class NsiRuns:
    """Per run of a sweep: the columns of :data:`COLUMNS`."""

    P: np.ndarray
    energy: np.ndarray
    dbar: np.ndarray
    f_rq: np.ndarray
    f_pom: np.ndarray
    mac: np.ndarray
    capture: np.ndarray
    pom_index: np.ndarray
    wall_s: float = 0.0


def write_runs(runs: NsiRuns, path: Path) -> None:
    """``path`` (``nsi.csv``) written to a temporary file, then renamed (:func:`daq.outputs.atomic_output`: a full
    disk leaves the previous table and no temporary file, and is one line)."""
    with atomic_output(path) as tmp, open(tmp, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(COLUMNS)
        for k in range(runs.P.size):
            w.writerow([f"{runs.P[k]:.9g}", f"{runs.energy[k]:.9g}", f"{runs.dbar[k]:.9g}", f"{runs.f_rq[k]:.9g}",
                        f"{runs.f_pom[k]:.9g}", f"{runs.mac[k]:.6f}", int(runs.capture[k]), int(runs.pom_index[k])])  # fmt: skip


def read_runs(path: Path) -> NsiRuns:
    """The table back; a file that is not one is one line (:class:`BadInput`)."""
    try:
        with open(path, newline="") as fh:
            rows = list(csv.DictReader(fh))
        if not rows or any(c not in rows[0] for c in COLUMNS):
            raise ValueError(f"expected columns {', '.join(COLUMNS)}")
        col = {c: np.array([float(r[c]) for r in rows]) for c in COLUMNS}
    except (OSError, ValueError, KeyError) as exc:
        raise BadInput(f"{path}: not an NSI run table ({exc})") from None
    return NsiRuns(col["P_N"], col["input_energy_J"], col["dbar_m"], col["f_rq_hz"], col["f_pom_hz"], col["mac"],
                   col["capture"] > 0, col["pom_index"].astype(np.int64))  # fmt: skip
