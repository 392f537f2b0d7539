"""Shared fixtures: example files, the external validation data folder; the collision referee
(:mod:`referee`) for every test."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from referee import SIM_COLLISION_EVENT, pytest_runtest_makereport  # noqa: F401  (the referee)

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "examples"

pytest_plugins = ("captured",)  # session-scoped captures the analysis tests share


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


def grid_plan_text(
    theta_i: tuple[float, float, float],
    theta_r: tuple[float, float, float],
    delta_phi: tuple[float, float, float],
    *,
    name: str = "small",
    reference_every: int | None = None,
) -> str:
    """A grid plan file's text; each range is (start, stop, step) in degrees."""

    def rng(r: tuple[float, float, float]) -> str:
        return f"{{ start = {r[0]}, stop = {r[1]}, step = {r[2]} }}"

    text = (
        f'format_version = 1\nname = "{name}"\n[sampling]\nkind = "grid"\n'
        f"theta_i = {rng(theta_i)}\ntheta_r = {rng(theta_r)}\ndelta_phi = {rng(delta_phi)}\n"
    )
    if reference_every is not None:
        text += f"[capture]\nreference_every = {reference_every}\n"
    return text


SMALL_PLAN = grid_plan_text((0, 60, 30), (0, 60, 30), (0, 180, 90))
"""27 candidate poses on a 30° × 30° × 90° grid: the suite's usual small capture."""

TINY_PLAN_ARGS = ((20, 40, 20), (30, 30, 10), (90, 180, 90))
"""Four poses: (θi 20/40) × (θr 30) × (Δφ 90/180)."""


@pytest.fixture
def clock():
    """The simulated clock of the servo simulator (modules may override: faster motion)."""
    from simulators.clock import SimClock

    return SimClock(1.0)


@pytest.fixture
def sim(clock):
    """Three simulated X-series servos (IDs 1–3) on a pty, sharing ``clock``."""
    from simulators.dynamixel import SimServoBus

    with SimServoBus([1, 2, 3], clock=clock) as bus:
        yield bus


@pytest.fixture
def sims() -> list:
    """Every simulated bus the code under test starts (to look at its servos afterwards)."""
    return _STARTED_BUSES


_STARTED_BUSES: list = []


@pytest.fixture(autouse=True)
def record_started_buses(monkeypatch: pytest.MonkeyPatch) -> None:
    """Keep every simulated bus built during the test for the ``sims`` fixture.

    Whether the simulated arms collided is the referee's business (:mod:`referee`, loaded
    below): it sees every bus of the process, also those of module- and session-scoped
    fixtures.
    """
    from simulators.dynamixel import bus as bus_mod

    _STARTED_BUSES.clear()
    original = bus_mod.SimServoBus.__init__

    def recording_init(self, *args, **kwargs) -> None:  # noqa: ANN001
        original(self, *args, **kwargs)
        _STARTED_BUSES.append(self)

    monkeypatch.setattr(bus_mod.SimServoBus, "__init__", recording_init)


def assert_no_sim_collision(session: Path) -> None:
    """The session's journal records no contact of the simulated arms (a capture that ran in
    a child process, out of the referee's sight)."""
    from acquisition import api

    hits = [e[3] for e in api.session_status(session, drift=False).events
            if SIM_COLLISION_EVENT in e[3]]
    assert not hits, f"{session}: {hits}"


# ---------------------------------------------------------------------------- outputs
TINY_MATERIAL = "lambert:albedo=0.4"
LIGHTSTAGE_RIG = EXAMPLES / "rig-lightstage-sim.toml"


@pytest.fixture(scope="session")
def finished(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A finished four-pose session ``session`` (made under umask 022), its plan file ``plan``
    and its table ``table`` (outside the session)."""
    from acquisition import api

    root = tmp_path_factory.mktemp("finished")
    plan = root / "plan.toml"
    plan.write_text(grid_plan_text(*TINY_PLAN_ARGS, name="tiny"))
    old = os.umask(0o022)
    try:
        api.capture(EXAMPLES / "rig-sim.toml", plan, root / "s", material=TINY_MATERIAL, seed=3)
        api.reduce(root / "s", root / "t.h5")
    finally:
        os.umask(old)
    return {"session": root / "s", "plan": plan, "table": root / "t.h5", "root": root}


@pytest.fixture(scope="session")
def lightstage_field(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A light-stage OLAT session ``session`` with its reflectance field ``field`` and a small
    environment map ``env`` (made under umask 022)."""
    import numpy as np

    from acquisition import api
    from acquisition.formats.envmap import write_exr

    root = tmp_path_factory.mktemp("lightstage-field")
    old = os.umask(0o022)
    try:
        api.capture_lightstage(LIGHTSTAGE_RIG, root / "l", material="ggx:albedo=0.2,alpha=0.3,f0=0.04",
                               seed=2)
        api.write_field(root / "l", root / "l" / "field")
        write_exr(root / "env.exr", np.ones((8, 16, 3), dtype=np.float32))
    finally:
        os.umask(old)
    return {"session": root / "l", "field": root / "l" / "field", "env": root / "env.exr",
            "root": root}


def unfinish(session: Path, steps: int = 2) -> list[int]:
    """Send the last ``steps`` done frame steps of ``session`` back to planned, as an
    interrupted run leaves them (their frames deleted); returns their numbers."""
    import sqlite3

    db = sqlite3.connect(session / "journal.sqlite")
    try:
        rows = db.execute("SELECT step, frame FROM steps WHERE status = 'done' AND frame IS NOT "
                          "NULL ORDER BY step DESC LIMIT ?", (steps,)).fetchall()
        for step, frame in rows:
            db.execute("UPDATE steps SET status = 'planned', frame = NULL, sha256 = NULL "
                       "WHERE step = ?", (step,))
            (session / "frames" / frame).unlink()
        db.commit()
    finally:
        db.close()
    return [r[0] for r in rows]


HOST_TIMED_MODULES = frozenset({
    "test_dxl_simulator.py", "test_instruction_faults.py", "test_planner_eta.py",
    "test_bluesky.py", "test_distributed.py",
})
"""Test files that measure host timing (pty round trips, reply delays, timeouts) or load the
host heavily (a Dask cluster of worker processes): under ``pytest -n 2 --dist loadgroup`` (make
test) they run one after another on one worker, so the cluster never competes with the timed
tests for the two cores."""


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Under ``--dist loadgroup`` a file's tests run on one worker (its module-scoped captures
    are made once, not once per worker); the host-timed files share one worker."""
    for item in items:
        group = "host-timed" if item.path.name in HOST_TIMED_MODULES else item.path.name
        item.add_marker(pytest.mark.xdist_group(group))
