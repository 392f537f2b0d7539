"""The side every target is approached from on a rig with backlash.

Gears have play: an arm stops ``backlash / 2`` short of the centre of its play, behind the
direction it came from. A rig whose file states backlash therefore approaches every target
from one side — from below (+1), turning :data:`APPROACH_DEG` past it the other way first —
so the play is always taken up the same way: the geometric calibration measures it, and the
planner and the reduction correct for it. Where the axis' lower limit leaves no room for
that, the target is approached from above (−1). The rule depends only on the target and the
limits, so the reduction knows the side of every step from its commanded joints.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

APPROACH_DEG = 1.0
"""How far past a target (deg) an axis turns before approaching it: more than any backlash."""


def approach_signs(joints: np.ndarray, lower_deg: Sequence[float] | np.ndarray) -> np.ndarray:
    """The side (+1 from below, −1 from above) each target of joints (N, J) is approached
    from, given the axes' lower limits (J,) in degrees."""
    joints = np.asarray(joints, float)
    lo = np.asarray(lower_deg, float)
    return np.where(joints - APPROACH_DEG < lo - 1e-9, -1.0, 1.0)


def approach_point(target: Mapping[str, float], lower_deg: Mapping[str, float]
                   ) -> dict[str, float]:
    """Where the axes turn to before approaching ``target`` (deg): :data:`APPROACH_DEG` short
    of it on the side :func:`approach_signs` gives."""
    out = {}
    for name, value in target.items():
        lo = lower_deg.get(name, -np.inf)
        sign = -1.0 if value - APPROACH_DEG < lo - 1e-9 else 1.0
        out[name] = value - sign * APPROACH_DEG
    return out
