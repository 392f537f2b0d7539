"""Moving and looking for the geometric calibration: approach a target from a stated direction,
take a frame, read its region of interest, scan one axis across a peak and locate it.

Every target is approached from a stated direction per axis (``approach``: +1 from below, −1
from above): the axes first go :data:`APPROACH_DEG` beyond it on the other side, then to it,
so the play of the gears (backlash) is taken up the same way every time; a scan then moves its
axis monotonically in that direction. Every move passes the rig's guard (``RigDevices.move_to``).
Frames are exposed so the region of interest stays unclipped (a clipped frame is retaken at a
quarter of the exposure) and read as DN/s with their relative uncertainty (the bundle's or the
simulated sensor's noise model, else the scatter over the region). :func:`locate_peak` scans
coarse then fine around the expected peak (widths :data:`COARSE`, :data:`FINE` on the sphere).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from acquisition.calibrate.mirror_model import PeakObservation, WhiteObservation
from acquisition.config.rig import EXPOSURE_RANGE_S, RigConfig
from acquisition.config.sensor import nominal_noise_model
from acquisition.devices.rig import RigDevices
from acquisition.geometry.kinematics import Kinematics
from calibration.linearize import NoiseModel, linearize, roi_mean
from calibration.peaks import fit_peak
from calibration.raw import load_raw
from drivers.errors import CalibrationError

APPROACH_DEG = 1.0
"""How far beyond a target the axes turn before approaching it (more than any backlash)."""
MAX_RETAKES = 8
TARGET_FILL = 0.4
"""Fraction of the sensor's range the brightest point of a scan is exposed to."""
COARSE = (4.0, 0.5)
"""Half width and step (deg, on the sphere) of the coarse scans around the expected peak."""
FINE = (0.9, 0.15)
"""Half width and step (deg, on the sphere) of the fine scans around the coarse peak."""
RECENTRE_STEPS = 0.5
"""A fine scan whose peak lies farther than this many steps from its centre may be repeated."""
PEAK_FLOOR_DEG = 0.006
"""Added in quadrature to every fitted peak's 1σ: what the model leaves out (the lamp's size
pulls an elevation peak by a few thousandths of a degree; the mirror's flatness)."""

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
    kinematics: Kinematics = field(init=False)
    """The rig file's kinematics (a scan's nominal geometry)."""
    roi: tuple[int, int, int, int] = field(init=False)
    """The superpixels read (x0, y0, x1, y1), end exclusive: the rig file's region of
    interest unless the procedure chooses others."""

    def __post_init__(self) -> None:
        self.kinematics = self.rig.kinematics()
        self.roi = self.rig.camera.roi
        if self.rig.camera.driver == "simulated":
            self.noise = nominal_noise_model(self.rig, float(self.rig.camera.iso))

    def read(self) -> Reading:
        """A frame now, retaken shorter until its region of interest (:attr:`roi`) is
        unclipped."""
        x0, y0, x1, y1 = self.roi
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


def scan_points(half_deg: float, step_deg: float) -> int:
    """How many frames a scan of ``± half_deg`` by ``step_deg`` takes."""
    return int(round(2 * half_deg / step_deg)) + 1


def locate_peak(scope: Scope, joints: Mapping[str, float], axis: str, approach: Mapping[str, int],
                *, stretch: float = 1.0, coarse: bool = True, recentre: int = 0
                ) -> tuple[float, float, dict]:
    """Scan ``axis`` across the peak near ``joints[axis]`` (coarse then fine; ``stretch``
    turns widths on the sphere into the axis' degrees); (peak deg, 1σ deg, joints there).
    Up to ``recentre`` times the fine scan is repeated about its peak while that lies more
    than :data:`RECENTRE_STEPS` fine steps from its centre: a vertex fitted to a lopsided
    scan is pulled by the lobe's non-parabolic shoulders.

    The signals are multiplied by the nominal cos θr first: a BRDF is radiance over irradiance
    per projected solid angle, so a mirror's radiance carries a 1/cos θr that would pull the
    peak of the facet distribution towards grazing by w²·tan θr along a scan that moves θr."""
    centre = joints[axis]
    what = f"mirror peak of {axis} near {centre:.1f}°"
    if coarse:
        s = scan(scope, joints, axis, centre, COARSE[0] * stretch, COARSE[1] * stretch, approach)
        centre = fit_peak(s.x_deg, _facet_signal(scope, s), s.rel_sigma, what=what).centre_deg
        scope.expose_for(float(np.max(s.signal)))
    for _ in range(recentre + 1):
        s = scan(scope, joints, axis, centre, FINE[0] * stretch, FINE[1] * stretch, approach)
        peak = fit_peak(s.x_deg, _facet_signal(scope, s), s.rel_sigma, what=what)
        off_centre = abs(peak.centre_deg - centre) > RECENTRE_STEPS * FINE[1] * stretch
        centre = peak.centre_deg
        if not off_centre:
            break
    return centre, math.hypot(peak.sigma_deg, PEAK_FLOOR_DEG), {**s.joints, axis: centre}


def _facet_signal(scope: Scope, s: Scan) -> np.ndarray:
    """The scan's signals times the nominal cos θr at each of its points."""
    kin = scope.kinematics
    rows = np.repeat(kin.to_array(s.joints)[None], len(s.x_deg), axis=0)
    rows[:, kin.joint_names.index(s.axis)] = s.x_deg
    _, camera = kin.forward_array(rows)
    return s.signal * camera[:, 2]


@dataclass(frozen=True)
class Procedure:
    """One rig kind's geometric calibration: its mirror configurations, its white fall-off
    (the absolute reference) and how many frames they take."""

    description: str
    mirror_peaks: Callable[[Scope, RigConfig], list[PeakObservation]]
    white_falloff: Callable[[Scope, RigConfig], list[WhiteObservation]]
    expected_frames: Callable[[RigConfig], int]
