"""The portable atan2/acos (acquisition.tables.portable_trig) and the vectorised MERL index
guarded by them: accurate to a few ulp, and the MERL bins exactly libm's."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numba import njit

from acquisition.geometry.halfdiff import vectors_from_halfdiff
from acquisition.tables import kernels, portable_trig

_JIT = {"fastmath": False, "error_model": "numpy"}


@njit(**_JIT)
def _atan2_all(y, x, out):  # pragma: no cover - compiled
    for i in range(y.size):
        out[i] = portable_trig.atan2(y[i], x[i])


@njit(**_JIT)
def _acos_all(c, out):  # pragma: no cover - compiled
    for i in range(c.size):
        out[i] = portable_trig.acos(c[i])


@njit(**_JIT)
def _merl_libm_all(wi, wo, out):  # pragma: no cover - compiled
    for i in range(wi.shape[0]):
        out[i] = kernels._merl_flat_vectors(wi, wo, i)


def _atan2(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    out = np.empty(y.size)
    _atan2_all(np.ascontiguousarray(y, float), np.ascontiguousarray(x, float), out)
    return out


def _ulps(got: np.ndarray, want: np.ndarray) -> np.ndarray:
    return np.abs(got - want) / np.spacing(np.maximum(np.abs(want), 1e-300))


def test_atan2_within_3_ulp_of_libm_over_all_scales() -> None:
    rng = np.random.default_rng(5)
    n = 200_000
    y = rng.normal(size=n) * 10.0 ** rng.uniform(-40, 40, n)
    x = rng.normal(size=n) * 10.0 ** rng.uniform(-40, 40, n)
    y[:1000], x[:1000] = rng.normal(size=1000), rng.normal(size=1000)  # near 1:1 too
    want = np.array([math.atan2(a, b) for a, b in zip(y, x, strict=True)])
    assert _ulps(_atan2(y, x), want).max() <= 3.0


def test_atan2_follows_c_conventions_for_zeros_and_nan() -> None:
    cases = [(0.0, 0.0), (-0.0, 0.0), (0.0, -0.0), (-0.0, -0.0), (0.0, -1.0), (-0.0, -1.0),
             (1.0, 0.0), (-1.0, -0.0), (math.inf, 1.0), (1.0, math.inf), (-1.0, -math.inf)]
    got = _atan2(np.array([c[0] for c in cases]), np.array([c[1] for c in cases]))
    for (y, x), g in zip(cases, got, strict=True):
        want = math.atan2(y, x)
        assert g == want and math.copysign(1.0, g) == math.copysign(1.0, want), (y, x)
    assert np.isnan(_atan2(np.array([math.nan, 1.0]), np.array([1.0, math.nan]))).all()


def test_acos_within_3_ulp_including_tiny_angles() -> None:
    rng = np.random.default_rng(6)
    c = np.concatenate([rng.uniform(-1, 1, 50_000), 1 - 10.0 ** rng.uniform(-16, 0, 50_000),
                        -1 + 10.0 ** rng.uniform(-16, 0, 50_000), [1.0, -1.0, 0.0]])
    out = np.empty(c.size)
    _acos_all(c, out)
    assert _ulps(out, np.array([math.acos(v) for v in c])).max() <= 3.0
    bad = np.empty(3)
    _acos_all(np.array([1.0 + 1e-15, -2.0, math.nan]), bad)
    assert np.isnan(bad).all()


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
