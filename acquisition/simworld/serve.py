"""Simulated devices served in the foreground (``gonio sim``), for any client to open.

Each serves until SIGINT or SIGTERM and reports its device path (a pseudo-terminal) first.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TextIO

from drivers.errors import ConfigError


def serve_servos(ids: Sequence[int], baud: int = 57600, time_scale: float = 1.0,
                 faults: Sequence[str] = (), seed: int = 0) -> int:
    """A bare Dynamixel Protocol 2.0 bus of X-series servos with ``ids``; returns 0 on exit."""
    from simulators.dynamixel import serve_servos_forever

    if time_scale <= 0:
        raise ConfigError(f"--time-scale must be > 0, got {time_scale}")
    return serve_servos_forever(list(ids), baud, time_scale, list(faults), seed)


def serve_dmx(out: TextIO, err: TextIO) -> int:
    """An Enttec DMX USB Pro compatible widget; its path is the first line of ``out``, its
summary goes to ``err`` on exit."""
    from simulators.dmx import serve_dmx_forever

    return serve_dmx_forever(out=out, err=err)
