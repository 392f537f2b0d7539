"""The pinhole camera of an image-based rig, in the sample frame (metres, superpixels).

Conventions (the rig file's; :mod:`acquisition.reduction.imaging` applies them per pixel, the
geometric calibration to the pixels it reads):

* pixel (row i, column j) is centred at image coordinates (x, y) = (j, i); x grows to the
  right, y downwards, and the camera looks along its +z axis (OpenCV's pinhole model):
  x = fx · X/Z + cx, y = fy · Y/Z + cy;
* the camera sits ``camera_distance_m`` along the camera direction from the origin and looks
  at the origin; image "up" is the sample frame's +z projected onto the image plane; with the
  camera exactly at the zenith, up is −x (the limit of that rule at azimuth 0);
* a pointing error (x°, y°) turns the optical axis towards the image's +x by ``x``, then +y
  by ``y`` (the point it aimed at moves to −x, −y), the image x axis kept in the plane of the
  old one and the new optical axis.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

ZENITH_TOLERANCE = 1e-9
"""|sin θ| below which the camera counts as exactly at the zenith (up = −x)."""


def camera_rotations(camera_dirs: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rows: the right, down and forward axes of cameras along ``camera_dirs``
    (N, 3) looking at the origin (module docstring)."""
    c = np.asarray(camera_dirs, dtype=np.float64)
    c = c / np.linalg.norm(c, axis=-1, keepdims=True)
    up = np.array([0.0, 0.0, 1.0]) - c[:, 2:3] * c  # +z projected onto the image plane
    norm = np.linalg.norm(up, axis=-1, keepdims=True)
    fallback = np.where(c[:, 2:3] > 0, [[-1.0, 0.0, 0.0]], [[1.0, 0.0, 0.0]])
    up = np.where(norm < ZENITH_TOLERANCE, fallback, up / np.maximum(norm, ZENITH_TOLERANCE))
    right = np.cross(-c, up)
    right /= np.linalg.norm(right, axis=-1, keepdims=True)
    return np.stack([right, np.cross(-c, right), -c], axis=1)


def pointed_rotations(rotations: np.ndarray, x_deg: float, y_deg: float) -> np.ndarray:
    """``rotations`` (N, 3, 3) with the optical axis turned by the pointing error (x°, y°)
    (module docstring)."""
    if not x_deg and not y_deg:
        return rotations
    right, down, forward = rotations[:, 0], rotations[:, 1], rotations[:, 2]
    f = forward + np.tan(np.radians(x_deg)) * right + np.tan(np.radians(y_deg)) * down
    f /= np.linalg.norm(f, axis=-1, keepdims=True)
    r = right - np.sum(right * f, axis=-1, keepdims=True) * f
    r /= np.linalg.norm(r, axis=-1, keepdims=True)
    return np.stack([r, np.cross(f, r), f], axis=1)


@dataclass(frozen=True)
class PinholeCamera:
    """A calibrated pinhole camera in the sample frame.

    Attributes
    ----------
    fx, fy, cx, cy:
        Intrinsics in superpixels.
    shape:
        Image size (rows, columns) in superpixels.
    position:
        Centre of projection (3,), m.
    rotation:
        (3, 3) rows = the camera's x (right), y (down) and z (forward) axes in the sample frame.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    shape: tuple[int, int]
    position: np.ndarray
    rotation: np.ndarray

    @classmethod
    def looking_at_origin(
        cls,
        intrinsics: tuple[float, float, float, float],
        shape: tuple[int, int],
        camera_dir: np.ndarray,
        distance_m: float,
    ) -> PinholeCamera:
        """Camera ``distance_m`` along unit ``camera_dir`` looking at the origin (see module doc)."""
        c = np.asarray(camera_dir, dtype=np.float64)
        c = c / np.linalg.norm(c)
        fx, fy, cx, cy = intrinsics
        return cls(fx, fy, cx, cy, shape, c * distance_m, camera_rotations(c[None])[0])

    def pointed(self, x_deg: float, y_deg: float) -> PinholeCamera:
        """The camera with its optical axis turned towards its image's +x by ``x_deg``, then
        towards +y by ``y_deg`` (a pointing error: the point it aimed at moves to −x, −y)."""
        if not x_deg and not y_deg:
            return self
        return replace(self, rotation=pointed_rotations(self.rotation[None], x_deg, y_deg)[0])

    def ray_directions(self, pixels: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """Unit ray directions (rows, columns, 3) through every pixel centre, sample frame;
        with ``pixels`` (rows, columns: index arrays of length K), (K, 3) through those."""
        rx, ry, rz = self.rotation
        if pixels is not None:
            x = (np.asarray(pixels[1], dtype=np.float64) - self.cx) / self.fx
            y = (np.asarray(pixels[0], dtype=np.float64) - self.cy) / self.fy
            d = x[:, None] * rx + y[:, None] * ry + rz
        else:
            h, w = self.shape
            x = (np.arange(w, dtype=np.float64) - self.cx) / self.fx
            y = (np.arange(h, dtype=np.float64) - self.cy) / self.fy
            d = x[None, :, None] * rx + y[:, None, None] * ry + rz
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        return d

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Image coordinates (x, y) in superpixels of points (…, 3) in the sample frame."""
        cam = (np.asarray(points, dtype=np.float64) - self.position) @ self.rotation.T
        with np.errstate(divide="ignore", invalid="ignore"):
            return (self.fx * cam[..., 0] / cam[..., 2] + self.cx,
                    self.fy * cam[..., 1] / cam[..., 2] + self.cy)
