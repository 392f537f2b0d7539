"""The servo side of a rig: opening its buses (starting simulators for simulated ones), checking
that every declared servo answers, and the motion controller behind the guard.

Opening a bus checks, in order: the port opens (one-line error naming it), every servo the rig
file declares on it answers (one error listing the missing IDs; if none answers but they do at
another common baud rate, the error names that rate and the rig-file field to change), and on a
real port the USB adapter's latency timer (a :class:`LatencyWarning` above 1 ms).
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from acquisition.config.rig import MOTION_POLL_S, AxisConfig, RigConfig
from acquisition.devices.health import HealthGuard, HealthLimits
from acquisition.geometry.kinematics import Pose
from acquisition.planning.planner import Planner
from acquisition.simworld.servos import (
    check_sim_faults,
    make_clock,
    start_simulated_rig,
)
from drivers.dynamixel import (
    COMMON_BAUD_RATES,
    Axis,
    MotionController,
    PartialMoveError,
    ServoBus,
)
from drivers.dynamixel.bus import Addr
from drivers.dynamixel.latency import SYSFS_USB_SERIAL, latency_warning
from drivers.errors import CollisionError, ConfigError, LimitError

if TYPE_CHECKING:
    from simulators.clock import SimClock
    from simulators.dynamixel import SimServoBus
    from simulators.dynamixel.rig import SimRig

LATENCY_SYSFS = SYSFS_USB_SERIAL
"""Where the USB-serial adapters' ``latency_timer`` files live (a test may point it elsewhere)."""

SIM_REPLY_GRACE_S = 0.5
"""Host seconds a simulated bus on a stepped clock may take to reply beyond the SDK's 34 ms:
its replies come in host scheduling time, and a late one taken for a lost one would add a
retry to the rig's timeline (a loaded two-core host has delayed them past 34 ms)."""


def sim_reply_grace_s(sim: SimServoBus | None, clock: SimClock | None) -> float:
    """The driver's extra wait for a reply (:data:`SIM_REPLY_GRACE_S`) on a simulated bus
    whose clock is stepped and which is not told to drop packets (where a missing reply can
    only be a late one); 0 otherwise (a bus that drops packets on purpose would spend the
    grace on each loss, and its tables do not depend on the retries)."""
    if sim is None or clock is None or clock.follows_host:
        return 0.0
    return 0.0 if any(f.kind == "drop" for f in sim.faults) else SIM_REPLY_GRACE_S


class LatencyWarning(UserWarning):
    """The servo port's USB latency timer is above 1 ms (slow round trips)."""


def make_axis(cfg: AxisConfig) -> Axis:
    """The driver's axis for one rig-file axis."""
    return Axis(
        name=cfg.name, servo_id=cfg.servo_id, zero_tick=cfg.zero_tick, direction=cfg.direction,
        min_deg=cfg.min_deg, max_deg=cfg.max_deg, profile_velocity=cfg.profile_velocity,
        profile_acceleration=cfg.profile_acceleration,
    )


def park_ticks(rig: RigConfig, planner: Planner) -> dict[str, float]:
    """``{axis: encoder ticks}`` of the park pose (where simulated servos start)."""
    park = park_joints(rig, planner)
    return {name: make_axis(cfg).deg_to_ticks(park[name]) for name, cfg in rig.axes.items()}


def park_joints(rig: RigConfig, planner: Planner) -> dict[str, float]:
    """Joints (deg) of the park pose: the white-reference pose, where a simulated rig starts.

    A rig file has no park key yet; the white-reference pose is reachable and guarded by
    construction (every capture starts and ends there).
    """
    wr = rig.white_reference
    return dict(planner.joints_for(Pose(wr.theta_i, wr.theta_r, wr.delta_phi)))


@dataclass
class ServoRig:
    """The servo side of an open rig: buses, motion controller, health guard, clock.

    ``sims`` holds the in-process simulators of simulated buses (empty on hardware).
    """

    rig: RigConfig
    planner: Planner
    axes: dict[str, Axis]
    buses: dict[str, ServoBus]
    """``{bus name: ServoBus}``."""
    motion: MotionController
    health: HealthGuard
    clock: SimClock | None
    sims: dict[str, SimServoBus] = field(default_factory=dict)
    """The in-process simulators of simulated buses, by bus name (empty on hardware)."""
    sim_rig: SimRig | None = None
    """The simulated rig those buses belong to (its arms' true positions), or None."""

    @property
    def park(self) -> dict[str, float]:
        """Joints (deg) of the park pose, see :func:`park_joints`."""
        return park_joints(self.rig, self.planner)

    def bus_of(self, axis: str) -> ServoBus:
        """The bus that drives ``axis``."""
        return self.buses[self.rig.axes[axis].bus]

    def sleep(self, seconds: float) -> None:
        """Wait on the device clock (s)."""
        if self.clock is not None:
            self.clock.sleep(seconds)
        else:  # pragma: no cover - hardware
            time.sleep(seconds)

    def move_to(self, joints: Mapping[str, float], *, health_wait_s: float | None = None,
                on_route: RouteNotice | None = None) -> dict[str, float]:
        """Health check (maybe a pause), then the move, routed round the other arm when the
        direct one is not safe (each leg guarded, one sync write, read back); returns the
        read-back degrees of every axis."""
        self.health.wait_until_healthy(health_wait_s)
        return routed_move(self.motion, self.planner, joints, on_route)

    def true_joints(self) -> dict[str, float]:
        """The arms' TRUE joint angles (deg) in the simulated world (zero offsets, backlash and
        position noise included: the driver never sees them); simulated buses only."""
        if self.sim_rig is None:
            raise ConfigError(f"{self.rig.path}: no simulated servo bus: the true joints of real "
                              "arms are not known")
        return self.sim_rig.sim_true_joints_deg()

    def sim_collisions(self) -> list[str]:
        """The arms' contacts the simulators saw (one line each, oldest first)."""
        seen: dict[str, None] = {}
        for sim in self.sims.values():  # buses of one rig share one world
            seen.update(dict.fromkeys(str(c) for c in sim.sim_collisions()))
        return list(seen)


RouteNotice = Callable[[list[dict[str, float]]], None]
"""Told the legs (joints, deg) of a move before it starts, when it has via points."""


MAX_REPLANS = 3
"""Re-plans of one move after partial moves (each needs another lost goal write)."""


def routed_move(motion: MotionController, planner: Planner, joints: Mapping[str, float],
                on_route: RouteNotice | None = None) -> dict[str, float]:
    """Move to ``joints`` from where the axes stand: directly when that is safe, else through
    the planner's via points (``on_route`` is told them first); every leg passes the motion
    guard. After a partial move (a servo missed the goal write, the others moved alone, every
    axis stopped) that the guard will not finish as sent, the move is routed again from the
    read-back pose (``on_route`` is told the new legs) and goes on. Returns the read-back
    degrees of every axis.

    Raises
    ------
    LimitError, CollisionError
        The target is unsafe, or no route reaches it (one line; nothing moved) — also from
        where a partial move stopped (the line says so; the axes stay there).
    """
    where = motion.where_deg()
    target = {**where, **joints}
    legs = planner.route(where, target)
    if on_route is not None and len(legs) > 1:
        on_route(legs)
    replans = 0
    while True:
        try:
            for leg in legs:
                motion.move_to(leg)
            return motion.where_deg()
        except PartialMoveError as exc:
            replans += 1
            if replans > MAX_REPLANS:
                raise
            legs = _replan(planner, exc, target)
            if on_route is not None and len(legs) > 1:
                on_route(legs)


def _replan(planner: Planner, partial: PartialMoveError, target: Mapping[str, float]
            ) -> list[dict[str, float]]:
    """The route from where a partial move stopped to ``target``, or one line saying that
    there is none (from :meth:`Planner.route`)."""
    try:
        return planner.route(partial.readback, target)
    except (LimitError, CollisionError) as exc:
        at = ", ".join(f"{n} {v:.1f}°" for n, v in partial.readback.items())
        kind = CollisionError if isinstance(exc, CollisionError) else LimitError
        raise kind(f"after a partial move ({', '.join(partial.lost)} missed the goal write; "
                   f"all axes stopped at {at}): {exc}") from None


def require_servos(bus: ServoBus, rig: RigConfig, bus_name: str) -> None:
    """Check that every servo the rig declares on ``bus_name`` answers.

    Raises
    ------
    ConfigError
        None answers at the rig file's baud rate but they do at another common one (names it).
    ServoSilentError
        Some (or all) stay silent; the message lists the IDs and their axes.
    """
    ids = [a.servo_id for a in rig.axes.values() if a.bus == bus_name]
    if not ids:
        return
    missing = [i for i in ids if bus.try_ping(i, attempts=2) is None]
    if not missing:
        return
    if len(missing) == len(ids):
        elsewhere = bus.scan(ids, [b for b in COMMON_BAUD_RATES if b != bus.baud])
        if elsewhere:
            baud, found = max(elsewhere.items(), key=lambda kv: len(kv[1]))
            raise ConfigError(
                f"{rig.path} [buses.{bus_name}]: no servo answers on {bus.port_name} at "
                f"{bus.baud} baud, but ID {', '.join(map(str, sorted(found)))} answer at "
                f"{baud} baud: set baud = {baud} in [buses.{bus_name}]"
            )
    bus.require(missing)  # one ServoSilentError naming every silent ID and its axis


@contextmanager
def open_servos(
    rig: RigConfig,
    planner: Planner,
    *,
    clock: SimClock | None = None,
    sim_faults: Sequence[str] = (),
    seed: int = 0,
    prepare: bool = True,
    health_limits: HealthLimits | None = None,
) -> Iterator[ServoRig]:
    """Open every servo bus of the rig (starting simulators for simulated ones).

    Parameters
    ----------
    clock:
        The device clock; the rig's own (:func:`make_clock`) when a bus is simulated and none
        is given. On a :class:`SteppedClock` move timeouts are counted on it too.
    prepare:
        Write every axis' motion profile and switch torque on (what a capture needs). A
        console leaves a real rig as it is (a servo in hardware error must stay readable).
    """
    check_sim_faults(rig, sim_faults)  # a rig without simulated buses refuses them
    if clock is None and any(b.simulated for b in rig.buses.values()):
        clock = make_clock(rig)
    axes = {name: make_axis(cfg) for name, cfg in rig.axes.items()}
    with ExitStack() as stack:
        sim_rig = None
        if clock is not None:
            sim_rig = stack.enter_context(start_simulated_rig(
                rig, clock, park_ticks(rig, planner), sim_faults=sim_faults, seed=seed))
        sims = {} if sim_rig is None else dict(sim_rig.buses)
        buses: dict[str, ServoBus] = {}
        for name, bus_cfg in rig.buses.items():
            port = sims[name].port if name in sims else bus_cfg.port
            grace = sim_reply_grace_s(sims.get(name), clock)
            bus = stack.enter_context(ServoBus(port, bus_cfg.baud, name=name,
                                               reply_grace_s=grace))
            buses[name] = bus
            for a in rig.axes.values():
                if a.bus == name:
                    bus.label(a.servo_id, a.name)
            if name not in sims:
                message = latency_warning(port, LATENCY_SYSFS)
                if message:
                    warnings.warn(message, LatencyWarning, stacklevel=3)
            require_servos(bus, rig, name)
        by_axis = {name: buses[cfg.bus] for name, cfg in rig.axes.items()}
        timing: dict[str, Any] = {"sleep": clock.sleep} if clock is not None else {}
        if clock is not None and not clock.follows_host:  # host time says nothing of a stepped rig
            timing["monotonic"] = clock.now
        motion = MotionController(axes.values(), by_axis, guard=planner, poll_s=MOTION_POLL_S,
                                  **timing)
        health = HealthGuard(
            axes, by_axis, health_limits,
            **({"now": clock.now, "sleep": clock.sleep} if clock is not None else {}),
        )
        if prepare:
            set_low_latency(buses, rig)
            motion.apply_profiles()
            motion.set_torque(True)
        yield ServoRig(rig, planner, axes, buses, motion, health, clock, sims, sim_rig)


def set_low_latency(buses: Mapping[str, ServoBus], rig: RigConfig) -> None:
    """Set every servo's Return Delay Time to 0 (the low-latency setting; factory 500 µs).

    It lives in EEPROM, so it is written only where it differs and only while torque is off
    (a servo already holding a pose keeps its value until the next cold start).
    """
    for name, bus in buses.items():
        for axis in (a for a in rig.axes.values() if a.bus == name):
            sid = axis.servo_id
            if bus.read(sid, Addr.RETURN_DELAY_TIME, 1, signed=False, check_alert=False) == 0:
                continue
            torque_on, _ = bus.read_safety([sid])[sid]
            if not torque_on:
                bus.set_return_delay([sid], 0)
