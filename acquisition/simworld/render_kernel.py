"""The simulated camera's compiled renderer: an image-based frame in one compiled pass.

What each superpixel sees, with the conventions and operations of
:mod:`acquisition.simworld.optics` (``camera_rays``, ``ray_sphere`` / ``ray_plane``,
``shading_frames``, ``SurfaceView.lit_by``) and :func:`acquisition.simworld.scene.render_view`:
the camera ray through its centre, the ray's nearest hit on the sphere (or the square plate),
the local shading frame there, the unit direction to the camera, then for each of the lamp's m
points the light direction, cos θi / r² (m⁻²) and the material's BRDF
(:mod:`simulators.material_kernels`, sr⁻¹): L = (1/m) · Σ f(wi, wo) · I · cos θi / r²
(W·sr⁻¹·m⁻²). A row at a time: which columns' rays meet the surface (every superpixel costs
only this test), then for those alone their geometry, each lamp point's light and BRDF, in
short loops over row buffers that LLVM vectorises; no (h·w, 3) temporaries. Rows go to numba's
thread pool on frames of :data:`PARALLEL_MIN_SUPERPIXELS` or more, the same bits either way.

The numpy path (:func:`acquisition.simworld.scene.render_image_numpy`) stays the reference, and
renders materials without a compiled evaluator (measured ones); ``tests/test_render_kernel.py``
holds the two to 1e-9 relative (1e-12 of the brightest pixel at the terminator, where
cos θi → 0 amplifies either path's rounding).

Numba's on-disk cache is invalidated by a change to a function's own file only, and these
kernels call :func:`simulators.material_kernels.accumulate_packed`, whose machine code is linked
into theirs: so on import, when that file's source differs from the one the cached code was
compiled with, this module's cached code is deleted first (:func:`_forget_stale_code`).
"""

from __future__ import annotations

import math

import numba
import numpy as np

import simulators.material_kernels as material_kernels
from acquisition.config.rig import RigConfig
from acquisition.simworld.optics import camera_axes, intrinsics_of, pointed_axes, target_surface
from drivers.numba_cache import drop_stale_cache
from simulators.exposure import PARALLEL_MIN_PIXELS

drop_stale_cache(__file__, (material_kernels.__file__,))  # numba sees this file only
accumulate_packed = material_kernels.accumulate_packed

PARALLEL_MIN_SUPERPIXELS = PARALLEL_MIN_PIXELS // 4
"""Frames of fewer superpixels are rendered on one thread (the exposure's threshold: waking
numba's thread pool costs more than it saves on the example rigs' small frames)."""

_JIT = {"cache": True, "nogil": True, "error_model": "numpy"}
_INLINE = {**_JIT, "inline": "always"}  # per-pixel helpers: inside the loops, which vectorise


def render_frame(rig: RigConfig, camera_dir: np.ndarray, shape: tuple[int, int],
                 target_shape: str | None, light_points: np.ndarray,
                 packed: tuple[int, np.ndarray], intensity_w_per_sr: float, *,
                 pointing_deg: tuple[float, float] = (0.0, 0.0), height_m: float = 0.0
                 ) -> np.ndarray:
    """Radiance image (rows, columns, 3), W·sr⁻¹·m⁻², of the sample (``target_shape="flat"``:
    the white plate, raised by ``height_m``, m) seen by the rig's camera along ``camera_dir``
    pointed by ``pointing_deg`` (deg), under a lamp of ``intensity_w_per_sr`` made of
    ``light_points`` (m, 3; m) sharing it, for a material packed by
    :func:`simulators.material_kernels.packed_material`; black off the sample."""
    surface = target_surface(rig, target_shape, height_m)
    aimed = camera_axes(camera_dir)
    axes = np.ascontiguousarray(pointed_axes(aimed, pointing_deg), dtype=np.float64)
    camera = np.concatenate([aimed[2] * -rig.camera_distance_m, axes.ravel(),
                             intrinsics_of(rig, shape)])
    target = np.array([*surface.centre_m, surface.size_m], dtype=np.float64)
    lights = np.ascontiguousarray(light_points, dtype=np.float64).reshape(-1, 3)
    kind, params = packed
    out = np.empty((*shape, 3))
    kernel = _render_parallel if shape[0] * shape[1] >= PARALLEL_MIN_SUPERPIXELS else _render_serial
    kernel(camera, surface.sphere, target, lights, float(intensity_w_per_sr), kind, params, out)
    return out


@numba.njit(parallel=True, **_JIT)
def _render_parallel(camera, sphere, target, lights, intensity, kind, params,
                     out):  # pragma: no cover - compiled
    """:func:`render_frame`'s rows on numba's thread pool."""
    for i in numba.prange(out.shape[0]):
        _render_row(i, camera, sphere, target, lights, intensity, kind, params, out)


@numba.njit(**_JIT)
def _render_serial(camera, sphere, target, lights, intensity, kind, params,
                   out):  # pragma: no cover - compiled
    """:func:`render_frame`'s rows on the calling thread."""
    for i in range(out.shape[0]):
        _render_row(i, camera, sphere, target, lights, intensity, kind, params, out)


# Layout of ``camera``: the centre of projection (3, m), the axes right, down, forward (3 × 3,
# rows), then fx, fy, cx, cy (superpixels). ``target``: the sphere's centre or the plate's
# (3, m), then the radius or the plate's edge (m). A row's geometry ``geo`` holds per
# superpixel that sees the surface: the point (0–2, m), the local frame's tangent (3–5),
# bitangent (6–8) and normal (9–11), the unit direction to the camera in it (12–14) and
# whether the surface faces the camera (15, 1.0 or 0.0).
_GEO_ROWS = 16


@numba.njit(**_INLINE)
def _ray(camera, i, j):  # pragma: no cover - compiled
    """``optics.camera_rays``: the unit ray (sample frame) through superpixel (i, j)'s centre."""
    x = (j - camera[14]) / camera[12]
    y = (i - camera[15]) / camera[13]
    s = math.sqrt(x * x + y * y + 1.0)
    vx, vy, vz = x / s, y / s, 1.0 / s
    return (vx * camera[3] + vy * camera[6] + vz * camera[9],
            vx * camera[4] + vy * camera[7] + vz * camera[10],
            vx * camera[5] + vy * camera[8] + vz * camera[11])


@numba.njit(**_INLINE)
def _sphere_hit(camera, target, d):  # pragma: no cover - compiled
    """``optics.ray_sphere`` for one ray ``d``: (meets, outward vector centre → hit (m))."""
    rx, ry, rz = camera[0] - target[0], camera[1] - target[1], camera[2] - target[2]
    radius = target[3]
    along = -(d[0] * rx + d[1] * ry + d[2] * rz)
    far2 = rx * rx + ry * ry + rz * rz
    cx, cy, cz = rx + along * d[0], ry + along * d[1], rz + along * d[2]
    half2 = radius * radius - (cx * cx + cy * cy + cz * cz)
    half = math.sqrt(max(half2, 0.0))
    meets = ((far2 - along * along <= radius * radius + 1e-9 * far2) & (along > 0.0)
             & (half2 >= 0.0) & (along > half))
    return meets, cx - half * d[0], cy - half * d[1], cz - half * d[2]


@numba.njit(**_INLINE)
def _plate_hit(camera, target, d):  # pragma: no cover - compiled
    """``optics.ray_plane`` for one ray ``d``: (meets, the hit point's x, y (m))."""
    drop = camera[2] - target[2]
    descent = -d[2]
    reach = drop / descent
    x, y = camera[0] + reach * d[0], camera[1] + reach * d[1]
    half = target[3] / 2.0
    return (drop > 0.0) & (descent > 0.0) & (abs(x) <= half) & (abs(y) <= half), x, y


@numba.njit(**_INLINE)
def _seen(i, camera, sphere, target, columns):  # pragma: no cover - compiled
    """The columns of row ``i`` whose ray meets the surface, into ``columns``; their count."""
    w = columns.shape[0]
    meets = np.empty(w, dtype=np.bool_)
    for j in range(w):  # branch-free: LLVM vectorises it
        d = _ray(camera, i, j)
        meets[j] = _sphere_hit(camera, target, d)[0] if sphere else _plate_hit(camera, target, d)[0]
    n = 0
    for j in range(w):
        if meets[j]:
            columns[n] = j
            n += 1
    return n


@numba.njit(**_INLINE)
def _sphere_geometry(i, camera, target, columns, n, geo):  # pragma: no cover - compiled
    """``geo`` (module layout) of the ``n`` superpixels of row ``i`` in ``columns``, all on
    the sphere: ``ray_sphere``, ``shading_frames``, ``surface_view``."""
    for q in range(n):
        d = _ray(camera, i, columns[q])
        ox, oy, oz = _sphere_hit(camera, target, d)[1:]
        norm = math.sqrt(ox * ox + oy * oy + oz * oz)
        nx, ny, nz = ox / norm, oy / norm, oz / norm
        use_y = nx * nx >= 0.5
        s = math.sqrt((nx * nx if use_y else ny * ny) + nz * nz)
        inv = 1.0 / s
        mixed = -nx * ny * inv
        geo[0, q], geo[1, q], geo[2, q] = target[0] + ox, target[1] + oy, target[2] + oz
        geo[3, q] = mixed if use_y else s
        geo[4, q] = s if use_y else mixed
        geo[5, q] = (-ny if use_y else -nx) * nz * inv
        geo[6, q] = -nz * inv if use_y else 0.0
        geo[7, q] = 0.0 if use_y else nz * inv
        geo[8, q] = (nx if use_y else -ny) * inv
        geo[9, q], geo[10, q], geo[11, q] = nx, ny, nz


@numba.njit(**_INLINE)
def _plate_geometry(i, camera, target, columns, n, geo):  # pragma: no cover - compiled
    """``geo`` (module layout) of the ``n`` superpixels of row ``i`` in ``columns``, all on
    the plate, whose local frame is the sample frame."""
    for q in range(n):
        x, y = _plate_hit(camera, target, _ray(camera, i, columns[q]))[1:]
        geo[0, q], geo[1, q], geo[2, q] = x, y, target[2]
        geo[3, q], geo[4, q], geo[5, q] = 1.0, 0.0, 0.0
        geo[6, q], geo[7, q], geo[8, q] = 0.0, 1.0, 0.0
        geo[9, q], geo[10, q], geo[11, q] = 0.0, 0.0, 1.0


@numba.njit(**_INLINE)
def _local(geo, q, x, y, z):  # pragma: no cover - compiled
    """Vector (x, y, z) of the sample frame in superpixel ``q``'s local frame (``to_local``)."""
    return (geo[3, q] * x + geo[4, q] * y + geo[5, q] * z,
            geo[6, q] * x + geo[7, q] * y + geo[8, q] * z,
            geo[9, q] * x + geo[10, q] * y + geo[11, q] * z)


@numba.njit(**_INLINE)
def _view(camera, n, geo):  # pragma: no cover - compiled
    """``geo``'s unit directions to the camera (local) and whether the surface faces it."""
    for q in range(n):
        cx, cy, cz = camera[0] - geo[0, q], camera[1] - geo[1, q], camera[2] - geo[2, q]
        to_camera = math.sqrt(cx * cx + cy * cy + cz * cz)
        ox, oy, oz = _local(geo, q, cx / to_camera, cy / to_camera, cz / to_camera)
        geo[12, q], geo[13, q], geo[14, q] = ox, oy, oz
        geo[15, q] = 1.0 if oz > 0.0 else 0.0  # not: a ray that grazes the sphere's rim


@numba.njit(**_INLINE)
def _lit(light, intensity, n, geo, wi):  # pragma: no cover - compiled
    """``SurfaceView.lit_by``: the unit light directions (local) into ``wi`` rows 0–2 and
    I · cos θi / r² (W·sr⁻¹·m⁻²) into row 3, 0 where unlit or not seen."""
    for q in range(n):
        lx, ly, lz = light[0] - geo[0, q], light[1] - geo[1, q], light[2] - geo[2, q]
        r2 = lx * lx + ly * ly + lz * lz
        ix, iy, iz = _local(geo, q, lx, ly, lz)
        root = math.sqrt(r2)
        wi[0, q], wi[1, q], wi[2, q] = ix / root, iy / root, iz / root
        lit = (wi[2, q] > 0.0) & (geo[15, q] != 0.0)
        wi[3, q] = intensity * (wi[2, q] / r2) if lit else 0.0


@numba.njit(**_INLINE)
def _render_row(i, camera, sphere, target, lights, intensity, kind, params,
                out):  # pragma: no cover - compiled
    """Row ``i`` of :func:`render_frame`: the columns that see the surface, their geometry,
    each lamp point's light and BRDF summed, the mean over the lamp's points."""
    w = out.shape[1]
    out[i] = 0.0
    columns = np.empty(w, dtype=np.int64)
    n = _seen(i, camera, sphere, target, columns)
    if n == 0:
        return
    geo = np.empty((_GEO_ROWS, n))
    if sphere:
        _sphere_geometry(i, camera, target, columns, n, geo)
    else:
        _plate_geometry(i, camera, target, columns, n, geo)
    _view(camera, n, geo)
    wi = np.empty((4, n))
    radiance = np.zeros((3, n))
    for k in range(lights.shape[0]):
        _lit(lights[k], intensity, n, geo, wi)
        accumulate_packed(kind, params, n, wi, geo[12:15], wi[3], radiance)
    m = lights.shape[0]
    for q in range(n):
        j = columns[q]
        out[i, j, 0], out[i, j, 1], out[i, j, 2] = (radiance[0, q] / m, radiance[1, q] / m,
                                                    radiance[2, q] / m)
