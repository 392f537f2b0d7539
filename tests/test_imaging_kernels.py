"""The compiled per-pixel path (acquisition.reduction.imaging_kernels) against the numpy
reference: the same geometry and the same BRDF samples, bit for bit, on random cameras, lights
and samples (grazing views, the zenith, samples partly out of the image, light below the
horizon), images with invalid and NaN pixels, with and without a noise variance; and the
isotropic table's single-index budget path against the numpy backend on samples on bin
edges, NaN and out of range."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from acquisition.config.rig import SampleConfig
from acquisition.geometry.pinhole import PinholeCamera
from acquisition.reduction.image import frame_samples
from acquisition.reduction.imaging import collect, pixel_geometry, pixel_samples
from acquisition.tables import IsotropicTable

SHAPE = (90, 120)


def unit(theta_deg: float, phi_deg: float) -> np.ndarray:
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])


def scene(seed: int, theta_c: float, theta_l: float, shape: str):
    """A random camera (pointed), light and sample seeing part of the image."""
    rng = np.random.default_rng(seed)
    f = rng.uniform(150.0, 600.0)  # the sample fills from ~a third to beyond the image
    intr = (f, f * rng.uniform(0.9, 1.1), rng.uniform(40, 80), rng.uniform(30, 60))
    cam = PinholeCamera.looking_at_origin(intr, SHAPE, unit(theta_c, rng.uniform(-180, 180)),
                                          rng.uniform(0.3, 0.8))
    cam = cam.pointed(*rng.uniform(-1.0, 1.0, 2))
    light = unit(theta_l, rng.uniform(-180, 180)) * rng.uniform(0.3, 1.0)
    sample = SampleConfig(shape=shape, size_m=rng.uniform(0.02, 0.1),
                          radius_m=rng.uniform(0.01, 0.04),
                          centre_m=tuple(rng.uniform(-0.005, 0.005, 3)))
    return cam, light, sample


def same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal arrays, bit for bit (−0 and +0 differ; NaNs of one pattern are equal)."""
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


SCENES = dict(seed=st.integers(0, 2**31), theta_c=st.sampled_from([0.0, 20.0, 55.0, 87.0]),
              theta_l=st.sampled_from([0.0, 40.0, 85.0, 95.0]),
              shape=st.sampled_from(["flat", "sphere"]))


@given(**SCENES)
@settings(max_examples=40, deadline=None)
def test_compiled_geometry_is_the_numpy_geometry_bit_for_bit(seed, theta_c, theta_l, shape):
    cam, light, sample = scene(seed, theta_c, theta_l, shape)
    for target in (None, "flat"):
        ref = pixel_geometry(cam, light, sample, target, backend="numpy")
        got = pixel_geometry(cam, light, sample, target, backend="numba")
        for name in ("mask", "wi", "wo", "irradiance"):
            assert same_bits(getattr(got, name), getattr(ref, name)), name
    rng = np.random.default_rng(seed)
    pixels = (rng.integers(-5, SHAPE[0] + 5, 500), rng.integers(-5, SHAPE[1] + 5, 500))
    ref = pixel_geometry(cam, light, sample, pixels=pixels, backend="numpy")
    got = pixel_geometry(cam, light, sample, pixels=pixels, backend="numba")
    for name in ("mask", "wi", "wo", "irradiance"):
        assert same_bits(getattr(got, name), getattr(ref, name)), name


class Image:
    """The parts of a LinearImage frame_samples reads."""

    def __init__(self, rgb: np.ndarray, valid: np.ndarray, variance: np.ndarray | None):
        self.rgb, self.valid, self.variance = rgb, valid, variance


def random_image(seed: int, with_variance: bool) -> Image:
    rng = np.random.default_rng(seed)
    rgb = rng.uniform(0.0, 5e4, SHAPE + (3,)).astype(np.float32)
    valid = rng.random(SHAPE) > 0.1
    rgb[~valid] = np.nan
    rgb[rng.random(SHAPE) < 0.02] = np.nan  # a NaN the validity map missed stays NaN
    variance = rng.uniform(1.0, 1e3, SHAPE + (3,)).astype(np.float32) if with_variance else None
    return Image(rgb, valid, variance)


@given(**SCENES, with_variance=st.booleans(), min_cos=st.sampled_from([0.0, 0.02, 0.5]))
@settings(max_examples=40, deadline=None)
def test_compiled_samples_are_frame_samples_bit_for_bit(seed, theta_c, theta_l, shape,
                                                        with_variance, min_cos):
    cam, light, sample = scene(seed, theta_c, theta_l, shape)
    image = random_image(seed, with_variance)
    cal = np.random.default_rng(seed).uniform(1e-3, 1e3, 3)
    geo = pixel_geometry(cam, light, sample, backend="numpy")
    ref = frame_samples(image, geo, cal, 0, min_cos)  # type: ignore[arg-type]
    wi, wo, brdf, var, (rows, cols) = pixel_samples(
        cam, light, sample, image.rgb, image.valid, image.variance, cal, min_cos,
        capacity=7)  # tiny: the outputs grow many times
    assert same_bits(wi, ref.wi) and same_bits(wo, ref.wo) and same_bits(brdf, ref.brdf)
    assert same_bits(rows, ref.pixels[0].astype(np.int64))
    assert same_bits(cols, ref.pixels[1].astype(np.int64))
    assert (var is None) == (ref.variance is None)
    if var is not None:
        assert same_bits(var, ref.variance)


def test_collect_grows_and_trims() -> None:
    """Outputs grow by doubling from any capacity and come back with the rows written."""
    data = np.arange(1000, dtype=np.float64)

    def run(out, n, start):
        for q in range(start, data.size):
            if n >= out[0].shape[0]:
                return n, q
            if data[q] % 3:
                out[0][n] = data[q]
                n += 1
        return n, data.size

    for capacity in (1, 5, 666, 2000):
        (got,) = collect(run, [((), np.float64)], data.size, capacity)
        assert np.array_equal(got, data[data % 3 != 0])


def tricky_samples(seed: int, n: int = 4000):
    """Angles on bin edges, beyond the table, NaN; values NaN and ±inf; budget terms NaN."""
    rng = np.random.default_rng(seed)
    edges = np.arange(0.0, 95.0, 5.0)
    ti = rng.choice(np.concatenate([edges, rng.uniform(-5, 100, 50), [np.nan]]), n)
    tr = rng.choice(np.concatenate([edges, rng.uniform(-5, 100, 50)]), n)
    dp = rng.choice(np.concatenate([np.arange(-360.0, 361.0, 5.0), rng.uniform(-400, 400, 50),
                                    [np.nan, 180.0, -180.0]]), n)
    rgb = rng.uniform(0.0, 3.0, (n, 3))
    rgb[rng.random(n) < 0.02, 1] = np.nan
    rgb[rng.random(n) < 0.01, 2] = np.inf
    noise = rng.uniform(0.0, 1e-3, (n, 3))
    noise[rng.random(n) < 0.02] = np.nan
    return ti, tr, dp, rgb, noise


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_budget_path_indexes_once_like_the_numpy_backend(seed: int) -> None:
    ti, tr, dp, rgb, noise = tricky_samples(seed)
    parts = []
    for backend in ("numpy", "numba"):
        table = IsotropicTable(np.arange(0.0, 95.0, 5.0), np.arange(0.0, 95.0, 5.0),
                               np.arange(0.0, 185.0, 5.0), backend=backend)
        table.track_uncertainty({"noise": "n"}, {"white_reference": "w"})
        for a in (0, 1500):  # two batches
            b = slice(a, a + 1500 if a == 0 else None)
            table.add(ti[b], tr[b], dp[b], rgb[b], variances={"noise": noise[b]},
                      uncertainties={"white_reference": 0.01 * np.abs(rgb[b])})
        parts.append(table.partial())
    ref, got = parts
    assert got.dropped == ref.dropped and ref.dropped[0] > 0 and ref.dropped[1] > 0
    assert got.values.same_as(ref.values) and got.budget.sums.same_as(ref.budget.sums)
    assert ref.values.count.sum() == 4000 - sum(ref.dropped)
