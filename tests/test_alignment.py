"""The calibrated geometry model: joint targets that realise a pose on the real rig, a guard
that checks the joints it sends where the arms really are, and backlash taken up from one side."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import EXAMPLES

from acquisition.config.rig import load_rig
from acquisition.geometry.alignment import Alignment
from acquisition.geometry.approach import APPROACH_DEG, approach_signs
from acquisition.geometry.kinematics import Pose
from acquisition.geometry.kinematics.calibrated import CalibratedKinematics
from acquisition.planning.planner import Planner
from acquisition.simworld.misalignment import TrueGeometry

MISALIGNED = EXAMPLES / "rig-misaligned-sim.toml"
TRUTH = Alignment({"light_theta": 0.8, "camera_theta": -0.6, "camera_phi": 1.0}, (0.4, -0.3),
                  backlash_deg={"light_theta": 0.2, "camera_theta": 0.2, "camera_phi": 0.2})


def test_calibrated_targets_realise_the_pose_on_the_true_rig() -> None:
    """The planner's joints, sent to the simulated world's true geometry (its own code), give
    the requested pose: the calibration model and the referee agree on every convention."""
    rig = load_rig(MISALIGNED)
    planner = Planner(rig, alignment=TRUTH)
    truth = TrueGeometry(rig)
    for pose in (Pose(40, 36, 180), Pose(30, 60, 90), Pose(60, 20, 135), Pose(45, 45, 40)):
        joints = planner.joints_for(pose)
        true = {a: v + TRUTH.zero_offset_deg[a] - TRUTH.backlash_deg[a] / 2
                for a, v in joints.items()}  # approached from below
        light, camera = truth.directions(true)
        got = np.degrees([np.arccos(light[2]), np.arccos(camera[2])])
        assert got == pytest.approx([pose.theta_i, pose.theta_r], abs=1e-6)
        assert planner.kinematics.forward(joints).theta_r == pytest.approx(pose.theta_r, abs=1e-6)
    nominal = Planner(rig).joints_for(Pose(40, 36, 180))
    assert abs(nominal["light_theta"] - planner.joints_for(Pose(40, 36, 180))["light_theta"]) > 0.5


def test_the_guard_sees_the_arms_where_the_calibration_puts_them() -> None:
    rig = load_rig(MISALIGNED)
    kin = CalibratedKinematics(rig.kinematics(), TRUTH)
    joints = np.array([[-30.0, 40.0, 10.0]])
    light, camera = kin.arm_directions_array(joints)
    base_light, _ = rig.kinematics().arm_directions_array(joints + [[0.7, -0.7, 0.9]])
    assert light == pytest.approx(base_light)
    planner = Planner(rig, alignment=TRUTH)
    assert planner.kinematics is not None and isinstance(planner.kinematics, CalibratedKinematics)
    # the gap the guard computes is that of the arms' calibrated positions
    gap = planner.arm_gap_m(joints)[0]
    assert gap == pytest.approx(Planner(rig).arm_gap_m(joints + [[0.7, -0.7, 0.9]])[0])


def test_captures_approach_every_target_from_below() -> None:
    rig = load_rig(MISALIGNED)
    planner = Planner(rig)
    assert planner.approach  # the rig file states backlash
    start = {"light_theta": -10.0, "camera_theta": 50.0, "camera_phi": 20.0}
    target = {"light_theta": -20.0, "camera_theta": 40.0, "camera_phi": 30.0}
    legs = planner.route(start, target)
    assert legs[-1] == target
    assert legs[-2] == {a: v - APPROACH_DEG for a, v in target.items()}
    assert approach_signs(np.array([[0.2, 10.0]]), [0.0, -90.0]).tolist() == [[-1.0, 1.0]]
    assert Planner(load_rig(EXAMPLES / "rig-sim.toml")).route(start, target) == [target]


def test_alignment_round_trips_through_its_bundle_section() -> None:
    a = Alignment({"light_theta": 0.5}, (0.1, -0.2), ("light_theta", "tilt_about_x"),
                  np.array([[1e-4, 0.0], [0.0, 4e-4]]), {"light_theta": 0.2}, (0.3, -0.1),
                  (0.01, 0.02))
    b = Alignment.from_dict(a.to_dict())
    assert b.zero_offset_deg == a.zero_offset_deg and b.sample_tilt_deg == a.sample_tilt_deg
    assert b.camera_pointing_deg == a.camera_pointing_deg and b.sigma("tilt_about_x") == 0.02
    assert b.shifted("backlash:light_theta", 0.1).backlash_deg["light_theta"] == pytest.approx(0.3)
