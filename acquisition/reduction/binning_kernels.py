"""Fused per-pixel binning: a frame's samples into the MERL table and into the isotropic table
with its uncertainty budget, one compiled pass per table, no per-sample arrays in between.

The reference path (:func:`acquisition.reduction.image.bin_frames` through the tables' own
``add`` methods) makes ~10 passes over a frame: MERL indices, values; poses, isotropic
indices, Δφ folded, the budget's terms joined into one array, range checks, value and budget
sums. Here each sample is read once: its pose (:func:`pose_kernels.block_poses`, vectorised),
its bins (:func:`acquisition.tables.kernels.iso_block`, ``merl_block_vectors``), and its value,
value², budget terms, angles and angle products go block by block through the exact sums'
own conversion and scatter (:mod:`acquisition.tables.exact_kernels`). Every value is computed
by the same IEEE operations in the same order as the reference path, so the tables hold the
same integers and drop tallies (tests/test_fused_binning.py compares them).

Numba's cache is invalidated by a change to a function's own file only, and these kernels
call compiled functions of other files: so on import, when the sources of those files
(:data:`DEPENDENCIES`) differ from those the cached code was compiled with, this module's
cached code is deleted first (:func:`_drop_stale_cache`).
"""

from __future__ import annotations

import os
from pathlib import Path

os.environ["NUMBA_DISABLE_INTEL_SVML"] = "1"  # as acquisition.tables.kernels: libm only

from drivers.numba_cache import drop_stale_cache  # noqa: E402

_HERE = Path(__file__).resolve()
_TABLES = _HERE.parents[1] / "tables"
DEPENDENCIES = (_HERE.parent / "pose_kernels.py", _TABLES / "kernels.py",
                _TABLES / "exact_kernels.py", _TABLES / "portable_trig.py")
"""The files whose compiled functions these kernels call."""


def _drop_stale_cache() -> None:
    """This module's cached machine code deleted when a dependency changed (numba_cache)."""
    drop_stale_cache(_HERE, DEPENDENCIES)


_drop_stale_cache()

import numpy as np  # noqa: E402
from numba import njit  # noqa: E402

from acquisition.reduction.pose_kernels import block_poses  # noqa: E402
from acquisition.tables.exact_kernels import BLOCK, PAD, _room, _scatter, add_block, scatter_padded  # noqa: E402
from acquisition.tables.kernels import iso_block, merl_block_vectors  # noqa: E402

_JIT = {"cache": True, "nogil": True, "fastmath": False, "error_model": "numpy"}
DROP_NAN = -2
BUDGET_SUMS = 15
"""The budget's sums per sample: noise variance (3), white reference's u (3), the angles (3)
and their products (6): :class:`acquisition.tables.uncertainty.UncertaintySums`' order."""
assert BUDGET_SUMS <= PAD  # rows of scatter_padded


@njit(**_JIT)
def merl_frame(wi, wo, rgb, slot, rows, count, limbs, used, tally, start):  # pragma: no cover
    """MERL index of each light/view pair and its value added block by block, from ``start``
    (:func:`acquisition.tables.exact_kernels.add_block`); returns where it stopped for room."""
    idx, scratch = np.empty(BLOCK, np.int64), np.empty((6, BLOCK))
    for a in range(start, wi.shape[0], BLOCK):
        m = min(BLOCK, wi.shape[0] - a)
        merl_block_vectors(wi, wo, a, m, scratch, idx)
        if not add_block(idx[:m], rgb, a, slot, rows, count, limbs, used, tally):
            return a
    return wi.shape[0]


@njit(inline="always", **_JIT)
def _budget_into(xb, var, rgb, rel, i, ti, tr, d):  # pragma: no cover - compiled
    """Sample ``i``'s budget sums into xb[0 … BUDGET_SUMS − 1]; False when one is not finite."""
    for c in range(3):
        xb[c] = var[i, c]
        xb[3 + c] = abs(rgb[i, c]) * rel[c]
    xb[6], xb[7], xb[8] = ti, tr, d
    xb[9], xb[10], xb[11] = ti * ti, tr * tr, d * d
    xb[12], xb[13], xb[14] = ti * tr, ti * d, tr * d
    ok = True
    for k in range(BUDGET_SUMS):
        ok &= np.isfinite(xb[k])  # no short circuit: a branch-free loop
    return ok


@njit(**_JIT)
def iso_frame(wi, wo, rgb, var, rel, budget, ei, er, ep, fold,
              slot, rows, count, limbs, used, tally,
              bslot, brows, bcount, blimbs, bused, btally, start):  # pragma: no cover
    """Pose, isotropic bin, values and (``budget``) budget of each sample from ``start``,
    into the value store (``slot`` …, drops in ``tally`` as ``add_block``) and the budget
    store (``bslot`` …); returns where it stopped for room in either."""
    bins = np.empty(BLOCK, np.int64)
    angles, scratch = np.empty((4, BLOCK)), np.empty((6, BLOCK))
    work = iso_buffers()
    for a in range(start, wi.shape[0], BLOCK):
        m = min(BLOCK, wi.shape[0] - a)
        if not (_room(m, slot, rows, used) and _room(m, bslot, brows, bused)):
            return a
        block_poses(wi, wo, a, m, scratch, angles[0], angles[1], angles[2])
        iso_block(angles[0], angles[1], angles[2], m, ei, er, ep, fold, bins, angles[3])
        iso_block_sums(angles[0], angles[1], angles[3], bins, a, m, rgb, var, rel, budget,
                       slot, rows, count, limbs, used, tally,
                       bslot, brows, bcount, blimbs, bused, btally, work)
    return wi.shape[0]


@njit(**_JIT)
def iso_buffers():  # pragma: no cover - compiled
    """Scratch of :func:`iso_block_sums`: values, budget (rows padded with zeros to PAD) and
    their bins."""
    return (np.empty(BLOCK * 6), np.zeros((BLOCK, PAD)), np.empty(BLOCK, np.int64),
            np.empty(BLOCK, np.int64))


@njit(**_JIT)
def iso_block_sums(ti_, tr_, d_, bins, a, m, rgb, var, rel, budget,
                   slot, rows, count, limbs, used, tally,
                   bslot, brows, bcount, blimbs, bused, btally, work):  # pragma: no cover
    """Samples ``a … a + m − 1`` (at most BLOCK; their θi, θr, folded Δφ and bin at
    ``ti_[j]`` … for j < m) into the value and budget stores, which have room for them."""
    n_bins = slot.size
    xv, xb, bv, bb = work
    nv = nb = 0
    for i in range(a, a + m):
        ti, tr, d, b = ti_[i - a], tr_[i - a], d_[i - a], bins[i - a]
        total = 0.0
        for c in range(3):
            total += rgb[i, c]
        if b == DROP_NAN or not np.isfinite(total):
            tally[1] += 1
            continue
        if b < 0 or b >= n_bins:
            tally[2] += 1
            continue
        for c in range(3):
            xv[6 * nv + c] = rgb[i, c]
            xv[6 * nv + 3 + c] = rgb[i, c] * rgb[i, c]
        bv[nv] = b
        nv += 1
        if budget and _budget_into(xb[nb], var, rgb, rel, i, ti, tr, d):
            bb[nb] = b
            nb += 1
    _scatter(xv, bv, nv, slot, rows, count, limbs, used, tally)
    scatter_padded(xb, bb, nb, bslot, brows, bcount, blimbs, bused, btally)
