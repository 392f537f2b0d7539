"""The simulated camera's own optics: what every superpixel of an image-based rig's camera sees.

A referee: this computes the TRUE per-pixel geometry with code of its own and never calls the
reduction's per-pixel geometry (:mod:`acquisition.reduction.imaging`) that it judges; the two
share only the conventions the rig file defines, stated here as this module applies them.

Conventions
-----------
* Superpixel (row i, column j) is centred at image point (x, y) = (j, i) (the rig file's
  :class:`~acquisition.config.rig.CameraIntrinsics`); a camera-frame point (X, Y, Z) (X right,
  Y down, Z forward) images at x = fx·X/Z + cx, y = fy·Y/Z + cy; a missing principal point is
  the image centre ((w − 1)/2, (h − 1)/2).
* The camera stands ``camera_distance_m`` along its unit direction c from the origin and looks
  at the origin with the sample frame's +z up in its image. In c's spherical angles (θ from
  +z, φ from +x towards +y) its axes are right = e_φ, down = e_θ, forward = −c; at the zenith
  (sin θ < :data:`ZENITH_SIN`) φ counts as 0, so up is −x.
* A pointing error (x°, y°) turns the optical axis onto the unturned camera's ray through image
  point (cx + fx·tan x, cy + fy·tan y) (so the point it aimed at shows fx·tan x, fy·tan y
  superpixels towards −x, −y); the image x axis stays in the plane of the old x axis and the
  new optical axis (Gram–Schmidt).
* The flat sample (and the white plate) is a square of edge ``size_m`` centred on the z axis in
  the plane z = h, seen from above; the sphere has ``radius_m`` and its centre at ``centre_m``
  + (0, 0, h); h is the sample's height error (0 on an aligned rig).
* A pixel's local shading frame has the surface normal as +z; its tangent is the sample
  frame's x axis (y where the normal is within 45° of x) made perpendicular to the normal, its
  bitangent normal × tangent; on the flat sample that is the sample frame itself. Simulated
  materials are isotropic: only the angles between normal, wi and wo matter.
* A lat-long environment map's row i is the polar band θ ∈ π·[i, i + 1]/H, column j the
  azimuths 2π·[j, j + 1]/W; its pixel direction is the cell's centre and its solid angle the
  cell's exact area, (4π/W)·sin θc·sin(π/2H) (sr): that of :mod:`acquisition.formats.envmap`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from acquisition.config.rig import RigConfig
from drivers.errors import ConfigError

ZENITH_SIN = 1e-9
"""sin θ of the camera direction below which the camera is at the zenith (up = −x)."""


# ---------------------------------------------------------------------------- the camera
def intrinsics_of(rig: RigConfig, shape: tuple[int, int]) -> tuple[float, float, float, float]:
    """(fx, fy, cx, cy) in superpixels for an image of ``shape`` (rows, columns)."""
    k = rig.camera.intrinsics
    if k is None:
        raise ConfigError(f"{rig.path}: the simulated camera of an image-based rig renders "
                          "through its pinhole model: add [camera.intrinsics] with fx (superpixels)")
    rows, cols = shape
    return (float(k.fx), float(k.fy), (cols - 1) / 2.0 if k.cx is None else float(k.cx),
            (rows - 1) / 2.0 if k.cy is None else float(k.cy))


def camera_axes(camera_dir: np.ndarray) -> np.ndarray:
    """(3, 3) rows: the camera's right, down and forward axes for a camera along
    ``camera_dir`` looking at the origin (e_φ, e_θ, −c; see the module docstring)."""
    c = np.asarray(camera_dir, dtype=np.float64)
    c = c / math.sqrt(float(c @ c))
    sin_t = math.hypot(c[0], c[1])
    cos_t = float(c[2])
    cos_p, sin_p = (c[0] / sin_t, c[1] / sin_t) if sin_t >= ZENITH_SIN else (1.0, 0.0)
    right = np.array([-sin_p, cos_p, 0.0])
    down = np.array([cos_t * cos_p, cos_t * sin_p, -sin_t])
    return np.stack([right, down, -c])


def pointed_axes(axes: np.ndarray, pointing_deg: tuple[float, float]) -> np.ndarray:
    """``axes`` with the optical axis turned by the pointing error (x°, y°) (module docstring)."""
    x_deg, y_deg = pointing_deg
    if not x_deg and not y_deg:
        return axes
    turned = np.array([math.tan(math.radians(x_deg)), math.tan(math.radians(y_deg)), 1.0]) @ axes
    q, r = np.linalg.qr(np.column_stack([turned, axes[0], axes[1]]))
    q = q * np.sign(np.diag(r))
    return np.stack([q[:, 1], q[:, 2], q[:, 0]])


def camera_rays(rig: RigConfig, camera_dir: np.ndarray, shape: tuple[int, int],
                pointing_deg: tuple[float, float] = (0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """The camera's centre of projection (3,) (m) and the unit ray (rows, columns, 3) through
    every superpixel's centre, in the sample frame."""
    fx, fy, cx, cy = intrinsics_of(rig, shape)
    aimed = camera_axes(camera_dir)
    axes = pointed_axes(aimed, pointing_deg)
    rows, cols = shape
    x = np.broadcast_to(((np.arange(cols) - cx) / fx)[None, :], shape)
    y = np.broadcast_to(((np.arange(rows) - cy) / fy)[:, None], shape)
    v = np.stack([x, y, np.ones(shape)], axis=-1)
    v /= np.sqrt(x * x + y * y + 1.0)[..., None]
    return aimed[2] * -rig.camera_distance_m, v @ axes


# ---------------------------------------------------------------------------- the surfaces
def ray_plane(origin: np.ndarray, rays: np.ndarray, height_m: float, edge_m: float
              ) -> tuple[np.ndarray, np.ndarray]:
    """Rays from ``origin`` (above the plane) against the square of edge ``edge_m`` in the
    plane z = ``height_m``: hit mask (rows, columns) and the hit points (N, 3), m."""
    drop = origin[2] - height_m
    descent = -rays[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        reach = drop / descent  # distance along the ray to the plane
    x = origin[0] + reach * rays[..., 0]
    y = origin[1] + reach * rays[..., 1]
    half = edge_m / 2.0
    hit = (drop > 0) & (descent > 0) & (np.abs(x) <= half) & (np.abs(y) <= half)
    return hit, np.column_stack([x[hit], y[hit], np.full(int(hit.sum()), height_m)])


def ray_sphere(origin: np.ndarray, rays: np.ndarray, centre_m: np.ndarray, radius_m: float
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rays (unit) from ``origin`` outside the sphere against it: hit mask (rows, columns), the
    nearest hit points (N, 3) (m) and their unit outward normals (N, 3).

    Each ray is solved from its closest approach to the centre and the half chord there, the
    half chord from the explicit centre → closest-approach vector (not from a difference of
    squared distances); rays whose closest approach is plainly outside are culled first."""
    rel = origin - centre_m  # the camera seen from the sphere's centre
    along = -(rays @ rel)  # distance to each ray's closest approach
    far2 = float(rel @ rel)
    miss2 = far2 - along * along  # (closest approach)², rough (cancellation): a cull only
    hit = (miss2 <= radius_m * radius_m + 1e-9 * far2) & (along > 0.0)
    d, along = rays[hit], along[hit]
    closest = rel + along[:, None] * d  # centre → closest approach
    half2 = radius_m * radius_m - np.einsum("nk,nk->n", closest, closest)
    half = np.sqrt(np.maximum(half2, 0.0))
    outward = closest - half[:, None] * d  # centre → the nearer intersection
    meets = (half2 >= 0.0) & (along > half)  # the ray meets the sphere, ahead of the camera
    if not meets.all():
        hit[hit] = meets
        outward = outward[meets]
    normals = outward / np.sqrt(np.einsum("nk,nk->n", outward, outward))[:, None]
    return hit, centre_m + outward, normals


def shading_frames(normals: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rows: tangent, bitangent, normal (module docstring). With the helper axis x
    the tangent is (s, −nx·ny/s, −nx·nz/s) and the bitangent (0, nz, −ny)/s, s = |(ny, nz)|;
    with y, (−nx·ny/s, s, −ny·nz/s) and (−nz, 0, nx)/s, s = |(nx, nz)|."""
    nx, ny, nz = np.ascontiguousarray(normals.T)
    use_y = nx * nx >= 0.5
    s = np.sqrt(np.where(use_y, nx * nx, ny * ny) + nz * nz)
    inv = 1.0 / s
    frames = np.empty((3, 3, len(normals)))  # filled component by component, contiguously
    mixed = -nx * ny * inv
    frames[0, 0] = np.where(use_y, mixed, s)
    frames[0, 1] = np.where(use_y, s, mixed)
    frames[0, 2] = np.where(use_y, -ny, -nx) * nz * inv
    frames[1, 0] = np.where(use_y, -nz * inv, 0.0)
    frames[1, 1] = np.where(use_y, 0.0, nz * inv)
    frames[1, 2] = np.where(use_y, nx, -ny) * inv
    frames[2] = (nx, ny, nz)
    return frames.transpose(2, 0, 1)


def to_local(frames: np.ndarray, world: np.ndarray) -> np.ndarray:
    """Vectors (N, 3) of the sample frame in the local ``frames`` (N, 3, 3)."""
    return np.einsum("nij,nj->ni", frames, world)


@dataclass(frozen=True)
class TargetSurface:
    """The surface a render sees: a sphere of radius ``size_m`` about ``centre_m`` (m), or
    the square plate of edge ``size_m`` centred at ``centre_m`` in the plane z = centre z."""

    sphere: bool
    centre_m: np.ndarray
    size_m: float


def target_surface(rig: RigConfig, target_shape: str | None = None, height_m: float = 0.0
                   ) -> TargetSurface:
    """The rig's sample (``target_shape="flat"``: the white plate) raised by ``height_m``
    (m); raises ConfigError for an unknown shape."""
    sample = rig.sample
    kind = target_shape or sample.shape
    if kind == "flat":
        return TargetSurface(False, np.array([0.0, 0.0, height_m]), float(sample.size_m))
    if kind == "sphere":
        centre = np.asarray(sample.centre_m, dtype=np.float64) + [0.0, 0.0, height_m]
        return TargetSurface(True, centre, float(sample.radius_m))
    raise ConfigError(f"sample shape '{kind}' is unknown: use 'flat' or 'sphere'")


# ---------------------------------------------------------------------------- what a pixel sees
@dataclass(frozen=True)
class SurfaceView:
    """The pixels that see the surface's front, and what each sees.

    Attributes
    ----------
    mask:
        (rows, columns) bool: the pixel's ray meets the surface where it faces the camera.
    points, frames:
        For the ``mask`` pixels in C order: the surface points (N, 3, m, sample frame) and
        their local shading frames (N, 3, 3; rows tangent, bitangent, normal).
    wo:
        (N, 3) unit directions to the camera in the local frames.
    """

    mask: np.ndarray
    points: np.ndarray
    frames: np.ndarray
    wo: np.ndarray

    def lit_by(self, light_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A point light at ``light_m`` (3,), m: which pixels it lights (N,) bool, and for
        those the unit light direction in the local frame (M, 3) and cos θi / r² (M,), m⁻²."""
        to_light = np.asarray(light_m, dtype=np.float64) - self.points
        r2 = np.einsum("nk,nk->n", to_light, to_light)
        wi = to_local(self.frames, to_light) / np.sqrt(r2)[:, None]
        lit = wi[:, 2] > 0.0
        return lit, wi[lit], wi[lit, 2] / r2[lit]

    def scatter(self, values: np.ndarray) -> np.ndarray:
        """Image (rows, columns, …) of ``values`` (N, …) at the mask pixels, 0 elsewhere."""
        out = np.zeros(self.mask.shape + values.shape[1:])
        out[self.mask] = values
        return out


def surface_view(rig: RigConfig, camera_dir: np.ndarray, shape: tuple[int, int],
                 target_shape: str | None = None, *, pointing_deg: tuple[float, float] = (0.0, 0.0),
                 height_m: float = 0.0) -> SurfaceView:
    """What the rig's camera along ``camera_dir`` sees of the sample (``target_shape="flat"``:
    of the flat white plate), pointed by ``pointing_deg`` (deg), the sample ``height_m`` (m)
    above its nominal place."""
    origin, rays = camera_rays(rig, camera_dir, shape, pointing_deg)
    surface = target_surface(rig, target_shape, height_m)
    if surface.sphere:
        hit, points, normals = ray_sphere(origin, rays, surface.centre_m, surface.size_m)
        frames = shading_frames(normals)
    else:
        hit, points = ray_plane(origin, rays, height_m, surface.size_m)
        frames = np.broadcast_to(np.eye(3), (len(points), 3, 3))
    to_camera = origin - points
    to_camera /= np.sqrt(np.einsum("nk,nk->n", to_camera, to_camera))[:, None]
    wo = to_local(frames, to_camera)
    facing = wo[:, 2] > 0.0
    if not facing.all():  # rays that graze the sphere's rim
        hit[hit] = facing
        points, frames, wo = points[facing], frames[facing], wo[facing]
    return SurfaceView(hit, points, frames, wo)


# ---------------------------------------------------------------------------- the environment
def latlong_cells(shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """A lat-long map's pixel directions (H, W, 3) and exact cell solid angles (H, W), sr."""
    rows, cols = shape
    theta = math.pi * (np.arange(rows) + 0.5) / rows
    phi = 2.0 * math.pi * (np.arange(cols) + 0.5) / cols
    sin_t, cos_t = np.sin(theta)[:, None, None], np.cos(theta)[:, None, None]
    around = np.stack([np.cos(phi), np.sin(phi), np.zeros(cols)], axis=-1)[None]
    dirs = sin_t * around + cos_t * np.array([0.0, 0.0, 1.0])
    omega = 4.0 * math.pi / cols * math.sin(math.pi / (2 * rows)) * np.sin(theta)
    return dirs, np.repeat(omega[:, None], cols, axis=1)
