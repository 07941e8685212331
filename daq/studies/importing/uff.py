"""``gvt import FILE.uff``: UFF 58 time histories or FRFs (with coherence), and 15/82 geometry, into an import record.

What a lab's import does (issue 31): every dataset 58 is one function at a response DOF (node, direction) over a
reference DOF. Function type 1 (time response) -> :class:`TimeImport`, one channel per response DOF, records of a
channel laid end to end on one grid; type 4 (FRF) -> :class:`FrfImport`, outputs the response DOFs, references the
reference DOFs -- so a roving-hammer file (one accelerometer, the hammer at many nodes) has the hit points as
references, as it was measured; type 6 (coherence) goes with the FRF of the same pair. Any other function type,
or an ordinate that is not a vibration quantity (a temperature), is refused naming its dataset. Units: each
axis' unit label through pint (:mod:`daq.studies.importing.units`); without a label, the axis' unit exponents
with the file's dataset 164 factors; with neither, refused. Nodes' coordinates and trace lines come from
datasets 15 and 82 (``daq.studies.uff.datasets.geometry_from_sets``). gvtlink's own export states the FRFs'
exponential window in a dataset 1858 and ID line 3 (``daq/studies/uff/datasets.py``); it is read back so
``gvt modal`` removes it again.
"""

from __future__ import annotations

import hashlib
import re
import threading
from dataclasses import replace
from pathlib import Path

import numpy as np

from analysis.frf import FRFSet
from analysis.model.channels import Channel
from analysis.model.units import direction_label
from daq.studies.importing.data import FrfImport, ImportError_, Provenance, TimeImport
from daq.studies.importing.uff_records import parse_58, parse_other, split_blocks
from daq.studies.importing.units import si_factor

SUFFIXES = (".uff", ".unv", ".58", ".bunv")
FUNC_NAMES = {0: "general", 1: "time response", 2: "auto spectrum", 3: "cross spectrum", 4: "frequency response",
              5: "transmissibility", 6: "coherence", 7: "auto correlation", 8: "cross correlation",
              9: "power spectral density", 10: "energy spectral density", 11: "probability density",
              12: "spectrum", 13: "cumulative frequency distribution", 14: "peaks valley", 15: "stress/cycles",
              16: "strain/cycles", 17: "orbit", 18: "mode indicator", 19: "force pattern", 20: "partial power",
              21: "partial coherence", 22: "eigenvalue", 23: "eigenvector", 24: "shock response spectrum",
              25: "finite impulse response filter", 26: "multiple coherence", 27: "order function"}  # fmt: skip
#: UFF specific data types (records 8-11 field 1) that gvtlink measures, and what each is.
SPEC_QUANTITY = {8: "displacement", 9: "force", 11: "velocity", 12: "acceleration", 13: "force", 15: "pressure"}
SPEC_NAMES = {0: "unknown", 1: "general", 2: "stress", 3: "strain", 5: "temperature", 6: "heat flux", 16: "mass",
              17: "time", 18: "frequency", 19: "rpm", 20: "order", 21: "sound pressure level", 22: "voltage"}  # fmt: skip
FORMS = {"acceleration": "accelerance", "velocity": "mobility", "displacement": "receptance"}
_SIGMA = re.compile(r"exp window sigma ([-+0-9.eE]+) 1/s")


def is_uff(path: Path) -> bool:
    """A UFF file by content: its first non-blank line is ``    -1`` followed by a dataset number."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(256).lstrip(b" \r\n\t")
    except OSError:
        return False
    lines = head.splitlines()
    return len(lines) >= 2 and lines[0].strip() == b"-1" and lines[1][:6].strip().isdigit()


def read(path: Path, channels: Path | None = None) -> TimeImport | FrfImport:
    """The UFF file at ``path`` as an import record (``channels``, a channel table CSV, is not used: a UFF file
    names each function's node and direction itself). A field that is not what its record says (pyuff's
    extractors and number parsing raise many kinds) is one line, never a traceback."""
    try:
        return _read(Path(path), channels)
    except (ValueError, IndexError, KeyError, TypeError, OverflowError, UnicodeError) as exc:
        raise ImportError_(f"{path}: not a readable UFF file ({type(exc).__name__}: {str(exc)[:120]})") from None
    except Exception as exc:  # pyuff raises bare Exception("Error reading data-set #58b") and the like
        if isinstance(exc, ImportError_):
            raise
        raise ImportError_(f"{path}: not a readable UFF file ({str(exc)[:120] or type(exc).__name__})") from None


def _read(path: Path, channels: Path | None) -> TimeImport | FrfImport:
    where = str(path)
    raw = _mapped(Path(path))
    digest = _Digest(raw)  # the provenance's sha256, on the other core while the datasets are parsed
    blocks = split_blocks(raw, where)
    if not blocks:
        raise ImportError_(f"{where}: no UFF dataset in the file")
    notes: list[str] = []
    if channels is not None:
        notes.append(f"--channels {channels} not used: a UFF dataset 58 names its node and direction itself")
    funcs, others = [], []
    for b in blocks:
        if b.type == 58:
            funcs.append(parse_58(b, where))
        elif (d := parse_other(b)) is not None:
            others.append(d)
        else:
            notes.append(f"dataset {b.number} (type {b.type}) not imported: gvtlink does not read that dataset type")
    units = next((d for d in others if d.get("type") == 164), None)
    for d in funcs:
        _check_function(d, where)
    fmt = "uff58b" if any(b.binary for b in blocks if b.type == 58) else "uff58"
    writer = next((str(d.get("id3", "")) for d in funcs if d.get("id3") and d["id3"] != "NONE"), "")
    from daq.studies.uff.datasets import geometry_from_sets

    geometry = geometry_from_sets(others) if any(d.get("type") == 15 for d in others) else None
    prov = dict(path=where, sha256=digest.hexdigest(), format=fmt, writer=writer.split(":")[0][:80])
    frfs = [d for d in funcs if d["func_type"] == 4]
    if frfs:
        times = sum(d["func_type"] == 1 for d in funcs)
        if times:
            notes.append(f"{times} time histories (dataset 58, type 1) not imported: the file's FRFs are; "
                         "import the time histories from a file without FRFs")  # fmt: skip
        rec = _frf_import(frfs, [d for d in funcs if d["func_type"] == 6], others, units, geometry, prov, notes)
    else:
        times = [d for d in funcs if d["func_type"] == 1]
        if not times:
            raise ImportError_(f"{where}: no time history or FRF (dataset 58, function type 1 or 4) in the file")
        rec = _time_import(times, units, geometry, prov, notes)
    shapes = [d for d in others if d.get("type") == 55]
    if shapes:
        rec.modes = mode_shapes(shapes, rec.channels, notes)
        rec.provenance = replace(rec.provenance, assumptions=tuple(dict.fromkeys(notes)))
    return rec


def mode_shapes(sets: list[dict], channels: list[Channel], notes: list[str]) -> dict | None:
    """Datasets 55 at the channels' DOFs: ``{"freq_hz", "zeta", "outputs", "shapes"}`` (``shapes`` (n_out, n_modes),
    a channel's value the node's component along its direction, with its sign: the inverse of
    ``daq/studies/uff/datasets.py`` mode_shape_sets), or None when no channel sits on a shape's node."""
    from daq.studies.uff.datasets import mode_from_set

    modes = [mode_from_set(d) for d in sets]
    nodes = set().union(*(set(n.tolist()) for _f, _z, n, _r in modes))
    outs = [c for c in channels if c.node in nodes and c.quantity != "force"]  # shapes are of the responses
    if not outs:
        notes.append(f"{len(sets)} mode shape(s) (dataset 55) not imported: no channel on their nodes")
        return None
    shapes = np.zeros((len(outs), len(modes)), dtype=complex)
    for m, (_f, _z, ids, r) in enumerate(modes):
        col = {int(n): i for i, n in enumerate(ids)}
        for o, c in enumerate(outs):
            if c.node in col:
                shapes[o, m] = np.sign(c.direction) * r[abs(c.direction) - 1, col[c.node]]
    if not np.iscomplexobj(shapes) or not np.any(shapes.imag):
        shapes = shapes.real
    notes.append(f"{len(sets)} mode shape(s) (dataset 55) kept at {len(outs)} channel(s) as import/modes.json")
    return {"freq_hz": [float(f) for f, *_ in modes], "zeta": [float(z) for _f, z, *_ in modes],
            "outputs": [c.name for c in outs], "shapes": shapes}  # fmt: skip


def _mapped(path: Path) -> bytes:
    """The file's bytes (read whole, not memory-mapped: a file cut short while mapped kills the process with SIGBUS;
    a file being written by another program is a lab's everyday case)."""
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ImportError_(f"{path}: cannot read: {exc.strerror or exc}") from None
    if not raw:
        raise ImportError_(f"{path}: empty file")
    return raw


class _Digest:
    """sha256 of ``data`` in a thread (hashlib lets go of the GIL on large buffers)."""

    def __init__(self, data) -> None:
        self._h = hashlib.sha256()
        self._t = threading.Thread(target=self._h.update, args=(data,), daemon=True)
        self._t.start()

    def hexdigest(self) -> str:
        self._t.join()
        return self._h.hexdigest()


def _name(d: dict) -> str:
    return f"dataset 58 {d['id1']!r} (node {d['rsp_node']} dir {d['rsp_dir']})"


def _check_function(d: dict, where: str) -> None:
    """Refuse, by name, a function that is not a time history, FRF or coherence, or whose ordinate is not a vibration
    quantity (a thermocouple's temperature, a voltage)."""
    ft = d["func_type"]
    if ft not in (1, 4, 6):
        raise ImportError_(f"{where}: {_name(d)} is function type {ft} ({FUNC_NAMES.get(ft, 'unknown')}): "
                           "gvtlink imports time histories (1), FRFs (4) and coherence (6) only; remove it from the file"
                           )  # fmt: skip
    spec = d["ordinate_spec_data_type"]
    if ft != 6 and spec not in SPEC_QUANTITY and spec not in (0, 1):
        raise ImportError_(f"{where}: {_name(d)} holds {SPEC_NAMES.get(spec, f'specific data type {spec}')} "
                           f"[{d['ordinate_axis_units_lab'] or 'no unit'}]: not a vibration quantity; remove it from the file"
                           )  # fmt: skip


def _axis_factor(d: dict, prefix: str, units: dict | None, where: str, notes: list[str]) -> tuple[float, str]:
    """(factor to SI, quantity) of one axis: its unit label through pint, else its unit exponents with dataset
    164's factors (SI = value / length^le / force^fe), else refused."""
    label = d[f"{prefix}_axis_units_lab"]
    at = f"{where}: {_name(d)} {prefix} unit"
    quantity = SPEC_QUANTITY.get(d[f"{prefix}_spec_data_type"])
    if label and label.upper() != "NONE":
        factor, of_unit = si_factor(label, at)
        if quantity is not None and of_unit != quantity and {of_unit, quantity} != {"force", "pressure"}:
            raise ImportError_(f"{at} {label!r} is a {of_unit} unit, but the record's data type says {quantity}; "
                               "correct one of them")  # fmt: skip
        return factor, of_unit
    if units is None or quantity is None:
        return si_factor("", at)  # refused: no unit, and nothing in the file to take one from
    le, fe = d[f"{prefix}_len_unit_exp"], d[f"{prefix}_force_unit_exp"]
    factor = 1.0 / (float(units["length"]) ** le * float(units["force"]) ** fe)
    notes.append(f"{prefix} units without a label taken from dataset 164 ({units.get('units_description', '')}) "
                 "and the unit exponents")  # fmt: skip
    return factor, quantity


def _dof_name(ent: str, node: int, direction: int) -> str:
    tag = direction_label(direction) if direction in (1, 2, 3, -1, -2, -3) else f"d{direction}"
    return f"{ent}:{node}{tag}" if ent and ent.upper() != "NONE" else f"{node}{tag}"


def _names(dofs: list[tuple[int, int, str]]) -> list[str]:
    """A name per DOF: its entity name where that names one DOF only, else entity:node+direction (a roving hammer's
    one name at many nodes)."""
    ents = [e for _n, _d, e in dofs]
    return [e if e and e.upper() != "NONE" and ents.count(e) == 1 else _dof_name(e, n, d) for n, d, e in dofs]


def _channel(name: str, quantity: str, node: int, direction: int, geometry, notes: list[str]) -> Channel:
    if quantity == "pressure":
        raise ImportError_(f"{name}: a pressure (Pa) channel: gvtlink's channel table holds acceleration, velocity, "
                           "displacement and force only; remove it from the file")  # fmt: skip
    xyz = (0.0, 0.0, 0.0)
    if geometry is not None and node in geometry.ids:
        xyz = tuple(float(v) for v in geometry.xyz[list(geometry.ids).index(node)])
    if direction not in (1, 2, 3, -1, -2, -3):
        notes.append(f"{name}: direction code {direction} is not a translation; kept as +Z in the channel table")
        direction = 3
    return Channel(name, quantity, node, xyz, direction)


def _frf_import(frfs: list[dict], cohs: list[dict], others: list[dict], units: dict | None, geometry, prov: dict,
                notes: list[str]) -> FrfImport:  # fmt: skip
    where = prov["path"]
    outs = list(dict.fromkeys((d["rsp_node"], d["rsp_dir"], d["rsp_ent_name"]) for d in frfs))
    refs = list(dict.fromkeys((d["ref_node"], d["ref_dir"], d["ref_ent_name"]) for d in frfs))
    x = frfs[0]["x"]
    H = np.full((len(outs), len(refs), x.size), np.nan + 0j)
    forms = set()
    for d in frfs:
        if d["x"].size != x.size or not np.allclose(d["x"], x, rtol=1e-6, atol=1e-9 * max(1.0, float(x[-1]))):
            raise ImportError_(f"{where}: {_name(d)} has another frequency axis than the first FRF; one FRF set has one")
        a, qa = _axis_factor(d, "ordinate", units, where, notes)
        b, qb = _axis_factor(d, "orddenom", units, where, notes)
        if qb != "force" or qa not in FORMS:
            raise ImportError_(f"{where}: {_name(d)} is {qa} over {qb}: gvtlink takes accelerance, mobility or "
                               "receptance (a response over a force)")  # fmt: skip
        forms.add(FORMS[qa])
        H[outs.index((d["rsp_node"], d["rsp_dir"], d["rsp_ent_name"])),
          refs.index((d["ref_node"], d["ref_dir"], d["ref_ent_name"]))] = np.asarray(d["data"]) * (a / b)  # fmt: skip
    if len(forms) > 1:
        raise ImportError_(f"{where}: FRFs of several forms ({', '.join(sorted(forms))}); one FRF set has one")
    missing = np.argwhere(np.isnan(H[:, :, 0]))
    if missing.size:
        o, r = missing[0]
        raise ImportError_(f"{where}: the FRF matrix lacks {len(missing)} pair(s), e.g. node {outs[o][0]} over node "
                           f"{refs[r][0]}; every response needs an FRF for every reference")  # fmt: skip
    if not np.isfinite(H).all():
        raise ImportError_(f"{where}: the FRFs hold NaN or inf values")
    coherence, known = _coherence(cohs, outs, refs, H.shape), True
    if coherence is None:
        coherence, known = np.ones(H.shape), False
        notes.append("no coherence (dataset 58, type 6) for every FRF: coherence taken as 1 and not judged")
    out_names, ref_names = _names(outs), _names(refs)
    form = forms.pop()
    sigma = _window_sigma(frfs, others)
    window = {"force": "unknown", "tau_s": 1.0 / sigma if sigma else None, "sigma_added": sigma or 0.0}
    if sigma:
        notes.append(f"exponential window of the file's FRFs (sigma {sigma:.6g} 1/s, dataset 1858 / ID line 3) is "
                     "removed from the damping by gvt modal")  # fmt: skip
    kind, n_avg = _kind_and_averages(frfs, len(refs), notes)
    frf = FRFSet(freq=np.asarray(x, dtype=float), H=H, coherence=coherence, outputs=out_names, references=ref_names,
                 kind=kind, quantity=form, units=f"{ {'accelerance': 'm/s^2', 'mobility': 'm/s', 'receptance': 'm'}[form]}/N",
                 n_averages=n_avg, window=window,
                 quality={"warnings": [] if known else ["coherence not in the file: taken as 1, not judged"]})  # fmt: skip
    quantity = {v: k for k, v in FORMS.items()}[form]
    chans = [_channel(n, quantity, node, dr, geometry, notes) for n, (node, dr, _e) in zip(out_names, outs, strict=True)]
    chans += [_channel(n, "force", node, dr, geometry, notes) for n, (node, dr, _e) in zip(ref_names, refs, strict=True)]
    return FrfImport(frf, chans, Provenance(**prov, assumptions=tuple(dict.fromkeys(notes))), known, geometry)


def _coherence(cohs: list[dict], outs: list, refs: list, shape: tuple) -> np.ndarray | None:
    c = np.full(shape, np.nan)
    for d in cohs:
        o, r = (d["rsp_node"], d["rsp_dir"], d["rsp_ent_name"]), (d["ref_node"], d["ref_dir"], d["ref_ent_name"])
        if o in outs and r in refs and np.size(d["data"]) == shape[2]:
            c[outs.index(o), refs.index(r)] = np.clip(np.real(d["data"]), 0.0, 1.0)
    return None if np.isnan(c).any() else c


def _window_sigma(frfs: list[dict], others: list[dict]) -> float | None:
    """The exponential window's added decay (1/s) gvtlink's export states (dataset 1858 or ID line 3), else None."""
    for d in others:
        if d.get("type") == 1858 and int(d.get("window_type", 0)) == 6 and d.get("exponential_window_damping_factor"):
            return float(d["exponential_window_damping_factor"])
    m = _SIGMA.search(str(frfs[0].get("id3", "")))
    return float(m.group(1)) if m else None


def _kind_and_averages(frfs: list[dict], n_ref: int, notes: list[str]) -> tuple[str, np.ndarray]:
    first = str(frfs[0].get("id1", "")).split()
    kind = first[0] if first and first[0] in ("H1", "H2", "Hv") else "H1"
    if kind != (first[0] if first else ""):
        notes.append("FRF estimator not stated in the file: taken as H1")
    avgs: dict[tuple, int] = {}
    for d in frfs:
        m = re.search(r"(\d+) averages", str(d.get("id2", "")))
        if m:
            avgs.setdefault((d["ref_node"], d["ref_dir"], d["ref_ent_name"]), int(m.group(1)))
    return kind, (np.array(list(avgs.values()), dtype=int) if len(avgs) == n_ref else np.zeros(0, dtype=int))


def _time_import(times: list[dict], units: dict | None, geometry, prov: dict, notes: list[str]) -> TimeImport:
    """One channel per response DOF; a channel's records (hits) in time order on one grid, gaps filled with zeros
    (said once), overlaps refused."""
    where = prov["path"]
    dofs = list(dict.fromkeys((d["rsp_node"], d["rsp_dir"], d["rsp_ent_name"]) for d in times))
    dt = float(times[0]["abscissa_inc"])
    if not dt > 0 or any(d["abscissa_spacing"] != 1 for d in times):
        raise ImportError_(f"{where}: {_name(times[0])}: time histories need an even abscissa with a positive step")
    t0 = min(float(d["abscissa_min"]) for d in times)
    end = max(round((float(d["abscissa_min"]) - t0) / dt) + d["num_pts"] for d in times)
    spans: dict[int, list[tuple[int, int]]] = {}
    quantity: dict[int, str] = {}
    src_units: dict[int, str] = {}
    parts = []
    for d in times:
        if abs(float(d["abscissa_inc"]) / dt - 1) > 1e-5:
            raise ImportError_(f"{where}: {_name(d)} is sampled at {1 / float(d['abscissa_inc']):g} Hz, the first "
                               f"record at {1 / dt:g} Hz; one import has one rate")  # fmt: skip
        k = dofs.index((d["rsp_node"], d["rsp_dir"], d["rsp_ent_name"]))
        factor, q = _axis_factor(d, "ordinate", units, where, notes)
        if quantity.setdefault(k, q) != q:
            raise ImportError_(f"{where}: {_name(d)} is {q}, an earlier record of the same DOF {quantity[k]}")
        src_units[k] = d["ordinate_axis_units_lab"]
        a = round((float(d["abscissa_min"]) - t0) / dt)
        b = a + d["num_pts"]
        if any(a < y and x < b for x, y in spans.get(k, [])):
            raise ImportError_(f"{where}: {_name(d)} overlaps an earlier record of the same DOF in time")
        spans.setdefault(k, []).append((a, b))
        parts.append((k, a, b, d["data"], factor))
    covered = all(sum(b - a for a, b in spans.get(k, [])) == end for k in range(len(dofs)))
    data = (np.empty if covered else np.zeros)((end, len(dofs)), order="F")  # by column: a record is one copy
    for k, a, b, y, factor in parts:
        y = np.real(y)
        data[a:b, k] = y if factor == 1.0 else y * factor
    if not np.isfinite(data).all():
        raise ImportError_(f"{where}: the time histories hold NaN or inf values; a measurement has numbers")
    empty = max(end - sum(b - a for a, b in spans.get(k, [])) for k in range(len(dofs)))
    if empty:
        notes.append(f"{empty} samples between records (no data in the file) set to 0")
    if "force" not in quantity.values():
        raise ImportError_(f"{where}: no force channel (an ordinate in N or lbf): a hammer test needs the hammer's force")
    names = _names(dofs)
    chans = [_channel(n, quantity[k], node, dr, geometry, notes)
             for k, (n, (node, dr, _e)) in enumerate(zip(names, dofs, strict=True))]  # fmt: skip
    return TimeImport(data, 1.0 / dt, chans, Provenance(**prov, assumptions=tuple(dict.fromkeys(notes))),
                      [src_units[k] for k in range(len(dofs))], t0, geometry)  # fmt: skip


__all__ = ["SUFFIXES", "is_uff", "mode_shapes", "read"]
