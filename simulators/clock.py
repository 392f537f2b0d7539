"""The simulated clocks shared by every simulated device of one rig.

Two kinds, one interface (``now()``, ``advance(s)``, ``sleep(s)``, ``frozen()``,
``time_scale``):

* :class:`SimClock` runs ``time_scale`` times faster than the host's monotonic clock, so a
  simulator that external programs talk to (``gonio sim servos``, an operator's console) moves
  in something like real time. Devices may jump it forward (an exposure of 2 s) and freeze it
  while they compute (rendering a frame), but host work nobody froze shows up as simulated
  time, scaled up.
* :class:`SteppedClock` is discrete-event: time moves only when a device waits (``sleep``) or
  spends time on purpose (``advance``: an exposure, a packet's time on the wire), never while
  the host computes. A run's simulated time is then the hardware timeline (motion, polling,
  wire time, settle, exposure) whatever the host's load, and ``sleep`` costs no host time.
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

    follows_host = True
    """Simulated time advances with host time (timeouts may be measured on the host clock)."""

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


class SteppedClock(SimClock):
    """Discrete-event simulated time: moves only in ``sleep`` and ``advance``.

    Drop-in for :class:`SimClock`: ``sleep(s)`` advances the clock by ``s`` and returns at
    once (after yielding the GIL, so simulator threads run), ``frozen()`` is a no-op (nothing
    else moves the clock) and ``time_scale`` is reported as 1.0 for compatibility (the real
    ratio is unbounded). Thread-safe: concurrent advances add up.
    """

    follows_host = False

    def __init__(self, start_s: float = 0.0) -> None:
        super().__init__(1.0)
        if start_s < 0:
            raise ValueError(f"a clock cannot start before 0 s (got {start_s} s)")
        self._t = float(start_s)

    def now(self) -> float:
        """Simulated seconds since the clock was made (plus ``start_s``)."""
        with self._lock:
            return self._t

    def advance(self, seconds: float) -> None:
        """Move simulated time forward by ``seconds`` (≥ 0)."""
        if seconds < 0:
            raise ValueError(f"cannot advance the clock by a negative time ({seconds} s)")
        with self._lock:
            self._t += seconds

    def sleep(self, sim_seconds: float) -> None:
        """Advance by ``sim_seconds`` (nothing for ≤ 0) and yield the GIL once."""
        if sim_seconds > 0:
            self.advance(sim_seconds)
        time.sleep(0)

    @contextmanager
    def frozen(self) -> Iterator[None]:
        """No-op: host work never moves a stepped clock."""
        yield
