"""The portable atan2/acos (acquisition.tables.portable_trig): within 3 ulp of libm's, C's
conventions for zeros, NaN in NaN out."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from acquisition.tables import portable_trig

_JIT = {"fastmath": False, "error_model": "numpy"}


@njit(**_JIT)
def _atan2_all(y, x, out):  # pragma: no cover - compiled
    for i in range(y.size):
        out[i] = portable_trig.atan2(y[i], x[i])


@njit(**_JIT)
def _acos_all(c, out):  # pragma: no cover - compiled
    for i in range(c.size):
        out[i] = portable_trig.acos(c[i])


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
