"""The compiled pass behind :func:`calibration.linearize.linearize`: one read of the mosaic
(LibRaw's own uint16 buffer, or any array) per superpixel, writing RGB, validity and variance.

Per superpixel (2 × 2 Bayer cell) and pixel: the cell is invalid if the pixel reaches its
saturation threshold or is on a per-pixel bad map; the signal is the raw value minus the black
level (or minus a master dark); the variance ``max(s, 0)/g + σ_r²`` is taken on the
black-subtracted signal (the dark current's shot noise counts); a per-pixel flat divides both
(signal by f, variance by f²), and a zero or negative flat makes the cell invalid. R, the mean
of the two greens and B are scaled and divided by a per-superpixel flat; invalid cells are NaN.

How it is fast: the four pixels of a cell are read at fixed places (columns 2x and 2x + 1 of
rows 2y and 2y + 1) with constants per place (black, threshold, 1/gain, read² of that place's
colour, from the Bayer layout ``red_at``), and a row's results go first to a small buffer of
float64 rows (:func:`_cell_row`), then to the interleaved outputs (:func:`_write_row`): so the
compiler turns the per-cell loop into SIMD code (AVX2, AVX-512). Optional inputs are ``None``
and each combination is compiled on its own (no test in the loop). Every value is computed by
the same IEEE operations in the same order as a plain per-pixel loop, so SIMD or not, the bits
are the same on every CPU.
"""

from __future__ import annotations

import math

import numba
import numpy as np

PARALLEL_MIN_CELLS = 1 << 16
"""Frames of fewer superpixels are linearized on one thread: waking the thread pool costs
more than it saves on them (~15 ms per frame on a busy 2-core host for a 96 × 64 frame)."""
ROWS_PER_TASK = 8
"""Superpixel rows per task of the thread pool (each task has its own row buffer)."""
_JIT = {"cache": True, "nogil": True, "error_model": "numpy"}


def linearize_cells(mosaic: np.ndarray, red_at: tuple[int, int], black: np.ndarray,
                    threshold: np.ndarray, dark: np.ndarray | None,
                    flat_px: np.ndarray | None, flat_sp: np.ndarray | None,
                    bad_px: np.ndarray | None, bad_sp: np.ndarray | None,
                    gain: np.ndarray | None, read: np.ndarray | None, scale: float,
                    rgb: np.ndarray, valid: np.ndarray, variance: np.ndarray | None) -> None:
    """Fill ``rgb`` (h, w, 3), ``valid`` (h, w) and, with a noise model (``gain`` e⁻/DN and
    ``read`` DN per colour), ``variance``. ``black`` and ``threshold``: (2, 2) DN per CFA
    position; ``dark`` and ``flat_px``/``bad_px`` per pixel, ``flat_sp`` (h, w, 3) and
    ``bad_sp`` per superpixel, each ``None`` when absent. Rows go to numba's thread pool on
    frames of :data:`PARALLEL_MIN_CELLS` superpixels or more."""
    kernel = _cells_parallel if valid.size >= PARALLEL_MIN_CELLS else _cells_serial
    pixels, stride = _rows(mosaic)
    kernel(pixels, stride, red_at, black, threshold, _c_order(dark), _c_order(flat_px),
           _c_order(flat_sp), _c_order(bad_px), _c_order(bad_sp), gain, read, scale, rgb,
           valid, variance)


def _rows(mosaic: np.ndarray) -> tuple[np.ndarray, int]:
    """The mosaic as one contiguous run of memory and its row stride (elements): pixel (r, c)
    is ``run[r * stride + c]``. LibRaw's visible area is a view into the sensor's full rows,
    which compiled code indexed in two dimensions cannot vectorise; the run covers it from
    its first pixel to its last, no copy (a copy only for a view with gaps inside a row)."""
    rows, cols = mosaic.shape
    item = mosaic.itemsize
    if mosaic.flags.c_contiguous or rows <= 1:
        return np.ascontiguousarray(mosaic).reshape(-1), cols
    row_step, col_step = mosaic.strides
    if col_step != item or row_step % item or row_step < cols * item:
        return np.ascontiguousarray(mosaic).reshape(-1), cols
    stride = row_step // item
    run = np.lib.stride_tricks.as_strided(mosaic, shape=((rows - 1) * stride + cols,),
                                          strides=(item,), writeable=False)
    return run, stride


def _c_order(a: np.ndarray | None) -> np.ndarray | None:
    """A calibration array in C order (they are, unless a caller sliced one)."""
    return None if a is None else np.ascontiguousarray(a)


@numba.njit(parallel=True, **_JIT)
def _cells_parallel(mosaic, stride, red_at, black, threshold, dark, flat_px, flat_sp, bad_px, bad_sp,
                    gain, read, scale, rgb, valid, variance):  # pragma: no cover - compiled
    """:func:`linearize_cells`, :data:`ROWS_PER_TASK` rows per task of numba's thread pool."""
    h, w = valid.shape
    for task in numba.prange((h + ROWS_PER_TASK - 1) // ROWS_PER_TASK):
        buf = np.empty((7, w))
        for y in range(task * ROWS_PER_TASK, min(h, (task + 1) * ROWS_PER_TASK)):
            _cell_row(y, mosaic, stride, red_at, black, threshold, dark, flat_px, flat_sp,
                      bad_px, bad_sp, gain, read, scale, buf)
            _write_row(y, buf, rgb, valid, variance)


@numba.njit(**_JIT)
def _cells_serial(mosaic, stride, red_at, black, threshold, dark, flat_px, flat_sp, bad_px, bad_sp,
                  gain, read, scale, rgb, valid, variance):  # pragma: no cover - compiled
    """:func:`linearize_cells` on the calling thread."""
    buf = np.empty((7, valid.shape[1]))
    for y in range(valid.shape[0]):
        _cell_row(y, mosaic, stride, red_at, black, threshold, dark, flat_px, flat_sp, bad_px,
                  bad_sp, gain, read, scale, buf)
        _write_row(y, buf, rgb, valid, variance)


@numba.njit(**_JIT)
def _place_constants(red_at, black, threshold, gain, read):  # pragma: no cover - compiled
    """Per place (i, j) of the 2 × 2 cell, in the order 00, 01, 10, 11: threshold and black
    (DN), 1/gain (DN/e⁻) and read² (DN²) of its colour (0 without a noise model)."""
    ri, rj = red_at
    colour = np.empty(4, np.int64)
    for i in range(2):
        for j in range(2):  # red at (ri, rj), blue diagonal to it, the greens elsewhere
            colour[2 * i + j] = 0 if (i == ri and j == rj) else (
                2 if (i != ri and j != rj) else 1)
    thr, blk = np.empty(4), np.empty(4)
    inv_gain, read2 = np.zeros(4), np.zeros(4)
    for p in range(4):
        thr[p], blk[p] = threshold[p // 2, p % 2], black[p // 2, p % 2]
        if gain is not None:
            inv_gain[p] = 1.0 / gain[colour[p]]
            read2[p] = read[colour[p]] * read[colour[p]]
    return thr, blk, inv_gain, read2


@numba.njit(**_JIT)
def _cell_row(y, mosaic, stride, red_at, black, threshold, dark, flat_px, flat_sp, bad_px,
              bad_sp, gain, read, scale, buf):  # pragma: no cover - compiled
    """Superpixel row ``y`` into ``buf`` rows R, G, B, their variances, validity (1 or 0);
    ``mosaic`` is one run of pixels, ``stride`` apart from row to row (:func:`_rows`)."""
    t, k, g, d = _place_constants(red_at, black, threshold, gain, read)
    ri, rj = red_at
    f_rb, f_g = scale, 0.5 * scale
    q_rb, q_g = f_rb * f_rb, f_g * f_g
    r0, r1 = 2 * y, 2 * y + 1
    m0, m1 = max(r0 * stride, 0), max(r1 * stride, 0)  # ≥ 0: no wrap-around test per read
    t0, t1, t2, t3, k0, k1, k2, k3 = t[0], t[1], t[2], t[3], k[0], k[1], k[2], k[3]
    g0, g1, g2, g3, d0, d1, d2, d3 = g[0], g[1], g[2], g[3], d[0], d[1], d[2], d[3]
    nan = math.nan
    for x in range(buf.shape[1]):
        e, o = 2 * x, 2 * x + 1
        a0, a1 = float(mosaic[m0 + e]), float(mosaic[m0 + o])
        a2, a3 = float(mosaic[m1 + e]), float(mosaic[m1 + o])
        bad = (a0 >= t0) | (a1 >= t1) | (a2 >= t2) | (a3 >= t3)
        if bad_px is not None:
            bad = bad | bad_px[r0, e] | bad_px[r0, o] | bad_px[r1, e] | bad_px[r1, o]
        if bad_sp is not None:
            bad = bad | bad_sp[y, x]
        s0, s1, s2, s3 = a0 - k0, a1 - k1, a2 - k2, a3 - k3
        v0, v1 = max(s0, 0.0) * g0 + d0, max(s1, 0.0) * g1 + d1
        v2, v3 = max(s2, 0.0) * g2 + d2, max(s3, 0.0) * g3 + d3
        if dark is not None:
            s0, s1 = a0 - float(dark[r0, e]), a1 - float(dark[r0, o])
            s2, s3 = a2 - float(dark[r1, e]), a3 - float(dark[r1, o])
        if flat_px is not None:
            f0, f1 = float(flat_px[r0, e]), float(flat_px[r0, o])
            f2, f3 = float(flat_px[r1, e]), float(flat_px[r1, o])
            bad = bad | (not f0 > 0.0) | (not f1 > 0.0) | (not f2 > 0.0) | (not f3 > 0.0)
            n0, n1, n2, n3 = 1.0 / f0, 1.0 / f1, 1.0 / f2, 1.0 / f3
            s0, s1, s2, s3 = s0 * n0, s1 * n1, s2 * n2, s3 * n3
            v0, v1, v2, v3 = v0 * (n0 * n0), v1 * (n1 * n1), v2 * (n2 * n2), v3 * (n3 * n3)
        # red (ri, rj), green 1 (ri, bj), green 2 (bi, rj), blue (bi, bj)
        if ri == 0:
            red, vr, gr1, vg1 = (s0, v0, s1, v1) if rj == 0 else (s1, v1, s0, v0)
            gr2, vg2, blue, vb = (s2, v2, s3, v3) if rj == 0 else (s3, v3, s2, v2)
        else:
            red, vr, gr1, vg1 = (s2, v2, s3, v3) if rj == 0 else (s3, v3, s2, v2)
            gr2, vg2, blue, vb = (s0, v0, s1, v1) if rj == 0 else (s1, v1, s0, v0)
        p0, p1, p2 = red * f_rb, (gr1 + gr2) * f_g, blue * f_rb
        w0, w1, w2 = vr * q_rb, (vg1 + vg2) * q_g, vb * q_rb
        if flat_sp is not None:
            c0, c1, c2 = float(flat_sp[y, x, 0]), float(flat_sp[y, x, 1]), float(flat_sp[y, x, 2])
            bad = bad | (not c0 > 0.0) | (not c1 > 0.0) | (not c2 > 0.0)
            p0, p1, p2 = p0 / c0, p1 / c1, p2 / c2
            w0, w1, w2 = w0 / (c0 * c0), w1 / (c1 * c1), w2 / (c2 * c2)
        buf[0, x], buf[1, x], buf[2, x] = (nan if bad else p0), (nan if bad else p1), (nan if bad else p2)
        buf[3, x], buf[4, x], buf[5, x] = (nan if bad else w0), (nan if bad else w1), (nan if bad else w2)
        buf[6, x] = 0.0 if bad else 1.0


@numba.njit(**_JIT)
def _write_row(y, buf, rgb, valid, variance):  # pragma: no cover - compiled
    """Row ``y`` of the outputs (float32 RGB and variance, bool validity) from ``buf``."""
    for x in range(buf.shape[1]):
        valid[y, x] = buf[6, x] != 0.0
        rgb[y, x, 0], rgb[y, x, 1], rgb[y, x, 2] = buf[0, x], buf[1, x], buf[2, x]
        if variance is not None:
            variance[y, x, 0], variance[y, x, 1], variance[y, x, 2] = buf[3, x], buf[4, x], buf[5, x]
