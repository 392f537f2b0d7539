"""An image-based rig's camera pointing, from where its sphere falls in the image.

The camera of an image-based rig is meant to look at the arms' common point, where the sphere's
centre is; a camera turned by a small angle towards its image's +x (+y) shows the sphere's
centre ``fx · tan(angle)`` superpixels towards −x (−y) of where the pinhole model puts it
(:mod:`acquisition.geometry.pinhole`).

The sphere is lit from beside the camera, the light :data:`LIGHT_SIDE_DEG` to either side of
it in the plane of incidence (two frames, the camera not moved between them). Each frame
leaves a thin crescent beyond its terminator unlit, on opposite sides; the union of the two
frames' lit pixels is the whole disc but two slivers at the limb a few hundredths of a pixel
wide. A circle is fitted to that union's outline (least squares in the centre and radius,
:func:`fit_circle`), leaving out the image's border: the sphere fills most of the image, and a
pointing error of a few tenths of a degree pushes its disc over an edge, which would pull a
centroid. The fit's own scatter gives the centre's 1σ (the outline is quantised to pixels),
with :data:`EDGE_FLOOR_PX` in quadrature for the slivers. The centre is an observation of the
geometric calibration's joint fit (:class:`~acquisition.calibrate.mirror_model.
CentreObservation`); the fitted radius gives the sphere's radius in the image and the camera
distance it implies.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from acquisition.calibrate.mirror_model import CentreObservation
from acquisition.calibrate.scans import Scope
from acquisition.config.rig import RigConfig
from acquisition.geometry.kinematics import Pose
from acquisition.geometry.pinhole import PinholeCamera
from acquisition.planning.planner import Planner
from calibration.linearize import linearize
from calibration.raw import load_raw
from drivers.errors import CalibrationError

CAMERA_THETA_DEG = 30.0
LIGHT_SIDE_DEG = 10.0
THRESHOLD = 0.03
"""A superpixel is lit above this fraction of the frame's brightest (the unlit slivers at the
limb, where both lights graze, are then ≈ THRESHOLD²/2 of the radius wide)."""
EDGE_INSET_PX = 0.5
"""How far inside the sphere's edge the centres of its outline's pixels lie, on average."""
EDGE_FLOOR_PX = 0.02
"""Added in quadrature to the fitted centre's 1σ (superpixels): the unlit slivers."""
MIN_EDGE_PIXELS = 20


@dataclass(frozen=True)
class Pointing:
    """The sphere as the image shows it: its centre (superpixels, with its 1σ) with the camera
    at the joints of :attr:`centre`, a first estimate of the pointing error (deg) from it with
    the rig file's geometry, the radius (superpixels) and the camera distance it implies."""

    centre: CentreObservation
    shape: tuple[int, int]
    """The image's (rows, columns), superpixels."""
    x_deg: float
    y_deg: float
    radius_px: float
    camera_distance_m: float


@dataclass(frozen=True)
class Circle:
    """A fitted circle (superpixels): centre, radius and the centre's 1σ on each axis."""

    x: float
    y: float
    radius: float
    sigma_x: float
    sigma_y: float


def fit_circle(mask: np.ndarray) -> Circle:
    """The circle through the outline of ``mask`` (its pixels with a 4-neighbour outside it,
    the image's border rows and columns left out): algebraic fit, then Gauss–Newton on the
    distances; the centre's 1σ from their scatter."""
    inner = np.zeros_like(mask)
    inner[1:-1, 1:-1] = (mask[1:-1, 1:-1] & mask[:-2, 1:-1] & mask[2:, 1:-1]
                         & mask[1:-1, :-2] & mask[1:-1, 2:])
    edge = mask & ~inner
    edge[[0, -1], :] = False
    edge[:, [0, -1]] = False
    ys, xs = np.nonzero(edge)
    if len(xs) < MIN_EDGE_PIXELS:
        raise ValueError("too few edge pixels")
    x, y = xs.astype(float), ys.astype(float)
    (d, e, f), *_ = np.linalg.lstsq(np.column_stack([x, y, np.ones_like(x)]), -(x * x + y * y),
                                    rcond=None)
    p = np.array([-d / 2.0, -e / 2.0, math.sqrt(max(d * d / 4.0 + e * e / 4.0 - f, 0.0))])
    for _ in range(3):
        dx, dy = x - p[0], y - p[1]
        dist = np.hypot(dx, dy)
        jac = np.column_stack([-dx / dist, -dy / dist, -np.ones_like(x)])
        p -= np.linalg.lstsq(jac, dist - p[2], rcond=None)[0]
    dist = np.hypot(x - p[0], y - p[1])
    var = float(np.sum((dist - p[2]) ** 2)) / max(len(x) - 3, 1)
    cov = var * np.linalg.inv(jac.T @ jac)
    return Circle(float(p[0]), float(p[1]), float(p[2]), math.sqrt(cov[0, 0]),
                  math.sqrt(cov[1, 1]))


def lit(luminance: np.ndarray) -> np.ndarray:
    """The superpixels of a frame's luminance (rows, columns) lit above :data:`THRESHOLD` of
    its brightest (a clipped one, NaN, counts as lit)."""
    finite = np.isfinite(luminance)
    peak = float(luminance[finite].max()) if finite.any() else 0.0
    if peak <= 0:
        return np.zeros_like(finite)
    return ~finite | (np.nan_to_num(luminance) > THRESHOLD * peak)


def outline_centre(masks: list[np.ndarray]) -> tuple[Circle, float]:
    """The circle through the outline of the frames' lit superpixels together, and its
    centre's 1σ on either axis (superpixels: the fit's, :data:`EDGE_FLOOR_PX` in quadrature);
    raises ValueError when the outline is too short to fit."""
    circle = fit_circle(np.logical_or.reduce(masks))
    return circle, math.hypot(max(circle.sigma_x, circle.sigma_y), EDGE_FLOOR_PX)


def measure_pointing(scope: Scope, rig: RigConfig, planner: Planner) -> Pointing:
    """Two frames of the lit sphere (light on either side of the camera, the camera not moved
    between them) → :class:`Pointing` (module docstring)."""
    scope.dev.present("sample")
    masks = []
    at: dict[str, float] = {}
    for side in (1.0, -1.0):
        joints = dict(planner.joints_for(Pose(CAMERA_THETA_DEG + side * LIGHT_SIDE_DEG,
                                              CAMERA_THETA_DEG, 0.0)))
        if at:  # the light alone moves
            at = scope.go({**at, "light_theta": joints["light_theta"]}, {"light_theta": 1})
        else:
            at = scope.go(joints, dict.fromkeys(joints, 1))
        path = scope.folder / f"pointing-{len(masks)}.dng"
        scope.dev.capture(path, scope.exposure_s, rig.camera.iso, 9_000_011 + len(masks))
        masks.append(lit(linearize(load_raw(path)).rgb.mean(axis=-1)))
    try:
        circle, sigma = outline_centre(masks)
    except ValueError:
        raise CalibrationError(f"{rig.path}: the sphere is not in the image (or not lit): check "
                               "the camera's pointing and the exposure") from None
    return _pointing(rig, planner, at, masks[0].shape, circle, sigma)


def _pointing(rig: RigConfig, planner: Planner, at: dict[str, float], shape: tuple[int, int],
              circle: Circle, sigma: float) -> Pointing:
    """The measured circle as a :class:`Pointing` (the first estimate: the rig file's camera
    direction at the read-back joints)."""
    k = rig.camera.intrinsics
    if k is None:
        raise CalibrationError(f"{rig.path}: an image-based rig needs [camera.intrinsics]")
    intrinsics = k.at(shape)
    camera_dir = planner.kinematics.forward_geometry(at).camera_dir
    ex, ey = PinholeCamera.looking_at_origin(intrinsics, shape, camera_dir,
                                             rig.camera_distance_m).project(
        np.asarray(rig.sample.centre_m, float))
    radius = circle.radius + EDGE_INSET_PX
    approach = {n: 1 for n in at}
    return Pointing(
        CentreObservation(dict(at), approach, circle.x, circle.y, sigma), shape,
        math.degrees(math.atan((float(ex) - circle.x) / k.fx)),
        math.degrees(math.atan((float(ey) - circle.y) / k.fy)),
        radius, rig.sample.radius_m * math.sqrt(1.0 + (k.fx / radius) ** 2))
