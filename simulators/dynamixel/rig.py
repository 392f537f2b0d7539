"""A rig file's servos on simulated buses, with the rig's solid parts: :class:`SimRig`.

Entry point::

    from simulators.dynamixel import serve_rig

    with serve_rig("examples/rig-sim.toml") as rig:   # started; stopped on exit
        port = rig.port                                # the pty path (one bus)
        ...                                            # any client: dynamixel_sdk, gonio
        rig.sim_collisions()                           # contacts of the arms so far

Each of the rig's buses is a :class:`~simulators.dynamixel.bus.SimServoBus` on its own pty,
with that bus's servo IDs and baud rate; each servo's Min/Max Position Limit registers (52/48)
hold its axis' soft limits (rounded outwards), and it starts at the park pose (the white
reference, :meth:`~simulators.rig_solids.SolidRig.park_deg`) unless positions are given. One
:class:`~simulators.dynamixel.world.SolidWorld` spans all buses (they share a clock and a lock),
built from the rig file with the simulator's own geometry (:mod:`simulators.rig_solids`); it is
left out when an arm's joint is on a bus that is not served.

The rig file is read with :mod:`tomllib` (or given as the parsed dict); validating it is gonio's
rig parser's job, not the simulator's.
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any, Literal

from drivers.errors import ConfigError
from simulators.clock import SimClock
from simulators.dynamixel import control_table as ct
from simulators.dynamixel.bus import SimServoBus, WireTime
from simulators.dynamixel.drivetrain import Drivetrain, drivetrains_from_toml
from simulators.dynamixel.faults import Fault, parse_faults
from simulators.dynamixel.servo import SimServo
from simulators.dynamixel.world import DEFAULT_TICK_S, Collision, SolidWorld
from simulators.rig_solids import SolidRig, load_rig_toml, solid_rig_from_toml

logger = logging.getLogger(__name__)

RigSource = str | Path | Mapping[str, Any]
"""A rig file path, or its parsed TOML (``tomllib``) dict."""


def _limit_ticks(rig: SolidRig, axis: str) -> tuple[int, int]:
    a = rig.axes[axis]
    lo, hi = sorted((a.ticks(a.min_deg), a.ticks(a.max_deg)))
    return max(0, math.floor(lo)), min(ct.TICKS_PER_REV - 1, math.ceil(hi))


class SimRig:
    """The servos of one rig file on simulated buses, with its solid parts.

    Parameters
    ----------
    rig:
        Rig file path or parsed dict.
    clock:
        Simulated clock shared by every bus (a real-time one if None).
    faults, seed, strict_baud, wire_time, stall_trip_s, physics_tick_s:
        As for :class:`~simulators.dynamixel.bus.SimServoBus` (every bus gets the same fault
        list and seed; fault IDs must exist somewhere on the rig).
    positions_deg:
        Start joint angles (deg) by axis name; the park pose for the others.
    positions_ticks:
        Start positions (Present Position ticks) by axis name; they win over ``positions_deg``.
    buses:
        Names of the buses to serve (all if None).
    solids:
        Model the arms' solid parts (False: bare buses with the rig's IDs, bauds and limits).

    Attributes
    ----------
    solid_rig:
        The rig's solid parts as the simulator models them.
    buses:
        ``{bus name: SimServoBus}``.
    world:
        The solid world, or None.
    drivetrains:
        ``{axis: Drivetrain}``: where each arm really is given its shaft (the rig file's
        ``[simulation.errors]``: zero offsets, backlash, position noise).
    """

    def __init__(
        self,
        rig: RigSource,
        *,
        clock: SimClock | None = None,
        faults: Iterable[str | Fault] = (),
        seed: int = 0,
        strict_baud: bool = False,
        wire_time: bool | WireTime | Literal["auto"] = "auto",
        stall_trip_s: float = 1.0,
        physics_tick_s: float = DEFAULT_TICK_S,
        positions_deg: Mapping[str, float] | None = None,
        positions_ticks: Mapping[str, float] | None = None,
        buses: Iterable[str] | None = None,
        solids: bool = True,
    ) -> None:
        where = str(rig) if isinstance(rig, str | Path) else "rig dict"
        data = load_rig_toml(rig) if isinstance(rig, str | Path) else rig
        self.solid_rig = solid_rig_from_toml(data, where)
        sr = self.solid_rig
        if not sr.axes:
            raise ConfigError(f"{where}: the rig has no servo axes to simulate")
        names = list(sr.bauds) if buses is None else list(buses)
        unknown = [b for b in names if b not in sr.bauds]
        if unknown:
            raise ConfigError(f"{where}: no bus {unknown} in [buses] (has {list(sr.bauds)})")
        fault_list = parse_faults(faults)
        ids = {a.servo_id for a in sr.axes.values()}
        stray = sorted({f.servo_id for f in fault_list if f.servo_id is not None} - ids)
        if stray:
            raise ConfigError(f"{where}: fault specs name servo IDs {stray} that the rig does not "
                              f"have (IDs {sorted(ids)})")
        unknown_axes = sorted((set(positions_deg or {}) | set(positions_ticks or {})) - set(sr.axes))
        if unknown_axes:
            raise ConfigError(f"{where}: start positions for unknown axes {unknown_axes}")
        start_deg = {**self._park(positions_deg), **(positions_deg or {})}
        start = {n: sr.axes[n].ticks(d) for n, d in start_deg.items()}
        start.update(positions_ticks or {})
        self.clock = clock if clock is not None else SimClock()
        self._lock = threading.RLock()
        self.buses: dict[str, SimServoBus] = {}
        self._servo_of: dict[str, SimServo] = {}
        for bus in names:
            on_bus = {n: a for n, a in sr.axes.items() if a.bus == bus}
            if not on_bus:
                continue
            sim = SimServoBus(
                [a.servo_id for a in on_bus.values()], baud=sr.bauds[bus], clock=self.clock,
                faults=fault_list, seed=seed, strict_baud=strict_baud, wire_time=wire_time,
                positions={a.servo_id: start[n] for n, a in on_bus.items()},
                stall_trip_s=stall_trip_s, lock=self._lock)
            for n, a in on_bus.items():
                servo = sim.servos[a.servo_id]
                lo, hi = _limit_ticks(sr, n)
                for address, value in ((52, lo), (48, hi)):  # torque is off: EEPROM writable
                    servo.write(address, value.to_bytes(4, "little"))
                self._servo_of[n] = servo
            self.buses[bus] = sim
        self.drivetrains: dict[str, Drivetrain] = drivetrains_from_toml(
            data, {n: sr.axes[n].deg for n in self._servo_of}, seed=seed, where=where)
        for n, train in self.drivetrains.items():
            self._servo_of[n].sim_attach_drivetrain(train.on_goal)
        self.world: SolidWorld | None = None
        arm_joints = [j for js in sr.arm_axes.values() for j in js]
        if solids and arm_joints:
            absent = [j for j in arm_joints if j not in self._servo_of]
            if absent:
                logger.warning("%s: axes %s are not on a served bus: no solid parts simulated",
                               where, absent)
            else:
                self.world = SolidWorld(sr, self._servo_of, tick_s=physics_tick_s,
                                        arm_deg={n: t.arm_deg for n, t in self.drivetrains.items()})
                for sim in self.buses.values():
                    sim.sim_attach_world(self.world)

    def _park(self, given: Mapping[str, float] | None) -> dict[str, float]:
        try:
            return self.solid_rig.park_deg()
        except ConfigError:
            if given is not None and set(given) >= set(self.solid_rig.axes):
                return {}
            raise

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> SimRig:
        """Open every bus's pty and start its thread."""
        try:
            for sim in self.buses.values():
                sim.start()
        except BaseException:
            self.stop()
            raise
        return self

    def stop(self) -> None:
        """Stop every bus (idempotent)."""
        for sim in self.buses.values():
            sim.stop()

    def __enter__(self) -> SimRig:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ------------------------------------------------------------------ access
    @property
    def ports(self) -> dict[str, str]:
        """``{bus name: pty path}`` (while started)."""
        return {name: sim.port for name, sim in self.buses.items()}

    @property
    def port(self) -> str:
        """The pty path of a one-bus rig."""
        if len(self.buses) != 1:
            raise ConfigError(f"the rig has {len(self.buses)} buses; use .ports")
        return next(iter(self.buses.values())).port

    def servo(self, axis: str) -> SimServo:
        """The simulated servo driving ``axis``."""
        return self._servo_of[axis]

    def sim_true_joints_deg(self) -> dict[str, float]:
        """TRUE joint angles (deg) of every arm: its shaft's position through its gears
        (zero offset, backlash, position noise: :mod:`simulators.dynamixel.drivetrain`)."""
        with self._lock:
            return {n: self.drivetrains[n].arm_deg(s.sim_true_position_ticks())
                    for n, s in self._servo_of.items()}

    def sim_collisions(self) -> list[Collision]:
        """Every contact of the arms so far (oldest first); empty without solids."""
        with self._lock:
            return [] if self.world is None else self.world.collisions_at(self.clock.now())


def serve_rig(rig: RigSource, **options: Any) -> SimRig:
    """Start a :class:`SimRig` (its buses are open); ``with serve_rig(...) as r`` stops it.

    ``options`` are :class:`SimRig`'s keyword parameters.
    """
    return SimRig(rig, **options).start()
