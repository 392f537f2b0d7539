"""Opening a rig's devices — real or simulated — behind one interface for the capture engine.

For a bus declared ``simulated = true`` the servo simulator is started in-process on a
pseudo-terminal and the driver opens that path through ``dynamixel_sdk``, exactly as it would
open a USB adapter. A simulated camera renders the scene from the simulator's *true* servo
angles. Every move passes the planner's guard before the motion controller sends it, and the
servos' temperature and supply voltage before that (:class:`HealthGuard`).

Opening a bus checks, in order: the port opens (one-line error naming it), every servo the rig
file declares on it answers (one error listing the missing IDs; if none answers but they do at
another common baud rate, the error names that rate and the rig-file field to change), and on a
real port the USB adapter's latency timer (a :class:`LatencyWarning` above 1 ms).
"""

from __future__ import annotations

import logging
import time
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import AbstractContextManager, ExitStack, contextmanager, nullcontext
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from acquisition.config.rig import MOTION_POLL_S, AxisConfig, RigConfig
from acquisition.geometry.kinematics import Pose
from acquisition.planning.planner import Planner
from acquisition.simworld.scene import SampleHolder, make_scene, white_material
from calibration.linearize import linearize
from calibration.raw import load_raw
from drivers.camera import Camera
from drivers.dynamixel import (
    COMMON_BAUD_RATES,
    Axis,
    MotionController,
    ServoBus,
    ServoStatus,
)
from drivers.dynamixel.bus import Addr
from drivers.dynamixel.latency import SYSFS_USB_SERIAL, latency_warning
from drivers.errors import ConfigError, HardwareError
from drivers.gphoto2 import GPhoto2Camera
from simulators.camera import SimCamera
from simulators.clock import SimClock, SteppedClock
from simulators.dynamixel import SimServoBus
from simulators.materials import Material
from simulators.sensor import SensorModel

log = logging.getLogger(__name__)

LATENCY_SYSFS = SYSFS_USB_SERIAL
"""Where the USB-serial adapters' ``latency_timer`` files live (a test may point it elsewhere)."""


class LatencyWarning(UserWarning):
    """The servo port's USB latency timer is above 1 ms (slow round trips)."""


class ServoHealthError(HardwareError):
    """Servos stayed too hot, or their supply outside its range, for longer than allowed."""


def make_axis(cfg: AxisConfig) -> Axis:
    """The driver's axis for one rig-file axis."""
    return Axis(
        name=cfg.name, servo_id=cfg.servo_id, zero_tick=cfg.zero_tick, direction=cfg.direction,
        min_deg=cfg.min_deg, max_deg=cfg.max_deg, profile_velocity=cfg.profile_velocity,
        profile_acceleration=cfg.profile_acceleration,
    )


def park_joints(rig: RigConfig, planner: Planner) -> dict[str, float]:
    """Joints (deg) of the park pose: the white-reference pose, where a simulated rig starts.

    A rig file has no park key yet; the white-reference pose is reachable and guarded by
    construction (every capture starts and ends there).
    """
    wr = rig.white_reference
    return dict(planner.joints_for(Pose(wr.theta_i, wr.theta_r, wr.delta_phi)))


# ---------------------------------------------------------------------- health guard
@dataclass(frozen=True)
class HealthLimits:
    """When to pause before a move, and when to go on (X-series defaults).

    A move waits while any servo is at or above ``pause_at_c`` until all are below
    ``resume_below_c``, and while any supply voltage lies outside ``[min_v, max_v]`` until all
    are inside ``[min_v + hysteresis_v, max_v − hysteresis_v]``. The X-series trips on its own
    at its Temperature Limit (80 °C) and outside its voltage limits (9.5–16.0 V); the guard
    stops earlier and recovers without a reboot.
    """

    pause_at_c: float = 70.0
    resume_below_c: float = 60.0
    min_v: float = 10.0
    max_v: float = 14.8
    hysteresis_v: float = 0.3
    poll_s: float = 2.0
    """Pause between readings while waiting (device-clock s)."""
    give_up_s: float = 1800.0
    """Longest wait (device-clock s) before :class:`ServoHealthError`; 0 refuses at once."""

    def __post_init__(self) -> None:
        if not self.resume_below_c < self.pause_at_c:
            raise ConfigError(f"health limits: resume_below_c {self.resume_below_c} °C must be "
                              f"below pause_at_c {self.pause_at_c} °C")
        if not self.min_v + self.hysteresis_v < self.max_v - self.hysteresis_v:
            raise ConfigError(f"health limits: voltage range [{self.min_v}, {self.max_v}] V is "
                              f"too narrow for a hysteresis of {self.hysteresis_v} V")
        if self.poll_s <= 0 or self.give_up_s < 0:
            raise ConfigError("health limits: poll_s must be > 0 and give_up_s >= 0")


@dataclass(frozen=True)
class HealthPause:
    """One pause of the guard: device-clock start and end (s), and why it paused."""

    start_s: float
    end_s: float
    reasons: tuple[str, ...]


class HealthGuard:
    """Reads every servo's temperature and input voltage before a move, pausing when needed.

    Parameters
    ----------
    axes:
        ``{axis name: Axis}``.
    buses:
        ``{axis name: ServoBus}`` (one sync read per bus per reading).
    limits:
        Thresholds and timing.
    now, sleep:
        The device clock (a simulated rig's :class:`SimClock`, else the host's monotonic clock).
    """

    def __init__(
        self,
        axes: Mapping[str, Axis],
        buses: Mapping[str, ServoBus],
        limits: HealthLimits | None = None,
        *,
        now: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        self.axes = dict(axes)
        self.buses = dict(buses)
        self.limits = limits or HealthLimits()
        self._now, self._sleep = now, sleep
        self.pauses: list[HealthPause] = []

    def read(self) -> dict[str, ServoStatus]:
        """``{axis: ServoStatus}``, one sync read per bus (never raises on hardware errors)."""
        groups: dict[ServoBus, list[str]] = {}
        for name in self.axes:
            groups.setdefault(self.buses[name], []).append(name)
        out: dict[str, ServoStatus] = {}
        for bus, names in groups.items():
            status = bus.read_status([self.axes[n].servo_id for n in names])
            for n in names:
                out[n] = status[self.axes[n].servo_id]
        return out

    def problems(self, status: Mapping[str, ServoStatus], paused: bool = False) -> list[str]:
        """Why a move must wait (empty: go). ``paused`` applies the resume thresholds."""
        lim = self.limits
        hot = lim.resume_below_c if paused else lim.pause_at_c
        lo = lim.min_v + lim.hysteresis_v if paused else lim.min_v
        hi = lim.max_v - lim.hysteresis_v if paused else lim.max_v
        out = []
        for name, s in status.items():
            who = f"axis '{name}' (servo {self.axes[name].servo_id})"
            if s.temperature_c >= hot:
                out.append(f"{who} at {s.temperature_c} °C (pause at {lim.pause_at_c:g} °C, "
                           f"resume below {lim.resume_below_c:g} °C)")
            if not lo <= s.voltage_v <= hi:
                out.append(f"{who} supply {s.voltage_v:.1f} V (outside {lim.min_v:g}–"
                           f"{lim.max_v:g} V)")
        return out

    def wait_until_healthy(self, give_up_s: float | None = None) -> float:
        """Return at once when every servo is in range, else wait (torque stays on, nothing
        moves), polling on the device clock, until all are back inside the resume thresholds.

        Returns the time waited (device s).

        Raises
        ------
        ServoHealthError
            Still out of range after ``give_up_s`` (default: the limits'); nothing was moved.
        """
        give_up = self.limits.give_up_s if give_up_s is None else give_up_s
        reasons = self.problems(self.read())
        if not reasons:
            return 0.0
        if give_up <= 0:
            raise ServoHealthError(
                f"move refused: {'; '.join(reasons)}; wait until the servos cool down or the "
                f"supply is back in range, then try again"
            )
        start = self._now()
        log.warning("pausing before the next move: %s", "; ".join(reasons))
        first = tuple(reasons)
        while True:
            self._sleep(self.limits.poll_s)
            waited = self._now() - start
            reasons = self.problems(self.read(), paused=True)
            if not reasons:
                self.pauses.append(HealthPause(start, start + waited, first))
                log.warning("resuming after %.0f s: servos back in range", waited)
                return waited
            if waited >= give_up:
                self.pauses.append(HealthPause(start, start + waited, first))
                raise ServoHealthError(
                    f"paused {waited:.0f} s and still {'; '.join(reasons)}; nothing moved, "
                    f"all axes hold their position — cool the servos or fix the supply, then "
                    f"continue (a capture with `gonio resume SESSION`)"
                )


# ---------------------------------------------------------------------- clock
def make_clock(rig: RigConfig) -> SimClock:
    """The device clock of a simulated rig: ``[simulation] clock`` (default ``"stepped"``).

    A :class:`SteppedClock` moves only when a device waits or spends time on purpose, and the
    servo simulators then charge each packet its time on the wire (``wire_time="clock"``),
    so a run's rig time is motion + polling + wire time + settle + exposure, independent of the
    host's load. ``"scaled"`` runs at ``time_scale`` × host time (external clients).
    """
    return SteppedClock() if rig.sim_clock == "stepped" else SimClock(rig.time_scale)


# ---------------------------------------------------------------------- servos
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

    def move_to(self, joints: Mapping[str, float], *, health_wait_s: float | None = None
                ) -> dict[str, float]:
        """Health check (maybe a pause), guard, one sync write, readback; returns degrees."""
        self.health.wait_until_healthy(health_wait_s)
        return dict(self.motion.move_to(joints))

    def true_joints(self) -> dict[str, float]:
        """The simulators' TRUE joint angles (deg); simulated buses only."""
        out = {}
        for name, cfg in self.rig.axes.items():
            ticks = self.sims[cfg.bus].servos[cfg.servo_id].sim_true_position_ticks()
            out[name] = self.axes[name].ticks_to_deg(ticks)
        return out


@contextmanager
def start_simulated_buses(
    rig: RigConfig,
    planner: Planner,
    clock: SimClock,
    *,
    sim_faults: Sequence[str] = (),
    seed: int = 0,
) -> Iterator[dict[str, SimServoBus]]:
    """Start a simulator for every ``simulated = true`` bus, its servos at the park pose.

    The servos are deaf at any other baud rate than the rig file's (``strict_baud``), like a
    real bus, so ``gonio scan`` finds them at that rate only.
    """
    park = park_joints(rig, planner)
    with ExitStack() as stack:
        sims: dict[str, SimServoBus] = {}
        for name, bus_cfg in rig.buses.items():
            if not bus_cfg.simulated:
                continue
            on_bus = [a for a in rig.axes.values() if a.bus == name]
            sim = SimServoBus(
                [a.servo_id for a in on_bus], baud=bus_cfg.baud, clock=clock,
                faults=list(sim_faults), seed=seed, strict_baud=True,
                wire_time="clock" if isinstance(clock, SteppedClock) else False,
                positions={a.servo_id: make_axis(a).deg_to_ticks(park[a.name]) for a in on_bus},
            )
            sim.start()
            stack.callback(sim.stop)
            sims[name] = sim
        yield sims


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
    if clock is None and any(b.simulated for b in rig.buses.values()):
        clock = make_clock(rig)
    axes = {name: make_axis(cfg) for name, cfg in rig.axes.items()}
    with ExitStack() as stack:
        sims = {}
        if clock is not None:
            sims = stack.enter_context(start_simulated_buses(
                rig, planner, clock, sim_faults=sim_faults, seed=seed))
        buses: dict[str, ServoBus] = {}
        for name, bus_cfg in rig.buses.items():
            port = sims[name].port if name in sims else bus_cfg.port
            bus = stack.enter_context(ServoBus(port, bus_cfg.baud, name=name))
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
        names = list(axes)

        def guard(targets: Mapping[str, float]) -> None:
            # Axes not asked to move stay where they are: check the pose they will make.
            rest = [n for n in names if n not in targets]
            full = {**motion.positions_deg(rest), **targets} if rest else dict(targets)
            planner.check_joints(full)

        timing: dict[str, Any] = {"sleep": clock.sleep} if clock is not None else {}
        if isinstance(clock, SteppedClock):  # host time says nothing about a stepped rig
            timing["monotonic"] = clock.now
        motion = MotionController(axes.values(), by_axis, guard=guard, poll_s=MOTION_POLL_S,
                                  **timing)
        health = HealthGuard(
            axes, by_axis, health_limits,
            **({"now": clock.now, "sleep": clock.sleep} if clock is not None else {}),
        )
        if prepare:
            set_low_latency(buses, rig)
            motion.apply_profiles()
            motion.set_torque(True)
        yield ServoRig(rig, planner, axes, buses, motion, health, clock, sims)


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


# ---------------------------------------------------------------------- whole rig
class RigDevices:
    """An open rig: motion controller, camera, sample holder, and (simulated) clock."""

    def __init__(
        self,
        rig: RigConfig,
        motion: MotionController,
        camera: SimCamera | Camera,
        holder: SampleHolder | None,
        clock: SimClock | None,
        *,
        health: HealthGuard | None = None,
    ) -> None:
        self.rig = rig
        self.motion = motion
        self.camera = camera
        self.holder = holder
        self.clock = clock
        self.health = health

    def move_to(self, joints: dict[str, float]) -> dict[str, float]:
        """Health-checked, guarded, readback-confirmed move; returns the read-back joints (deg).

        Before the move the servos' temperature and supply voltage are read; out of range, the
        move waits (see :class:`HealthGuard`) and raises :class:`ServoHealthError` if they do
        not recover in time.
        """
        if self.health is not None:
            self.health.wait_until_healthy()
        readback = self.motion.move_to(joints)
        if self.rig.settle_s:
            if self.clock is not None:
                self.clock.sleep(self.rig.settle_s)
            else:  # pragma: no cover - hardware
                time.sleep(self.rig.settle_s)
        return dict(readback)

    def capture(self, path: Path, exposure_s: float, iso: int, frame_seed: int) -> None:
        """Expose one RAW frame; ``frame_seed`` fixes a simulated camera's noise (resumes
        re-shoot identical frames) and is meaningless to a real one."""
        if isinstance(self.camera, SimCamera):
            self.camera.capture(path, exposure_s, iso, frame_seed=frame_seed)
        else:
            self.camera.capture(path, exposure_s, iso)

    def present(self, target: str) -> None:
        if self.holder is None:  # pragma: no cover - hardware: the operator swaps targets
            input(f"Put the {target} on the stage and press Enter… ")
        else:
            self.holder.present(target)

    def light(self, on: bool) -> None:
        """Switch the rig's light (dark frames). Simulated rigs only, for now."""
        if self.holder is None:
            raise ConfigError(
                f"{self.rig.path}: this rig declares no light controller, so dark frames need "
                "the lamp switched by hand: remove Dark steps or take darks with `gonio calibrate dark`"
            )
        self.holder.light_on = on

    def stop_motion(self) -> None:
        self.motion.stop()

    def device_time_s(self) -> float | None:
        return None if self.clock is None else self.clock.now()

    def host_work(self) -> AbstractContextManager[None]:
        """Stops the simulated clock during host-only work (no effect on real hardware)."""
        return self.clock.frozen() if self.clock is not None else nullcontext()

    def roi_saturated(self, frame: Path) -> bool:
        """True when any pixel of the region of interest is clipped."""
        image = linearize(load_raw(frame))
        x0, y0, x1, y1 = self.rig.camera.roi
        return not bool(np.all(image.valid[y0:y1, x0:x1]))


CAMERA_DRIVERS = ("simulated", "gphoto2")
"""``[camera] driver`` values: the simulated RAW camera, or a DSLR/mirrorless body over gphoto2."""


def check_camera_driver(rig: RigConfig) -> None:
    """Refuse camera drivers gonio lacks, and a simulated camera on real servos."""
    driver = rig.camera.driver
    if driver not in CAMERA_DRIVERS:
        raise ConfigError(
            f"{rig.path}: [camera] driver '{driver}' is unknown: use one of {', '.join(CAMERA_DRIVERS)}"
        )
    if driver == "simulated" and not all(b.simulated for b in rig.buses.values()):
        raise ConfigError(
            f"{rig.path}: a simulated camera renders from the simulator's true servo angles; "
            "set simulated = true on every [buses.*] or use driver = 'gphoto2'"
        )


@contextmanager
def open_devices(
    rig: RigConfig,
    planner: Planner,
    *,
    material: Material | None,
    seed: int = 0,
    sim_faults: Sequence[str] = (),
    health_limits: HealthLimits | None = None,
) -> Iterator[RigDevices]:
    """Open (and for simulated devices, start) everything the rig file declares."""
    check_camera_driver(rig)
    any_sim = any(b.simulated for b in rig.buses.values()) or rig.camera.driver == "simulated"
    clock = make_clock(rig) if any_sim else None
    with open_servos(rig, planner, clock=clock, sim_faults=sim_faults, seed=seed,
                     health_limits=health_limits) as servos:
        if rig.camera.driver == "gphoto2":
            with GPhoto2Camera(rig.camera.port) as real_camera:
                yield RigDevices(rig, servos.motion, real_camera, None, clock, health=servos.health)
            return
        holder = None
        if material is not None:
            holder = SampleHolder(material, white_material(rig))
            holder.sim_attach(rig, clock)  # the lamp follows the device clock (light drift)
        sensor = SensorModel.from_dict(rig.camera.sensor, where=f"{rig.path} [camera.sensor]")
        scene = make_scene(rig, planner.kinematics, servos.true_joints, holder,
                           sensor.superpixel_shape)
        camera = SimCamera(sensor, scene, clock, seed=seed)
        yield RigDevices(rig, servos.motion, camera, holder, clock, health=servos.health)
