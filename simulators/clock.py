"""The simulated clock shared by every simulated device of one rig.

Simulated time runs ``time_scale`` times faster than the host's monotonic clock, so a sweep
that takes an hour on hardware takes minutes on the simulator. Devices may also jump it
forward (an exposure of 2 s) and freeze it while they compute (rendering a frame), so that
host-side work does not show up as simulated time.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager


class SimClock:
    """Simulated seconds, ``time_scale`` × host seconds, plus explicit jumps.

    Parameters
    ----------
    time_scale:
        Simulated seconds per host second (1.0 = real time, 20.0 = twenty times faster).
    """

    def __init__(self, time_scale: float = 1.0) -> None:
        if not time_scale > 0:
            raise ValueError(f"time_scale must be > 0, got {time_scale}")
        self._lock = threading.Lock()
        self._time_scale = float(time_scale)
        self._host_origin = time.monotonic()
        self._sim_origin = 0.0
        self._frozen_depth = 0

    @property
    def time_scale(self) -> float:
        """Simulated seconds per host second."""
        return self._time_scale

    def now(self) -> float:
        """Simulated seconds since the clock was made."""
        with self._lock:
            return self._now_locked()

    def _now_locked(self) -> float:
        if self._frozen_depth:
            return self._sim_origin
        return self._sim_origin + (time.monotonic() - self._host_origin) * self._time_scale

    def advance(self, seconds: float) -> None:
        """Jump simulated time forward by ``seconds`` (≥ 0), e.g. for an exposure."""
        if seconds < 0:
            raise ValueError(f"cannot advance the clock by a negative time ({seconds} s)")
        with self._lock:
            self._sim_origin = self._now_locked() + seconds
            self._host_origin = time.monotonic()

    @contextmanager
    def frozen(self) -> Iterator[None]:
        """Stop simulated time inside the block (host-side computation costs no sim time)."""
        with self._lock:
            if self._frozen_depth == 0:
                self._sim_origin = self._now_locked()
            self._frozen_depth += 1
        try:
            yield
        finally:
            with self._lock:
                self._frozen_depth -= 1
                if self._frozen_depth == 0:
                    self._host_origin = time.monotonic()

    def sleep(self, sim_seconds: float) -> None:
        """Sleep until ``sim_seconds`` of simulated time have passed."""
        if sim_seconds > 0:
            time.sleep(sim_seconds / self._time_scale)
