"""The captures of plan-quick, plan-demo and plan-dense on every moving-arm rig record zero
collisions: real ``api.capture`` runs (planner, session engine, routed and guarded moves, the
motion controller on the simulated servos through ``dynamixel_sdk``, the simulator's own solid
arms on the stepped clock), about 9,000 steps in all.

To fit the suite's time budget, what cannot change where an arm goes is made cheap (the camera
writes the smallest DNG instead of rendering, the controller reads back every 100 ms instead of
10 ms while a move runs: :func:`lean_capture.make_lean`), and the three rigs capture in child
processes side by side (each a serial run of its three plans). The test-wide referee cannot
see into them, so each child drains the simulator's process-wide record of contacts after every
capture and fails on any, and this test reads every session's journal (what ``gonio info``
shows) and the children's stderr (the simulator's warnings).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import assert_no_sim_collision
from lean_capture import PLANS
from referee import SIM_COLLISION_LOG

from acquisition import api

RIGS = ("rig-sim", "rig-coaxial-sim", "rig-sphere-sim")
"""Every example rig whose arms move."""
HELPER = Path(__file__).with_name("lean_capture.py")
TMPFS = Path("/dev/shm")


@pytest.fixture
def session_root(tmp_path: Path) -> Iterator[Path]:
    """A folder for the sessions: on a tmpfs when there is one (``fsync`` is free there)."""
    usable = TMPFS.is_dir() and os.access(TMPFS, os.W_OK)
    root = Path(tempfile.mkdtemp(prefix="gonio-captures-", dir=TMPFS if usable else tmp_path))
    try:
        yield root
    finally:
        shutil.rmtree(root, ignore_errors=True)


@pytest.mark.slow
def test_the_example_plans_capture_without_a_collision_on_every_moving_arm_rig(
        session_root: Path) -> None:
    children = {rig: subprocess.Popen([sys.executable, str(HELPER), rig, str(session_root / rig)],
                                      stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
                for rig in RIGS}
    try:
        for rig, child in children.items():
            out, err = child.communicate(timeout=600)
            assert child.returncode == 0, f"{rig}: {out}{err}"
            assert SIM_COLLISION_LOG not in err, err
            assert out.count(" steps in ") == len(PLANS), out
            for plan in PLANS:
                session = session_root / rig / plan
                status = api.session_status(session, drift=False)
                assert status.done == status.total > 100, (rig, plan, status.done, status.total)
                assert_no_sim_collision(session)
    finally:
        for child in children.values():
            child.kill()
            child.wait(timeout=10)
