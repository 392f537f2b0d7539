"""Kinematics: forward ∘ inverse round trips, solution choice, geometry conventions."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from acquisition.geometry.kinematics import (
    CoaxialArms,
    JointLimits,
    LightStage,
    OutOfPlaneArcs,
    Pose,
    pose_from_directions,
)
from drivers.errors import UnreachablePoseError
from simulators.materials import directions_from_angles

LIMITS = {
    "light_theta": JointLimits(-87, 87),
    "camera_theta": JointLimits(0, 87),
    "camera_phi": JointLimits(-179, 179),
}


def arcs() -> OutOfPlaneArcs:
    return OutOfPlaneArcs(LIMITS, 0.5, 0.6)


def angle_diff(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)


@settings(max_examples=300, deadline=None)
@given(
    st.floats(0.01, 87), st.floats(0.01, 87), st.floats(-180, 180, exclude_min=True),
)
def test_forward_inverse_round_trip(theta_i: float, theta_r: float, delta_phi: float) -> None:
    k = arcs()
    pose = Pose(theta_i, theta_r, delta_phi)
    joints = k.inverse(pose)
    back = k.forward(joints)
    assert abs(back.theta_i - theta_i) < 1e-9
    assert abs(back.theta_r - theta_r) < 1e-9
    assert angle_diff(back.delta_phi, delta_phi) < 1e-9


def test_mirror_configuration_uses_light_on_far_side() -> None:
    joints = arcs().inverse(Pose(30, 30, 180))
    assert joints["light_theta"] == pytest.approx(-30)
    assert joints["camera_phi"] == pytest.approx(0)
    g = arcs().forward_geometry(joints)
    # The camera direction is the light direction mirrored about the normal.
    mirrored = np.array([-g.light_dir[0], -g.light_dir[1], g.light_dir[2]])
    assert np.allclose(g.camera_dir, mirrored)


def test_directions_agree_with_material_convention() -> None:
    """Kinematics and materials describe the same (θi, θr, Δφ) the same way."""
    k = arcs()
    for pose in [Pose(20, 50, 70), Pose(60, 10, -120), Pose(45, 45, 180)]:
        g = k.forward_geometry(k.inverse(pose))
        wi, wo = directions_from_angles(*pose.as_tuple())
        # Same pose up to a rotation about the normal.
        assert np.isclose(g.light_dir @ g.camera_dir, wi @ wo)
        assert pose_from_directions(g.light_dir, g.camera_dir).theta_i == pytest.approx(pose.theta_i)


def test_inverse_picks_nearest_solution() -> None:
    k = arcs()
    pose = Pose(40, 30, 90)
    near_a = {"light_theta": 40, "camera_theta": 30, "camera_phi": 85}
    near_b = {"light_theta": -40, "camera_theta": 30, "camera_phi": -85}
    assert k.inverse(pose, near_a)["light_theta"] == pytest.approx(40)
    assert k.inverse(pose, near_b)["light_theta"] == pytest.approx(-40)


def test_unreachable_pose_raises_with_reason() -> None:
    k = OutOfPlaneArcs(
        {"light_theta": JointLimits(0, 60), "camera_theta": JointLimits(0, 60),
         "camera_phi": JointLimits(-90, 90)}, 0.5, 0.6,
    )
    with pytest.raises(UnreachablePoseError, match="outside the joint limits"):
        k.inverse(Pose(70, 20, 0))


# -- coaxial arms ------------------------------------------------------------------------

COAX_LIMITS = {
    "light_azimuth": JointLimits(-179, 179),
    "camera_azimuth": JointLimits(-179, 179),
    "stage_tilt": JointLimits(-80, 80),
}


def coaxial() -> CoaxialArms:
    return CoaxialArms(COAX_LIMITS, 0.5, 0.6)


@settings(max_examples=300, deadline=None)
@given(st.floats(0.0, 87), st.floats(0.0, 87), st.floats(-180, 180, exclude_min=True))
def test_coaxial_forward_inverse_round_trip(theta_i: float, theta_r: float, delta_phi: float) -> None:
    k = coaxial()
    pose = Pose(theta_i, theta_r, delta_phi)
    candidates = [c for c in k.inverse_candidates(pose) if k.within_limits(c)]
    assume(candidates)
    for joints in candidates:  # every reachable solution realises the pose
        back = k.forward(joints)
        assert abs(back.theta_i - theta_i) < 1e-9
        assert abs(back.theta_r - theta_r) < 1e-9
        if min(theta_i, theta_r) > 1e-6:  # Δφ is undefined at the normal
            assert angle_diff(back.delta_phi, delta_phi) < 1e-9


def test_coaxial_arms_stay_horizontal_and_tilt_sets_the_normal() -> None:
    k = coaxial()
    joints = k.inverse(Pose(30, 50, 120))
    light_w, camera_w = k.arm_directions_array(k.to_array(joints)[None])
    assert light_w[0, 2] == 0 and camera_w[0, 2] == 0
    # The angle between the arms equals the angle between light and camera in the sample.
    g = k.forward_geometry(joints)
    assert np.dot(light_w[0], camera_w[0]) == pytest.approx(np.dot(g.light_dir, g.camera_dir))
    t = np.radians(joints["stage_tilt"])
    normal = np.array([np.cos(t), 0.0, np.sin(t)])
    assert np.degrees(np.arccos(normal @ light_w[0])) == pytest.approx(30)
    assert np.degrees(np.arccos(normal @ camera_w[0])) == pytest.approx(50)


def test_coaxial_two_mirror_solutions_pick_nearest() -> None:
    k = coaxial()
    pose = Pose(40, 30, 100)
    sols = {round(c["stage_tilt"], 6) for c in k.inverse_candidates(pose) if k.within_limits(c)}
    assert len(sols) == 2 and sum(sols) == pytest.approx(0)  # tilt ±t: mirror images
    up = k.inverse(pose, {"light_azimuth": 0, "camera_azimuth": 0, "stage_tilt": 20})
    down = k.inverse(pose, {"light_azimuth": 0, "camera_azimuth": 0, "stage_tilt": -20})
    assert up["stage_tilt"] > 0 > down["stage_tilt"]
    assert up["light_azimuth"] == pytest.approx(-down["light_azimuth"])


def test_coaxial_tilt_limit_makes_pose_unreachable() -> None:
    # Both directions near grazing on opposite sides need a large tilt.
    k = CoaxialArms({**COAX_LIMITS, "stage_tilt": JointLimits(-10, 10)}, 0.5, 0.6)
    with pytest.raises(UnreachablePoseError):
        k.inverse(Pose(80, 80, 20))
    k.inverse(Pose(80, 80, 180))  # in the plane of the arms: no tilt needed


def test_coaxial_stage_rotation_is_held() -> None:
    k = CoaxialArms({**COAX_LIMITS, "stage_rotation": JointLimits(-90, 90)}, 0.5, 0.6)
    joints = k.inverse(Pose(20, 40, 60), {"light_azimuth": 0, "camera_azimuth": 0,
                                          "stage_tilt": 0, "stage_rotation": 33})
    assert joints["stage_rotation"] == 33
    back = k.forward(joints)
    assert back.theta_i == pytest.approx(20) and back.delta_phi == pytest.approx(60)


# -- light stage ---------------------------------------------------------------------------

def light_stage() -> LightStage:
    angles = [(0, 0), (30, 0), (30, 90), (60, 180), (45, 270)]
    dirs = [directions_from_angles(0, t, p)[1] for t, p in angles]  # (θ, φ) → unit vector
    camera = directions_from_angles(0, 45, 0)[1]
    return LightStage(np.array(dirs), camera, 1.0, 1.0)


def test_light_stage_pose_is_a_light_index() -> None:
    k = light_stage()
    for i, row in enumerate(k.native_poses()):
        pose = Pose(*row)
        joints = k.inverse(pose)
        assert joints == {"light": float(i)}
        back = k.forward(joints)
        assert back.theta_i == pytest.approx(pose.theta_i) and back.theta_r == pytest.approx(45)


def test_light_stage_pose_between_lights_is_unreachable() -> None:
    k = light_stage()
    with pytest.raises(UnreachablePoseError):
        k.inverse(Pose(31, 45, 180))
