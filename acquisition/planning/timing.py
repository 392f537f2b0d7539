"""Time model of Dynamixel X-series moves (trapezoidal velocity profile) and of a capture step.

X-series units: profile velocity in 0.229 rev/min, profile acceleration in 214.577 rev/min².
A move of one axis accelerates at ``a`` up to ``v``, cruises, and decelerates; a short move
never reaches ``v`` (triangular profile). All axes start together and each runs its own
profile, so a move of several axes takes as long as its slowest axis.

A capture step costs, besides the move: the settle time, the bus cycle (commands and the
position polls that confirm arrival) and the exposure. :class:`TimeModel` works on joint
dicts (the engine's progress ETA) and on (…, J) joint arrays (the planner).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

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


def trapezoid_time_array(distance_deg: np.ndarray, velocity_deg_s: np.ndarray,
                         accel_deg_s2: np.ndarray) -> np.ndarray:
    """:func:`trapezoid_time_s` for arrays (broadcast), seconds."""
    d = np.abs(distance_deg)
    v, a = velocity_deg_s, accel_deg_s2
    return np.where(d >= v * v / a, d / v + v / a, 2.0 * np.sqrt(d / a))


def trapezoid_progress_deg(distance_deg: np.ndarray, velocity_deg_s: np.ndarray,
                           accel_deg_s2: np.ndarray, t_s: np.ndarray) -> np.ndarray:
    """Signed distance covered after ``t_s`` seconds of a rest-to-rest move (broadcast)."""
    d = np.abs(distance_deg)
    v, a = velocity_deg_s, accel_deg_s2
    vp = np.minimum(v, np.sqrt(a * d))  # peak speed (triangle when the move is short)
    t_acc = vp / a
    total = trapezoid_time_array(d, v, a)
    t = np.clip(t_s, 0.0, total)
    t_dec = total - t  # time left
    s = np.where(
        t <= t_acc, 0.5 * a * t * t,
        np.where(t_dec <= t_acc, d - 0.5 * a * t_dec * t_dec, 0.5 * a * t_acc * t_acc + vp * (t - t_acc)),
    )
    return np.sign(distance_deg) * s


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
    bus_cycle_s: float = 0.03
    """Bus time of one move: the commands, and the position polls that confirm arrival."""
    leg_bus_s: float = 0.03
    """Bus time of each further leg of a routed or approached move (no health read)."""
    exposure_s: float = 0.01


class TimeModel:
    """Move and step durations for a set of axes (degrees, seconds).

    Parameters
    ----------
    profiles:
        Axis name → speed limits. Joints without a profile (a light stage's light index, a
        joint no servo drives) take no time to change.
    costs:
        Per-step settle, bus and exposure times.
    """

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

    def for_joints(self, joint_names: Sequence[str]) -> ArrayTimeModel:
        """The vectorised model over joint arrays in ``joint_names`` order."""
        return ArrayTimeModel(self, tuple(joint_names))


class ArrayTimeModel:
    """Move times between joint arrays (…, J) in a fixed joint order; see :class:`TimeModel`."""

    def __init__(self, model: TimeModel, joint_names: tuple[str, ...]) -> None:
        self.joint_names = joint_names
        self.axes = np.array([i for i, n in enumerate(joint_names) if n in model.profiles], dtype=int)
        self.velocity = np.array([model.profiles[joint_names[i]].velocity_deg_s for i in self.axes])
        self.accel = np.array([model.profiles[joint_names[i]].accel_deg_s2 for i in self.axes])
        self._reach_v = self.velocity**2 / self.accel  # distance at which v is reached
        self._four_over_a = 4.0 / self.accel
        self._inv_v = 1.0 / self.velocity

    def reach_deg(self, t_s: np.ndarray) -> np.ndarray:
        """Farthest travel (…, J) in degrees each joint can make in ``t_s`` seconds (…);
        infinite for joints that take no time."""
        t = np.asarray(t_s, dtype=float)[..., None]
        out = np.full(t.shape[:-1] + (len(self.joint_names),), np.inf)
        v, a = self.velocity, self.accel
        out[..., self.axes] = np.where(t >= 2 * v / a, v * (t - v / a), a * t * t / 4.0)
        return out

    def move_s(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Durations (…) of the moves a → b (broadcast), seconds; NaN where a joint is NaN.

        Per axis the trapezoid is written without branches: with c = v²/a the distance at
        which the profile reaches v, t = 2·√(min(d, c)/a) + max(d − c, 0)/v.
        """
        if a.size + b.size < 50_000:  # small: one expression over the axis dimension
            if len(self.axes) == 0:
                return np.zeros(np.broadcast_shapes(a.shape, b.shape)[:-1])
            d = np.abs(b[..., self.axes] - a[..., self.axes])
            t = np.sqrt(np.minimum(d, self._reach_v) * self._four_over_a)
            t += np.maximum(d - self._reach_v, 0.0) * self._inv_v
            return t.max(axis=-1)
        shape = np.broadcast_shapes(a.shape, b.shape)[:-1]
        dtype = np.result_type(a.dtype, b.dtype, np.float32)
        out = np.zeros(shape, dtype)
        work = np.empty(shape, dtype)
        tmp = np.empty(shape, dtype)
        for k, j in enumerate(self.axes):  # one axis at a time: no reduction over a short axis
            v, acc = self.velocity[k], self.accel[k]
            c = v * v / acc
            np.subtract(b[..., j], a[..., j], out=work)
            np.abs(work, out=work)
            np.minimum(work, c, out=tmp)
            tmp *= 4.0 / acc
            np.sqrt(tmp, out=tmp)
            work -= c
            np.maximum(work, 0.0, out=work)
            work *= 1.0 / v
            work += tmp
            np.fmax(out, work, out=out)
        if len(self.axes):
            nan_a = np.isnan(a[..., self.axes]).any(-1)
            nan_b = np.isnan(b[..., self.axes]).any(-1)
            if nan_a.any() or nan_b.any():
                out = np.where(nan_a | nan_b, np.nan, out)
        return out

    def positions(self, a: np.ndarray, b: np.ndarray, t_s: np.ndarray) -> np.ndarray:
        """Joints (…, J) at ``t_s`` seconds into the moves a → b (all axes start together)."""
        out = np.array(np.broadcast_to(b, np.broadcast_shapes(a.shape, b.shape)), dtype=float)
        if len(self.axes):
            d = b[..., self.axes] - a[..., self.axes]
            out[..., self.axes] = a[..., self.axes] + trapezoid_progress_deg(
                d, self.velocity, self.accel, np.asarray(t_s)[..., None]
            )
        return out
