"""The solid world of a simulated rig: the arms' capsules driven by the servos' TRUE positions.

:class:`SolidWorld` couples a :class:`~simulators.rig_solids.SolidRig` (the simulator's own
geometry) to the :class:`~simulators.dynamixel.servo.SimServo` of every arm joint, and steps
those servos together on its physics tick whenever any of them is asked for its state (a
packet, a sim-only accessor), so contacts are found whoever asks first.

Stepping
--------
- While the arms are ``g`` metres apart and no point of them moves faster than ``S`` (m/s: each
  moving joint's profile speed bound times its arm's reach), they cannot touch for ``g / S``
  seconds: the world steps by ``max(g / S, tick_s)`` (conservative advancement), never across a
  servo's own event (arrival, stall, trip), and not at all while nothing moves.
- When the gap at the end of a step is ≤ 0 (no clearance margin: that is the planner's
  business), Brent's method on the servos' planned trajectories finds the first touch to
  within :data:`CONTACT_TOL_S`; every arm servo is stepped there. The servos whose own motion
  closes the gap stall at that position (:meth:`SimServo.sim_set_contact`): Moving stays 1,
  Present Current reads the stall current, and after the servo's ``stall_trip_s`` it sets the
  overload bit and applies its Shutdown register (default: torque off). The other servos keep
  moving.
- A servo stalled at a contact keeps pushing: when the other arm gives way, it follows the
  contact (its shaft moves on to where the surfaces touch again, no faster than its own
  profile speed) and stays stalled, so its stall time runs on and it trips if it pushes for
  ``stall_trip_s`` in all (it is placed to within :data:`FOLLOW_TOL_TICKS` once the contact has
  moved a tick on). Its block is lifted once its way to the goal is free, or when the
  contact leaves faster than it can follow; the move then resumes. A block is also lifted when
  the servo is not pushing (it moved away, torque off) and one tick more in the blocked
  direction would leave the arms apart. Moving away from the contact is always possible.
- A grazing pass shallower than about ``S × tick_s / 2`` within one tick can go unseen: that is
  the tick's resolution.
- The bound also makes most calls free: until ``g / S`` after the last full step, and while no
  servo's planned motion has changed (:attr:`SimServo.sim_motion_generation`; events such as
  arrival or a trip only slow a servo down), no contact is possible and the servos advance on
  their own as on a bare bus.

Each new contact is recorded as a :class:`Collision` (device time, the stalled axes and servo
IDs, every arm joint's position in deg and ticks, the closest points) in
:attr:`SolidWorld.collisions`, in the process-wide record :func:`take_recorded` empties (for
a referee that must see every world of a process, whoever built it), and logged as a warning
on this module's logger. A servo that stalls again in the same contact episode (the arms have
not been more than :data:`EPISODE_REARM_M` apart since) is not recorded twice.
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass

from scipy.optimize import brentq

from simulators.dynamixel.servo import SimServo
from simulators.rig_solids import SolidRig, Vec

logger = logging.getLogger(__name__)

DEFAULT_TICK_S = 1e-3
"""Physics tick (simulated s): the shortest step while the arms are close."""
CONTACT_TOL_S = 1e-7
"""Tolerance (simulated s) of the time of first touch."""
EPISODE_REARM_M = 5e-3
"""Gap (m) the arms must exceed before a new contact of the same servo is recorded again."""
FOLLOW_TOL_TICKS = 1e-3
"""Resolution (ticks) of the position where a following servo touches again."""

_recorded: list[Collision] = []
_recorded_lock = threading.Lock()


def take_recorded() -> list[Collision]:
    """Every collision any solid world of this process recorded since the last call (oldest
    first), and forget them."""
    with _recorded_lock:
        out = list(_recorded)
        _recorded.clear()
    return out


@dataclass(frozen=True)
class Collision:
    """One contact of the arms.

    Attributes
    ----------
    time_s:
        Device (simulated clock) time of the first touch, s.
    axes, servo_ids:
        The joints whose servos pushed into the contact and stalled, and their servo IDs.
    positions_deg, positions_ticks:
        Every arm joint's position at the touch (deg, Present Position ticks).
    light_point_m, camera_point_m:
        Closest points of the two capsule axes (m, world frame).
    """

    time_s: float
    axes: tuple[str, ...]
    servo_ids: tuple[int, ...]
    positions_deg: Mapping[str, float]
    positions_ticks: Mapping[str, float]
    light_point_m: Vec
    camera_point_m: Vec

    def __str__(self) -> str:
        joints = ", ".join(f"{n}={d:.3f}° ({self.positions_ticks[n]:.1f} ticks)"
                           for n, d in self.positions_deg.items())
        who = ", ".join(f"{a} (servo {i})" for a, i in zip(self.axes, self.servo_ids, strict=True))
        return f"arms touched at t={self.time_s:.4f} s: {who} stalled; {joints}"


class SolidWorld:
    """The arms of one rig, moved by their servos' true positions.

    Parameters
    ----------
    rig:
        The solid parts (geometry, axes).
    servos:
        ``{joint name: SimServo}`` for at least every joint that moves an arm; the servos share
        one clock and one lock (one bus, or buses built with the same ``lock``).
    tick_s:
        Physics tick (simulated s), see the module docstring.
    arm_deg:
        ``{joint name: arm angle (deg) at a Present Position (ticks)}`` where the arms are not
        where their servos' ticks say (a :class:`~simulators.dynamixel.drivetrain.Drivetrain`:
        zero offsets, backlash, position noise); default the axis' own conversion.
    """

    def __init__(self, rig: SolidRig, servos: Mapping[str, SimServo], *,
                 tick_s: float = DEFAULT_TICK_S,
                 arm_deg: Mapping[str, Callable[[float], float]] | None = None) -> None:
        if not tick_s > 0:
            raise ValueError(f"tick_s must be > 0, got {tick_s}")
        self.rig = rig
        self.tick_s = tick_s
        arm_of = {j: arm for arm, joints in rig.arm_axes.items() for j in joints}
        missing = [j for j in arm_of if j not in servos]
        if missing:
            raise ValueError(f"the solid world needs the servos of {missing}")
        self._servos = {j: servos[j] for j in arm_of}
        self._axes = {j: rig.axes[j] for j in arm_of}
        self._arm_deg = {j: (arm_deg or {}).get(j, self._axes[j].deg) for j in arm_of}
        self._rad_per_tick = {j: 2.0 * math.pi / a.ticks_per_rev for j, a in self._axes.items()}
        self._reach = {j: rig.reach_m(arm) for j, arm in arm_of.items()}
        self.collisions: list[Collision] = []
        """Every recorded contact, oldest first."""
        self._episode: set[str] = set()
        self._followed_at: dict[str, float] = {}  # last time each blocked servo was placed
        self._blocked_at: dict[str, float] = {}  # when each block was set (not lifted then)
        self._safe_until = -math.inf  # no contact before this while the motion key holds
        self._safe_key: tuple[int, ...] = ()
        self._busy = False
        clocks = {id(s.clock) for s in self._servos.values()}
        if len(clocks) > 1:
            raise ValueError("the servos of one solid world must share one clock")
        self._t = next(iter(self._servos.values())).clock.now() if self._servos else 0.0
        for s in self._servos.values():
            s.sim_step_to(self._t)
            s.sim_attach_world(self.advance)

    @property
    def time_s(self) -> float:
        """Simulated time (s) up to which the world has been stepped."""
        return self._t

    def detach(self) -> None:
        """Let the servos advance on their own again (contact blocks are removed)."""
        for s in self._servos.values():
            s.sim_attach_world(None)
            s.sim_set_contact(None)

    # ------------------------------------------------------------------ geometry at a time
    def _joints(self, position: Callable[[SimServo], float]) -> dict[str, float]:
        return {j: self._arm_deg[j](position(s)) for j, s in self._servos.items()}

    def _gap_at(self, t: float) -> float:
        return self.rig.gap_m(self._joints(lambda s: s.sim_peek_ticks(t)))

    def _closing_speed_m_per_s(self) -> float:
        return sum(s.sim_speed_bound_ticks_per_s() * self._rad_per_tick[j] * self._reach[j]
                   for j, s in self._servos.items())

    # ------------------------------------------------------------------ stepping
    def collisions_at(self, now: float) -> list[Collision]:
        """Every contact of the arms up to device time ``now`` (oldest first)."""
        self.advance(now)
        return list(self.collisions)

    def advance(self, now: float) -> None:
        """Step every arm servo to simulated time ``now`` (s), handling contacts on the way.

        Runs with the buses' lock held: the servos call it from their own accessors.
        """
        if self._busy or now <= self._t:
            return
        if now <= self._safe_until and self._motion_key() == self._safe_key:
            self._t = now  # no contact possible: the servos advance lazily on their own
            return
        self._busy = True
        try:
            self._run(now)
        finally:
            self._busy = False

    def _motion_key(self) -> tuple[int, ...]:
        return tuple(s.sim_motion_generation for s in self._servos.values())

    def _run(self, now: float) -> None:
        servos = self._servos.values()
        while True:
            t0 = self._t
            for s in servos:
                s.sim_step_to(t0)
            self._relieve()
            speed = self._closing_speed_m_per_s()
            blocked = any(s.sim_contact() for s in servos)
            if speed <= 0.0:  # nothing moves: nothing changes until some motion does
                self._safe_until, self._safe_key = math.inf, self._motion_key()
            if t0 >= now or speed <= 0.0:
                break
            gap0 = self._gap_at(t0)
            if gap0 > 0 and not blocked:
                self._safe_until, self._safe_key = t0 + gap0 / speed, self._motion_key()
            if gap0 > EPISODE_REARM_M and not blocked:
                self._episode.clear()
            dt = max(gap0 / speed, self.tick_s) if gap0 > 0 else self.tick_s
            t1 = min(now, t0 + dt)
            t_event = min(s.sim_next_event_s() for s in servos)
            if t0 < t_event < t1:
                t1 = t_event
            if self._gap_at(t1) > 0:
                self._t = t1
                continue
            lo = t0 if gap0 <= 0 else _last_positive(self._gap_at, t0, t1, CONTACT_TOL_S)
            self._t = lo
            for s in servos:
                s.sim_step_to(lo)
            if not self._touch(lo):
                self._t = t1  # nothing could be blocked (degenerate): let the step happen
        for s in servos:
            s.sim_step_to(now)
        self._t = now
        self._relieve()  # a following servo catches up with where the contact is now

    def _relieve(self) -> None:
        """Blocked servos at the world's time: follow, stay, or have the block lifted."""
        for j, s in self._servos.items():
            block = s.sim_contact()
            if block is None or self._blocked_at.get(j) == self._t:
                continue  # a block set now is not lifted now: the world always moves on
            at, d = block
            arm_deg = self._arm_deg[j]
            joints = self._joints(lambda x: x.sim_peek_ticks(self._t))

            def gap(ticks: float, joints: dict[str, float] = joints, j: str = j,
                    arm_deg=arm_deg) -> float:
                joints[j] = arm_deg(ticks)
                return self.rig.gap_m(joints)

            since = self._followed_at.get(j, self._t)
            if gap(at + d) <= 0:
                self._followed_at[j] = self._t  # still touching
                continue
            goal = s.sim_goal_ticks() if s.sim_stalled() else None
            if goal is None or d * (goal - at) <= 0:  # not pushing (any more)
                s.sim_set_contact(None)
                self._followed_at.pop(j, None)
                continue
            touch = self._first_touch(gap, at, goal, d, self._rad_per_tick[j] * self._reach[j])
            reach = s.sim_profile_speed_ticks_per_s() * (self._t - since) + 1.0
            if touch is None or abs(touch - at) > reach:  # free, or gone faster than it follows
                s.sim_set_contact(None)
                self._followed_at.pop(j, None)
            else:
                s.sim_follow_contact(touch)
                self._followed_at[j] = self._t

    @staticmethod
    def _first_touch(gap: Callable[[float], float], start: float, goal: float, d: int,
                     m_per_tick: float) -> float | None:
        """First position (ticks) from ``start`` towards ``goal`` where the gap reaches 0 (the
        last free one within :data:`FOLLOW_TOL_TICKS`), or None if the way is free. Marches by
        the gap over its Lipschitz bound (``m_per_tick``), at least one tick at a time."""
        prev, q = start, start + d
        while True:
            if d * (q - goal) > 0:
                q = goal
            g = gap(q)
            if g <= 0:
                return _last_positive(gap, prev, q, FOLLOW_TOL_TICKS)
            if q == goal:
                return None
            prev, q = q, q + d * max(g / m_per_tick, 1.0)

    def _touch(self, t: float) -> bool:
        """The arms touch at ``t``: stall every servo whose own motion closes the gap; returns
        whether any servo was blocked."""
        ticks = {j: s.sim_peek_ticks(t) for j, s in self._servos.items()}
        joints = {j: self._arm_deg[j](v) for j, v in ticks.items()}
        contact = self.rig.contact(joints)
        moving = [j for j, s in self._servos.items() if s.sim_moving()]
        pushers = []
        for j in moving:
            probe = dict(joints)
            probe[j] = self._arm_deg[j](self._servos[j].sim_peek_ticks(t + self.tick_s))
            if self.rig.gap_m(probe) < contact.gap_m:
                pushers.append(j)
        if not pushers:  # only their combined motion closes the gap
            pushers = moving
        pushers = [j for j in pushers if self._servos[j].sim_direction()]
        for j in pushers:
            self._servos[j].sim_set_contact(self._servos[j].sim_direction())
            self._blocked_at[j] = t
        if set(pushers) - self._episode:
            self._episode.update(pushers)
            record = Collision(
                time_s=t, axes=tuple(pushers),
                servo_ids=tuple(self._axes[j].servo_id for j in pushers),
                positions_deg=joints, positions_ticks=ticks,
                light_point_m=contact.light_point_m, camera_point_m=contact.camera_point_m)
            self.collisions.append(record)
            with _recorded_lock:
                _recorded.append(record)
            logger.warning("%s", record)
        return bool(pushers)


def _last_positive(f: Callable[[float], float], a: float, b: float, tol: float) -> float:
    """A point within ``tol`` of the first root of ``f`` between ``a`` (f > 0) and ``b``
    (f ≤ 0) where f is still > 0 (Brent's method)."""
    x = brentq(f, a, b, xtol=tol)
    back = tol if a < b else -tol
    for _ in range(3):
        if f(x) > 0:
            return x
        x -= back
    lo, hi = a, x  # Brent found a later crossing: bisect towards the first one
    while abs(hi - lo) > tol:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if f(mid) > 0 else (lo, mid)
    return lo
