"""Captures several test modules share (session-scoped fixtures, imported where used)."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import EXAMPLES

from acquisition import api

MATERIALS = {
    "ggx": ("ggx:albedo=0.2,alpha=0.3,f0=0.04", {"albedo": 0.2, "alpha": 0.3, "f0": 0.04}),
    "beckmann": ("beckmann:albedo=0.15,alpha=0.2,f0=0.05",
                 {"albedo": 0.15, "alpha": 0.2, "f0": 0.05}),
    "blinn-phong": ("blinn-phong:albedo=0.3,ks=0.05,e=100",
                    {"albedo": 0.3, "ks": 0.05, "e": 100.0}),
}
"""Simulated materials (spec, true parameters) the analysis tests capture."""


@pytest.fixture(scope="session")
def quick_tables(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """examples/plan-quick.toml captured on examples/rig-sim.toml (its sensor model) for each
    of :data:`MATERIALS`, reduced; ``{name}`` is the table, ``{name}-session`` the session."""
    root = tmp_path_factory.mktemp("quick")
    tables = {}
    for seed, (name, (spec, _)) in enumerate(MATERIALS.items()):
        session = root / name
        api.capture(EXAMPLES / "rig-sim.toml", EXAMPLES / "plan-quick.toml", session,
                    material=spec, seed=10 + seed)
        tables[name] = root / f"{name}.h5"
        tables[f"{name}-session"] = session
        api.reduce(session, tables[name])
    return tables
