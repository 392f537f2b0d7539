"""Serve simulated servo buses in the foreground until SIGINT or SIGTERM (``gonio sim servos``).

:func:`serve_servos_forever` runs a bare bus (``--ids``); :func:`serve_rig_forever` a rig file's
servos with its solid parts (``--rig``). Both call ``ready`` once the ptys exist, so the caller
(the CLI) announces them (``gonio sim servos`` prints each path as one line on stdout, first,
the contract scripts rely on). The banner goes to this module's logger (INFO). Both must run
in the main thread (signals).
"""

from __future__ import annotations

import logging
import signal
import threading
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from typing import Any

from simulators.clock import SimClock
from simulators.dynamixel.bus import SimServoBus
from simulators.dynamixel.faults import Fault
from simulators.dynamixel.rig import RigSource, SimRig

logger = logging.getLogger(__name__)


@contextmanager
def _until_signalled() -> Iterator[threading.Event]:
    stop = threading.Event()

    def _handler(signum: int, frame: object) -> None:
        stop.set()

    previous = {sig: signal.signal(sig, _handler) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield stop
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def serve_servos_forever(
    ids: Iterable[int],
    baud: int = 57600,
    time_scale: float = 1.0,
    faults: Iterable[str | Fault] = (),
    seed: int = 0,
    *,
    ready: Callable[[SimServoBus], None],
) -> int:
    """Run a bare simulated bus until SIGINT or SIGTERM; return 0.

    ``ready(bus)`` is called once the pty exists (``bus.port`` is its path).
    """
    with _until_signalled() as stop, SimServoBus(
            ids, baud=baud, clock=SimClock(time_scale), faults=faults, seed=seed,
            strict_fault_ids=True) as bus:
        ready(bus)
        logger.info("simulating XM430-W350 servos %s at %d baud on %s (time scale %g); "
                    "Ctrl-C to stop", sorted(bus.servos), baud, bus.port, time_scale)
        while not stop.is_set():
            stop.wait()
    return 0


def serve_rig_forever(
    rig: RigSource,
    time_scale: float = 1.0,
    faults: Iterable[str | Fault] = (),
    seed: int = 0,
    *,
    ready: Callable[[SimRig], None],
    **options: Any,
) -> int:
    """Run a rig file's servos with its solid parts until SIGINT or SIGTERM; return 0.

    ``ready(sim_rig)`` is called once the ptys exist (``sim_rig.ports``: one path per bus, in
    the rig file's bus order). ``options`` go to :class:`SimRig` (``stall_trip_s``, ...).
    """
    with _until_signalled() as stop, SimRig(rig, clock=SimClock(time_scale), faults=faults,
                                            seed=seed, **options) as sim:
        ready(sim)
        for name, bus in sim.buses.items():
            logger.info("bus '%s': servos %s at %d baud on %s", name, sorted(bus.servos),
                        bus.baud, bus.port)
        logger.info("solid parts: %s; time scale %g; Ctrl-C to stop",
                    "simulated" if sim.world else "none", time_scale)
        while not stop.is_set():
            stop.wait()
    return 0
