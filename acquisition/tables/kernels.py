"""Numba kernels for binning: the flat bin index of every sample, in one compiled pass.

The tables compute a chunk's indices here (for (θh, θd, φd) given directly, a branch-free loop
that LLVM vectorises), then add the chunk to their exact sums
(:mod:`acquisition.tables.exact_kernels`). The two stay in separate compiled functions on
purpose: numba's on-disk cache is invalidated by a change to a function's own file only, so a
kernel that inlined code of another file could run stale machine code after an edit there.

Bins are the reference reader's, bit for bit: the index uses the reference's arithmetic in IEEE
double, operation for operation as :mod:`acquisition.geometry.halfdiff`, with ``math.sin``/``cos``/
``acos``/``atan2``/``sqrt`` compiled to calls of the process's libm (what ``math`` and the C
reader call). Nothing may change that arithmetic, and this module enforces it:

* no fast-math (``fastmath=False``): no reassociation, no FMA contraction (LLVM fuses a
  multiply and an add only when flagged, and numba flags nothing without fast-math);
* no Intel SVML: with the ``icc_rt`` / intel-cmplr-lib-rt package installed numba lets LLVM
  replace libm calls in vectorised loops by SVML's (a few ulp away). This module sets
  ``NUMBA_DISABLE_INTEL_SVML=1`` before importing numba and refuses to load if numba was
  already imported with SVML in use (that LLVM option cannot be undone in the process).

So the numba and numpy backends give the same bins, the same counts, exact sums and sums of
squares (each x² rounded once, then held exactly) and the same drop tallies, bit for bit, on any
x86-64 CPU and whatever the batch split or order.

The kernels release the GIL (``nogil``): threads may bin concurrently into *separate* tables
(merge them afterwards); two threads must never write into the same table at once. Compiled
code is cached in ``__pycache__`` (``cache=True``), so only the first run after an edit pays
the compile time.
"""

from __future__ import annotations

import math
import os

os.environ["NUMBA_DISABLE_INTEL_SVML"] = "1"  # read when numba is imported (just below)

import numba  # noqa: E402
import numpy as np  # noqa: E402
from numba import njit  # noqa: E402

from acquisition.geometry.halfdiff import DEG2RAD, PHI_D_BINS, THETA_D_BINS, THETA_H_BINS  # noqa: E402
from acquisition.tables import portable_trig  # noqa: E402
from acquisition.tables.accumulator import DROP_NAN, DROP_OUT_OF_RANGE  # noqa: E402
from drivers.numba_cache import drop_stale_cache  # noqa: E402

drop_stale_cache(__file__, (portable_trig.__file__,))  # the MERL kernels compile its acos in

if numba.config.USING_SVML:  # pragma: no cover - only with icc_rt and numba imported earlier
    raise ImportError(
        "numba was imported with Intel SVML enabled before acquisition.tables.kernels, so its "
        "kernels would not reproduce libm's bins; set NUMBA_DISABLE_INTEL_SVML=1 in the "
        "environment (or import acquisition.tables first), or use GONIO_BINNING_BACKEND=numpy"
    )

_HALF_PI = np.pi / 2.0
_DEG2RAD = DEG2RAD  # np.radians(x) is x * (π / 180)
_NH = float(THETA_H_BINS)
_ND = float(THETA_D_BINS)
_NP = float(PHI_D_BINS)

SLOW = -3
"""Index a vectorised pass leaves to the scalar, libm path."""
GUARD_REL = 1e-13
"""Relative distance from a bin edge within which the vectorised MERL path defers to libm's:
portable_trig is within 3 ulp and libm's acos/atan2 within 1 (4 ulp < 1e-15 relative)."""
PAIR_BLOCK = 256
"""Light/view pairs per block of :func:`merl_block_vectors` (its scratch: (6, PAIR_BLOCK))."""

# Every kernel: exact IEEE arithmetic (no fast-math); x/0 → inf/NaN rather than an exception.
_JIT = {"cache": True, "nogil": True, "fastmath": False, "error_model": "numpy"}


# ---------------------------------------------------------------------------- MERL indices
@njit(inline="always", **_JIT)
def _merl_inside(x, y, z):  # pragma: no cover - compiled
    """Flat MERL index of (θh, θd, φd) in radians inside the table with φd in (−π, π], with
    the reference's arithmetic (as :func:`_merl_flat_rad`); −3 for any other (NaN, out of
    range, φd to fold). Branch-free: loops that call it vectorise."""
    ok = (x >= 0.0) & (x <= _HALF_PI) & (y >= 0.0) & (y <= _HALF_PI)
    ok = ok & (z > -np.pi) & (z <= np.pi)
    p = (np.pi if z < 0.0 else 0.0) + z
    h = np.floor(np.sqrt(x / _HALF_PI * _NH * _NH))
    h = h if h < _NH - 1.0 else _NH - 1.0
    d = np.floor(y / _HALF_PI * _ND)
    d = d if d < _ND - 1.0 else _ND - 1.0
    p = np.floor(p / np.pi * _NP)
    p = p if p < _NP - 1.0 else _NP - 1.0
    flat = (h * _ND + d) * _NP + p
    return int(flat) if ok else SLOW


@njit(**_JIT)
def _merl_block(th, td, pd, a, out, scale):  # pragma: no cover - compiled
    """Flat MERL index of samples ``a + j`` into ``out[j]``, angles times ``scale`` in radians
    (π/180 for degrees, exactly ``np.radians``; 1 for radians); returns how many needed the
    general path.

    A branch-free pass (LLVM vectorises it, ~4× the scalar speed) computes the index of every
    sample inside the table with φd in (−π, π] with the reference's arithmetic, exactly as
    :func:`_merl_flat_rad`; the rest (NaN, out of range, φd to fold) go through that function.
    """
    n_slow = 0
    for j in range(out.size):
        out[j] = _merl_inside(th[a + j] * scale, td[a + j] * scale, pd[a + j] * scale)
        n_slow += 1 if out[j] == SLOW else 0
    if n_slow:
        for j in range(out.size):
            if out[j] == SLOW:
                out[j] = _merl_flat_rad(th[a + j] * scale, td[a + j] * scale, pd[a + j] * scale)
    return n_slow


@njit(**_JIT)
def _merl_flat_rad(th, td, pd):  # pragma: no cover - compiled
    """Unclamped flat MERL index of (θh, θd, φd) in radians, the reference reader's arithmetic
    (θh/(π/2)·90·90, θd/(π/2)·90, φd′/π·180); −2 for NaN, −1 outside θh, θd ∈ [0, π/2]."""
    if -np.pi < pd <= np.pi:  # noqa: SIM108
        p = (np.pi if pd < 0.0 else 0.0) + pd
    else:
        p = pd % np.pi
    if math.isnan(th) or math.isnan(td) or math.isnan(p):
        return DROP_NAN
    if not (th >= 0.0 and th <= _HALF_PI and td >= 0.0 and td <= _HALF_PI):
        return DROP_OUT_OF_RANGE
    h = min(math.floor(math.sqrt(th / _HALF_PI * _NH * _NH)), _NH - 1.0)
    d = min(math.floor(td / _HALF_PI * _ND), _ND - 1.0)
    p = min(math.floor(p / np.pi * _NP), _NP - 1.0)
    return int((h * _ND + d) * _NP + p)


@njit(**_JIT)
def _clip1(x):  # pragma: no cover - compiled
    """``x`` clipped into [−1, 1] for acos; NaN stays NaN."""
    return 1.0 if x > 1.0 else (-1.0 if x < -1.0 else x)


@njit(inline="always", **_JIT)
def _halfdiff_args(ix, iy, iz, ox, oy, oz):  # pragma: no cover - compiled
    """(cos θh, cos θd, clipped into [−1, 1]; φd's atan2 arguments y, x (for ρ² ≠ 0); ρ² of
    the half vector) of a light/view pair, the reference's arithmetic
    (:func:`acquisition.geometry.halfdiff.halfdiff_rad_from_vectors`)."""
    hx = ix + ox
    hy = iy + oy
    hz = iz + oz
    rho2 = hx * hx + hy * hy
    norm = np.sqrt(hz * hz + rho2)
    a = ix * hx + iy * hy
    return (_clip1(hz / norm), _clip1((iz * hz + a) / norm), (iy * hx - ix * hy) * norm,
            a * hz - iz * rho2, rho2)


@njit(**_JIT)
def _halfdiff_vectors(ix, iy, iz, ox, oy, oz):  # pragma: no cover - compiled
    """(θh, θd, φd) in radians, operation for operation as
    :func:`acquisition.geometry.halfdiff.halfdiff_rad_from_vectors`."""
    cos_h, cos_d, y, x, rho2 = _halfdiff_args(ix, iy, iz, ox, oy, oz)
    phi_d = math.atan2(iy, ix * cos_h) if rho2 == 0.0 else math.atan2(y, x)
    return math.acos(cos_h), math.acos(cos_d), phi_d


@njit(**_JIT)
def _merl_flat_pair(ix, iy, iz, ox, oy, oz):  # pragma: no cover - compiled
    """Flat MERL index of the light/view pair (ix, iy, iz), (ox, oy, oz): below the horizon
    −1, NaN −2."""
    th, td, pd = _halfdiff_vectors(ix, iy, iz, ox, oy, oz)
    b = _merl_flat_rad(th, td, pd)
    if not (iz > 0.0 and oz > 0.0):
        given_nan = (
            math.isnan(ix) or math.isnan(iy) or math.isnan(iz)
            or math.isnan(ox) or math.isnan(oy) or math.isnan(oz)
        )
        if (iz <= 0.0 or oz <= 0.0) and not given_nan:
            b = DROP_OUT_OF_RANGE
    return b


@njit(**_JIT)
def pair_columns(wi, wo, a, m, scratch):  # pragma: no cover - compiled
    """Rows a … a + m − 1 of wi and wo (N, 3) as the columns of scratch (6, ≥ m): loops that
    read them with a stride of 3 do not vectorise."""
    for j in range(m):
        for q in range(3):
            scratch[q, j] = wi[a + j, q]
            scratch[3 + q, j] = wo[a + j, q]


@njit(inline="always", **_JIT)
def _spread(v):  # pragma: no cover - compiled
    """(low, high) bounds of an angle computed by portable_trig around libm's value."""
    e = abs(v) * GUARD_REL + 1e-300
    return v - e, v + e


@njit(**_JIT)
def _merl_guarded(c, m, out):  # pragma: no cover - compiled
    """Flat MERL index of the pairs in the columns of c, or SLOW: the half/difference angles
    by :mod:`acquisition.tables.portable_trig` (vectorised), then the index at both ends of
    each angle's error bound; where both agree (and both light and view are above the
    horizon), libm's angle, which lies between, has that index too (the index is monotonic
    in each angle, φd's jump at 0 aside, which the two ends see)."""
    for j in range(m):
        ix, iy, iz, ox, oy, oz = c[0, j], c[1, j], c[2, j], c[3, j], c[4, j], c[5, j]
        cos_h, cos_d, y, x, rho2 = _halfdiff_args(ix, iy, iz, ox, oy, oz)
        th = portable_trig.acos(cos_h)
        td = portable_trig.acos(cos_d)
        pd = portable_trig.atan2(y, x)
        h0, h1 = _spread(th)
        d0, d1 = _spread(td)
        p0, p1 = _spread(pd)
        lo = _merl_inside(h0, d0, p0)
        hi = _merl_inside(h1, d1, p1)
        above = (iz > 0.0) & (oz > 0.0) & (rho2 != 0.0)
        out[j] = lo if (lo == hi) & above else SLOW


@njit(**_JIT)
def merl_block_columns(c, m, out):  # pragma: no cover - compiled
    """Flat MERL index of the m pairs in the columns of c (6, ≥ m) into out[:m], equal to
    :func:`_merl_flat_pair`'s: vectorised and guarded (:func:`_merl_guarded`), libm's
    arithmetic for the few near a bin edge (and NaN, below the horizon, straight up)."""
    _merl_guarded(c, m, out)
    for j in range(m):
        if out[j] == SLOW:
            out[j] = _merl_flat_pair(c[0, j], c[1, j], c[2, j], c[3, j], c[4, j], c[5, j])


@njit(**_JIT)
def merl_block_vectors(wi, wo, a, m, scratch, out):  # pragma: no cover - compiled
    """:func:`merl_block_columns` of pairs a … a + m − 1 (m ≤ PAIR_BLOCK) of wi and wo (N, 3),
    through ``scratch`` (6, ≥ m)."""
    pair_columns(wi, wo, a, m, scratch)
    merl_block_columns(scratch, m, out)


@njit(**_JIT)
def _rotate(v0, v1, v2, a0, a1, a2, angle):  # pragma: no cover - compiled
    """Rodrigues rotation with every term (zeros included) in the reference's order."""
    c = math.cos(angle)
    s = math.sin(angle)
    temp = (a0 * v0 + a1 * v1 + a2 * v2) * (1.0 - c)
    x = v0 * c + a0 * temp + (a1 * v2 - a2 * v1) * s
    y = v1 * c + a1 * temp + (a2 * v0 - a0 * v2) * s
    z = v2 * c + a2 * temp + (a0 * v1 - a1 * v0) * s
    return x, y, z


@njit(**_JIT)
def _merl_flat_angles(ti_deg, tr_deg, dp_deg):  # pragma: no cover - compiled
    """Flat MERL index for isotropic (θi, θr, Δφ) in degrees, light at azimuth 0, operation
    for operation as :func:`acquisition.geometry.halfdiff.halfdiff_rad_reference` (the reference's
    ``std_coords_to_half_diff_coords``, acos arguments clipped into [−1, 1]); θi or θr outside
    [0°, 90°] gives −1 (unless NaN, −2)."""
    ti = ti_deg * _DEG2RAD
    to = tr_deg * _DEG2RAD
    po = dp_deg * _DEG2RAD
    pi_ = 0.0
    iz = math.cos(ti)
    ip = math.sin(ti)
    ix = ip * math.cos(pi_)
    iy = ip * math.sin(pi_)
    oz = math.cos(to)
    op = math.sin(to)
    ox = op * math.cos(po)
    oy = op * math.sin(po)
    n_in = math.sqrt(ix * ix + iy * iy + iz * iz)
    nx, ny, nz = ix / n_in, iy / n_in, iz / n_in
    hx = (ix + ox) / 2.0
    hy = (iy + oy) / 2.0
    hz = (iz + oz) / 2.0
    n_h = math.sqrt(hx * hx + hy * hy + hz * hz)
    theta_h = math.acos(_clip1(hz / n_h))
    phi_h = math.atan2(hy / n_h, hx / n_h)
    tx, ty, tz = _rotate(nx, ny, nz, 0.0, 0.0, 1.0, -phi_h)
    dx, dy, dz = _rotate(tx, ty, tz, 0.0, 1.0, 0.0, -theta_h)
    theta_d = math.acos(_clip1(dz))  # d_z may round past 1 where θd ≈ 0: bin 0, as the reference
    phi_d = math.atan2(dy, dx)
    b = _merl_flat_rad(theta_h, theta_d, phi_d)
    if b != DROP_NAN and not (0.0 <= ti_deg <= 90.0 and 0.0 <= tr_deg <= 90.0):
        b = DROP_OUT_OF_RANGE
    return b


@njit(**_JIT)
def merl_flat_index_vectors(wi, wo, out):  # pragma: no cover - compiled
    """Flat MERL index per light/view pair into ``out`` (what :func:`merl_add_vectors` bins)."""
    scratch = np.empty((6, PAIR_BLOCK))
    for a in range(0, wi.shape[0], PAIR_BLOCK):
        m = min(PAIR_BLOCK, wi.shape[0] - a)
        merl_block_vectors(wi, wo, a, m, scratch, out[a:])


@njit(**_JIT)
def merl_flat_index_angles(ti, tr, dp, out):  # pragma: no cover - compiled
    """Flat MERL index per (θi, θr, Δφ) in degrees into ``out`` (what merl_add_angles bins)."""
    for i in range(ti.size):
        out[i] = _merl_flat_angles(ti[i], tr[i], dp[i])


@njit(**_JIT)
def merl_flat_index_deg(th, td, pd, out):  # pragma: no cover - compiled
    """Flat MERL index per (θh, θd, φd) in degrees into ``out`` (what merl_add_halfdiff_deg bins)."""
    _merl_block(th, td, pd, 0, out, _DEG2RAD)


# ---------------------------------------------------------------------------- isotropic
@njit(**_JIT)
def _axis_index(v, edges):  # pragma: no cover - compiled
    """Bin of ``v`` in [e_k, e_k+1), the last bin closed; −1 outside (and for NaN).

    The k with e_k ≤ v < e_k+1 (``searchsorted(side="right") − 1``) is unique for strictly
    increasing edges: it is found from a guess (exact for evenly spaced edges) by comparing
    with the edges themselves, so the guess's rounding never changes the bin."""
    n = edges.size - 1
    if v == edges[n]:
        return n - 1
    if not (v >= edges[0] and v < edges[n]):  # NaN too
        return -1
    k = int((v - edges[0]) / (edges[n] - edges[0]) * n)
    k = min(max(k, 0), n - 1)
    while edges[k] > v:
        k -= 1
    while edges[k + 1] <= v:
        k += 1
    return k


@njit(inline="always", **_JIT)
def _mod360(x):  # pragma: no cover - compiled
    """``x % 360.0`` (numpy's ``np.mod``: fmod, then + 360 when the signs differ, a zero
    +0), without the fmod call for |x| < 360, where fmod(x, 360) is x itself."""
    if not (-360.0 < x < 360.0):
        return x % 360.0
    if x == 0.0:
        return 0.0
    return x + 360.0 if x < 0.0 else x


@njit(inline="always", **_JIT)
def _delta_on_axis(dp, fold, start):  # pragma: no cover - compiled
    """Δφ (deg) as the table's Δφ axis bins it: folded into [0, 180], or brought into
    [start, start + 360)."""
    if fold:
        d = _mod360(dp)
        return 360.0 - d if d > 180.0 else d
    return start + _mod360(dp - start)


@njit(**_JIT)
def _iso_flat(ti, tr, dp, ei, er, ep, fold, start):  # pragma: no cover - compiled
    """Flat isotropic index, the edge rule of :class:`~acquisition.tables.IsotropicTable`
    (numba's float ``%`` is numpy's ``np.mod``: fmod, then + 360 when the signs differ)."""
    if math.isnan(ti) or math.isnan(tr) or math.isnan(dp):
        return DROP_NAN
    d = _delta_on_axis(dp, fold, start)
    ii = _axis_index(ti, ei)
    ir = _axis_index(tr, er)
    ip = _axis_index(d, ep)
    if ii < 0 or ir < 0 or ip < 0:
        return DROP_OUT_OF_RANGE
    return (ii * (er.size - 1) + ir) * (ep.size - 1) + ip


UNEVEN = 1e-6
"""Edges further than this (in bins) from evenly spaced: every sample takes the scalar path."""


@njit(**_JIT)
def axis_spacing(edges):  # pragma: no cover - compiled
    """(first edge, bins per unit, guard in bins) of an axis for :func:`_axis_guess`: the
    guard is how far (in bins) the edges stray from evenly spaced, plus 1e-9 for rounding;
    1 (nothing passes) past :data:`UNEVEN`."""
    n = edges.size - 1
    step = (edges[n] - edges[0]) / n
    stray = 0.0
    for k in range(n + 1):
        stray = max(stray, abs(edges[k] - (edges[0] + k * step)) / step)
    return edges[0], n / (edges[n] - edges[0]), (stray + 1e-9 if stray <= UNEVEN else 1.0)


@njit(inline="always", **_JIT)
def _axis_guess(v, first, per_unit, guard, n):  # pragma: no cover - compiled
    """Bin of ``v`` (:func:`_axis_index`'s) from arithmetic alone, where v is more than
    ``guard`` bins from every edge (g's rounding, ~1e-13 bins, is well inside the guard;
    within it the edges may stray from evenly spaced, on the same side of v); else −1, and
    the scalar path decides (edges, NaN, outside). Branch-free: no gathers."""
    g = (v - first) * per_unit
    k = np.floor(g)
    frac = g - k
    clear = (frac > guard) & (frac < 1.0 - guard) & (k >= 0.0) & (k < n)
    return int(k) if clear else -1


@njit(**_JIT)
def iso_block(ti, tr, dp, m, ei, er, ep, fold, bins, delta):  # pragma: no cover - compiled
    """Flat isotropic bin (:func:`_iso_flat`, the same index and drop codes) and the Δφ it
    bins on (folded into [0, 180] or brought into [ep[0], ep[0] + 360)) of samples j < m:
    a vectorised pass, then :func:`_iso_flat` for the few it leaves (see _axis_guess)."""
    start = ep[0]
    ni, nr, npd = ei.size - 1, er.size - 1, ep.size - 1
    i0, iu, ig = axis_spacing(ei)
    r0, ru, rg = axis_spacing(er)
    p0, pu, pg = axis_spacing(ep)
    for j in range(m):
        x = dp[j] if fold else dp[j] - start
        w = x + 360.0 if x < 0.0 else x  # _mod360 for |x| < 360, +0 for ±0
        w = 0.0 if w == 0.0 else w
        w = 360.0 - w if fold & (w > 180.0) else w
        d = w if fold else start + w
        ii = _axis_guess(ti[j], i0, iu, ig, ni)
        ir = _axis_guess(tr[j], r0, ru, rg, nr)
        ip = _axis_guess(d, p0, pu, pg, npd)
        fast = (ii >= 0) & (ir >= 0) & (ip >= 0) & (x > -360.0) & (x < 360.0)
        bins[j] = (ii * nr + ir) * npd + ip if fast else SLOW
        delta[j] = d
    for j in range(m):
        if bins[j] == SLOW:
            bins[j] = _iso_flat(ti[j], tr[j], dp[j], ei, er, ep, fold, start)
            delta[j] = _delta_on_axis(dp[j], fold, start)


@njit(**_JIT)
def iso_flat_index(ti, tr, dp, ei, er, ep, fold, out):  # pragma: no cover - compiled
    """Flat isotropic bin index per sample into ``out`` (what :func:`iso_add` bins)."""
    delta = np.empty(PAIR_BLOCK)
    for a in range(0, ti.size, PAIR_BLOCK):
        m = min(PAIR_BLOCK, ti.size - a)
        iso_block(ti[a:], tr[a:], dp[a:], m, ei, er, ep, fold, out[a:], delta)

