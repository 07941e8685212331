"""Universal File Format (UFF) datasets through pyuff: geometry (15), trace lines (82), units (164), functions at
nodal DOFs (58: FRFs, coherence, time histories) and mode shapes (55).

Why UFF: it is what every modal package reads (Simcenter Testlab, ME'scope, DewesoftX, sdypy-EMA, pyuff); the
record layouts are those of the I-DEAS universal file reference (https://www.ceas3.uc.edu/sdrluff/, mirrored in
pyuff's ``get_structure_*``). pyuff (https://github.com/ladisk/pyuff) writes and reads them; this module only
builds its dataset dicts from arrays and channel-table entries (:class:`analysis.model.channels.Channel`: node,
direction, quantity), so it needs no FRF or modal object. ``frfset_sets`` takes anything shaped like
``analysis.frf.FRFSet``.

What the format keeps (measured in tests/test_uff.py): ordinates in double precision (58 writes E20.11, 12
digits, or raw float64 in binary 58b); the abscissa start and increment, a mode's eigenvalue and the 55 shape
values only as E13.5 (6 significant digits). A time increment 1/16384 s is stored as 6.10352e-05 (7e-7 relative):
the abscissa pyuff rebuilds drifts by 7e-7 of the record length; the samples themselves are exact to 1e-11.
Units: everything SI (dataset 164, code 1: m, N, K); each 58 also names its units (``*_axis_units_lab``) and
their length/force exponents. Entity names (the channel names) are cut to 10 characters by record 6's 10A1.

The exponential window (issue 29): gvtlink's FRFs of hammer hits are windowed (``analysis/frf.py``: every pole
gains the decay rate ``sigma_added`` = 1/tau), and ``gvt modal`` takes that back out of the damping. A reader of
the UFF file cannot know it from dataset 58 alone -- sdypy-EMA read gvtlink's FRFs with damping up to +197 %
(mode 1 of the demo) -- so each windowed FRF states it twice: its ID line 3 (``exp window sigma ... 1/s: zeta =
zeta_read - sigma/w``) and a dataset 1858 (the I-DEAS qualifiers of dataset 58: window type 6, impact and
exponential; field "exponential window damping factor" = sigma in 1/s) written just before it; and
:func:`window_note` gives ``gvt export`` its one-line warning. The FRFs themselves are exported as measured:
undoing the window needs the modal model (a pole shift), which is ``gvt modal``'s result, not the data.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from analysis.errors import BadInput
from analysis.model.channels import Channel
from analysis.model.wireframe import Geometry, make_geometry

#: UFF specific data types (dataset 58 records 8-11, dataset 55 record 6 field 4).
SPEC_DATA_TYPE = {"displacement": 8, "velocity": 11, "acceleration": 12, "force": 13}
TIME, FREQUENCY = 17, 18
#: SI units of each quantity and its (length, force) unit exponents, as record 8-11 fields 2-3 want them.
UNIT = {"displacement": ("m", 1, 0), "velocity": ("m/s", 1, 0), "acceleration": ("m/s^2", 1, 0), "force": ("N", 0, 1)}
#: FRF forms by the response quantity of the numerator (sdypy-EMA's ``read_uff`` reads the form from it too).
FRF_FORMS = {"receptance": "displacement", "mobility": "velocity", "accelerance": "acceleration"}
FUNC_TIME, FUNC_FRF, FUNC_COHERENCE = 1, 4, 6
#: Dataset 1858 record 2 field 2: window type 6 is "impact and exponential" (force window + response window).
WINDOW_IMPACT_EXPONENTIAL = 6
#: A UFF 82 trace line holds at most 250 node entries (record 1 field 2).
MAX_TRACE_NODES = 250


class UffError(BadInput):
    """Data that cannot be written as UFF as asked (one line, exit 2)."""


def units_set() -> dict[str, Any]:
    """Dataset 164: SI (meter, newton, kelvin), so importers scale nothing."""
    return {
        "type": 164,
        "units_code": 1,
        "units_description": "SI",
        "temp_mode": 2,
        "length": 1.0,
        "force": 1.0,
        "temp": 1.0,
        "temp_offset": 273.15,
    }


def geometry_sets(geometry: Geometry) -> list[dict[str, Any]]:
    """Dataset 15: every node in the global (0) coordinate system."""
    n = geometry.ids.size
    zeros = np.zeros(n, dtype=int)
    return [
        {
            "type": 15,
            "node_nums": geometry.ids.astype(int),
            "def_cs": zeros,
            "disp_cs": zeros,
            "color": zeros,
            "x": geometry.xyz[:, 0],
            "y": geometry.xyz[:, 1],
            "z": geometry.xyz[:, 2],
        }
    ]


def trace_polylines(lines: np.ndarray) -> list[list[int]]:
    """Lines (a, b) as UFF 82 node lists: consecutive lines that share an end become one stroke; a 0 before a node
    lifts the pen (record 3). Each list holds at most :data:`MAX_TRACE_NODES` entries."""
    out: list[list[int]] = []
    cur: list[int] = []
    for a, b in lines.tolist():
        if cur and cur[-1] == a and len(cur) < MAX_TRACE_NODES:
            cur.append(b)
            continue
        if cur and len(cur) + 3 <= MAX_TRACE_NODES:
            cur += [0, a, b]
            continue
        if cur:
            out.append(cur)
        cur = [a, b]
    if cur:
        out.append(cur)
    return out


def trace_line_sets(geometry: Geometry, name: str = "gvtlink") -> list[dict[str, Any]]:
    """Dataset 82: the geometry's lines, as few trace lines as 250 entries each allow."""
    return [
        {"type": 82, "trace_num": k + 1, "color": 0, "id": f"{name} lines {k + 1}"[:80], "nodes": np.asarray(p, dtype=int)}
        for k, p in enumerate(trace_polylines(geometry.lines))
    ]


def trace_pairs(nodes: Sequence[float]) -> list[tuple[int, int]]:
    """The (a, b) lines of a UFF 82 node list read back (0: pen up before the next node)."""
    pairs, prev, pen_up = [], None, True
    for v in (round(float(x)) for x in nodes):
        if v == 0:
            pen_up = True
            continue
        if prev is not None and not pen_up:
            pairs.append((prev, v))
        prev, pen_up = v, False
    return pairs


def _axis(prefix: str, spec: int, label: str, units: str, length_exp: int = 0, force_exp: int = 0) -> dict[str, Any]:
    return {
        f"{prefix}_spec_data_type": spec,
        f"{prefix}_len_unit_exp": length_exp,
        f"{prefix}_force_unit_exp": force_exp,
        f"{prefix}_temp_unit_exp": 0,
        f"{prefix}_axis_lab": label[:20],
        f"{prefix}_axis_units_lab": units[:20],
    }


def _quantity_axis(prefix: str, quantity: str) -> dict[str, Any]:
    units, le, fe = UNIT[quantity]
    return _axis(prefix, SPEC_DATA_TYPE[quantity], quantity, units, le, fe)


def function_set(
    func_type: int,
    x: np.ndarray,
    data: np.ndarray,
    response: Channel,
    reference: Channel | None,
    ids: Sequence[str],
    *,
    binary: bool = False,
    ver_num: int = 0,
    func_id: int = 0,
) -> dict[str, Any]:
    """One dataset 58 at (response node, direction) / (reference node, direction); the abscissa is even when ``x`` is
    (to 1e-9), else stored point by point. NaN/inf are refused (pyuff would write them as 0)."""
    data = np.asarray(data)
    if not np.all(np.isfinite(data)):
        raise UffError(f"{response.name}: {ids[0]!r} holds NaN or inf; UFF cannot carry them")
    dx = np.diff(x)
    even = x.size > 1 and bool(np.allclose(dx, dx[0], rtol=1e-9, atol=0))
    ref = reference if reference is not None else response
    out = {
        "type": 58,
        "binary": int(binary),
        "func_type": func_type,
        "func_id": func_id,
        "ver_num": ver_num,
        "load_case_id": 0,
        "rsp_ent_name": response.name[:10],
        "rsp_node": response.node,
        "rsp_dir": response.direction,
        "ref_ent_name": ref.name[:10] if reference is not None else "NONE",
        "ref_node": ref.node if reference else 0,
        "ref_dir": ref.direction if reference else 0,
        "abscissa_spacing": int(even),
        "x": np.asarray(x, dtype=float),
        "data": data.astype(complex if np.iscomplexobj(data) else float),
        "z_axis_value": 0.0,
        **_axis("z_axis", 0, "NONE", "NONE"),
    }
    for k, text in enumerate(ids[:5]):
        out[f"id{k + 1}"] = str(text)[:80] or "NONE"
    return out


def time_sets(
    data: np.ndarray,
    fs: float,
    channels: Sequence[Channel],
    reference: Channel,
    *,
    t0: float = 0.0,
    hit: int = 0,
    binary: bool = False,
    first_id: int = 1,
) -> list[dict[str, Any]]:
    """Datasets 58 (function type 1, time response) of one hit record ``data`` (n_samples, n_channels) in SI units,
    one per channel; the reference DOF is the hammer's (single-point excitation), the version number the hit + 1."""
    data = np.asarray(data, dtype=float)
    if data.ndim != 2 or data.shape[1] != len(channels):
        raise UffError(f"time data of shape {data.shape} for {len(channels)} channels")
    t = t0 + np.arange(data.shape[0]) / fs
    out = []
    for k, ch in enumerate(channels):
        ids = (f"hit {hit} {ch.name} [{ch.unit}]", f"time history, {fs:g} Hz, t0 {t0:.6f} s", "gvtlink", "NONE", "NONE")
        d = function_set(FUNC_TIME, t, data[:, k], ch, reference, ids, binary=binary, ver_num=hit + 1, func_id=first_id + k)
        d.update(
            _axis("abscissa", TIME, "time", "s"),
            **_quantity_axis("ordinate", ch.quantity),
            **_axis("orddenom", 0, "NONE", "NONE"),
        )
        out.append(d)
    return out


def frf_sets(
    freq: np.ndarray,
    H: np.ndarray,
    outputs: Sequence[Channel],
    references: Sequence[Channel],
    *,
    coherence: np.ndarray | None = None,
    form: str = "accelerance",
    kind: str = "H1",
    n_averages: Sequence[int] | None = None,
    binary: bool = False,
    first_id: int = 1,
    sigma_added: float | None = None,
) -> list[dict[str, Any]]:
    """Datasets 58: an FRF (function type 4) per (output, reference) pair of ``H`` (n_out, n_ref, n_f), response
    quantity by ``form`` over force, then its coherence (type 6, dimensionless) when given. ``sigma_added`` (1/s):
    the exponential window's added decay, stated in ID line 3 and in a dataset 1858 before each FRF."""
    H = np.asarray(H)
    if H.ndim != 3 or H.shape[:2] != (len(outputs), len(references)) or H.shape[2] != np.size(freq):
        raise UffError(f"H of shape {H.shape} for {len(outputs)} outputs x {len(references)} references x {np.size(freq)} lines")
    if form not in FRF_FORMS:
        raise UffError(f"FRF form {form!r}: use one of {sorted(FRF_FORMS)}")
    num = FRF_FORMS[form]
    units = f"{UNIT[num][0]}/N"
    out, fid = [], first_id
    for r, ref in enumerate(references):
        navg = "" if n_averages is None else f", {int(n_averages[r])} averages"
        for o, resp in enumerate(outputs):
            ids = (f"{kind} {resp.name}/{ref.name} [{units}]", f"{form}{navg}", window_id(sigma_added), "NONE", "NONE")
            d = function_set(FUNC_FRF, np.asarray(freq, dtype=float), H[o, r], resp, ref, ids, binary=binary, func_id=fid)
            if sigma_added:
                out.append(window_qualifier_set(float(sigma_added), resp, ref))
            d.update(
                _axis("abscissa", FREQUENCY, "frequency", "Hz"),
                **_quantity_axis("ordinate", num),
                **_quantity_axis("orddenom", "force"),
            )
            out.append(d)
            fid += 1
            if coherence is not None:
                ids = (f"coherence {resp.name}/{ref.name}", f"{kind}{navg}", "gvtlink", "NONE", "NONE")
                c = function_set(
                    FUNC_COHERENCE,
                    np.asarray(freq, dtype=float),
                    np.asarray(coherence)[o, r],
                    resp,
                    ref,
                    ids,
                    binary=binary,
                    func_id=fid,
                )
                c.update(
                    _axis("abscissa", FREQUENCY, "frequency", "Hz"),
                    **_axis("ordinate", 0, "coherence", "1"),
                    **_axis("orddenom", 0, "NONE", "NONE"),
                )
                out.append(c)
                fid += 1
    return out


def frfset_sets(frf: Any, channels: Mapping[str, Channel], *, binary: bool = False) -> list[dict[str, Any]]:
    """:func:`frf_sets` of an ``analysis.frf.FRFSet`` (or anything with its fields), channels looked up by name."""
    missing = [n for n in (*frf.outputs, *frf.references) if n not in channels]
    if missing:
        raise UffError(f"FRF channels {missing} are not in the channel table ({sorted(channels)}); give them a node")
    navg = getattr(frf, "n_averages", None)
    return frf_sets(
        frf.freq,
        frf.H,
        [channels[n] for n in frf.outputs],
        [channels[n] for n in frf.references],
        coherence=frf.coherence,
        form=frf.quantity,
        kind=frf.kind,
        n_averages=navg if navg is not None and len(navg) == len(frf.references) else None,
        binary=binary,
        sigma_added=frf_sigma_added(frf),
    )


def frf_sigma_added(frf: Any) -> float | None:
    """The exponential window's added decay (1/s) of an FRFSet-like object, or None when it has none."""
    window = getattr(frf, "window", None) or {}
    sigma = window.get("sigma_added") if isinstance(window, Mapping) else None
    return float(sigma) if sigma else None


def window_id(sigma_added: float | None) -> str:
    """ID line 3 of a windowed FRF (80 characters at most): the decay the window added and how to take it out."""
    if not sigma_added:
        return "gvtlink, no exponential window"
    return f"exp window sigma {sigma_added:.6g} 1/s (gvtlink): zeta = zeta_read - sigma/w"


def window_qualifier_set(sigma_added: float, response: Channel, reference: Channel) -> dict[str, Any]:
    """Dataset 1858 (qualifiers of the dataset 58 that follows): window type 6 (impact and exponential) and the
    exponential window damping factor, written as the added decay rate sigma in 1/s."""
    def direction(ch: Channel) -> str:
        return f"{'XYZ'[abs(ch.direction) - 1]}{'+' if ch.direction > 0 else '-'}"

    zeros = dict.fromkeys(("z_rpm_value", "z_time_value", "z_order_value", "num_of_samples", "user_value_1",
                           "user_value_2", "user_value_3", "user_value_4"), 0.0)  # fmt: skip
    ints = dict.fromkeys(("octave_format", "measurement_run", "weighting_type", "amplitude_units",
                          "normalization_method", "abscissa_data_type_qualifier", "ordinate_numerator_data_type_qualifier",
                          "ordinate_denominator_data_type_qualifier", "z_axis_data_type_qualifier", "sampling_type"),
                         0)  # fmt: skip
    return {"type": 1858, "record_num": 1, **ints, **zeros, "window_type": WINDOW_IMPACT_EXPONENTIAL,
            "exponential_window_damping_factor": float(sigma_added), "response_direction": direction(response),
            "reference_direction": direction(reference)}  # fmt: skip


def window_note(frf: Any) -> str | None:
    """``gvt export``'s one-line warning for windowed FRFs (None without a window)."""
    sigma = frf_sigma_added(frf)
    if sigma is None:
        return None
    return (f"the FRFs carry the exponential window (every pole's decay + {sigma:.4g} 1/s): damping read from them "
            "is high by sigma/w (stated in each FRF's ID line 3 and dataset 1858); gvt modal's modes file has it "
            "removed")  # fmt: skip


def _node_components(shape: np.ndarray, outputs: Sequence[Channel]) -> tuple[np.ndarray, np.ndarray]:
    """One mode's values per output placed on (node, X/Y/Z) with the direction's sign: (node ids, (3, n_nodes))."""
    nodes = sorted({c.node for c in outputs})
    col = {n: i for i, n in enumerate(nodes)}
    r = np.zeros((3, len(nodes)), dtype=shape.dtype)
    filled = np.zeros((3, len(nodes)), dtype=bool)
    for value, ch in zip(shape, outputs, strict=True):
        axis, j = abs(ch.direction) - 1, col[ch.node]
        if filled[axis, j]:
            raise UffError(f"two outputs on node {ch.node} direction {'XYZ'[axis]} ({ch.name}); a mode shape has one value there")
        r[axis, j] = np.sign(ch.direction) * value
        filled[axis, j] = True
    return np.asarray(nodes, dtype=int), r


def mode_quality_id(row: Mapping[str, Any]) -> str:
    """A modes-file row's quality figures as a dataset 55 ID line (80 characters at most): MPC, stability count,
    share of the FRFs, the FE partner with Δf and MAC, and ``ok`` or the kinds of its flags."""
    fe = (f" FE{row['fe_mode']} df{100 * row['freq_error']:+.2f}% MAC{row['mac']:.3f}" if row.get("fe_mode") else
          (" FE unpaired" if "fe_mode" in row else ""))  # fmt: skip
    kinds = ",".join(dict.fromkeys(str(f).split(":")[0] for f in row.get("flags", []))) or "ok"
    nan = float("nan")
    text = f"MPC{row.get('mpc', nan):.3f} stab{row.get('stability', 0)} share{row.get('contribution', nan):.2f}{fe} {kinds}"
    return text[:80]


def mode_shape_sets(
    freq_hz: Sequence[float], zeta: Sequence[float], shapes: np.ndarray, outputs: Sequence[Channel], name: str = "gvtlink",
    notes: Sequence[str] | None = None,
) -> list[dict[str, Any]]:
    """Dataset 55, one per mode: complex shapes (n_out, n_modes) as complex modes (analysis type 3) with the
    eigenvalue ``lambda = -zeta w + i w sqrt(1 - zeta^2)`` (rad/s); real shapes as normal modes (type 2) with
    frequency (Hz) and viscous damping ratio. A value goes to its channel's node, in r1/r2/r3 by X/Y/Z, with the
    direction's sign (a -Z accelerometer's value is minus the +Z displacement). ``notes``: one ID line 2 per mode
    (``gvt modal``'s quality figures, :func:`mode_quality_id`)."""
    shapes = np.asarray(shapes)
    if shapes.ndim != 2 or shapes.shape != (len(outputs), len(freq_hz)) or len(zeta) != len(freq_hz):
        raise UffError(
            f"mode shapes {shapes.shape} for {len(outputs)} outputs x {len(freq_hz)} modes ({len(zeta)} damping ratios)"
        )
    if not np.all(np.isfinite(shapes)):
        raise UffError("mode shapes hold NaN or inf; UFF cannot carry them")
    out = []
    for m, (f, z) in enumerate(zip(freq_hz, zeta, strict=True)):
        nodes, r = _node_components(shapes[:, m], outputs)
        d: dict[str, Any] = {
            "type": 55,
            "id1": f"{name} mode {m + 1}: {f:.6g} Hz, zeta {z:.6g}",
            "id2": (notes[m] if notes is not None and m < len(notes) else "NONE")[:80] or "NONE",
            "id3": "NONE",
            "id4": "NONE",
            "id5": "NONE",
            "model_type": 1,
            "data_ch": 2,
            "spec_data_type": 8,
            "load_case": 1,
            "mode_n": m + 1,
            "node_nums": nodes,
            "r1": r[0],
            "r2": r[1],
            "r3": r[2],
        }
        w = 2.0 * np.pi * float(f)
        if np.iscomplexobj(shapes):
            d.update(analysis_type=3, eig=complex(-z * w, w * np.sqrt(1.0 - z * z)), modal_a=0j, modal_b=0j)
        else:
            d.update(analysis_type=2, freq=float(f), modal_m=0.0, modal_damp_vis=float(z), modal_damp_his=0.0)
        out.append(d)
    return out


def mode_from_set(d: Mapping[str, Any]) -> tuple[float, float, np.ndarray, np.ndarray]:
    """A dataset 55 read back: (frequency Hz, damping ratio, node ids, (3, n_nodes) values)."""
    r = np.vstack([d["r1"], d["r2"], d["r3"]])
    if d["analysis_type"] == 2:
        return float(d["freq"]), float(d.get("modal_damp_vis", 0.0)), np.asarray(d["node_nums"], dtype=int), r
    lam = complex(d["eig"])
    w = abs(lam)
    return w / (2.0 * np.pi), -lam.real / w, np.asarray(d["node_nums"], dtype=int), r


def write_uff(path: str | Path, sets: Sequence[dict[str, Any]]) -> None:
    """Write ``sets`` to ``path`` (replacing it) through pyuff. pyuff re-reads the whole file after each set it
    writes (``UFF.refresh``: its index of the sets, for reading), quadratic in the sets: an export of 438 sets spent
    three quarters of its time there. Nothing is read here, so the index is not kept; the bytes written are the same
    (tests/test_modal_cmd.py compares them)."""
    import pyuff

    class _Writer(pyuff.UFF):
        def refresh(self) -> bool:  # the index is for reading; write_sets calls this after every set
            return True

    if not sets:
        raise UffError("nothing to write")
    _Writer(str(path)).write_sets(list(sets), mode="overwrite")


def read_uff(path: str | Path) -> list[dict[str, Any]]:
    """Every dataset of a UFF file as pyuff reads it (always a list)."""
    import pyuff

    sets = pyuff.UFF(str(path)).read_sets()
    return [sets] if isinstance(sets, dict) else list(sets)


def geometry_from_sets(sets: Sequence[Mapping[str, Any]]) -> Geometry:
    """The geometry of datasets 15 and 82 read back."""
    nodes = [
        (int(n), x, y, z)
        for d in sets
        if d.get("type") == 15
        for n, x, y, z in zip(d["node_nums"], d["x"], d["y"], d["z"], strict=True)
    ]
    lines = [p for d in sets if d.get("type") == 82 for p in trace_pairs(d["nodes"])]
    return make_geometry(nodes, lines)


__all__ = [
    "FRF_FORMS",
    "SPEC_DATA_TYPE",
    "UNIT",
    "UffError",
    "frf_sets",
    "frf_sigma_added",
    "frfset_sets",
    "function_set",
    "geometry_from_sets",
    "geometry_sets",
    "mode_from_set",
    "mode_quality_id",
    "mode_shape_sets",
    "read_uff",
    "time_sets",
    "trace_line_sets",
    "trace_pairs",
    "trace_polylines",
    "units_set",
    "window_id",
    "window_note",
    "window_qualifier_set",
    "write_uff",
]
