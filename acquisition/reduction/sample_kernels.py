"""The compiled pass behind :func:`acquisition.reduction.imaging.pixel_samples`: a frame's BRDF
samples, row by row, over each row's span of columns that can see the sample
(:mod:`.sample_spans`).

How it is fast, with the same bits as the per-pixel code (:mod:`.imaging_kernels`, itself the
numpy path's operations in the same order):

* Only the span is computed; the pixels outside it are misses (:mod:`.sample_spans` says why).
* SIMD. A row's geometry (:func:`_geometry_row`, :func:`_count_row`) and BRDF (:func:`_brdf_row`)
  go to a small buffer of float64 rows with no branch and no early exit, so that the compiler
  turns the loops into AVX2/AVX-512 code; then a scalar pass (:func:`_emit`) copies the kept
  pixels (valid, seen, cos θi and cos θr ≥ the minimum) to the outputs in column order. The
  arithmetic is the per-pixel code's, operation for operation, in IEEE double with no
  fast-math: vector or scalar, every CPU rounds each operation the same way. Inputs are read
  through 1-D rows starting at index 0 (no wrap-around test; a 2-D row's run-time stride would
  make the compiler's vector version bail out at run time), and no SIMD loop reads back what
  it writes (its aliasing checks would fail).
* Threads. :func:`count_rows` counts the kept pixels of the rows before the last block, so each
  block of rows knows where its samples start; :func:`fill_blocks` then fills the blocks at
  once, each into its own rows of the outputs. The blocks' outputs follow in row order: the
  samples are in C order of pixels, as with one thread (:func:`fill_serial`).

A block stops at the end of its outputs and reports it (−1): the counts and the fill compute
the same rows with the same code, so that is a bug, never a result.
"""

from __future__ import annotations

import os

os.environ["NUMBA_DISABLE_INTEL_SVML"] = "1"  # as acquisition.tables.kernels

from drivers.numba_cache import drop_stale_cache  # noqa: E402

# the row functions compile in imaging_kernels' arithmetic
drop_stale_cache(__file__, (os.path.join(os.path.dirname(__file__), "imaging_kernels.py"),))

import numba  # noqa: E402
import numpy as np  # noqa: E402

from acquisition.reduction import imaging_kernels as k  # noqa: E402

_JIT = k._JIT
PARALLEL_MIN_CELLS = 1 << 16
"""Frames of fewer pixels are reduced on the calling thread: waking the thread pool costs more
than it saves on them (as :data:`calibration.linearize_kernel.PARALLEL_MIN_CELLS`)."""
BUFFER_ROWS = 14
"""Rows of a row's buffer: kept (1.0/0.0), wi (3), wo (3), cos θi / r², BRDF (3), variance (3)."""


@numba.njit(inline="always", **_JIT)
def _shade(lx, ly, lz, px, py, pz, x, y, z, n0, n1, n2, min_cos):  # pragma: no cover
    """(kept, wi (3), wo (3), cos θi / r²) at the hit point (x, y, z) of unit normal n, light
    at l, camera at p (m): :func:`.imaging_kernels._pixel` after the hit, branch-free."""
    l0, l1, l2 = lx - x, ly - y, lz - z
    r2 = k._dot(l0, l1, l2, l0, l1, l2)
    r = np.sqrt(r2)
    l0, l1, l2 = l0 / r, l1 / r, l2 / r
    o0, o1, o2 = px - x, py - y, pz - z
    no = k._norm(o0, o1, o2)
    o0, o1, o2 = o0 / no, o1 / no, o2 / no
    i0, i1, i2 = k._local(l0, l1, l2, n0, n1, n2)
    w0, w1, w2 = k._local(o0, o1, o2, n0, n1, n2)
    kept = (i2 > 0.0) & (w2 > 0.0) & (i2 >= min_cos) & (w2 >= min_cos)
    return kept, i0, i1, i2, w0, w1, w2, i2 / r2


@numba.njit(inline="always", **_JIT)
def _store(buf, j, pixel):  # pragma: no cover - compiled
    """Column j of ``buf``: a pixel's (kept, wi, wo, cos θi / r²)."""
    kept, i0, i1, i2, w0, w1, w2, e = pixel
    buf[0, j] = 1.0 if kept else 0.0
    buf[1, j], buf[2, j], buf[3, j] = i0, i1, i2
    buf[4, j], buf[5, j], buf[6, j] = w0, w1, w2
    buf[7, j] = e


@numba.njit(inline="always", **_JIT)
def _constants(p, y):  # pragma: no cover - compiled
    """The frame's scalars for a row at y = (row − cy)/fy: the rotation's columns (y·down
    taken once per row), camera, light, sphere (centre − camera, oc·oc − r², centre, radius)
    or flat (half edge, camera above the plane: 1.0 or 0.0)."""
    return (p[k.ROT], p[k.ROT + 1], p[k.ROT + 2],
            y * p[k.ROT + 3], y * p[k.ROT + 4], y * p[k.ROT + 5],
            p[k.ROT + 6], p[k.ROT + 7], p[k.ROT + 8],
            p[k.POS], p[k.POS + 1], p[k.POS + 2], p[k.LIGHT], p[k.LIGHT + 1], p[k.LIGHT + 2],
            p[k.OC], p[k.OC + 1], p[k.OC + 2], p[k.C_SPHERE],
            p[k.CENTRE], p[k.CENTRE + 1], p[k.CENTRE + 2], p[k.HALF],
            1.0 if p[k.POS + 2] > 0.0 else 0.0)


@numba.njit(inline="always", **_JIT)
def _ray(c, x):  # pragma: no cover - compiled
    """Unit ray through x = (column − cx)/fx of the row of constants ``c``
    (:func:`.imaging_kernels._ray`)."""
    d0, d1, d2 = (x * c[0] + c[3]) + c[6], (x * c[1] + c[4]) + c[7], (x * c[2] + c[5]) + c[8]
    nd = k._norm(d0, d1, d2)
    return d0 / nd, d1 / nd, d2 / nd


@numba.njit(inline="always", **_JIT)
def _sphere_pixel(c, x, min_cos):  # pragma: no cover - compiled
    """(kept, wi (3), wo (3), cos θi / r²) of a pixel, sphere sample (:func:`.imaging_kernels._hit`)."""
    d0, d1, d2 = _ray(c, x)
    b = k._dot(d0, d1, d2, c[15], c[16], c[17])
    disc = b * b - c[18]
    t = -b - np.sqrt(disc)
    hx, hy, hz = c[9] + t * d0, c[10] + t * d1, c[11] + t * d2
    n0, n1, n2 = (hx - c[19]) / c[22], (hy - c[20]) / c[22], (hz - c[21]) / c[22]
    nn = k._norm(n0, n1, n2)
    kept, i0, i1, i2, w0, w1, w2, e = _shade(c[12], c[13], c[14], c[9], c[10], c[11],
                                             hx, hy, hz, n0 / nn, n1 / nn, n2 / nn, min_cos)
    return kept & (disc >= 0.0) & (t > 0.0), i0, i1, i2, w0, w1, w2, e


@numba.njit(inline="always", **_JIT)
def _flat_pixel(c, x, min_cos):  # pragma: no cover - compiled
    """:func:`_sphere_pixel` for the flat square in z = 0 (normal +z)."""
    d0, d1, d2 = _ray(c, x)
    t = -c[11] / d2
    hx, hy = c[9] + t * d0, c[10] + t * d1
    kept, i0, i1, i2, w0, w1, w2, e = _shade(c[12], c[13], c[14], c[9], c[10], c[11],
                                             hx, hy, 0.0, 0.0, 0.0, 1.0, min_cos)
    hit = (t > 0.0) & (np.abs(hx) <= c[22]) & (np.abs(hy) <= c[22]) & (c[23] != 0.0)
    return kept & hit, i0, i1, i2, w0, w1, w2, e


@numba.njit(**_JIT)
def _geometry_row(p, xs, y, min_cos, buf):  # pragma: no cover - compiled
    """Geometry of the pixels x = ``xs`` of the row at y into ``buf``'s first 8 rows."""
    c = _constants(p, y)
    if p[k.KIND] == 0.0:
        for j in range(xs.size):
            _store(buf, j, _flat_pixel(c, xs[j], min_cos))
    else:
        for j in range(xs.size):
            _store(buf, j, _sphere_pixel(c, xs[j], min_cos))


@numba.njit(**_JIT)
def _count_row(p, xs, y, min_cos, valid):  # pragma: no cover - compiled
    """How many pixels x = ``xs`` of the row at y are kept and ``valid``."""
    c = _constants(p, y)
    n = 0
    if p[k.KIND] == 0.0:
        for j in range(xs.size):
            n += _flat_pixel(c, xs[j], min_cos)[0] & valid[j]
    else:
        for j in range(xs.size):
            n += _sphere_pixel(c, xs[j], min_cos)[0] & valid[j]
    return n


@numba.njit(**_JIT)
def _brdf_row(rgb, variance, calibration, buf):  # pragma: no cover - compiled
    """f = P / (C · cos θi / r²) and var P / (C · cos θi / r²)² of a row's pixels (``rgb``,
    ``variance``: their 3 values each, flat; ``variance`` None: none)."""
    c0, c1, c2 = calibration[0], calibration[1], calibration[2]
    for j in range(rgb.size // 3):
        e = buf[7, j]
        s0, s1, s2 = e * c0, e * c1, e * c2
        buf[8, j] = np.float64(rgb[3 * j]) / s0
        buf[9, j] = np.float64(rgb[3 * j + 1]) / s1
        buf[10, j] = np.float64(rgb[3 * j + 2]) / s2
        if variance is not None:
            buf[11, j] = np.float64(variance[3 * j]) / (s0 * s0)
            buf[12, j] = np.float64(variance[3 * j + 1]) / (s1 * s1)
            buf[13, j] = np.float64(variance[3 * j + 2]) / (s2 * s2)


@numba.njit(**_JIT)
def _emit(buf, valid, row, col0, out, var, n, end):  # pragma: no cover - compiled
    """Copy the kept valid pixels of a row (columns ``col0`` + j) to ``out`` (wi, wo, brdf,
    rows, cols) and ``var`` (or None) from row ``n``; −1 if they pass ``end``. The row index
    is unsigned: no negative-index test per store."""
    wi, wo, brdf, rows, cols = out
    u, stop, one = np.uint64(n), np.uint64(end), np.uint64(1)
    for j in range(valid.size):
        if buf[0, j] != 0.0 and valid[j]:
            if u >= stop:
                return -1
            wi[u, 0], wi[u, 1], wi[u, 2] = buf[1, j], buf[2, j], buf[3, j]
            wo[u, 0], wo[u, 1], wo[u, 2] = buf[4, j], buf[5, j], buf[6, j]
            brdf[u, 0], brdf[u, 1], brdf[u, 2] = buf[8, j], buf[9, j], buf[10, j]
            if var is not None:
                var[u, 0], var[u, 1], var[u, 2] = buf[11, j], buf[12, j], buf[13, j]
            rows[u] = row
            cols[u] = col0 + j
            u += one
    return np.int64(u)


@numba.njit(**_JIT)
def _fill_rows(frame, variance, spans, first, stop, out, var_out, n, end,
               buf):  # pragma: no cover - compiled
    """The samples of rows [first, stop) to ``out`` and ``var_out`` from row ``n`` (not past
    ``end``); returns the row after the last written, or −1."""
    p, xs, rgb, valid, calibration, min_cos = frame
    lo, hi = spans
    for i in range(first, stop):
        a, b = lo[i], hi[i]
        if a >= b:
            continue
        _geometry_row(p, xs[a:b], (i - p[k.CY]) / p[k.FY], min_cos, buf)
        if variance is None:  # pruned at compile time, as in _brdf_row
            _brdf_row(rgb[i, 3 * a:3 * b], None, calibration, buf)
        else:
            _brdf_row(rgb[i, 3 * a:3 * b], variance[i, 3 * a:3 * b], calibration, buf)
        n = _emit(buf, valid[i, a:b], i, a, out, var_out, n, end)
        if n < 0:
            return n
    return n


@numba.njit(**_JIT)
def column_x(p, width):  # pragma: no cover - compiled
    """x = (column − cx)/fx of each column (PinholeCamera.ray_directions)."""
    xs = np.empty(width)
    for j in range(width):
        xs[j] = (float(j) - p[k.CX]) / p[k.FX]
    return xs


@numba.njit(**_JIT)
def fill_serial(frame, variance, spans, out, var_out, end):  # pragma: no cover - compiled
    """All rows' samples on the calling thread; returns their count, or −1 past ``end``."""
    buf = np.empty((BUFFER_ROWS, frame[1].size))
    return _fill_rows(frame, variance, spans, 0, frame[3].shape[0], out, var_out, 0, end, buf)


@numba.njit(parallel=True, **_JIT)
def count_rows(frame, spans, bounds, counts):  # pragma: no cover - compiled
    """``counts[i]``: the samples of row i, for the rows of the parts [bounds[t], bounds[t + 1])
    (one per thread), on numba's threads."""
    p, xs, _, valid, _, min_cos = frame
    lo, hi = spans
    for part in numba.prange(bounds.size - 1):
        for i in range(bounds[part], bounds[part + 1]):
            a, b = lo[i], hi[i]
            counts[i] = 0 if a >= b else _count_row(p, xs[a:b], (i - p[k.CY]) / p[k.FY],
                                                     min_cos, valid[i, a:b])


@numba.njit(parallel=True, **_JIT)
def fill_blocks(frame, variance, spans, bounds, starts, ends, out, var_out,
                got):  # pragma: no cover - compiled
    """Block b (rows [bounds[b], bounds[b + 1])) to ``out`` rows [starts[b], ends[b]), on
    numba's threads; ``got[b]``: the row after its last sample, or −1."""
    for b in numba.prange(starts.size):
        buf = np.empty((BUFFER_ROWS, frame[1].size))
        got[b] = _fill_rows(frame, variance, spans, bounds[b], bounds[b + 1], out, var_out,
                            starts[b], ends[b], buf)
