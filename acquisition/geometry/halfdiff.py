"""MERL half/difference coordinates (θh, θd, φd) and the MERL table's bin indices.

Conventions follow the MERL database's reference reader (Matusik et al. 2003, ``BRDFRead.cpp``):

* the half vector h is the normalised sum of the light direction ``wi`` and the view direction
  ``wo`` (both unit, pointing away from the sample, normal +z); θh = acos(h_z),
  φh = atan2(h_y, h_x);
* the difference vector is ``wi`` rotated by −φh about z and then by −θh about y (into the frame
  where h is the pole); θd = acos(d_z), φd = atan2(d_y, d_x) ∈ (−180°, 180°];
* bins (90 × 90 × 180, flat index ``(ih·90 + id)·180 + ip``):
  θh index ⌊√(θh / 90°) · 90⌋ (square-root spacing: fine near the specular peak),
  θd index ⌊θd / 90° · 90⌋, φd index ⌊φd′ / 180° · 180⌋ with φd′ = φd + 180° when φd < 0
  (reciprocity: swapping wi and wo turns φd into φd ± 180°).

The reference clamps every index into its range (NaN gives 0); :func:`merl_indices` does so by
default, or marks samples outside θh, θd ∈ [0°, 90°] with −1 (``clamp=False``) for binning.

Public functions take and return degrees; the ``*_rad`` functions are the radian internals
used by the tables and the MERL reader.
"""

from __future__ import annotations

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


# ---------------------------------------------------------------------------- coordinates
def halfdiff_rad_from_vectors(
    wi: np.ndarray, wo: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(θh, θd, φd) in radians for unit light ``wi`` and view ``wo`` vectors (…, 3).

    The reference's rotation of ``wi`` into the half-vector frame, with the rotation folded
    into closed forms so that only three inverse trigonometric calls remain (h = wi + wo,
    ρ = |h_xy|, a = wi_x·h_x + wi_y·h_y):

    * cos θh = h_z / |h|, cos θd = (a + wi_z·h_z) / |h|;
    * φd = atan2(|h|·(wi_y·h_x − wi_x·h_y), a·h_z − wi_z·ρ²) (both reference components
      scaled by ρ·|h| > 0).

    Agrees with the reference up to float rounding. Where h is the normal (ρ = 0) φh is taken
    as 0, giving φd = atan2(wi_y, wi_x·cos θh).
    """
    wi = np.asarray(wi, dtype=np.float64)
    wo = np.asarray(wo, dtype=np.float64)
    shape = np.broadcast_shapes(wi.shape, wo.shape)[:-1]
    i = np.ascontiguousarray(np.broadcast_to(wi, (*shape, 3)).reshape(-1, 3).T)
    o = np.broadcast_to(wo, (*shape, 3)).reshape(-1, 3).T
    ix, iy, iz = i
    hx = ix + o[0]
    hy = iy + o[1]
    hz = iz + o[2]
    rho2 = hx * hx
    rho2 += hy * hy
    norm = hz * hz
    norm += rho2
    np.sqrt(norm, out=norm)
    a = ix * hx
    a += iy * hy
    with np.errstate(invalid="ignore", divide="ignore"):
        cos_h = hz / norm
        cos_d = iz * hz
        cos_d += a
        cos_d /= norm
        np.clip(cos_h, -1.0, 1.0, out=cos_h)
        np.clip(cos_d, -1.0, 1.0, out=cos_d)
        num = iy * hx
        num -= ix * hy
        num *= norm
        den = a * hz
        den -= iz * rho2
        phi_d = np.arctan2(num, den)
        pole = rho2 == 0.0
        if pole.any():
            phi_d[pole] = np.arctan2(iy[pole], ix[pole] * cos_h[pole])
    theta_h = np.arccos(cos_h)
    theta_d = np.arccos(cos_d)
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
    lookups by angle land in the same bins as the reference reader even in degenerate
    in-plane configurations, up to differences between numpy's and the C library's sin/cos.
    """
    ti, pi_, to, po = (
        np.asarray(a, dtype=np.float64)
        for a in np.broadcast_arrays(theta_in, phi_in, theta_out, phi_out)
    )
    iz = np.cos(ti)
    ip = np.sin(ti)
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
    with np.errstate(invalid="ignore"):
        theta_h = np.arccos(hz / n_h)
    phi_h = np.arctan2(hy / n_h, hx / n_h)
    tx, ty, tz = _rotate_like_reference((nx, ny, nz), (0.0, 0.0, 1.0), -phi_h)
    dx, dy, dz = _rotate_like_reference((tx, ty, tz), (0.0, 1.0, 0.0), -theta_h)
    with np.errstate(invalid="ignore"):
        theta_d = np.arccos(dz)
    phi_d = np.arctan2(dy, dx)
    return theta_h, theta_d, phi_d


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
    return _unclamped_indices(th, td, pd, np.pi)


def _unclamped_indices(
    th: np.ndarray, td: np.ndarray, pd: np.ndarray, half_turn: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unclamped indices for angles in radians (``half_turn`` = π) or degrees (180).

    Outside θh, θd ∈ [0, quarter turn] → −1 in all three; NaN in any → −2 in all three.
    φd is folded like the reference inside (−half, half] (so φd = half turn stays there and
    is clamped into the last bin) and by whole half turns elsewhere. In degrees the bins are
    computed as in the fast path of :func:`flat_index_unclamped_into` (√(θh·90), ⌊θd⌋, ⌊φd′⌋),
    so a sample's bin does not depend on which path its chunk took.
    """
    quarter = half_turn / 2.0
    with np.errstate(invalid="ignore"):
        inside = (pd > -half_turn) & (pd <= half_turn)
        pd = np.where(inside, np.where(pd < 0.0, pd + half_turn, pd), np.mod(pd, half_turn))
        if _one_bin_per_degree(half_turn):
            h = np.sqrt(np.maximum(th, 0.0) * float(THETA_H_BINS))
            d = td
            p = pd
        else:
            h = np.sqrt(np.maximum(th, 0.0) / quarter * THETA_H_BINS * THETA_H_BINS)
            d = td / quarter * THETA_D_BINS
            p = pd / half_turn * PHI_D_BINS
        ih = np.minimum(h.astype(np.int64, casting="unsafe"), THETA_H_BINS - 1)
        idd = np.minimum(d.astype(np.int64, casting="unsafe"), THETA_D_BINS - 1)
        ip = np.minimum(p.astype(np.int64, casting="unsafe"), PHI_D_BINS - 1)
        nan = np.isnan(th) | np.isnan(td) | np.isnan(pd)
        bad = ~((th >= 0.0) & (th <= quarter) & (td >= 0.0) & (td <= quarter)) | nan
    if np.any(bad):
        code = np.where(nan, NAN_INDEX, OUT_OF_RANGE_INDEX)
        ih = np.where(bad, code, ih)
        idd = np.where(bad, code, idd)
        ip = np.where(bad, code, ip)
    return ih, idd, ip


def _one_bin_per_degree(half_turn: float) -> bool:
    """Angles in degrees on the 90 × 90 × 180 grid: θd and φd bins are whole degrees."""
    return half_turn == 180.0 and MERL_SHAPE == (90, 90, 180)


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
    th: np.ndarray, td: np.ndarray, pd: np.ndarray, out: np.ndarray, half_turn: float
) -> bool:
    """Unclamped flat MERL index of 1-D angles into ``out`` (int64): −1 outside, −2 NaN.

    Returns True when every sample got a valid index (nothing marked).

    Angles in radians (``half_turn`` = π) or degrees (180). Same arithmetic as
    :func:`merl_indices_rad` (the reference's operation order) done in place on L2-sized
    chunks, the index built in float64 (exact for these integers) and cast once. Range and NaN
    checks are reductions over the chunk; only a chunk that fails them takes the general path.
    """
    quarter = half_turn / 2.0
    degrees = _one_bin_per_degree(half_turn)
    size = min(_INDEX_CHUNK, th.size)
    buf_h, buf_d, buf_p = np.empty(size), np.empty(size), np.empty(size)
    buf_m = np.empty(size, dtype=bool)
    all_valid = True
    with np.errstate(invalid="ignore"):
        for a in range(0, th.size, _INDEX_CHUNK):
            b = min(a + _INDEX_CHUNK, th.size)
            x, y, z = th[a:b], td[a:b], pd[a:b]
            ok = (
                x.min() >= 0.0
                and x.max() <= quarter
                and y.min() >= 0.0
                and y.max() <= quarter
                and z.min() > -half_turn
                and z.max() <= half_turn  # all of these are False when a NaN is present
            )
            if not ok:
                ih, idd, ip = _unclamped_indices(x, y, z, half_turn)
                out[a:b] = np.where(ih < 0, ih, (ih * THETA_D_BINS + idd) * PHI_D_BINS + ip)
                all_valid = all_valid and bool(ih.min(initial=0) >= 0)
                continue
            k = b - a
            h, d, p, neg = buf_h[:k], buf_d[:k], buf_p[:k], buf_m[:k]
            np.less(z, 0.0, out=neg)
            np.multiply(neg, half_turn, out=p)
            p += z
            if degrees:
                # One bin per degree in θd and φd, θh = 90·(k/90)²: no divisions needed.
                np.multiply(x, float(THETA_H_BINS), out=h)
                np.floor(y, out=d)
            else:
                np.divide(x, quarter, out=h)
                h *= THETA_H_BINS
                h *= THETA_H_BINS
                np.divide(y, quarter, out=d)
                d *= THETA_D_BINS
                np.floor(d, out=d)
                p /= half_turn
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
    """Flat MERL index for angles in degrees; see :func:`merl_flat_index_rad`.

    With ``clamp=False`` the index is computed from degrees directly (θh/90°, not via
    radians); it can differ from the radian path only where a value sits within float
    rounding of a bin edge.
    """
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
