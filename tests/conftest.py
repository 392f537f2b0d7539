"""Shared fixtures: example files, the external validation data folder."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "examples"


def external_data_dir() -> Path | None:
    """``$GONIO_EXTERNAL_DATA`` or ``../shared/data`` beside the project, if present."""
    env = os.environ.get("GONIO_EXTERNAL_DATA")
    candidates = [Path(env)] if env else []
    candidates.append(ROOT.parent / "shared" / "data")
    return next((p for p in candidates if p.is_dir()), None)


@pytest.fixture
def external_data() -> Path:
    path = external_data_dir()
    if path is None:
        pytest.skip("external validation data absent: set GONIO_EXTERNAL_DATA or provide ../shared/data")
    return path


@pytest.fixture
def rig_sim_path() -> Path:
    return EXAMPLES / "rig-sim.toml"


@pytest.fixture
def plan_quick_path() -> Path:
    return EXAMPLES / "plan-quick.toml"
