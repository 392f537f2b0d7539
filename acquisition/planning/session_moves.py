"""The moves a session makes besides the sweep's own (a part of
:class:`~acquisition.planning.planner.Planner`): the white references it interleaves, every move
checked against the guard and routed where the direct one is unsafe, and their time."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence

import numpy as np

from acquisition.geometry.kinematics import Kinematics
from acquisition.planning.sweep import PlannedPose
from drivers.errors import CollisionError, LimitError


class SessionMoves:
    """Session-level moves of the planner; :class:`~acquisition.planning.planner.Planner`
    provides the guard (``route``, ``check_move``, ``leg_s``, ``transit_ok``) and the rest."""

    kinematics: Kinematics
    reference_every: int

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
