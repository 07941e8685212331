"""An FRF set from a file that is not a session's samples: a UFF 58 file read directly, or a log ``gvt import`` wrote
from FRFs (its ``frf/matrix.npz``). What lets ``gvt modal``, ``gvt frf`` and ``gvt model update`` take either, as
a lab's tools take a UFF FRF file (issue 31): before, a UFF file stopped at "not an MCAP file (bad magic bytes)"."""

from __future__ import annotations

import io
from pathlib import Path

from analysis.frf import FRFSet
from daq.studies.importing.data import FrfImport, ImportError_

MCAP_MAGIC = b"\x89MCAP"


def frf_file(path: Path) -> tuple[FRFSet, list[str]] | None:
    """(the FRF set, the assumptions made reading it) of a UFF file (by content) or of an FRF log of ``gvt import``;
    None for anything else (a session log with samples goes the usual way). A UFF file of time histories is
    refused: its FRFs need the hits (``gvt import`` it, then ``gvt frf``)."""
    from daq.studies.importing import uff

    path = Path(path)
    if uff.is_uff(path):
        data = uff.read(path)
        if not isinstance(data, FrfImport):
            raise ImportError_(f"{path}: a UFF file of time histories, not FRFs; `gvt import {path} -o LOG.mcap` "
                               "makes a log of it, whose hits `gvt frf LOG.mcap --rig RIG` turns into FRFs")  # fmt: skip
        return data.frf, list(data.provenance.assumptions)
    try:
        with open(path, "rb") as fh:
            if fh.read(5) != MCAP_MAGIC:
                return None
    except OSError:
        return None
    from daq.log.reader import LogReader, LogReadError
    from daq.studies.importing.log import MATRIX_ATTACHMENT, META_IMPORT

    try:
        reader = LogReader(path)
        if META_IMPORT not in reader.metadata():
            return None
        blob = reader.attachments().get(MATRIX_ATTACHMENT)
    except LogReadError:
        return None
    if blob is None:
        return None
    return FRFSet.from_npz(io.BytesIO(blob[1])), []


#: Coherence below this at a peak of the mode indicator is worth a warning (docs/frf.md's judgement of a session).
LOW_COHERENCE = 0.8


def frf_run(path: Path, frf: FRFSet, assumptions: list[str], n_peaks: int = 6):
    """``gvt frf`` of a given FRF set: nothing to average, so the set as it is, with the coherence at its peaks judged
    (a warning per peak where some pair is below :data:`LOW_COHERENCE`) and the reader's assumptions as notes."""
    from dataclasses import replace

    from daq.studies.frf import FRFRun

    df = float(frf.freq[1] - frf.freq[0]) if frf.freq.size > 1 else 1.0
    warnings = list(frf.quality.get("warnings", []))
    if "coherence not in the file" not in " ".join(warnings):
        for k in frf.peaks(n_peaks):
            low = float(frf.coherence[:, :, k].min())
            if low < LOW_COHERENCE:
                warnings.append(f"coherence {low:.2f} at the peak at {frf.freq[k]:.2f} Hz: noise or nonlinearity "
                                "there; re-measure or leave the mode's figures in doubt")  # fmt: skip
    w = frf.window or {}
    frf = replace(frf, quality={**frf.quality, "warnings": warnings, "notes": assumptions})
    return FRFRun(str(path), "FRF file", "", frf, 1.0 / df, 0.0, w.get("tau_s"), float(frf.freq[-1]))


__all__ = ["LOW_COHERENCE", "frf_file", "frf_run"]
