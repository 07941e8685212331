"""What a reader of another tool's file hands the log writer: samples or FRFs in SI units, the channel table, and
what was read and assumed.

Why one record for every format: a lab's import (Testlab, DewesoftX) says what it found and what it assumed, once,
and drops nothing silently. Readers (one module per format) only parse and convert units; the log writer
(``daq.studies.importing.log``) is the one place that builds a format-2 log, so a CSV, a TDMS file and a UFF 58
file of the same samples give the same log.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from analysis.errors import BadInput
from analysis.frf import FRFSet
from analysis.model.channels import Channel
from analysis.model.wireframe import Geometry


class ImportError_(BadInput):
    """A file that cannot be imported; ``str`` is one line: file (and record/line), what, how to fix (exit 2)."""


@dataclass(frozen=True)
class Provenance:
    """Where imported data came from: the source ``path`` (as given), its ``sha256``, the ``format`` read
    ("uff58", "uff58b", "csv", "tdms", "hdf5-sep005", ...), the ``writer`` named in the file (a tool, a
    program name; "" when the file does not say) and ``assumptions``: every choice the reader made that the
    file did not state (a unit taken from a header, a sample rate from a time track, a direction). Each is
    printed once by ``gvt import`` and kept in the log's metadata."""

    path: str
    sha256: str
    format: str
    writer: str = ""
    assumptions: tuple[str, ...] = ()


@dataclass
class TimeImport:
    """Time histories: ``samples`` (n, n_ch) float64 in SI units (N, m/s^2, m/s, m, Pa) on one uniform grid of
    rate ``fs`` Hz starting at ``t0_s``; ``channels`` the channel table (one per column, same order); the force
    channel(s) have quantity "force". ``source_units`` the unit each column had in the file (pint spelling)."""

    samples: np.ndarray
    fs: float
    channels: list[Channel]
    provenance: Provenance
    source_units: list[str] = field(default_factory=list)
    t0_s: float = 0.0
    geometry: Geometry | None = None
    modes: dict | None = None  # mode shapes the file carries (UFF 55): freq_hz, zeta, outputs, shapes (n_out, n_modes)

    def __post_init__(self) -> None:
        n_ch = len(self.channels)
        if self.samples.ndim != 2 or self.samples.shape[1] != n_ch:
            raise ImportError_(f"{self.provenance.path}: {self.samples.shape} samples for {n_ch} channels")
        if not (np.isfinite(self.fs) and self.fs > 0):
            raise ImportError_(f"{self.provenance.path}: sample rate {self.fs!r} Hz is not a positive number")


@dataclass
class FrfImport:
    """FRFs (with coherence where the file has it; ``coherence_known`` False when it does not, and the set's
    coherence is then all ones and says so in ``frf.quality['warnings']``) and the channel table of the outputs
    and references."""

    frf: FRFSet
    channels: list[Channel]
    provenance: Provenance
    coherence_known: bool = True
    geometry: Geometry | None = None
    modes: dict | None = None  # mode shapes the file carries (UFF 55), as in TimeImport
