"""Pixels straight into the tables (acquisition/reduction/pixelbinning.py) give the tables of
the per-pixel samples binned by the reference path (pixel_samples, then the tables' own add
methods) bit for bit: on random spherical and flat frames with invalid, NaN and infinite
pixels, with and without a variance and a calibration uncertainty, folded and unfolded Δφ, with an
isotropic grid over all the angles and over part of them (each table dropping its own), on
one thread and on two taking blocks of rows in turn, with the MERL store growing mid-frame;
a value past the exact sums' range raises and a budget near it defers, both before either
table changes."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from test_fused_binning import assert_same_tables
from test_imaging_kernels import random_image, scene

from acquisition.reduction import pixelbinning
from acquisition.reduction.image import FrameSamples, bin_frames
from acquisition.reduction.imaging import pixel_samples
from acquisition.reduction.point import UNCERTAINTY_TERMS
from acquisition.tables import IsotropicTable, MerlTable
from acquisition.tables.exact import ExactSums
from acquisition.tables.fixedpoint import OutOfRangeError


def _tables(fold: bool, part: bool = False) -> tuple[IsotropicTable, MerlTable]:
    """Fresh tables; ``part``: an isotropic grid over part of the angles only, so that many
    samples the MERL table takes are out of its range."""
    dp = np.linspace(0, 180, 19) if fold else np.linspace(-180, 180, 37)
    if part:
        dp = np.linspace(0, 120, 7) if fold else np.linspace(-60, 120, 10)
    theta = np.linspace(10, 60, 6) if part else np.linspace(0, 90, 10)
    table = IsotropicTable(theta, theta, dp)
    table.track_uncertainty(*UNCERTAINTY_TERMS)
    return table, MerlTable()


def _reference(cam, light, sample, image, cal, rel, min_cos, fold, part=False):
    """The tables of the reference path: pixel_samples, then each table's own add."""
    wi, wo, brdf, var, pixels = pixel_samples(cam, light, sample, image.rgb, image.valid,
                                              image.variance, cal, min_cos)
    tables = _tables(fold, part)
    bin_frames([FrameSamples(0, wi, wo, brdf, var, rel, pixels)], *tables, None, 0,
               fused=False)
    return tables, wi.shape[0]


@pytest.fixture(scope="module")
def pool():
    with ThreadPoolExecutor(1) as executor:
        yield executor


CASES = [(15, 30.0, 40.0, "sphere", True, True, True, False),
         (16, 55.0, 0.0, "sphere", False, True, True, False),
         (10, 20.0, 85.0, "flat", True, False, True, False),
         (4, 0.0, 40.0, "flat", True, True, False, False),
         (31, 87.0, 40.0, "sphere", True, True, True, False),
         (15, 30.0, 40.0, "sphere", True, True, True, True),
         (16, 55.0, 0.0, "sphere", False, True, False, True)]


@pytest.mark.parametrize(("seed", "theta_c", "theta_l", "shape", "fold", "variance", "rel",
                          "part"), CASES)
def test_pixel_binning_is_the_reference_bit_for_bit(pool, monkeypatch, seed, theta_c, theta_l,
                                                    shape, fold, variance, rel, part) -> None:
    cam, light, sample = scene(seed, theta_c, theta_l, shape)
    image = random_image(seed, variance)
    cal = np.random.default_rng(seed).uniform(1e-3, 1e3, 3)
    rel_u = np.array([0.01, 0.02, 0.03]) if rel else None
    ref, n = _reference(cam, light, sample, image, cal, rel_u, 0.02, fold, part)
    assert n > 2000  # the scene puts samples in the frame
    if part:  # many samples in the MERL table only: each table drops its own
        iso, merl = ref
        assert iso._acc.n_dropped_range > n // 10
        assert iso._acc.n_dropped_range > 2 * merl._acc.n_dropped_range
    monkeypatch.setattr(pixelbinning, "HELPER_FROM_SAMPLES", 0)  # small frames on two threads
    monkeypatch.setattr(pixelbinning, "CHUNKS", 7)
    for executor in (None, pool):
        got = _tables(fold, part)
        count = pixelbinning.bin_pixels(cam, light, sample, image.rgb, image.valid,
                                        image.variance, cal, rel_u, 0.02, *got, executor)
        assert count == n
        assert_same_tables(got, ref)


def test_the_stores_grow_mid_frame_and_lose_nothing(pool, monkeypatch) -> None:
    """A MERL store of 64 rows fills many times over a frame: each time the pass stops
    before the batch, the store grows, and the pass resumes there."""
    cam, light, sample = scene(31, 30.0, 40.0, "sphere")
    image = random_image(31, True)
    cal = np.ones(3)
    ref, n = _reference(cam, light, sample, image, cal, None, 0.02, True)
    grown: list[int] = []
    original_new, original_grow = pixelbinning._new_part, ExactSums.grow

    def small_part(table, merl):
        part = original_new(table, merl)
        part.merl = MerlTable(backend="numba")
        part.merl._acc._sums = ExactSums(part.merl._acc._sums.n_bins, 6, capacity=64)
        return part

    def counting_grow(self, need=1):
        grown.append(need)
        original_grow(self, need)

    monkeypatch.setattr(pixelbinning, "_new_part", small_part)
    monkeypatch.setattr(ExactSums, "grow", counting_grow)
    monkeypatch.setattr(pixelbinning, "HELPER_FROM_SAMPLES", 0)
    got = _tables(True)
    assert pixelbinning.bin_pixels(cam, light, sample, image.rgb, image.valid, image.variance,
                                   cal, None, 0.02, *got, pool) == n
    assert grown
    assert_same_tables(got, ref)


def test_a_value_past_the_range_raises_before_either_table_changes(pool) -> None:
    cam, light, sample = scene(15, 30.0, 40.0, "sphere")
    image = random_image(15, True)
    cal = np.full(3, 1e-3)
    image.rgb[image.valid] = 5e4  # f = P / (C cos θi / r²) well past 2^20 sr⁻¹
    got = _tables(True)
    with pytest.raises(OutOfRangeError, match="sample value"):
        pixelbinning.bin_pixels(cam, light, sample, image.rgb, image.valid, image.variance,
                                cal, None, 0.02, *got, pool)
    assert got[0].n_samples == 0 and got[1].partial().values.bins.size == 0


def test_a_budget_near_the_range_defers_to_the_reference_path(pool) -> None:
    cam, light, sample = scene(15, 30.0, 40.0, "sphere")
    image = random_image(15, True)
    image.variance[...] = 3e38  # var f past 2^40 sr⁻²: only the reference path may decide
    got = _tables(True)
    assert pixelbinning.bin_pixels(cam, light, sample, image.rgb, image.valid, image.variance,
                                   np.full(3, 1e3), np.full(3, 0.01), 0.02, *got, pool) is None
    assert got[0].n_samples == 0 and got[1].partial().values.bins.size == 0
