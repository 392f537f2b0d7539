"""The vectorised kernels of acquisition.tables equal the scalar paths they guard or replace
bit for bit: the MERL index (portable trig, libm's within 1e-13 of an edge) and the isotropic
index (arithmetic on evenly spaced edges, the edge search elsewhere)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numba import njit

from acquisition.geometry.halfdiff import vectors_from_halfdiff
from acquisition.tables import kernels

_JIT = {"fastmath": False, "error_model": "numpy"}


@njit(**_JIT)
def _merl_libm_all(wi, wo, out):  # pragma: no cover - compiled
    for i in range(wi.shape[0]):
        out[i] = kernels._merl_flat_pair(wi[i, 0], wi[i, 1], wi[i, 2], wo[i, 0], wo[i, 1], wo[i, 2])


@njit(**_JIT)
def _iso_scalar_all(ti, tr, dp, ei, er, ep, fold, out):  # pragma: no cover - compiled
    for i in range(ti.size):
        out[i] = kernels._iso_flat(ti[i], tr[i], dp[i], ei, er, ep, fold, ep[0])


def _pairs_near_merl_edges(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Light/view pairs with one half/difference angle on (or an ulp-scale step from) a MERL
    bin edge, θh = (k/90)²·90°, θd = k·1° or φd = k·1°, the others anywhere."""
    th, td, pd = rng.uniform(0.5, 89.5, n), rng.uniform(0.5, 89.5, n), rng.uniform(-179, 179, n)
    which = rng.integers(0, 3, n)
    jitter = rng.normal(size=n) * 10.0 ** rng.uniform(-15, -11, n)
    th = np.where(which == 0, (rng.integers(1, 90, n) / 90.0) ** 2 * 90.0 * (1 + jitter), th)
    td = np.where(which == 1, rng.integers(1, 90, n) + jitter * 90, td)
    pd = np.where(which == 2, rng.integers(-179, 180, n) + jitter * 180, pd)
    return vectors_from_halfdiff(th, td, pd, rng.uniform(-180, 180, n))


@pytest.mark.parametrize("case", ["random", "edges"])
def test_vectorised_merl_index_equals_libm_path_bit_for_bit(case: str) -> None:
    rng = np.random.default_rng(7)
    n = 100_000
    if case == "random":
        wi, wo = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
        wi[:, 2], wo[1000:, 2] = abs(wi[:, 2]), abs(wo[1000:, 2])  # some views below the horizon
        wi /= np.linalg.norm(wi, axis=1)[:, None]
        wo /= np.linalg.norm(wo, axis=1)[:, None]
        wi[:5] = [[0, 0, 1], [math.nan, 0, 1], [0.6, 0, 0.8], [0, 0, -1], [1, 0, 0]]
        wo[:5] = [[0, 0, 1], [0, 0, 1], [-0.6, 0, 0.8], [0, 0, 1], [-1, 0, 0]]
    else:
        wi, wo = _pairs_near_merl_edges(rng, n)
    wi, wo = np.ascontiguousarray(wi), np.ascontiguousarray(wo)
    fast, libm = np.empty(n, np.int64), np.empty(n, np.int64)
    kernels.merl_flat_index_vectors(wi, wo, fast)
    _merl_libm_all(wi, wo, libm)
    np.testing.assert_array_equal(fast, libm)
    scratch, guarded = np.empty((6, n)), np.empty(n, np.int64)
    kernels.pair_columns(wi, wo, 0, n, scratch)
    kernels._merl_guarded(scratch, n, guarded)
    deferred = np.count_nonzero(guarded == kernels.SLOW)
    if case == "edges":  # the guard catches what sits on an edge, and only that
        assert 0.2 * n < deferred < 0.9 * n
    else:
        assert 200 < deferred < 0.02 * n  # below the horizon, NaN, straight up
    kept = guarded != kernels.SLOW
    np.testing.assert_array_equal(guarded[kept], libm[kept])


def _iso_angles(rng: np.random.Generator, n: int, ei: np.ndarray, ep: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Angles anywhere, on edges, an ulp from edges, outside the table, NaN."""
    ti, tr, dp = rng.uniform(-5, 95, n), rng.uniform(0, 90, n), rng.uniform(-400, 400, n)
    on = rng.integers(0, 4, n)
    ti = np.where(on == 1, rng.choice(ei, n), ti)
    tr = np.where(on == 2, np.nextafter(rng.choice(ei, n), rng.choice([-1e9, 1e9], n)), tr)
    dp = np.where(on == 3, rng.choice(np.concatenate([ep, -ep, ep + 360]), n), dp)
    ti[:3], tr[3:6], dp[6:9] = math.nan, math.nan, math.nan
    dp[9:12] = [-0.0, 0.0, 360.0]
    return ti, tr, dp


@pytest.mark.parametrize("edges", ["even", "linspace_odd", "uneven"])
@pytest.mark.parametrize("fold", [True, False])
def test_vectorised_isotropic_index_equals_edge_search(edges: str, fold: bool) -> None:
    rng = np.random.default_rng(8)
    ei = {"even": np.arange(0.0, 91.0, 5.0), "linspace_odd": np.linspace(0, 90, 14),
          "uneven": np.array([0.0, 10, 15, 40, 41, 75, 90])}[edges]
    ep = np.linspace(0, 180, 37) if fold else np.linspace(-180, 180, 25)
    n = 50_000
    ti, tr, dp = _iso_angles(rng, n, ei, ep)
    got, want = np.empty(n, np.int64), np.empty(n, np.int64)
    kernels.iso_flat_index(ti, tr, dp, ei, ei, ep, fold, got)
    _iso_scalar_all(ti, tr, dp, ei, ei, ep, fold, want)
    np.testing.assert_array_equal(got, want)
    bins, delta = np.empty(n, np.int64), np.empty(n)
    kernels.iso_block(ti, tr, dp, n, ei, ei, ep, fold, bins, delta)
    folded = np.mod(dp, 360.0)
    folded = np.where(folded > 180.0, 360.0 - folded, folded) if fold else (
        ep[0] + np.mod(dp - ep[0], 360.0))
    assert np.array_equal(delta, folded, equal_nan=True)
    assert np.array_equal(np.signbit(delta), np.signbit(folded))
    if edges == "uneven":  # uneven edges: every sample took the edge search
        assert kernels.axis_spacing(ei)[2] == 1.0
    else:
        assert kernels.axis_spacing(ei)[2] < 1e-8


def test_max_finite_abs_by_bit_patterns_equals_numpy() -> None:
    from acquisition.tables.exact_kernels import max_finite_abs

    rng = np.random.default_rng(9)
    a = rng.normal(size=(10_000, 3)) * 10.0 ** rng.uniform(-320, 300, (10_000, 3))
    a[5, 1], a[7, 2], a[9, 0], a[11, 1] = math.inf, math.nan, -math.inf, -0.0
    assert max_finite_abs(a) == np.max(np.abs(a[np.isfinite(a)]))
    assert max_finite_abs(a[:, :2]) == np.max(np.abs(a[:, :2][np.isfinite(a[:, :2])]))
    assert max_finite_abs(np.full((2, 3), math.nan)) == 0.0
    assert max_finite_abs(np.array([[-3.0, 2.0, math.inf]])) == 3.0
    assert max_finite_abs(np.array([[5e-324, -0.0, 0.0]])) == 5e-324
