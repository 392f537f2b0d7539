"""The measurement model of the geometric calibration, for any rig with moving arms.

Parameters (deg, but the white amplitude), in :attr:`MirrorModel.names` order: the zero offset
of every essential joint of the rig's kinematics (out-of-plane arcs: ``light_theta``,
``camera_theta``, ``camera_phi``; coaxial arms: ``light_azimuth``, ``camera_azimuth``,
``stage_tilt``); the sample tilt ``tilt_about_x``, ``tilt_about_y`` on its holder
(:mod:`acquisition.geometry.alignment`'s conventions: the holder frame is the kinematics'
nominal sample frame, which on a coaxial rig turns with the stage rotation); each of those
axes' backlash (``backlash:AXIS``, the width of its play: an arm stops ``backlash / 2`` short
of the centre of its play, behind the direction it came from); and ``white:log_amplitude``
(ln of the white target's signal at normal incidence). On an image-based rig
(:class:`CameraOptics`) the camera's pointing error ``camera_pointing_x``, ``camera_pointing_y``
comes before the amplitude. A free joint (a turntable, a stage rotation) is taken as
commanded: its zero is a convention (the tilt is stated in its frame).

The true directions are the kinematics plug-in's (the same code
:class:`~acquisition.geometry.kinematics.calibrated.CalibratedKinematics` applies the result
through) at the true joints, turned into the true sample frame by the tilt. Observations:

* a mirror peak (:class:`PeakObservation`): a scan of one axis, the others where they stood,
  peaked at ``joints[axis]`` (the commanded frame). A mirror reflects towards the camera
  through the facets whose normal is the half vector ``h = (l + c) / |l + c|``, and its facets
  cluster about the true normal n: the scan peaks where ``h·n`` is largest along it (exactly
  the mirror direction of l when the scan can pass through it; off the mirror plane, where a
  limit keeps the camera, the nearest point in facet slope, not in direction);
* the white target's signal (:class:`WhiteObservation`) ∝ cos θi of the true light about the
  true normal: the absolute reference of the light arm, which mirror peaks see only together
  with the tilt (out-of-plane: ``light_theta − 2·tilt_about_y``; coaxial: only the sum of the
  two arm azimuths' offsets, against the normal's azimuth).

On a rig whose camera looks through a pinhole (image-based: :class:`CameraOptics`) the
directions are those seen from the surface point a pixel looks at — the camera
``camera_distance_m`` away, turned by its pointing error (:mod:`acquisition.geometry.pinhole`),
its ray meeting the sample plane; the light ``light_distance_m`` away — since a pointing error
of 0.3° moves that point 3 mm, which turns the light's and the camera's directions by ≈ 0.35°
and 0.3°: a mirror peak is read in a few pixels about where the arms' common point images
(:attr:`CameraOptics.mirror_pixel`), the white signal is the mean of cos θi / r² over the
region of interest's pixels (:attr:`CameraOptics.white_pixels`), and the sphere's centre in
the image (:class:`CentreObservation`, :mod:`acquisition.calibrate.pointing`) is where the
pointed camera projects it: the observation that fixes the pointing.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from acquisition.geometry.alignment import (
    BACKLASH_PREFIX,
    POINTING_PARAMS,
    TILT_PARAMS,
    tilt_matrix,
)
from acquisition.geometry.kinematics import Kinematics
from acquisition.geometry.pinhole import camera_rotations, pointed_rotations

AMPLITUDE = "white:log_amplitude"
AMPLITUDE_SCALE = 0.01
"""Typical size of the amplitude (1 % of signal); every other parameter's is 1°."""
NEWTON_STEPS = 4
STEP_DEG = 0.05
"""Finite-difference step of the peak search along a scanned axis, deg."""


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


@dataclass(frozen=True)
class CentreObservation:
    """The sphere's centre at image point (``x_px``, ``y_px``) ± ``sigma_px`` (superpixels,
    each axis), the camera's joints at ``joints`` approached as ``approach`` says."""

    joints: Mapping[str, float]
    approach: Mapping[str, int]
    x_px: float
    y_px: float
    sigma_px: float


@dataclass(frozen=True)
class CameraOptics:
    """An image-based rig's camera as the calibration reads it (module docstring)."""

    intrinsics: tuple[float, float, float, float]
    """(fx, fy, cx, cy), superpixels."""
    camera_distance_m: float
    light_distance_m: float
    mirror_pixel: tuple[float, float]
    """(x, y) image point the mirror peaks are read at (the centre of their window)."""
    white_pixels: np.ndarray
    """(M, 2) image points (x, y) whose mean is the white target's signal."""
    sphere_centre_m: tuple[float, float, float]

    def cameras(self, p: Mapping[str, float], camera: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
        """Positions (N, 3, m) and rotations (N, 3, 3) of cameras along unit directions
        ``camera`` (N, 3), pointed as ``p`` says."""
        rot = camera_rotations(camera)
        return camera * self.camera_distance_m, pointed_rotations(
            rot, p[POINTING_PARAMS[0]], p[POINTING_PARAMS[1]])

    def seen(self, p: Mapping[str, float], light: np.ndarray, camera: np.ndarray,
             pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Unit directions to the light and to the camera (N, M, 3) and the squared light
        distance (N, M, m²) at the points of the sample plane z = 0 that image points
        ``pixels`` (M, 2) see, for light and camera directions (N, 3)."""
        position, rot = self.cameras(p, camera)
        fx, fy, cx, cy = self.intrinsics
        x = (pixels[:, 0] - cx) / fx
        y = (pixels[:, 1] - cy) / fy
        rays = (x[None, :, None] * rot[:, None, 0] + y[None, :, None] * rot[:, None, 1]
                + rot[:, None, 2])
        reach = -position[:, None, 2] / rays[..., 2]
        points = position[:, None] + reach[..., None] * rays
        to_light = light[:, None] * self.light_distance_m - points
        r2 = np.sum(to_light**2, axis=-1)
        to_camera = position[:, None] - points
        return (to_light / np.sqrt(r2)[..., None],
                to_camera / np.linalg.norm(to_camera, axis=-1, keepdims=True), r2)

    def project_centre(self, p: Mapping[str, float], camera: np.ndarray) -> np.ndarray:
        """(N, 2) image point of the sphere's centre for cameras along ``camera`` (N, 3)."""
        position, rot = self.cameras(p, camera)
        v = np.einsum("nij,nj->ni", rot, np.asarray(self.sphere_centre_m) - position)
        fx, fy, cx, cy = self.intrinsics
        return np.column_stack([fx * v[:, 0] / v[:, 2] + cx, fy * v[:, 1] / v[:, 2] + cy])


class MirrorModel:
    """The model of one rig's kinematics (see the module docstring)."""

    def __init__(self, kinematics: Kinematics, optics: CameraOptics | None = None) -> None:
        self.kinematics = kinematics
        self.optics = optics
        self.joint_names = kinematics.joint_names
        self.axes = tuple(n for n in self.joint_names if n not in kinematics.free_joints)
        self.backlash = tuple(f"{BACKLASH_PREFIX}{a}" for a in self.axes)
        self.pointing = POINTING_PARAMS if optics is not None else ()
        self.names = (*self.axes, *TILT_PARAMS, *self.backlash, *self.pointing, AMPLITUDE)
        self.scales = (1.0,) * (len(self.names) - 1) + (AMPLITUDE_SCALE,)

    def params(self, x: np.ndarray) -> dict[str, float]:
        """Parameter vector (:attr:`names` order) → {name: value}."""
        return dict(zip(self.names, np.asarray(x, float).tolist(), strict=True))

    def _shift(self, p: Mapping[str, float], approach: Mapping[str, int]) -> np.ndarray:
        """True − commanded angle of every joint (deg): offset − side × backlash / 2."""
        return np.array([p[n] - approach.get(n, 0) * p[f"{BACKLASH_PREFIX}{n}"] / 2.0
                         if n in self.axes else 0.0 for n in self.joint_names])

    def _true_joints(self, p: Mapping[str, float], joints: Sequence[Mapping[str, float]],
                     approach: Sequence[Mapping[str, int]]) -> np.ndarray:
        cmd = np.array([[float(j.get(n, 0.0)) for n in self.joint_names] for j in joints])
        return cmd + np.array([self._shift(p, a) for a in approach]).reshape(cmd.shape)

    def _directions(self, p: Mapping[str, float], true: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
        """Light and camera (N, 3) in the true sample frame at true joints (N, J)."""
        light, camera = self.kinematics.forward_array(true)
        rot = tilt_matrix(p[TILT_PARAMS[0]], p[TILT_PARAMS[1]])
        return light @ rot, camera @ rot

    def _facet(self, p: Mapping[str, float], true: np.ndarray) -> np.ndarray:
        """h·n at true joints (N, J) (where the mirror peaks are read, on an image-based rig)."""
        light, camera = self._directions(p, true)
        if self.optics is not None:
            light, camera, _ = (v[:, 0] for v in self.optics.seen(
                p, light, camera, np.array([self.optics.mirror_pixel])))
        h = light + camera
        return h[:, 2] / np.linalg.norm(h, axis=1)

    def predict_peaks(self, p: Mapping[str, float], peaks: Sequence[PeakObservation]
                      ) -> np.ndarray:
        """Where (commanded frame, deg) each scan peaks under parameters ``p``: h·n's maximum
        along the scanned axis (Newton, from the observed peak)."""
        if not peaks:
            return np.zeros(0)
        true = self._true_joints(p, [o.joints for o in peaks], [o.approach for o in peaks])
        col = np.array([self.joint_names.index(o.axis) for o in peaks])
        rows = np.arange(len(peaks))
        x = true[rows, col].copy()
        for _ in range(NEWTON_STEPS):
            trial = np.repeat(true[None], 3, axis=0)
            for k, d in enumerate((STEP_DEG, 0.0, -STEP_DEG)):
                trial[k, rows, col] = x + d
            up, mid, down = self._facet(p, trial.reshape(-1, true.shape[1])).reshape(3, -1)
            curvature = (up - 2.0 * mid + down) / STEP_DEG**2
            climbing = curvature < 0
            x[climbing] -= ((up - down)[climbing] / (2.0 * STEP_DEG)) / curvature[climbing]
        shift = np.array([self._shift(p, o.approach)[c] for o, c in zip(peaks, col, strict=True)])
        return x - shift

    def predict_peak(self, p: Mapping[str, float], obs: PeakObservation) -> float:
        """:meth:`predict_peaks` of one observation."""
        return float(self.predict_peaks(p, [obs])[0])

    def predict_log_whites(self, p: Mapping[str, float], whites: Sequence[WhiteObservation]
                           ) -> np.ndarray:
        """ln of the white target's signal under ``p``: amplitude × cos θi (true light, normal)."""
        if not whites:
            return np.zeros(0)
        true = self._true_joints(p, [w.joints for w in whites], [w.approach for w in whites])
        light, camera = self._directions(p, true)
        if self.optics is None:
            return p[AMPLITUDE] + np.log(np.maximum(light[:, 2], 1e-12))
        wi, _, r2 = self.optics.seen(p, light, camera, self.optics.white_pixels)
        irradiance = np.maximum(wi[..., 2], 0.0) * self.optics.light_distance_m**2 / r2
        return p[AMPLITUDE] + np.log(np.maximum(np.mean(irradiance, axis=1), 1e-12))

    def predict_centres(self, p: Mapping[str, float], centres: Sequence[CentreObservation]
                        ) -> np.ndarray:
        """(N, 2) image points of the sphere's centre under ``p``."""
        if not centres or self.optics is None:
            return np.zeros((0, 2))
        true = self._true_joints(p, [c.joints for c in centres], [c.approach for c in centres])
        _, camera = self._directions(p, true)
        return self.optics.project_centre(p, camera)

    def residuals(self, x: np.ndarray, peaks: Sequence[PeakObservation],
                  whites: Sequence[WhiteObservation],
                  centres: Sequence[CentreObservation] = ()) -> np.ndarray:
        """Normalised residuals (observed − predicted) / σ of every observation at parameters
        ``x`` (in :attr:`names` order): peaks, whites, then each centre's x and y."""
        p = self.params(x)
        observed = np.array([o.joints[o.axis] for o in peaks])
        diff = observed - self.predict_peaks(p, peaks) if peaks else np.zeros(0)
        peak_r = ((diff + 180.0) % 360.0 - 180.0) / np.array([o.sigma_deg for o in peaks])
        white_r = (np.array([w.log_signal for w in whites]) - self.predict_log_whites(p, whites)
                   ) / np.array([w.sigma for w in whites]) if whites else np.zeros(0)
        centre_r = ((np.array([[c.x_px, c.y_px] for c in centres]).reshape(-1, 2)
                     - self.predict_centres(p, centres))
                    / np.array([c.sigma_px for c in centres])[:, None]).ravel()
        return np.concatenate([peak_r, white_r, centre_r])

    def start(self, whites: Sequence[WhiteObservation],
              pointing_deg: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
        """Starting parameters: every angle 0 but the pointing (``pointing_deg``, a first
        estimate), the amplitude from the white frames."""
        x = np.zeros(len(self.names))
        for name, value in zip(self.pointing, pointing_deg, strict=False):
            x[self.names.index(name)] = value
        if whites:
            zero = self.params(x)
            k = self.names.index(AMPLITUDE)
            x[k] = float(np.mean([w.log_signal for w in whites])
                         - np.mean(self.predict_log_whites(zero, whites)))
        return x
