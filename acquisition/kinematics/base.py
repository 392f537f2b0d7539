"""What every rig kinematics plug-in provides: joints ↔ isotropic BRDF coordinates."""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from drivers.errors import UnreachablePoseError

Joints = dict[str, float]
"""Joint name → angle in degrees (or a light index for a light stage)."""


@dataclass(frozen=True, order=True)
class Pose:
    """An isotropic BRDF measurement direction pair, all in degrees.

    ``delta_phi`` is the camera azimuth minus the light azimuth (both directions pointing
    away from the sample), so ``delta_phi = 180`` with ``theta_i == theta_r`` is the mirror.
    """

    theta_i: float
    theta_r: float
    delta_phi: float

    def as_tuple(self) -> tuple[float, float, float]:
        return (self.theta_i, self.theta_r, self.delta_phi)


@dataclass(frozen=True)
class Geometry:
    """Directions in the sample's frame (normal +z), unit vectors, plus distances in metres."""

    light_dir: np.ndarray
    camera_dir: np.ndarray
    light_distance_m: float
    camera_distance_m: float


@dataclass(frozen=True)
class JointLimits:
    """Soft limits of one joint in degrees."""

    min_deg: float
    max_deg: float

    def contains(self, value_deg: float, tol: float = 1e-9) -> bool:
        return self.min_deg - tol <= value_deg <= self.max_deg + tol


def wrap_deg(angle_deg: float) -> float:
    """Wrap an angle into (−180, 180] degrees."""
    wrapped = (angle_deg + 180.0) % 360.0 - 180.0
    return 180.0 if wrapped == -180.0 else wrapped


def angle_between_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle between two unit vectors in degrees."""
    return float(np.degrees(np.arccos(np.clip(np.dot(a, b), -1.0, 1.0))))


def pose_from_directions(light_dir: np.ndarray, camera_dir: np.ndarray) -> Pose:
    """Isotropic coordinates (degrees) of unit light/camera vectors in the sample frame."""
    theta_i = np.degrees(np.arctan2(np.hypot(light_dir[0], light_dir[1]), light_dir[2]))
    theta_r = np.degrees(np.arctan2(np.hypot(camera_dir[0], camera_dir[1]), camera_dir[2]))
    phi_l = np.degrees(np.arctan2(light_dir[1], light_dir[0]))
    phi_c = np.degrees(np.arctan2(camera_dir[1], camera_dir[0]))
    return Pose(float(theta_i), float(theta_r), wrap_deg(float(phi_c - phi_l)))


class Kinematics(ABC):
    """A rig's mapping between joint angles and measurement geometry.

    Subclasses declare ``joint_names`` and implement :meth:`forward_geometry` and
    :meth:`inverse_candidates`; :meth:`inverse` picks the reachable candidate nearest the
    current joints.
    """

    name: str = "abstract"
    joint_names: tuple[str, ...] = ()

    def __init__(
        self,
        limits: Mapping[str, JointLimits],
        light_distance_m: float,
        camera_distance_m: float,
    ) -> None:
        missing = [j for j in self.joint_names if j not in limits]
        if missing:
            raise ValueError(f"{self.name} kinematics needs limits for {', '.join(missing)}")
        self.limits = dict(limits)
        self.light_distance_m = light_distance_m
        self.camera_distance_m = camera_distance_m

    @abstractmethod
    def forward_geometry(self, joints: Mapping[str, float]) -> Geometry:
        """Light and camera directions in the sample frame for the given joints."""

    @abstractmethod
    def inverse_candidates(self, pose: Pose) -> list[Joints]:
        """Every joint solution for ``pose`` (limits not yet applied)."""

    def forward(self, joints: Mapping[str, float]) -> Pose:
        """The (θi, θr, Δφ) pose in degrees that the joints realise."""
        g = self.forward_geometry(joints)
        return pose_from_directions(g.light_dir, g.camera_dir)

    def within_limits(self, joints: Mapping[str, float]) -> bool:
        return all(self.limits[name].contains(joints[name]) for name in self.joint_names)

    def violated_limits(self, joints: Mapping[str, float]) -> list[str]:
        """Names of the joints outside their soft limits, with values, for error messages."""
        out = []
        for name in self.joint_names:
            lim = self.limits[name]
            if not lim.contains(joints[name]):
                out.append(f"{name}={joints[name]:.3f}° outside [{lim.min_deg:g}, {lim.max_deg:g}]°")
        return out

    def inverse(self, pose: Pose, current: Mapping[str, float] | None = None) -> Joints:
        """The reachable joint solution nearest ``current`` (max joint travel, degrees)."""
        candidates = [c for c in self.inverse_candidates(pose) if self.within_limits(c)]
        if not candidates:
            raise UnreachablePoseError(
                f"pose θi={pose.theta_i:g}° θr={pose.theta_r:g}° Δφ={pose.delta_phi:g}° is "
                f"outside the joint limits of the {self.name} rig: narrow the plan's ranges"
            )
        if current is None:
            return candidates[0]
        return min(candidates, key=lambda c: self.travel_deg(current, c))

    def travel_deg(self, a: Mapping[str, float], b: Mapping[str, float]) -> float:
        """Largest single-joint travel between two joint sets, degrees."""
        return max(abs(a[n] - b[n]) for n in self.joint_names)
