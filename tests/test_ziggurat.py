"""The simulated sensor's normal draws (simulators.ziggurat): the standard normal law in the
body, the wedges and the tail, and independent of the stream and draw index."""

from __future__ import annotations

import numba
import numpy as np
import pytest
from scipy import stats

from simulators.counter_rng import GAMMA, mix
from simulators.ziggurat import LAYERS, R, V, X, normal

N = 2_000_000


@numba.njit(cache=True)
def _draws(key: np.uint64, n: int) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover
    """The first normal of n pixel streams, and the draws each took."""
    z, used = np.empty(n), np.empty(n, np.int64)
    for p in range(n):
        z[p], used[p] = normal(mix(key ^ (np.uint64(p) * GAMMA)), 0)
    return z, used


@pytest.fixture(scope="module")
def draws() -> tuple[np.ndarray, np.ndarray]:
    return _draws(np.uint64(20261202), N)


def test_the_layers_have_equal_areas_and_cover_the_half_density() -> None:
    f = np.exp(-0.5 * X * X)
    areas = X[1:-1] * (f[2:] - f[1:-1])
    np.testing.assert_allclose(areas, V, rtol=1e-8)
    assert X[0] * f[1] == pytest.approx(V)  # the base layer: rectangle plus tail
    assert np.all(np.diff(X) < 0) and X[LAYERS] == 0.0 and X[1] == R
    total = LAYERS * V  # the half-density's area √(π/2) plus the parts outside the curve
    assert total > np.sqrt(np.pi / 2)


def test_draws_follow_the_standard_normal_law(draws: tuple[np.ndarray, np.ndarray]) -> None:
    z, used = draws
    assert abs(z.mean()) < 5 / np.sqrt(N)
    assert z.var() == pytest.approx(1.0, abs=5 * np.sqrt(2 / N))
    assert stats.kstest(z, "norm").pvalue > 1e-4
    assert abs(stats.skew(z)) < 5 * np.sqrt(6 / N)
    assert abs(stats.kurtosis(z)) < 5 * np.sqrt(24 / N)
    assert np.mean(used == 1) > 0.98  # one 64-bit draw, nearly always


def test_the_tail_and_the_wedges_have_the_normal_probabilities(
        draws: tuple[np.ndarray, np.ndarray]) -> None:
    """Beyond R (layer 0's tail) and in each band between consecutive edges (the wedges are
    where a rejection step decides): counts against the normal law's, χ² test."""
    z, _ = draws
    a = np.abs(z)
    tail = int((a > R).sum())
    expected = 2 * stats.norm.sf(R) * N
    assert abs(tail - expected) < 5 * np.sqrt(expected), (tail, expected)
    assert a.max() > R  # the tail is reached at all
    edges = np.concatenate([[0.0], X[:0:-1][1:], [np.inf]])  # 0 < X[LAYERS-1] < … < R < ∞
    observed = np.histogram(a, bins=edges)[0]
    probs = 2 * np.diff(stats.norm.cdf(edges))
    chi2 = ((observed - probs * N) ** 2 / (probs * N)).sum()
    assert stats.chi2.sf(chi2, edges.size - 2) > 1e-4, chi2


def test_successive_draws_of_a_stream_are_independent() -> None:
    @numba.njit
    def pairs(n: int) -> np.ndarray:  # pragma: no cover
        out = np.empty((n, 2))
        for p in range(n):
            stream = mix(np.uint64(7) ^ (np.uint64(p) * GAMMA))
            first, k = normal(stream, 0)
            out[p, 0], out[p, 1] = first, normal(stream, k)[0]
        return out

    z = pairs(500_000)
    r = np.corrcoef(z[:, 0], z[:, 1])[0, 1]
    assert abs(r) < 5 / np.sqrt(z.shape[0])
    assert stats.kstest(z[:, 1], "norm").pvalue > 1e-4
