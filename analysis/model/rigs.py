"""Resolve a rig argument: a path to a TOML file, or the name of a rig shipped in ``configs/rigs``."""

from __future__ import annotations

from pathlib import Path

from analysis.model.rig import Rig, load_rig

CONFIG_DIR = Path(__file__).resolve().parents[2] / "configs"
RIG_DIR = CONFIG_DIR / "rigs"


def resolve_rig_path(arg: str | Path) -> Path:
    p = Path(arg)
    if p.exists() or p.suffix == ".toml" or len(p.parts) > 1:
        return p
    shipped = RIG_DIR / f"{arg}.toml"
    return shipped if shipped.exists() else p


def open_rig(arg: str | Path) -> Rig:
    return load_rig(resolve_rig_path(arg))
