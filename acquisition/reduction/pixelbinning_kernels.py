"""The compiled passes behind :mod:`acquisition.reduction.pixelbinning`: a frame's rows
straight into the MERL and isotropic tables' exact sums, in two passes.

* :func:`geometry_rows` needs no pixel value, only the pose: so it can run while the frame is
  still being decoded. Row by row, over each row's span of columns that can see the sample,
  the geometry goes through :mod:`.sample_kernels`' own SIMD row function; each pixel that sees
  the sample with cos θi and cos θr ≥ the minimum (a *candidate*) gets its column, its
  cos θi / r², its MERL bin (:func:`~acquisition.tables.kernels.merl_block_columns`), its
  pose and isotropic bin (:func:`.pose_kernels._contiguous_poses`,
  :func:`~acquisition.tables.kernels.iso_block`), at the row's offset in flat arrays.
* :func:`value_rows` takes the valid candidates (the linearized frame's validity), computes
  their BRDF and variance as :func:`.sample_kernels._brdf_row` does, and adds them, with the
  bins and poses found before, to the exact sums, a batch of :data:`BATCH` samples at a time,
  in one pass over it (:func:`_sum_batch`: each value split once for both tables, each store
  summing its own runs; the exact sums' own primitives).

So the tables get the samples that :func:`~acquisition.reduction.imaging.pixel_samples` gives,
binned as :func:`~acquisition.reduction.fusedbinning.bin_frame` bins them: the same integers,
bit for bit (exact sums: the order is irrelevant).

Room: before a row joins the batch, every store is checked for room for the batch's samples
plus that row's (at most one new bin each); when one lacks it, :func:`value_rows` returns the
first row of the batch (nothing of it was added), the caller grows the stores and calls again
from there.
"""

from __future__ import annotations

import os
from pathlib import Path

os.environ["NUMBA_DISABLE_INTEL_SVML"] = "1"  # as acquisition.tables.kernels: libm only

from drivers.numba_cache import drop_stale_cache  # noqa: E402

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
from acquisition.reduction.binning_kernels import _budget_into  # noqa: E402
from acquisition.reduction.pose_kernels import _contiguous_poses  # noqa: E402
from acquisition.reduction.sample_kernels import BUFFER_ROWS, _geometry_row  # noqa: E402
from acquisition.tables.exact_kernels import BLOCK, DROP_NAN, PAD, _convert, _room, _scatter6, scatter_padded  # noqa: E402
from acquisition.tables.kernels import iso_block, merl_block_columns  # noqa: E402

_JIT = {"cache": True, "nogil": True, "fastmath": False, "error_model": "numpy"}
BATCH = 4096
"""Samples binned together: the batch's values, bins and poses (~300 kB) stay in the L2
cache."""
_INF = np.inf


@njit(**_JIT)
def geometry_rows(frame, spans, first, stop, offsets, ncand, cols, e, midx, iidx, ti, tr, dp,
                  ei, er, ep, fold):  # pragma: no cover - compiled
    """The candidates of rows [first, stop) (``frame``: the pose's parameters, the columns'
    x and the minimum cosine): row i's ``ncand[i]`` candidates at ``offsets[i]`` onwards,
    each's column, cos θi / r² (m⁻²), MERL bin, isotropic bin, θi, θr and Δφ (folded as the
    table folds it), degrees."""
    p, xs, min_cos = frame
    lo, hi = spans
    buf = np.empty((BUFFER_ROWS, xs.size))
    pairs, raw_dp = np.empty((6, BLOCK)), np.empty(BLOCK)
    for i in range(first, stop):
        a, c = lo[i], hi[i]
        ncand[i] = 0
        if a >= c:
            continue
        _geometry_row(p, xs[a:c], (i - p[k.CY]) / p[k.FY], min_cos, buf)
        o, n, m = offsets[i], 0, 0
        for j in range(c - a):
            if buf[0, j] != 0.0:
                for q in range(6):
                    pairs[q, m] = buf[1 + q, j]
                cols[o + n] = a + j
                e[o + n] = buf[7, j]
                n += 1
                m += 1
                if m == BLOCK:
                    _pair_bins(pairs, m, o + n - m, midx, iidx, ti, tr, dp, raw_dp, ei, er, ep,
                               fold)
                    m = 0
        if m:
            _pair_bins(pairs, m, o + n - m, midx, iidx, ti, tr, dp, raw_dp, ei, er, ep, fold)
        ncand[i] = n


@njit(**_JIT)
def _pair_bins(pairs, m, at, midx, iidx, ti, tr, dp, raw_dp, ei, er, ep,
               fold):  # pragma: no cover - compiled
    """The MERL bin, θi, θr, isotropic bin and binned Δφ of the m light/view pairs in the
    columns of ``pairs`` (6, ≥ m) into those arrays from ``at`` on."""
    end = at + m
    merl_block_columns(pairs, m, midx[at:end])
    _contiguous_poses(pairs, m, ti[at:end], tr[at:end], raw_dp)
    iso_block(ti[at:end], tr[at:end], raw_dp, m, ei, er, ep, fold, iidx[at:end], dp[at:end])


@njit(**_JIT)
def _has_room(n, v, b, m):  # pragma: no cover - compiled
    """Room for ``n`` new bins in every store."""
    return _room(n, v[0], v[1], v[4]) and _room(n, b[0], b[1], b[4]) and _room(n, m[0], m[1], m[4])


@njit(inline="always", **_JIT)
def _verdict(b, finite, n_bins, tally):  # pragma: no cover - compiled
    """Whether a sample of bin ``b`` joins a store of ``n_bins`` bins; a dropped one is counted
    in ``tally`` as :func:`~acquisition.tables.exact_kernels.add_block` counts it (NaN: [1],
    out of range: [2])."""
    if b == DROP_NAN or not finite:
        tally[1] += 1
        return False
    if b < 0 or b >= n_bins:
        tally[2] += 1
        return False
    return True


@njit(**_JIT)
def sum_buffers():  # pragma: no cover - compiled
    """Scratch of :func:`_sum_batch`: the values (x, x² per channel) of :data:`BLOCK` samples
    and their parts, the MERL and isotropic bins (−1: dropped), budget values (rows padded
    with zeros to PAD) and their bins."""
    return (np.empty(6 * BLOCK), np.empty((3, 6 * BLOCK)), np.empty(BLOCK, np.int64),
            np.empty(BLOCK, np.int64), np.zeros((BLOCK, PAD)), np.empty(BLOCK, np.int64))


@njit(**_JIT)
def _sum_block(a, n, f, var, mi, ii, t0, t1, t2, rel, budget, v, b, m,
               work):  # pragma: no cover - compiled
    """Samples a … a + n − 1 (n ≤ BLOCK) of the batch into the stores: their values split
    once (:func:`~acquisition.tables.exact_kernels._convert`) for both tables, each table's
    runs then summed from the same parts."""
    x, parts, mb, ib, xb, bb = work
    n_merl, n_iso = m[0].size, v[0].size
    kept = nb = 0
    for j in range(a, a + n):
        finite = np.isfinite(f[j, 0] + f[j, 1] + f[j, 2])
        to_merl = _verdict(mi[j], finite, n_merl, m[5])
        to_iso = _verdict(ii[j], finite, n_iso, v[5])
        if not (to_merl or to_iso):
            continue
        for c in range(3):
            x[6 * kept + c] = f[j, c]
            x[6 * kept + 3 + c] = f[j, c] * f[j, c]
        mb[kept] = mi[j] if to_merl else -1
        ib[kept] = ii[j] if to_iso else -1
        kept += 1
        if to_iso and budget and _budget_into(xb[nb], var, f, rel, j, t0[j], t1[j], t2[j]):
            bb[nb] = ii[j]
            nb += 1
    _convert(x, 6 * kept, parts[0], parts[1], parts[2])
    _scatter6(mb, kept, parts[0], parts[1], parts[2], m[0], m[1], m[2], m[3], m[4], m[5])
    _scatter6(ib, kept, parts[0], parts[1], parts[2], v[0], v[1], v[2], v[3], v[4], v[5])
    scatter_padded(xb, bb, nb, b[0], b[1], b[2], b[3], b[4], b[5])


@njit(**_JIT)
def _sum_batch(n, f, var, mi, ii, t0, t1, t2, rel, budget, v, b, m,
               work):  # pragma: no cover - compiled
    """The batch's first ``n`` samples into the MERL store ``m`` and the isotropic value and
    budget stores ``v``, ``b`` (each: slot, rows, count, limbs, used, tally), which have room
    for them: the samples, drops and integers of ``add_block`` and ``iso_block_sums``."""
    for a in range(0, n, BLOCK):
        _sum_block(a, min(BLOCK, n - a), f, var, mi, ii, t0, t1, t2, rel, budget, v, b, m, work)


@njit(**_JIT)
def value_rows(frame, variance, first, stop, geometry, rel, budget, v, b, m,
               found):  # pragma: no cover - compiled
    """The valid candidates of rows [first, stop) (``frame``: rgb rows (3 values a pixel),
    validity, C (3,); ``geometry``: :func:`geometry_rows`' arrays) into the stores;
    ``found``: (samples, largest finite |f|, largest finite variance), updated. Returns
    ``stop``, or the row to call again from once the stores have grown."""
    rgb, valid, calibration = frame
    offsets, ncand, cols, e, midx, iidx, ti, tr, dp = geometry
    c0, c1, c2 = calibration[0], calibration[1], calibration[2]
    size = BATCH + valid.shape[1]
    f, var = np.empty((size, 3)), np.empty((size, 3))
    mi, ii = np.empty(size, np.int64), np.empty(size, np.int64)
    t0, t1, t2 = np.empty(size), np.empty(size), np.empty(size)
    work = sum_buffers()
    n, batch_first = 0, first
    samples, big_f, big_var = 0, found[1], found[2]
    for i in range(first, stop):
        count = ncand[i]
        if count == 0:
            continue
        if n + count > BATCH:
            _sum_batch(n, f, var, mi, ii, t0, t1, t2, rel, budget, v, b, m, work)
            samples += n
            n, batch_first = 0, i
        if not _has_room(n + count, v, b, m):
            found[0] += samples
            found[1], found[2] = big_f, big_var
            return batch_first
        o = offsets[i]
        for j in range(o, o + count):
            col = cols[j]
            if not valid[i, col]:
                continue
            s = e[j]
            s0, s1, s2 = s * c0, s * c1, s * c2  # as sample_kernels._brdf_row
            f[n, 0] = np.float64(rgb[i, 3 * col]) / s0
            f[n, 1] = np.float64(rgb[i, 3 * col + 1]) / s1
            f[n, 2] = np.float64(rgb[i, 3 * col + 2]) / s2
            if variance is not None:  # pruned at compile time
                var[n, 0] = np.float64(variance[i, 3 * col]) / (s0 * s0)
                var[n, 1] = np.float64(variance[i, 3 * col + 1]) / (s1 * s1)
                var[n, 2] = np.float64(variance[i, 3 * col + 2]) / (s2 * s2)
                for q in range(3):
                    a_s = abs(var[n, q])
                    big_var = a_s if (a_s < _INF) & (a_s > big_var) else big_var
            for q in range(3):
                ax = abs(f[n, q])
                big_f = ax if (ax < _INF) & (ax > big_f) else big_f
            mi[n], ii[n] = midx[j], iidx[j]
            t0[n], t1[n], t2[n] = ti[j], tr[j], dp[j]
            n += 1
    if n:
        _sum_batch(n, f, var, mi, ii, t0, t1, t2, rel, budget, v, b, m, work)
        samples += n
    found[0] += samples
    found[1], found[2] = big_f, big_var
    return stop
