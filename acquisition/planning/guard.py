"""The motion guard (a part of :class:`~acquisition.planning.planner.Planner`): the checks every
goal passes before it reaches a servo, and the routes round the other arm.

:meth:`MoveGuard.check_move` is the :class:`~drivers.dynamixel.motion.MotionGuard` the motion
controller calls before every goal it sends, braking included: the target's limits, elevation,
clearance and shadow cone (:meth:`MoveGuard.check_joints`) and the move's whole swept path, also
for every subset of the axes moving alone (a sync write one servo missed).
:meth:`MoveGuard.route` finds via points round the other arm when the direct move is refused,
approaching every target from one side on a rig with backlash; :meth:`MoveGuard.leg_s` times
the move as the rig will make it.
"""

from __future__ import annotations

import threading
from collections.abc import Mapping, Sequence

from acquisition.config.rig import ArmsConfig
from acquisition.geometry.approach import approach_point
from acquisition.geometry.kinematics import Joints, Kinematics, Pose
from acquisition.geometry.kinematics.base import angle_between_deg_array
from acquisition.planning import refusals
from acquisition.planning.paths import (
    MEMO_SIZE,
    MOVING_DEG,
    PathChecker,
    PathProblem,
    Router,
    route_or_raise,
)
from acquisition.planning.segments import segment_params
from acquisition.planning.sweep import SAFETY_REASONS, Reason, Rejection
from acquisition.planning.timing import TimeModel
from drivers.errors import CollisionError, LimitError


class MoveGuard:
    """The guard's half of the planner; :class:`~acquisition.planning.planner.Planner` sets
    the attributes below and provides ``collision_mask``, ``arm_gap_m`` and ``_detail``."""

    kinematics: Kinematics
    arms: ArmsConfig
    paths: PathChecker
    router: Router
    time_model: TimeModel
    approach: bool
    max_elevation_deg: float
    shadow_cone_deg: float
    _target_memo: dict[tuple[object, ...], Rejection | None]
    _memo_lock: threading.Lock

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
