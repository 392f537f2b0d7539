"""Trapezoidal motion profiles of the X-series, as piecewise constant-acceleration segments.

The X-series velocity-based profile (drive mode bit 2 = 0) accelerates at Profile Acceleration
up to Profile Velocity, cruises, and decelerates to stop at the goal: a trapezoid, or a triangle
when the move is too short to reach the velocity. Acceleration 0 means infinite acceleration (a
rectangular velocity profile). Profile Velocity 0 means "no profile limit": the servo then runs
at its Velocity Limit (address 44), which is what a real motor does. The time-based profile
(drive mode bit 2 = 1) reads Profile Velocity as the total time and Profile Acceleration as the
acceleration time, both in ms.

Units inside this module: ticks, seconds, ticks/s, ticks/s².
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from simulators.dynamixel.control_table import (
    ACCELERATION_UNIT_RPM2,
    TICKS_PER_REV,
    VELOCITY_UNIT_RPM,
)

#: ticks/s per Profile Velocity unit (0.229 rev/min).
TICKS_PER_S_PER_VELOCITY_UNIT = VELOCITY_UNIT_RPM * TICKS_PER_REV / 60.0
#: ticks/s² per Profile Acceleration unit (214.577 rev/min²).
TICKS_PER_S2_PER_ACCELERATION_UNIT = ACCELERATION_UNIT_RPM2 * TICKS_PER_REV / 3600.0


@dataclass(frozen=True)
class Segment:
    """Constant acceleration from ``t0`` for ``duration`` s, starting at ``p0`` with ``v0``."""

    t0: float
    duration: float
    p0: float
    v0: float
    a: float

    @property
    def t1(self) -> float:
        """End time (s)."""
        return self.t0 + self.duration

    def position(self, t: float) -> float:
        """Position (ticks) at time ``t`` within the segment."""
        tau = t - self.t0
        return self.p0 + self.v0 * tau + 0.5 * self.a * tau * tau

    def velocity(self, t: float) -> float:
        """Velocity (ticks/s) at time ``t`` within the segment."""
        return self.v0 + self.a * (t - self.t0)


@dataclass(frozen=True)
class Trajectory:
    """A planned move: segments back to back, ending at rest at ``target``."""

    segments: tuple[Segment, ...]
    target: float

    @property
    def start(self) -> float:
        """Start time (s)."""
        return self.segments[0].t0 if self.segments else math.inf

    @property
    def end(self) -> float:
        """Time (s) at which the servo is at rest at the target."""
        return self.segments[-1].t1 if self.segments else -math.inf

    def state(self, t: float) -> tuple[float, float]:
        """(position ticks, velocity ticks/s) at time ``t``."""
        segs = self.segments
        if not segs or t >= segs[-1].t1:
            return self.target, 0.0
        if t <= segs[0].t0:
            return segs[0].p0, segs[0].v0
        for seg in segs:
            if t < seg.t1:
                return seg.position(t), seg.velocity(t)
        return self.target, 0.0  # pragma: no cover

    def first_crossing(self, bound: float) -> float | None:
        """Earliest time at which the position reaches ``bound``, or None."""
        for seg in self.segments:
            if seg.duration <= 0:
                continue
            c = seg.p0 - bound
            if c == 0:
                return seg.t0
            a, b = 0.5 * seg.a, seg.v0
            roots: list[float] = []
            if abs(a) < 1e-12:
                if b != 0:
                    roots.append(-c / b)
            else:
                disc = b * b - 4 * a * c
                if disc >= 0:
                    sq = math.sqrt(disc)
                    roots += [(-b - sq) / (2 * a), (-b + sq) / (2 * a)]
            hits = [r for r in roots if 0 <= r <= seg.duration]
            if hits:
                return seg.t0 + min(hits)
        return None


def plan(t0: float, p0: float, v0: float, target: float, vmax: float, amax: float) -> Trajectory:
    """Time-optimal move from (``p0``, ``v0``) at ``t0`` to rest at ``target``.

    Parameters
    ----------
    vmax:
        Cruise speed (ticks/s, > 0; ``math.inf`` for an instantaneous jump).
    amax:
        Acceleration (ticks/s², > 0; ``math.inf`` for a rectangular velocity profile).
    """
    if math.isinf(vmax):
        return Trajectory((), target)
    segs: list[Segment] = []
    t, p, v = t0, p0, v0

    def push(duration: float, a: float) -> None:
        nonlocal t, p, v
        if duration <= 0:
            return
        seg = Segment(t, duration, p, v, a)
        segs.append(seg)
        t, p, v = seg.t1, seg.position(seg.t1), seg.velocity(seg.t1)

    if math.isinf(amax):
        dist = target - p0
        if dist:
            segs.append(Segment(t0, abs(dist) / vmax, p0, math.copysign(vmax, dist), 0.0))
        return Trajectory(tuple(segs), target)

    direction = math.copysign(1.0, target - p) if target != p else math.copysign(1.0, v or 1.0)
    u = v * direction  # speed towards the target
    dist = (target - p) * direction
    if u < 0 or u * u / (2 * amax) > dist + 1e-9:
        # Moving away, or too fast to stop in time: brake to rest first, then start over.
        push(abs(v) / amax, -math.copysign(amax, v))
        v = 0.0
        direction = math.copysign(1.0, target - p) if target != p else 1.0
        u, dist = 0.0, (target - p) * direction
    if dist <= 0:
        return Trajectory(tuple(segs), target)
    if u > vmax:
        push((u - vmax) / amax, -amax * direction)
        u = vmax
        dist = (target - p) * direction
    # Peak speed: full trapezoid if there is room, else a triangle.
    d_acc = (vmax * vmax - u * u) / (2 * amax)
    d_dec = vmax * vmax / (2 * amax)
    if d_acc + d_dec <= dist:
        peak = vmax
        cruise = (dist - d_acc - d_dec) / vmax
    else:
        peak = math.sqrt(max(amax * dist + 0.5 * u * u, 0.0))
        cruise = 0.0
    push((peak - u) / amax, amax * direction)
    push(cruise, 0.0)
    push(peak / amax, -amax * direction)
    return Trajectory(tuple(segs), target)


def limits_from_registers(
    profile_velocity: int,
    profile_acceleration: int,
    velocity_limit: int,
    time_based: bool = False,
    distance: float = 0.0,
) -> tuple[float, float]:
    """(vmax ticks/s, amax ticks/s²) for the register values; ``inf`` where unlimited.

    ``distance`` (ticks) is needed only by the time-based profile.
    """
    if time_based:
        total_ms, acc_ms = profile_velocity, profile_acceleration
        if total_ms <= 0 or distance == 0:
            return math.inf, math.inf
        acc_ms = min(acc_ms, total_ms / 2)
        vmax = abs(distance) / ((total_ms - acc_ms) / 1000.0)
        amax = math.inf if acc_ms <= 0 else vmax / (acc_ms / 1000.0)
        return vmax, amax
    limit = velocity_limit if velocity_limit > 0 else 0
    pv = profile_velocity
    if pv == 0 or (limit and pv > limit):
        pv = limit
    vmax = math.inf if pv == 0 else pv * TICKS_PER_S_PER_VELOCITY_UNIT
    amax = (
        math.inf if profile_acceleration == 0
        else profile_acceleration * TICKS_PER_S2_PER_ACCELERATION_UNIT
    )
    return vmax, amax
