"""Rig kinematics plug-ins, chosen by the rig file's ``kinematics`` key."""

from __future__ import annotations

from acquisition.geometry.kinematics.base import (
    Geometry,
    JointLimits,
    Joints,
    Kinematics,
    Pose,
    pose_from_directions,
    poses_from_directions,
    poses_to_array,
    wrap_deg,
)
from acquisition.geometry.kinematics.coaxial import CoaxialArms
from acquisition.geometry.kinematics.lightstage import LightStage
from acquisition.geometry.kinematics.out_of_plane import OutOfPlaneArcs

KINEMATICS: dict[str, type[Kinematics]] = {
    OutOfPlaneArcs.name: OutOfPlaneArcs,
    CoaxialArms.name: CoaxialArms,
    LightStage.name: LightStage,
}
"""Rig-file name → kinematics class."""

__all__ = [
    "KINEMATICS",
    "CoaxialArms",
    "Geometry",
    "JointLimits",
    "Joints",
    "Kinematics",
    "LightStage",
    "OutOfPlaneArcs",
    "Pose",
    "pose_from_directions",
    "poses_from_directions",
    "poses_to_array",
    "wrap_deg",
]
