"""Servo health before every move: temperature and supply voltage, with a pause (torque on,
nothing moving) until they are back in range."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass

from drivers.dynamixel import (
    Axis,
    ServoBus,
    ServoStatus,
)
from drivers.errors import ConfigError, HardwareError

log = logging.getLogger(__name__)


class ServoHealthError(HardwareError):
    """Servos stayed too hot, or their supply outside its range, for longer than allowed."""


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
