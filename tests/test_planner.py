"""Planner: each rejection reason with a pose that triggers it and one just inside; timing."""

from __future__ import annotations

from pathlib import Path

import pytest

from acquisition.kinematics import Pose
from acquisition.plan import load_plan
from acquisition.planner import Planner, Reason, Rejection, serpentine
from acquisition.rig import load_rig
from acquisition.timing import trapezoid_time_s
from drivers.errors import CollisionError, LimitError


@pytest.fixture
def planner(rig_sim_path: Path) -> Planner:
    return Planner(load_rig(rig_sim_path))


def reason(result: object) -> Reason | None:
    return result.reason if isinstance(result, Rejection) else None


def test_shadow_cone_rejects_inside_and_accepts_just_outside(planner: Planner) -> None:
    # Camera and light on the same side (Δφ = 0) separated by |θi − θr|.
    assert reason(planner.check_pose(Pose(40, 47, 0))) is Reason.SHADOW
    assert reason(planner.check_pose(Pose(40, 48.01, 0))) is None


def test_max_elevation(planner: Planner) -> None:
    assert reason(planner.check_pose(Pose(85.01, 30, 90))) is Reason.MAX_ELEVATION
    assert reason(planner.check_pose(Pose(85.0, 30, 90))) is None


def test_joint_limits(rig_sim_path: Path) -> None:
    planner = Planner(load_rig(rig_sim_path), max_elevation_deg=90)
    assert reason(planner.check_pose(Pose(20, 87.5, 90))) is Reason.JOINT_LIMITS
    assert reason(planner.check_pose(Pose(20, 86.9, 90))) is None


def test_duplicates_are_reported(planner: Planner) -> None:
    start = planner.joints_for(Pose(0, 45, 180))
    sweep = planner.plan([Pose(30, 30, 90), Pose(30, 30, 90)], start)
    assert len(sweep.steps) == 1
    assert sweep.rejected_counts() == {"duplicate": 1}


def test_guard_refuses_unsafe_joint_targets(planner: Planner) -> None:
    with pytest.raises(CollisionError, match="shadow cone"):
        planner.check_joints({"light_theta": 30, "camera_theta": 32, "camera_phi": 0})
    with pytest.raises(LimitError, match="camera_phi"):
        planner.check_joints({"light_theta": 30, "camera_theta": 32, "camera_phi": 179.5})
    with pytest.raises(LimitError, match="no target"):
        planner.check_joints({"light_theta": 30})
    planner.check_joints({"light_theta": 30, "camera_theta": 32, "camera_phi": 90})


def test_quick_plan_rejections_and_estimate(rig_sim_path: Path, plan_quick_path: Path) -> None:
    rig, plan = load_rig(rig_sim_path), load_plan(plan_quick_path)
    planner = Planner.for_plan(rig, plan)
    sweep = planner.plan(plan.poses(), planner.joints_for(Pose(0, 45, 180)))
    assert len(sweep.steps) + len(sweep.rejected) == len(plan.poses())
    assert set(sweep.rejected_counts()) <= {r.value for r in Reason}
    for step in sweep.steps:
        planner.check_joints(step.joints)  # every planned target passes the guard
    assert sweep.motion_s == pytest.approx(sum(s.move_s for s in sweep.steps))
    assert sweep.estimated_s > sweep.motion_s
    assert sweep.motion_s <= sweep.naive_motion_s


def test_serpentine_alternates_inner_direction() -> None:
    poses = [Pose(0, tr, dp) for tr in (10, 20) for dp in (0, 90, 180)]
    order = [p.delta_phi for p in serpentine(poses)]
    assert order == [0, 90, 180, 180, 90, 0]


def test_trapezoid_time() -> None:
    # Long move: cruise + one acceleration time; short move: triangle.
    assert trapezoid_time_s(100, 50, 100) == pytest.approx(100 / 50 + 50 / 100)
    assert trapezoid_time_s(4, 50, 100) == pytest.approx(2 * (4 / 100) ** 0.5)
    assert trapezoid_time_s(0, 50, 100) == 0
