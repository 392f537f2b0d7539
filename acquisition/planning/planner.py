"""The motion planner: which candidate poses are safe and useful, their order, and the ETA.

Every pose is checked against the rig's constraints and kept or rejected with a named
:class:`Reason`. :meth:`Planner.check_move` is the motion guard (the
:class:`~drivers.dynamixel.motion.MotionGuard` the motion controller calls before *every* goal
it sends, braking included): the target's limits and clearance (:meth:`Planner.check_joints`,
which checks a target alone) and the move's whole swept path, also for every subset of the
axes moving alone (a sync write one servo missed). :meth:`Planner.route` finds via points
round the other arm when the direct move is refused. So nothing reaches a servo that the
planner has not checked.

Constraints (in the order a rejection reports them):

``max-elevation``  θi or θr above the rig's maximum (default 85°; below the horizon too).
``duplicate``      the same measurement listed twice (Δφ folded to |Δφ| when the plan's table
                   folds it; Δφ ignored when a direction is the normal).
``unreachable``    the kinematics has no solution at all (a light stage without that light).
``joint-limits``   every solution leaves a joint's soft limits.
``arm-collision``  every remaining solution brings the arms' swept volumes (capsules from
                   the rig's ``[arms]``) closer than the clearance; moves between poses are
                   checked along their whole path too.
``shadow``         camera and light closer than the shadow cone (default 8°).
``footprint``      at grazing angles the light spot or the camera's measured region, stretched
                   by 1/cos θ, no longer fits on the sample.
``reciprocal``     the reciprocal pose (θi ↔ θr) is already planned (unless the plan asks for
                   both).

Accepted poses are ordered by :mod:`acquisition.planning.ordering` on the time model's metric; the
sweep reports the planned motion time, that of the naive order (sorted by (θi, θr, Δφ), each
pose's solution nearest the previous one), a lower bound, and the total estimate including
the white-reference captures the session interleaves.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

from acquisition.config.plan import PlanSpec
from acquisition.config.rig import DEFAULT_CLEARANCE_M, ArmConfig, ArmsConfig, FootprintConfig, RigConfig
from acquisition.geometry.alignment import Alignment
from acquisition.geometry.approach import APPROACH_DEG, approach_point, approach_signs
from acquisition.geometry.kinematics import Joints, Kinematics, Pose, poses_to_array
from acquisition.geometry.kinematics.base import (
    angle_between_deg_array,
    directions_from_poses,
    wrap_deg_array,
)
from acquisition.geometry.kinematics.calibrated import CalibratedKinematics
from acquisition.planning import ordering, refusals
from acquisition.planning.paths import (
    MEMO_SIZE,
    MOVING_DEG,
    PathChecker,
    PathProblem,
    Router,
    route_or_raise,
)
from acquisition.planning.timing import AxisProfile, StepCosts, TimeModel
from drivers.errors import CollisionError, LimitError

KEY_DECIMALS = 6
"""Poses equal to this many decimals of a degree are the same measurement."""

BOUNDS = ("auto", "held-karp", "nearest")
HELD_KARP_AUTO_MAX = 1200
"""Largest sweep for which ``bound="auto"`` computes the Held–Karp bound."""


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


def segment_params(p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Where segments p1–q1 and p2–q2 (…, 3) come closest: the fractions (s, t) ∈ [0, 1] along
    each, vectorised."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a = np.sum(d1 * d1, -1)
    e = np.sum(d2 * d2, -1)
    f = np.sum(d2 * r, -1)
    c = np.sum(d1 * r, -1)
    b = np.sum(d1 * d2, -1)
    denom = a * e - b * b
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.where(denom > 1e-15, np.clip((b * f - c * e) / denom, 0.0, 1.0), 0.0)
        t = np.where(e > 1e-15, (b * s + f) / e, 0.0)
        s = np.where(t < 0, np.where(a > 1e-15, np.clip(-c / a, 0, 1), 0.0), s)
        s = np.where(t > 1, np.where(a > 1e-15, np.clip((b - c) / a, 0, 1), 0.0), s)
        t = np.clip(t, 0.0, 1.0)
    return s, t


def segment_distance(p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Shortest distance between segments p1–q1 and p2–q2 (…, 3), vectorised."""
    s, t = segment_params(p1, q1, p2, q2)
    gap = (p1 + (q1 - p1) * s[..., None]) - (p2 + (q2 - p2) * t[..., None])
    return np.linalg.norm(gap, axis=-1)


def _fmt_pose(p: np.ndarray | Pose) -> str:
    ti, tr, dp = p.as_tuple() if isinstance(p, Pose) else p
    return f"θi={ti:g}° θr={tr:g}° Δφ={dp:g}°"


class Planner:
    """Checks poses and joint targets against one rig's constraints and plans sweeps.

    Parameters
    ----------
    rig:
        The rig (kinematics, limits, arms, sample/spot sizes, speeds).
    shadow_cone_deg, max_elevation_deg, exposure_s:
        Overrides of the rig's values.
    reciprocal:
        "once" (default) keeps one of a pose and its reciprocal; "both" keeps both.
    mirror_delta_phi:
        Treat Δφ and −Δφ as the same measurement (an isotropic table folded to [0°, 180°]).
    reference_every:
        The session's white-reference interval (0: first and last only), for the ETA.
    time_budget_s:
        Host time the order search may take.
    bound:
        Lower bound on the motion time: "held-karp" (Lagrangian 1-tree; needs the dense
        matrix of move times, seconds of work for a few thousand poses), "nearest" (each pose
        entered by its cheapest move; fast) or "auto" (Held–Karp up to
        :data:`HELD_KARP_AUTO_MAX` poses).
    alignment:
        The rig's geometric calibration (zero offsets, sample tilt, backlash): the joint
        targets then realise each pose on the real rig, and the guard checks the joints it
        sends with the arms where the calibration puts them
        (:class:`~acquisition.geometry.kinematics.calibrated.CalibratedKinematics`).
    approach:
        Approach every target from one side (:mod:`acquisition.geometry.approach`: a leg to
        just below it first, guarded like any other); default: when the rig file states
        backlash on an axis, or the calibration measured some.
    """

    def __init__(
        self,
        rig: RigConfig,
        *,
        shadow_cone_deg: float | None = None,
        max_elevation_deg: float | None = None,
        exposure_s: float | None = None,
        reciprocal: str = "once",
        mirror_delta_phi: bool = True,
        reference_every: int = 0,
        time_budget_s: float = 2.0,
        bound: str = "auto",
        alignment: Alignment | None = None,
        approach: bool | None = None,
    ) -> None:
        self.rig = rig
        self.alignment = alignment
        if approach is None:
            approach = any(a.backlash_deg > 0 for a in rig.axes.values()) or (
                alignment is not None and any(alignment.backlash_deg.values()))
        self.approach = approach
        self.kinematics: Kinematics = rig.kinematics()
        if alignment is not None and self.kinematics.moving_arms:
            self.kinematics = CalibratedKinematics(self.kinematics, alignment)
        self.shadow_cone_deg = rig.shadow_cone_deg if shadow_cone_deg is None else shadow_cone_deg
        self.max_elevation_deg = (
            rig.max_elevation_deg if max_elevation_deg is None else max_elevation_deg
        )
        self.reciprocal = reciprocal
        self.mirror_delta_phi = mirror_delta_phi
        self.reference_every = reference_every
        self.time_budget_s = time_budget_s
        if bound not in BOUNDS:
            raise ValueError(f"bound must be one of {', '.join(BOUNDS)}, got {bound!r}")
        self.bound = bound
        self._target_memo: dict[tuple[object, ...], Rejection | None] = {}
        self._memo_lock = threading.Lock()
        self.arms: ArmsConfig = rig.arms or ArmsConfig(
            ArmConfig(0.0, rig.light_distance_m, rig.light_distance_m),
            ArmConfig(0.0, rig.camera_distance_m, rig.camera_distance_m), DEFAULT_CLEARANCE_M)
        self.footprint: FootprintConfig | None = rig.footprint
        profiles = {
            name: AxisProfile.from_xseries(a.profile_velocity, a.profile_acceleration)
            for name, a in rig.axes.items()
        }
        costs = StepCosts(
            settle_s=rig.settle_s,
            bus_cycle_s=rig.bus_cycle_s,
            leg_bus_s=max(rig.bus_cycle_s - rig.health_read_s, 0.0),
            exposure_s=rig.camera.exposure_s if exposure_s is None else exposure_s,
        )
        self.time_model = TimeModel(profiles, costs)
        self.array_time = self.time_model.for_joints(self.kinematics.joint_names)
        scale = np.zeros(len(self.kinematics.joint_names))
        scale[self.array_time.axes] = 1.0 / self.array_time.accel
        self._scale = scale
        self.paths = PathChecker(self.arm_gap_m, self.array_time.positions, self.array_time.move_s,
                                 self.arms.light.to_m + self.arms.camera.to_m, self._arm_joints())
        self.router = Router(self.paths, self.kinematics._lo, self.kinematics._hi,
                             self.array_time.move_s, self.safe_mask)

    def _arm_joints(self) -> list[int]:
        """Indices of the joints that move an arm (found by turning each one a little at a
        general configuration; a light stage has none)."""
        if not self.kinematics.moving_arms:
            return []
        kin = self.kinematics
        base = kin._lo + 0.37 * (kin._hi - kin._lo)
        light0, camera0 = kin.arm_directions_array(base[None])
        out = []
        for j in range(len(base)):
            turned = base.copy()
            turned[j] += 1.0
            light1, camera1 = kin.arm_directions_array(turned[None])
            if not (np.allclose(light0, light1) and np.allclose(camera0, camera1)):
                out.append(j)
        return out

    @classmethod
    def for_plan(cls, rig: RigConfig, plan: PlanSpec, alignment: Alignment | None = None
                 ) -> Planner:
        """A planner with the plan's constraint, exposure and reciprocity settings (and the
        rig's geometric calibration, if given)."""
        return cls(
            rig,
            shadow_cone_deg=plan.shadow_cone_deg,
            max_elevation_deg=plan.max_elevation_deg,
            exposure_s=plan.capture.exposure_s,
            reciprocal=plan.reciprocal,
            mirror_delta_phi=plan.mirror_delta_phi,
            reference_every=plan.capture.reference_every,
            alignment=alignment,
        )

    # -- vectorised constraint checks ----------------------------------------------------

    def arm_gap_m(self, joints: np.ndarray) -> np.ndarray:
        """Clearance (m) between the two arms' capsules for joints (N, J); < 0 collides."""
        light, camera = self.kinematics.arm_directions_array(joints)
        la, ca = self.arms.light, self.arms.camera
        dist = segment_distance(light * la.from_m, light * la.to_m, camera * ca.from_m,
                                camera * ca.to_m)
        return dist - la.radius_m - ca.radius_m - self.arms.clearance_m

    def collision_mask(self, joints: np.ndarray) -> np.ndarray:
        """True where the arms collide at joints (N, J) (never for a fixed light stage)."""
        if not self.kinematics.moving_arms:
            return np.zeros(len(joints), dtype=bool)
        return self.arm_gap_m(joints) < 0

    def transit_ok(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """True where the moves a → b (M, J) are proven to keep the arms apart along their
        whole path, each axis on its own trapezoid from the same start, and so does every
        subset of the moving axes moving alone (:mod:`acquisition.planning.paths`)."""
        m = len(a)
        if not self.kinematics.moving_arms or m == 0:
            return np.ones(m, dtype=bool)
        return self.paths.move_safe(a, b)

    def safe_mask(self, joints: np.ndarray) -> np.ndarray:
        """True where joints (N, J) pass every safety constraint of :meth:`joint_problem`
        except the soft limits (within limits by construction of the caller's points)."""
        poses = self.kinematics.poses_array(joints)
        high = np.nanmax(poses[:, :2], axis=1) > self.max_elevation_deg + 1e-9
        light, camera = self.kinematics.forward_array(joints)
        shadow = angle_between_deg_array(light, camera) < self.shadow_cone_deg
        return ~(high | shadow | self.collision_mask(joints))

    def _pose_geometry_reasons(self, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(shadow, footprint) masks for (θi, θr, Δφ) rows (N, 3)."""
        light, camera = directions_from_poses(poses)
        shadow = angle_between_deg_array(light, camera) < self.shadow_cone_deg
        fp = self.footprint
        if fp is None:
            return shadow, np.zeros(len(poses), dtype=bool)
        cos_i, cos_r = np.cos(np.radians(poses[:, 0])), np.cos(np.radians(poses[:, 1]))
        with np.errstate(divide="ignore"):
            spot = fp.spot_diameter_m / np.maximum(cos_i, 0)
            view = fp.view_diameter_m / np.maximum(cos_r, 0)
        return shadow, (spot > fp.sample_size_m) | (view > fp.sample_size_m)

    def _footprint_detail(self, pose: np.ndarray) -> str:
        fp = self.footprint
        assert fp is not None
        spot = fp.spot_diameter_m / max(np.cos(np.radians(pose[0])), 1e-12)
        view = fp.view_diameter_m / max(np.cos(np.radians(pose[1])), 1e-12)
        what = (f"light spot {spot * 1e3:.1f} mm" if spot > fp.sample_size_m
                else f"camera's measured region {view * 1e3:.1f} mm")
        return f"at grazing angle the {what} exceeds the {fp.sample_size_m * 1e3:g} mm sample"

    def _keys(self, poses: np.ndarray, swap: bool = False) -> np.ndarray:
        """Canonical measurement keys (N, 3) (rounded, Δφ folded/ignored as appropriate)."""
        ti, tr = (poses[:, 1], poses[:, 0]) if swap else (poses[:, 0], poses[:, 1])
        dp = wrap_deg_array(poses[:, 2])
        if self.mirror_delta_phi:
            dp = np.abs(dp)
        elif swap:
            dp = wrap_deg_array(-dp)  # the reciprocal of Δφ is −Δφ
        dp = np.where(np.minimum(ti, tr) < 10.0**-KEY_DECIMALS, 0.0, dp)
        return np.round(np.column_stack([ti, tr, dp]), KEY_DECIMALS) + 0.0

    def candidates(self, poses: np.ndarray, hold: Mapping[str, float] | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
        """Every joint solution (N, K, J) of each pose, and (N, K) whether it realises the
        mirrored pose (Δφ → −Δφ). Mirrored solutions come after the direct ones."""
        cands = self.kinematics.inverse_array(poses, hold)
        mirrored = np.zeros(cands.shape[:2], dtype=bool)
        if self.mirror_delta_phi:
            flipped = poses.copy()
            flipped[:, 2] = -flipped[:, 2]
            more = self.kinematics.inverse_array(flipped, hold)
            cands = np.concatenate([cands, more], axis=1)
            mirrored = np.concatenate([mirrored, np.ones(more.shape[:2], dtype=bool)], axis=1)
        return cands, mirrored

    def screen(self, poses: np.ndarray, hold: Mapping[str, float] | None = None
               ) -> tuple[list[Reason | None], np.ndarray, np.ndarray]:
        """Check candidate poses (N, 3) against every constraint but reciprocity.

        Returns the reason per pose (None when accepted), the usable configurations
        (N, K, J) (NaN where a solution is unusable) and the mirrored-solution mask (N, K).
        """
        n = len(poses)
        reason: list[Reason | None] = [None] * n
        over = np.max(poses[:, :2], axis=1) > self.max_elevation_deg + 1e-9
        keys = self._keys(poses)
        _, first = np.unique(keys, axis=0, return_index=True)
        dup = np.ones(n, dtype=bool)
        dup[first] = False
        cands, mirrored = self.candidates(poses, hold)
        exists = ~np.any(np.isnan(cands), axis=-1)
        within = exists & self.kinematics.limit_mask(cands)
        free = within.copy()
        if within.any():
            flat = cands[within]
            free[within] = ~self.collision_mask(flat)
        shadow, footprint = self._pose_geometry_reasons(poses)
        checks = [
            (Reason.MAX_ELEVATION, over),
            (Reason.DUPLICATE, dup),
            (Reason.UNREACHABLE, ~exists.any(axis=1)),
            (Reason.JOINT_LIMITS, ~within.any(axis=1)),
            (Reason.ARM_COLLISION, ~free.any(axis=1)),
            (Reason.SHADOW, shadow),
            (Reason.FOOTPRINT, footprint),
        ]
        decided = np.zeros(n, dtype=bool)
        for r, mask in checks:
            hit = mask & ~decided
            for i in np.flatnonzero(hit):
                reason[i] = r
            decided |= hit
        usable = np.where(free[..., None], cands, np.nan)
        return reason, usable, mirrored

    def _detail(self, reason: Reason, pose: np.ndarray) -> str:
        if reason is Reason.MAX_ELEVATION:
            where = "below the horizon" if max(pose[0], pose[1]) > 90 else "above the rig's maximum"
            return f"θ {where} (maximum elevation {self.max_elevation_deg:g}°)"
        if reason is Reason.DUPLICATE:
            return "the same measurement is listed earlier in the plan"
        if reason is Reason.UNREACHABLE:
            return f"the {self.kinematics.name} rig cannot realise this pose"
        if reason is Reason.JOINT_LIMITS:
            cands = self.kinematics.inverse_candidates(Pose(*map(float, pose)))
            if cands:
                bad = self.kinematics.violated_limits(cands[0])
                return "every solution leaves the soft limits, e.g. " + "; ".join(bad)
            return "every solution leaves the soft limits"
        if reason is Reason.ARM_COLLISION:
            return (f"every solution brings the arms within the {self.arms.clearance_m * 1e3:g} mm "
                    "clearance")
        if reason is Reason.UNROUTABLE:
            return ("no collision-free route from the start pose reaches it (the arms would "
                    "have to pass through each other)")
        if reason is Reason.SHADOW:
            light, camera = directions_from_poses(pose[None])
            sep = float(angle_between_deg_array(light, camera)[0])
            return f"camera {sep:.2f}° from the light, inside the {self.shadow_cone_deg:g}° shadow cone"
        if reason is Reason.FOOTPRINT:
            return self._footprint_detail(pose)
        return "its reciprocal (θi ↔ θr) is already planned"

    # -- single pose / joints (the guard) ----------------------------------------------

    def joint_problem(self, joints: Mapping[str, float]) -> Rejection | None:
        """The first safety constraint the joint targets violate, or None when they are safe.

        Checks maximum elevation, soft limits, arm collision and the shadow cone (not the
        footprint, which makes a measurement useless but not unsafe)."""
        arr = self.kinematics.to_array(joints)[None]
        pose_row = self.kinematics.poses_array(arr)[0]
        pose = Pose(*map(float, pose_row))
        if max(pose.theta_i, pose.theta_r) > self.max_elevation_deg + 1e-9:
            return Rejection(pose, Reason.MAX_ELEVATION, self._detail(Reason.MAX_ELEVATION, pose_row))
        bad = self.kinematics.violated_limits(joints)
        if bad:
            return Rejection(pose, Reason.JOINT_LIMITS, "; ".join(bad))
        if self.collision_mask(arr)[0]:
            gap = float(self.arm_gap_m(arr)[0]) + self.arms.clearance_m
            where = f"overlap by {-gap * 1e3:.1f} mm" if gap < 0 else f"be {gap * 1e3:.1f} mm apart"
            detail = (f"the arms' swept volumes would {where} (clearance "
                      f"{self.arms.clearance_m * 1e3:g} mm)")
            return Rejection(pose, Reason.ARM_COLLISION, detail)
        light, camera = self.kinematics.forward_array(arr)
        sep = float(angle_between_deg_array(light, camera)[0])
        if sep < self.shadow_cone_deg:
            detail = f"camera {sep:.2f}° from the light, inside the {self.shadow_cone_deg:g}° shadow cone"
            return Rejection(pose, Reason.SHADOW, detail)
        return None

    def check_joints(self, joints: Mapping[str, float], moving: Sequence[str] | None = None
                     ) -> None:
        """The target part of the guard (:meth:`check_move`): raise unless the joint targets
        pass every safety constraint, in one line naming the axes (``moving``: those the move
        turns; all by default), where the arms would meet and what to do."""
        missing = [n for n in self.kinematics.joint_names if n not in joints]
        if missing:
            raise LimitError(f"move names no target for {', '.join(missing)}: give every axis a target")
        problem = self._remembered_problem(joints)
        if problem is None:
            return
        err = CollisionError if problem.reason in SAFETY_REASONS else LimitError
        raise err(self._target_refusal(problem, joints, moving))

    def _remembered_problem(self, joints: Mapping[str, float]) -> Rejection | None:
        """:meth:`joint_problem`, remembering the last :data:`MEMO_SIZE` targets (a session
        step's target is checked when planned, routed and sent)."""
        key = (tuple(float(joints[n]) for n in self.kinematics.joint_names),
               self.max_elevation_deg, self.shadow_cone_deg, self.arms)
        with self._memo_lock:
            if key in self._target_memo:
                return self._target_memo[key]
        problem = self.joint_problem(joints)
        with self._memo_lock:
            self._target_memo[key] = problem
            while len(self._target_memo) > MEMO_SIZE:
                del self._target_memo[next(iter(self._target_memo))]
        return problem

    def _target_refusal(self, problem: Rejection, joints: Mapping[str, float],
                        moving: Sequence[str] | None) -> str:
        names = self.kinematics.joint_names
        axes = list(moving) if moving else list(names)
        at = {n: float(joints[n]) for n in names}
        if problem.reason is Reason.JOINT_LIMITS:
            limits = self.kinematics.limits
            return refusals.limits([n for n in names if not limits[n].contains(at[n])],
                                   self.kinematics.violated_limits(at))
        if problem.reason is Reason.MAX_ELEVATION:
            return refusals.elevation(axes, problem.pose.theta_i, problem.pose.theta_r,
                                      self.max_elevation_deg)
        if problem.reason is Reason.ARM_COLLISION:
            return refusals.target_collision(axes, at, self.arm_meeting(at), self.arms.clearance_m)
        light, camera = self.kinematics.forward_array(self.kinematics.to_array(at)[None])
        return refusals.shadow(axes, at, float(angle_between_deg_array(light, camera)[0]),
                               self.shadow_cone_deg)

    def arm_meeting(self, joints: Mapping[str, float]) -> refusals.Meeting:
        """Where the arms' capsules come closest at ``joints``: the clearance left there (m)
        and the distance of each closest point from the sample centre along its arm (m)."""
        arr = self.kinematics.to_array(joints)[None]
        light, camera = self.kinematics.arm_directions_array(arr)
        la, ca = self.arms.light, self.arms.camera
        s, t = segment_params(light * la.from_m, light * la.to_m, camera * ca.from_m,
                              camera * ca.to_m)
        return refusals.Meeting(float(self.arm_gap_m(arr)[0]),
                                la.from_m + float(s[0]) * (la.to_m - la.from_m),
                                ca.from_m + float(t[0]) * (ca.to_m - ca.from_m))

    def check_move(self, current: Mapping[str, float], target: Mapping[str, float]) -> None:
        """The motion guard: raise unless ``target`` passes every safety constraint and the
        move from ``current`` keeps the arms apart along its whole swept path, also when some
        axes miss the sync write (:class:`LimitError` or :class:`CollisionError`, one line
        naming the axes, where the arms would meet and what to do)."""
        full = {**current, **target}
        self.check_joints(full, self._moving(current, full))
        if not self.kinematics.moving_arms:
            return
        names = self.kinematics.joint_names
        problem = self.paths.problem(self.kinematics.to_array(current),
                                     self.kinematics.to_array(full), names)
        if problem is not None:
            raise CollisionError(self.describe(problem))

    def _moving(self, current: Mapping[str, float], full: Mapping[str, float]) -> list[str]:
        """The axes a move from ``current`` to ``full`` turns (all when ``current`` lacks one)."""
        names = self.kinematics.joint_names
        if any(n not in current for n in names):
            return list(names)
        return [n for n in names if abs(full[n] - current[n]) > MOVING_DEG]

    def describe(self, problem: PathProblem | None, *, routed: bool = True) -> str:
        """The refusal of a move whose swept path ``problem`` shows (``routed=False``: and no
        route round it exists): which axes, where on the way the arms would meet, what to do."""
        if problem is None:  # cannot happen for a refused route; worded all the same
            return refusals.refusal([], "no safe route was found", refusals.NO_ROUTE_ADVICE)
        return refusals.swept_path(problem.moving, problem.others, problem.at,
                                   self.arm_meeting(problem.at), self.arms.clearance_m,
                                   routed=routed)

    def route(self, current: Mapping[str, float], target: Mapping[str, float]) -> list[Joints]:
        """The legs of a safe move from ``current`` to ``target``: ``[target]`` when the direct
        move is safe, else via points round the other arm, then ``target``.

        Raises
        ------
        LimitError, CollisionError
            ``target`` itself is unsafe, or no route exists inside the joint limits (one line).
        """
        full = {**current, **target}
        moving = self._moving(current, full)
        self.check_joints(full, moving)
        if not self.kinematics.moving_arms:
            return [full]
        names = self.kinematics.joint_names
        if self.approach and moving:
            legs = self._approached(current, full)
            if legs is not None:
                return legs
        return route_or_raise(self.router, current, full, names,
                              lambda problem: self.describe(problem, routed=False))

    def _approached(self, current: Mapping[str, float], full: Mapping[str, float]
                    ) -> list[Joints] | None:
        """The legs of a move that approaches ``full`` from the side every capture approaches
        from (through :func:`~acquisition.geometry.approach.approach_point`), or None where
        that point or its last leg is not safe (the move then goes straight)."""
        names = self.kinematics.joint_names
        lower = {n: self.kinematics.limits[n].min_deg for n in names}
        pre = approach_point({n: full[n] for n in names}, lower)
        try:
            self.check_joints(pre)
            legs = route_or_raise(self.router, current, pre, names,
                                  lambda problem: self.describe(problem, routed=False))
        except (LimitError, CollisionError):
            return None
        if self.paths.problem(self.kinematics.to_array(pre), self.kinematics.to_array(full),
                              names) is not None:
            return None
        return [*legs, dict(full)]

    def route_s(self, current: Mapping[str, float], target: Mapping[str, float]) -> float:
        """Motion time (s) of :meth:`route` (the direct move's when it is safe or unroutable)."""
        try:
            legs = self.route(current, target)
        except (LimitError, CollisionError):
            return self.time_model.move_s(current, target)
        total, at = 0.0, dict(current)
        for leg in legs:
            total += self.time_model.move_s(at, leg)
            at = leg
        return total

    def check_pose(self, pose: Pose, current: Mapping[str, float] | None = None) -> Joints | Rejection:
        """Joint targets for ``pose`` (the usable solution that moves least from ``current``),
        or the reason it cannot be measured."""
        row = np.array([pose.as_tuple()], dtype=float)
        hold = None
        if current is not None:
            hold = {n: current[n] for n in self.kinematics.free_joints if n in current}
        reason, usable, _ = self.screen(row, hold)
        if reason[0] is not None:
            return Rejection(pose, reason[0], self._detail(reason[0], row[0]))
        cfg = usable[0]
        ok = np.flatnonzero(~np.any(np.isnan(cfg), axis=-1))
        if current is None:
            pick = ok[0]
        else:
            cost = self.array_time.move_s(self.kinematics.to_array(current)[None], cfg[ok])
            pick = ok[int(np.argmin(cost))]
        return self.kinematics.to_dict(cfg[pick])

    def joints_for(self, pose: Pose, current: Mapping[str, float] | None = None) -> Joints:
        """Joint targets for ``pose``; raises LimitError/CollisionError naming the reason."""
        result = self.check_pose(pose, current)
        if isinstance(result, Rejection):
            err = CollisionError if result.reason in SAFETY_REASONS else LimitError
            raise err(
                f"pose {_fmt_pose(pose)} rejected ({result.reason.value}): {result.detail}"
            )
        return result

    # -- planning ----------------------------------------------------------------------

    def plan(self, poses: Sequence[Pose], start: Mapping[str, float]) -> Sweep:
        """Filter, order and time ``poses`` starting from joints ``start``."""
        t0 = time.monotonic()
        req = poses_to_array(list(poses))
        start_arr = self.kinematics.to_array(start)
        hold = {n: float(start[n]) for n in self.kinematics.free_joints}
        reason, usable, mirrored = self.screen(req, hold) if len(req) else ([], req, req)
        accepted = np.array([r is None for r in reason], dtype=bool)
        if self.kinematics.moving_arms and accepted.any():
            usable = self._reachable_only(start_arr, usable, accepted, reason)
        if self.reciprocal == "once" and accepted.any():
            self._reject_reciprocals(req, accepted, reason)
        t_screen = time.monotonic() - t0
        for _ in range(4):
            idx = np.flatnonzero(accepted)
            cfg, mir = self._compact(usable[idx], mirrored[idx]) if len(idx) else (
                np.zeros((0, 1, len(start_arr))), np.zeros((0, 1), bool))
            problem = ordering.Problem(cfg, start_arr, self.array_time.move_s, self._scale,
                                       transit_ok=self.transit_ok, reach=self.array_time.reach_deg)
            sol = ordering.solve(problem, self.time_budget_s)
            steps, stuck = self._routed(
                self._steps(req, idx, cfg, mir, sol.order, sol.choice, start_arr), start)
            if not stuck:
                break
            # No collision-free route into these poses (the arms cannot pass each other):
            # leave them out, order the rest again.
            for k in stuck:
                i = idx[sol.order[k]]
                accepted[i] = False
                reason[i] = Reason.UNROUTABLE
        else:
            raise CollisionError("the plan's poses cannot be ordered so that every move is safe: "
                                 "narrow its ranges (`gonio plan --out plan.png` shows them)")
        t_order = time.monotonic() - t0 - t_screen
        naive = self._naive_motion_s(req[idx], cfg, start_arr)
        use_hk = self.bound == "held-karp" or (
            self.bound == "auto" and problem.n <= HELD_KARP_AUTO_MAX)
        if use_hk and problem.n <= ordering.DENSE_MAX:
            bound = ordering.held_karp_bound(problem, sol.motion_s, time_budget_s=self.time_budget_s)
        else:
            bound = ordering.nearest_move_bound(problem) if problem.n else 0.0
        rejected = self._rejections(req, reason)
        sweep = Sweep(
            steps=steps,
            rejected=rejected,
            start_joints=dict(start),
            motion_s=float(sum(s.move_s for s in steps)),
            overhead_s=len(steps) * self.time_model.step_overhead_s(),
            naive_motion_s=naive,
            lower_bound_motion_s=bound,
            reference_s=self._reference_s(steps, start),
        )
        sweep.extra.update({
            "routed_moves": float(sum(1 for s in steps if s.via)),
            "unsafe_moves": float(sol.unsafe_moves),
            "screen_s": t_screen,
            "order_s": t_order,
            "plan_s": time.monotonic() - t0,
        })
        return sweep

    def _reachable_only(self, start: np.ndarray, usable: np.ndarray, accepted: np.ndarray,
                        reason: list[Reason | None]) -> np.ndarray:
        """``usable`` (N, K, J) without the solutions no collision-free route joins to the start
        (arms that would have to pass through each other); poses left with none are rejected
        as arm collisions."""
        idx = np.flatnonzero(accepted)
        cfg = usable[idx]
        flat = cfg.reshape(-1, cfg.shape[-1])
        ok = self.router.reachable(start, flat).reshape(cfg.shape[:2])
        usable = usable.copy()
        usable[idx] = np.where(ok[..., None], cfg, np.nan)
        for i in idx[~ok.any(axis=1)]:
            accepted[i] = False
            reason[i] = Reason.UNROUTABLE
        return usable

    def _rejections(self, req: np.ndarray, reason: list[Reason | None]) -> list[Rejection]:
        """Rejection records, with the per-pose detail computed only where it varies."""
        fixed: dict[Reason, str] = {}
        rows = req.tolist()
        out = []
        for i, r in enumerate(reason):
            if r is None:
                continue
            if r in (Reason.DUPLICATE, Reason.RECIPROCAL, Reason.UNREACHABLE, Reason.ARM_COLLISION,
                     Reason.UNROUTABLE):
                detail = fixed.get(r)
                if detail is None:
                    detail = fixed[r] = self._detail(r, req[i])
            else:
                detail = self._detail(r, req[i])
            out.append(Rejection(Pose(*rows[i]), r, detail))
        return out

    def _reject_reciprocals(self, req: np.ndarray, accepted: np.ndarray,
                            reason: list[Reason | None]) -> None:
        """Reject each accepted pose whose reciprocal is accepted earlier in the list."""
        idx = np.flatnonzero(accepted)
        keys = self._keys(req[idx])
        recip = self._keys(req[idx], swap=True)
        _, ids = np.unique(np.vstack([keys, recip]), axis=0, return_inverse=True)
        ids = ids.ravel()
        position = np.full(ids.max() + 1, -1)
        position[ids[: len(idx)]] = np.arange(len(idx))
        partner = position[ids[len(idx):]]
        later = (partner >= 0) & (partner < np.arange(len(idx)))
        for i in idx[later]:
            accepted[i] = False
            reason[i] = Reason.RECIPROCAL

    @staticmethod
    def _compact(cfg: np.ndarray, mirrored: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Usable solutions first, duplicates dropped, the K axis cut to the most any pose has."""
        ok = ~np.any(np.isnan(cfg), axis=-1)
        # drop exact duplicates within a pose
        rounded = np.round(np.nan_to_num(cfg, nan=1e9), 9)
        for k in range(1, cfg.shape[1]):
            same = np.all(rounded[:, :k] == rounded[:, k:k + 1], axis=-1).any(axis=1)
            ok[:, k] &= ~same
        order = np.argsort(~ok, axis=1, kind="stable")
        cfg = np.take_along_axis(cfg, order[..., None], axis=1)
        mirrored = np.take_along_axis(mirrored, order, axis=1)
        ok = np.take_along_axis(ok, order, axis=1)
        kmax = max(int(ok.sum(axis=1).max(initial=1)), 1)
        cfg = np.where(ok[..., None], cfg, np.nan)[:, :kmax]
        return cfg, mirrored[:, :kmax]

    def _steps(self, req: np.ndarray, idx: np.ndarray, cfg: np.ndarray, mir: np.ndarray,
               order: np.ndarray, choice: np.ndarray, start: np.ndarray) -> list[PlannedPose]:
        if not len(order):
            return []
        joints = cfg[order, choice[order]]
        prev = np.vstack([start[None], joints[:-1]])
        moves = self._step_moves_s(prev, joints)
        steps = []
        for n, (k, row, move) in enumerate(zip(order, joints, moves, strict=True)):
            ti, tr, dp = req[idx[k]]
            if mir[k, choice[k]]:
                dp = -dp
            steps.append(PlannedPose(n, Pose(float(ti), float(tr), float(dp) + 0.0),
                                     self.kinematics.to_dict(row), float(move)))
        return steps

    def _step_moves_s(self, prev: np.ndarray, joints: np.ndarray) -> np.ndarray:
        """Motion times (s) of the moves prev → joints (N, J) as the rig makes them: with
        backlash, by the approach point :data:`APPROACH_DEG` short of the target (one more
        leg and its bus cycle, as :meth:`leg_s` counts them); routed moves are re-timed later."""
        direct = self.array_time.move_s(prev, joints)
        if not self.approach or not self.kinematics.moving_arms:
            return direct
        lower = [self.kinematics.limits[n].min_deg for n in self.kinematics.joint_names]
        pre = joints - approach_signs(joints, lower) * APPROACH_DEG
        legs = self.array_time.move_s(prev, pre) + self.array_time.move_s(pre, joints)
        moving = np.any(prev != joints, axis=-1)
        return np.where(moving, legs + self.time_model.costs.leg_bus_s, direct)

    def _naive_motion_s(self, req: np.ndarray, cfg: np.ndarray, start: np.ndarray) -> float:
        """Motion time of the poses sorted by (θi, θr, Δφ), each taking the solution nearest
        the previous one (what nested loops calling the inverse kinematics would do)."""
        if not len(req):
            return 0.0
        order = np.lexsort((req[:, 2], req[:, 1], req[:, 0]))
        c = cfg[order]
        first = self.array_time.move_s(start[None, :], c[0])
        trans = self.array_time.move_s(c[:-1, :, None, :], c[1:, None, :, :])  # (N-1, K, K)
        first = np.where(np.isnan(first), np.inf, first)
        trans = np.where(np.isnan(trans), np.inf, trans).tolist()
        j = int(np.argmin(first))
        total = float(first[j])
        for row in trans:
            nxt = row[j]
            j = min(range(len(nxt)), key=nxt.__getitem__)
            total += nxt[j]
        return total

    def reference_joints(self) -> Joints | None:
        """Joints of the rig's white-reference pose, or None when this rig cannot take it."""
        wr = self.rig.white_reference
        result = self.check_pose(Pose(wr.theta_i, wr.theta_r, wr.delta_phi))
        return None if isinstance(result, Rejection) else result

    def leg_s(self, current: Mapping[str, float], target: Mapping[str, float]) -> float:
        """Predicted time (s) of the move as the rig will make it: routed when the direct move
        is unsafe, each extra leg adding its bus time (goal write and confirming polls)."""
        legs = self._legs(current, target)
        total, at = 0.0, dict(current)
        for leg in legs:
            total += self.time_model.move_s(at, leg)
            at = leg
        return total + (len(legs) - 1) * self.time_model.costs.leg_bus_s

    def _legs(self, current: Mapping[str, float], target: Mapping[str, float]) -> list[Joints]:
        try:
            return self.route(current, target)
        except (LimitError, CollisionError):
            return [dict(target)]

    def _routed(self, steps: list[PlannedPose], start: Mapping[str, float]
                ) -> tuple[list[PlannedPose], list[int]]:
        """``steps`` with every move the session will make (white references included) checked
        against the guard and, where the direct move is not safe, routed round the other arm
        (via points and time); and the steps no route reaches.

        Raises
        ------
        CollisionError
            The white reference has no safe route: nothing can be captured.
        """
        if not self.kinematics.moving_arms or not steps:
            return steps, []
        ref = self.reference_joints()
        # (from, to, the step entered or None for a reference, the step it leaves). A step's
        # move_s is the move from the previous pose; the session also goes by the reference.
        legs: list[tuple[Mapping[str, float], Mapping[str, float], int | None, int | None]] = []
        if ref is not None:
            legs += [(start, ref, None, None), (ref, steps[0].joints, None, 0)]
        legs.append((start, steps[0].joints, 0, None))
        every = self.reference_every
        for i in range(1, len(steps)):
            legs.append((steps[i - 1].joints, steps[i].joints, i, None))
            if ref is not None and every and i % every == 0:
                legs += [(steps[i - 1].joints, ref, None, i - 1), (ref, steps[i].joints, None, i)]
        if ref is not None:
            legs.append((steps[-1].joints, ref, None, len(steps) - 1))
        names = self.kinematics.joint_names
        a = np.array([[leg[0][n] for n in names] for leg in legs])
        b = np.array([[leg[1][n] for n in names] for leg in legs])
        out, stuck = list(steps), []
        for k in np.flatnonzero(~self.transit_ok(a, b)):
            cur, target, entered, other = legs[k]
            try:
                route = self.route(cur, target)
            except CollisionError as exc:
                culprit = entered if entered is not None else other
                if culprit is None:
                    raise CollisionError(f"the white reference cannot be reached safely from "
                                         f"the start: {exc}") from None
                stuck.append(culprit)
                continue
            if entered is not None:
                out[entered] = dataclasses.replace(out[entered], via=tuple(route[:-1]),
                                                   move_s=self.leg_s(cur, target))
        return out, sorted(set(stuck))

    def unsafe_moves(self, sweep_steps: Sequence[PlannedPose], start: Mapping[str, float]) -> int:
        """How many moves of the session (white references included) the guard would refuse
        along their route: 0 for every plan :meth:`plan` returns."""
        ref = self.reference_joints()
        points = ([start, ref] if ref is not None else [start]) + [s.joints for s in sweep_steps]
        if ref is not None:
            points.append(ref)
        bad = 0
        for a, b in zip(points, points[1:], strict=False):
            try:
                at = dict(a)
                for leg in self.route(a, b):
                    self.check_move(at, leg)
                    at = leg
            except (LimitError, CollisionError):
                bad += 1
        return bad

    def _reference_s(self, steps: Sequence[PlannedPose], start: Mapping[str, float]) -> float:
        """Time of the white-reference steps the session interleaves: first, every
        ``reference_every`` poses, and last (each move routed as the rig will make it)."""
        ref = self.reference_joints()
        if ref is None:
            return 0.0
        leg, over = self.leg_s, self.time_model.step_overhead_s()
        total = leg(start, ref) + over
        if not steps:
            return total
        total -= steps[0].move_s  # the first pose is reached from the reference
        total += leg(ref, steps[0].joints)
        every = self.reference_every
        if every:
            for i in range(every, len(steps), every):
                a, b = steps[i - 1].joints, steps[i].joints
                total += leg(a, ref) + over + leg(ref, b) - steps[i].move_s
        return total + leg(steps[-1].joints, ref) + over


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
