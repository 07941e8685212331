from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest
from hypothesis import settings

ROOT = Path(__file__).resolve().parents[1]
RIGS = ROOT / "configs" / "rigs"

settings.register_profile("default", max_examples=200, deadline=None)
settings.register_profile("fuzz", max_examples=20000, deadline=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "default"))


@pytest.fixture(scope="session")
def rigs():
    from analysis.model.rig import load_rig

    cache: dict[str, object] = {}

    def get(name: str):
        if name not in cache:
            cache[name] = load_rig(RIGS / f"{name}.toml")
        return cache[name]

    return get


def gvt_command() -> list[str]:
    exe = Path(sys.executable).parent / "gvt"
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "daq.cli"]


def pytest_configure(config):
    # the `browser` marker (issue 8): tests that open a file in headless Chromium; they skip when it is absent
    config.addinivalue_line("markers", "browser: renders in headless Chromium (/usr/bin/chromium); skips when it is absent")
