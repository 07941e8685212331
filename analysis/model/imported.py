"""Kept for daq/cli/model_export.py, which imports :func:`export_plan` and :func:`write_matrix` from here.

A ``kind = "matrices"`` rig is read and built by analysis/model/matrices.py (below the rig) and written out by
analysis/model/fe_export.py (above it); this module only re-exports the latter's two names until daq imports them
from there (issue 28). It imports nothing the rig imports, so it closes no circle.
"""

from analysis.model.fe_export import export_plan, write_matrix

__all__ = ["export_plan", "write_matrix"]
