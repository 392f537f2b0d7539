"""Per-pixel measurement geometry: a calibrated pinhole camera looking at a flat or spherical sample.

Everything is expressed in the sample frame (normal of the flat sample +z, origin at the point
the arms aim at), in metres. For one frame, :func:`pixel_geometry` gives for every pixel that
sees a lit part of the sample its light direction ``wi`` and view direction ``wo`` in the local
shading frame (surface normal +z) and the point light's irradiance term cos θi / r² (m⁻²), so
that the radiance the pixel sees is

    L = f(wi, wo) · I · cos θi / r²        [W·sr⁻¹·m⁻²]

with I the light's radiant intensity (W·sr⁻¹) and r the light–surface distance.

Conventions
-----------
* Pixels are superpixels (2×2 CFA cells, the grid of :func:`calibration.linearize.linearize`);
  the camera is :class:`~acquisition.geometry.pinhole.PinholeCamera` (its module states the
  conventions: pixel centres, image axes, the camera looking at the origin, image "up" the
  sample frame's +z projected, the pointing error).
* The light is a point source ``light_distance_m`` along the light direction.
* The local shading frame's tangents follow Duff et al. (2017), "Building an orthonormal
  basis, revisited"; for the flat sample it is the sample frame itself. Isotropic BRDFs do not
  depend on the tangents' azimuth, only on its being the same for ``wi`` and ``wo``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from acquisition.config.rig import CameraIntrinsics, RigConfig, SampleConfig
from acquisition.geometry.pinhole import PinholeCamera
from acquisition.reduction.fixedorder import dot3, norm3
from acquisition.tables.backend import resolve_backend
from calibration import recycling
from drivers.errors import ConfigError

Pixels = tuple[np.ndarray, np.ndarray]
"""Pixel indices (rows, columns), superpixels, each of length K."""


# ---------------------------------------------------------------------------- camera
def camera_intrinsics(rig: RigConfig, shape: tuple[int, int]) -> tuple[float, float, float, float]:
    """(fx, fy, cx, cy) in superpixels; a missing principal point is the image centre."""
    k: CameraIntrinsics | None = rig.camera.intrinsics
    if k is None:
        raise ConfigError(
            f"{rig.path}: image-based measurement needs the camera's pinhole model: "
            "add [camera.intrinsics] with fx (superpixels)"
        )
    return k.at(shape)


# ---------------------------------------------------------------------------- sample shapes
@dataclass(frozen=True)
class Hits:
    """Ray–sample intersections: ``hit`` (rows, columns) and, for the hit pixels only (in C
    order), the surface points (N, 3, m) and unit outward normals (N, 3)."""

    hit: np.ndarray
    points: np.ndarray
    normals: np.ndarray


def intersect_flat(
    origin: np.ndarray, dirs: np.ndarray, size_m: float
) -> Hits:
    """Rays against a square of edge ``size_m`` in the plane z = 0, centred at the origin,
    seen from above (normal +z)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -origin[2] / dirs[..., 2]
    half = size_m / 2.0
    x = origin[0] + t * dirs[..., 0]
    y = origin[1] + t * dirs[..., 1]
    hit = (t > 0) & (np.abs(x) <= half) & (np.abs(y) <= half) & (origin[2] > 0)
    points = np.stack([x[hit], y[hit], np.zeros(int(hit.sum()))], axis=-1)
    normals = np.broadcast_to(np.array([0.0, 0.0, 1.0]), points.shape)
    return Hits(hit, points, normals)


def intersect_sphere(
    origin: np.ndarray, dirs: np.ndarray, radius_m: float, centre_m: np.ndarray
) -> Hits:
    """Rays (unit ``dirs``) against a sphere: the nearest intersection in front of the camera."""
    oc = origin - np.asarray(centre_m, dtype=np.float64)
    b = dot3(dirs, oc)
    disc = b * b - (dot3(oc, oc) - radius_m * radius_m)
    hit = disc >= 0.0
    with np.errstate(invalid="ignore"):
        t = -b[hit] - np.sqrt(disc[hit])
    front = t > 0
    if not front.all():
        hit[hit] = front
        t = t[front]
    points = origin + t[:, None] * dirs[hit]
    normals = (points - centre_m) / radius_m
    normals /= norm3(normals)[:, None]
    return Hits(hit, points, normals)


def intersect(sample: SampleConfig, origin: np.ndarray, dirs: np.ndarray,
              shape: str | None = None) -> Hits:
    """Rays against the rig's sample (or, with ``shape="flat"``, its flat white plate)."""
    kind = shape or sample.shape
    if kind == "flat":
        return intersect_flat(origin, dirs, sample.size_m)
    if kind == "sphere":
        return intersect_sphere(origin, dirs, sample.radius_m, np.asarray(sample.centre_m))
    raise ConfigError(f"sample shape '{kind}' is unknown: use 'flat' or 'sphere'")


def tangent_frames(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit tangents (N, 3) and bitangents (N, 3) completing ``normals`` to right-handed frames
    (Duff et al. 2017; for n = +z they are +x and +y)."""
    nx, ny, nz = normals[:, 0], normals[:, 1], normals[:, 2]
    sign = np.where(nz >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + nz)
    b = nx * ny * a
    t = np.stack([1.0 + sign * nx * nx * a, sign * b, -sign * nx], axis=-1)
    bt = np.stack([b, sign + ny * ny * a, -ny], axis=-1)
    return t, bt


# ---------------------------------------------------------------------------- compiled path
def frame_parameters(camera: PinholeCamera, light_pos: np.ndarray, sample: SampleConfig,
                     shape: str | None = None) -> np.ndarray:
    """What the compiled kernels need of a frame, float64 (layout: :mod:`.imaging_kernels`):
    the camera (superpixels, rotation, position in m), the light (m) and the sample (m), its
    scalars computed here as the numpy path computes them."""
    from acquisition.reduction import imaging_kernels as k

    kind = shape or sample.shape
    p = np.zeros(k.N_PARAMS)
    p[[k.FX, k.FY, k.CX, k.CY]] = camera.fx, camera.fy, camera.cx, camera.cy
    p[k.ROT:k.ROT + 9] = np.asarray(camera.rotation, np.float64).reshape(9)
    p[k.POS:k.POS + 3] = camera.position
    p[k.LIGHT:k.LIGHT + 3] = np.asarray(light_pos, dtype=np.float64)
    if kind == "flat":
        p[k.HALF] = sample.size_m / 2.0
    elif kind == "sphere":
        centre = np.asarray(sample.centre_m, dtype=np.float64)
        oc = np.asarray(camera.position, np.float64) - centre
        p[k.KIND], p[k.HALF] = 1.0, sample.radius_m
        p[k.CENTRE:k.CENTRE + 3], p[k.OC:k.OC + 3] = centre, oc
        p[k.C_SPHERE] = dot3(oc, oc) - sample.radius_m * sample.radius_m
    else:
        raise ConfigError(f"sample shape '{kind}' is unknown: use 'flat' or 'sphere'")
    return p


Columns = list[tuple[tuple[int, ...], type]]
"""Output columns of a compiled kernel: (shape of one row, dtype) each."""


def collect(run: Callable[[list[np.ndarray], int, int], tuple[int, int]], columns: Columns,
            total: int, capacity: int) -> list[np.ndarray]:
    """Rows a compiled kernel writes, in arrays grown as needed: ``run(arrays, n, start)``
    fills rows from ``n`` with the items from ``start`` on and returns (rows written, item
    stopped at), below ``total`` when the arrays are full. Returns the arrays' written rows
    (copied when they fill less than three quarters of their capacity)."""
    cap = max(1, int(capacity))
    arrays = [np.empty((cap, *shape), dtype) for shape, dtype in columns]
    n, start = 0, 0
    while True:
        n, start = run(arrays, n, start)
        if start >= total:
            break
        cap = 2 * cap
        grown = [np.empty((cap, *a.shape[1:]), a.dtype) for a in arrays]
        for g, a in zip(grown, arrays, strict=True):
            g[:n] = a[:n]
        arrays = grown
    return [a[:n].copy() if 4 * n < 3 * cap else a[:n] for a in arrays]


def _compiled_geometry(camera: PinholeCamera, light_pos: np.ndarray, sample: SampleConfig,
                       shape: str | None, pixels: Pixels | None) -> PixelGeometry:
    """:func:`pixel_geometry` in one compiled pass per pixel."""
    from acquisition.reduction import imaging_kernels as k

    p = frame_parameters(camera, light_pos, sample, shape)
    if pixels is None:
        rows = cols = np.zeros(0, np.int64)
        mask_shape: tuple[int, ...] = tuple(camera.shape)
    else:
        rows = np.ascontiguousarray(pixels[0], dtype=np.int64).reshape(-1)
        cols = np.ascontiguousarray(pixels[1], dtype=np.int64).reshape(-1)
        mask_shape = (rows.size,)
    mask = np.zeros(int(np.prod(mask_shape)), bool)
    width = int(camera.shape[1])
    wi, wo, irradiance = collect(
        lambda out, n, start: k.geometry(p, width, rows, cols, mask, *out, n, start),
        [((3,), np.float64), ((3,), np.float64), ((), np.float64)], mask.size, mask.size // 2)
    return PixelGeometry(mask.reshape(mask_shape), wi, wo, irradiance)


# ---------------------------------------------------------------------------- per pixel
@dataclass(frozen=True)
class PixelGeometry:
    """The measurement geometry of the pixels that see a lit, visible part of the sample.

    Attributes
    ----------
    mask:
        (rows, columns) bool (or (K,) for K given pixels): the pixel sees the sample, lit
        (cos θi > 0) and facing the camera (cos θr > 0).
    wi, wo:
        (N, 3) unit light and view directions in the local shading frame (normal +z), for the
        ``mask`` pixels in C order.
    irradiance:
        (N,) cos θi / r², m⁻²: times the light's intensity (W·sr⁻¹) the irradiance (W·m⁻²).
    """

    mask: np.ndarray
    wi: np.ndarray
    wo: np.ndarray
    irradiance: np.ndarray

    @property
    def count(self) -> int:
        return int(self.wi.shape[0])

    def scatter(self, values: np.ndarray, fill: float = 0.0) -> np.ndarray:
        """Per-pixel image (rows, columns, …) of ``values`` (N, …) given for the mask pixels."""
        out = np.full(self.mask.shape + values.shape[1:], fill, dtype=np.float64)
        out[self.mask] = values
        return out


def pixel_geometry(
    camera: PinholeCamera,
    light_pos: np.ndarray,
    sample: SampleConfig,
    shape: str | None = None,
    pixels: Pixels | None = None,
    *,
    backend: str | None = None,
) -> PixelGeometry:
    """Per-pixel wi, wo (local frame) and cos θi / r² for one camera and point-light position.

    ``shape`` overrides the sample's shape ("flat" for the white-reference plate); ``pixels``
    (rows, columns) restricts it to those pixels (the mask is then theirs, (K,)).
    ``backend``: "numba" (one compiled pass per pixel, :mod:`.imaging_kernels`) or "numpy"
    (the reference); default as the tables' (:func:`~acquisition.tables.backend.resolve_backend`).
    Both give the same arrays, bit for bit.
    """
    if resolve_backend(backend) == "numba":
        return _compiled_geometry(camera, light_pos, sample, shape, pixels)
    hits = intersect(sample, camera.position, camera.ray_directions(pixels), shape)
    to_light = np.asarray(light_pos, dtype=np.float64) - hits.points
    r2 = dot3(to_light, to_light)
    wi_world = to_light / np.sqrt(r2)[:, None]
    wo_world = camera.position - hits.points
    wo_world /= norm3(wo_world)[:, None]
    n = hits.normals
    cos_i = dot3(wi_world, n)
    cos_o = dot3(wo_world, n)
    keep = (cos_i > 0.0) & (cos_o > 0.0)
    mask = hits.hit.copy()
    mask[mask] = keep
    n, wi_world, wo_world = n[keep], wi_world[keep], wo_world[keep]
    t, b = tangent_frames(np.ascontiguousarray(n))

    def local(v: np.ndarray) -> np.ndarray:
        return np.stack([dot3(v, t), dot3(v, b), dot3(v, n)], axis=-1)

    wi, wo = local(wi_world), local(wo_world)
    return PixelGeometry(mask, wi, wo, wi[:, 2] / r2[keep])


def frame_camera(
    rig: RigConfig,
    light_dir: np.ndarray,
    camera_dir: np.ndarray,
    shape_superpixels: tuple[int, int],
    *,
    pointing_deg: tuple[float, float] = (0.0, 0.0),
    light_pos: np.ndarray | None = None,
) -> tuple[PinholeCamera, np.ndarray]:
    """The rig's camera (pointed) and the light's position (m) at the given arm directions
    (:func:`frame_geometry`'s arguments)."""
    camera = PinholeCamera.looking_at_origin(
        camera_intrinsics(rig, shape_superpixels), shape_superpixels, camera_dir,
        rig.camera_distance_m,
    ).pointed(*pointing_deg)
    if light_pos is None:
        light_pos = np.asarray(light_dir, dtype=np.float64) * rig.light_distance_m
    return camera, light_pos


def frame_geometry(
    rig: RigConfig,
    light_dir: np.ndarray,
    camera_dir: np.ndarray,
    shape_superpixels: tuple[int, int],
    target_shape: str | None = None,
    *,
    pointing_deg: tuple[float, float] = (0.0, 0.0),
    light_pos: np.ndarray | None = None,
    sample: SampleConfig | None = None,
    pixels: Pixels | None = None,
    backend: str | None = None,
) -> PixelGeometry:
    """:func:`pixel_geometry` for the rig's camera and light at the given arm directions
    (unit vectors in the sample frame, e.g. from ``Kinematics.forward_geometry``).

    ``pointing_deg``: the camera's optical axis turned towards the image's +x, then +y (deg;
    a calibrated pointing error, :meth:`PinholeCamera.pointed`); ``light_pos``: the light's
    position (m; default ``light_distance_m`` along ``light_dir``); ``sample``: the sample's
    shape and place (default the rig file's); ``pixels``: only those (rows, columns)."""
    camera, light_pos = frame_camera(rig, light_dir, camera_dir, shape_superpixels,
                                     pointing_deg=pointing_deg, light_pos=light_pos)
    return pixel_geometry(camera, light_pos, sample or rig.sample, target_shape, pixels,
                          backend=backend)


SampleArrays = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, Pixels]
"""A frame's samples: wi, wo (N, 3), BRDF (N, 3, sr⁻¹), its variance (N, 3, sr⁻²) or None,
and their pixels (rows, columns)."""


def pixel_samples(camera: PinholeCamera, light_pos: np.ndarray, sample: SampleConfig,
                  rgb: np.ndarray, valid: np.ndarray, variance: np.ndarray | None,
                  calibration: np.ndarray, min_cos: float, *, blocks: int = 0
                  ) -> SampleArrays:
    """The BRDF samples f = P / (C · cos θi / r²) of an image's valid pixels that see the
    sample with cos θi, cos θr ≥ ``min_cos`` (``rgb``, ``variance``: (rows, columns, 3) in
    DN/s and its square; ``calibration`` C (3,)), compiled (:mod:`.sample_kernels`): the
    same arrays as :func:`pixel_geometry` then :func:`acquisition.reduction.image.frame_samples`,
    bit for bit. Only each row's span of columns that can see the sample is computed
    (:mod:`.sample_spans`). ``blocks``: the rows go to numba's threads in that many blocks
    (1: on the calling thread); by default one per thread for frames of
    :data:`~.sample_kernels.PARALLEL_MIN_CELLS` pixels or more, else 1."""
    import numba

    from acquisition.reduction import sample_kernels as sk
    from acquisition.reduction.sample_spans import row_spans

    p = frame_parameters(camera, light_pos, sample)
    valid = np.ascontiguousarray(valid)
    h, w = valid.shape
    var = None if variance is None else np.ascontiguousarray(variance).reshape(h, 3 * w)
    frame = (p, sk.column_x(p, w), np.ascontiguousarray(rgb).reshape(h, 3 * w), valid,
             np.ascontiguousarray(calibration, dtype=np.float64), float(min_cos))
    spans = row_spans(p, (h, w))
    if not blocks:
        blocks = numba.get_num_threads() if valid.size >= sk.PARALLEL_MIN_CELLS else 1
    if blocks < 2 or valid.size == 0:
        out, var_out, n = _serial_samples(frame, var, spans)
    else:
        out, var_out, n = _threaded_samples(frame, var, spans, blocks)
    wi, wo, brdf, rows, cols = (a[:n] for a in out)
    return wi, wo, brdf, None if var_out is None else var_out[:n], (rows, cols)


def _sample_arrays(capacity: int, variance: bool
                   ) -> tuple[tuple[np.ndarray, ...], np.ndarray | None]:
    """Outputs for up to ``capacity`` samples: (wi, wo, brdf, rows, cols) and the variance's,
    in an earlier frame's memory where nothing holds it any more (:mod:`calibration.recycling`)."""
    f64 = [recycling.empty((capacity, 3)) for _ in range(4 if variance else 3)]
    out = (*f64[:3], recycling.empty(capacity, np.int64), recycling.empty(capacity, np.int64))
    return out, (f64[3] if variance else None)


def _serial_samples(frame: tuple, var: np.ndarray | None, spans: tuple[np.ndarray, np.ndarray]
                    ) -> tuple[tuple[np.ndarray, ...], np.ndarray | None, int]:
    """:func:`pixel_samples` on the calling thread, into outputs as large as the spans."""
    from acquisition.reduction import sample_kernels as sk

    capacity = int(np.sum(spans[1] - spans[0]))
    out, var_out = _sample_arrays(capacity, var is not None)
    n = sk.fill_serial(frame, var, spans, out, var_out, capacity)
    if n < 0:
        raise RuntimeError("per-pixel samples overflowed the spans' pixel count (a bug)")
    return out, var_out, n


def _threaded_samples(frame: tuple, var: np.ndarray | None,
                      spans: tuple[np.ndarray, np.ndarray], blocks: int
                      ) -> tuple[tuple[np.ndarray, ...], np.ndarray | None, int]:
    """:func:`pixel_samples` in ``blocks`` blocks of rows of about equal work: the rows before
    the last block are counted first (on all threads), so each block writes its own rows of
    the outputs, in row order; the last block's rows are bounded by its spans' pixels."""
    import numba

    from acquisition.reduction import sample_kernels as sk

    width = spans[1] - spans[0]
    bounds = _balanced(width, 0, width.size, blocks)
    counts = np.zeros(width.size, np.int64)
    sk.count_rows(frame, spans, _balanced(width, 0, int(bounds[-2]), numba.get_num_threads()),
                  counts)
    before = np.concatenate([[0], np.cumsum(counts)])
    sizes = before[bounds[1:]] - before[bounds[:-1]]
    sizes[-1] = int(np.sum(width[bounds[-2]:]))
    ends = np.cumsum(sizes)
    starts = ends - sizes
    out, var_out = _sample_arrays(int(ends[-1]), var is not None)
    got = np.zeros(blocks, np.int64)
    sk.fill_blocks(frame, var, spans, bounds, starts, ends, out, var_out, got)
    if got[-1] < 0 or not np.array_equal(got[:-1], ends[:-1]):
        raise RuntimeError("per-pixel samples differ between their count and fill (a bug)")
    return out, var_out, int(got[-1])


def _balanced(work: np.ndarray, first: int, stop: int, parts: int) -> np.ndarray:
    """Row bounds (int64, ``parts`` + 1) splitting rows [first, stop) into parts of about equal
    total ``work``."""
    total = np.concatenate([[0], np.cumsum(work[first:stop])])
    bounds = first + np.searchsorted(total, total[-1] * np.arange(parts + 1) / parts,
                                     side="left")
    bounds[0], bounds[-1] = first, stop
    return np.minimum(bounds, stop).astype(np.int64)
