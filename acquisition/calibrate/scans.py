"""Moving and looking for the geometric calibration: approach a target from a stated direction,
take a frame, read its region of interest, and scan one axis across a peak.

Every target is approached from a stated direction per axis (``approach``: +1 from below, −1
from above): the axes first go :data:`APPROACH_DEG` beyond it on the other side, then to it,
so the play of the gears (backlash) is taken up the same way every time; a scan then moves its
axis monotonically in that direction. Every move passes the rig's guard (``RigDevices.move_to``).
Frames are exposed so the region of interest stays unclipped (a clipped frame is retaken at a
quarter of the exposure) and read as DN/s with their relative uncertainty (the bundle's or the
simulated sensor's noise model, else the scatter over the region).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from acquisition.config.rig import EXPOSURE_RANGE_S, RigConfig
from acquisition.config.sensor import nominal_noise_model
from acquisition.devices.rig import RigDevices
from calibration.linearize import NoiseModel, linearize, roi_mean
from calibration.raw import load_raw
from drivers.errors import CalibrationError

APPROACH_DEG = 1.0
"""How far beyond a target the axes turn before approaching it (more than any backlash)."""
MAX_RETAKES = 8
TARGET_FILL = 0.4
"""Fraction of the sensor's range the brightest point of a scan is exposed to."""

Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class Reading:
    """One frame's region of interest: signal (DN/s, mean of the colours), its relative 1σ."""

    signal: float
    rel_sigma: float


@dataclass
class Scope:
    """Takes and reads frames of whatever stands in front of the camera (see module doc)."""

    dev: RigDevices
    rig: RigConfig
    folder: Path
    exposure_s: float
    progress: Progress | None = None
    total: int = 1
    count: int = 0
    noise: NoiseModel | None = field(default=None)

    def __post_init__(self) -> None:
        if self.rig.camera.driver == "simulated":
            self.noise = nominal_noise_model(self.rig, float(self.rig.camera.iso))

    def read(self) -> Reading:
        """A frame now, retaken shorter until its region of interest is unclipped."""
        x0, y0, x1, y1 = self.rig.camera.roi
        for _ in range(MAX_RETAKES):
            path = self.folder / f"geometry-{self.count:05d}.dng"
            self.dev.capture(path, self.exposure_s, self.rig.camera.iso, 7_000_003 + self.count)
            self.count += 1
            if self.progress:
                self.progress(min(self.count, self.total), max(self.total, self.count))
            image = linearize(load_raw(path), noise=self.noise)
            path.unlink()
            mean, var, n = roi_mean(image, (x0, y0, x1 - x0, y1 - y0))
            if n == (x1 - x0) * (y1 - y0):
                m = float(np.mean(mean))
                rel = math.sqrt(float(np.sum(var))) / 3.0 / m if m > 0 else math.inf
                return Reading(m, rel)
            self.exposure_s = max(self.exposure_s / 4.0, EXPOSURE_RANGE_S[0])
        raise CalibrationError(f"{self.rig.path}: the region of interest stays clipped at "
                               f"{self.exposure_s:g} s: dim the light or shorten the exposure")

    def expose_for(self, signal_dn_per_s: float) -> None:
        """Expose so that ``signal_dn_per_s`` fills :data:`TARGET_FILL` of the range."""
        sensor = self.rig.camera.sensor
        span = 2 ** int(sensor.get("bits", 14)) - float(sensor.get("black_level_dn", 0))
        if signal_dn_per_s > 0:
            t = TARGET_FILL * span / signal_dn_per_s
            self.exposure_s = min(max(t, EXPOSURE_RANGE_S[0]), 1.0)

    def go(self, joints: Mapping[str, float], approach: Mapping[str, int]) -> dict[str, float]:
        """Move to ``joints``, each axis of ``approach`` from its stated side; the read-back."""
        pre = {a: joints[a] - s * APPROACH_DEG for a, s in approach.items() if s}
        if pre:
            self.dev.move_to({**joints, **pre})
        return self.dev.move_to(dict(joints))


@dataclass(frozen=True)
class Scan:
    """A scan of one axis: read-back positions (deg), signals and their relative 1σ, and the
    joints of its last point."""

    axis: str
    x_deg: np.ndarray
    signal: np.ndarray
    rel_sigma: np.ndarray
    joints: dict[str, float]


def scan(scope: Scope, joints: Mapping[str, float], axis: str, centre_deg: float,
         half_deg: float, step_deg: float, approach: Mapping[str, int]) -> Scan:
    """Scan ``axis`` over ``centre ± half`` in its approach direction, the other joints at
    ``joints`` (approached as stated first)."""
    s = approach.get(axis, 1) or 1
    n = int(round(2 * half_deg / step_deg)) + 1
    points = centre_deg + s * np.linspace(-half_deg, half_deg, n)
    xs, sig, rel = [], [], []
    at = scope.go({**joints, axis: float(points[0])}, approach)
    for k, x in enumerate(points):
        if k:
            at = scope.dev.move_to({**at, axis: float(x)})
        reading = scope.read()
        xs.append(at[axis])
        sig.append(reading.signal)
        rel.append(reading.rel_sigma)
    return Scan(axis, np.array(xs), np.array(sig), np.array(rel), dict(at))
