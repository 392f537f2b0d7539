"""What the planner returns: the accepted poses in capture order with their joint targets, the
rejected ones with a named :class:`Reason`, and the time estimate (s)."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from enum import StrEnum

from acquisition.geometry.kinematics import Joints, Pose


class Reason(StrEnum):
    """Why a candidate pose was not planned."""

    MAX_ELEVATION = "max-elevation"
    DUPLICATE = "duplicate"
    UNREACHABLE = "unreachable"
    JOINT_LIMITS = "joint-limits"
    ARM_COLLISION = "arm-collision"
    UNROUTABLE = "no-route"
    SHADOW = "shadow"
    FOOTPRINT = "footprint"
    RECIPROCAL = "reciprocal"


SAFETY_REASONS = frozenset({Reason.ARM_COLLISION, Reason.SHADOW})
"""Reasons the guard reports as :class:`CollisionError` (the others as LimitError)."""


@dataclass(frozen=True)
class Rejection:
    """A candidate pose left out, the reason, and a human-readable detail."""

    pose: Pose
    reason: Reason
    detail: str


@dataclass(frozen=True)
class PlannedPose:
    """One accepted pose in capture order with its joint targets (degrees).

    ``pose`` is the pose the joints realise: the requested one, or its mirror image
    (Δφ → −Δφ) when the plan's table folds Δφ and the mirrored solution moves less.
    """

    index: int
    pose: Pose
    joints: Joints
    move_s: float
    """Predicted duration of the move into this pose from the previous one (routed round the
    other arm when the direct move is not safe)."""
    via: tuple[Joints, ...] = ()
    """Via points of that move when it is routed (empty: the direct move is safe)."""


@dataclass
class Sweep:
    """The planner's output: the ordered poses, the rejections, and the time estimate (s)."""

    steps: list[PlannedPose]
    rejected: list[Rejection]
    start_joints: Joints
    motion_s: float
    overhead_s: float
    naive_motion_s: float = float("nan")
    lower_bound_motion_s: float = float("nan")
    extra: dict[str, float] = field(default_factory=dict)
    reference_s: float = 0.0
    """Moves to, captures of and moves back from the white reference the session adds."""

    @property
    def estimated_s(self) -> float:
        """Total predicted duration: motion, per-pose settle/bus/exposure, white references."""
        return self.motion_s + self.overhead_s + self.reference_s

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
