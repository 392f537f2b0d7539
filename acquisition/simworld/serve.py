"""Simulated devices served in the foreground (``gonio sim``), for any client to open.

Each serves until SIGINT or SIGTERM and calls ``ready`` with its device path(s) (pseudo-
terminals) first, so the caller announces them.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TextIO

from drivers.errors import ConfigError

Ready = Callable[[list[str]], None]
"""Called once the device paths exist (one per bus, in the rig file's order)."""


def _check_time_scale(time_scale: float) -> None:
    if time_scale <= 0:
        raise ConfigError(f"--time-scale must be > 0, got {time_scale}")


def serve_servos(ids: Sequence[int], baud: int = 57600, time_scale: float = 1.0,
                 faults: Sequence[str] = (), seed: int = 0, *,
                 ready: Ready) -> int:
    """A bare Dynamixel Protocol 2.0 bus of X-series servos with ``ids``; returns 0 on exit."""
    from simulators.dynamixel import serve_servos_forever

    _check_time_scale(time_scale)
    return serve_servos_forever(list(ids), baud, time_scale, list(faults), seed,
                                ready=lambda bus: ready([bus.port]))


def serve_rig(rig_path: str | Path, time_scale: float = 1.0, faults: Sequence[str] = (),
              seed: int = 0, *, ready: Ready, stall_trip_s: float = 1.0) -> int:
    """A rig file's servos (IDs, baud, limits, park pose) with its solid parts: arms that touch
    stall, and after ``stall_trip_s`` (device s) trip on overload, as an XM430 does."""
    from acquisition.config.rig import load_rig
    from simulators.dynamixel import serve_rig_forever

    _check_time_scale(time_scale)
    rig = load_rig(rig_path)  # the rig file is checked by gonio's own parser first
    return serve_rig_forever(rig.raw, time_scale, list(faults), seed,
                             ready=lambda sim: ready(list(sim.ports.values())),
                             stall_trip_s=stall_trip_s)


def serve_dmx(out: TextIO, err: TextIO) -> int:
    """An Enttec DMX USB Pro compatible widget; its path is the first line of ``out``, its
    summary goes to ``err`` on exit."""
    from simulators.dmx import serve_dmx_forever

    return serve_dmx_forever(out=out, err=err)
