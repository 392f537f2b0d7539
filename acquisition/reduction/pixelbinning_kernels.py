"""The compiled pass behind :mod:`acquisition.reduction.pixelbinning`: a linearized frame's
rows straight into the MERL and isotropic tables' exact sums, no per-sample arrays in between.

Row by row, over each row's span of columns that can see the sample, the geometry and BRDF go
through :mod:`.sample_kernels`' own SIMD row functions (the same bits as
:func:`acquisition.reduction.imaging.pixel_samples`); the kept pixels (valid, cos θi and cos θr
≥ the minimum) are copied, in column order, to a small batch (:data:`BATCH` samples, in the L2
cache) that goes through the fused binning kernels (:mod:`.binning_kernels`) when full. So the
tables get the samples ``pixel_samples`` then ``fusedbinning.bin_frame`` would give them, and
exact sums make the order irrelevant: the same integers, bit for bit.

Room: before a row joins the batch, every store is checked for room for the batch's samples
plus that row's (at most one new bin each); when one lacks it, the pass returns the first row
of the batch (nothing of it was added), the caller grows the stores and calls again from there.
"""

from __future__ import annotations

import os
from pathlib import Path

os.environ["NUMBA_DISABLE_INTEL_SVML"] = "1"  # as acquisition.tables.kernels: libm only

from acquisition.numba_cache import drop_stale_cache  # noqa: E402

_HERE = Path(__file__).resolve()
_TABLES = _HERE.parents[1] / "tables"
DEPENDENCIES = (_HERE.parent / "binning_kernels.py", _HERE.parent / "sample_kernels.py",
                _HERE.parent / "imaging_kernels.py", _HERE.parent / "pose_kernels.py",
                _TABLES / "kernels.py", _TABLES / "exact_kernels.py", _TABLES / "portable_trig.py")
"""The files whose compiled functions this pass calls (numba_cache: a change there drops this
module's cached code)."""
drop_stale_cache(_HERE, DEPENDENCIES)

import numpy as np  # noqa: E402
from numba import njit  # noqa: E402

from acquisition.reduction import imaging_kernels as k  # noqa: E402
from acquisition.reduction.binning_kernels import iso_frame, merl_frame  # noqa: E402
from acquisition.reduction.sample_kernels import BUFFER_ROWS, _brdf_row, _geometry_row  # noqa: E402
from acquisition.tables.exact_kernels import _room  # noqa: E402

_JIT = {"cache": True, "nogil": True, "fastmath": False, "error_model": "numpy"}
BATCH = 4096
"""Samples binned together: the batch's directions, values and variances (~400 kB) stay in
the L2 cache."""
_INF = np.inf


@njit(**_JIT)
def _bin_batch(n, wi, wo, f, var, rel, budget, ei, er, ep, fold,
               v, b, m):  # pragma: no cover - compiled
    """The batch's first ``n`` samples into the MERL store ``m`` and the isotropic value and
    budget stores ``v``, ``b`` (each: slot, rows, count, limbs, used, tally)."""
    merl_frame(wi[:n], wo[:n], f[:n], m[0], m[1], m[2], m[3], m[4], m[5], 0)
    iso_frame(wi[:n], wo[:n], f[:n], var[:n], rel, budget, ei, er, ep, fold,
              v[0], v[1], v[2], v[3], v[4], v[5], b[0], b[1], b[2], b[3], b[4], b[5], 0)


@njit(**_JIT)
def _has_room(n, v, b, m):  # pragma: no cover - compiled
    """Room for ``n`` new bins in every store."""
    return _room(n, v[0], v[1], v[4]) and _room(n, b[0], b[1], b[4]) and _room(n, m[0], m[1], m[4])


@njit(**_JIT)
def bin_rows(frame, variance, spans, first, stop, rel, budget, ei, er, ep, fold, v, b, m,
             found):  # pragma: no cover - compiled
    """Rows [first, stop) of the frame (``pixel_samples``' frame tuple and variance rows) into
    the stores; ``found``: (samples, largest finite |f|, largest finite variance), updated.
    Returns ``stop``, or the row to call again from once the stores have grown."""
    p, xs, rgb, valid, calibration, min_cos = frame
    lo, hi = spans
    buf = np.empty((BUFFER_ROWS, xs.size))
    wi, wo, f, var = (np.empty((BATCH + xs.size, 3)), np.empty((BATCH + xs.size, 3)),
                      np.empty((BATCH + xs.size, 3)), np.empty((BATCH + xs.size, 3)))
    n, batch_first = 0, first
    samples, big_f, big_var = 0, found[1], found[2]
    for i in range(first, stop):
        a, c = lo[i], hi[i]
        if a >= c:
            continue
        if n + (c - a) > BATCH:
            _bin_batch(n, wi, wo, f, var, rel, budget, ei, er, ep, fold, v, b, m)
            samples += n
            n, batch_first = 0, i
        if not _has_room(n + (c - a), v, b, m):
            found[0] += samples
            found[1], found[2] = big_f, big_var
            return batch_first
        _geometry_row(p, xs[a:c], (i - p[k.CY]) / p[k.FY], min_cos, buf)
        if variance is None:  # pruned at compile time
            _brdf_row(rgb[i, 3 * a:3 * c], None, calibration, buf)
        else:
            _brdf_row(rgb[i, 3 * a:3 * c], variance[i, 3 * a:3 * c], calibration, buf)
        row_valid = valid[i, a:c]
        for j in range(c - a):
            if buf[0, j] != 0.0 and row_valid[j]:
                for q in range(3):
                    wi[n, q] = buf[1 + q, j]
                    wo[n, q] = buf[4 + q, j]
                    x = buf[8 + q, j]
                    f[n, q] = x
                    ax = abs(x)
                    big_f = ax if (ax < _INF) & (ax > big_f) else big_f
                    if variance is not None:
                        s = buf[11 + q, j]
                        var[n, q] = s
                        a_s = abs(s)
                        big_var = a_s if (a_s < _INF) & (a_s > big_var) else big_var
                n += 1
    if n:
        _bin_batch(n, wi, wo, f, var, rel, budget, ei, er, ep, fold, v, b, m)
        samples += n
    found[0] += samples
    found[1], found[2] = big_f, big_var
    return stop
