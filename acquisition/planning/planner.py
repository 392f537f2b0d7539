"""The motion planner: which candidate poses are safe and useful, their order, and the ETA.

Every pose is checked against the rig's constraints and kept or rejected with a named
:class:`~acquisition.planning.sweep.Reason`. The planner is also the motion guard
(:mod:`acquisition.planning.guard`: ``check_move`` before *every* goal a servo receives,
``route`` round the other arm) and times the moves a session adds
(:mod:`acquisition.planning.session_moves`). So nothing reaches a servo that the planner has
not checked.

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

import threading
import time
from collections.abc import Mapping, Sequence

import numpy as np

from acquisition.config.plan import PlanSpec
from acquisition.config.rig import DEFAULT_CLEARANCE_M, ArmConfig, ArmsConfig, FootprintConfig, RigConfig
from acquisition.geometry.alignment import Alignment
from acquisition.geometry.approach import APPROACH_DEG, approach_signs
from acquisition.geometry.kinematics import Joints, Kinematics, Pose, poses_to_array
from acquisition.geometry.kinematics.base import (
    angle_between_deg_array,
    directions_from_poses,
    wrap_deg_array,
)
from acquisition.geometry.kinematics.calibrated import CalibratedKinematics
from acquisition.planning import ordering
from acquisition.planning.guard import MoveGuard
from acquisition.planning.paths import PathChecker, Router
from acquisition.planning.segments import segment_distance
from acquisition.planning.session_moves import SessionMoves
from acquisition.planning.sweep import SAFETY_REASONS, PlannedPose, Reason, Rejection, Sweep
from acquisition.planning.timing import AxisProfile, StepCosts, TimeModel
from drivers.errors import CollisionError, LimitError

KEY_DECIMALS = 6
"""Poses equal to this many decimals of a degree are the same measurement."""

BOUNDS = ("auto", "held-karp", "nearest")
HELD_KARP_AUTO_MAX = 1200
"""Largest sweep for which ``bound="auto"`` computes the Held–Karp bound."""


def _fmt_pose(p: np.ndarray | Pose) -> str:
    ti, tr, dp = p.as_tuple() if isinstance(p, Pose) else p
    return f"θi={ti:g}° θr={tr:g}° Δφ={dp:g}°"


class Planner(MoveGuard, SessionMoves):
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
