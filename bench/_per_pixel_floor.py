"""The per-pixel path's arithmetic with none of its bookkeeping: a floor to measure it against.

:func:`floor_rows` does, for every candidate pixel of a frame (a pixel that sees the sample
with cos θi and cos θr ≥ the minimum), what the per-pixel path
(:mod:`acquisition.reduction.pixelbinning_kernels`) cannot do without, with the library's own
compiled functions and arithmetic (the exactness and cross-CPU identity the integrity issue
fixes):

* the row's geometry (:func:`~acquisition.reduction.sample_kernels._geometry_row`, the SIMD
  row function) and BRDF and variance (:func:`~acquisition.reduction.sample_kernels._brdf_row`);
* the candidates' light/view pairs gathered into blocks (as ``geometry_rows`` gathers them);
* the MERL index through the vectorised, guarded half/difference angles
  (:func:`~acquisition.tables.kernels._merl_guarded`: portable acos, acos, atan2);
* the pose (θi, θr, Δφ) through four portable atan2
  (:func:`~acquisition.reduction.pose_kernels._contiguous_poses`);
* the 21 values a sample adds to the tables' exact sums (x and x² of RGB; the budget's
  variance, |f|·u, angles and their products) each split into its three fixed-point parts
  (:func:`~acquisition.tables.exact_kernels.split`) and added to one accumulator.

Left out: the isotropic bin, the scalar libm path for the few samples near a MERL bin edge,
every table store (rows, runs, counts, carries, room), drop verdicts and range maxima. So no
implementation of that arithmetic reaches this rate; ``bench/image_reduce.py`` records it on
2 threads beside the real path, in the same run.
"""

from __future__ import annotations

import os

os.environ["NUMBA_DISABLE_INTEL_SVML"] = "1"  # as acquisition.tables.kernels: libm only

import numpy as np  # noqa: E402
from numba import njit  # noqa: E402

from acquisition.reduction import imaging_kernels as k  # noqa: E402
from acquisition.reduction.pose_kernels import _contiguous_poses  # noqa: E402
from acquisition.reduction.sample_kernels import BUFFER_ROWS, _brdf_row, _geometry_row  # noqa: E402
from acquisition.tables.exact_kernels import BLOCK, split  # noqa: E402
from acquisition.tables.kernels import _merl_guarded  # noqa: E402

_JIT = {"cache": False, "nogil": True, "fastmath": False, "error_model": "numpy"}
SUMS = 24
"""Columns of the value buffer: the 21 sums, padded to whole AVX2 / AVX-512 vectors."""


@njit(**_JIT)
def _block(pairs, vals, m, midx, ti, tr, dp, rel, acc):  # pragma: no cover - compiled
    """MERL index and pose of the block's m candidates, then their 21 values split and added
    into ``acc`` (3, SUMS)."""
    _merl_guarded(pairs, m, midx)
    _contiguous_poses(pairs, m, ti, tr, dp)
    for j in range(m):
        for c in range(3):
            vals[j, 9 + c] = abs(vals[j, c]) * rel[c]
        a0, a1, a2 = ti[j], tr[j], dp[j]
        vals[j, 12], vals[j, 13], vals[j, 14] = a0, a1, a2
        vals[j, 15], vals[j, 16], vals[j, 17] = a0 * a0, a1 * a1, a2 * a2
        vals[j, 18], vals[j, 19], vals[j, 20] = a0 * a1, a0 * a2, a1 * a2
    for j in range(m):
        for q in range(SUMS):
            p0, p1, p2 = split(vals[j, q])
            acc[0, q] += p0
            acc[1, q] += p1
            acc[2, q] += p2


@njit(**_JIT)
def floor_rows(frame, spans, first, stop, rgb, variance, calibration, rel,
               acc):  # pragma: no cover - compiled
    """The floor's arithmetic (module docstring) for rows [first, stop) (``frame``: pose
    parameters, the columns' x, minimum cosine; ``rgb``, ``variance``: (rows, 3 · columns));
    returns the candidates."""
    p, xs, min_cos = frame
    lo, hi = spans
    buf = np.empty((BUFFER_ROWS, xs.size))
    pairs, vals = np.empty((6, BLOCK)), np.zeros((BLOCK, SUMS))
    midx = np.empty(BLOCK, np.int64)
    ti, tr, dp = np.empty(BLOCK), np.empty(BLOCK), np.empty(BLOCK)
    total = 0
    for i in range(first, stop):
        a, c = lo[i], hi[i]
        if a >= c:
            continue
        _geometry_row(p, xs[a:c], (i - p[k.CY]) / p[k.FY], min_cos, buf)
        _brdf_row(rgb[i, 3 * a:3 * c], variance[i, 3 * a:3 * c], calibration, buf)
        m = 0
        for j in range(c - a):
            if buf[0, j] != 0.0:
                for q in range(6):
                    pairs[q, m] = buf[1 + q, j]
                for q in range(3):
                    f = buf[8 + q, j]
                    vals[m, q], vals[m, 3 + q], vals[m, 6 + q] = f, f * f, buf[11 + q, j]
                m += 1
                if m == BLOCK:
                    _block(pairs, vals, m, midx, ti, tr, dp, rel, acc)
                    total += m
                    m = 0
        if m:
            _block(pairs, vals, m, midx, ti, tr, dp, rel, acc)
            total += m
    return total
