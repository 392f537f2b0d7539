"""The motion guard's refusals, each one line: which axes, where the arms would meet, what to do.

Every refusal reads ``refused move of AXES: WHY; WHAT TO DO``. ``WHY`` names the joint angles
(and, for the arms, how far along each arm from the sample centre they would meet);
``WHAT TO DO`` is the operator's next step. The kinds:

- :func:`limits`: a target outside an axis' soft limits;
- :func:`elevation`: a target pose above the rig's maximum elevation (or below the horizon);
- :func:`target_collision`: the arms too close at the target itself;
- :func:`shadow`: the camera inside the light's shadow cone at the target;
- :func:`swept_path`: the arms too close on the way (the whole move, or a subset of its axes
  moving alone because the others missed the sync write);
- ``swept_path(..., routed=False)``: no route round the other arm either.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass

ROUTE_ADVICE = ("let gonio route it (gonio jog, move, home and park do), or move the other arm "
                "out of the way first")
SUBSET_ADVICE = ("let gonio route it (each leg of a route stays clear even if a servo misses its "
                 "sync write), or move the axes one at a time")
NO_ROUTE_ADVICE = ("park the rig (`gonio park`) and approach from there, or choose a target the "
                   "arms can reach without passing each other")


@dataclass(frozen=True)
class Meeting:
    """Where the arms come closest: the clearance left (m, negative: inside it) and how far
    from the sample centre along each arm (m)."""

    gap_m: float
    light_m: float
    camera_m: float

    def __str__(self) -> str:
        return (f"the light arm {self.light_m:.2f} m and the camera arm {self.camera_m:.2f} m "
                "from the sample centre")


def axes_phrase(axes: Iterable[str]) -> str:
    """``a``, ``a and b``, ``a, b and c``."""
    names = list(axes)
    if len(names) <= 1:
        return "".join(names)
    return f"{', '.join(names[:-1])} and {names[-1]}"


def joints_phrase(joints: Mapping[str, float]) -> str:
    """``light_theta 40.0°, camera_theta 40.0°, camera_phi 2.0°``."""
    return ", ".join(f"{n} {v:.1f}°" for n, v in joints.items())


def refusal(axes: Iterable[str], why: str, fix: str) -> str:
    """The one line: ``refused move of AXES: WHY; FIX`` (``refused move: …`` without axes)."""
    names = list(axes)
    return f"refused move{f' of {axes_phrase(names)}' if names else ''}: {why}; {fix}"


def limits(axes: Iterable[str], violations: Iterable[str]) -> str:
    """Targets outside the soft limits (``violations``: ``name=value° outside [lo, hi]°``)."""
    names = list(axes)
    tables = ", ".join(f"[axes.{n}]" for n in names)
    return refusal(names, "; ".join(violations),
                   f"give {axes_phrase(names)} a target inside the soft limits (min_deg/max_deg "
                   f"of {tables} in the rig file)")


def elevation(axes: Iterable[str], theta_i: float, theta_r: float, max_deg: float) -> str:
    """The target pose's θi or θr above the rig's maximum elevation (or below the horizon)."""
    high = [f"{name} {v:.1f}°" for name, v in (("θi", theta_i), ("θr", theta_r)) if v > max_deg]
    where = ("below the horizon" if max(theta_i, theta_r) > 90.0
             else f"above the rig's {max_deg:g}° maximum elevation")
    return refusal(axes, f"at the target {' and '.join(high)} {'is' if len(high) == 1 else 'are'} "
                         f"{where}", f"choose a target with θi and θr at most {max_deg:g}° "
                                     "(the rig's maximum elevation)")


def target_collision(axes: Iterable[str], joints: Mapping[str, float], meeting: Meeting,
                     clearance_m: float) -> str:
    """The arms inside the clearance at the target itself."""
    gap = meeting.gap_m + clearance_m
    how = f"overlap by {-gap * 1e3:.1f} mm" if gap < 0 else f"be {gap * 1e3:.1f} mm apart"
    return refusal(axes, f"at {joints_phrase(joints)} the arms' swept volumes would {how} "
                         f"(clearance {clearance_m * 1e3:g} mm), meeting at {meeting}",
                   "choose a target that keeps the arms further apart")


def shadow(axes: Iterable[str], joints: Mapping[str, float], separation_deg: float,
           cone_deg: float) -> str:
    """The camera inside the light's shadow cone at the target."""
    return refusal(axes, f"at {joints_phrase(joints)} the camera is {separation_deg:.2f}° from "
                         f"the light, inside the {cone_deg:g}° shadow cone",
                   f"choose a target with the camera at least {cone_deg:g}° from the light")


def swept_path(moving: Iterable[str], others: Iterable[str], at: Mapping[str, float],
               meeting: Meeting, clearance_m: float, *, routed: bool = True) -> str:
    """The arms too close on the way: ``moving`` (alone when ``others``, the rest of the
    move's axes, miss the sync write), at joints ``at``. ``routed=False``: no route either."""
    moving, others = list(moving), list(others)
    short = -meeting.gap_m * 1e3
    how = (f"{short:.1f} mm inside the {clearance_m * 1e3:g} mm clearance" if short > 0
           else "too close to prove clear")
    alone = (f" alone (if {axes_phrase(others)} {'misses' if len(others) == 1 else 'miss'} "
             "the sync write)") if others else ""
    why = (f"moving {axes_phrase(moving)}{alone} brings the arms {how} at {joints_phrase(at)} "
           f"({meeting})")
    axes = [n for n in at if n in {*moving, *others}]  # in the rig's joint order
    if not routed:
        return refusal(axes, f"{why}, and no route round it exists inside the joint limits",
                       NO_ROUTE_ADVICE)
    return refusal(axes, why, SUBSET_ADVICE if others else ROUTE_ADVICE)
