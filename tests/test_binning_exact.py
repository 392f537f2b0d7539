"""Reproducible binning: every backend bins like the MERL reference reader, bit for bit.

The reference below is transcribed from ``BRDFRead.cpp`` (``std_coords_to_half_diff_coords``,
``rotate_vector``, ``normalize`` and the three ``*_index`` functions, in their term order) with
Python's :mod:`math`, which calls the C library's sin, cos, acos, atan2 and sqrt as the C reader
does; it shares no code with :mod:`acquisition.geometry.halfdiff`. numpy's vector math may round
differently from libm (it does on AVX-512 CPUs): the perturbation tests replace numpy's ufuncs
by ones a few ulp off, so that a binning path relying on numpy's last bits fails here too.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import zlib
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

import acquisition.geometry.halfdiff as halfdiff
from acquisition.geometry.halfdiff import MERL_BINS, MERL_SHAPE, merl_bin_edges
from acquisition.tables import IsotropicTable, MerlTable, kernels

ROOT = Path(__file__).resolve().parent.parent
BACKENDS = ("numba", "numpy")
INT_MIN = -(2**31)


# ---------------------------------------------------------------------------- reference reader
def c_int(x: float) -> int:
    """C ``(int)x`` on x86-64: truncation toward zero; NaN and overflow give INT_MIN."""
    return int(x) if math.isfinite(x) and abs(x) < 2.0**31 else INT_MIN


def c_acos(x: float) -> float:
    """C ``acos``: NaN outside [−1, 1] (Python's raises instead)."""
    return math.acos(x) if -1.0 <= x <= 1.0 else math.nan


def normalize(v: list[float]) -> list[float]:
    length = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    return [v[0] / length, v[1] / length, v[2] / length]


def rotate_vector(vector: list[float], axis: list[float], angle: float) -> list[float]:
    cos_ang = math.cos(angle)
    sin_ang = math.sin(angle)
    out = [vector[0] * cos_ang, vector[1] * cos_ang, vector[2] * cos_ang]
    temp = axis[0] * vector[0] + axis[1] * vector[1] + axis[2] * vector[2]
    temp = temp * (1.0 - cos_ang)
    out = [out[k] + axis[k] * temp for k in range(3)]
    cross = [
        axis[1] * vector[2] - axis[2] * vector[1],
        axis[2] * vector[0] - axis[0] * vector[2],
        axis[0] * vector[1] - axis[1] * vector[0],
    ]
    return [out[k] + cross[k] * sin_ang for k in range(3)]


def std_coords_to_half_diff_coords(
    theta_in: float, fi_in: float, theta_out: float, fi_out: float
) -> tuple[float, float, float, float]:
    in_vec_z = math.cos(theta_in)
    proj_in_vec = math.sin(theta_in)
    in_vec_x = proj_in_vec * math.cos(fi_in)
    in_vec_y = proj_in_vec * math.sin(fi_in)
    in_ = normalize([in_vec_x, in_vec_y, in_vec_z])
    out_vec_z = math.cos(theta_out)
    proj_out_vec = math.sin(theta_out)
    out_vec_x = proj_out_vec * math.cos(fi_out)
    out_vec_y = proj_out_vec * math.sin(fi_out)
    # The half vector is built from the unnormalised components (as in the C code).
    half = normalize(
        [(in_vec_x + out_vec_x) / 2.0, (in_vec_y + out_vec_y) / 2.0, (in_vec_z + out_vec_z) / 2.0]
    )
    theta_half = c_acos(half[2])
    fi_half = math.atan2(half[1], half[0])
    temp = rotate_vector(in_, [0.0, 0.0, 1.0], -fi_half)
    diff = rotate_vector(temp, [0.0, 1.0, 0.0], -theta_half)
    return theta_half, fi_half, c_acos(diff[2]), math.atan2(diff[1], diff[0])


def theta_half_index(theta_half: float) -> int:
    if theta_half <= 0.0:
        return 0
    theta_half_deg = (theta_half / (math.pi / 2.0)) * 90
    ret = c_int(math.sqrt(theta_half_deg * 90))
    return min(max(ret, 0), 89)


def theta_diff_index(theta_diff: float) -> int:
    tmp = c_int(theta_diff / (math.pi * 0.5) * 90)
    return 0 if tmp < 0 else min(tmp, 89)


def phi_diff_index(phi_diff: float) -> int:
    if phi_diff < 0.0:
        phi_diff += math.pi
    tmp = c_int(phi_diff / math.pi * 360 / 2)
    return 0 if tmp < 0 else min(tmp, 179)


def lookup_index(theta_in: float, fi_in: float, theta_out: float, fi_out: float) -> int:
    """The flat index ``lookup_brdf_val`` reads for spherical angles in radians."""
    th, _, td, pd = std_coords_to_half_diff_coords(theta_in, fi_in, theta_out, fi_out)
    return phi_diff_index(pd) + theta_diff_index(td) * 180 + theta_half_index(th) * 180 * 90


def reference_index(theta_i_deg: float, theta_r_deg: float, delta_phi_deg: float) -> int:
    """The reference lookup's flat index for isotropic angles in degrees (light at azimuth 0)."""
    return lookup_index(
        math.radians(theta_i_deg), 0.0, math.radians(theta_r_deg), math.radians(delta_phi_deg)
    )


# The same formulas over arrays: every +, −, ×, ÷, √ is one IEEE operation in numpy as in C,
# every sin, cos, acos, atan2 a scalar math (libm) call, distinct input angles evaluated once.
def libm(f: Callable[..., float], *args: np.ndarray) -> np.ndarray:
    return np.fromiter(map(f, *(a.tolist() for a in args)), dtype=np.float64, count=args[0].size)


def libm_of_degrees(f: Callable[[float], float], deg: np.ndarray) -> np.ndarray:
    values, inverse = np.unique(deg, return_inverse=True)
    return libm(lambda d: f(math.radians(d)), values)[inverse]


def libm_acos(x: np.ndarray) -> np.ndarray:
    out = libm(math.acos, np.clip(x, -1.0, 1.0))
    out[(x < -1.0) | (x > 1.0)] = np.nan
    return out


def rotate_arrays(v: tuple[np.ndarray, ...], axis: tuple[float, ...], angle: np.ndarray):
    cos_ang, sin_ang = libm(math.cos, angle), libm(math.sin, angle)
    temp = (axis[0] * v[0] + axis[1] * v[1] + axis[2] * v[2]) * (1.0 - cos_ang)
    cross = (axis[1] * v[2] - axis[2] * v[1], axis[2] * v[0] - axis[0] * v[2],
             axis[0] * v[1] - axis[1] * v[0])
    return tuple(v[k] * cos_ang + axis[k] * temp + cross[k] * sin_ang for k in range(3))


def c_int_array(x: np.ndarray) -> np.ndarray:
    ok = np.isfinite(x) & (np.abs(x) < 2.0**31)
    return np.where(ok, np.trunc(np.where(ok, x, 0.0)), INT_MIN).astype(np.int64)


def reference_index_arrays(
    ti_deg: np.ndarray, tr_deg: np.ndarray, dp_deg: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`reference_index` of every sample, and θd/(π/2)·90 (the θd bin coordinate)."""
    cos0, sin0 = math.cos(0.0), math.sin(0.0)
    in_z = libm_of_degrees(math.cos, ti_deg)
    proj_in = libm_of_degrees(math.sin, ti_deg)
    in_x, in_y = proj_in * cos0, proj_in * sin0
    length = np.sqrt(in_x * in_x + in_y * in_y + in_z * in_z)
    in_ = (in_x / length, in_y / length, in_z / length)
    out_z = libm_of_degrees(math.cos, tr_deg)
    proj_out = libm_of_degrees(math.sin, tr_deg)
    out_x = proj_out * libm_of_degrees(math.cos, dp_deg)
    out_y = proj_out * libm_of_degrees(math.sin, dp_deg)
    hx, hy, hz = (in_x + out_x) / 2.0, (in_y + out_y) / 2.0, (in_z + out_z) / 2.0
    length = np.sqrt(hx * hx + hy * hy + hz * hz)
    hx, hy, hz = hx / length, hy / length, hz / length
    theta_half = libm_acos(hz)
    fi_half = libm(math.atan2, hy, hx)
    temp = rotate_arrays(in_, (0.0, 0.0, 1.0), -fi_half)
    dx, dy, dz = rotate_arrays(temp, (0.0, 1.0, 0.0), -theta_half)
    theta_diff = libm_acos(dz)
    phi_diff = libm(math.atan2, dy, dx)
    with np.errstate(invalid="ignore"):
        ih = c_int_array(np.sqrt((theta_half / (math.pi / 2.0)) * 90 * 90))
        ih = np.where(theta_half <= 0.0, 0, np.clip(ih, 0, 89))
        coord_d = theta_diff / (math.pi * 0.5) * 90
        idd = np.clip(c_int_array(coord_d), 0, 89)
        phi_diff = np.where(phi_diff < 0.0, phi_diff + math.pi, phi_diff)
        ip = np.clip(c_int_array(phi_diff / math.pi * 360 / 2), 0, 179)
    return ip + idd * 180 + ih * 180 * 90, coord_d


def closed_form_index(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """Flat index of light/view pairs by the documented closed form of
    :func:`acquisition.geometry.halfdiff.halfdiff_rad_from_vectors`, scalar, with libm."""
    out = np.empty(wi.shape[0], dtype=np.int64)
    for k, ((ix, iy, iz), (ox, oy, oz)) in enumerate(zip(wi.tolist(), wo.tolist(), strict=True)):
        if iz <= 0.0 or oz <= 0.0:
            out[k] = -1
            continue
        hx, hy, hz = ix + ox, iy + oy, iz + oz
        rho2 = hx * hx + hy * hy
        norm = math.sqrt(hz * hz + rho2)
        a = ix * hx + iy * hy
        cos_h = min(max(hz / norm, -1.0), 1.0)
        cos_d = min(max((iz * hz + a) / norm, -1.0), 1.0)
        if rho2 == 0.0:
            phi_d = math.atan2(iy, ix * cos_h)
        else:
            phi_d = math.atan2((iy * hx - ix * hy) * norm, a * hz - iz * rho2)
        th, td = math.acos(cos_h), math.acos(cos_d)
        if td > math.pi / 2.0:
            out[k] = -1
            continue
        out[k] = phi_diff_index(phi_d) + theta_diff_index(td) * 180 + theta_half_index(th) * 16200
    return out


# ---------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def grid() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every integer-degree pose θi, θr ∈ 0..89, Δφ ∈ 0..359 (2,916,000): (θi, θr, Δφ, the
    reference's flat index, the reference's θd bin coordinate)."""
    ti, tr, dp = (
        a.reshape(-1).astype(np.float64)
        for a in np.meshgrid(np.arange(90), np.arange(90), np.arange(360), indexing="ij")
    )
    want, coord_d = reference_index_arrays(ti, tr, dp)
    return ti, tr, dp, want, coord_d


def _sphere_raster(light_theta_deg: float, res: int) -> tuple[np.ndarray, np.ndarray]:
    """Light/view pairs (local frames, raster order) of a sphere lit from ``light_theta_deg``,
    unlit pixels included."""
    u = (np.arange(res) + 0.5) / res * 2.0 - 1.0
    x, y = np.meshgrid(u, -u)
    on = x * x + y * y < 1.0
    n = np.stack([x[on], y[on], np.sqrt(1.0 - x[on] ** 2 - y[on] ** 2)], axis=-1)
    t = math.radians(light_theta_deg)
    light = 4.0 * np.array([math.sin(t), 0.0, math.cos(t)]) - n
    view = np.array([0.0, 0.0, 10.0]) - n
    light /= np.linalg.norm(light, axis=-1, keepdims=True)
    view /= np.linalg.norm(view, axis=-1, keepdims=True)
    tangent = np.cross([0.0, 1.0, 0.0], n)
    tangent /= np.linalg.norm(tangent, axis=-1, keepdims=True)
    frame = np.stack([tangent, np.cross(n, tangent), n], axis=-2)
    return np.einsum("nij,nj->ni", frame, light), np.einsum("nij,nj->ni", frame, view)


@pytest.fixture(scope="module")
def vector_pairs() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sphere rasters plus integer-degree poses as vectors (made with libm; in-plane poses hit
    the φd wrap, others exact θd edges), and their closed-form flat index."""
    rasters = [_sphere_raster(d, 100) for d in (20.0, 65.0)]
    ti, tr, dp = (
        a.reshape(-1).astype(np.float64)
        for a in np.meshgrid(np.arange(0, 90, 2), np.arange(1, 90, 2), np.arange(0, 360, 15),
                             indexing="ij")
    )
    sin_r = libm_of_degrees(math.sin, tr)
    wi = np.stack([libm_of_degrees(math.sin, ti), 0.0 * ti, libm_of_degrees(math.cos, ti)], -1)
    wo = np.stack([sin_r * libm_of_degrees(math.cos, dp), sin_r * libm_of_degrees(math.sin, dp),
                   libm_of_degrees(math.cos, tr)], -1)
    wi = np.concatenate([wi, *(a for a, _ in rasters)])
    wo = np.concatenate([wo, *(b for _, b in rasters)])
    return wi, wo, closed_form_index(wi, wo)


def _perturbing(ufunc: np.ufunc, rng: np.random.Generator) -> Callable[..., np.ndarray]:
    """``ufunc`` with every finite result moved 1 to 4 ulp up or down at random."""

    def wrapper(*args, **kwargs):
        result = ufunc(*args, **kwargs)
        exact = np.asarray(result, dtype=np.float64)
        steps = rng.integers(1, 5, exact.shape) * rng.choice([-1, 1], exact.shape)
        towards = np.where(steps > 0, np.inf, -np.inf)
        moved = exact.copy()
        for s in range(1, 5):
            moved = np.where(np.abs(steps) >= s, np.nextafter(moved, towards), moved)
        moved = np.where(np.isfinite(exact), moved, exact)
        if np.ndim(result) == 0:
            return np.float64(moved)
        result[...] = moved
        return result

    return wrapper


@pytest.fixture
def perturbed_vector_math(monkeypatch) -> Iterator[None]:
    """numpy's sin, cos, arccos and arctan2 replaced by versions 1–4 ulp off (seeded)."""
    rng = np.random.default_rng(2024)
    for name in ("sin", "cos", "arccos", "arctan2"):
        monkeypatch.setattr(np, name, _perturbing(getattr(np, name), rng))
    yield


def _assert_bit_identical(a, b, what: object = "") -> None:
    """Same counts, Σx, Σx² (exactly, not to a tolerance) and drop tallies."""
    np.testing.assert_array_equal(a.count, b.count, err_msg=str(what))
    np.testing.assert_array_equal(a._acc._sum, b._acc._sum, err_msg=str(what))
    np.testing.assert_array_equal(a._acc._sumsq, b._acc._sumsq, err_msg=str(what))
    assert a._acc.partial().same_as(b._acc.partial()), what  # the exact sums, limb for limb
    assert (a.n_dropped_nan, a.n_dropped_range) == (b.n_dropped_nan, b.n_dropped_range), what


# ---------------------------------------------------------------------------- MERL reference
def test_reference_transcription_arrays_equal_scalar(grid):
    """The array form of the reference used below is the scalar transcription, bit for bit."""
    ti, tr, dp, want, _ = grid
    rng = np.random.default_rng(0)
    pick = np.concatenate([
        np.flatnonzero((dp % 180 == 0) | (ti == tr) | (ti == 0) | (tr == 0))[::3],
        rng.choice(ti.size, 4000, replace=False),
    ])
    scalar = [reference_index(a, b, c) for a, b, c in zip(ti[pick], tr[pick], dp[pick], strict=True)]
    np.testing.assert_array_equal(want[pick], scalar)
    assert pick.size > 10_000


def test_integer_degree_grid_bins_like_the_reference_reader(grid):
    """Done-when test: all 2,916,000 integer-degree poses, both backends, every flat index."""
    ti, tr, dp, want, coord_d = grid
    # The grid bites: tens of thousands of poses sit on a θd edge to within rounding (and with
    # glibc a few retro-reflection poses have d_z rounded past 1: NaN in the reference, bin 0).
    on_edge = (coord_d >= 0.5) & (np.abs(coord_d - np.rint(coord_d)) < 1e-9)
    assert on_edge.sum() > 10_000
    values = np.random.default_rng(1).uniform(0.0, 2.0, (ti.size, 3))
    tables = {}
    for backend in BACKENDS:
        table = MerlTable(backend=backend)
        np.testing.assert_array_equal(table.flat_index_angles(ti, tr, dp), want, err_msg=backend)
        assert table.add_angles(ti, tr, dp, values) == ti.size
        tables[backend] = table
    count = np.bincount(want, minlength=MERL_BINS).reshape(MERL_SHAPE)
    np.testing.assert_array_equal(tables["numpy"].count, count)
    _assert_bit_identical(tables["numba"], tables["numpy"])


def test_numpy_backend_is_exact_with_perturbed_vector_math(grid, vector_pairs, perturbed_vector_math,
                                                           monkeypatch):
    ti, tr, dp, want, _ = grid
    wi, wo, want_v = vector_pairs
    table = MerlTable(backend="numpy")
    np.testing.assert_array_equal(table.flat_index_angles(ti, tr, dp), want)
    np.testing.assert_array_equal(table.flat_index_vectors(wi, wo), want_v)
    # The same through halfdiff's angles, clamped like the reference (the MERL reader's lookup).
    th, td, pd = halfdiff.halfdiff_rad_reference(np.radians(ti[::5]), 0.0, np.radians(tr[::5]),
                                                 np.radians(dp[::5]))
    np.testing.assert_array_equal(halfdiff.merl_flat_index_rad(th, td, pd), want[::5])
    # Without the scalar fallback the perturbation does move samples: the test can fail.
    monkeypatch.setattr(halfdiff, "GUARD_BAND", 0.0)
    monkeypatch.setattr(halfdiff, "_POLE", 0.0)
    monkeypatch.setattr(halfdiff, "_MIN_HALF", 0.0)
    some = slice(None, None, 9)
    moved = table.flat_index_angles(ti[some], tr[some], dp[some]) != want[some]
    assert moved.sum() > 100
    assert (table.flat_index_vectors(wi, wo) != want_v).sum() > 10


def test_lookup_at_any_light_azimuth_is_exact_with_perturbed_vector_math(perturbed_vector_math):
    # What the MERL reader's lookup computes (light azimuth ≠ 0, any array shapes); integer
    # degrees with in-plane and perpendicular views, where the bins hang on the last bits.
    rng = np.random.default_rng(5)
    n = 20_000
    ti, tr = rng.integers(0, 91, n).astype(float), rng.integers(0, 91, n).astype(float)
    phi_in = rng.integers(-360, 361, n).astype(float)
    phi_out = phi_in + rng.choice([0.0, 180.0, -180.0, 90.0, 37.0], n)
    angles = [np.radians(a) for a in (ti, phi_in, tr, phi_out)]
    want = [lookup_index(*a) for a in zip(*(x.tolist() for x in angles), strict=True)]
    th, td, pd = halfdiff.halfdiff_rad_reference(*(a.reshape(100, -1) for a in angles))
    np.testing.assert_array_equal(halfdiff.merl_flat_index_rad(th, td, pd).reshape(-1), want)


def test_vector_kernel_matches_the_closed_form_with_libm(vector_pairs):
    wi, wo, want = vector_pairs
    for backend in BACKENDS:
        np.testing.assert_array_equal(MerlTable(backend=backend).flat_index_vectors(wi, wo), want)
    assert (want == -1).sum() > 100 and (want >= 0).sum() > 20_000


# ---------------------------------------------------------------------------- isotropic
def _iso_bin(v: float, edges: list[float]) -> int | None:
    """[e_k, e_k+1), the last bin closed."""
    for k in range(len(edges) - 1):
        if edges[k] <= v < edges[k + 1]:
            return k
    return len(edges) - 2 if v == edges[-1] else None


def _iso_delta_phi(d: float, fold: bool, start: float) -> float:
    """Whole turns removed by repeated steps (exact for integer degrees); folded: |Δφ| after
    bringing it into (−180, 180]; wrapped: into [start, start + 360)."""
    if fold:
        while d > 180.0:
            d -= 360.0
        while d <= -180.0:
            d += 360.0
        return abs(d)
    while d < start:
        d += 360.0
    while d >= start + 360.0:
        d -= 360.0
    return d


@pytest.mark.parametrize(
    ("dphi_edges", "fold"),
    [(np.arange(0.0, 181.0, 10.0), True), (np.arange(-180.0, 181.0, 15.0), False),
     (np.arange(-5.0, 356.0, 30.0), False)],
)
def test_isotropic_edge_rule_on_integer_grid(dphi_edges, fold):
    edges_t = np.arange(0.0, 91.0, 5.0)
    ti_values = np.arange(-1.0, 92.0)
    tr_values = np.array([-1.0, 0.0, 4.0, 5.0, 6.0, 45.0, 89.0, 90.0, 91.0, np.nan])
    dp_values = np.concatenate([np.arange(-540.0, 541.0),
                                [-0.0, 180.0, -180.0, 360.0, -360.0, 540.0, np.inf, np.nan]])
    start = float(dphi_edges[0])
    bins_i = [_iso_bin(v, edges_t.tolist()) for v in ti_values.tolist()]
    bins_r = [None if math.isnan(v) else _iso_bin(v, edges_t.tolist()) for v in tr_values.tolist()]
    bins_p = [None if not math.isfinite(v) else _iso_bin(_iso_delta_phi(v, fold, start),
                                                         dphi_edges.tolist())
              for v in dp_values.tolist()]
    ti, tr, dp = (a.reshape(-1) for a in np.meshgrid(ti_values, tr_values, dp_values, indexing="ij"))
    ki, kr, kp = (a.reshape(-1) for a in np.meshgrid(
        *(np.array([-1 if b is None else b for b in bins]) for bins in (bins_i, bins_r, bins_p)),
        indexing="ij"))
    ne, nphi = edges_t.size - 1, dphi_edges.size - 1
    want = np.where((ki < 0) | (kr < 0) | (kp < 0), -1, (ki * ne + kr) * nphi + kp)
    want[np.isnan(tr) | np.isnan(dp)] = -2
    values = np.random.default_rng(2).uniform(0.0, 1.0, (ti.size, 3))
    tables = {}
    for backend in BACKENDS:
        table = IsotropicTable(edges_t, edges_t, dphi_edges, fold_delta_phi=fold, backend=backend)
        table.add(ti, tr, dp, values)
        tables[backend] = table
    got = np.empty(ti.size, dtype=np.int64)
    kernels.iso_flat_index(ti, tr, dp, edges_t, edges_t, dphi_edges, fold, got)
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(tables["numpy"].flat_index(ti, tr, dp), want)
    count = np.bincount(want[want >= 0], minlength=ne * ne * nphi).reshape(tables["numpy"].shape)
    np.testing.assert_array_equal(tables["numpy"].count, count)
    assert tables["numpy"].n_dropped_nan == (want == -2).sum()
    assert tables["numpy"].n_dropped_range == (want == -1).sum()
    _assert_bit_identical(tables["numba"], tables["numpy"])
    # Exact edges were exercised: every Δφ edge below the last is itself among the samples.
    normalised = {_iso_delta_phi(v, fold, start) for v in dp_values[np.isfinite(dp_values)].tolist()}
    assert set(dphi_edges[:-1].tolist()) <= normalised


# ---------------------------------------------------------------------------- batches
def _samples(kind: str) -> tuple[np.ndarray, ...]:
    """~1500 samples for one entry point: integer-degree poses (edges), exact bin edges,
    random values, NaN and out-of-range ones, then values."""
    rng = np.random.default_rng(zlib.crc32(kind.encode()))
    n = 1200
    if kind in ("angles", "iso_fold", "iso_wrap"):
        a = np.concatenate([rng.integers(0, 91, n).astype(float), rng.uniform(-2, 92, 300)])
        b = np.concatenate([rng.integers(0, 91, n).astype(float), rng.uniform(-2, 92, 300)])
        c = np.concatenate([rng.choice([0.0, -0.0, 180.0, -180.0, 360.0, 90.0], n // 2),
                            rng.integers(-360, 361, n - n // 2).astype(float),
                            rng.uniform(-400, 400, 300)])
        a[::101], c[5::211] = np.nan, np.inf
        arrays: tuple[np.ndarray, ...] = (a, b, c)
    elif kind == "halfdiff":
        eh, ed, ep = merl_bin_edges()
        a = np.concatenate([rng.choice(eh, n), rng.uniform(-1, 91, 300)])
        b = np.concatenate([rng.choice(ed, n), rng.uniform(-1, 91, 300)])
        c = np.concatenate([rng.choice(np.concatenate([ep, -ep]), n), rng.uniform(-400, 400, 300)])
        a[::97] = np.nan
        arrays = (a, b, c)
    else:  # vectors: integer-degree poses and a raster, some below the horizon
        wi, wo = _sphere_raster(40.0, 34)
        ti, tr, dp = (rng.integers(0, 91, n).astype(float) for _ in range(3))
        dp[::2] = rng.choice([0.0, 180.0], n // 2)
        t1, t2, p = (np.radians(x) for x in (ti, tr, dp))
        wi = np.concatenate([np.stack([np.sin(t1), 0 * t1, np.cos(t1)], -1), wi])
        wo = np.concatenate([np.stack([np.sin(t2) * np.cos(p), np.sin(t2) * np.sin(p), np.cos(t2)], -1),
                             wo])
        wi[::89, 0] = np.nan
        arrays = (wi, wo)
    values = rng.uniform(0.0, 3.0, (arrays[0].shape[0], 3))
    values[7::173, 1] = np.nan
    return (*arrays, values)


@pytest.mark.parametrize("kind", ["angles", "vectors", "halfdiff", "iso_fold", "iso_wrap"])
def test_tables_bit_identical_across_backends_and_batch_sizes(kind):
    *arrays, values = _samples(kind)
    n = values.shape[0]
    tables = {}
    for backend in BACKENDS:
        for batch in (1, 7, 1000, n):
            if kind.startswith("iso"):
                edges = np.arange(0.0, 91.0, 5.0)
                dphi = np.arange(0.0, 181.0, 10.0) if kind == "iso_fold" else np.arange(-180.0, 181.0, 20.0)
                table = IsotropicTable(edges, edges, dphi, backend=backend)
                add = table.add
            else:
                table = MerlTable(backend=backend)
                add = getattr(table, f"add_{kind}")
            kept = sum(add(*(x[a:a + batch] for x in arrays), values[a:a + batch])
                       for a in range(0, n, batch))
            assert kept == table.n_samples
            tables[backend, batch] = table
    first = tables["numba", n]
    assert 0 < first.n_samples < n and first.n_dropped_nan > 0 and first.n_dropped_range > 0
    for key, table in tables.items():
        _assert_bit_identical(table, first, key)
    if not kind.startswith("iso"):
        index = [getattr(MerlTable(backend=b), f"flat_index_{kind}")(*arrays) for b in BACKENDS]
        np.testing.assert_array_equal(index[0], index[1])


# ---------------------------------------------------------------------------- compiled code
_PROBE = r"""
import json, os, re
import acquisition.tables.kernels as kernels  # first: it must set NUMBA_DISABLE_INTEL_SVML
import llvmlite.binding as ll
import numba
import numpy as np
from acquisition.tables import MerlTable

table, rgb = MerlTable(backend="numba"), np.ones((2, 3))
table.add_angles(np.array([10.0, 20.0]), np.array([30.0, 40.0]), np.array([50.0, 60.0]), rgb)
table.add_vectors(np.array([[0.0, 0.6, 0.8], [0.0, 0.0, 1.0]]), np.array([[0.6, 0.0, 0.8]] * 2), rgb)
table.add_halfdiff(np.array([10.0, 20.0]), np.array([5.0, 6.0]), np.array([1.0, 2.0]), rgb)
fused = numba.njit(fastmath=True)(lambda x, y, z: x * y + z)
fused(1.0, 2.0, 3.0)
FMA = r"\bvfn?m(?:add|sub)\w*"
FLAGS = r"\bf(?:add|sub|mul|div|neg) ((?:fast|contract|reassoc|nnan|ninf|nsz|arcp|afn)\b)"

def listing(f):
    return f.inspect_llvm(f.signatures[0]), f.inspect_asm(f.signatures[0])

report = {
    "env": os.environ.get("NUMBA_DISABLE_INTEL_SVML"),
    "disable_svml": int(numba.config.DISABLE_INTEL_SVML),
    "using_svml": bool(numba.config.USING_SVML),
    "host_fma": "+fma" in ll.get_host_cpu_features().flatten(),
}
import acquisition.tables.exact_kernels as exact_kernels
for module, name in ((kernels, "merl_flat_index_angles"), (kernels, "merl_flat_index_vectors"),
                     (kernels, "merl_flat_index_deg"), (exact_kernels, "add_flat")):
    llvm, asm = listing(getattr(module, name))
    report[name] = {
        "calls": sorted(set(re.findall(r'call [^@]*@"?([\w.]+)', llvm))),
        "fma": len(re.findall(FMA, asm)),
        "svml": (llvm + asm).lower().count("svml"),
        "flags": sorted(set(re.findall(FLAGS, llvm))),
    }
llvm, asm = listing(fused)
report["fused"] = {"fma": len(re.findall(FMA, asm)), "flags": sorted(set(re.findall(FLAGS, llvm)))}
print(json.dumps(report))
"""


def _run(code: str, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", code], cwd=ROOT, env={**os.environ, **env},
                          capture_output=True, text=True, timeout=300, check=False)


def test_numba_kernels_call_libm_without_svml_fast_math_or_contraction(tmp_path):
    # A fresh cache (compiled code can be inspected) and a user asking for SVML.
    done = _run(_PROBE, {"NUMBA_CACHE_DIR": str(tmp_path), "NUMBA_DISABLE_INTEL_SVML": "0"})
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout.splitlines()[-1])
    assert report["env"] == "1" and report["disable_svml"] == 1 and report["using_svml"] is False
    # Scalar libm calls (SVML would show as __svml_* vector calls); the θh index's square root
    # is the (correctly rounded) sqrt instruction, vectorised in the (θh, θd, φd) kernel. The
    # exact accumulation's float → limb conversion (floor, rint) is no less strict.
    libm = {"merl_flat_index_angles": {"acos", "atan2", "llvm.sin.f64", "llvm.cos.f64"},
            "merl_flat_index_vectors": {"acos", "atan2"}, "merl_flat_index_deg": set()}
    for name, calls in libm.items():
        kernel = report[name]
        assert calls <= set(kernel["calls"]), (name, kernel["calls"])
        assert any(c.startswith("llvm.sqrt.") for c in kernel["calls"]), (name, kernel["calls"])
        assert (kernel["fma"], kernel["svml"], kernel["flags"]) == (0, 0, []), (name, kernel)
    exact = report["add_flat"]
    assert (exact["fma"], exact["svml"], exact["flags"]) == (0, 0, []), exact
    # The checks can see contraction: fast-math code on this CPU does fuse x·y + z.
    assert report["fused"]["flags"]
    if report["host_fma"]:
        assert report["fused"]["fma"] > 0


def test_kernels_refuse_to_load_when_numba_already_uses_svml():
    code = "import numba\nnumba.config.USING_SVML = True\nimport acquisition.tables.kernels\n"
    done = _run(code, {})
    assert done.returncode != 0 and "SVML" in done.stderr and "ImportError" in done.stderr
