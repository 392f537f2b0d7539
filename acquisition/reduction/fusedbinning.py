"""One frame's per-pixel samples into the MERL and isotropic tables through the fused kernels
(:mod:`acquisition.reduction.binning_kernels`): the same tables, bit for bit, as the tables'
own ``add`` methods (the reference path), several times faster.

The range checks run first, as in the reference: a sample value with |f| ≥ 2^20 sr⁻¹ raises
before either table changes. The budget's check is a bound (largest variance, largest |f|
times largest relative u, and the Δφ edges for the angles): when the bound reaches the exact
sums' range the frame goes through the reference path, which raises exactly as before or adds
it. Tables that do not match the fused kernel (numpy backend, other budget terms) go through
the reference path too.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np

from acquisition.tables import IsotropicTable, MerlTable
from acquisition.tables.exact import ExactSums
from acquisition.tables.fixedpoint import VALUE_LIMIT
from acquisition.tables.uncertainty import ANGLE_LIMIT

HELPER_SHARE = 0.2
"""Share of the isotropic table's samples the helper thread bins after the MERL table (which
costs about 0.6 of the isotropic table per sample, its budget included): the two threads then
finish about together (1 − s = 0.6 + s)."""
HELPER_FROM_SAMPLES = 1 << 15
"""Frames of fewer samples are binned on the calling thread alone (:func:`helper_for`): handing
work to the helper thread costs more than it saves there (a light-stage frame of ≈ 1,900
samples: 2.3 ms per frame with the helper, 0.9 ms without, on a busy 2-core host); above it the
two threads share the work (20,000 samples into a 9 × 9 × 18 table: 8 ms instead of 10)."""
BUDGET_TERMS = ("noise", "white_reference")
"""The budget the fused kernel sums: the image reduction's independent and correlated term."""


_POOL: list[ThreadPoolExecutor] = []


def helper_pool() -> ThreadPoolExecutor:
    """The process's one helper thread for :func:`bin_frame` (created on first use; the
    kernels release the GIL, and each thread adds into tables of its own)."""
    if not _POOL:
        _POOL.append(ThreadPoolExecutor(1, thread_name_prefix="gonio-binning"))
    return _POOL[0]


def helper_for(samples: int, pool: ThreadPoolExecutor | None) -> ThreadPoolExecutor | None:
    """``pool`` for a frame of :data:`HELPER_FROM_SAMPLES` samples or more, else None."""
    return pool if samples >= HELPER_FROM_SAMPLES else None


def fits(table: IsotropicTable, merl: MerlTable) -> bool:
    """True when the fused kernels bin into these tables (numba backend, the image
    reduction's budget, Δφ normalised within the budget's angle range)."""
    unc = table._unc
    return (table.backend == merl.backend == "numba"
            and (unc is None or (unc._summed == BUDGET_TERMS and unc._sums.n_sums == 15))
            and abs(float(table.delta_phi_edges[0])) + 360.0 < ANGLE_LIMIT)


def _largest(a: np.ndarray) -> float:
    from acquisition.tables.exact_kernels import max_finite_abs

    return float(max_finite_abs(np.asarray(a, np.float64).reshape(-1, a.shape[-1]))) if a.size else 0.0


def budget_in_range(brdf: np.ndarray, variance: np.ndarray | None, rel: np.ndarray) -> bool:
    """True when no finite budget term can reach the exact sums' range (a bound)."""
    return maxima_in_range(_largest(brdf), None if variance is None else _largest(variance),
                           _largest(rel.reshape(1, 3)))


def maxima_in_range(largest_f: float, largest_var: float | None, largest_rel: float) -> bool:
    """:func:`budget_in_range` from the largest finite |f|, variance (None: no variance) and
    relative u."""
    if largest_var is not None and largest_var >= VALUE_LIMIT:
        return False
    return largest_f * largest_rel < VALUE_LIMIT


def _bin_merl(merl: MerlTable, wi: np.ndarray, wo: np.ndarray, rgb: np.ndarray) -> None:
    from acquisition.reduction import binning_kernels

    acc = merl._acc
    tally = np.zeros(4, np.int64)
    acc._sums.run_kernel(binning_kernels.merl_frame, (wi, wo, rgb), wi.shape[0], tally)
    acc.n_dropped_nan += int(tally[1])
    acc.n_dropped_range += int(tally[2])


def _bin_isotropic(table: IsotropicTable, wi: np.ndarray, wo: np.ndarray, rgb: np.ndarray,
                   variance: np.ndarray | None, rel: np.ndarray) -> None:
    from acquisition.reduction import binning_kernels

    acc = table._acc
    tracked = table._unc is not None
    budget = table._unc._sums if tracked else ExactSums(1, 15)  # type: ignore[union-attr]
    table._stored = None
    table._stored_scatter = None
    var = np.zeros((1, 3)) if variance is None else np.ascontiguousarray(variance, np.float64)
    tally, btally = np.zeros(4, np.int64), np.zeros(4, np.int64)
    args = (wi, wo, rgb, var, rel, tracked and variance is not None, table.theta_i_edges,
            table.theta_r_edges, table.delta_phi_edges, bool(table.fold_delta_phi))
    store: ExactSums = acc._sums
    store.run_paired_kernel(budget, binning_kernels.iso_frame, args, wi.shape[0], tally, btally)
    acc.n_dropped_nan += int(tally[1])
    acc.n_dropped_range += int(tally[2])


def bin_frame(wi: np.ndarray, wo: np.ndarray, brdf: np.ndarray, variance: np.ndarray | None,
              calibration_rel: np.ndarray | None, table: IsotropicTable, merl: MerlTable,
              pool: ThreadPoolExecutor | None = None) -> bool:
    """Bin one frame's samples (unit wi, wo (N, 3); BRDF and its variance (N, 3), sr⁻¹, sr⁻²;
    C's relative u (3,)) into both tables, the MERL one in ``pool``'s thread when given;
    False, having changed nothing, when the fused path does not apply (:func:`fits`, the
    budget's range): bin through the tables then."""
    rel = (np.full(3, np.nan) if calibration_rel is None
           else np.ascontiguousarray(calibration_rel, np.float64).reshape(3))
    rgb = np.ascontiguousarray(brdf, np.float64).reshape(-1, 3)
    if not fits(table, merl):
        return False
    merl._acc.check_values(rgb)  # |f| ≥ 2^20 sr⁻¹: raises before either table changes
    if table.tracks_uncertainty and not budget_in_range(rgb, variance, rel):
        return False
    wi = np.ascontiguousarray(wi, np.float64).reshape(-1, 3)
    wo = np.ascontiguousarray(wo, np.float64).reshape(-1, 3)
    if pool is None:
        _bin_merl(merl, wi, wo, rgb)
        _bin_isotropic(table, wi, wo, rgb, variance, rel)
        return True
    split = int(wi.shape[0] * (1.0 - HELPER_SHARE))
    var = None if variance is None else variance[split:]
    helper = pool.submit(_merl_then_part, table, merl, wi, wo, rgb, var, rel, split)
    _bin_isotropic(table, wi[:split], wo[:split], rgb[:split],
                   None if variance is None else variance[:split], rel)
    table.merge_partial(helper.result().partial())  # exact sums: any split, the same table
    return True


def _merl_then_part(table: IsotropicTable, merl: MerlTable, wi: np.ndarray, wo: np.ndarray,
                    rgb: np.ndarray, variance: np.ndarray | None, rel: np.ndarray,
                    split: int) -> IsotropicTable:
    """The helper thread's share: the MERL table, then samples ``split …`` into a new
    isotropic table like ``table``."""
    _bin_merl(merl, wi, wo, rgb)
    part = table._empty_like()
    if table.tracks_uncertainty:
        part.track_uncertainty(*(dict(terms) for terms in table._budget_terms()))
    _bin_isotropic(part, wi[split:], wo[split:], rgb[split:], variance, rel)
    return part
