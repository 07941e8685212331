"""Rigs whose linear model comes from an FE code: mass, stiffness (and damping) matrices at the measured DOFs.

A real airframe is modelled in Nastran, Abaqus or Ansys, not as a TOML beam; the seed itself took a 210-DOF
Guyan-reduced plane model out of Abaqus (L1852-L1856) into MATLAB. A ``[structure] kind = "matrices"`` rig reads
those matrices (MatrixMarket, MATLAB .mat or Harwell-Boeing, all through ``scipy.io``) with a DOF map naming each
row's node and direction, and builds the same :class:`~analysis.model.structure.Structure` a beam gives; the TOML's
point masses, springs and nonlinear springs are added on top at ``"<node>:<direction>"`` DOFs, so modes, Guyan
reduction, simulation and analysis need no other change. ``K = sum_i p_i K_i`` from named ``stiffness_parts``
is kept on the structure (``K_parts``) for updating. A damping matrix ``C`` is projected onto the modes (the
simulator runs modal damping): ``zeta_r = phi_r^T C phi_r / (2 omega_r)``, exact for proportional damping.

Every problem with a file (missing, unreadable, wrong shape, not symmetric, ``M`` not positive definite, ``K``
with a negative eigenvalue, a DOF map naming an unknown node) is a :class:`ConfigFieldError` naming the TOML field,
which ``load_rig`` turns into the one-line ``ConfigError`` (exit 2).

The rig (analysis/model/rig.py) builds such a structure and places channels on its DOFs with this module, so it
sits below the rig; writing a rig out as such files (``gvt model export``) needs a built rig and sits above it, in
analysis/model/fe_export.py (issue 28: no import circle).
"""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from analysis.model.beam import FloatArray
from analysis.model.loader import ConfigFieldError
from analysis.model.nonlinear import NonlinearSpring
from analysis.model.structure import Dof, ModalDamping, StiffnessPart, Structure

if TYPE_CHECKING:
    from analysis.model.config import MatricesSpec, RigConfig

#: Directions of a DOF map row: three translations and three rotations; Nastran/Abaqus component numbers 1-6 too.
DIRECTIONS = ("X", "Y", "Z", "RX", "RY", "RZ")
_COMPONENTS = {str(i + 1): d for i, d in enumerate(DIRECTIONS)}
#: DOFs of an imported model: the same dense eigenproblem as the largest lumped rig (config.MAX_LUMPED_DOFS).
MAX_IMPORTED_DOFS = 2000
#: A matrix file: 2000 x 2000 dense in MatrixMarket text is ~100 MB; beyond that the path is wrong, not the model.
MAX_MATRIX_FILE_BYTES = 256 << 20
#: A DOF map: 2000 rows of "node,direction,x,y,z" are ~100 kB.
MAX_DOF_MAP_BYTES = 1 << 20
#: Asymmetry an export may carry from printing each entry separately (|a_ij - a_ji| over sqrt(|a_ii a_jj|)).
SYMMETRY_TOL = 1e-6
#: ``K`` may have rigid-body modes, not negative ones: its lowest eigenvalue (of K phi = lam M phi) must not be
#: below -this x the largest (the rounding of a PSD matrix exported to ~16 digits stays far below it).
NEGATIVE_TOL = 1e-9


def parse_dof_direction(text: str) -> str:
    """``"Z"``, ``"+z"``, ``"-Z"``, ``"ry"`` or a component number ``"3"`` -> ``"Z"`` (the sign is the sensor's
    orientation, which the rig keeps as metadata, as on a beam); ValueError names the choices."""
    t = str(text).strip().upper().lstrip("+-")
    t = _COMPONENTS.get(t, t)
    if t not in DIRECTIONS:
        raise ValueError(f"{text!r} is not a DOF direction; use one of {', '.join(DIRECTIONS)} or 1-6")
    return t


def dof_name(node: int, direction: str) -> str:
    return f"{int(node)}:{direction}"


@dataclass(frozen=True)
class DofMap:
    """Node id and direction of each matrix row, optionally the node's coordinates (m)."""

    nodes: tuple[int, ...]
    directions: tuple[str, ...]
    xyz: FloatArray | None = None

    def __len__(self) -> int:
        return len(self.nodes)

    @property
    def names(self) -> list[str]:
        return [dof_name(n, d) for n, d in zip(self.nodes, self.directions, strict=True)]

    def dofs(self) -> tuple[Dof, ...]:
        out = []
        for i, (n, d) in enumerate(zip(self.nodes, self.directions, strict=True)):
            x = None if self.xyz is None else float(self.xyz[i, 0])
            out.append(Dof(name=dof_name(n, d), kind="theta" if d.startswith("R") else "x", node=n, x=x))
        return tuple(out)

    def to_csv(self) -> str:
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(["node", "direction", *(("x", "y", "z") if self.xyz is not None else ())])
        for i, (n, d) in enumerate(zip(self.nodes, self.directions, strict=True)):
            w.writerow([n, d, *(repr(float(v)) for v in self.xyz[i])] if self.xyz is not None else [n, d])
        return buf.getvalue()


def parse_dof_map(text: str, field: str = "structure.dofs") -> DofMap:
    """A DOF map CSV: header ``node,direction`` (+ ``x,y,z``), one row per matrix row in matrix order."""
    rows = [r for r in csv.reader(io.StringIO(text)) if r and any(c.strip() for c in r) and not r[0].lstrip().startswith("#")]
    if not rows:
        raise ConfigFieldError(field, "the DOF map is empty; write a 'node,direction' header and one row per matrix row")
    head = [c.strip().lower() for c in rows[0]]
    if head[:2] != ["node", "direction"] or head[2:] not in ([], ["x", "y", "z"]):
        raise ConfigFieldError(
            field, f"the DOF map's header must be 'node,direction' or 'node,direction,x,y,z' (got {','.join(head)!r})"
        )
    if len(rows) - 1 > MAX_IMPORTED_DOFS:
        raise ConfigFieldError(field, f"{len(rows) - 1} DOFs, above the limit of {MAX_IMPORTED_DOFS} (the dense eigenproblem)")
    nodes, dirs, xyz, seen = [], [], [], set()
    for k, r in enumerate(rows[1:], start=2):
        if len(r) != len(head):
            raise ConfigFieldError(field, f"line {k}: {len(r)} columns, the header has {len(head)}")
        try:
            node = int(r[0])
            d = parse_dof_direction(r[1])
            coords = [float(v) for v in r[2:]]
        except ValueError as exc:
            raise ConfigFieldError(field, f"line {k}: {exc}") from None
        if node < 1:
            raise ConfigFieldError(field, f"line {k}: node {node}; node ids are positive integers")
        if not all(np.isfinite(coords)):
            raise ConfigFieldError(field, f"line {k}: a coordinate is not finite")
        if (node, d) in seen:
            raise ConfigFieldError(field, f"line {k}: DOF {dof_name(node, d)} is listed twice")
        seen.add((node, d))
        nodes.append(node)
        dirs.append(d)
        xyz.append(coords)
    return DofMap(tuple(nodes), tuple(dirs), np.array(xyz, dtype=float) if len(head) == 5 else None)


def _checked_path(base: Path, ref: str, field: str) -> tuple[Path, str | None]:
    name = None
    if "#" in ref:
        ref, name = ref.rsplit("#", 1)
    p = Path(ref) if Path(ref).is_absolute() else base / ref
    if not p.is_file():
        raise ConfigFieldError(field, f"{p}: no such file (paths are relative to the rig TOML)")
    size = p.stat().st_size
    if size > MAX_MATRIX_FILE_BYTES:
        raise ConfigFieldError(field, f"{p}: {size} bytes, above the {MAX_MATRIX_FILE_BYTES >> 20} MB a matrix file may have")
    return p, name


def read_dof_map(base: Path, ref: str, field: str = "structure.dofs") -> DofMap:
    p, _ = _checked_path(base, ref, field)
    if p.stat().st_size > MAX_DOF_MAP_BYTES:
        raise ConfigFieldError(field, f"{p}: above the {MAX_DOF_MAP_BYTES >> 10} kB a DOF map may have")
    try:
        text = p.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigFieldError(field, f"{p}: cannot read ({exc})") from None
    return parse_dof_map(text, field)


def read_matrix(base: Path, ref: str, fmt: str, field: str) -> FloatArray:
    """One matrix as a dense float array, read by scipy.io (``file.mat#NAME`` picks a .mat variable)."""
    import scipy.io
    import scipy.sparse

    p, name = _checked_path(base, ref, field)
    try:
        if fmt == "matrixmarket":
            rows, cols = scipy.io.mminfo(p)[:2]
            if max(rows, cols) > MAX_IMPORTED_DOFS:
                raise ConfigFieldError(field, f"{p}: {rows} x {cols}, above the limit of {MAX_IMPORTED_DOFS} DOFs")
            a = scipy.io.mmread(p)
        elif fmt == "matlab":  # shapes from the header first: a sparse 80 kB file densified to 2.4 GB (issue 30)
            shapes = {k: tuple(shape) for k, shape, _cls in scipy.io.whosmat(p)}
            names = list(shapes)
            if name is None and len(names) != 1:
                raise ConfigFieldError(field, f"{p} holds {names}; name the matrix as '{p.name}#NAME'")
            if name is not None and name not in shapes:
                raise ConfigFieldError(field, f"{p} has no variable {name!r}; it holds {names}")
            chosen = name if name is not None else names[0]
            if max(shapes[chosen], default=0) > MAX_IMPORTED_DOFS:
                dims = " x ".join(str(d) for d in shapes[chosen])
                raise ConfigFieldError(field, f"{p}: {dims}, above the limit of {MAX_IMPORTED_DOFS} DOFs")
            a = scipy.io.loadmat(p, variable_names=[chosen])[chosen]
        elif fmt == "harwell-boeing":
            a = scipy.io.hb_read(p)
        else:  # the schema allows no other
            raise ConfigFieldError("structure.format", f"unknown matrix format {fmt!r}")
    except ConfigFieldError:
        raise
    except Exception as exc:  # each reader raises its own family (ValueError, OSError, NotImplementedError, ...)
        first = " ".join(str(exc).split())[:200] or type(exc).__name__
        raise ConfigFieldError(field, f"{p}: not a readable {fmt} matrix ({first})") from None
    if scipy.sparse.issparse(a) and max(a.shape) > MAX_IMPORTED_DOFS:  # the size before the dense copy, not after
        raise ConfigFieldError(field, f"{p}: {a.shape[0]} x {a.shape[1]}, above the limit of {MAX_IMPORTED_DOFS} DOFs")
    a = a.toarray() if scipy.sparse.issparse(a) else np.asarray(a)
    if a.dtype.kind not in "biuf":
        raise ConfigFieldError(field, f"{p}: a {a.dtype} matrix; the model needs real numbers")
    a = np.array(a, dtype=float)
    if a.ndim != 2 or a.shape[0] != a.shape[1]:
        raise ConfigFieldError(field, f"{p}: shape {a.shape}, not a square matrix")
    if not np.all(np.isfinite(a)):
        raise ConfigFieldError(field, f"{p}: holds inf or nan")
    return a


def checked_symmetric(a: FloatArray, n: int, field: str, dofs_field: str = "structure.dofs") -> FloatArray:
    """``a`` is n x n (the DOF map's size) and symmetric to :data:`SYMMETRY_TOL`; returned exactly symmetric."""
    if a.shape != (n, n):
        raise ConfigFieldError(field, f"{a.shape[0]} x {a.shape[1]}, but the DOF map ({dofs_field}) lists {n} DOFs")
    if not a.size:
        return a
    # each entry against its own scale sqrt(|a_ii a_jj|) (its bound in a definite matrix): rotational and
    # translational DOFs differ by orders of magnitude in size, so "of the largest entry" would hide a bad one
    d = np.sqrt(np.abs(np.diag(a)))
    scale = np.outer(d, d)
    scale[scale == 0.0] = float(np.max(np.abs(a)))
    rel = np.abs(a - a.T) / np.where(scale > 0.0, scale, 1.0)
    worst = float(np.max(rel))
    if worst > SYMMETRY_TOL:
        i, j = np.unravel_index(int(np.argmax(rel)), a.shape)
        raise ConfigFieldError(
            field,
            f"not symmetric: entries ({i + 1},{j + 1}) and ({j + 1},{i + 1}) differ by {abs(a[i, j] - a[j, i]):.3g} "
            f"({worst:.2g} of sqrt(|a_ii a_jj|))",
        )
    return a if worst == 0.0 else 0.5 * (a + a.T)


def check_mass(M: FloatArray, field: str = "structure.mass") -> None:
    """``M`` must be positive definite: every DOF carries inertia (condense massless rotations out, Guyan)."""
    import scipy.linalg

    try:
        scipy.linalg.cholesky(M, lower=True)
    except np.linalg.LinAlgError:
        d = np.diag(M)
        hint = f" (diagonal entry {int(np.argmin(d)) + 1} is {float(np.min(d)):.3g})" if d.size and float(np.min(d)) <= 0 else ""
        raise ConfigFieldError(
            field, f"the mass matrix is not positive definite{hint}; condense massless DOFs out (Guyan) before exporting"
        ) from None


def check_stiffness(M: FloatArray, K: FloatArray, field: str = "structure.stiffness") -> None:
    """``K`` must be positive semi-definite: rigid-body modes are fine, a negative eigenvalue is a broken model."""
    import scipy.linalg

    lam = scipy.linalg.eigh(K, M, eigvals_only=True)
    top = float(np.max(np.abs(lam))) if lam.size else 0.0
    if lam.size and lam[0] < -NEGATIVE_TOL * top:
        raise ConfigFieldError(
            field, f"the stiffness matrix has a negative eigenvalue ({lam[0]:.3g} (rad/s)^2); K must be positive semi-definite"
        )


def modal_damping_from_matrix(M: FloatArray, K: FloatArray, C: FloatArray) -> ModalDamping:
    """Per-mode ratios ``zeta_r = phi_r^T C phi_r / (2 omega_r)`` (mass-normalised modes), all modes given.

    The simulator runs modal damping (eq. 3.14 with the factor 2); a proportional ``C`` (Rayleigh, or the
    modal ``M Phi diag(2 zeta omega) Phi^T M`` that :func:`~analysis.model.modal.modal_damping_matrix` builds)
    is reproduced exactly, a non-proportional one loses its off-diagonal modal terms."""
    from analysis.model.modal import modal_analysis

    modes = modal_analysis(M, K)
    c = np.einsum("ir,ij,jr->r", modes.shapes, C, modes.shapes)
    zeta = np.where(modes.omega > 0, c / (2.0 * np.where(modes.omega > 0, modes.omega, 1.0)), 0.0)
    return ModalDamping(zeta=tuple(float(z) for z in zeta), zeta_rest=0.0, factor2=True)


def resolve_dof(
    dofs: Sequence[Dof], field: str, dof: str | None = None, node: int | None = None, direction: str | None = None
) -> int:
    """The index of ``dof = "<node>:<direction>"``, or of ``node`` + ``direction`` (direction may be left out
    where the node has one translational DOF); a :class:`ConfigFieldError` at ``field`` otherwise."""
    by_node: dict[int, list[tuple[str, int]]] = {}
    for i, d in enumerate(dofs):
        n, _, dr = d.name.partition(":")
        by_node.setdefault(int(n), []).append((dr, i))
    if dof is not None:
        text = dof
        n_text, sep, d_text = dof.partition(":")
        try:
            if not sep:
                raise ValueError("write it as '<node>:<direction>', e.g. '12:Z'")
            node, direction = int(n_text), parse_dof_direction(d_text)
        except ValueError as exc:
            raise ConfigFieldError(f"{field}.dof", f"{text!r}: {exc}") from None
        where = f"{field}.dof"
    else:
        where = f"{field}.node"
    if node is None:
        raise ConfigFieldError(where, "an imported rig places it by 'dof' (\"<node>:<direction>\") or by 'node' and 'direction'")
    have = by_node.get(int(node))
    if have is None:
        ids = sorted(by_node)
        raise ConfigFieldError(
            where, f"node {node} is not in the DOF map (its nodes are {ids[0]}..{ids[-1]}, {len(ids)} of them)"
        )
    if direction is None:
        trans = [(dr, i) for dr, i in have if not dr.startswith("R")]
        if len(trans) != 1:
            raise ConfigFieldError(f"{field}.direction", f"node {node} has DOFs {[dr for dr, _ in have]}; give the direction")
        return trans[0][1]
    try:
        axis = parse_dof_direction(direction)
    except ValueError as exc:
        raise ConfigFieldError(f"{field}.direction", str(exc)) from None
    for dr, i in have:
        if dr == axis:
            return i
    raise ConfigFieldError(where, f"node {node} has no {axis} DOF in the DOF map (it has {[dr for dr, _ in have]})")


def build_imported(cfg: RigConfig, base: Path, damping: ModalDamping) -> Structure:
    """The structure of a ``kind = "matrices"`` rig: the files' M, K (= sum p_i K_i) and C, plus the TOML's
    point masses, grounded springs and nonlinear springs at their DOFs (the same additions a beam gets)."""
    spec: MatricesSpec = cfg.structure  # type: ignore[assignment]
    dmap = read_dof_map(base, spec.dofs)
    n = len(dmap)
    fmt = spec.format
    M = checked_symmetric(read_matrix(base, spec.mass, fmt, "structure.mass"), n, "structure.mass")
    check_mass(M)
    parts: tuple[StiffnessPart, ...] = ()
    if spec.stiffness is not None:
        K = checked_symmetric(read_matrix(base, spec.stiffness, fmt, "structure.stiffness"), n, "structure.stiffness")
        kfield = "structure.stiffness"
    else:
        parts = tuple(
            StiffnessPart(
                p.name,
                checked_symmetric(
                    read_matrix(base, p.file, fmt, f"structure.stiffness_parts[{i}].file"),
                    n,
                    f"structure.stiffness_parts[{i}].file",
                ),
                p.scale,
            )
            for i, p in enumerate(spec.stiffness_parts)
        )
        K = sum((p.scale * p.matrix for p in parts), np.zeros((n, n)))
        kfield = "structure.stiffness_parts"
    check_stiffness(M, K, kfield)
    dofs = dmap.dofs()
    for i, pm in enumerate(cfg.point_masses):
        j = resolve_dof(dofs, f"point_masses[{i}]", pm.dof)
        M[j, j] += pm.mass
    for i, sp in enumerate(cfg.springs):
        j = resolve_dof(dofs, f"springs[{i}]", sp.dof)
        K[j, j] += sp.k
    nl = tuple(
        NonlinearSpring(
            dof=resolve_dof(dofs, f"nonlinear_springs[{i}]", p.dof),
            law=p.law,
            coefficient=p.coefficient,
            exponent=p.exponent,
            ref=None if p.to is None else resolve_dof(dofs, f"nonlinear_springs[{i}].to", str(p.to)),
        )
        for i, p in enumerate(cfg.nonlinear_springs)
    )
    if spec.damping is not None:
        C = checked_symmetric(read_matrix(base, spec.damping, fmt, "structure.damping"), n, "structure.damping")
        damping = modal_damping_from_matrix(M, K, C)
    return Structure(M=M, K=K, dofs=dofs, nonlinear=nl, damping=damping, K_parts=parts)


__all__ = [
    "DIRECTIONS",
    "MAX_IMPORTED_DOFS",
    "DofMap",
    "build_imported",
    "check_mass",
    "check_stiffness",
    "checked_symmetric",
    "dof_name",
    "modal_damping_from_matrix",
    "parse_dof_direction",
    "parse_dof_map",
    "read_dof_map",
    "read_matrix",
    "resolve_dof",
]
