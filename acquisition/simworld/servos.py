"""Simulated servo buses for a rig: the device clock and one in-process Dynamixel simulator per
``simulated = true`` bus, on a pseudo-terminal the driver opens like a USB adapter."""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager

from acquisition.config.rig import RigConfig
from acquisition.geometry.kinematics.lightstage import LightStage
from drivers.errors import ConfigError
from simulators.clock import SimClock, SteppedClock
from simulators.dynamixel import SimServoBus
from simulators.dynamixel.faults import Fault, parse_faults
from simulators.dynamixel.rig import SimRig


def check_sim_faults(rig: RigConfig, specs: Sequence[str | Fault]) -> list[Fault]:
    """Parse ``--sim-fault`` specs against ``rig`` before anything is created or sent.

    Raises
    ------
    ConfigError
        A malformed spec (the syntax is shown), a rig with no simulated servo bus (the faults
        would be ignored), or a fault naming a servo ID no simulated bus has.
    """
    if not specs:
        return []
    faults = parse_faults(specs)
    simulated = {n for n, b in rig.buses.items() if b.simulated}
    if not simulated:
        what = ("a light stage has no servo bus" if rig.kinematics_name == LightStage.name
                else "its [buses] are real hardware")
        raise ConfigError(f"{rig.path}: --sim-fault {specs[0]} needs a simulated servo bus and "
                          f"this rig has none ({what}): drop --sim-fault")
    ids = sorted({a.servo_id for a in rig.axes.values() if a.bus in simulated})
    for fault in faults:
        if fault.servo_id is not None and fault.servo_id not in ids:
            raise ConfigError(f"{rig.path}: --sim-fault {fault} names servo ID {fault.servo_id}, "
                              f"which no simulated bus has: use one of IDs "
                              f"{', '.join(map(str, ids))}")
    return faults


def make_clock(rig: RigConfig) -> SimClock:
    """The device clock of a simulated rig: ``[simulation] clock`` (default ``"stepped"``).

    A :class:`SteppedClock` moves only when a device waits or spends time on purpose, and the
    servo simulators then charge each packet its time on the wire (``wire_time="clock"``),
    so a run's rig time is motion + polling + wire time + settle + exposure, independent of the
    host's load. ``"scaled"`` runs at ``time_scale`` × host time (external clients).
    """
    return SteppedClock() if rig.sim_clock == "stepped" else SimClock(rig.time_scale)


def scaled_clock(rig: RigConfig) -> SimClock:
    """A clock running at the rig's ``time_scale`` × host time (for external clients, whose
    timeouts are measured on the host's clock)."""
    return SimClock(rig.time_scale)


@contextmanager
def start_simulated_rig(
    rig: RigConfig,
    clock: SimClock,
    start_ticks: Mapping[str, float],
    *,
    sim_faults: Sequence[str] = (),
    seed: int = 0,
) -> Iterator[SimRig | None]:
    """Start a simulator for every ``simulated = true`` bus, each servo at ``start_ticks[axis]``,
    with the rig's solid parts: arms that touch stall and trip on overload, as hardware would
    (:class:`simulators.dynamixel.rig.SimRig`, its own model of the arms), and its gears: the
    arms stand where ``[simulation.errors]`` puts them (zero offsets, backlash, position noise,
    seeded by ``seed``), not where the ticks say. None when no bus is simulated.

    The servos are deaf at any other baud rate than the rig file's (``strict_baud``), like a
    real bus, so ``gonio scan`` finds them at that rate only. Collisions are recorded on the
    buses (``SimServoBus.sim_collisions()``).
    """
    names = [n for n, b in rig.buses.items() if b.simulated]
    if not names:
        yield None
        return
    with SimRig(rig.raw, clock=clock, faults=list(sim_faults), seed=seed, strict_baud=True,
                wire_time="auto",  # on the stepped clock: charged to it
                positions_ticks={a: start_ticks[a] for a, cfg in rig.axes.items()
                                 if cfg.bus in names},
                buses=names) as sim_rig:
        yield sim_rig


@contextmanager
def start_simulated_buses(
    rig: RigConfig,
    clock: SimClock,
    start_ticks: Mapping[str, float],
    *,
    sim_faults: Sequence[str] = (),
    seed: int = 0,
) -> Iterator[dict[str, SimServoBus]]:
    """:func:`start_simulated_rig`'s buses, ``{bus name: SimServoBus}`` (empty when none)."""
    with start_simulated_rig(rig, clock, start_ticks, sim_faults=sim_faults,
                             seed=seed) as sim_rig:
        yield {} if sim_rig is None else dict(sim_rig.buses)
