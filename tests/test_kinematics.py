"""Kinematics: forward ∘ inverse round trips, solution choice, geometry conventions."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from acquisition.kinematics import JointLimits, OutOfPlaneArcs, Pose, pose_from_directions
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
