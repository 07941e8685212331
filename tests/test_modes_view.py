"""Mode shapes animated on the test geometry (``gvt modal --rrd``, daq/view/modes.py).

Data: the linear ``beam_ch4_exp`` session of tests/test_frf.py (five 200 N hits, 1 % noise, and a refused 3000 N overload) through
``gvt modal``.
Oracle for the drawing: the modes file that the same ``gvt modal`` call writes (``--modes-out``: the ModalRun's
shapes, by daq/studies/modal.py) and the rig's channel table (node coordinates, directions), combined here by hand:
at phase 0 node = xyz + scale · Re(shape) · direction, with scale = 10 % of the extent / max |shape| (one
channel per node on a beam, so the peak over the period of a node's displacement is |shape|). The .rrd is checked by
the bundled ``rerun rrd verify``/``rrd print`` and read back by rerun's ``RrdReader``; positions are float32: rel 1e-5.
"""

from __future__ import annotations

import json
import re
import subprocess

import numpy as np
import pytest

from daq.cli import run as gvt

from .test_frf import FORCE, shared_session
from .test_view import ENV, RERUN, rrd_verify

pytestmark = pytest.mark.skipif(not RERUN.exists(), reason="the rerun CLI is not installed next to python")


@pytest.fixture(scope="module")
def linear(tmp_path_factory):
    return shared_session(tmp_path_factory, 0.01, 0.01, (FORCE,) * 5 + (3000.0,))  # tests/test_frf.py's ``clean``


def rrd_frames(path) -> dict[str, dict[int, np.ndarray]]:
    """Points3D positions of each /modes entity by frame, read back with rerun's own RrdReader (float32)."""
    from rerun.chunk import RrdReader

    out: dict[str, dict[int, np.ndarray]] = {}
    for ch in RrdReader(path).stream():
        rb = ch.to_record_batch()
        if "Points3D:positions" in rb.schema.names:
            seq = [n for n in rb.schema.names if n.startswith("mode")]
            frames = rb.column(seq[0]).to_pylist() if seq else [None] * rb.num_rows
            pos = rb.column("Points3D:positions").to_pylist()
            out.setdefault(ch.entity_path, {}).update({f: np.asarray(x) for f, x in zip(frames, pos, strict=True)})
    return out


def test_gvt_modal_rrd_draws_each_mode_on_the_geometry(linear, tmp_path):
    from analysis.model.channels import by_name, rig_channels
    from analysis.model.geometry import rig_geometry

    rig, log = linear
    rrd, modes = tmp_path / "modes.rrd", tmp_path / "modes.json"
    assert gvt(["modal", str(log), "--rrd", str(rrd), "--modes-out", str(modes)]) == 0
    assert rrd_verify(rrd).returncode == 0
    p = subprocess.run([str(RERUN), "rrd", "print", "-vvv", str(rrd)], capture_output=True, text=True, env=ENV, timeout=60)
    assert p.returncode == 0, p.stderr
    m = json.loads(modes.read_text())
    n_modes = len(m["freq_hz"])
    assert n_modes >= 6
    paths = set(re.findall(r"- (/modes/[\w/]+) -", p.stdout))
    want = {"/modes/geometry/nodes", "/modes/geometry/lines"}
    want |= {f"/modes/m{k}/{e}" for k in range(1, n_modes + 1) for e in ("nodes", "lines", "info")}
    assert want <= paths, sorted(want - paths)
    assert f"mode 1: {m['freq_hz'][0]:.2f} Hz" in p.stdout and "MAC " in p.stdout
    frames = rrd_frames(rrd)
    assert all(sorted(frames[f"/modes/m{k}/nodes"]) == list(range(24)) for k in range(1, n_modes + 1))

    geometry = rig_geometry(rig)
    chans = by_name(rig_channels(rig))
    shapes = np.asarray(m["shapes_re"]) + 1j * np.asarray(m["shapes_im"])
    assert len({chans[o].node for o in m["outputs"]}) == len(m["outputs"])  # one response per node on this beam
    extent = np.ptp(geometry.xyz, axis=0).max()
    for k in (1, 3):
        u = shapes[:, k - 1]
        scale = 0.1 * extent / np.abs(u).max()
        for frame, part in ((0, u.real), (6, -u.imag)):  # 24 frames: frame 6 is θ = π/2, Re(u·i) = -Im u
            got = frames[f"/modes/m{k}/nodes"][frame]
            assert got.shape == geometry.xyz.shape
            for o, s in zip(m["outputs"], part, strict=True):
                c = chans[o]
                direction = np.sign(c.direction) * np.eye(3)[abs(c.direction) - 1]
                i = int(np.flatnonzero(geometry.ids == c.node)[0])
                np.testing.assert_allclose(got[i], np.asarray(c.xyz) + scale * s * direction, rtol=1e-5, atol=1e-6 * extent)
        peak = max(np.linalg.norm(f - geometry.xyz, axis=1).max() for f in frames[f"/modes/m{k}/nodes"].values())
        assert peak <= 0.1 * extent * (1 + 1e-5)


def test_unmeasured_nodes_interpolate_along_lines_and_scale_is_ten_percent():
    from analysis.model.channels import Channel
    from analysis.model.wireframe import make_geometry
    from daq.view.modes import channel_displacements, deformed_frames, interpolate_unmeasured, mode_scale

    # chain 1-2-3 with node 2 at x = 0.5 of 2 m (not the midpoint), and node 4 joined to nothing measured
    g = make_geometry([(1, 0, 0, 0), (2, 0.5, 0, 0), (3, 2, 0, 0), (4, 0, 5, 0), (5, 0, 6, 0)], [(1, 2), (2, 3), (4, 5)])
    chans = [Channel("a", "acceleration", 1, (0, 0, 0), 3), Channel("b", "acceleration", 3, (2, 0, 0), -3),
             Channel("c", "acceleration", 1, (0, 0, 0), 2)]  # fmt: skip
    shapes = np.array([[1.0 + 1.0j], [0.2 - 0.6j], [0.5 + 0.0j]])
    disp, measured = channel_displacements(g, chans, shapes)
    assert measured.tolist() == [True, False, True, False, False]
    disp = interpolate_unmeasured(g, disp, measured)
    w3 = -(0.2 - 0.6j)  # -Z sensor
    assert disp[1, 2, 0] == pytest.approx(0.75 * (1 + 1j) + 0.25 * w3)  # linear in distance, not in steps
    assert disp[1, 1, 0] == pytest.approx(0.75 * 0.5)
    assert np.all(disp[3:] == 0)
    u = disp[:, :, 0]
    scale = mode_scale(u, g.xyz)
    frames = deformed_frames(g.xyz, u, scale, 360)
    peak = np.linalg.norm(frames - g.xyz, axis=2).max()  # dense sampling of the period against the SVD peak
    assert peak == pytest.approx(0.1 * 6.0, rel=1e-4)
