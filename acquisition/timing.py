"""Time model of Dynamixel X-series moves (trapezoidal velocity profile) and of a capture step.

X-series units: profile velocity in 0.229 rev/min, profile acceleration in 214.577 rev/min².
A move of one axis accelerates at ``a`` up to ``v``, cruises, and decelerates; a short move
never reaches ``v`` (triangular profile). A move of several axes takes as long as its slowest.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

VELOCITY_UNIT_DEG_PER_S = 0.229 * 360.0 / 60.0
"""One profile-velocity unit in degrees per second (0.229 rev/min)."""

ACCELERATION_UNIT_DEG_PER_S2 = 214.577 * 360.0 / 3600.0
"""One profile-acceleration unit in degrees per second² (214.577 rev/min²)."""


def trapezoid_time_s(distance_deg: float, velocity_deg_s: float, accel_deg_s2: float) -> float:
    """Seconds to travel ``distance_deg`` from rest to rest under a trapezoidal profile."""
    d = abs(distance_deg)
    if d == 0.0:
        return 0.0
    if d >= velocity_deg_s**2 / accel_deg_s2:
        return d / velocity_deg_s + velocity_deg_s / accel_deg_s2
    return 2.0 * math.sqrt(d / accel_deg_s2)


@dataclass(frozen=True)
class AxisProfile:
    """Speed limits of one axis in physical units."""

    velocity_deg_s: float
    accel_deg_s2: float

    @classmethod
    def from_xseries(cls, profile_velocity: int, profile_acceleration: int) -> AxisProfile:
        return cls(
            profile_velocity * VELOCITY_UNIT_DEG_PER_S,
            profile_acceleration * ACCELERATION_UNIT_DEG_PER_S2,
        )


@dataclass(frozen=True)
class StepCosts:
    """Fixed per-pose costs in seconds, added to the motion time."""

    settle_s: float = 0.05
    bus_cycle_s: float = 0.005
    exposure_s: float = 0.01


class TimeModel:
    """Move and step durations for a set of axes (degrees, seconds)."""

    def __init__(self, profiles: Mapping[str, AxisProfile], costs: StepCosts) -> None:
        self.profiles = dict(profiles)
        self.costs = costs

    def move_s(self, a: Mapping[str, float], b: Mapping[str, float]) -> float:
        """Duration of the move from joints ``a`` to ``b``: the slowest axis's trapezoid."""
        longest = 0.0
        for name, prof in self.profiles.items():
            if name in a and name in b:
                t = trapezoid_time_s(b[name] - a[name], prof.velocity_deg_s, prof.accel_deg_s2)
                longest = max(longest, t)
        return longest

    def step_overhead_s(self) -> float:
        """Per-pose time that is not motion: settle, bus traffic, exposure."""
        c = self.costs
        return c.settle_s + c.bus_cycle_s + c.exposure_s
