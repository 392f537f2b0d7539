"""The columns of each image row that can see the sample: one conservative span per row, so
that the per-pixel kernel (:mod:`.sample_kernels`) tests only those pixels.

The kernel decides every pixel of a span exactly as the per-pixel code does; the pixels outside
are not computed and count as misses. That gives the same samples, bit for bit, if every pixel
the floating-point test can call a hit lies in its row's span, which holds by construction:

1. Float to exact. A pixel that the test (:mod:`.imaging_kernels`) calls a hit has a ray that,
   computed exactly, meets a slightly grown sample: the test's rounding (ε = 2⁻⁵³) moves the
   ray's direction by a few ε, the sphere's discriminant by ~64 ε |v|² (v: camera to centre),
   the flat hit point by ~10 ε (|O| + h)² / height (O: camera, h: half edge). The spans are
   those of the sample grown by :data:`ENLARGE` (sphere: r² + ENLARGE·|v|²; flat: half edge
   h + ENLARGE·(|O| + h)): over 10⁵ times that rounding, for every geometry culled (the flat
   one's is largest at the lowest camera culled, :data:`GRAZING`).
2. Exact span. The rays of a row are A + x·B (x = (column − cx)/fx, A = y·down + forward,
   B = right): those meeting the grown sphere solve a quadratic inequality in x, those meeting
   the grown square five linear ones (in front of the camera, inside the four edges); either
   solution is one interval. Its double-precision rounding is far inside the enlargement: on a
   row with a hit the sphere's discriminant exceeds 1e-8 |v|⁴, some 10⁶ times its rounding
   (the quadratic's leading coefficient is at most −:data:`DEGENERATE`·|v|²), so x is off by
   ~1e-9 at most; the square's linear forms are off by ~ε of their terms, 10⁶ times less than
   the enlargement moves them.
3. Pixels. The interval maps to columns cx + fx·x, widened by :data:`MARGIN_PX` columns on
   each side plus 1e-6 of the column values, then clipped to the image.

Where those conditions do not hold, whole rows are tested: a sphere whose row quadratic is
nearly degenerate (its centre near the camera's x axis: the camera inside it, on it, or the
sphere nearly beside the camera), a camera less than :data:`GRAZING` (relative) above the flat
sample's plane, a zero or non-finite focal length, anything not finite. A flat sample seen from
below its plane (camera z ≤ 0) has no hits in any row, as in the per-pixel test.
tests/test_imaging_kernels.py checks that every hit lies inside its span with at least one of
the two margin columns to spare, and that the spans exceed the hits by a few columns a row.
"""

from __future__ import annotations

import numpy as np

from acquisition.reduction import imaging_kernels as k
from acquisition.reduction.fixedorder import dot3

ENLARGE = 1e-6
"""Growth of the sample for the spans, relative to the camera's distance (see module doc)."""
MARGIN_PX = 2.0
"""Columns added on each side of a row's exact span."""
DEGENERATE = 1e-2
"""Sphere: the row quadratic's leading coefficient must be below −DEGENERATE·|v|²·|B|²."""
GRAZING = 1e-3
"""Flat: the camera's height must be at least GRAZING·(|O| + h) (about 0.06° of elevation)."""

Spans = tuple[np.ndarray, np.ndarray]
"""Per row (int64): the columns [lo, hi) to test."""


def row_spans(p: np.ndarray, shape: tuple[int, int]) -> Spans:
    """The columns [lo, hi) of each row of an image of ``shape`` (rows, columns) whose rays can
    meet the sample of the frame parameters ``p`` (:func:`.imaging.frame_parameters`)."""
    h, w = shape
    fx = p[k.FX]
    if not (np.isfinite(fx) and fx != 0.0 and np.isfinite(p[k.CX])):
        return np.zeros(h, np.int64), np.full(h, w, np.int64)
    with np.errstate(all="ignore"):
        y = (np.arange(h, dtype=np.float64) - p[k.CY]) / p[k.FY]
        rot = p[k.ROT:k.ROT + 9].reshape(3, 3)
        a = y[:, None] * rot[1] + rot[2]  # the ray of column x is a + x·b
        b = rot[0]
        if p[k.KIND] == 0.0:
            x0, x1 = _flat_interval(p, a, b)
        else:
            x0, x1 = _sphere_interval(p, a, b)
        return _columns(p, x0, x1, w)


def _full(n: int) -> tuple[np.ndarray, np.ndarray]:
    return np.full(n, -np.inf), np.full(n, np.inf)


def _sphere_interval(p: np.ndarray, a: np.ndarray, b: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Per row, the x of the rays a + x·b meeting the grown sphere (either side of the camera):
    (a·v + x b·v)² ≥ (|v|² − r'²)|a + x b|²; (+inf, −inf) when none, (−inf, +inf) when the
    geometry is not culled."""
    v = p[k.CENTRE:k.CENTRE + 3] - p[k.POS:k.POS + 3]
    vv = float(dot3(v, v))
    big_v = vv - (p[k.HALF] * p[k.HALF] + ENLARGE * vv)
    a1, q2 = float(dot3(b, v)), float(dot3(b, b))
    lead = a1 * a1 - big_v * q2
    if not (np.isfinite(lead) and lead <= -DEGENERATE * vv * q2 and big_v > 0.0):
        return _full(a.shape[0])
    a0, q0, q1 = dot3(a, v), dot3(a, a), dot3(a, b)
    half_b = a0 * a1 - big_v * q1
    const = a0 * a0 - big_v * q0
    disc = half_b * half_b - lead * const
    root = np.sqrt(np.maximum(disc, 0.0))
    xa, xb = (-half_b + root) / lead, (-half_b - root) / lead
    x0, x1 = np.minimum(xa, xb), np.maximum(xa, xb)
    empty = disc < 0.0
    x0, x1 = np.where(empty, np.inf, x0), np.where(empty, -np.inf, x1)
    bad = ~(np.isfinite(disc) & np.isfinite(xa) & np.isfinite(xb))
    return np.where(bad, -np.inf, x0), np.where(bad, np.inf, x1)


def _flat_interval(p: np.ndarray, a: np.ndarray, b: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Per row, the x of the rays a + x·b meeting the grown square in z = 0 from above: with
    u = −(a + x b)_z > 0 and g = O_xy·u + height·(a + x b)_xy (the hit point times u),
    |g| ≤ h'·u; five linear inequalities α + β·x ≤ 0."""
    o = p[k.POS:k.POS + 3]
    height, half = o[2], p[k.HALF]
    n = a.shape[0]
    if not height > 0.0:  # the per-pixel test: no hit from below the plane
        return np.full(n, np.inf), np.full(n, -np.inf)
    reach = float(np.sqrt(dot3(o, o))) + half
    if not (np.isfinite(reach) and height >= GRAZING * reach):
        return _full(n)
    grown = half + ENLARGE * reach
    u0, u1 = -a[:, 2], np.full(n, -b[2])
    alpha, beta = [-u0], [-u1]
    for i in (0, 1):
        g0, g1 = o[i] * u0 + height * a[:, i], o[i] * u1 + height * b[i]
        alpha += [g0 - grown * u0, -g0 - grown * u0]
        beta += [g1 - grown * u1, -g1 - grown * u1]
    al, be = np.array(alpha), np.array(beta)
    bound = -al / np.where(be == 0.0, 1.0, be)
    x0 = np.max(np.where(be < 0.0, bound, -np.inf), axis=0)
    x1 = np.min(np.where(be > 0.0, bound, np.inf), axis=0)
    empty = np.any((be == 0.0) & (al > 0.0), axis=0) | ~(x0 <= x1)
    x0, x1 = np.where(empty, np.inf, x0), np.where(empty, -np.inf, x1)
    bad = ~np.all(np.isfinite(al) & np.isfinite(be), axis=0)
    return np.where(bad, -np.inf, x0), np.where(bad, np.inf, x1)


def _columns(p: np.ndarray, x0: np.ndarray, x1: np.ndarray, w: int) -> Spans:
    """Intervals of x (+inf, −inf when empty) to column spans, widened and clipped."""
    empty = x0 > x1
    cx, fx = p[k.CX], p[k.FX]
    ca, cb = cx + fx * x0, cx + fx * x1
    sa = MARGIN_PX + 1e-6 * (abs(cx) + np.abs(fx * x0))
    sb = MARGIN_PX + 1e-6 * (abs(cx) + np.abs(fx * x1))
    c0, c1 = np.fmin(ca - sa, cb - sb), np.fmax(ca + sa, cb + sb)  # inf − inf: NaN, ignored
    lo = np.floor(np.clip(c0, 0.0, float(w)))
    hi = np.floor(np.clip(c1, -1.0, float(w - 1))) + 1.0
    lo = np.where(empty | np.isnan(lo), 0.0, lo).astype(np.int64)
    hi = np.where(empty, 0.0, np.where(np.isnan(hi), float(w), hi)).astype(np.int64)
    return lo, np.maximum(hi, lo)
