"""Identified mode shapes drawn and animated on the test geometry, written as a rerun recording (``gvt modal --rrd``).

Why: a table of frequencies and MACs says whether a mode was found; the animation says which mode it is (bending,
torsion, a local mode of one sensor). This is the classic "animated mode shape on the wire frame" of every modal
package (e.g. the UFF 15/82/55 viewers; Ewins, *Modal Testing*, 2nd ed., §6.9).

What is drawn, per identified mode k (entity ``/modes/m<k>``):

* the undeformed geometry (``/modes/geometry``: nodes and trace lines, grey, static), and
* the deformed one, node ``n`` at ``xyz_n + scale · Re(u_n · e^{iθ})`` for θ = 2π j / frames, j = 0..frames-1, on a
  timeline of its own (``mode<k>``: sequence j), so picking that timeline in the viewer plays that mode over one
  period and shows no other mode. ``u_n`` (complex, 3-vector) is the sum of each channel's shape entry times its
  direction (a UFF direction code ±1..3) at the channel's node; a node no channel measures gets the harmonic
  interpolation of its neighbours along the trace lines (weights 1/length: linear along a chain, constant beyond
  the last measured node), and a node on a part of the geometry with no measured node stays undeformed.
* ``scale`` makes the largest displacement over the nodes and the period 10 % of the geometry's extent (the
  largest side of its bounding box). For a node, max over θ of |Re(u e^{iθ})| is the largest singular value of the
  3 x 2 matrix [Re u, Im u].
* the mode's frequency, damping and MAC (when paired with the FE model) as a text entity and the line's label.

Complex shapes are drawn as identified (no rotation to real): a mode with a large MPD shows a travelling wave.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from analysis.errors import BadInput
from analysis.model.channels import Channel
from analysis.model.wireframe import Geometry

ROOT = "/modes"
GEOMETRY = "/modes/geometry"
FRAMES = 24  # frames per period
EXTENT_FRACTION = 0.10  # the largest displacement, as a fraction of the geometry's extent
GREY = (150, 150, 150)
MODE_COLOR = (214, 39, 40)


def mode_entity(k: int) -> str:
    """Entity of mode ``k`` (1-based, as ``gvt modal`` numbers them)."""
    return f"{ROOT}/m{k}"


def mode_timeline(k: int) -> str:
    return f"mode{k}"


def direction_vector(code: int) -> np.ndarray:
    """UFF direction code ±1..3 -> unit vector along ±X, ±Y, ±Z."""
    v = np.zeros(3)
    v[abs(int(code)) - 1] = np.sign(code)
    return v


def channel_displacements(geometry: Geometry, channels: Sequence[Channel], shapes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Complex node displacements (n_nodes, 3, n_modes) from ``shapes`` (n_channels, n_modes), one row per channel,
    and which nodes are measured (n_nodes,) bool. Channels on the same node and axis are averaged (two sensors
    measuring the same DOF); different axes add up to the node's 3-D motion."""
    shapes = np.asarray(shapes, dtype=complex).reshape(len(channels), -1)
    index = {int(n): i for i, n in enumerate(geometry.ids)}
    total = np.zeros((geometry.ids.size, 3, shapes.shape[1]), dtype=complex)
    count = np.zeros((geometry.ids.size, 3))
    for ch, row in zip(channels, shapes, strict=True):
        if ch.node not in index:
            raise BadInput(f"channel {ch.name}: node {ch.node} is not in the test geometry (nodes {geometry.ids.tolist()})")
        axis, sign = abs(ch.direction) - 1, np.sign(ch.direction)
        total[index[ch.node], axis] += sign * row
        count[index[ch.node], axis] += 1
    disp = total / np.maximum(count, 1)[:, :, None]
    return disp, count.sum(axis=1) > 0


def interpolate_unmeasured(geometry: Geometry, disp: np.ndarray, measured: np.ndarray) -> np.ndarray:
    """Fill unmeasured nodes by harmonic interpolation along the trace lines (graph Laplacian, edge weight
    1/length, measured nodes fixed): on a chain this is linear interpolation in distance. Unmeasured nodes with
    no path to a measured one keep zero displacement."""
    n = geometry.ids.size
    index = {int(i): k for k, i in enumerate(geometry.ids)}
    lap = np.zeros((n, n))
    for a, b in geometry.lines.tolist():
        i, j = index[a], index[b]
        w = 1.0 / max(float(np.linalg.norm(geometry.xyz[i] - geometry.xyz[j])), 1e-12)
        lap[i, j] -= w
        lap[j, i] -= w
        lap[i, i] += w
        lap[j, j] += w
    reach = _reachable(lap, measured)
    free = np.flatnonzero(~measured & reach)
    out = disp.copy()
    out[~measured] = 0.0
    if free.size:
        fixed = np.flatnonzero(measured)
        rhs = -lap[np.ix_(free, fixed)] @ disp[fixed].reshape(fixed.size, -1)
        out[free] = np.linalg.solve(lap[np.ix_(free, free)], rhs).reshape(free.size, *disp.shape[1:])
    return out


def _reachable(lap: np.ndarray, seeds: np.ndarray) -> np.ndarray:
    """Nodes connected (by the Laplacian's off-diagonal) to any seed node."""
    adj = (lap != 0) & ~np.eye(lap.shape[0], dtype=bool)
    seen = seeds.copy()
    frontier = seeds.copy()
    while frontier.any():
        frontier = adj[frontier].any(axis=0) & ~seen
        seen |= frontier
    return seen


def extent(xyz: np.ndarray) -> float:
    """The largest side of the bounding box (m); 1 for a single point (nothing else to measure by)."""
    e = float(np.ptp(xyz, axis=0).max()) if len(xyz) else 0.0
    return e if e > 0 else 1.0


def peak_amplitude(u: np.ndarray) -> float:
    """max over nodes and θ of |Re(u_n e^{iθ})| for u (n_nodes, 3) complex: the largest singular value of [Re u, Im u]."""
    m = np.stack([u.real, u.imag], axis=-1)  # (n, 3, 2)
    return float(np.linalg.svd(m, compute_uv=False).max()) if len(u) else 0.0


def mode_scale(u: np.ndarray, xyz: np.ndarray, fraction: float = EXTENT_FRACTION) -> float:
    """The factor that makes the largest displacement ``fraction`` of the geometry's extent (0 for a null shape)."""
    peak = peak_amplitude(u)
    return fraction * extent(xyz) / peak if peak > 0 else 0.0


def deformed_frames(xyz: np.ndarray, u: np.ndarray, scale: float, frames: int = FRAMES) -> np.ndarray:
    """(frames, n_nodes, 3): ``xyz + scale · Re(u e^{iθ_j})``, θ_j = 2π j / frames (j = 0 is Re(u))."""
    theta = 2 * np.pi * np.arange(frames) / frames
    return xyz[None] + scale * np.real(u[None] * np.exp(1j * theta)[:, None, None])


def mode_label(row: dict) -> str:
    """``mode 2: 84.31 Hz, ζ 1.02 %, MAC 0.998 (FE 2)``; without an FE pairing, no MAC."""
    text = f"mode {row['mode']}: {row['freq_hz']:.2f} Hz, ζ {100 * row['zeta']:.2f} %"
    if "mac" in row:
        text += f", MAC {row['mac']:.3f} (FE {row['fe_mode']})"
    return text


def line_strips(geometry: Geometry, pos: np.ndarray) -> list[np.ndarray]:
    index = {int(i): k for k, i in enumerate(geometry.ids)}
    return [pos[[index[a], index[b]]] for a, b in geometry.lines.tolist()]


def write_mode_rrd(out: str | Path, geometry: Geometry, channels: Sequence[Channel], shapes: np.ndarray,
                   rows: Sequence[dict], frames: int = FRAMES) -> dict[int, float]:  # fmt: skip
    """Write ``out`` (.rrd with its blueprint): the geometry and one animated entity per mode (module docstring).
    ``channels`` are the responses in the order of ``shapes``' rows; returns each mode's scale (m per shape unit)."""
    import rerun as rr

    from daq.view.recording import new_recording

    disp, measured = channel_displacements(geometry, channels, shapes)
    disp = interpolate_unmeasured(geometry, disp, measured)
    xyz = geometry.xyz
    rec = new_recording()
    rec.save(str(out), default_blueprint=mode_blueprint())
    scales: dict[int, float] = {}
    try:
        rec.log(f"{GEOMETRY}/nodes", rr.Points3D(xyz, colors=GREY, labels=[str(i) for i in geometry.ids]), static=True)
        rec.log(f"{GEOMETRY}/lines", rr.LineStrips3D(line_strips(geometry, xyz), colors=GREY), static=True)
        for j, row in enumerate(rows):
            k, u = int(row["mode"]), disp[:, :, j]
            scales[k] = mode_scale(u, xyz)
            label = mode_label(row)
            rec.set_time(mode_timeline(k), sequence=0)
            rec.log(f"{mode_entity(k)}/info", rr.TextDocument(label))
            for f, pos in enumerate(deformed_frames(xyz, u, scales[k], frames)):
                rec.set_time(mode_timeline(k), sequence=f)
                rec.log(f"{mode_entity(k)}/nodes", rr.Points3D(pos, colors=MODE_COLOR))
                strips = line_strips(geometry, pos)
                rec.log(f"{mode_entity(k)}/lines", rr.LineStrips3D(strips, colors=MODE_COLOR, labels=label if f == 0 else None))
            rec.reset_time()
    finally:
        rec.flush()
        rec.disconnect()
    return scales


def mode_blueprint():
    """One 3-D view over the geometry and the modes; pick a ``mode<k>`` timeline to play that mode."""
    import rerun.blueprint as rrb

    return rrb.Blueprint(rrb.Spatial3DView(origin=ROOT, name="mode shapes (pick a mode<k> timeline)"), collapse_panels=False)


def rig_response_channels(rig, outputs: Sequence[str]) -> list[Channel]:
    """The rig's channel (node, direction) of each response, in the order of the shapes' rows; BadInput naming
    the first response the rig does not know."""
    from analysis.model.channels import by_name, rig_channels

    known = by_name(rig_channels(rig))
    missing = [o for o in outputs if o not in known]
    if missing:
        raise BadInput(f"response {missing[0]!r} is not a channel of rig {rig.name!r}; give the rig it was measured on (--rig)")
    return [known[o] for o in outputs]


def write_modal_run_rrd(run, rig, out: str | Path, frames: int = FRAMES) -> dict[int, float]:
    """``gvt modal --rrd``: :func:`write_mode_rrd` for a ``daq.studies.modal.ModalRun`` on ``rig``'s test geometry."""
    from analysis.model.geometry import rig_geometry

    if rig is None:
        raise BadInput("--rrd draws the modes on the rig's test geometry: give --rig (an FRF file carries none)")
    channels = rig_response_channels(rig, list(run.frf.outputs))
    return write_mode_rrd(out, rig_geometry(rig), channels, run.result.shapes, run.rows, frames)


__all__ = [
    "channel_displacements", "deformed_frames", "direction_vector", "extent", "interpolate_unmeasured", "mode_blueprint",
    "mode_entity", "mode_label", "mode_scale", "mode_timeline", "peak_amplitude", "rig_response_channels",
    "write_modal_run_rrd", "write_mode_rrd",
]  # fmt: skip
