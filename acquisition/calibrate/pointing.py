"""An image-based rig's camera pointing, from where its sphere falls in the image.

The camera of an image-based rig is meant to look at the arms' common point, where the sphere's
centre is; a camera turned by a small angle towards its image's +x (+y) shows the sphere's
centre ``fx · tan(angle)`` superpixels towards −x (−y) of where the pinhole model puts it. The
sphere is lit from beside the camera (the light :data:`LIGHT_SIDE_DEG` to either side of it in
the plane of incidence, so the thin unlit crescent falls on opposite sides in the two frames
and their mean centroid is unbiased); its silhouette's centroid gives the pointing, its area
the sphere's radius in the image (and the camera distance that radius implies).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from acquisition.calibrate.scans import Scope
from acquisition.config.rig import RigConfig
from acquisition.geometry.kinematics import Pose
from acquisition.planning.planner import Planner
from calibration.linearize import linearize
from calibration.raw import load_raw
from drivers.errors import CalibrationError

CAMERA_THETA_DEG = 30.0
LIGHT_SIDE_DEG = 10.0
THRESHOLD = 0.1
"""A superpixel belongs to the sphere above this fraction of the frame's brightest."""
CENTROID_FLOOR_PX = 0.2
"""Added in quadrature to the centroid's 1σ (superpixels): the silhouette's pixel edges."""


@dataclass(frozen=True)
class Pointing:
    """The camera's pointing error (deg) with its 1σ, and the sphere as the image shows it."""

    x_deg: float
    y_deg: float
    sigma_x_deg: float
    sigma_y_deg: float
    radius_px: float
    camera_distance_m: float


def expected_centre(rig: RigConfig, camera_dir: np.ndarray, shape: tuple[int, int]
                    ) -> tuple[float, float]:
    """Where a perfectly pointed camera shows the sphere's centre (superpixels): the camera
    ``camera_distance_m`` along ``camera_dir`` looks at the origin, image up = +z projected."""
    k = rig.camera.intrinsics
    if k is None:
        raise CalibrationError(f"{rig.path}: an image-based rig needs [camera.intrinsics]")
    h, w = shape
    cx = (w - 1) / 2.0 if k.cx is None else k.cx
    cy = (h - 1) / 2.0 if k.cy is None else k.cy
    c = camera_dir / np.linalg.norm(camera_dir)
    up = np.array([0.0, 0.0, 1.0]) - c[2] * c
    up = up / np.linalg.norm(up) if np.linalg.norm(up) > 1e-9 else np.array([-1.0, 0.0, 0.0])
    right = np.cross(-c, up)
    down = np.cross(-c, right)
    s = np.asarray(rig.sample.centre_m, float)
    depth = rig.camera_distance_m - float(s @ c)
    return cx + k.fx * float(s @ right) / depth, cy + k.fy * float(s @ down) / depth


def _silhouette(path: Path) -> tuple[float, float, float]:
    """Centroid (x, y) and area (superpixels) of the lit sphere in a frame."""
    image = linearize(load_raw(path))
    lum = np.nan_to_num(image.rgb.mean(axis=-1))
    mask = lum > THRESHOLD * float(lum.max())
    ys, xs = np.nonzero(mask)
    if len(xs) < 20:
        raise CalibrationError(f"{path}: the sphere is not in the image (or not lit): check "
                               "the camera's pointing and the exposure")
    return float(xs.mean()), float(ys.mean()), float(len(xs))


def measure_pointing(scope: Scope, rig: RigConfig, planner: Planner) -> Pointing:
    """Two frames of the lit sphere (light on either side of the camera) → :class:`Pointing`."""
    scope.dev.present("sample")
    centroids, areas = [], []
    camera_dir = np.zeros(3)
    for side in (1.0, -1.0):
        pose = Pose(CAMERA_THETA_DEG + side * LIGHT_SIDE_DEG, CAMERA_THETA_DEG, 0.0)
        joints = scope.dev.move_to(dict(planner.joints_for(pose)))
        camera_dir = planner.kinematics.forward_geometry(joints).camera_dir
        path = scope.folder / f"pointing-{len(areas)}.dng"
        scope.dev.capture(path, scope.exposure_s, rig.camera.iso, 9_000_011 + len(areas))
        x, y, area = _silhouette(path)
        centroids.append((x, y))
        areas.append(area)
    shape = linearize(load_raw(path)).valid.shape
    ex, ey = expected_centre(rig, camera_dir, shape)
    mx, my = np.mean(centroids, axis=0)
    spread = np.abs(np.diff(np.array(centroids), axis=0))[0] / 2.0
    k = rig.camera.intrinsics
    assert k is not None
    radius = math.sqrt(float(np.mean(areas)) / math.pi)
    r = rig.sample.radius_m
    return Pointing(
        math.degrees(math.atan((ex - mx) / k.fx)), math.degrees(math.atan((ey - my) / k.fy)),
        math.degrees(math.hypot(spread[0], CENTROID_FLOOR_PX) / k.fx),
        math.degrees(math.hypot(spread[1], CENTROID_FLOOR_PX) / k.fy),
        radius, r * math.sqrt(1.0 + (k.fx / radius) ** 2))
