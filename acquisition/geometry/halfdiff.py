"""MERL half/difference coordinates (θh, θd, φd) and the MERL table's bin indices.

Conventions follow the MERL database's reference reader (Matusik et al. 2003, ``BRDFRead.cpp``):

* the half vector h is the normalised sum of the light direction ``wi`` and the view direction
  ``wo`` (both unit, pointing away from the sample, normal +z); θh = acos(h_z),
  φh = atan2(h_y, h_x);
* the difference vector is ``wi`` rotated by −φh about z and then by −θh about y (into the frame
  where h is the pole); θd = acos(d_z), φd = atan2(d_y, d_x) ∈ (−180°, 180°];
* bins (90 × 90 × 180, flat index ``(ih·90 + id)·180 + ip``), computed from radians exactly as
  the reference does: ih = ⌊√(θh/(π/2)·90·90)⌋, id = ⌊θd/(π/2)·90⌋, ip = ⌊φd′/π·180⌋ with
  φd′ = φd + π when φd < 0 (reciprocity: swapping wi and wo turns φd into φd ± π). Angles in
  degrees are first converted like ``np.radians`` (x · (π/180)), as the reference's callers do.

The reference clamps every index into its range (NaN gives 0); :func:`merl_indices` does so by
default, or marks samples outside θh, θd ∈ [0°, 90°] with −1 (``clamp=False``) for binning.

Reproducible bins. The reference evaluates sin, cos, acos and atan2 with the C library (libm)
in IEEE double. numpy's versions of these may differ from libm in the last bits (on AVX-512
CPUs numpy dispatches them to SIMD code a few ulp away), which moves a sample sitting on a bin
edge into the neighbouring bin. :func:`halfdiff_rad_reference` and
:func:`halfdiff_rad_from_vectors` therefore compute every sample vectorised, then recompute with
scalar :mod:`math` (libm) calls, in the same operation order, every sample whose bin could
depend on those last bits (see :data:`GUARD_BAND`). Their angles always fall in the bins
that libm's would: every MERL index computed from them (clamped or not) is the libm one, on
any CPU. The acos arguments are clipped into [−1, 1] (rounding can push d_z just past 1 where
θd ≈ 0; the reference's acos returns NaN there and its index cast sends NaN to bin 0, the bin of
acos(1) = 0).

Public functions take and return degrees; the ``*_rad`` functions are the radian internals
used by the tables and the MERL reader.
"""

from __future__ import annotations

import math

import numpy as np

THETA_H_BINS = 90
THETA_D_BINS = 90
PHI_D_BINS = 180
MERL_SHAPE = (THETA_H_BINS, THETA_D_BINS, PHI_D_BINS)
MERL_BINS = THETA_H_BINS * THETA_D_BINS * PHI_D_BINS

OUT_OF_RANGE_INDEX = -1
"""Unclamped index of a sample outside θh, θd ∈ [0°, 90°]."""
NAN_INDEX = -2
"""Unclamped index of a sample with a NaN angle."""

_HALF_PI = np.pi / 2.0
DEG2RAD = np.pi / 180.0
"""Degrees → radians factor; ``x * DEG2RAD`` is exactly ``np.radians(x)``."""

# ---------------------------------------------------------------------------- exact bins
GUARD_BAND = 2.0**-16
"""Half-width, in bin units, of the band around every bin edge where samples are recomputed.

A sample is recomputed with libm when one of its continuous bin coordinates
(√(θh/(π/2)·90·90), θd/(π/2)·90, φd/π·180) lies within this distance of an integer: the bin
edges, the range limits θ = 0, π/2 and the φd wrap at 0 and ±π, where the sign of a zero
decides between bins 0 and 179. Error budget, ε being the relative error of one vector-math
result (≈ 9e-16 for 4 ulp):

* from vectors only the final acos/atan2 differ: a coordinate moves by ≤ 180·ε ≈ 2e-13;
* from angles the error propagates: vectors ≤ 3ε, the half vector's direction ≤ 3ε/|h|
  (≤ 2⁶·3ε while |h| ≥ :data:`_MIN_HALF`), φh that over sin θh (≤ 2¹⁶·3ε while
  θh ≥ :data:`_POLE`), φd that plus the error of d over sin θd (≤ 3·2¹⁶·3ε while
  θd ≥ :data:`_POLE`); θh and θd move by about the half vector's error. In bin units
  (× 180/π) that is ≤ 3e-8, plus last-bit rounding differences amplified by acos near the
  pole (≤ 2⁻⁵²·2¹⁰·57 ≈ 1.3e-11). Nearer the pole or with a shorter half vector the angles
  are always recomputed.

The band leaves a factor ~500 on that bound (measured: no integer-degree pose changes bin with
numpy's sin, cos, arccos and arctan2 off by up to 2²² ulp). It sends ~1e-4 of random samples
to the scalar path, and ~4% of integer-degree poses, many of which lie exactly on an edge.
"""
_POLE = 2.0**-10
"""θh or θd (rad) below which the angles path always recomputes (φh / φd ill-conditioned)."""
_MIN_HALF = 2.0**-6
"""|wi + wo|/2 below which the angles path always recomputes (half vector ill-conditioned)."""
_H_SCALE = THETA_H_BINS * THETA_H_BINS / _HALF_PI
_D_SCALE = THETA_D_BINS / _HALF_PI
_P_SCALE = PHI_D_BINS / np.pi


def _distance_to_integer(u: np.ndarray, buf: np.ndarray) -> np.ndarray:
    """|u − round(u)|, in place in ``u`` (``buf`` is scratch space of the same shape)."""
    np.rint(u, out=buf)
    np.subtract(u, buf, out=u)
    return np.abs(u, out=u)


def _near_bin_edge(
    theta_h: np.ndarray,
    theta_d: np.ndarray,
    phi_d: np.ndarray,
    scratch: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """Mask of the samples (1-D radians) with a bin coordinate within :data:`GUARD_BAND` of an
    integer; NaN angles are never near (NaN comes out of libm exactly where it comes out here).

    ``scratch``: three float64 arrays of the same size that may be overwritten.
    """
    dist, buf, other = scratch if scratch is not None else (np.empty_like(theta_h) for _ in "abc")
    with np.errstate(invalid="ignore"):
        np.multiply(theta_h, _H_SCALE, out=dist)
        np.sqrt(dist, out=dist)
        _distance_to_integer(dist, buf)
        np.multiply(theta_d, _D_SCALE, out=other)
        np.minimum(dist, _distance_to_integer(other, buf), out=dist)
        np.multiply(phi_d, _P_SCALE, out=other)  # φd and φd′ = φd + π have the same distance
        np.minimum(dist, _distance_to_integer(other, buf), out=dist)
        return dist < GUARD_BAND


def _ieee_div(a: float, b: float) -> float:
    """``a / b`` as IEEE double (and C, and numpy) evaluate it: no ZeroDivisionError."""
    if b != 0.0:
        return a / b
    if a == 0.0 or math.isnan(a) or math.isnan(b):
        return math.nan
    return math.copysign(math.inf, a) * math.copysign(1.0, b)


def _acos(x: float) -> float:
    """libm acos of ``x`` clipped into [−1, 1] (NaN stays NaN)."""
    return math.acos(1.0 if x > 1.0 else (-1.0 if x < -1.0 else x))


# ---------------------------------------------------------------------------- coordinates
def halfdiff_rad_from_vectors(
    wi: np.ndarray, wo: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(θh, θd, φd) in radians for unit light ``wi`` and view ``wo`` vectors (…, 3).

    The reference's rotation of ``wi`` into the half-vector frame, with the rotation folded
    into closed forms so that only three inverse trigonometric calls remain (h = wi + wo,
    ρ = |h_xy|, a = wi_x·h_x + wi_y·h_y):

    * cos θh = h_z / |h|, cos θd = (a + wi_z·h_z) / |h| (both clipped into [−1, 1]);
    * φd = atan2(|h|·(wi_y·h_x − wi_x·h_y), a·h_z − wi_z·ρ²) (both reference components
      scaled by ρ·|h| > 0).

    Where h is the normal (ρ = 0) φh is taken as 0, giving φd = atan2(wi_y, wi_x·cos θh).
    Every operation is IEEE double, in this order; acos and atan2 are libm's for every sample
    near a bin edge, so the bins are exactly those of the same closed form in C (and of the
    numba kernel) on any CPU. The angles agree with the reference up to float rounding.
    """
    wi = np.asarray(wi, dtype=np.float64)
    wo = np.asarray(wo, dtype=np.float64)
    shape = np.broadcast_shapes(wi.shape, wo.shape)[:-1]
    i = np.ascontiguousarray(np.broadcast_to(wi, (*shape, 3)).reshape(-1, 3).T)
    o = np.broadcast_to(wo, (*shape, 3)).reshape(-1, 3).T
    ix, iy, iz = i
    # Written with out= into few buffers (fresh temporaries of this size cost more than the
    # arithmetic); each line is one IEEE operation, in the order of the formulas above.
    hx = ix + o[0]
    hy = iy + o[1]
    hz = iz + o[2]
    tmp = hy * hy
    rho2 = hx * hx
    rho2 += tmp
    norm = np.multiply(hz, hz)
    norm += rho2
    np.sqrt(norm, out=norm)
    a = np.multiply(ix, hx)
    a += np.multiply(iy, hy, out=tmp)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos_h = hz / norm
        cos_d = iz * hz
        cos_d += a
        cos_d /= norm
        np.clip(cos_h, -1.0, 1.0, out=cos_h)
        np.clip(cos_d, -1.0, 1.0, out=cos_d)
        num = iy * hx
        num -= np.multiply(ix, hy, out=tmp)
        num *= norm
        den = a * hz
        den -= np.multiply(iz, rho2, out=tmp)
        pole = np.flatnonzero(rho2 == 0.0)
        if pole.size:
            num[pole] = iy[pole]
            den[pole] = ix[pole] * cos_h[pole]
        phi_d = np.arctan2(num, den, out=hx)
    theta_h = np.arccos(cos_h, out=hy)
    theta_d = np.arccos(cos_d, out=hz)
    # The inputs of acos and atan2 are exact (same IEEE operations as C): only those calls
    # are redone with libm where the bin could hang on their last bits.
    for k in np.flatnonzero(_near_bin_edge(theta_h, theta_d, phi_d, (tmp, rho2, a))).tolist():
        theta_h[k] = math.acos(cos_h[k])
        theta_d[k] = math.acos(cos_d[k])
        phi_d[k] = math.atan2(num[k], den[k])
    return theta_h.reshape(shape), theta_d.reshape(shape), phi_d.reshape(shape)


def halfdiff_rad_reference(
    theta_in: np.ndarray | float,
    phi_in: np.ndarray | float,
    theta_out: np.ndarray | float,
    phi_out: np.ndarray | float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(θh, θd, φd) in radians from spherical angles (radians), in the reference's operation order.

    Follows the reference conversion step by step (vectors from angles, half vector from the
    unnormalised components, two axis rotations of the normalised incoming vector), so that
    lookups by angle land in the same bins as the reference reader, degenerate in-plane
    configurations and exact bin edges included: samples whose bin could depend on the last
    bits of numpy's sin/cos/acos/atan2 are recomputed with libm (:func:`_reference_libm`).
    """
    arrays = np.broadcast_arrays(theta_in, phi_in, theta_out, phi_out)
    shape = arrays[0].shape
    ti, pi_, to, po = (np.asarray(a, dtype=np.float64).reshape(-1) for a in arrays)
    one_phi_in = float(phi_in) if np.ndim(phi_in) == 0 else None
    with np.errstate(invalid="ignore", divide="ignore"):
        theta_h, theta_d, phi_d, n_h = _reference_numpy(ti, pi_, to, po, one_phi_in)
        redo = _near_bin_edge(theta_h, theta_d, phi_d)
        redo |= theta_h < _POLE
        redo |= theta_d < _POLE
        redo |= n_h < _MIN_HALF
    for k in np.flatnonzero(redo).tolist():
        theta_h[k], theta_d[k], phi_d[k] = _reference_libm(
            float(ti[k]), float(pi_[k]), float(to[k]), float(po[k])
        )
    return theta_h.reshape(shape), theta_d.reshape(shape), phi_d.reshape(shape)


def _reference_numpy(
    ti: np.ndarray, pi_: np.ndarray, to: np.ndarray, po: np.ndarray, one_phi_in: float | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Vectorised reference conversion of 1-D radians; also returns |h| (unnormalised).

    ``one_phi_in``: the light azimuth when it is one value for all (e.g. 0), evaluated once
    with libm.
    """
    iz = np.cos(ti)
    ip = np.sin(ti)
    if one_phi_in is not None:
        ix = ip * math.cos(one_phi_in)
        iy = ip * math.sin(one_phi_in)
    else:
        ix = ip * np.cos(pi_)
        iy = ip * np.sin(pi_)
    oz = np.cos(to)
    op = np.sin(to)
    ox = op * np.cos(po)
    oy = op * np.sin(po)
    n_in = np.sqrt(ix * ix + iy * iy + iz * iz)
    nx, ny, nz = ix / n_in, iy / n_in, iz / n_in
    hx = (ix + ox) / 2.0
    hy = (iy + oy) / 2.0
    hz = (iz + oz) / 2.0
    n_h = np.sqrt(hx * hx + hy * hy + hz * hz)
    theta_h = np.arccos(np.clip(hz / n_h, -1.0, 1.0))
    phi_h = np.arctan2(hy / n_h, hx / n_h)
    tx, ty, tz = _rotate_like_reference((nx, ny, nz), (0.0, 0.0, 1.0), -phi_h)
    dx, dy, dz = _rotate_like_reference((tx, ty, tz), (0.0, 1.0, 0.0), -theta_h)
    theta_d = np.arccos(np.clip(dz, -1.0, 1.0))
    phi_d = np.arctan2(dy, dx)
    return theta_h, theta_d, phi_d, n_h


def _rotate_like_reference(
    v: tuple[np.ndarray, np.ndarray, np.ndarray],
    axis: tuple[float, float, float],
    angle: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rodrigues rotation of ``v`` about a unit ``axis``, every term (zeros included) added in
    the reference's order, so signed zeros (which decide atan2 = ±π in plane) come out alike."""
    c = np.cos(angle)
    s = np.sin(angle)
    a0, a1, a2 = axis
    v0, v1, v2 = v
    temp = (a0 * v0 + a1 * v1 + a2 * v2) * (1.0 - c)
    cross = (a1 * v2 - a2 * v1, a2 * v0 - a0 * v2, a0 * v1 - a1 * v0)
    return tuple(  # type: ignore[return-value]
        vk * c + ak * temp + ck * s for vk, ak, ck in zip(v, axis, cross, strict=True)
    )


def _reference_libm(ti: float, pi_: float, to: float, po: float) -> tuple[float, float, float]:
    """One sample of :func:`halfdiff_rad_reference` with libm (:mod:`math`), the same operations
    in the same order: what ``std_coords_to_half_diff_coords`` computes in C, acos clipped."""
    if not all(math.isfinite(x) for x in (ti, pi_, to, po)):
        return math.nan, math.nan, math.nan
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
    theta_h = _acos(_ieee_div(hz, n_h))
    phi_h = math.atan2(_ieee_div(hy, n_h), _ieee_div(hx, n_h))
    if math.isnan(theta_h) or math.isnan(phi_h):  # wi = −wo: no half vector
        return math.nan, math.nan, math.nan
    tx, ty, tz = _rotate_libm(nx, ny, nz, 0.0, 0.0, 1.0, -phi_h)
    dx, dy, dz = _rotate_libm(tx, ty, tz, 0.0, 1.0, 0.0, -theta_h)
    return theta_h, _acos(dz), math.atan2(dy, dx)


def _rotate_libm(
    v0: float, v1: float, v2: float, a0: float, a1: float, a2: float, angle: float
) -> tuple[float, float, float]:
    """Scalar :func:`_rotate_like_reference` (the reference's ``rotate_vector``)."""
    c = math.cos(angle)
    s = math.sin(angle)
    temp = (a0 * v0 + a1 * v1 + a2 * v2) * (1.0 - c)
    return (
        v0 * c + a0 * temp + (a1 * v2 - a2 * v1) * s,
        v1 * c + a1 * temp + (a2 * v0 - a0 * v2) * s,
        v2 * c + a2 * temp + (a0 * v1 - a1 * v0) * s,
    )


def halfdiff_from_vectors(
    wi: np.ndarray, wo: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(θh, θd, φd) in degrees for unit light ``wi`` and view ``wo`` vectors (…, 3), normal +z."""
    out = halfdiff_rad_from_vectors(wi, wo)
    return tuple(np.degrees(a) for a in out)  # type: ignore[return-value]


def halfdiff_from_angles(
    theta_i_deg: np.ndarray | float,
    theta_r_deg: np.ndarray | float,
    delta_phi_deg: np.ndarray | float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(θh, θd, φd) in degrees for isotropic (θi, θr, Δφ) in degrees (light at azimuth 0)."""
    out = halfdiff_rad_reference(
        np.radians(theta_i_deg), 0.0, np.radians(theta_r_deg), np.radians(delta_phi_deg)
    )
    return tuple(np.degrees(a) for a in out)  # type: ignore[return-value]


def vectors_from_halfdiff(
    theta_h_deg: np.ndarray | float,
    theta_d_deg: np.ndarray | float,
    phi_d_deg: np.ndarray | float,
    phi_h_deg: np.ndarray | float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Unit light and view vectors (…, 3) for half/difference angles in degrees.

    Inverse of :func:`halfdiff_from_vectors`: ``wi`` = Rz(φh)·Ry(θh)·d and ``wo`` is ``wi``
    mirrored about the half vector.
    """
    th, td, pd, ph = (
        np.radians(np.asarray(a, dtype=np.float64))
        for a in np.broadcast_arrays(theta_h_deg, theta_d_deg, phi_d_deg, phi_h_deg)
    )
    d = np.stack([np.sin(td) * np.cos(pd), np.sin(td) * np.sin(pd), np.cos(td)], axis=-1)
    # Ry(θh)
    ch, sh = np.cos(th), np.sin(th)
    x = d[..., 0] * ch + d[..., 2] * sh
    z = -d[..., 0] * sh + d[..., 2] * ch
    y = d[..., 1]
    # Rz(φh)
    cp, sp = np.cos(ph), np.sin(ph)
    wi = np.stack([x * cp - y * sp, x * sp + y * cp, z], axis=-1)
    h = np.stack([sh * cp, sh * sp, ch], axis=-1)
    wo = 2.0 * np.sum(wi * h, axis=-1, keepdims=True) * h - wi
    return wi, wo


def angles_from_halfdiff(
    theta_h_deg: np.ndarray | float,
    theta_d_deg: np.ndarray | float,
    phi_d_deg: np.ndarray | float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Isotropic (θi, θr, Δφ) in degrees, Δφ ∈ (−180, 180], for half/difference angles (deg)."""
    wi, wo = vectors_from_halfdiff(theta_h_deg, theta_d_deg, phi_d_deg)
    theta_i = np.degrees(np.arccos(np.clip(wi[..., 2], -1.0, 1.0)))
    theta_r = np.degrees(np.arccos(np.clip(wo[..., 2], -1.0, 1.0)))
    dphi = np.degrees(
        np.arctan2(wo[..., 1], wo[..., 0]) - np.arctan2(wi[..., 1], wi[..., 0])
    )
    dphi = np.where(dphi > 180.0, dphi - 360.0, np.where(dphi <= -180.0, dphi + 360.0, dphi))
    return theta_i, theta_r, dphi


# ---------------------------------------------------------------------------- bin indices
def merl_indices_rad(
    theta_h: np.ndarray, theta_d: np.ndarray, phi_d: np.ndarray, *, clamp: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """MERL bin indices (int64) for (θh, θd, φd) in radians.

    ``clamp=True`` reproduces the reference (indices clamped into range, NaN → 0).
    ``clamp=False`` marks θh or θd outside [0, π/2] with −1 (:data:`OUT_OF_RANGE_INDEX`) and
    NaN in any of the three with −2 (:data:`NAN_INDEX`) in all three indices; φd outside
    (−π, π] is folded by whole multiples of π.
    """
    th, td, pd = (
        np.asarray(a, dtype=np.float64) for a in np.broadcast_arrays(theta_h, theta_d, phi_d)
    )
    with np.errstate(invalid="ignore"):
        if clamp:
            pd = np.where(pd < 0.0, pd + np.pi, pd)
            h = np.sqrt(th / _HALF_PI * THETA_H_BINS * THETA_H_BINS)
            d = td / _HALF_PI * THETA_D_BINS
            p = pd / np.pi * PHI_D_BINS  # = (φd/π·360)/2 of the reference, exactly
            ih = _trunc_clamped(np.where(th <= 0.0, 0.0, h), THETA_H_BINS)
            idd = _trunc_clamped(d, THETA_D_BINS)
            ip = _trunc_clamped(p, PHI_D_BINS)
            return ih, idd, ip
    return _unclamped_indices(th, td, pd)


def _unclamped_indices(
    th: np.ndarray, td: np.ndarray, pd: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unclamped indices for angles in radians, the reference's arithmetic.

    Outside θh, θd ∈ [0, π/2] → −1 in all three; NaN in any → −2 in all three. φd is folded
    like the reference inside (−π, π] (so φd = π stays there and is clamped into the last
    bin) and by whole half turns elsewhere.
    """
    with np.errstate(invalid="ignore"):
        inside = (pd > -np.pi) & (pd <= np.pi)
        pd = np.where(inside, np.where(pd < 0.0, pd + np.pi, pd), np.mod(pd, np.pi))
        h = np.sqrt(np.maximum(th, 0.0) / _HALF_PI * THETA_H_BINS * THETA_H_BINS)
        d = td / _HALF_PI * THETA_D_BINS
        p = pd / np.pi * PHI_D_BINS
        ih = np.minimum(h.astype(np.int64, casting="unsafe"), THETA_H_BINS - 1)
        idd = np.minimum(d.astype(np.int64, casting="unsafe"), THETA_D_BINS - 1)
        ip = np.minimum(p.astype(np.int64, casting="unsafe"), PHI_D_BINS - 1)
        nan = np.isnan(th) | np.isnan(td) | np.isnan(pd)
        bad = ~((th >= 0.0) & (th <= _HALF_PI) & (td >= 0.0) & (td <= _HALF_PI)) | nan
    if np.any(bad):
        code = np.where(nan, NAN_INDEX, OUT_OF_RANGE_INDEX)
        ih = np.where(bad, code, ih)
        idd = np.where(bad, code, idd)
        ip = np.where(bad, code, ip)
    return ih, idd, ip


def _trunc_clamped(x: np.ndarray, n: int) -> np.ndarray:
    """C ``(int)x`` then clamp into [0, n − 1]; NaN → 0 as on x86 (INT_MIN, clamped)."""
    x = np.where(np.isnan(x), -1.0, np.clip(x, -1.0, float(n)))
    return np.clip(np.trunc(x).astype(np.int64), 0, n - 1)


def merl_flat_index_rad(
    theta_h: np.ndarray, theta_d: np.ndarray, phi_d: np.ndarray, *, clamp: bool = True
) -> np.ndarray:
    """Flat MERL index ``(ih·90 + id)·180 + ip`` for radians.

    ``clamp=True``: the reference's clamped index. ``clamp=False``: −1 outside, −2 for NaN
    (see :func:`merl_indices_rad`), computed by a fast chunked path.
    """
    if not clamp:
        return _flat_unclamped(theta_h, theta_d, phi_d, np.pi)
    ih, idd, ip = merl_indices_rad(theta_h, theta_d, phi_d, clamp=True)
    return (ih * THETA_D_BINS + idd) * PHI_D_BINS + ip


def _flat_unclamped(
    theta_h: np.ndarray | float,
    theta_d: np.ndarray | float,
    phi_d: np.ndarray | float,
    half_turn: float,
) -> np.ndarray:
    th, td, pd = np.broadcast_arrays(theta_h, theta_d, phi_d)
    out = np.empty(th.shape, dtype=np.int64)
    flat_index_unclamped_into(
        np.ravel(th).astype(np.float64, copy=False),
        np.ravel(td).astype(np.float64, copy=False),
        np.ravel(pd).astype(np.float64, copy=False),
        out.reshape(-1),
        half_turn,
    )
    return out


_INDEX_CHUNK = 1 << 16  # samples per step: temporaries stay in L2


def flat_index_unclamped_into(
    th: np.ndarray, td: np.ndarray, pd: np.ndarray, out: np.ndarray, half_turn: float = np.pi
) -> bool:
    """Unclamped flat MERL index of 1-D angles into ``out`` (int64): −1 outside, −2 NaN.

    Returns True when every sample got a valid index (nothing marked).

    Angles in radians (``half_turn`` = π) or degrees (180, converted like ``np.radians``
    first, so both units give the same bins). Same arithmetic as :func:`merl_indices_rad`
    (the reference's operation order) done in place on L2-sized chunks, the index built in
    float64 (exact for these integers) and cast once. Range and NaN checks are reductions over
    the chunk; only a chunk that fails them takes the general path.
    """
    if half_turn not in (np.pi, 180.0):
        raise ValueError(f"half_turn must be π (radians) or 180 (degrees), got {half_turn!r}")
    size = min(_INDEX_CHUNK, th.size)
    buf_h, buf_d, buf_p = np.empty(size), np.empty(size), np.empty(size)
    buf_m = np.empty(size, dtype=bool)
    radians = [np.empty(size) for _ in range(3)] if half_turn == 180.0 else None
    all_valid = True
    with np.errstate(invalid="ignore"):
        for a in range(0, th.size, _INDEX_CHUNK):
            b = min(a + _INDEX_CHUNK, th.size)
            k = b - a
            x, y, z = th[a:b], td[a:b], pd[a:b]
            if radians is not None:
                x = np.multiply(x, DEG2RAD, out=radians[0][:k])
                y = np.multiply(y, DEG2RAD, out=radians[1][:k])
                z = np.multiply(z, DEG2RAD, out=radians[2][:k])
            ok = (
                x.min() >= 0.0
                and x.max() <= _HALF_PI
                and y.min() >= 0.0
                and y.max() <= _HALF_PI
                and z.min() > -np.pi
                and z.max() <= np.pi  # all of these are False when a NaN is present
            )
            if not ok:
                ih, idd, ip = _unclamped_indices(x, y, z)
                out[a:b] = np.where(ih < 0, ih, (ih * THETA_D_BINS + idd) * PHI_D_BINS + ip)
                all_valid = all_valid and bool(ih.min(initial=0) >= 0)
                continue
            neg = buf_m[:k]
            np.less(z, 0.0, out=neg)
            p = np.multiply(neg, np.pi, out=buf_p[:k])
            p += z
            h = np.divide(x, _HALF_PI, out=buf_h[:k])
            h *= THETA_H_BINS
            h *= THETA_H_BINS
            d = np.divide(y, _HALF_PI, out=buf_d[:k])
            d *= THETA_D_BINS
            np.floor(d, out=d)
            p /= np.pi
            p *= PHI_D_BINS
            np.sqrt(h, out=h)
            np.floor(h, out=h)
            np.minimum(h, THETA_H_BINS - 1, out=h)
            np.minimum(d, THETA_D_BINS - 1, out=d)
            np.floor(p, out=p)
            np.minimum(p, PHI_D_BINS - 1, out=p)
            h *= THETA_D_BINS
            h += d
            h *= PHI_D_BINS
            h += p
            out[a:b] = h
    return all_valid


def merl_indices(
    theta_h_deg: np.ndarray | float,
    theta_d_deg: np.ndarray | float,
    phi_d_deg: np.ndarray | float,
    *,
    clamp: bool = True,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """MERL bin indices (θh, θd, φd) for angles in degrees; see :func:`merl_indices_rad`."""
    return merl_indices_rad(
        np.radians(theta_h_deg), np.radians(theta_d_deg), np.radians(phi_d_deg), clamp=clamp
    )


def merl_flat_index(
    theta_h_deg: np.ndarray | float,
    theta_d_deg: np.ndarray | float,
    phi_d_deg: np.ndarray | float,
    *,
    clamp: bool = True,
) -> np.ndarray:
    """Flat MERL index for angles in degrees (converted like ``np.radians``, then binned as
    radians); see :func:`merl_flat_index_rad`."""
    if not clamp:
        return _flat_unclamped(theta_h_deg, theta_d_deg, phi_d_deg, 180.0)
    return merl_flat_index_rad(
        np.radians(theta_h_deg), np.radians(theta_d_deg), np.radians(phi_d_deg), clamp=True
    )


def merl_bin_edges() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bin edges in degrees: θh (91, square-root spaced), θd (91), φd (181, folded to [0, 180])."""
    k_h = np.arange(THETA_H_BINS + 1, dtype=np.float64)
    return (
        90.0 * (k_h / THETA_H_BINS) ** 2,
        np.linspace(0.0, 90.0, THETA_D_BINS + 1),
        np.linspace(0.0, 180.0, PHI_D_BINS + 1),
    )


def merl_bin_angles() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nominal sample angles of the bins in degrees (each bin's lower edge, as MERL tabulates)."""
    h, d, p = merl_bin_edges()
    return h[:-1], d[:-1], p[:-1]
