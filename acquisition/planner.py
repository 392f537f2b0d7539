"""The motion planner: which candidate poses are safe and useful, their order, and the ETA.

Every pose is checked against the rig's constraints and kept or rejected with a named
:class:`Reason`. :meth:`Planner.check_joints` is also the guard the motion controller calls
before *every* move, so nothing reaches a servo that the planner has not checked.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum

from drivers.errors import CollisionError, LimitError, UnreachablePoseError

from .kinematics import Joints, Kinematics, Pose
from .kinematics.base import angle_between_deg
from .plan import PlanSpec
from .rig import RigConfig
from .timing import AxisProfile, StepCosts, TimeModel


class Reason(StrEnum):
    """Why a candidate pose was not planned."""

    MAX_ELEVATION = "max-elevation"
    JOINT_LIMITS = "joint-limits"
    SHADOW = "shadow"
    DUPLICATE = "duplicate"


@dataclass(frozen=True)
class Rejection:
    """A candidate pose left out, the reason, and a human-readable detail."""

    pose: Pose
    reason: Reason
    detail: str


@dataclass(frozen=True)
class PlannedPose:
    """One accepted pose in capture order with its joint targets (degrees)."""

    index: int
    pose: Pose
    joints: Joints
    move_s: float
    """Predicted duration of the move into this pose from the previous one."""


@dataclass
class Sweep:
    """The planner's output: the ordered poses, the rejections, and the time estimate."""

    steps: list[PlannedPose]
    rejected: list[Rejection]
    start_joints: Joints
    motion_s: float
    overhead_s: float
    naive_motion_s: float = float("nan")
    lower_bound_motion_s: float = float("nan")
    extra: dict[str, float] = field(default_factory=dict)

    @property
    def estimated_s(self) -> float:
        """Total predicted duration: motion plus per-pose settle, bus and exposure time."""
        return self.motion_s + self.overhead_s

    def rejected_counts(self) -> dict[str, int]:
        return dict(Counter(r.reason.value for r in self.rejected))

    def summary(self) -> dict[str, object]:
        """The figures ``gonio plan --json`` prints (seconds)."""
        return {
            "poses": len(self.steps),
            "rejected": self.rejected_counts(),
            "estimated_s": round(self.estimated_s, 3),
            "motion_s": round(self.motion_s, 3),
            "naive_motion_s": round(self.naive_motion_s, 3),
            "lower_bound_motion_s": round(self.lower_bound_motion_s, 3),
        }


class Planner:
    """Checks poses and joint targets against one rig's constraints and plans sweeps."""

    def __init__(
        self,
        rig: RigConfig,
        *,
        shadow_cone_deg: float | None = None,
        max_elevation_deg: float | None = None,
        exposure_s: float | None = None,
    ) -> None:
        self.rig = rig
        self.kinematics: Kinematics = rig.kinematics()
        self.shadow_cone_deg = rig.shadow_cone_deg if shadow_cone_deg is None else shadow_cone_deg
        self.max_elevation_deg = (
            rig.max_elevation_deg if max_elevation_deg is None else max_elevation_deg
        )
        profiles = {
            name: AxisProfile.from_xseries(a.profile_velocity, a.profile_acceleration)
            for name, a in rig.axes.items()
        }
        costs = StepCosts(
            settle_s=rig.settle_s,
            exposure_s=rig.camera.exposure_s if exposure_s is None else exposure_s,
        )
        self.time_model = TimeModel(profiles, costs)

    @classmethod
    def for_plan(cls, rig: RigConfig, plan: PlanSpec) -> Planner:
        """A planner with the plan's constraint and exposure overrides."""
        return cls(
            rig,
            shadow_cone_deg=plan.shadow_cone_deg,
            max_elevation_deg=plan.max_elevation_deg,
            exposure_s=plan.capture.exposure_s,
        )

    # -- constraints -------------------------------------------------------------------

    def joint_problem(self, joints: Mapping[str, float]) -> Rejection | None:
        """The first constraint the joint targets violate, or None when they are safe."""
        pose = self.kinematics.forward(joints)
        if max(pose.theta_i, pose.theta_r) > self.max_elevation_deg + 1e-9:
            return Rejection(pose, Reason.MAX_ELEVATION,
                             f"elevation above the rig's maximum {self.max_elevation_deg:g}°")
        bad = self.kinematics.violated_limits(joints)
        if bad:
            return Rejection(pose, Reason.JOINT_LIMITS, "; ".join(bad))
        geo = self.kinematics.forward_geometry(joints)
        sep = angle_between_deg(geo.light_dir, geo.camera_dir)
        if sep < self.shadow_cone_deg:
            detail = f"camera {sep:.2f}° from the light, inside the {self.shadow_cone_deg:g}° shadow cone"
            return Rejection(pose, Reason.SHADOW, detail)
        return None

    def check_joints(self, joints: Mapping[str, float]) -> None:
        """Guard for every move: raise unless the joint targets pass every constraint."""
        missing = [n for n in self.kinematics.joint_names if n not in joints]
        if missing:
            raise LimitError(f"move names no target for {', '.join(missing)}: give every axis a target")
        problem = self.joint_problem(joints)
        if problem is None:
            return
        if problem.reason is Reason.SHADOW:
            raise CollisionError(f"refused move: {problem.detail}")
        raise LimitError(f"refused move: {problem.detail}")

    def check_pose(self, pose: Pose, current: Mapping[str, float] | None = None) -> Joints | Rejection:
        """Joint targets for ``pose``, or the reason it cannot be measured."""
        if max(pose.theta_i, pose.theta_r) > self.max_elevation_deg + 1e-9:
            return Rejection(pose, Reason.MAX_ELEVATION,
                             f"θ above the rig's maximum elevation {self.max_elevation_deg:g}°")
        try:
            joints = self.kinematics.inverse(pose, current)
        except UnreachablePoseError as exc:
            return Rejection(pose, Reason.JOINT_LIMITS, str(exc))
        problem = self.joint_problem(joints)
        return joints if problem is None else Rejection(pose, problem.reason, problem.detail)

    def joints_for(self, pose: Pose, current: Mapping[str, float] | None = None) -> Joints:
        """Joint targets for ``pose``; raises LimitError/CollisionError naming the reason."""
        result = self.check_pose(pose, current)
        if isinstance(result, Rejection):
            err = CollisionError if result.reason is Reason.SHADOW else LimitError
            raise err(
                f"pose θi={pose.theta_i:g}° θr={pose.theta_r:g}° Δφ={pose.delta_phi:g}° "
                f"rejected ({result.reason.value}): {result.detail}"
            )
        return result

    # -- planning ----------------------------------------------------------------------

    def plan(self, poses: Sequence[Pose], start: Mapping[str, float]) -> Sweep:
        """Filter, order (serpentine) and time ``poses`` starting from joints ``start``."""
        accepted: list[Pose] = []
        rejected: list[Rejection] = []
        seen: set[tuple[float, float, float]] = set()
        for pose in poses:
            key = tuple(round(v, 9) for v in pose.as_tuple())
            if key in seen:
                rejected.append(Rejection(pose, Reason.DUPLICATE, "listed twice in the plan"))
                continue
            seen.add(key)
            result = self.check_pose(pose)
            if isinstance(result, Rejection):
                rejected.append(result)
            else:
                accepted.append(pose)
        ordered = serpentine(accepted)
        steps = self._assign_joints(ordered, start)
        naive = self._assign_joints(sorted(accepted, key=Pose.as_tuple), start)
        return Sweep(
            steps=steps,
            rejected=rejected,
            start_joints=dict(start),
            motion_s=sum(s.move_s for s in steps),
            overhead_s=len(steps) * self.time_model.step_overhead_s(),
            naive_motion_s=sum(s.move_s for s in naive),
        )

    def _assign_joints(self, ordered: Sequence[Pose], start: Mapping[str, float]) -> list[PlannedPose]:
        steps: list[PlannedPose] = []
        current = dict(start)
        for i, pose in enumerate(ordered):
            joints = self.joints_for(pose, current)
            steps.append(PlannedPose(i, pose, joints, self.time_model.move_s(current, joints)))
            current = joints
        return steps


def serpentine(poses: Sequence[Pose]) -> list[Pose]:
    """Nested-loop order whose inner loops reverse direction on every pass (boustrophedon)."""
    out: list[Pose] = []
    by_ti: dict[float, list[Pose]] = {}
    for p in sorted(poses, key=Pose.as_tuple):
        by_ti.setdefault(p.theta_i, []).append(p)
    flip_outer = False
    flip_inner = False
    for ti in sorted(by_ti):
        by_tr: dict[float, list[Pose]] = {}
        for p in by_ti[ti]:
            by_tr.setdefault(p.theta_r, []).append(p)
        for tr in sorted(by_tr, reverse=flip_outer):
            row = sorted(by_tr[tr], key=lambda p: p.delta_phi, reverse=flip_inner)
            out.extend(row)
            flip_inner = not flip_inner
        flip_outer = not flip_outer
    return out


