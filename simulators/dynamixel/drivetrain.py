"""The gears between a servo and its arm: where the arm really is, given the servo's shaft.

A real arm is not where its servo's encoder says: its zero is off (the horn was mounted a
little turned), its gears have play (backlash), and it settles a little differently every move
(position noise). :class:`Drivetrain` models one axis; the rig file's ``[simulation.errors]``
gives the numbers (read here with the simulator's own code: validating the rig file is gonio's
job). All angles in degrees, in the rig file's joint frame
(``deg = direction × (ticks − zero_tick) × 360 / 4096``):

* ``arm = clamp(a₀, shaft − b/2, shaft + b/2) + zero_offset + noise``: the play is a dead band
  of width ``b`` the shaft drags the arm through, so an arm that came from below stops ``b/2``
  below the centre of its play, one from above ``b/2`` above. ``a₀`` is where the play left the
  arm when the present move began (exact for the monotone moves a profile makes from rest);
* ``noise`` ~ N(0, σ²) is drawn anew at every goal that moves the shaft, from a generator
  seeded by the run's seed, the errors' ``seed`` and the axis name.
"""

from __future__ import annotations

import random
from collections.abc import Callable, Mapping
from typing import Any

from drivers.errors import ConfigError

MOVE_TICKS = 0.5
"""A goal this far (ticks) from the previous one is a new move (a new noise draw)."""


class Drivetrain:
    """One axis' gears (see the module docstring).

    Parameters
    ----------
    deg_of:
        Joint angle (deg) of a Present Position in ticks (the axis' own conversion).
    offset_deg, backlash_deg, noise_deg:
        Zero offset, backlash (width of the play) and the 1σ position noise, deg.
    rng:
        The noise generator.
    """

    def __init__(self, deg_of: Callable[[float], float], *, offset_deg: float = 0.0,
                 backlash_deg: float = 0.0, noise_deg: float = 0.0,
                 rng: random.Random | None = None) -> None:
        self.deg_of = deg_of
        self.offset_deg = offset_deg
        self.backlash_deg = backlash_deg
        self.noise_deg = noise_deg
        self._rng = rng or random.Random(0)
        self._play: float | None = None  # a₀: the arm in the shaft's frame when the move began
        self._noise = 0.0
        self._goal: float | None = None

    def on_goal(self, present_ticks: float, goal_ticks: float) -> None:
        """A new goal is planned from ``present_ticks``: the play holds the arm where the
        shaft has dragged it so far, and a move draws a new position error."""
        self._play = self._held(self.deg_of(present_ticks))
        new_goal = self._goal is None or abs(goal_ticks - self._goal) > MOVE_TICKS
        if new_goal and abs(goal_ticks - present_ticks) > MOVE_TICKS and self.noise_deg:
            self._noise = self._rng.gauss(0.0, self.noise_deg)
        self._goal = goal_ticks

    def _held(self, shaft_deg: float) -> float:
        half = self.backlash_deg / 2.0
        if self._play is None:
            return shaft_deg
        return min(max(self._play, shaft_deg - half), shaft_deg + half)

    def arm_deg(self, ticks: float) -> float:
        """The arm's TRUE joint angle (deg) with the shaft at ``ticks`` (Present Position)."""
        return self._held(self.deg_of(ticks)) + self.offset_deg + self._noise


def errors_table(data: Mapping[str, Any], where: str) -> Mapping[str, Any]:
    """``[simulation.errors]`` of a parsed rig file (empty when it has none)."""
    sim = data.get("simulation", {})
    errors = sim.get("errors", {}) if isinstance(sim, Mapping) else {}
    if not isinstance(errors, Mapping):
        raise ConfigError(f"{where}: [simulation.errors] must be a table")
    return errors


def _per_axis(errors: Mapping[str, Any], key: str, axis: str, where: str) -> float:
    table = errors.get(key, {})
    value = table.get(axis, 0.0) if isinstance(table, Mapping) else None
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigError(f"{where}: [simulation.errors] {key}.{axis} must be a number")
    return float(value)


def drivetrains_from_toml(data: Mapping[str, Any], deg_of: Mapping[str, Callable[[float], float]],
                          *, seed: int = 0, where: str = "rig file") -> dict[str, Drivetrain]:
    """One :class:`Drivetrain` per axis of ``deg_of`` from the rig file's
    ``[simulation.errors]`` (ideal gears where it states nothing)."""
    errors = errors_table(data, where)
    base = errors.get("seed", 0)
    out = {}
    for axis, conv in deg_of.items():
        out[axis] = Drivetrain(
            conv, offset_deg=_per_axis(errors, "zero_offset_deg", axis, where),
            backlash_deg=_per_axis(errors, "backlash_deg", axis, where),
            noise_deg=_per_axis(errors, "position_noise_deg", axis, where),
            rng=random.Random(f"gonio-drivetrain:{seed}:{base}:{axis}"))
    return out
