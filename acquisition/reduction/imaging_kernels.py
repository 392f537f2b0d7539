"""Numba kernel of the per-pixel geometry (:mod:`acquisition.reduction.imaging`), in one pass per
pixel; its per-pixel functions are those of a frame's BRDF samples too (:mod:`.sample_kernels`).

Bit for bit the numpy path, on every CPU: each pixel goes through the same IEEE operations, in
the same order, as the numpy code does them, and that code is elementwise only
(:mod:`acquisition.reduction.fixedorder`: no einsum, no BLAS, whose orders and fused
multiply-adds change with the CPU): a dot product is (a₀b₀ + a₁b₁) + a₂b₂ (:func:`_dot`), a
norm its square root (:func:`_norm`), as ``np.linalg.norm`` of a ray (√((v₀² + v₁²) + v₂²)).

Nothing here calls a transcendental function (square roots and divisions are correctly
rounded everywhere), there is no fast-math (no contraction, no reassociation), and
tests/test_imaging_kernels.py compares both paths on random cameras, lights and samples. The
scalars of a frame (camera rotation, ``oc · oc − r²``) are computed once by the numpy code
(elementwise too) and passed in (:func:`frame_parameters`).

Outputs are compacted: the kernel walks the pixels from ``start`` and writes every kept pixel
into the next free row of its output arrays; when they are full it returns where it stopped
and the caller grows them (:func:`acquisition.reduction.imaging.collect`).
"""

from __future__ import annotations

import os

os.environ["NUMBA_DISABLE_INTEL_SVML"] = "1"  # as acquisition.tables.kernels

import numpy as np  # noqa: E402
from numba import njit  # noqa: E402

_JIT = {"cache": True, "nogil": True, "fastmath": False, "error_model": "numpy"}

# Layout of the frame's parameters (float64 array, :func:`frame_parameters`).
FX, FY, CX, CY = 0, 1, 2, 3
ROT = 4  # 9 entries: rows right, down, forward
POS = 13  # camera position (3), m
LIGHT = 16  # light position (3), m
KIND = 19  # 0 flat, 1 sphere
HALF = 20  # flat: half the edge, m; sphere: radius, m
CENTRE = 21  # sphere centre (3), m
OC = 24  # camera position − centre (3), m
C_SPHERE = 27  # oc · oc − r², m² (fixedorder.dot3)
N_PARAMS = 28


@njit(inline="always", **_JIT)
def _dot(a0, a1, a2, b0, b1, b2):  # pragma: no cover - compiled
    """:func:`~acquisition.reduction.fixedorder.dot3` of one row: (a₀b₀ + a₁b₁) + a₂b₂."""
    return (a0 * b0 + a1 * b1) + a2 * b2


@njit(inline="always", **_JIT)
def _norm(v0, v1, v2):  # pragma: no cover - compiled
    """``np.linalg.norm`` / :func:`~acquisition.reduction.fixedorder.norm3` of one row."""
    return np.sqrt((v0 * v0 + v1 * v1) + v2 * v2)


@njit(inline="always", **_JIT)
def _ray(p, row, col):  # pragma: no cover - compiled
    """Unit ray direction through pixel (row, col) (PinholeCamera.ray_directions)."""
    x = (col - p[CX]) / p[FX]
    y = (row - p[CY]) / p[FY]
    d0 = (x * p[ROT] + y * p[ROT + 3]) + p[ROT + 6]
    d1 = (x * p[ROT + 1] + y * p[ROT + 4]) + p[ROT + 7]
    d2 = (x * p[ROT + 2] + y * p[ROT + 5]) + p[ROT + 8]
    n = _norm(d0, d1, d2)
    return d0 / n, d1 / n, d2 / n


@njit(inline="always", **_JIT)
def _hit(p, d0, d1, d2):  # pragma: no cover - compiled
    """(hit, point (3), unit normal (3)) of a ray from the camera (imaging.intersect)."""
    if p[KIND] == 0.0:  # flat square in z = 0
        t = -p[POS + 2] / d2
        x = p[POS] + t * d0
        y = p[POS + 1] + t * d1
        ok = t > 0.0 and abs(x) <= p[HALF] and abs(y) <= p[HALF] and p[POS + 2] > 0.0
        return ok, x, y, 0.0, 0.0, 0.0, 1.0
    b = _dot(d0, d1, d2, p[OC], p[OC + 1], p[OC + 2])
    disc = b * b - p[C_SPHERE]
    if not disc >= 0.0:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    t = -b - np.sqrt(disc)
    if not t > 0.0:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    x = p[POS] + t * d0
    y = p[POS + 1] + t * d1
    z = p[POS + 2] + t * d2
    n0 = (x - p[CENTRE]) / p[HALF]
    n1 = (y - p[CENTRE + 1]) / p[HALF]
    n2 = (z - p[CENTRE + 2]) / p[HALF]
    nn = _norm(n0, n1, n2)
    return True, x, y, z, n0 / nn, n1 / nn, n2 / nn


@njit(inline="always", **_JIT)
def _local(v0, v1, v2, n0, n1, n2):  # pragma: no cover - compiled
    """``v`` in the shading frame of normal n (imaging.tangent_frames, Duff et al. 2017)."""
    sign = 1.0 if n2 >= 0.0 else -1.0
    a = -1.0 / (sign + n2)
    b = n0 * n1 * a
    t0 = 1.0 + sign * n0 * n0 * a
    t1 = sign * b
    t2 = -sign * n0
    s1 = sign + n1 * n1 * a
    return (_dot(v0, v1, v2, t0, t1, t2), _dot(v0, v1, v2, b, s1, -n1),
            _dot(v0, v1, v2, n0, n1, n2))


@njit(inline="always", **_JIT)
def _pixel(p, row, col):  # pragma: no cover - compiled
    """(seen, wi (3), wo (3), cos θi / r²) of pixel (row, col) (imaging.pixel_geometry):
    ``seen`` when its ray hits the sample lit (cos θi > 0) and facing the camera."""
    d0, d1, d2 = _ray(p, row, col)
    hit, x, y, z, n0, n1, n2 = _hit(p, d0, d1, d2)
    if not hit:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    l0 = p[LIGHT] - x
    l1 = p[LIGHT + 1] - y
    l2 = p[LIGHT + 2] - z
    r2 = _dot(l0, l1, l2, l0, l1, l2)
    r = np.sqrt(r2)
    l0, l1, l2 = l0 / r, l1 / r, l2 / r
    o0 = p[POS] - x
    o1 = p[POS + 1] - y
    o2 = p[POS + 2] - z
    no = _norm(o0, o1, o2)
    o0, o1, o2 = o0 / no, o1 / no, o2 / no
    if not (_dot(l0, l1, l2, n0, n1, n2) > 0.0 and _dot(o0, o1, o2, n0, n1, n2) > 0.0):
        return False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    i0, i1, i2 = _local(l0, l1, l2, n0, n1, n2)
    w0, w1, w2 = _local(o0, o1, o2, n0, n1, n2)
    return True, i0, i1, i2, w0, w1, w2, i2 / r2


@njit(**_JIT)
def geometry(p, width, rows, cols, mask, wi, wo, irradiance, n, start):  # pragma: no cover
    """Per-pixel geometry of pixel q ≥ ``start``: the grid's pixels in C order (``rows`` of
    size 0, ``mask`` the flattened grid) or the given (``rows``, ``cols``). Seen pixels are
    flagged in ``mask`` and their wi, wo, cos θi / r² written from row ``n`` on. Returns
    (rows written, pixel stopped at): the outputs are full when it is below the pixel count."""
    grid = rows.size == 0
    for q in range(start, mask.size):
        if n >= irradiance.size:
            return n, q
        row = float(q // width) if grid else float(rows[q])
        col = float(q % width) if grid else float(cols[q])
        seen, i0, i1, i2, w0, w1, w2, e = _pixel(p, row, col)
        mask[q] = seen
        if seen:
            wi[n, 0], wi[n, 1], wi[n, 2] = i0, i1, i2
            wo[n, 0], wo[n, 1], wo[n, 2] = w0, w1, w2
            irradiance[n] = e
            n += 1
    return n, mask.size
