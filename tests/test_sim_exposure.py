"""The simulated sensor's compiled exposure: exact shot-noise statistics in every regime, the
same frame on any number of threads, and a 24-megapixel frame at a usable speed."""

from __future__ import annotations

import numba
import numpy as np
import pytest
from scipy import stats

from simulators.exposure import EXACT_POISSON_BELOW_E
from simulators.sensor import SensorModel

BLACK = 64


def _counting_sensor(width: int = 400, height: int = 300) -> SensorModel:
    """A sensor whose DN is the collected charge plus the black level: gain 1, no read noise,
    no fixed pattern, no dark current."""
    return SensorModel(width=width, height=height, bits=16, black_level_dn=BLACK,
                       black_noise_dn=0.0, read_noise_e=0.0, full_well_e=60000.0,
                       gain_e_per_dn=1.0, dark_current_e_per_s=0.0, prnu_sigma=0.0,
                       electrons_per_radiance_s=1.0)


@pytest.mark.parametrize("mu", [0.7, 4.0, 9.9, 10.0, 37.5, 400.0, 999.0])
def test_exact_poisson_below_the_normal_limit(mu: float) -> None:
    """Below EXACT_POISSON_BELOW_E the charge follows Poisson(μ): a χ² test of the histogram
    against scipy's law (the simulator's own draws: multiplication and PTRS)."""
    assert mu < EXACT_POISSON_BELOW_E
    sensor = _counting_sensor()
    charge = sensor.expose(np.full(3, mu), 1.0, frame_seed=11).astype(np.int64) - BLACK
    assert charge.mean() == pytest.approx(mu, abs=5 * np.sqrt(mu / charge.size))
    lo, hi = stats.poisson.ppf([1e-4, 1 - 1e-4], mu).astype(int)
    edges = np.arange(lo, hi + 2)
    observed = np.histogram(np.clip(charge, lo, hi), bins=edges)[0]
    expected = stats.poisson.pmf(edges[:-1], mu) * charge.size
    expected[0] += stats.poisson.cdf(lo - 1, mu) * charge.size
    expected[-1] += stats.poisson.sf(hi, mu) * charge.size
    keep = expected > 20
    chi2 = ((observed[keep] - expected[keep]) ** 2 / expected[keep]).sum()
    assert stats.chi2.sf(chi2, keep.sum() - 1) > 1e-4, (mu, chi2, keep.sum())


def test_normal_limit_has_the_poisson_mean_and_variance() -> None:
    mu = 5000.0
    sensor = _counting_sensor()
    charge = sensor.expose(np.full(3, mu), 1.0, frame_seed=3).astype(np.float64) - BLACK
    n = charge.size
    assert charge.mean() == pytest.approx(mu, abs=5 * np.sqrt(mu / n))
    assert charge.var() == pytest.approx(mu + 1 / 12, rel=5 * np.sqrt(2 / n))


def test_a_frame_is_the_same_on_one_thread_and_on_many(monkeypatch: pytest.MonkeyPatch) -> None:
    """The same bits from the one-thread kernel (small mosaics), and from the thread pool's
    (big ones) on one thread and on all."""
    from simulators import exposure

    sensor = SensorModel(width=600, height=400, prnu_sigma=0.01, optical_black_px=8)
    radiance = np.random.default_rng(0).uniform(0.0, 20.0, (*sensor.superpixel_shape, 3))
    monkeypatch.setattr(exposure, "PARALLEL_MIN_PIXELS", 10**12)
    serial = sensor.expose(radiance, 0.05, 200, frame_seed=5)
    monkeypatch.setattr(exposure, "PARALLEL_MIN_PIXELS", 0)
    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = sensor.expose(radiance, 0.05, 200, frame_seed=5)
    finally:
        numba.set_num_threads(threads)
    many = sensor.expose(radiance, 0.05, 200, frame_seed=5)
    assert np.array_equal(one, many) and np.array_equal(serial, many)
    assert not np.array_equal(many, sensor.expose(radiance, 0.05, 200, frame_seed=6))


def test_pixels_are_independent() -> None:
    """Neighbouring pixels (one counter apart) and rows share no noise."""
    sensor = _counting_sensor()
    charge = sensor.expose(np.full(3, 400.0), 1.0, frame_seed=1).astype(np.float64)
    d = charge - charge.mean()
    for a, b in ((d[:, 1:], d[:, :-1]), (d[1:], d[:-1])):
        r = (a * b).mean() / d.var()
        assert abs(r) < 5 / np.sqrt(a.size), r


def test_a_pixel_depends_on_its_own_radiance_alone() -> None:
    """Pixels that see the same radiance in two frames get the same bits whatever their
    neighbours see (dark next to lit in every regime: the kernel reuses exp(−μ) over runs of
    equal μ and must never carry it over to another μ)."""
    sensor = SensorModel(width=400, height=300, prnu_sigma=0.01, dark_current_e_per_s=40.0)
    rng = np.random.default_rng(4)
    dark = np.zeros((*sensor.superpixel_shape, 3))
    lit = dark.copy()
    spots = rng.random(sensor.superpixel_shape) < 0.3
    lit[spots] = rng.choice([1e-6, 2e-4, 3e-3, 0.05, 2.0], size=(int(spots.sum()), 3))
    frames = [sensor.expose(r, 0.05, 100, frame_seed=9) for r in (dark, lit)]
    same = ~np.repeat(np.repeat(spots, 2, axis=0), 2, axis=1)
    np.testing.assert_array_equal(frames[0][same], frames[1][same])
    assert not np.array_equal(frames[0][~same], frames[1][~same])
