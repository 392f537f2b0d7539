"""One simulated X-series servo: control-table memory plus physics on a :class:`SimClock`.

The servo is evaluated lazily: every access first advances its state to the clock's ``now``
(motion along the planned profile, temperature, faults due in between), so its present values
follow simulated time without a thread of its own.

Physics, in short:

- Motion (position modes 3, 4, 5, torque on): a goal write plans a profile
  (:mod:`simulators.dynamixel.profile`) from the present position and velocity; in mode 3 the
  goal is clamped to the Min/Max Position Limits. Homing Offset is added to Present Position
  and Goal Position (register frame = shaft frame + offset). Torque on copies the present
  position into Goal Position (no jump); torque off freezes the shaft where it is.
- Moving (122) is 1 while a profile is in progress (or stalled), or while
  ``|Present Velocity| > Moving Threshold``.
- Temperature follows a first-order model towards ambient + load heat (holding, moving,
  stalled) with time constant ``thermal_tau_s``; at the Temperature Limit the servo trips on
  overheating.
- Input voltage: supply minus a small sag while moving; outside the voltage limits, hardware
  error bit 0 (Alert, torque stays on unless Shutdown says otherwise).
- An obstruction (min/max shaft ticks) stops the shaft there; after ``stall_trip_s`` of pushing
  the servo trips on overload. A contact (:meth:`SimServo.sim_set_contact`, set by the solid
  world of :mod:`simulators.dynamixel.world` when the arms touch) is an obstruction at the
  present position in one direction of travel: the servo stalls there in the same way, and can
  always move away from it.
- A servo attached to a solid world (:meth:`SimServo.sim_attach_world`) lets the world advance
  every servo of the rig together before it advances itself, so that contacts between arms are
  found on the world's physics tick whoever asks first.
- A trip sets the Hardware Error Status bit; bits in Shutdown (63) turn the torque off and refuse
  torque-on (Result Fail) until REBOOT, which clears the bits whose cause is gone.
"""

from __future__ import annotations

import dataclasses
import math
import struct
import threading
from collections.abc import Callable

from simulators.clock import SimClock
from simulators.dynamixel import control_table as ct
from simulators.dynamixel.faults import Fault
from simulators.dynamixel.profile import (
    TICKS_PER_S_PER_VELOCITY_UNIT,
    Trajectory,
    limits_from_registers,
    plan,
)
from simulators.dynamixel.protocol import ErrorCode

_POSITION_MODES = (3, 4, 5)
_PRESENT_BLOCK = struct.Struct("<HBBhhiiiiHB")  # addresses 120..146
_ITEM_STRUCT = {
    item.name: (struct.Struct("<" + {1: "b", 2: "h", 4: "i"}[item.size] if item.signed
                              else "<" + {1: "B", 2: "H", 4: "I"}[item.size]), item.address)
    for item in ct.ITEMS
}
# Equilibrium temperature rise above ambient (°C) per load state.
_HEAT_HOLDING, _HEAT_MOVING, _HEAT_STALLED = 4.0, 20.0, 45.0
_VOLTAGE_SAG_V = 0.3
# REBOOT clears the overheating bit only this far below the Temperature Limit (°C).
_OVERHEAT_HYSTERESIS_C = 10.0


class SimServo:
    """A simulated XM430-W350 on a bus.

    Parameters
    ----------
    servo_id:
        Initial ID (0–252).
    clock:
        Simulated clock shared by the rig.
    baud_index:
        Initial Baud Rate register value (1 = 57600).
    position_ticks:
        Initial shaft position (ticks).
    ambient_c, supply_v:
        Ambient temperature (°C) and supply voltage (V).
    thermal_tau_s:
        Thermal time constant (simulated s).
    stall_trip_s:
        Simulated seconds of stall before the overload trip.
    faults:
        Faults of this servo (``overload``, ``overheat``, ``voltage``, ``obstruction``).
    lock:
        Lock shared with the bus; accessors take it.
    """

    def __init__(
        self,
        servo_id: int,
        clock: SimClock,
        *,
        baud_index: int = 1,
        position_ticks: float = 2048.0,
        ambient_c: float = 30.0,
        supply_v: float = 12.0,
        thermal_tau_s: float = 120.0,
        stall_trip_s: float = 1.0,
        faults: tuple[Fault, ...] = (),
        lock: threading.RLock | None = None,
    ) -> None:
        if not 0 <= servo_id <= 252:
            raise ValueError(f"servo ID must be 0..252, got {servo_id}")
        self.clock = clock
        self._lock = lock if lock is not None else threading.RLock()
        self.mem = ct.default_memory(servo_id, baud_index)
        self._t = clock.now()
        self._t_start = self._t
        self._pos = float(position_ticks)
        self._vel = 0.0
        self._traj: Trajectory | None = None
        self._hit: tuple[float, float] | None = None  # (time, ticks) of meeting the obstruction
        self._stall_since: float | None = None
        self._stall_tripped = False
        self._ambient = ambient_c
        self._temp = ambient_c + 2.0
        self._supply = supply_v
        self._tau = thermal_tau_s
        self._stall_trip_s = stall_trip_s
        self._obstruction: tuple[float | None, float | None] = (None, None)
        self._contact: tuple[float, int] | None = None  # (shaft ticks, blocked direction ±1)
        self._world: Callable[[float], None] | None = None
        self._goal_hook: Callable[[float, float], None] | None = None
        self._motion_gen = 0  # bumped whenever the planned motion may change
        self._registered: tuple[int, bytes] | None = None
        self._overload_at: float | None = None
        self._heat_faults: list[tuple[float, float]] = []  # (from sim time, extra °C)
        self._voltage_faults: list[tuple[float, float]] = []  # (from sim time, volts)
        for f in faults:
            self._add_fault(f)
        for start, volts in self._voltage_faults:
            if start <= self._t:
                self._supply = volts
        self._check_voltage()
        self._set_goal_to_present()

    # ------------------------------------------------------------------ registers
    def _get(self, name: str) -> int:
        fmt, address = _ITEM_STRUCT[name]
        return fmt.unpack_from(self.mem, address)[0]

    def _put(self, name: str, value: int) -> None:
        item = ct.BY_NAME[name]
        self.mem[item.address : item.address + item.size] = ct.encode(item, value)

    @property
    def servo_id(self) -> int:
        """Present ID (address 7)."""
        return self.mem[7]

    @property
    def baud_rate(self) -> int:
        """Baud rate (bit/s) set in address 8."""
        return ct.BAUD_RATES.get(self.mem[8], 57600)

    @property
    def status_return_level(self) -> int:
        """Status Return Level (68): 0 ping only, 1 ping + reads, 2 all."""
        return self.mem[68]

    @property
    def return_delay_s(self) -> float:
        """Return Delay Time (9) in seconds (unit 2 µs)."""
        return self.mem[9] * 2e-6

    @property
    def hardware_error(self) -> int:
        """Hardware Error Status (70) at the clock's now."""
        with self._lock:
            self._advance(self.clock.now())
            return self.mem[70]

    @property
    def torque_on(self) -> bool:
        return self.mem[64] == 1

    # ------------------------------------------------------------------ protocol-facing
    def read(self, address: int, length: int) -> tuple[int, bytes]:
        """(error code, data) of a READ of ``length`` bytes at ``address``."""
        with self._lock:
            if length <= 0:
                return ErrorCode.DATA_LENGTH, b""
            if address < 0 or address + length > ct.TABLE_SIZE:
                return ErrorCode.ACCESS, b""
            self._advance(self.clock.now())
            self._refresh()
            return ErrorCode.NONE, bytes(self.mem[address : address + length])

    def check_write(self, address: int, data: bytes) -> tuple[int, list[tuple[ct.Item, int]]]:
        """Validate a write without applying it: (error code, [(item, value), ...])."""
        if not data:
            return ErrorCode.DATA_LENGTH, []
        end = address + len(data)
        if address < 0 or end > ct.TABLE_SIZE:
            return ErrorCode.ACCESS, []
        items: list[tuple[ct.Item, int]] = []
        a = address
        while a < end:
            item = ct.OWNER[a]
            if item is None or not item.writable:
                return ErrorCode.ACCESS, []
            if item.eeprom and self.torque_on:
                return ErrorCode.ACCESS, []
            if item.address != a or a + item.size > end:
                return ErrorCode.DATA_LENGTH, []
            value = ct.decode(item, data[a - address : a - address + item.size])
            if not item.valid(value):
                return ErrorCode.DATA_RANGE, []
            items.append((item, value))
            a += item.size
        return ErrorCode.NONE, items

    def write(self, address: int, data: bytes) -> int:
        """Apply a WRITE; returns the error code (nothing is written on error)."""
        with self._lock:
            self._advance(self.clock.now())
            err, items = self.check_write(address, bytes(data))
            if err:
                return err
            for item, value in items:
                err = self._apply(item, value) or err
            return err

    def reg_write(self, address: int, data: bytes) -> int:
        """REG_WRITE: validate and hold the write until ACTION."""
        with self._lock:
            self._advance(self.clock.now())
            err, _ = self.check_write(address, bytes(data))
            if err:
                return err
            self._registered = (address, bytes(data))
            self.mem[69] = 1
            return ErrorCode.NONE

    def action(self) -> int:
        """ACTION: apply the registered write (Instruction error if there is none)."""
        with self._lock:
            if self._registered is None:
                return ErrorCode.INSTRUCTION
            address, data = self._registered
            self._registered = None
            self.mem[69] = 0
            return self.write(address, data)

    def reboot(self) -> None:
        """REBOOT: RAM back to defaults, torque off, errors whose cause is gone cleared."""
        with self._lock:
            self._advance(self.clock.now())
            self._reset_ram()

    def factory_reset(self, option: int) -> int:
        """FACTORY_RESET (0xFF all, 0x01 keep ID, 0x02 keep ID and baud rate)."""
        with self._lock:
            if option not in ct.FACTORY_RESET_KEEP:
                return ErrorCode.DATA_RANGE
            self._advance(self.clock.now())
            keep = {n: self._get(n) for n in ct.FACTORY_RESET_KEEP[option]}
            fresh = ct.default_memory(1, 1)
            self.mem[: ct.EEPROM_END] = fresh[: ct.EEPROM_END]
            for name, value in keep.items():
                self._put(name, value)
            self._reset_ram()
            return ErrorCode.NONE

    # ------------------------------------------------------------------ sim-only accessors
    def sim_true_position_ticks(self) -> float:
        """TRUE shaft position at the clock's now, in Present Position ticks (not rounded)."""
        with self._lock:
            self._advance(self.clock.now())
            return self._pos + self._get("homing_offset")

    def sim_set_obstruction(self, min_ticks: float | None, max_ticks: float | None) -> None:
        """Block the shaft below ``min_ticks`` / above ``max_ticks`` (shaft frame; None = free)."""
        with self._lock:
            self._advance(self.clock.now())
            self._obstruction = (min_ticks, max_ticks)
            if self._traj is not None:
                self._replan(self._traj.target)

    def sim_set_supply(self, volts: float) -> None:
        """Set the supply voltage (V)."""
        with self._lock:
            self._advance(self.clock.now())
            self._supply = volts
            self._check_voltage()

    def sim_trip(self, bits: int) -> None:
        """Raise hardware error ``bits`` now, as if the servo detected them."""
        with self._lock:
            self._advance(self.clock.now())
            self._trip(bits)

    # ------------------------------------------------------------------ solid-world interface
    # Positions here are Present Position ticks (register frame: shaft + Homing Offset), the
    # frame a rig's zero_tick is given in. Callers hold the bus lock.
    def sim_attach_world(self, advance: Callable[[float], None] | None) -> None:
        """Call ``advance(t)`` (the solid world's step to ``t``) before this servo advances."""
        self._world = advance

    def sim_attach_drivetrain(self, on_goal: Callable[[float, float], None] | None) -> None:
        """Call ``on_goal(present_ticks, goal_ticks)`` (Present Position frame) whenever a move
        is planned (a :class:`~simulators.dynamixel.drivetrain.Drivetrain` follows the shaft)."""
        self._goal_hook = on_goal

    def sim_step_to(self, t: float) -> None:
        """Advance this servo alone to simulated time ``t`` (the world's own stepping)."""
        with self._lock:
            self._step(t)

    def sim_next_event_s(self) -> float:
        """Simulated time of the next discrete event (arrival, stall, trip...), ``inf`` if none."""
        with self._lock:
            event = self._next_event(self._t)
            return event[0] if event is not None else math.inf

    @property
    def sim_motion_generation(self) -> int:
        """Changes whenever the servo's planned motion may have changed (a new goal, a stop,
        a contact block): while it stays, the motion is the planned one, or slower."""
        return self._motion_gen

    def sim_moving(self) -> bool:
        """True while the shaft follows a profile (not stalled, torque on)."""
        return self.torque_on and self._traj is not None and self._stall_since is None

    def sim_peek_ticks(self, t: float) -> float:
        """Position (Present Position ticks) at ``t`` ≥ the servo's time, assuming no event
        (:meth:`sim_next_event_s`) comes first; nothing is changed."""
        return self._shaft_at(t) + self._get("homing_offset")

    def sim_speed_bound_ticks_per_s(self) -> float:
        """Upper bound of |velocity| (ticks/s) over the rest of the present move (0 at rest)."""
        if not self.sim_moving():
            return 0.0
        t = self._t
        return max((max(abs(seg.v0), abs(seg.velocity(seg.t1)))
                    for seg in self._traj.segments if seg.t1 > t), default=0.0)

    def sim_direction(self) -> int:
        """Direction of travel now: +1, −1 (towards the goal if at rest on a profile), 0."""
        if not self.sim_moving():
            return 0
        _, v = self._traj.state(self._t)
        if abs(v) < 1e-9:
            v = self._traj.target - self._pos
        return (v > 0) - (v < 0)

    def sim_set_contact(self, direction: int | None) -> None:
        """Block travel beyond the present position in ``direction`` (+1 up, −1 down), as an
        obstruction there would; None removes the block (a stalled move resumes). Acts at the
        servo's own simulated time (where the world has stepped it), not at the clock's now."""
        with self._lock:
            self._motion_gen += 1
            self._contact = None if not direction else (self._pos, 1 if direction > 0 else -1)
            if self._traj is not None:
                self._replan(self._traj.target)

    def sim_follow_contact(self, ticks: float) -> None:
        """Move a servo stalled at a contact on to ``ticks`` (Present Position), where the
        contact has gone (the other arm gave way); it stays stalled: still pushing, its stall
        time runs on."""
        with self._lock:
            if self._contact is None or self._stall_since is None:
                raise RuntimeError("sim_follow_contact: the servo is not stalled at a contact")
            shaft = ticks - self._get("homing_offset")
            self._motion_gen += 1
            self._pos, self._vel = shaft, 0.0
            self._contact = (shaft, self._contact[1])

    def sim_goal_ticks(self) -> float | None:
        """Target (Present Position ticks) of the present move, also while stalled; None at
        rest or with torque off."""
        if not self.torque_on or self._traj is None:
            return None
        return self._traj.target + self._get("homing_offset")

    def sim_profile_speed_ticks_per_s(self) -> float:
        """Fastest |velocity| (ticks/s) of the present move's profile, also while stalled."""
        if not self.torque_on or self._traj is None:
            return 0.0
        return max((max(abs(seg.v0), abs(seg.velocity(seg.t1))) for seg in self._traj.segments),
                   default=0.0)

    def sim_contact(self) -> tuple[float, int] | None:
        """(Present Position ticks, blocked direction) of the contact block, or None."""
        if self._contact is None:
            return None
        return self._contact[0] + self._get("homing_offset"), self._contact[1]

    def sim_stalled(self) -> bool:
        """True while the shaft pushes against an obstruction or a contact."""
        return self._stall_since is not None

    # ------------------------------------------------------------------ internals
    def _add_fault(self, f: Fault) -> None:
        after = self._t_start + f.params.get("after", 0.0)
        if f.kind == "overload":
            self._overload_at = after
        elif f.kind == "overheat":
            self._heat_faults.append((after, f.params.get("heat", 60.0)))
        elif f.kind == "voltage":
            self._voltage_faults.append((after, f.params["volts"]))
        elif f.kind == "obstruction":
            self._obstruction = (f.params.get("min"), f.params.get("max"))

    def _reset_ram(self) -> None:
        fresh = ct.default_memory(self.servo_id)
        self.mem[ct.EEPROM_END :] = fresh[ct.EEPROM_END :]
        self._registered = None
        self._stop_motion()
        if self._temp > self._get("temperature_limit") - _OVERHEAT_HYSTERESIS_C:
            self.mem[70] |= ct.HW_OVERHEATING
        self._check_voltage()
        self._set_goal_to_present()

    def _set_goal_to_present(self) -> None:
        self._put("goal_position", round(self._pos) + self._get("homing_offset"))

    def _apply(self, item: ct.Item, value: int) -> int:
        name = item.name
        if name == "torque_enable":
            if value == 1 and self.mem[70] & self.mem[63]:
                return ErrorCode.RESULT_FAIL
            if value == 1 and not self.torque_on:
                self.mem[64] = 1
                self._set_goal_to_present()
            elif value == 0:
                self.mem[64] = 0
                self._stop_motion()
            return ErrorCode.NONE
        if name == "goal_position":
            mode = self._get("operating_mode")
            if mode == 3:
                value = min(max(value, self._get("min_position_limit")),
                            self._get("max_position_limit"))
            self._put(name, value)
            if self.torque_on and mode in _POSITION_MODES:
                self._replan(value - self._get("homing_offset"))
            return ErrorCode.NONE
        if name == "id":
            self._put(name, value)  # the bus re-indexes after the reply
            return ErrorCode.NONE
        self._put(name, value)
        if name in ("min_voltage_limit", "max_voltage_limit"):
            self._check_voltage()
        return ErrorCode.NONE

    def _bounds(self) -> tuple[float | None, float | None]:
        """Shaft bounds (ticks) of the obstruction fault and the contact, combined."""
        lo, hi = self._obstruction
        if self._contact is not None:
            at, direction = self._contact
            if direction > 0:
                hi = at if hi is None else min(hi, at)
            else:
                lo = at if lo is None else max(lo, at)
        return lo, hi

    def _shaft_at(self, t: float) -> float:
        """Shaft ticks at ``t`` ≥ self._t if no event comes first (no state change)."""
        if not self.sim_moving():
            return self._pos
        if self._hit is not None and t >= self._hit[0]:
            return self._hit[1]
        return self._traj.state(t)[0]

    def _replan(self, target: float) -> None:
        self._motion_gen += 1
        if self._goal_hook is not None:
            offset = self._get("homing_offset")
            self._goal_hook(self._pos + offset, target + offset)
        t = self._t
        lo, hi = self._bounds()
        if self._stall_since is not None:
            at_hi = hi is not None and abs(self._pos - hi) < 1e-6
            at_lo = lo is not None and abs(self._pos - lo) < 1e-6
            if (at_hi and target > self._pos) or (at_lo and target < self._pos):
                if self._traj is not None:  # still pushing: stays stalled, towards the new goal
                    self._traj = dataclasses.replace(self._traj, target=target)
                return
            self._stall_since, self._stall_tripped = None, False
        time_based = bool(self._get("drive_mode") & 0x04)
        vmax, amax = limits_from_registers(
            self._get("profile_velocity"), self._get("profile_acceleration"),
            self._get("velocity_limit"), time_based, target - self._pos)
        traj = plan(t, self._pos, self._vel, target, vmax, amax)
        if not traj.segments:  # instantaneous (no velocity limit at all)
            traj = Trajectory((), target)
        self._traj = traj
        self._hit = None
        hits: list[tuple[float, float]] = []
        for bound, sign in ((hi, 1.0), (lo, -1.0)):
            if bound is None:
                continue
            if not traj.segments:
                if sign * (target - bound) > 0 >= sign * (self._pos - bound):
                    hits.append((t, bound))
            elif (h := traj.first_crossing(bound)) is not None and (
                sign * traj.state(h)[1] > 0 or sign * (target - bound) > 0
            ):
                hits.append((h, bound))
        self._hit = min(hits) if hits else None
        if not traj.segments and self._hit is None:
            self._pos, self._vel, self._traj = target, 0.0, None

    def _load_heat(self, t: float) -> float:
        if not self.torque_on:
            return 0.0
        heat = _HEAT_HOLDING
        if self._stall_since is not None:
            heat = _HEAT_STALLED
        elif self._traj is not None:
            heat = _HEAT_MOVING
        heat += sum(extra for start, extra in self._heat_faults if t >= start)
        return heat

    def _next_event(self, t0: float) -> tuple[float, str] | None:
        events: list[tuple[float, str]] = []
        if self.torque_on:
            if self._overload_at is not None:
                events.append((max(self._overload_at, t0), "overload"))
            if self._hit is not None and self._stall_since is None:
                events.append((max(self._hit[0], t0), "stall"))
            if self._stall_since is not None and not self._stall_tripped:
                events.append((max(self._stall_since + self._stall_trip_s, t0), "stall_trip"))
            if self._traj is not None and self._hit is None and self._stall_since is None:
                events.append((max(self._traj.end, t0), "arrive"))
        for start, _ in self._heat_faults:
            if start > t0:
                events.append((start, "heat"))
        for start, _ in self._voltage_faults:
            if start > t0:
                events.append((start, "voltage"))
        # Temperature crossing the limit under the present load.
        limit = self._get("temperature_limit")
        t_eq = self._ambient + self._load_heat(t0)
        if t_eq > limit > self._temp and not self.mem[70] & ct.HW_OVERHEATING:
            dt = self._tau * math.log((t_eq - self._temp) / (t_eq - limit))
            events.append((t0 + dt, "overheat"))
        return min(events) if events else None

    def _integrate(self, t: float) -> None:
        """Advance continuous state from self._t to t (no events in between)."""
        dt = t - self._t
        if dt <= 0:
            return
        t_eq = self._ambient + self._load_heat(self._t)
        self._temp = t_eq + (self._temp - t_eq) * math.exp(-dt / self._tau)
        if self._traj is not None and self._stall_since is None:
            self._pos, self._vel = self._traj.state(t)
        self._t = t

    def _advance(self, now: float) -> None:
        if self._world is not None:
            self._world(now)  # steps every servo of the rig (this one too) to now
        self._step(now)

    def _step(self, now: float) -> None:
        while True:
            event = self._next_event(self._t)
            if event is None or event[0] > now:
                self._integrate(now)
                return
            te, kind = event
            self._integrate(te)
            if kind == "overload":
                self._overload_at = None
                self._trip(ct.HW_OVERLOAD)
            elif kind == "stall":
                self._pos = self._hit[1]
                self._vel, self._stall_since, self._hit = 0.0, te, None
            elif kind == "stall_trip":
                self._stall_tripped = True
                self._trip(ct.HW_OVERLOAD)
            elif kind == "arrive":
                self._pos, self._vel, self._traj = self._traj.target, 0.0, None
            elif kind == "overheat":
                self._temp = float(self._get("temperature_limit"))
                self._trip(ct.HW_OVERHEATING)
            elif kind == "voltage":
                self._supply = next(v for s, v in reversed(self._voltage_faults) if s <= te)
                self._check_voltage()
            # "heat" only changes the load from now on (its start is no longer > self._t).

    def _check_voltage(self) -> None:
        lo, hi = self._get("min_voltage_limit") / 10, self._get("max_voltage_limit") / 10
        if not lo <= self._supply <= hi:
            self._trip(ct.HW_INPUT_VOLTAGE)

    def _stop_motion(self) -> None:
        self._motion_gen += 1
        self._traj, self._hit, self._stall_since, self._vel = None, None, None, 0.0
        self._stall_tripped = False

    def _trip(self, bits: int) -> None:
        self.mem[70] |= bits
        if bits & self.mem[63]:
            self.mem[64] = 0
            self._stop_motion()

    def _refresh(self) -> None:
        """Write the present values at self._t into memory."""
        offset = self._get("homing_offset")
        present = round(self._pos) + offset
        vel_units = round(self._vel / TICKS_PER_S_PER_VELOCITY_UNIT)
        in_profile = self.torque_on and (self._traj is not None or self._stall_since is not None)
        moving = in_profile or abs(vel_units) > self._get("moving_threshold")
        goal = self._get("goal_position")
        status = (0x01 if abs(goal - present) <= 1 and not in_profile else 0) | (
            0x02 if in_profile else 0) | (0x30 if in_profile else 0)
        current = 0
        if self.torque_on:
            current = 900 if self._stall_since is not None else (120 if moving else 15)
        target = self._traj.target + offset if self._traj is not None else present
        volts = self._supply - (_VOLTAGE_SAG_V if moving else 0.0)
        # Realtime Tick (120) .. Present Temperature (146) in one go.
        _PRESENT_BLOCK.pack_into(
            self.mem, 120, int(self._t * 1000) % 32768, int(moving), status, min(current, 885),
            current, vel_units, present, vel_units, round(target),
            max(0, round(volts * 10)), max(0, min(255, round(self._temp))))
