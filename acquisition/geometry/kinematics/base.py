"""What every rig kinematics plug-in provides: joints ↔ isotropic BRDF coordinates.

A plug-in implements the vectorised core (:meth:`Kinematics.forward_array`,
:meth:`Kinematics.inverse_array`, optionally :meth:`Kinematics.arm_directions_array`); the
scalar, dict-based methods the rest of gonio calls (``forward_geometry``, ``forward``,
``inverse``) are derived from it, so the planner's batch checks and the motion guard's
single-pose checks run the same code. Joint arrays hold degrees in ``joint_names`` order.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from drivers.errors import UnreachablePoseError

if TYPE_CHECKING:
    from acquisition.config.rig import RigConfig

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


LIMIT_TOL_DEG = 1e-9
"""Slack on soft limits so that a pose exactly on a limit is reachable despite rounding."""


def wrap_deg(angle_deg: float) -> float:
    """Wrap an angle into (−180, 180] degrees."""
    wrapped = (angle_deg + 180.0) % 360.0 - 180.0
    return 180.0 if wrapped == -180.0 else wrapped


def wrap_deg_array(angle_deg: np.ndarray) -> np.ndarray:
    """Wrap angles into (−180, 180] degrees (array version of :func:`wrap_deg`)."""
    wrapped = (np.asarray(angle_deg, dtype=float) + 180.0) % 360.0 - 180.0
    return np.where(wrapped == -180.0, 180.0, wrapped)


def angle_between_deg_array(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angles between unit vectors (…, 3) in degrees, accurate near 0° and 180°."""
    cross = np.linalg.norm(np.cross(a, b), axis=-1)
    return np.degrees(np.arctan2(cross, np.sum(a * b, axis=-1)))


def poses_from_directions(light: np.ndarray, camera: np.ndarray) -> np.ndarray:
    """(θi, θr, Δφ) in degrees, shape (N, 3), of unit light/camera vectors (N, 3), sample frame."""
    theta_i = np.degrees(np.arctan2(np.hypot(light[:, 0], light[:, 1]), light[:, 2]))
    theta_r = np.degrees(np.arctan2(np.hypot(camera[:, 0], camera[:, 1]), camera[:, 2]))
    phi_l = np.degrees(np.arctan2(light[:, 1], light[:, 0]))
    phi_c = np.degrees(np.arctan2(camera[:, 1], camera[:, 0]))
    return np.column_stack([theta_i, theta_r, wrap_deg_array(phi_c - phi_l)])


def pose_from_directions(light_dir: np.ndarray, camera_dir: np.ndarray) -> Pose:
    """Isotropic coordinates (degrees) of unit light/camera vectors in the sample frame."""
    row = poses_from_directions(np.asarray(light_dir)[None], np.asarray(camera_dir)[None])[0]
    return Pose(float(row[0]), float(row[1]), float(row[2]))


def poses_to_array(poses: Sequence[Pose]) -> np.ndarray:
    """Poses as an (N, 3) float array of (θi, θr, Δφ) degrees."""
    if not poses:
        return np.zeros((0, 3))
    return np.array([p.as_tuple() for p in poses], dtype=float)


def directions_from_poses(poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit light (azimuth 0) and camera vectors (N, 3) for (θi, θr, Δφ) rows in degrees."""
    ti, tr, dp = (np.radians(poses[:, k]) for k in range(3))
    light = np.column_stack([np.sin(ti), np.zeros_like(ti), np.cos(ti)])
    camera = np.column_stack([np.sin(tr) * np.cos(dp), np.sin(tr) * np.sin(dp), np.cos(tr)])
    return light, camera


class Kinematics(ABC):
    """A rig's mapping between joint angles and measurement geometry.

    Subclasses declare ``joint_names`` and implement :meth:`forward_array` and
    :meth:`inverse_array`; :meth:`inverse` picks the reachable candidate nearest the current
    joints. ``free_joints`` do not change the isotropic pose (a sample turntable); the inverse
    holds them at the value it is given (default 0°).
    """

    name: str = "abstract"
    joint_names: tuple[str, ...] = ()
    free_joints: tuple[str, ...] = ()
    moving_arms: bool = True
    """False for rigs whose light and camera never move (no collision to check)."""

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
        self._lo = np.array([self.limits[n].min_deg for n in self.joint_names], dtype=float)
        self._hi = np.array([self.limits[n].max_deg for n in self.joint_names], dtype=float)

    @classmethod
    def from_rig(cls, rig: RigConfig) -> Kinematics:
        """The plug-in configured from a rig file (axes → joint limits, geometry)."""
        limits = {name: JointLimits(a.min_deg, a.max_deg) for name, a in rig.axes.items()}
        return cls(limits, rig.light_distance_m, rig.camera_distance_m)

    # -- vectorised core ---------------------------------------------------------------

    @abstractmethod
    def forward_array(self, joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Unit light and camera vectors (N, 3) in the sample frame for joints (N, J) in degrees."""

    @abstractmethod
    def inverse_array(self, poses: np.ndarray, hold: Mapping[str, float] | None = None) -> np.ndarray:
        """Every joint solution (N, K, J) for (θi, θr, Δφ) rows (N, 3), degrees.

        Missing solutions are NaN rows; soft limits are not applied. ``hold`` gives the
        values of the free joints (default 0°).
        """

    def arm_directions_array(self, joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Unit vectors (N, 3) from the sample to the light and camera heads, in the rig's
        (world) frame, for collision checks. Default: the sample frame is the world frame."""
        return self.forward_array(joints)

    # -- derived helpers ---------------------------------------------------------------

    def to_array(self, joints: Mapping[str, float]) -> np.ndarray:
        """A joint dict as a (J,) array in ``joint_names`` order."""
        return np.array([float(joints[n]) for n in self.joint_names], dtype=float)

    def to_dict(self, row: np.ndarray) -> Joints:
        """A (J,) joint array as a dict."""
        return {n: float(v) for n, v in zip(self.joint_names, row, strict=True)}

    def limit_mask(self, joints: np.ndarray) -> np.ndarray:
        """True where every joint of (…, J) lies within its soft limits (NaN rows are False)."""
        with np.errstate(invalid="ignore"):
            ok = (joints >= self._lo - LIMIT_TOL_DEG) & (joints <= self._hi + LIMIT_TOL_DEG)
        return np.all(ok, axis=-1)

    def poses_array(self, joints: np.ndarray) -> np.ndarray:
        """(θi, θr, Δφ) rows (N, 3) in degrees realised by joints (N, J)."""
        light, camera = self.forward_array(joints)
        return poses_from_directions(light, camera)

    # -- scalar API --------------------------------------------------------------------

    def forward_geometry(self, joints: Mapping[str, float]) -> Geometry:
        """Light and camera directions in the sample frame for the given joints."""
        light, camera = self.forward_array(self.to_array(joints)[None])
        return Geometry(light[0], camera[0], self.light_distance_m, self.camera_distance_m)

    def forward(self, joints: Mapping[str, float]) -> Pose:
        """The (θi, θr, Δφ) pose in degrees that the joints realise."""
        row = self.poses_array(self.to_array(joints)[None])[0]
        return Pose(float(row[0]), float(row[1]), float(row[2]))

    def inverse_candidates(self, pose: Pose, hold: Mapping[str, float] | None = None) -> list[Joints]:
        """Every joint solution for ``pose`` (limits not yet applied)."""
        cands = self.inverse_array(np.array([pose.as_tuple()], dtype=float), hold)[0]
        return [self.to_dict(c) for c in cands if not np.any(np.isnan(c))]

    def within_limits(self, joints: Mapping[str, float]) -> bool:
        return bool(self.limit_mask(self.to_array(joints)))

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
        hold = None if current is None else {n: current[n] for n in self.free_joints if n in current}
        candidates = [c for c in self.inverse_candidates(pose, hold) if self.within_limits(c)]
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
        return max((abs(a[n] - b[n]) for n in self.joint_names), default=0.0)
