"""Captures several test modules share (session-scoped fixtures, imported where used)."""

from __future__ import annotations

import fcntl
import os
from collections.abc import Iterator
from contextlib import contextmanager
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


@contextmanager
def shared_between_workers(tmp_path_factory: pytest.TempPathFactory, name: str) -> Iterator[Path]:
    """A folder every pytest-xdist worker of this run sees (the run's base temp folder),
    held under an exclusive lock: the first worker fills it, the others wait and reuse it."""
    base = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        base = base.parent  # shared by the workers of one run
    folder = base / name
    folder.mkdir(exist_ok=True)
    with open(folder / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        yield folder


@pytest.fixture(scope="session")
def quick_tables(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """examples/plan-quick.toml captured on examples/rig-sim.toml (its sensor model) for each
    of :data:`MATERIALS`, reduced; ``{name}`` is the table, ``{name}-session`` the session.
    Captured once per run, whatever the number of workers."""
    tables = {}
    with shared_between_workers(tmp_path_factory, "quick-tables") as root:
        for seed, (name, (spec, _)) in enumerate(MATERIALS.items()):
            session = root / name
            tables[name] = root / f"{name}.h5"
            tables[f"{name}-session"] = session
            if not tables[name].exists():  # written last: its session is complete
                api.capture(EXAMPLES / "rig-sim.toml", EXAMPLES / "plan-quick.toml", session,
                            material=spec, seed=10 + seed)
                api.reduce(session, tables[name])
    return tables
