"""Planner: each rejection reason with a pose that triggers it and one just inside; the guard;
sweeps (order, naive order, lower bound, ETA parts); swept-path collisions."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from acquisition.config.plan import load_plan
from acquisition.config.rig import FootprintConfig, RigConfig, load_rig
from acquisition.geometry.kinematics import Pose
from acquisition.planning.planner import Planner, Reason, Rejection, segment_distance, serpentine
from acquisition.planning.timing import trapezoid_time_s
from drivers.errors import CollisionError, LimitError

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


@pytest.fixture
def rig(rig_sim_path: Path) -> RigConfig:
    return load_rig(rig_sim_path)


@pytest.fixture
def planner(rig: RigConfig) -> Planner:
    return Planner(rig)


def reason(result: object) -> Reason | None:
    return result.reason if isinstance(result, Rejection) else None


def collision_angle_deg(rig: RigConfig) -> float:
    """Separation below which the sim rig's arm capsules touch: the camera capsule's inner
    end (a point) against the light capsule (it projects inside the light segment)."""
    arms = rig.arms
    assert arms is not None
    reach = arms.light.radius_m + arms.camera.radius_m + arms.clearance_m
    return math.degrees(math.asin(reach / arms.camera.from_m))


# -- one test per reason: triggered, and just inside -------------------------------------

def test_max_elevation(planner: Planner) -> None:
    assert reason(planner.check_pose(Pose(85.01, 30, 90))) is Reason.MAX_ELEVATION
    assert reason(planner.check_pose(Pose(85.0, 30, 90))) is None


def test_duplicate_same_measurement_listed_twice(planner: Planner) -> None:
    start = planner.reference_joints()
    sweep = planner.plan([Pose(30, 30, 90), Pose(30, 30, 90), Pose(30, 30, -90),
                          Pose(30, 30, 90.001), Pose(0, 40, 0), Pose(0, 40, 120)], start)
    # ±Δφ is one bin of a folded table; Δφ means nothing when the light is at the normal.
    assert sweep.rejected_counts() == {"duplicate": 3}
    assert len(sweep.steps) == 3
    # With a table that keeps the sign of Δφ, −90° is a different measurement (and the
    # reciprocal of (θi, θr, Δφ) is (θr, θi, −Δφ)).
    signed = Planner(planner.rig, mirror_delta_phi=False)
    assert signed.plan([Pose(20, 40, 90), Pose(20, 40, -90)], start).rejected_counts() == {}
    assert signed.plan([Pose(20, 40, 90), Pose(40, 20, -90)], start).rejected_counts() == {
        "reciprocal": 1}


def test_unreachable_on_a_light_stage(tmp_path: Path) -> None:
    rig_file = tmp_path / "stage.toml"
    rig_file.write_text(
        'format_version = 1\nkinematics = "light-stage"\n'
        '[geometry]\nlight_distance_m = 1.0\ncamera_distance_m = 1.0\n'
        '[camera]\nroi = [0, 0, 4, 4]\n'
        '[light_stage]\ncamera_angles_deg = [0, 0]\n'
        'light_angles_deg = [[20, 0], [40, 90], [60, 200]]\n'
    )
    planner = Planner(load_rig(rig_file))
    assert reason(planner.check_pose(Pose(40, 0, 0))) is None
    assert planner.joints_for(Pose(40, 0, 0)) == {"light": 1.0}
    assert reason(planner.check_pose(Pose(40.01, 0, 0))) is Reason.UNREACHABLE
    sweep = planner.plan([Pose(20, 0, 0), Pose(60, 0, 0), Pose(40, 0, 0)], {"light": 0.0})
    assert sweep.motion_s == 0 and sweep.lower_bound_motion_s == 0  # switching, no travel
    assert [s.joints["light"] for s in sweep.steps] and sweep.estimated_s > 0


def test_joint_limits(rig: RigConfig) -> None:
    planner = Planner(dataclasses.replace(rig, footprint=None), max_elevation_deg=90)
    assert reason(planner.check_pose(Pose(20, 87.5, 90))) is Reason.JOINT_LIMITS
    assert reason(planner.check_pose(Pose(20, 86.9, 90))) is None


def test_arm_collision(rig: RigConfig) -> None:
    planner = Planner(rig, shadow_cone_deg=0)
    gamma = collision_angle_deg(rig)
    # Camera and light on the same side (Δφ = 0) are |θi − θr| apart.
    inside = planner.check_pose(Pose(40, 40 + gamma - 0.01, 0))
    assert reason(inside) is Reason.ARM_COLLISION
    assert "clearance" in inside.detail
    assert reason(planner.check_pose(Pose(40, 40 + gamma + 0.01, 0))) is None


def test_shadow_cone(planner: Planner, rig: RigConfig) -> None:
    assert collision_angle_deg(rig) < 7  # so the arms do not collide first
    assert reason(planner.check_pose(Pose(40, 47, 0))) is Reason.SHADOW
    assert reason(planner.check_pose(Pose(40, 48.01, 0))) is None


def test_footprint(rig: RigConfig) -> None:
    # 10 mm spot on a 50 mm sample: stretched by 1/cos θi it leaves the sample past 78.46°.
    fp = FootprintConfig(sample_size_m=0.05, spot_diameter_m=0.01, view_diameter_m=0.005)
    planner = Planner(dataclasses.replace(rig, footprint=fp))
    limit = math.degrees(math.acos(0.01 / 0.05))
    over = planner.check_pose(Pose(limit + 0.01, 30, 90))
    assert reason(over) is Reason.FOOTPRINT and "light spot" in over.detail
    assert reason(planner.check_pose(Pose(limit - 0.01, 30, 90))) is None
    view_limit = math.degrees(math.acos(0.005 / 0.05))  # 84.26°: the camera's region
    assert "measured region" in planner.check_pose(Pose(30, view_limit + 0.01, 90)).detail
    assert reason(planner.check_pose(Pose(30, view_limit - 0.01, 90))) is None


def test_reciprocal_measured_once_unless_both(planner: Planner, rig: RigConfig) -> None:
    start = planner.reference_joints()
    poses = [Pose(20, 40, 90), Pose(40, 20, 90), Pose(40, 20.001, 90), Pose(30, 30, 90)]
    sweep = planner.plan(poses, start)
    assert sweep.rejected_counts() == {"reciprocal": 1}
    assert sweep.rejected[0].pose == Pose(40, 20, 90)  # the later one of the pair
    both = Planner(rig, reciprocal="both").plan(poses, start)
    assert both.rejected_counts() == {} and len(both.steps) == 4


def test_reciprocal_keeps_the_reachable_one(rig: RigConfig) -> None:
    # The camera arc stops at 87°, the light arm too; with a 60° light limit only one of a
    # pair is reachable, and that one is kept even though it comes second.
    axes = dict(rig.axes)
    axes["light_theta"] = dataclasses.replace(axes["light_theta"], min_deg=-60, max_deg=60)
    planner = Planner(dataclasses.replace(rig, axes=axes))
    sweep = planner.plan([Pose(70, 30, 90), Pose(30, 70, 90)], planner.reference_joints())
    assert sweep.rejected_counts() == {"joint-limits": 1}
    assert sweep.steps[0].pose == Pose(30, 70, 90)


# -- the guard ---------------------------------------------------------------------------

def test_guard_refuses_unsafe_joint_targets(planner: Planner) -> None:
    with pytest.raises(CollisionError, match="swept volumes"):
        planner.check_joints({"light_theta": 30, "camera_theta": 32, "camera_phi": 0})
    with pytest.raises(CollisionError, match="shadow cone"):
        planner.check_joints({"light_theta": 30, "camera_theta": 37, "camera_phi": 0})
    with pytest.raises(LimitError, match="camera_phi"):
        planner.check_joints({"light_theta": 30, "camera_theta": 32, "camera_phi": 179.5})
    with pytest.raises(LimitError, match="no target"):
        planner.check_joints({"light_theta": 30})
    planner.check_joints({"light_theta": 30, "camera_theta": 32, "camera_phi": 90})


def test_swept_path_collision(planner: Planner) -> None:
    """The camera swinging past the light collides on the way, though both ends are safe."""
    a = {"light_theta": 40, "camera_theta": 40, "camera_phi": 30}
    b = {"light_theta": 40, "camera_theta": 40, "camera_phi": -30}
    planner.check_joints(a)
    planner.check_joints(b)
    with pytest.raises(CollisionError, match=r"moving camera_phi brings the arms .* at "
                                              r"light_theta 40.0°, camera_theta 40.0°, "
                                              r"camera_phi -?\d"):
        planner.check_move(a, b)
    planner.check_move(a, {"light_theta": 40, "camera_theta": 40, "camera_phi": 90})
    # Going over the top instead (camera elevation first) is a different, safe path.
    planner.check_move(a, {"light_theta": 40, "camera_theta": 75, "camera_phi": 30})


def test_plan_avoids_moves_through_the_light(planner: Planner) -> None:
    # Poses just either side of the light's azimuth at the light's elevation: a sweep that
    # took them in azimuth order would swing the camera through the light.
    poses = [Pose(40, 40 + d, dp) for d in (-2, 0, 2) for dp in (20, 25, -20, -25)]
    sweep = planner.plan(poses, planner.reference_joints())
    assert planner.unsafe_moves(sweep.steps, sweep.start_joints) == 0
    current = sweep.start_joints
    for step in sweep.steps:
        for leg in (*step.via, step.joints):  # direct, or round the light through via points
            planner.check_move(current, leg)
            current = leg


def test_segment_distance() -> None:
    o = np.zeros(3)
    x, y = np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
    assert segment_distance(o + 2 * y, x + 2 * y, o, x) == pytest.approx(2)  # parallel
    assert segment_distance(np.array([2.0, -1, 1]), np.array([2.0, 1, 1]), o, x) == pytest.approx(
        math.hypot(1, 1))  # crossing beyond an end
    assert segment_distance(np.array([0.5, -1, 0.3]), np.array([0.5, 1, 0.3]), o, x) == pytest.approx(0.3)


# -- sweeps ------------------------------------------------------------------------------

def test_quick_plan_rejections_and_estimate(rig_sim_path: Path, plan_quick_path: Path) -> None:
    rig, plan = load_rig(rig_sim_path), load_plan(plan_quick_path)
    planner = Planner.for_plan(rig, plan)
    start = planner.reference_joints()
    sweep = planner.plan(plan.poses(), start)
    assert len(sweep.steps) + len(sweep.rejected) == len(plan.poses())
    assert set(sweep.rejected_counts()) <= {r.value for r in Reason}
    current = start
    for step in sweep.steps:
        planner.check_joints(step.joints)  # every planned target passes the guard
        assert planner.kinematics.forward(step.joints).theta_i == pytest.approx(step.pose.theta_i)
        # a move is timed as the rig makes it: direct, or routed round the other arm
        assert step.move_s == pytest.approx(planner.leg_s(current, step.joints))
        if not step.via:
            assert step.move_s == pytest.approx(planner.time_model.move_s(current, step.joints))
        current = step.joints
    assert sweep.motion_s == pytest.approx(sum(s.move_s for s in sweep.steps))
    assert sweep.lower_bound_motion_s <= sweep.motion_s < sweep.naive_motion_s
    per_pose = planner.time_model.step_overhead_s()
    assert sweep.overhead_s == pytest.approx(len(sweep.steps) * per_pose)
    # White reference first and last: two captures plus the moves out and back (the way back
    # from the last pose is routed when the direct move would swing an arm through the other).
    back = planner.leg_s(sweep.steps[-1].joints, start)
    assert sweep.reference_s == pytest.approx(2 * per_pose + back)
    assert sweep.estimated_s == pytest.approx(sweep.motion_s + sweep.overhead_s + sweep.reference_s)
    summary = sweep.summary()
    assert set(summary) == {"poses", "rejected", "estimated_s", "motion_s", "naive_motion_s",
                            "lower_bound_motion_s"}


def test_reference_every_adds_round_trips(rig: RigConfig, plan_quick_path: Path) -> None:
    plan = load_plan(plan_quick_path)
    plain = Planner.for_plan(rig, plan)
    every = Planner(rig, reference_every=10, reciprocal=plan.reciprocal,
                    mirror_delta_phi=plan.mirror_delta_phi)
    start = plain.reference_joints()
    a, b = plain.plan(plan.poses(), start), every.plan(plan.poses(), start)
    assert a.motion_s == pytest.approx(b.motion_s)
    n_extra = (len(b.steps) - 1) // 10
    assert b.reference_s > a.reference_s + n_extra * plain.time_model.step_overhead_s()


def test_coaxial_plan_keeps_the_arms_apart() -> None:
    rig = load_rig(EXAMPLES / "rig-coaxial-sim.toml")
    plan = load_plan(EXAMPLES / "plan-quick.toml")
    planner = Planner.for_plan(rig, plan)
    sweep = planner.plan(plan.poses(), planner.reference_joints())
    assert len(sweep.steps) > 80
    assert planner.unsafe_moves(sweep.steps, sweep.start_joints) == 0
    current = sweep.start_joints
    for step in sweep.steps:
        planner.check_move(current, step.joints)  # no move swings one arm through the other
        back = planner.kinematics.forward(step.joints)
        assert back.theta_r == pytest.approx(step.pose.theta_r, abs=1e-9)
        current = step.joints


def test_serpentine_alternates_inner_direction() -> None:
    poses = [Pose(0, tr, dp) for tr in (10, 20) for dp in (0, 90, 180)]
    order = [p.delta_phi for p in serpentine(poses)]
    assert order == [0, 90, 180, 180, 90, 0]


def test_trapezoid_time() -> None:
    # Long move: cruise + one acceleration time; short move: triangle.
    assert trapezoid_time_s(100, 50, 100) == pytest.approx(100 / 50 + 50 / 100)
    assert trapezoid_time_s(4, 50, 100) == pytest.approx(2 * (4 / 100) ** 0.5)
    assert trapezoid_time_s(0, 50, 100) == 0


# -- CLI ---------------------------------------------------------------------------------

def test_gonio_plan_json_and_plot(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import json

    from acquisition.cli import main

    png = tmp_path / "plan.png"
    code = main(["plan", str(EXAMPLES / "plan-quick.toml"), "--rig", str(EXAMPLES / "rig-sim.toml"),
                 "--json", "--plot", str(png)])
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) == {"poses", "rejected", "estimated_s", "motion_s", "naive_motion_s",
                        "lower_bound_motion_s"}
    assert out["poses"] + sum(out["rejected"].values()) == 6 * 6 * 7
    assert out["lower_bound_motion_s"] <= out["motion_s"] <= out["naive_motion_s"]
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000


# -- properties and rig-file tables ------------------------------------------------------

@settings(max_examples=150, deadline=None)
@given(st.floats(0, 89), st.floats(0, 89), st.floats(-180, 180),
       st.sampled_from(["rig-sim.toml", "rig-coaxial-sim.toml"]))
def test_accepted_poses_pass_the_guard_and_realise_the_pose(
    theta_i: float, theta_r: float, delta_phi: float, rig_name: str
) -> None:
    planner = _planners(rig_name)
    pose = Pose(theta_i, theta_r, delta_phi)
    result = planner.check_pose(pose)
    if isinstance(result, Rejection):
        assert result.detail and result.pose == pose
        return
    planner.check_joints(result)  # the guard accepts what the planner accepts
    back = planner.kinematics.forward(result)
    assert back.theta_i == pytest.approx(theta_i, abs=1e-9)
    assert back.theta_r == pytest.approx(theta_r, abs=1e-9)
    if min(theta_i, theta_r) > 1e-6:  # the mirrored solution realises −Δφ (same folded bin)
        assert abs(abs(back.delta_phi) - abs(delta_phi)) < 1e-9


_CACHE: dict[str, Planner] = {}


def _planners(name: str) -> Planner:
    if name not in _CACHE:
        _CACHE[name] = Planner(load_rig(EXAMPLES / name))
    return _CACHE[name]


@pytest.mark.parametrize(
    ("table", "match"),
    [
        ("[arms]\nlight = { from_m = 0.5, to_m = 0.4 }\n", "to_m"),
        ("[arms]\nclearence_m = 0.01\n", "clearence_m"),
        ("[sample]\nsize_m = 0\n", "size_m"),
        ("[timing]\nbus_cycle_s = -1\n", "bus_cycle_s"),
    ],
)
def test_rig_constraint_tables_are_checked(tmp_path: Path, table: str, match: str) -> None:
    from drivers.errors import ConfigError

    path = tmp_path / "rig.toml"
    path.write_text((EXAMPLES / "rig-sim.toml").read_text() + "\n" + table)
    with pytest.raises(ConfigError, match=match):
        load_rig(path)


def test_rig_arm_defaults_and_overrides(tmp_path: Path, rig: RigConfig) -> None:
    assert rig.arms is not None and rig.footprint is not None
    assert rig.arms.light.from_m == pytest.approx(0.8 * rig.light_distance_m)
    assert rig.arms.camera.to_m == pytest.approx(rig.camera_distance_m + rig.arms.camera.radius_m)
    path = tmp_path / "rig.toml"
    path.write_text((EXAMPLES / "rig-sim.toml").read_text()
                    + "\n[arms]\nclearance_m = 0.05\n")
    wide = Planner(load_rig(path), shadow_cone_deg=0)
    # A wider clearance rejects poses the default accepts.
    pose = Pose(40, 40 + collision_angle_deg(rig) + 1, 0)
    assert reason(Planner(rig, shadow_cone_deg=0).check_pose(pose)) is None
    assert reason(wide.check_pose(pose)) is Reason.ARM_COLLISION


def test_light_stage_rig_table_errors(tmp_path: Path) -> None:
    from drivers.errors import ConfigError

    base = ('format_version = 1\nkinematics = "light-stage"\n[geometry]\nlight_distance_m = 1.0\n'
            'camera_distance_m = 1.0\n[camera]\nroi = [0, 0, 4, 4]\n[light_stage]\n'
            'camera_angles_deg = [0, 0]\n')
    path = tmp_path / "stage.toml"
    path.write_text(base + "light_angles_deg = [[20, 0], [95, 10]]\n")
    with pytest.raises(ConfigError, match="entry 1 is not above the sample"):
        load_rig(path)
    path.write_text(base + "light_angles_deg = [[20, 0]]\nlight_directions = [[0, 0, 1]]\n")
    with pytest.raises(ConfigError, match="exactly one"):
        load_rig(path)
    path.write_text(base + "light_directions = [[0, 0.5, 1], [1, 0, 1]]\n")
    rig = load_rig(path)
    assert rig.kinematics().forward({"light": 1.0}).theta_i == pytest.approx(45)
