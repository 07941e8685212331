"""What the CSV, TDMS and HDF5 readers share: the file's hash, a unit to SI through pint, the channel table of the
imported columns, and the sample rate from a time track.

Why one module: the three readers differ only in how they find names, units and samples in a file; the rules
after that (a missing or unknown unit is refused, never guessed; volts need a sensitivity from a channel table;
every assumption is said) must be the same for all of them, so that one file written by two tools imports the same.
"""

from __future__ import annotations

import hashlib
import threading
from collections.abc import Callable
from pathlib import Path

import numpy as np

from analysis.model.channels import Channel, read_channel_csv
from analysis.model.units import SI_UNITS, _units
from daq.studies.importing.data import ImportError_

#: quantities a column may hold: the channel table's four, and volts (converted by a sensitivity)
VOLTAGE = "voltage"
UNIT_HELP = "write the unit as e.g. m/s^2, g, mm/s, mm, N, lbf, or V with a sensitivity in the channel table"


def file_sha256(path: Path) -> str:
    """The source's SHA-256 (hex), read in 1 MiB pieces: a large file is hashed without being held in memory."""
    with open(path, "rb") as fh:
        return hashlib.file_digest(fh, "sha256").hexdigest()


def hash_in_background(path: Path) -> Callable[[], str]:
    """Start :func:`file_sha256` of ``path`` in a thread and return the call that waits for it. Why: hashing a
    128 MB file takes as long as npTDMS or h5py take to read it (0.29 s vs 0.17 s here), and hashlib releases
    the GIL, so the hash overlaps the read instead of adding to it (bench/bench_import_formats.py)."""
    box: dict[str, object] = {}

    def run() -> None:
        try:
            box["sha"] = file_sha256(path)
        except OSError as exc:
            box["err"] = exc

    th = threading.Thread(target=run, name="import-sha256", daemon=True)
    th.start()

    def result() -> str:
        th.join()
        if "err" in box:
            raise ImportError_(f"{path}: cannot read ({box['err']})")
        return str(box["sha"])

    return result


def _si(unit_text: str) -> tuple[float, str]:
    """``"g"`` -> (9.80665, "acceleration"), ``"mm"`` -> (0.001, "displacement"), ``"mV"`` -> (0.001, "voltage"):
    the factor to the SI unit of the quantity (SI_UNITS, or V). ValueError (one line, no fix) for an empty, unknown
    or non-vibration unit. A bare ``g`` is standard gravity, as on every accelerometer sheet (analysis/model/units.py);
    spellings are read as ``daq/studies/importing/units.py`` (the UFF reader's) reads them (``m/s2``, ``sec``, a
    blank or ``none`` is no unit). Unlike that module's ``si_factor`` it takes volts (divided by a channel table's
    sensitivity) and refuses pressure (a channel table has no pressure quantity), and it returns the definition's
    decimal factor (:func:`_decimal`)."""
    from daq.studies.importing.units import _BLANK, _pint_text

    text = (unit_text or "").strip()
    if text.lower() in _BLANK:
        raise ValueError("has no unit")
    for quantity, si in SI_UNITS.items():  # the SI spellings gvtlink writes: no pint registry to build (~1 s)
        if text == si:
            return 1.0, quantity
    try:
        q = _units().Quantity(1.0, _pint_text(text))
    except Exception as exc:  # pint's UndefinedUnitError, tokenize's TokenError, SyntaxError, ...
        raise ValueError(f"has unit {text!r}, which pint does not know ({type(exc).__name__})") from None
    for quantity, si in (*SI_UNITS.items(), (VOLTAGE, "V")):
        if q.is_compatible_with(si):
            return _decimal(float(q.to(si).magnitude)), quantity
    raise ValueError(f"has unit {text!r} ({q.dimensionality}), not an acceleration, velocity, displacement, force or voltage")


def _decimal(f: float) -> float:
    """pint's factor as the decimal it stands for: unit definitions are exact decimals (lbf = 0.45359237 kg x 9.80665
    m/s^2 = 4.4482216152605 N) that pint multiplies in binary, one ulp off (4.4482216152605005); the shortest
    decimal of 15 digits within 4 ulp is the definition's own value, so imported samples equal raw x definition."""
    c = float(f"{f:.15g}")
    return c if abs(c - f) <= 4 * np.spacing(abs(f)) else f


def si_factors(
    where: str, names: list[str], units: list[str], table: dict[str, Channel] | None
) -> tuple[np.ndarray, list[str], list[str]]:
    """Per column: the factor to SI, the quantity, and what was assumed. A voltage column is divided by the
    sensitivity (V per SI unit) the channel table gives it and takes the table's quantity; a mechanical column's
    quantity must match the table's. ImportError_ ``where: channel NAME ...`` with the fix."""
    factors, quantities, notes = np.ones(len(names)), [], []
    for k, (name, unit) in enumerate(zip(names, units, strict=True)):
        try:
            f, q = _si(unit)
        except ValueError as exc:
            raise ImportError_(f"{where}: channel {name!r} {exc}; {UNIT_HELP}") from None
        ch = table.get(name) if table else None
        if q == VOLTAGE:
            if ch is None or ch.sensitivity is None:
                raise ImportError_(f"{where}: channel {name!r} is in {unit}; give its sensitivity in a channel table "
                                   "(--channels TABLE.csv: name,node,x,y,z,direction,sensitivity,unit)")  # fmt: skip
            f, q = f / ch.sensitivity, ch.quantity
            notes.append(f"{name}: {unit} / {ch.sensitivity * 1e3:g} mV per {SI_UNITS[q]} (the channel table)")
        elif ch is not None and ch.quantity != q:
            raise ImportError_(f"{where}: channel {name!r} is in {unit} ({q}) but the channel table makes it {ch.quantity}; "
                               "correct the file's unit or the table's sensitivity unit")  # fmt: skip
        factors[k] = f
        quantities.append(q)
    return factors, quantities, notes


def load_table(channels: Path | None) -> dict[str, Channel] | None:
    """The channel table ``--channels TABLE.csv`` by name (its own errors are one line, exit 2), or None."""
    return None if channels is None else {c.name: c for c in read_channel_csv(channels)}


def channel_list(
    where: str, names: list[str], quantities: list[str], table: dict[str, Channel] | None
) -> tuple[list[Channel], list[str]]:
    """The imported columns as channels: from the table (every column must be in it, and every table row in the
    file: nothing dropped silently), or, without a table, numbered nodes at the origin pointing +Z (said)."""
    if table is None:
        chans = [Channel(n, q, k + 1, (0.0, 0.0, 0.0), 3) for k, (n, q) in enumerate(zip(names, quantities, strict=True))]
        return chans, ["no channel table: nodes 1..n in column order at (0, 0, 0), direction +Z (give --channels TABLE.csv)"]
    missing = [n for n in names if n not in table]
    if missing:
        raise ImportError_(f"{where}: channel(s) {missing} are not in the channel table; add a row for each")
    absent = [n for n in table if n not in names]
    if absent:
        raise ImportError_(f"{where}: the channel table names {absent}, which the file does not hold; remove those rows")
    return [Channel(n, q, table[n].node, table[n].xyz, table[n].direction, table[n].sensitivity)
            for n, q in zip(names, quantities, strict=True)], []  # fmt: skip


#: a time stamp farther than this (in sample periods) from the uniform grid is a break: a missing sample, a jump
TIME_TOLERANCE = 0.05


def rate_from_time(t: np.ndarray, k: np.ndarray | None = None, tol_s: float | None = None) -> tuple[float, float, int]:
    """(fs, deviation, first bad row) of a time track ``t`` (s) at grid positions ``k`` (0..n-1 by default).

    A step between two stamps that differs from the median step by more than ``tol_s`` (default
    :data:`TIME_TOLERANCE` of a period) is a break (a missing sample, a repeated stamp). The rate is the span's,
    snapped to the simplest decimal (whole Hz first) that fits the stamps as well as the raw span's does (a time
    column printed with 9 decimals gives 50.000000003 Hz otherwise); a stamp farther than ``tol_s`` from
    ``t[0] + k / fs`` is a break too (a drift). The first bad row is returned (-1: none). Why no resampling: a lab's
    import says where the time breaks; it does not guess samples."""
    k = np.arange(t.size, dtype=np.float64) if k is None else (k - k[0]).astype(np.float64)
    if t.size < 2 or not k[-1] > 0 or not t[-1] > t[0]:
        return float("nan"), float("inf"), min(1, t.size - 1)
    step = np.diff(t) / np.diff(k)
    period = float(np.median(step))
    tol = TIME_TOLERANCE * period if tol_s is None else tol_s
    jump = np.flatnonzero(np.abs(np.diff(t) - np.diff(k) * period) > tol)  # a missing sample, a repeated stamp
    if jump.size or not period > 0:
        return 1.0 / period if period > 0 else float("nan"), float("inf"), int(jump[0]) + 1 if jump.size else 1
    raw = k[-1] / (t[-1] - t[0])

    def dev(fs: float) -> np.ndarray:
        return np.abs(t - t[0] - k / fs)

    base = float(dev(raw).max())
    fs = raw
    for digits in range(10):
        c = round(raw, digits)
        if c > 0 and float(dev(c).max()) <= max(2 * base, 1e-12 * float(np.abs(t).max())):
            fs = c
            break
    d = dev(fs)
    bad = np.flatnonzero(d > tol)  # a slow drift: each step within the tolerance, the sum not
    return fs, float(d.max()), int(bad[0]) if bad.size else -1
