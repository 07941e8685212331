"""Mode tables for ``gvt model modes`` and ``gvt demo``: the same numbers the tests check."""

from __future__ import annotations

from typing import Any

import numpy as np
from rich.console import Console

from analysis.model.guyan import guyan_reduce
from analysis.model.modal import modal_analysis, structure_modes
from analysis.model.rig import Rig
from daq.terminal import Col, FitTable


def modes_report(rig: Rig, limit: str = "low", count: int = 10) -> dict[str, Any]:
    st = rig.limit_structure(limit)
    modes = structure_modes(st)
    n = min(count, len(modes))
    masters = [st.dof_index(rig.structure.dofs[d].name) for d in rig.master_dofs() if _has(st, rig.structure.dofs[d].name)]
    g = guyan_reduce(st.M, st.K, masters)
    gm = modal_analysis(g.M, g.K)
    zeta = st.damping.ratios(len(modes))
    rows = []
    for i in range(n):
        rows.append(
            {
                "mode": i + 1,
                "frequency_hz": float(modes.frequencies_hz[i]),
                "guyan_hz": float(gm.frequencies_hz[i]) if i < len(gm) else None,
                "damping_ratio": float(zeta[i]),
            }
        )
    return {
        "rig": rig.name,
        "limit": limit,
        "n_dof": st.n_dof,
        "guyan_masters": len(masters),
        "nonlinear_springs": len(rig.structure.nonlinear),
        "modes": rows,
    }


def _has(st, name: str) -> bool:
    try:
        st.dof_index(name)
    except KeyError:
        return False
    return True


def modes_table(report: dict[str, Any], width: int | None = None) -> FitTable:
    """The modes of :func:`modes_report` as a table that fits ``width`` (default: the console's)."""
    title = (
        f"{report['rig']}: {'low-energy (linear)' if report['limit'] == 'low' else 'high-energy (springs pinned)'} "
        f"limit, {report['n_dof']} DOFs"
    )
    t = FitTable(
        title,
        [
            Col("mode", "right", key=True),
            Col("f [Hz]", "right"),
            Col(f"Guyan, {report['guyan_masters']} sensor DOFs [Hz]", "right"),
            Col("zeta", "right"),
        ],
        width=width,
    )
    for r in report["modes"]:
        g = None if r["guyan_hz"] is None else f"{r['guyan_hz']:.4g}"
        t.add_row(r["mode"], f"{r['frequency_hz']:.4f}", g, f"{r['damping_ratio']:.4f}")
    return t


def print_modes(console: Console, report: dict[str, Any], width: int | None = None) -> None:
    console.print(modes_table(report, width))


def fe_frequencies(rig: Rig, limit: str = "low", count: int = 10) -> np.ndarray:
    return np.array([r["frequency_hz"] for r in modes_report(rig, limit, count)["modes"]])
