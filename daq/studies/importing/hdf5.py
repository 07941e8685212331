"""SEP005 time series stored in HDF5 (h5py) into a :class:`TimeImport`.

SEP005 ("SDyPy unified timeseries", https://github.com/sdypy/sdypy/blob/main/docs/seps/sep-0005.rst; checked by
the ``sdypy-sep005`` package's ``assert_sep005``) is a list of channel dicts: compulsory ``data`` (1-D array),
``name`` (unique), ``unit_str``, and either ``fs`` (Hz) or ``time`` (s, one per sample); optional
``start_timestamp`` (ISO 8601) and any other field. It says nothing about files; the SEP005 readers and writers of
OWI-Lab (sdypy_io_tdms, sep005_io_*) keep one channel per stored object with its fields beside it. gvtlink reads
that mapping in HDF5:

* one HDF5 group per channel, directly under the root: dataset ``data`` (1-D, any real dtype), optional dataset
  ``time``; the other fields as the group's attributes (``name``, default the group's name; ``unit_str``;
  ``fs``; ``start_timestamp``; an optional ``quantity`` checked against the unit);
* or, the same with the channel's ``data`` as a dataset directly under the root carrying the attributes;
* channels in the file's order: creation order when the file tracks it (h5py ``track_order=True``), else by name
  (said in the assumptions); any other root object is named as not imported.

All channels must share one grid (rate, length, start); else the file is refused naming them. A channel with no
unit, an unknown one, or neither ``fs`` nor ``time`` is one line, exit 2. ``data`` is read as stored and converted
to float64, then multiplied by the unit's exact factor: a file written by h5py imports bit for bit. The samples
are the transpose of a channel-major array (each channel contiguous; see tdms.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from daq.studies.importing._common import _si, channel_list, hash_in_background, load_table, rate_from_time, si_factors
from daq.studies.importing.data import ImportError_, Provenance, TimeImport

SPEC = "SEP005 in HDF5: one group per channel (dataset data, attributes name, unit_str, fs) (docs/import-formats.md)"


@dataclass
class _Channel:
    key: str
    name: str
    unit: str
    data: object  # the h5py dataset, read once the grid is agreed
    fs: float
    t0: float
    source: str  # "fs", or "time" with its deviation
    start: str = ""  # SEP005 start_timestamp


def _text(v) -> str:
    v = _scalar(v)
    return v.decode("utf-8", "replace") if isinstance(v, bytes) else str(v)


def _scalar(v):
    """An attribute as one value: MATLAB and some h5py writers store a scalar as a 1-element array."""
    return v.reshape(-1)[0] if isinstance(v, np.ndarray) and v.size == 1 else v


def _as_channel(where: str, key: str, obj) -> _Channel | None:
    """A SEP005 channel from a root object (a group with ``data``, or a dataset with SEP005 attributes), else None."""
    import h5py

    if isinstance(obj, h5py.Group):
        if not isinstance(obj.get("data"), h5py.Dataset):
            return None
        data, attrs, time = obj["data"], obj.attrs, obj.get("time")
    elif isinstance(obj, h5py.Dataset) and ("unit_str" in obj.attrs or "fs" in obj.attrs):
        data, attrs, time = obj, obj.attrs, None
    else:
        return None
    name = _text(attrs.get("name", key))
    if data.ndim != 1 or data.dtype.kind not in "fiub":
        raise ImportError_(f"{where}: channel {name!r} data is {data.dtype} of shape {data.shape}; SEP005 here needs 1-D numbers")
    unit = _text(attrs.get("unit_str", "")).strip()
    q = attrs.get("quantity")
    if q is not None and unit:
        try:
            if _si(unit)[1] != _text(q):
                raise ImportError_(f"{where}: channel {name!r} has quantity {_text(q)!r} but unit {unit!r}; correct one")
        except ValueError:
            pass  # the unit itself is refused with its channel name below
    start = _text(attrs["start_timestamp"]) if "start_timestamp" in attrs else ""
    if "fs" in attrs:
        try:
            fs = float(_scalar(attrs["fs"]))
        except (TypeError, ValueError):
            fs = float("nan")
        if not (np.isfinite(fs) and fs > 0):
            raise ImportError_(f"{where}: channel {name!r} has fs = {attrs['fs']!r}; SEP005's fs is a positive rate in Hz")
        return _Channel(key, name, unit, data, fs, 0.0, "fs", start)
    if isinstance(time, h5py.Dataset):
        t = time[...].astype(np.float64)
        if t.shape != data.shape:
            raise ImportError_(f"{where}: channel {name!r}: time has {t.size} values, data {data.size}; SEP005 needs one each")
        fs, dev, bad = rate_from_time(t)
        if bad >= 0:
            raise ImportError_(f"{where}: channel {name!r}: time breaks at sample {bad} (t = {t[bad]:.9g} s); gvtlink "
                               "does not resample: split the record there")  # fmt: skip
        return _Channel(key, name, unit, data, fs, float(t[0]), f"time (within {dev * fs:.2g} of a period)", start)
    raise ImportError_(f"{where}: channel {name!r} has neither fs nor time; SEP005 needs one of them")


def read(path: Path, channels: Path | None = None) -> TimeImport:
    """Read the SEP005 HDF5 file ``path`` (module docstring) with an optional channel table ``channels``."""
    import h5py

    path = Path(path)
    where = str(path)
    table = load_table(channels)
    if not path.is_file():
        raise ImportError_(f"{where}: no such file")
    sha = hash_in_background(path)  # beside h5py's reads, not after them
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise ImportError_(f"{where}: not a readable HDF5 file ({str(exc)[:80]})") from None
    with f:
        found = [(k, _as_channel(where, k, f[k])) for k in f]
        chans = [c for _k, c in found if c is not None]
        other = [k for k, c in found if c is None]
        if not chans:
            raise ImportError_(f"{where}: no SEP005 channel ({SPEC})")
        names = [c.name for c in chans]
        if len(set(names)) < len(names):
            raise ImportError_(f"{where}: channel names repeat ({names}); SEP005 names are unique")
        grids = {(c.fs, c.data.shape[0], c.t0) for c in chans}
        if len(grids) > 1:
            desc = "; ".join(f"{c.name} ({c.fs:.9g} Hz, {c.data.shape[0]} samples from {c.t0:g} s)" for c in chans)
            raise ImportError_(f"{where}: channels on different grids: {desc}; write one file per grid")
        units = [c.unit for c in chans]
        factors, quantities, conv = si_factors(where, names, units, table)
        by_channel = np.empty((len(chans), chans[0].data.shape[0]), np.float64)  # channel-major, as in tdms.py
        for k, c in enumerate(chans):
            if c.data.dtype == np.float64 and factors[k] == 1:
                c.data.read_direct(by_channel[k])
            else:  # float32, ints -> float64 exactly, then the factor, in one pass
                np.multiply(c.data[...], factors[k], out=by_channel[k], dtype=np.float64)
        order = f["/"].id.get_create_plist().get_link_creation_order() & h5py.h5p.CRT_ORDER_TRACKED
        writer = _text(f.attrs.get("writer", f.attrs.get("software", "")))
    table_chans, more = channel_list(where, names, quantities, table)
    notes = [SPEC, "channels in creation order" if order else "channels by name (the file does not track creation order)",
             f"sample rate {chans[0].fs:.9g} Hz from " + ", ".join(sorted({c.source for c in chans})),
             *sorted({f"starts at {c.start} (start_timestamp)" for c in chans if c.start}), *conv, *more]  # fmt: skip
    if other:
        notes.append(f"root object(s) {other} are not SEP005 channels: not imported")
    prov = Provenance(where, sha(), "hdf5-sep005", writer, tuple(notes))
    return TimeImport(by_channel.T, chans[0].fs, table_chans, prov, source_units=units, t0_s=chans[0].t0)
