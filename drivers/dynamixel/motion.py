"""Checked, synchronous multi-axis moves on one or more servo buses.

:meth:`MotionController.move_to` is the only way gonio moves the rig:

1. the guard (:class:`MotionGuard`: the planner's limits, collision and swept-path check) sees
   where every axis stands (read back, or known from the last confirmed move) and the targets
   first, and may refuse by raising; a controller cannot be built without one;
2. every target is converted with the axis' soft limits (:class:`~drivers.errors.LimitError`,
   nothing sent);
3. torque and latched hardware errors are checked (one sync read per bus);
4. ONE sync write per bus sends all goals;
5. one sync read per bus and control cycle polls goal, moving and present position (116–135,
   so the goal read-back costs no extra round trip) until every axis is within
   ``tolerance_ticks`` of its goal with ``moving == 0`` — the move is confirmed by readback,
   never by acknowledgement. A goal that reads back different never arrived (a sync write has
   no reply, so a lost or garbled one is silent) and the other axes are moving alone: the
   move is partial. Every axis of it stops (braking), and from the read-back pose the guard
   checks the move again before all goals are sent again, by sync write up to
   ``goal_resends - 1`` times, then by acknowledged WRITEs, whose status packets prove arrival.
   Where the guard refuses the rest of the move from there, :class:`PartialMoveError` carries
   the read-back pose to the caller, which re-plans (gonio routes round the other arm from it).
   A servo that acknowledged and still holds another value clamps it (its EEPROM position
   limits): :class:`~drivers.errors.LimitError`. One whose acknowledged write gets no valid
   answer: :class:`~drivers.errors.CommunicationError` naming axis and port;
6. on a hardware error, a timeout or Ctrl-C, all axes stop at once (goal := braking point,
   torque stays on; the stop goals are read back and a lost one is written again, acknowledged)
   before the error propagates; braking goals pass the guard too (an axis whose braking path it
   refuses stops where it is); :meth:`MotionController.stop` called from another thread ends
   an in-flight move with :class:`~drivers.errors.SafetyStop`.

Resends and retries are counted per axis (:meth:`MotionController.link_stats`).
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from typing import Protocol, runtime_checkable

from drivers.dynamixel.axis import Axis
from drivers.dynamixel.bus import Addr, ServoBus, ServoLinkStats
from drivers.dynamixel.codes import (
    MotionTimeoutError,
    PartialMoveError,
    ServoSilentError,
    TorqueOffError,
)
from drivers.errors import (
    CollisionError,
    CommunicationError,
    ConfigError,
    GonioError,
    LimitError,
    SafetyStop,
)


@runtime_checkable
class MotionGuard(Protocol):
    """What checks every goal before it reaches a servo (implemented by gonio's planner)."""

    def check_move(self, start_deg: Mapping[str, float], targets_deg: Mapping[str, float]) -> None:
        """Raise (:class:`~drivers.errors.LimitError`, :class:`~drivers.errors.CollisionError`)
        unless moving from ``start_deg`` (every axis, where it stands) to ``targets_deg`` (the
        axes to move) is safe along the whole swept path, also for every subset of the moving
        axes moving alone (a sync write one servo missed)."""
        ...


class MotionController:
    """Moves named axes, each driven by one servo on a :class:`ServoBus`.

    Parameters
    ----------
    axes:
        The axes (names unique).
    buses:
        ``{axis name: ServoBus}``, or one bus for every axis.
    guard:
        A :class:`MotionGuard`: ``guard.check_move(start, targets)`` before any goal is sent,
        braking goals included; it refuses a move by raising (``LimitError``,
        ``CollisionError``).
    tolerance_ticks:
        How close (ticks) the read-back position must be to the goal.
    poll_s:
        Pause between control cycles (s), passed to ``sleep``.
    sleep:
        Pause function for polling (``time.sleep``; a simulated clock's may be given).
    monotonic:
        Clock for timeouts (host s).
    goal_resends:
        Resends of a goal that reads back different before giving up (≥ 1): the last one is an
        acknowledged WRITE, the others sync writes.
    """

    def __init__(
        self,
        axes: Iterable[Axis],
        buses: Mapping[str, ServoBus] | ServoBus,
        guard: MotionGuard,
        *,
        tolerance_ticks: int = 3,
        poll_s: float = 0.01,
        sleep: Callable[[float], None] = time.sleep,
        monotonic: Callable[[], float] = time.monotonic,
        goal_resends: int = 3,
    ) -> None:
        if not isinstance(guard, MotionGuard):
            raise ConfigError(
                "MotionController needs a guard: an object whose check_move(start, targets) "
                "checks limits, collisions and the swept path before any goal is sent"
            )
        self._axes: dict[str, Axis] = {}
        for axis in axes:
            if axis.name in self._axes:
                raise ConfigError(f"axis '{axis.name}' is defined twice")
            self._axes[axis.name] = axis
        if isinstance(buses, ServoBus):
            buses = dict.fromkeys(self._axes, buses)
        missing = [n for n in self._axes if n not in buses]
        if missing:
            raise ConfigError(f"no servo bus given for axes {missing}")
        self._bus: dict[str, ServoBus] = {n: buses[n] for n in self._axes}
        seen: dict[tuple[int, int], str] = {}
        for name, axis in self._axes.items():
            key = (id(self._bus[name]), axis.servo_id)
            if key in seen:
                raise ConfigError(f"axes '{seen[key]}' and '{name}' both use servo "
                                  f"{axis.servo_id} on the same bus")
            seen[key] = name
            self._bus[name].label(axis.servo_id, name)
        if goal_resends < 1:
            raise ConfigError(f"goal_resends must be >= 1, got {goal_resends}")
        self.goal_resends = goal_resends
        self.guard = guard
        self._stops = 0  # bumped by stop(): an in-flight move_to ends with SafetyStop
        # Held by stop() and around every goal write of move_to, so that a move never re-sends
        # goals after a stop from another thread.
        self._goal_lock = threading.RLock()
        self.tolerance_ticks = tolerance_ticks
        self.poll_s = poll_s
        self._sleep = sleep
        self._monotonic = monotonic
        self._known: dict[str, float] | None = None
        """Where every axis stands (deg), from the last confirmed move; None: read it."""

    @property
    def axes(self) -> dict[str, Axis]:
        """``{name: Axis}``."""
        return dict(self._axes)

    def _groups(self, names: Iterable[str]) -> dict[ServoBus, list[str]]:
        groups: dict[ServoBus, list[str]] = {}
        for n in names:
            groups.setdefault(self._bus[n], []).append(n)
        return groups

    # ------------------------------------------------------------------ set-up verbs
    def apply_profiles(self) -> None:
        """Write each axis' profile velocity/acceleration to its servo."""
        for name, axis in self._axes.items():
            self._bus[name].set_profile(axis.servo_id, axis.profile_velocity,
                                        axis.profile_acceleration)

    def set_torque(self, on: bool, names: Iterable[str] | None = None) -> None:
        """Torque on/off for the named axes (all if None)."""
        self._known = None  # an axis without torque may be moved by hand
        for bus, group in self._groups(names or self._axes).items():
            bus.set_torque([self._axes[n].servo_id for n in group], on)

    def link_stats(self) -> dict[str, ServoLinkStats]:
        """``{axis: ServoLinkStats}``: requests, retries and goal resends of each axis' servo."""
        stats: dict[int, dict[int, ServoLinkStats]] = {}
        out = {}
        for name, axis in self._axes.items():
            bus = self._bus[name]
            per_servo = stats.setdefault(id(bus), bus.servo_stats())
            out[name] = per_servo.get(axis.servo_id, ServoLinkStats())
        return out

    def positions_deg(self, names: Iterable[str] | None = None) -> dict[str, float]:
        """Read-back positions (deg), one sync read per bus."""
        out: dict[str, float] = {}
        for bus, group in self._groups(names or self._axes).items():
            ticks = bus.read_positions([self._axes[n].servo_id for n in group])
            for n in group:
                out[n] = self._axes[n].ticks_to_deg(ticks[self._axes[n].servo_id])
        return out

    def where_deg(self) -> dict[str, float]:
        """Where every axis stands (deg): known from the last confirmed move, else read back."""
        if self._known is None:
            self._known = self.positions_deg()
        return dict(self._known)

    # ------------------------------------------------------------------ moves
    def move_to(self, targets_deg: Mapping[str, float], timeout_s: float = 30.0
                ) -> dict[str, float]:
        """Move the named axes to ``targets_deg`` together; return the read-back degrees.

        Raises
        ------
        ConfigError
            An unknown axis name.
        LimitError, CollisionError
            From the guard or the soft limits; nothing was sent.
        TorqueOffError, ServoHardwareError
            Before the move (nothing sent) or during it (all axes stopped).
        MotionTimeoutError
            The axes did not settle within ``timeout_s`` (all axes stopped).
        """
        targets = {str(k): float(v) for k, v in targets_deg.items()}
        unknown = sorted(set(targets) - set(self._axes))
        if unknown:
            raise ConfigError(f"unknown axes {unknown}; the rig has {sorted(self._axes)}")
        if not targets:
            return {}
        goals = {n: self._axes[n].deg_to_ticks(d) for n, d in targets.items()}  # soft limits
        self.guard.check_move(self.where_deg(), dict(targets))
        groups = self._groups(targets)
        self._check_ready(groups)
        generation = self._stops
        self._known = None  # until the move is confirmed
        try:
            with self._goal_lock, self._permits():
                self._check_generation(generation, goals)
                for bus, names in groups.items():
                    bus.write_goals({self._axes[n].servo_id: goals[n] for n in names})
            reached = self._settle(groups, goals, targets, timeout_s, generation)
        except SafetyStop:
            raise  # stop() already ran
        except (GonioError, KeyboardInterrupt):
            self._stop_quietly()
            raise
        rest = [n for n in self._axes if n not in reached]
        self._known = {**(self.positions_deg(rest) if rest else {}), **reached}
        return reached

    @contextlib.contextmanager
    def _permits(self) -> Iterator[None]:
        """Goal writes allowed on every bus of this controller (its guard checked them)."""
        with contextlib.ExitStack() as stack:
            for bus in {id(b): b for b in self._bus.values()}.values():
                stack.enter_context(bus.permit_goals())
            yield

    def _check_ready(self, groups: Mapping[ServoBus, list[str]]) -> None:
        for bus, names in groups.items():
            ids = {self._axes[n].servo_id: n for n in names}
            state = bus.read_safety(ids)
            for sid, (torque, bits) in state.items():
                if bits:
                    raise bus.hardware_error_of(sid)
                if not torque:
                    raise TorqueOffError(
                        f"{bus.describe(sid)}: torque is off, so the axis cannot move; run "
                        f"`gonio torque on` (nothing was sent)"
                    )

    def _settle(self, groups: Mapping[ServoBus, list[str]], goals: Mapping[str, int],
                targets: Mapping[str, float], timeout_s: float, generation: int
                ) -> dict[str, float]:
        deadline = self._monotonic() + timeout_s
        attempts = 0
        tol = self.tolerance_ticks
        while True:
            self._check_generation(generation, goals)
            done = True
            readback: dict[str, int] = {}
            lagging: list[str] = []
            lost: dict[str, tuple[ServoBus, int]] = {}
            for bus, names in groups.items():
                samples = bus.read_motion([self._axes[n].servo_id for n in names])
                for n in names:
                    axis, s = self._axes[n], samples[self._axes[n].servo_id]
                    readback[n] = s.position
                    if s.goal != goals[n]:
                        lost[n] = (bus, axis.servo_id)
                    if s.moving or abs(s.position - goals[n]) > tol:
                        done = False
                        lagging.append(f"{n} at {axis.ticks_to_deg(s.position):.2f}° "
                                       f"(goal {axis.ticks_to_deg(goals[n]):.2f}°)")
            if lost:
                if attempts >= self.goal_resends:
                    bus, sid = next(iter(lost.values()))
                    raise LimitError(
                        f"{bus.describe(sid)}: the servo holds another goal than "
                        f"{goals[next(iter(lost))]} ticks although it acknowledged the write; "
                        f"its Min/Max Position Limit (EEPROM 52/48) clamps it — widen them or "
                        f"narrow the axis limits in the rig file"
                    )
                attempts += 1
                self._restart_partial(groups, goals, targets, lost, generation,
                                      acknowledged=attempts == self.goal_resends)
                continue
            if done:
                return {n: self._axes[n].ticks_to_deg(t) for n, t in readback.items()}
            if self._monotonic() > deadline:
                raise MotionTimeoutError(
                    f"move not finished after {timeout_s:g} s: {', '.join(lagging)}; all axes "
                    f"stopped — check for an obstruction, or raise the profile velocity"
                )
            self._sleep(self.poll_s)

    def _restart_partial(self, groups: Mapping[ServoBus, list[str]], goals: Mapping[str, int],
                         targets: Mapping[str, float], lost: Mapping[str, tuple[ServoBus, int]],
                         generation: int, *, acknowledged: bool) -> None:
        """A partial move (some goals never arrived): stop every axis, wait until all are at
        rest, check the move again from the read-back pose, then send every goal again (the
        lost ones counted as resends; ``acknowledged``: by WRITEs whose replies prove arrival)."""
        with self._goal_lock, self._permits():
            self._check_generation(generation, goals)
            try:
                self._stop_all()
            except CommunicationError:
                name = next(iter(lost))
                bus, sid = lost[name]
                raise self._never_arrived(bus, sid, goals[name]) from None
        self._wait_at_rest(groups, generation, goals)
        self._recheck_partial(targets, lost)
        with self._goal_lock, self._permits():
            self._check_generation(generation, goals)
            for bus, names in groups.items():
                ids = {self._axes[n].servo_id: goals[n] for n in names}
                resent = {self._axes[n].servo_id for n in names if n in lost}
                if acknowledged:
                    for sid, goal in ids.items():
                        self._write_goal_acknowledged(bus, sid, goal, resend=sid in resent)
                    continue
                bus.resend_goals(ids, lost=resent)

    def _recheck_partial(self, targets: Mapping[str, float], lost: Iterable[str]) -> None:
        """The guard judges the rest of a partial move from where every axis stopped; where it
        refuses, :class:`PartialMoveError` hands the read-back pose to whoever re-plans."""
        readback = self.positions_deg()
        try:
            self.guard.check_move(readback, dict(targets))
        except (LimitError, CollisionError) as exc:
            missed = sorted(lost)
            at = ", ".join(f"{n} {v:.1f}°" for n, v in readback.items())
            raise PartialMoveError(
                f"partial move: {', '.join(missed)} missed the goal write and the other axes "
                f"moved alone; all axes stopped at {at}, from where the move as sent is refused "
                f"({exc})", readback, missed) from None

    def _wait_at_rest(self, groups: Mapping[ServoBus, list[str]], generation: int,
                      goals: Mapping[str, int], timeout_s: float = 10.0) -> None:
        """Poll until no axis of the move is moving (after a stop)."""
        deadline = self._monotonic() + timeout_s
        while True:
            self._check_generation(generation, goals)
            moving = []
            for bus, names in groups.items():
                samples = bus.read_motion([self._axes[n].servo_id for n in names])
                moving += [n for n in names if samples[self._axes[n].servo_id].moving]
            if not moving:
                return
            if self._monotonic() > deadline:
                raise MotionTimeoutError(f"{', '.join(moving)} still moving {timeout_s:g} s "
                                         "after a stop; check the servos")
            self._sleep(self.poll_s)

    def _write_goal_acknowledged(self, bus: ServoBus, servo_id: int, goal: int, *,
                                 resend: bool = True) -> None:
        try:
            bus.write_goal(servo_id, goal, resend=resend)
        except ServoSilentError:
            raise self._never_arrived(bus, servo_id, goal) from None

    def _never_arrived(self, bus: ServoBus, servo_id: int, goal: int) -> CommunicationError:
        return CommunicationError(
            f"{bus.describe(servo_id)}: the goal write ({goal} ticks) never arrived: sync "
            f"writes lost and acknowledged writes got no valid answer after {bus.retries + 1} "
            f"attempts; check the bus cable, termination and power (`gonio info` shows each "
            f"axis' retries); all axes stopped"
        )

    def _check_generation(self, generation: int, goals: Mapping[str, int]) -> None:
        if self._stops != generation:
            raise SafetyStop(
                f"move of {', '.join(sorted(goals))} was stopped (goal := present, torque on); "
                f"run the move again to continue"
            )

    def stop(self) -> dict[str, float]:
        """Stop every axis at once, braking without reversal (torque stays on).

        Returns where each axis comes to rest (degrees): its present position plus the braking
        distance at its profile acceleration, clamped to the soft limits.

        All positions are read first (one sync read per bus), then all goals written (one sync
        write per bus), so the axes stop within one control cycle of each other.
        """
        with self._goal_lock, self._permits():
            self._stops += 1
            self._known = None
            return self._stop_all()

    def _stop_all(self) -> dict[str, float]:
        groups = self._groups(self._axes)
        present: dict[ServoBus, dict[int, int]] = {}
        errors: list[Exception] = []
        goals: dict[ServoBus, dict[int, int]] = {}
        for bus, names in groups.items():
            try:
                # One sync read of 108–135: profile acceleration, velocity, present position.
                # No Alert check: a servo in hardware error still reports where it is.
                raw = bus.sync_read([self._axes[n].servo_id for n in names],
                                    Addr.PROFILE_ACCELERATION, 28, check_alert=False)
            except GonioError as exc:
                errors.append(exc)
                continue

            def field(b: bytes, addr: int) -> int:
                off = addr - Addr.PROFILE_ACCELERATION
                return int.from_bytes(b[off:off + 4], "little", signed=True)

            present[bus] = {i: field(b, Addr.PRESENT_POSITION) for i, b in raw.items()}
            goals[bus] = {
                sid: self._braking_goal(
                    self._axes[n], field(raw[sid], Addr.PRESENT_POSITION),
                    field(raw[sid], Addr.PRESENT_VELOCITY), field(raw[sid], Addr.PROFILE_ACCELERATION),
                )
                for n in names
                for sid in (self._axes[n].servo_id,)
            }
        self._guard_braking(groups, present, goals)
        for bus, ticks in goals.items():
            try:
                bus.write_goals(ticks)
            except GonioError as exc:
                errors.append(exc)
        for bus, ticks in goals.items():
            try:  # a sync write has no reply: read the stop goals back, rewrite any lost one
                held = bus.sync_read(ticks, Addr.GOAL_POSITION, 4, check_alert=False)
                for sid, goal in ticks.items():
                    if int.from_bytes(held[sid], "little", signed=True) != goal:
                        bus.write_goal(sid, goal, resend=True)
            except GonioError as exc:
                errors.append(exc)
        if errors:
            raise errors[0]
        out = {}
        for bus, names in groups.items():
            for n in names:
                if bus in goals:
                    out[n] = self._axes[n].ticks_to_deg(goals[bus][self._axes[n].servo_id])
        return out

    def _guard_braking(self, groups: Mapping[ServoBus, list[str]],
                       present: Mapping[ServoBus, Mapping[int, int]],
                       goals: dict[ServoBus, dict[int, int]]) -> None:
        """Braking goals pass the guard like any goal; where it refuses them (or cannot judge:
        a bus did not answer), every axis stops where it stands instead (goal := present)."""
        names = {n: bus for bus, group in groups.items() for n in group}
        if any(bus not in present for bus in names.values()):
            stop_here = True
        else:
            start = {n: self._axes[n].ticks_to_deg(present[b][self._axes[n].servo_id])
                     for n, b in names.items()}
            braking = {n: self._axes[n].ticks_to_deg(goals[b][self._axes[n].servo_id])
                       for n, b in names.items()}
            try:
                self.guard.check_move(start, braking)
                stop_here = False
            except (LimitError, CollisionError):
                stop_here = True
        if stop_here:
            for bus in goals:
                goals[bus] = dict(present[bus])

    @staticmethod
    def _braking_goal(axis: Axis, position_ticks: int, velocity_units: int, accel_units: int) -> int:
        """Where the axis comes to rest braking at the servo's profile acceleration, ticks.

        Goal := present would make a moving X-series servo overshoot by v²/2a and drive back;
        aiming at the braking point (clamped to the soft limits) stops it without reversing.
        """
        if velocity_units == 0 or accel_units <= 0:
            return position_ticks
        ticks_per_rev = axis.ticks_per_rev
        v = velocity_units * 0.229 / 60.0 * ticks_per_rev  # ticks/s
        a = accel_units * 214.577 / 3600.0 * ticks_per_rev  # ticks/s²
        goal = position_ticks + (1 if v > 0 else -1) * v * v / (2.0 * a)
        deg = min(max(axis.ticks_to_deg(goal), axis.min_deg), axis.max_deg)
        return axis.deg_to_ticks(deg)

    def _stop_quietly(self) -> None:
        with contextlib.suppress(GonioError, KeyboardInterrupt):
            self.stop()

