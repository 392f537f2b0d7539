"""The measurement model of the geometric calibration on an out-of-plane-arcs rig.

Parameters (deg, but the white amplitude): the zero offsets of ``light_theta``,
``camera_theta`` and ``camera_phi``; the sample tilt ``tilt_about_x``, ``tilt_about_y``
(:mod:`acquisition.geometry.alignment`'s conventions); each axis' backlash (``backlash:AXIS``,
the width of its play: an arm stops ``backlash / 2`` short of the centre of its play, behind
the direction it came from); and ``white:log_amplitude`` (ln of the white target's signal at
normal incidence).

Observations:

* a mirror peak (:class:`PeakObservation`): with the light and the other camera axis where
  they stood, a scan of one camera axis peaked at ``joints[axis]`` (the commanded frame). A
  mirror reflects towards the camera through the facets whose normal is the half vector
  ``h = (l + c) / |l + c|``, and its facets cluster about the true normal n: the scan peaks
  where ``h·n`` is largest along it (exactly the mirror direction of l when the scan can pass
  through it; off the mirror plane, where a limit keeps the camera, the nearest point in facet
  slope, not in direction);
* the white target's signal (:class:`WhiteObservation`) ∝ cos θi of the true light about the
  true normal: the absolute reference of the light arm (mirror peaks see only ``light_theta −
  2·tilt_about_y`` of the two).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from acquisition.geometry.alignment import TILT_PARAMS, tilt_matrix

AXES = ("light_theta", "camera_theta", "camera_phi")
"""The joints the model calibrates (out-of-plane arcs)."""
BACKLASH = tuple(f"backlash:{a}" for a in AXES)
AMPLITUDE = "white:log_amplitude"
NAMES = (*AXES, *TILT_PARAMS, *BACKLASH, AMPLITUDE)
SCALES = (1.0,) * (len(NAMES) - 1) + (0.01,)
NEWTON_STEPS = 4
"""Typical size of each parameter (deg; the amplitude's unit is 1 % of signal)."""


@dataclass(frozen=True)
class PeakObservation:
    """A scan of ``axis`` peaked at ``joints[axis]`` (deg, commanded frame) ± ``sigma_deg``,
    the other joints as commanded; ``approach``: the direction (±1) each axis last moved."""

    joints: Mapping[str, float]
    axis: str
    approach: Mapping[str, int]
    sigma_deg: float


@dataclass(frozen=True)
class WhiteObservation:
    """ln of the white target's signal at ``joints`` ± ``sigma`` (relative)."""

    joints: Mapping[str, float]
    approach: Mapping[str, int]
    log_signal: float
    sigma: float


def _true(p: Mapping[str, float], joints: Mapping[str, float], approach: Mapping[str, int],
          axis: str) -> float:
    return joints[axis] + p[axis] - approach.get(axis, 0) * p[f"backlash:{axis}"] / 2.0


def _directions(p: Mapping[str, float], joints: Mapping[str, float],
                approach: Mapping[str, int]) -> tuple[np.ndarray, np.ndarray, float, float]:
    """The true light (holder frame), the true normal, and the camera's true (θ, φ), rad."""
    lt = math.radians(_true(p, joints, approach, "light_theta"))
    light = np.array([math.sin(lt), 0.0, math.cos(lt)])
    n = tilt_matrix(p["tilt_about_x"], p["tilt_about_y"])[:, 2]
    return (light, n, math.radians(_true(p, joints, approach, "camera_theta")),
            math.radians(_true(p, joints, approach, "camera_phi")))


def _facet(light: np.ndarray, n: np.ndarray, theta: float, phi: float) -> float:
    """h·n for the camera at (θ, φ) (rad)."""
    st = math.sin(theta)
    h = light + np.array([st * math.cos(phi), st * math.sin(phi), math.cos(theta)])
    return float(h @ n) / float(np.linalg.norm(h))


def predict_peak(p: Mapping[str, float], obs: PeakObservation) -> float:
    """Where (commanded frame, deg) the scan of ``obs.axis`` peaks under parameters ``p``:
    h·n's maximum along the scanned axis (Newton, from the observed peak)."""
    light, n, theta, phi = _directions(p, obs.joints, obs.approach)
    scan_phi = obs.axis == "camera_phi"
    x = phi if scan_phi else theta
    step = 1e-5

    def g(v: float) -> float:
        return _facet(light, n, theta, v) if scan_phi else _facet(light, n, v, phi)

    for _ in range(NEWTON_STEPS):
        up, mid, down = g(x + step), g(x), g(x - step)
        curvature = (up - 2.0 * mid + down) / step**2
        if curvature >= 0:
            break
        x -= (up - down) / (2.0 * step) / curvature
    back = obs.approach.get(obs.axis, 0) * p[f"backlash:{obs.axis}"] / 2.0
    return math.degrees(x) - p[obs.axis] + back


def predict_log_white(p: Mapping[str, float], obs: WhiteObservation) -> float:
    """ln of the white target's signal under ``p``: amplitude × cos θi (true light, normal)."""
    light, n, _, _ = _directions(p, obs.joints, obs.approach)
    return p[AMPLITUDE] + math.log(max(float(light @ n), 1e-12))


def residuals(x: np.ndarray, peaks: Sequence[PeakObservation],
              whites: Sequence[WhiteObservation]) -> np.ndarray:
    """Normalised residuals (observed − predicted) / σ of every observation at parameters
    ``x`` (in :data:`NAMES` order)."""
    p = dict(zip(NAMES, x.tolist(), strict=True))
    out = []
    for obs in peaks:
        diff = obs.joints[obs.axis] - predict_peak(p, obs)
        out.append(((diff + 180.0) % 360.0 - 180.0) / obs.sigma_deg)
    for w in whites:
        out.append((w.log_signal - predict_log_white(p, w)) / w.sigma)
    return np.array(out)
