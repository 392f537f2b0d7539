"""Rig kinematics plug-ins, chosen by the rig file's ``kinematics`` key."""

from __future__ import annotations

from .base import Geometry, JointLimits, Joints, Kinematics, Pose, pose_from_directions, wrap_deg
from .out_of_plane import OutOfPlaneArcs

KINEMATICS: dict[str, type[Kinematics]] = {
    OutOfPlaneArcs.name: OutOfPlaneArcs,
}
"""Rig-file name → kinematics class."""

__all__ = [
    "KINEMATICS",
    "Geometry",
    "JointLimits",
    "Joints",
    "Kinematics",
    "OutOfPlaneArcs",
    "Pose",
    "pose_from_directions",
    "wrap_deg",
]
