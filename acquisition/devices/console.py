"""The operator's console as a Python API: status, scan, jog, move, home, park, torque, reboot.

``gonio status|scan|jog|move|home|park|torque|reboot`` are thin wrappers over this module, and
scripts use it directly::

    from acquisition.devices.console import open_console
    with open_console("rig.toml") as con:
        print(format_status(con.status()))
        con.jog("camera_phi", 10.0)                  # relative, degrees
        con.move_pose(30.0, 45.0, 180.0)            # θi, θr, Δφ in degrees
        print(format_pose(con.pose()))              # the pose the joints realise
        con.home()                                  # the rig file's [home] (default: park)

Every move goes through the planner's guard (limits, arm collisions, shadow cone) inside the
:class:`~drivers.dynamixel.MotionController`, after a temperature/voltage check that refuses
(rather than waits) by default. Ctrl-C during a move stops all axes (goal := present, torque
stays on) and raises :class:`~drivers.errors.SafetyStop`.

On a rig file whose bus is ``simulated = true`` each :func:`open_console` starts a FRESH
simulator at the park pose with torque on: its servos live only as long as the process, so
``gonio jog`` followed by ``gonio status`` shows the park pose again. This still checks the rig
file, the guard and the driver paths; keep one :class:`Console` open to script a sequence
(``gonio console`` does: one connection for a whole shell session).
On a real rig the console changes nothing when it opens: torque stays as it was (a servo in
hardware error stays readable), and profiles are written just before a move.

A rig with no moving axes (the light stage) has nothing for these verbs: :func:`open_console`
and :func:`scan_rig` refuse it with one :class:`~drivers.errors.ConfigError` line.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping, Sequence
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from pathlib import Path

from acquisition.config.plan import warn_if_radians
from acquisition.config.rig import RigConfig, load_rig
from acquisition.devices.health import HealthLimits
from acquisition.devices.servos import RouteNotice, ServoRig, open_servos, park_joints, park_ticks
from acquisition.geometry.kinematics import Pose
from acquisition.geometry.kinematics.lightstage import LightStage
from acquisition.planning.planner import Planner, Rejection
from acquisition.simworld.servos import check_sim_faults, scaled_clock, start_simulated_buses
from drivers.dynamixel import COMMON_BAUD_RATES, ServoBus
from drivers.dynamixel.codes import HARDWARE_BITS
from drivers.errors import ConfigError, SafetyStop

ALL_IDS = range(253)
"""Every servo ID a scan can find (0–252)."""


@dataclass(frozen=True)
class AxisStatus:
    """One row of ``gonio status``: degrees, °C, V; ``errors`` names latched hardware bits."""

    axis: str
    servo_id: int
    position_deg: float
    goal_deg: float
    moving: bool
    temperature_c: int
    voltage_v: float
    errors: tuple[str, ...]
    torque_on: bool


NO_AXES_VERBS = {
    "status": "report the status of", "scan": "scan", "jog": "jog", "move": "move", "home": "home",
    "park": "park", "torque": "switch torque on or off for", "reboot": "reboot",
    "console": "drive from a console",
}
"""How each verb reads in the refusal of a rig with no moving axes ("nothing to …")."""


def require_moving_axes(rig: RigConfig, verb: str) -> None:
    """Refuse ``verb`` on a rig without servo axes (the light stage), in one line.

    Raises
    ------
    ConfigError
        ``<rig>: the light stage has no moving axes: nothing to <verb>; …``.
    """
    if rig.axes and rig.kinematics_name != LightStage.name:
        return
    what = "the light stage" if rig.kinematics_name == LightStage.name else "the rig"
    raise ConfigError(f"{rig.path}: {what} has no moving axes: nothing to "
                      f"{NO_AXES_VERBS.get(verb, verb)}; its lights are driven by "
                      "gonio lightstage capture")


def home_joints(rig: RigConfig, planner: Planner) -> dict[str, float]:
    """Joints (deg) of the rig's home pose: its ``[home]`` table, else the park pose.

    A pose is realised by the first joint solution within the limits that the guard finds
    safe (as the park pose is).

    Raises
    ------
    ConfigError
        The declared home pose is not safe (arm collision, shadow cone, elevation), named.
    """
    home = rig.home
    if home is None:
        return park_joints(rig, planner)
    problem: Rejection | None = None
    if home.joints_deg is not None:
        joints = dict(home.joints_deg)
        problem = planner.joint_problem(joints)
        if problem is None:
            return joints
        what = "joints " + ", ".join(f"{n} = {v:g}" for n, v in joints.items())
    else:
        assert home.pose_deg is not None  # one of the two forms is set (load_rig)
        kin = planner.kinematics
        for joints in (c for c in kin.inverse_candidates(Pose(*home.pose_deg))
                       if kin.within_limits(c)):
            problem = planner.joint_problem(joints)
            if problem is None:
                return joints
        theta_i, theta_r, delta_phi = home.pose_deg
        what = f"pose θi={theta_i:g}° θr={theta_r:g}° Δφ={delta_phi:g}°"
    why = (f"is not safe ({problem.reason.value}: {problem.detail})" if problem is not None
           else "is outside the joint limits")
    raise ConfigError(f"{rig.path}: [home] {what} {why}: choose a safe home pose")


def error_names(bits: int) -> tuple[str, ...]:
    """Names of the Hardware Error Status bits set in ``bits`` (most serious first)."""
    names = tuple(b.name for b in HARDWARE_BITS if bits & b.mask)
    rest = bits & ~sum(b.mask for b in HARDWARE_BITS)
    return names + ((f"0x{rest:02X}",) if rest else ())


class Console:
    """Operator verbs on an open rig (see :func:`open_console`).

    Parameters
    ----------
    servos:
        The open servo side of the rig.
    health_wait_s:
        How long a move may wait for hot servos / an out-of-range supply (device s); 0 refuses
        at once with a :class:`~acquisition.devices.health.ServoHealthError`.
    """

    def __init__(self, servos: ServoRig, *, health_wait_s: float = 0.0,
                 on_route: RouteNotice | None = None) -> None:
        self.servos = servos
        self.health_wait_s = health_wait_s
        self.on_route = on_route
        """Told the legs (joints, deg) of a routed move before it starts (the CLI prints them)."""
        self.home_deg = home_joints(servos.rig, servos.planner)
        """Joints (deg) of the home pose (see :func:`home_joints`)."""

    @property
    def rig(self) -> RigConfig:
        return self.servos.rig

    @property
    def axis_names(self) -> list[str]:
        return list(self.servos.axes)

    def _axis(self, name: str) -> str:
        if name not in self.servos.axes:
            raise ConfigError(f"{self.rig.path}: no axis '{name}'; the rig has "
                              f"{', '.join(self.servos.axes)}")
        return name

    # ------------------------------------------------------------------ reading
    def status(self) -> list[AxisStatus]:
        """Every axis' position, goal, moving flag, temperature, voltage and errors."""
        rows = []
        for name, s in self.servos.health.read().items():
            axis = self.servos.axes[name]
            rows.append(AxisStatus(
                axis=name, servo_id=axis.servo_id, position_deg=axis.ticks_to_deg(s.position),
                goal_deg=axis.ticks_to_deg(s.goal), moving=s.moving,
                temperature_c=s.temperature_c, voltage_v=s.voltage_v,
                errors=error_names(s.hardware_error), torque_on=s.torque_on,
            ))
        return rows

    def positions(self) -> dict[str, float]:
        """Read-back joints (deg)."""
        return self.servos.motion.positions_deg()

    def pose(self, joints: Mapping[str, float] | None = None) -> Pose:
        """The (θi, θr, Δφ) pose (deg) that ``joints`` (default: the read-back ones) realise."""
        return self.servos.planner.kinematics.forward(self.positions() if joints is None else joints)

    def scan(self, *, bauds: Iterable[int] = COMMON_BAUD_RATES,
             ids: Iterable[int] = ALL_IDS) -> list[ScanResult]:
        """Scan every open bus (each returns to its own baud rate afterwards)."""
        bauds, ids = list(bauds), list(ids)
        if not bauds:
            raise ConfigError("scan: give at least one baud rate")
        return [ScanResult(name, bus.port_name, bus.scan(ids, bauds))
                for name, bus in self.servos.buses.items()]

    # ------------------------------------------------------------------ moves
    def move_joints(self, targets: Mapping[str, float]) -> dict[str, float]:
        """Move the named axes (deg, absolute); the others hold. Returns the read-back joints.

        Raises
        ------
        LimitError, CollisionError
            The guard refused the resulting pose, or no route reaches it; nothing was sent.
            A direct move that is not safe is routed round the other arm; ``on_route`` is told
            the legs first.
        ServoHealthError
            A servo is too hot or its supply out of range.
        ServoHardwareError, TorqueOffError, MotionTimeoutError
            From the servos (all axes stopped).
        SafetyStop
            Ctrl-C during the move (all axes stopped, torque on).
        """
        for name in targets:
            self._axis(name)
        servos = self.servos
        try:
            servos.motion.apply_profiles()
            reached = servos.move_to(targets, health_wait_s=self.health_wait_s,
                                     on_route=self.on_route)
            return {n: reached[n] for n in targets}
        except KeyboardInterrupt:
            servos.motion.stop()
            raise SafetyStop(
                "interrupted: all axes stopped where they were (goal := present), torque on; "
                "`gonio status` shows where"
            ) from None

    def jog(self, axis: str, delta_deg: float) -> dict[str, float]:
        """Move one axis by ``delta_deg`` from where it reads back now (the others hold)."""
        self._axis(axis)
        here = self.servos.motion.positions_deg([axis])[axis]
        return self.move_joints({axis: here + delta_deg})

    def move_pose(self, theta_i: float, theta_r: float, delta_phi: float) -> dict[str, float]:
        """Move every axis to the joints of pose (θi, θr, Δφ) in degrees (nearest solution).

        Angles that all look like radians (within ±2π) warn (:class:`UnitsWarning`) first."""
        warn_if_radians((theta_i, theta_r, delta_phi),
                        f"move θi={theta_i:g} θr={theta_r:g} Δφ={delta_phi:g}",
                        "give degrees (radians × 180/π)")
        joints = self.servos.planner.joints_for(Pose(theta_i, theta_r, delta_phi),
                                                self.positions())
        return self.move_joints(joints)

    def home(self, axes: Sequence[str] | None = None) -> dict[str, float]:
        """Move every axis (routed round the other arm when needed) to the home pose, the rig
        file's ``[home]`` (default: the park pose), or only the named ``axes`` to their home
        joint angles (the others hold; the guard checks the resulting pose)."""
        names = [self._axis(n) for n in axes] if axes else self.axis_names
        return self.move_joints({n: self.home_deg[n] for n in names})

    def park(self) -> dict[str, float]:
        """Move to the park pose (the white-reference pose, where captures start and end)."""
        return self.move_joints(self.servos.park)

    def stop(self) -> dict[str, float]:
        """Stop every axis where it is (goal := present), torque stays on."""
        return self.servos.motion.stop()

    # ------------------------------------------------------------------ servo verbs
    def set_torque(self, on: bool, axes: Sequence[str] | None = None) -> None:
        """Torque on (profiles written first) or off for the named axes (all if None).

        Torque off lets the arms move freely: support them first.
        """
        names = [self._axis(n) for n in axes] if axes else None
        if on:
            self.servos.motion.apply_profiles()
        self.servos.motion.set_torque(on, names)

    def reboot(self, axis: str) -> AxisStatus:
        """REBOOT the axis' servo (clears latched hardware errors whose cause is gone).

        Torque comes back OFF and the motion profile is written again; returns the axis'
        status. Raises the typed hardware error if a bit is still latched.
        """
        self._axis(axis)
        servo = self.servos.axes[axis]
        bus = self.servos.bus_of(axis)
        bus.reboot(servo.servo_id)
        bus.set_profile(servo.servo_id, servo.profile_velocity, servo.profile_acceleration)
        row = next(r for r in self.status() if r.axis == axis)
        if row.errors:
            raise bus.hardware_error_of(servo.servo_id)
        return row


@contextmanager
def open_console(
    rig_path: str | Path,
    *,
    sim_faults: Sequence[str] = (),
    seed: int = 0,
    health_wait_s: float = 0.0,
    health_limits: HealthLimits | None = None,
    verb: str = "move",
) -> Iterator[Console]:
    """Open the rig's servo buses for operator commands (see the module notes on simulation).

    ``verb`` names what the console is opened for, in the refusal of a rig without moving
    axes (see :data:`NO_AXES_VERBS`).

    Raises
    ------
    ConfigError
        Bad rig file (a home pose the guard refuses included), a rig without moving axes, or
        the servos answer at another baud rate than the rig file's (named).
    CommunicationError
        The port does not open, or servos stay silent (their IDs and axes are named).
    """
    rig = load_rig(rig_path)
    require_moving_axes(rig, verb)
    planner = Planner(rig)
    home_joints(rig, planner)  # a home pose the guard refuses is a rig-file error
    simulated = any(b.simulated for b in rig.buses.values())
    with open_servos(rig, planner, sim_faults=sim_faults, seed=seed, prepare=simulated,
                     health_limits=health_limits) as servos:
        yield Console(servos, health_wait_s=health_wait_s)


# ---------------------------------------------------------------------- scan
@dataclass(frozen=True)
class ScanResult:
    """Servos found on one port: ``{baud: {id: model number}}``."""

    bus: str | None
    port: str
    found: dict[int, dict[int, int]]


def scan_port(port: str, *, bauds: Iterable[int] = COMMON_BAUD_RATES,
              ids: Iterable[int] = ALL_IDS, bus_name: str | None = None) -> ScanResult:
    """Ping ``ids`` on ``port`` at each baud rate (broadcast ping when more than 8 IDs).

    Raises
    ------
    CommunicationError
        The port does not open (named, with the fix).
    ConfigError
        A baud rate the SDK cannot set.
    """
    bauds = list(bauds)
    if not bauds:
        raise ConfigError("scan: give at least one baud rate")
    with ServoBus(port, bauds[0], name=bus_name) as bus:
        found = bus.scan(ids, bauds)
    return ScanResult(bus_name, port, found)


def scan_rig(rig_path: str | Path, *, bauds: Iterable[int] = COMMON_BAUD_RATES,
             ids: Iterable[int] = ALL_IDS, sim_faults: Sequence[str] = (), seed: int = 0
             ) -> list[ScanResult]:
    """Scan every bus of a rig file; a simulated bus is started (at its park pose) and scanned.

    Raises ConfigError on a rig without moving axes (the light stage)."""
    rig = load_rig(rig_path)
    require_moving_axes(rig, "scan")
    check_sim_faults(rig, sim_faults)
    bauds, ids = list(bauds), list(ids)
    with ExitStack() as stack:
        sims = {}
        if any(b.simulated for b in rig.buses.values()):
            sims = stack.enter_context(start_simulated_buses(
                rig, scaled_clock(rig), park_ticks(rig, Planner(rig)),
                sim_faults=sim_faults, seed=seed))
        return [
            scan_port(sims[name].port if name in sims else cfg.port, bauds=bauds, ids=ids,
                      bus_name=name)
            for name, cfg in rig.buses.items()
        ]


def format_status(rows: Sequence[AxisStatus]) -> str:
    """The status table as text (one header line, one line per axis)."""
    header = ("axis", "ID", "position °", "goal °", "moving", "temp °C", "voltage V", "torque",
              "errors")
    body = [
        (r.axis, str(r.servo_id), f"{r.position_deg:.2f}", f"{r.goal_deg:.2f}",
         "yes" if r.moving else "no", str(r.temperature_c), f"{r.voltage_v:.1f}",
         "on" if r.torque_on else "off", ", ".join(r.errors) or "-")
        for r in rows
    ]
    widths = [max(len(row[i]) for row in (header, *body)) for i in range(len(header))]
    right = {1, 2, 3, 5, 6}

    def line(cells: Sequence[str]) -> str:
        return "  ".join(c.rjust(w) if i in right else c.ljust(w)
                         for i, (c, w) in enumerate(zip(cells, widths, strict=True))).rstrip()

    return "\n".join(line(r) for r in (header, *body))


def format_pose(pose: Pose) -> str:
    """One line: the (θi, θr, Δφ) the read-back joints realise (Δφ is undefined, and shown
    so, when the light or the camera is at the sample normal)."""
    normal = min(pose.theta_i, pose.theta_r) < POSE_NORMAL_DEG
    delta_phi = "- (a direction is at the normal)" if normal else f"{pose.delta_phi:.2f}°"
    return f"pose: θi {pose.theta_i:.2f}°  θr {pose.theta_r:.2f}°  Δφ {delta_phi}"


POSE_NORMAL_DEG = 0.01
"""Below this θi or θr (deg) a direction is at the normal and Δφ means nothing."""


def pose_fields(pose: Pose) -> dict[str, float | None]:
    """The pose as ``{"theta_i_deg", "theta_r_deg", "delta_phi_deg"}`` (Δφ None when the light
    or the camera is at the normal)."""
    normal = min(pose.theta_i, pose.theta_r) < POSE_NORMAL_DEG
    return {"theta_i_deg": pose.theta_i, "theta_r_deg": pose.theta_r,
            "delta_phi_deg": None if normal else pose.delta_phi}


def format_joints(joints: Mapping[str, float], digits: int = 1) -> str:
    """``light_theta 33.0° camera_theta 50.0° …``."""
    return " ".join(f"{name} {deg:.{digits}f}°" for name, deg in joints.items())


def format_route(legs: Sequence[Mapping[str, float]]) -> str:
    """One line for a routed move: ``route: 3 legs via A → B → target``."""
    via = " → ".join(format_joints(leg) for leg in legs[:-1])
    return f"route: {len(legs)} legs via {via} → {format_joints(legs[-1])}"


def format_scan(results: Sequence[ScanResult]) -> str:
    """Scan results as text: one line per port and baud rate where servos answered."""
    lines = []
    for res in results:
        where = f"bus '{res.bus}' ({res.port})" if res.bus else res.port
        if not res.found:
            lines.append(f"{where}: no servo answered")
        for baud, hits in res.found.items():
            servos = ", ".join(f"ID {i} (model {m})" for i, m in sorted(hits.items()))
            lines.append(f"{where} at {baud} baud: {servos}")
    return "\n".join(lines)

