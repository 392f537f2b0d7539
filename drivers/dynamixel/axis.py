"""One rotary axis driven by one servo: degrees ↔ ticks, soft limits, motion profile."""

from __future__ import annotations

import math
from dataclasses import KW_ONLY, dataclass

from drivers.errors import ConfigError, LimitError

#: deg/s per Profile Velocity unit (0.229 rev/min).
DPS_PER_VELOCITY_UNIT = 0.229 * 360.0 / 60.0
#: deg/s² per Profile Acceleration unit (214.577 rev/min²).
DPS2_PER_ACCELERATION_UNIT = 214.577 * 360.0 / 3600.0
#: X-series default Velocity Limit (address 44), used when Profile Velocity is 0.
DEFAULT_VELOCITY_LIMIT = 200
_EPS_DEG = 1e-9


@dataclass(frozen=True)
class Axis:
    """A joint of the rig: ``deg = direction × (ticks − zero_tick) × 360 / ticks_per_rev``.

    Parameters
    ----------
    name:
        Axis name used in messages (``theta_i``).
    servo_id:
        ID of the servo on its bus (0–252).
    min_deg, max_deg:
        Soft limits (deg). :meth:`deg_to_ticks` refuses anything outside them.
    zero_tick:
        Present Position (ticks) at 0°.
    direction:
        +1 if degrees grow with ticks, −1 otherwise.
    ticks_per_rev:
        Encoder resolution (4096 for the X-series).
    profile_velocity:
        Profile Velocity register value (0.229 rev/min units; 0 = the servo's Velocity Limit).
    profile_acceleration:
        Profile Acceleration register value (214.577 rev/min² units; 0 = infinite).
    """

    name: str
    servo_id: int
    _: KW_ONLY
    min_deg: float
    max_deg: float
    zero_tick: int = 2048
    direction: int = 1
    ticks_per_rev: int = 4096
    profile_velocity: int = 0
    profile_acceleration: int = 0

    def __post_init__(self) -> None:
        where = f"axis '{self.name}'"
        if not 0 <= self.servo_id <= 252:
            raise ConfigError(f"{where}: servo ID {self.servo_id} is outside 0..252")
        if self.direction not in (1, -1):
            raise ConfigError(f"{where}: direction must be +1 or -1, got {self.direction}")
        if not (math.isfinite(self.min_deg) and math.isfinite(self.max_deg)
                and self.min_deg < self.max_deg):
            raise ConfigError(f"{where}: limits must satisfy min_deg < max_deg, got "
                              f"[{self.min_deg}, {self.max_deg}]")
        if self.ticks_per_rev <= 0:
            raise ConfigError(f"{where}: ticks_per_rev must be > 0")
        for value, what in ((self.profile_velocity, "profile_velocity"),
                            (self.profile_acceleration, "profile_acceleration")):
            if not 0 <= value <= 32767:
                raise ConfigError(f"{where}: {what} {value} is outside 0..32767 (X-series units)")
        ends = sorted(self._raw_ticks(d) for d in (self.min_deg, self.max_deg))
        if ends[0] < 0 or ends[1] > self.ticks_per_rev - 1:
            raise ConfigError(
                f"{where}: limits [{self.min_deg}, {self.max_deg}]° map to ticks "
                f"{ends[0]}..{ends[1]}, outside the servo's 0..{self.ticks_per_rev - 1}; "
                f"adjust zero_tick or the limits"
            )

    @property
    def deg_per_tick(self) -> float:
        """Degrees per encoder tick."""
        return 360.0 / self.ticks_per_rev

    def _raw_ticks(self, deg: float) -> int:
        return round(self.zero_tick + self.direction * deg / self.deg_per_tick)

    def within(self, deg: float) -> bool:
        """True if ``deg`` lies inside the soft limits."""
        return self.min_deg - _EPS_DEG <= deg <= self.max_deg + _EPS_DEG

    def deg_to_ticks(self, deg: float) -> int:
        """Goal ticks for ``deg``; :class:`LimitError` outside the soft limits (nothing sent)."""
        if not self.within(deg):
            raise LimitError(
                f"axis '{self.name}': {deg:.3f}° is outside its limits "
                f"[{self.min_deg:g}, {self.max_deg:g}]°; nothing was sent"
            )
        return self._raw_ticks(deg)

    def ticks_to_deg(self, ticks: float) -> float:
        """Degrees for ``ticks`` (no limit check: a read-back may lie anywhere)."""
        return self.direction * (ticks - self.zero_tick) * self.deg_per_tick

    @property
    def velocity_dps(self) -> float:
        """Cruise speed (deg/s) the servo will use."""
        units = self.profile_velocity or DEFAULT_VELOCITY_LIMIT
        return units * DPS_PER_VELOCITY_UNIT

    @property
    def acceleration_dps2(self) -> float:
        """Acceleration (deg/s²); ``inf`` when the profile acceleration is 0."""
        if self.profile_acceleration == 0:
            return math.inf
        return self.profile_acceleration * DPS2_PER_ACCELERATION_UNIT

    def move_time_s(self, delta_deg: float) -> float:
        """Duration (s) of a move of ``|delta_deg|`` from rest to rest (trapezoid/triangle)."""
        d, v, a = abs(delta_deg), self.velocity_dps, self.acceleration_dps2
        if d == 0:
            return 0.0
        if math.isinf(a):
            return d / v
        if d >= v * v / a:  # room to reach cruise speed
            return d / v + v / a
        return 2.0 * math.sqrt(d / a)
