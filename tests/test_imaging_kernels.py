"""The compiled per-pixel paths (acquisition.reduction.imaging_kernels, and the row kernel of a
frame's samples, sample_spans + sample_kernels) against the numpy reference and the per-pixel
loop: the same geometry and the same BRDF samples, bit for bit, on random cameras, lights and
samples (grazing views, the zenith, samples partly or wholly out of the image, light below the
horizon), edge cases (camera inside, on or beside the sphere, looking away, flat sample seen
edge-on or from below, mirrored and skewed cameras), images with invalid, NaN and infinite
pixels, with and without a noise variance, on one thread or in blocks on the threads, and
compiled for a generic x86-64; the spans hold every hit with margin and stay tight; and the
isotropic table's single-index budget path against the numpy backend on samples on bin
edges, NaN and out of range."""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numba import njit

from acquisition.config.rig import SampleConfig
from acquisition.geometry.pinhole import PinholeCamera
from acquisition.reduction import imaging_kernels as k
from acquisition.reduction import sample_kernels as sk
from acquisition.reduction.image import frame_samples
from acquisition.reduction.imaging import (
    collect,
    frame_parameters,
    intersect,
    pixel_geometry,
    pixel_samples,
)
from acquisition.reduction.sample_spans import row_spans
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


def random_image(seed: int, with_variance: bool, shape: tuple[int, int] = SHAPE) -> Image:
    rng = np.random.default_rng(seed)
    rgb = rng.uniform(0.0, 5e4, shape + (3,)).astype(np.float32)
    valid = rng.random(shape) > 0.1
    rgb[~valid] = np.nan
    rgb[rng.random(shape) < 0.02] = np.nan  # a NaN the validity map missed stays NaN
    rgb[rng.random(shape) < 0.01] = np.inf
    variance = rng.uniform(1.0, 1e3, shape + (3,)).astype(np.float32) if with_variance else None
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
    for blocks in (1, 3):  # on the calling thread, and three blocks of rows on the threads
        got = pixel_samples(cam, light, sample, image.rgb, image.valid, image.variance, cal,
                            min_cos, blocks=blocks)
        assert_same_samples(got, (ref.wi, ref.wo, ref.brdf, ref.variance, ref.pixels))


def assert_same_samples(got, ref) -> None:
    """Two pixel_samples results (wi, wo, brdf, variance or None, (rows, cols)): the same
    arrays, bit for bit, in the same order."""
    for name, a, b in zip(("wi", "wo", "brdf"), got[:3], ref[:3], strict=True):
        assert same_bits(a, b), name
    assert (got[3] is None) == (ref[3] is None)
    if got[3] is not None:
        assert same_bits(got[3], ref[3]), "variance"
    for a, b in zip(got[4], ref[4], strict=True):
        assert same_bits(a, np.asarray(b).astype(np.int64)), "pixels"


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


# ---------------------------------------------------------------- the row kernel (spans, SIMD, threads)
@njit
def _per_pixel_samples(p, rgb, valid, variance, calibration, min_cos):
    """The per-pixel loop the row kernel replaced (every pixel, in C order, through
    imaging_kernels._pixel): the reference for its culling, SIMD rows and threads."""
    h, w = valid.shape
    wi, wo, brdf = np.empty((h * w, 3)), np.empty((h * w, 3)), np.empty((h * w, 3))
    var = np.empty((h * w if variance.size else 0, 3))
    rows, cols = np.empty(h * w, np.int64), np.empty(h * w, np.int64)
    n = 0
    for i in range(h):
        for j in range(w):
            if not valid[i, j]:
                continue
            seen, i0, i1, i2, w0, w1, w2, e = k._pixel(p, float(i), float(j))
            if not (seen and i2 >= min_cos and w2 >= min_cos):
                continue
            wi[n, 0], wi[n, 1], wi[n, 2] = i0, i1, i2
            wo[n, 0], wo[n, 1], wo[n, 2] = w0, w1, w2
            for c in range(3):
                s = e * calibration[c]
                brdf[n, c] = np.float64(rgb[i, j, c]) / s
                if variance.size:
                    var[n, c] = np.float64(variance[i, j, c]) / (s * s)
            rows[n], cols[n] = i, j
            n += 1
    return wi[:n], wo[:n], brdf[:n], var[:n], rows[:n], cols[:n]


def per_pixel_samples(cam, light, sample, image, cal, min_cos):
    """:func:`_per_pixel_samples` as pixel_samples returns it."""
    p = frame_parameters(cam, light, sample)
    var = np.zeros((0, 0, 3), np.float32) if image.variance is None else image.variance
    wi, wo, brdf, v, rows, cols = _per_pixel_samples(p, image.rgb, image.valid, var, cal,
                                                     min_cos)
    return wi, wo, brdf, None if image.variance is None else v, (rows, cols)


def samples_every_way(cam, light, sample, image, cal, min_cos) -> None:
    """pixel_samples on one thread, in 2 and 5 blocks of rows: the per-pixel loop's samples."""
    ref = per_pixel_samples(cam, light, sample, image, cal, min_cos)
    for blocks in (1, 2, 5):
        got = pixel_samples(cam, light, sample, image.rgb, image.valid, image.variance, cal,
                            min_cos, blocks=blocks)
        assert_same_samples(got, ref)


@given(**SCENES, with_variance=st.booleans(), min_cos=st.sampled_from([0.0, 0.3]),
       pointing=st.sampled_from([0.0, 4.0, 12.0]))
@settings(max_examples=40, deadline=None)
def test_row_kernel_is_the_per_pixel_loop_bit_for_bit(seed, theta_c, theta_l, shape,
                                                      with_variance, min_cos, pointing):
    """Random cameras (pointed up to 12° off: the sample partly or wholly out of the image),
    lights, grazing views, invalid, NaN and infinite pixels."""
    cam, light, sample = scene(seed, theta_c, theta_l, shape)
    cam = cam.pointed(pointing, -pointing / 2)
    samples_every_way(cam, light, sample, random_image(seed, with_variance),
                      np.random.default_rng(seed).uniform(1e-3, 1e3, 3), min_cos)


def hits(cam: PinholeCamera, sample: SampleConfig) -> np.ndarray:
    """(rows, columns): the pixels whose ray meets the sample (the numpy reference)."""
    return intersect(sample, cam.position, cam.ray_directions()).hit


@given(**SCENES, pointing=st.sampled_from([0.0, 4.0]))
@settings(max_examples=60, deadline=None)
def test_spans_hold_every_hit_with_their_margin_and_little_more(seed, theta_c, theta_l,
                                                                 shape, pointing):
    """Every pixel that meets the sample is inside its row's span, with at least one column
    to spare of the two-column margin (unless at the image's edge); and the spans are tight:
    a few columns beyond the hits per row, so the kernel does skip the misses."""
    cam, _, sample = scene(seed, theta_c, theta_l, shape)
    cam = cam.pointed(pointing, pointing)
    lo, hi = row_spans(frame_parameters(cam, np.ones(3), sample), SHAPE)
    hit = hits(cam, sample)
    j = np.arange(SHAPE[1])
    inside = ((j >= lo[:, None] + 1) | (lo[:, None] == 0)) & (
        (j < hi[:, None] - 1) | (hi[:, None] == SHAPE[1]))
    assert not np.any(hit & ~inside)
    assert np.sum(hi - lo) <= hit.sum() + 12 * np.count_nonzero(hi > lo)


EDGE_CASES = {
    # name: (camera θ (deg, φ = 10°), distance m, focal px, sample (shape, size m), pointing deg;
    # "behind": the camera turned round its down axis)
    "sphere fills the frame": (30.0, 0.1, 900.0, ("sphere", 0.06), 0.0),
    "camera inside the sphere": (30.0, 0.05, 300.0, ("sphere", 0.2), 0.0),
    "camera on the sphere": (30.0, 0.04, 300.0, ("sphere", 0.04), 0.0),
    "sphere behind the camera": (30.0, 0.5, 300.0, ("sphere", 0.03), "behind"),
    "sphere at a wide view's edge": (30.0, 0.5, 30.0, ("sphere", 0.03), 55.0),
    "sphere near the camera's x axis": (30.0, 0.5, 4.0, ("sphere", 0.03), 86.0),
    "sphere cut by the frame": (60.0, 0.5, 600.0, ("sphere", 0.03), 5.0),
    "sphere at 89°": (89.0, 0.5, 600.0, ("sphere", 0.03), 0.0),
    "flat seen from below": (120.0, 0.5, 300.0, ("flat", 0.1), 0.0),
    "flat seen edge-on": (90.0, 0.5, 300.0, ("flat", 0.1), 0.0),
    "flat at 89.99°": (89.99, 0.5, 300.0, ("flat", 0.1), 0.0),
    "flat at 88°": (88.0, 0.5, 300.0, ("flat", 0.1), 0.0),
    "flat fills the frame": (10.0, 0.1, 100.0, ("flat", 0.5), 0.0),
    "flat cut by the frame": (45.0, 0.5, 400.0, ("flat", 0.1), 6.0),
}


def edge_case(name: str) -> tuple[PinholeCamera, SampleConfig]:
    theta, distance, f, (kind, size), pointing = EDGE_CASES[name]
    cam = PinholeCamera.looking_at_origin((f, f, 60.0, 45.0), SHAPE, unit(theta, 10.0),
                                          distance)  # the origin on a pixel's centre
    if pointing == "behind":
        right, down, forward = cam.rotation
        cam = replace(cam, rotation=np.stack([-right, down, -forward]))
    else:
        cam = cam.pointed(float(pointing), 0.0)
    return cam, SampleConfig(shape=kind, size_m=size, radius_m=size, centre_m=(0.0, 0.0, 0.0))


@pytest.mark.parametrize("name", list(EDGE_CASES))
def test_row_kernel_edge_cases_are_the_per_pixel_loop(name: str) -> None:
    cam, sample = edge_case(name)
    samples_every_way(cam, unit(40.0, 200.0) * 0.7, sample, random_image(7, True), np.ones(3),
                      0.0)
    lo, hi = row_spans(frame_parameters(cam, np.ones(3), sample), SHAPE)
    j = np.arange(SHAPE[1])
    assert not np.any(hits(cam, sample) & ((j < lo[:, None]) | (j >= hi[:, None])))


def test_odd_cameras_are_the_per_pixel_loop() -> None:
    """A mirrored image (fx < 0) and a rotation that is not orthonormal (the spans' algebra
    does not assume it), both seeing a sphere and a flat sample."""
    rng = np.random.default_rng(3)
    image = random_image(3, False)
    base = PinholeCamera.looking_at_origin((-300.0, 280.0, 60.0, 45.0), SHAPE,
                                           unit(35.0, 20.0), 0.5)
    skewed = replace(base, fx=300.0, rotation=base.rotation + rng.normal(0, 0.05, (3, 3)))
    for cam in (base, skewed):
        for kind in ("sphere", "flat"):
            sample = SampleConfig(shape=kind, size_m=0.08, radius_m=0.03)
            samples_every_way(cam, unit(30.0, 180.0) * 0.6, sample, image, np.ones(3), 0.0)


def test_large_frame_uses_the_threads_and_gives_the_same_bits(monkeypatch) -> None:
    """A 1000 × 800 frame (over PARALLEL_MIN_CELLS) goes to the threads by default; the same
    bits as the numpy path, and as one thread (NUMBA_NUM_THREADS=1, as on Dask workers)."""
    shape = (800, 1000)
    cam = PinholeCamera.looking_at_origin((4500.0, 4500.0, 499.5, 399.5), shape,
                                          unit(50.0, 30.0), 0.5).pointed(0.5, -0.3)
    light, sample = unit(40.0, 60.0) * 0.7, SampleConfig(shape="sphere", radius_m=0.04)
    image = random_image(11, True, shape)
    cal = np.array([0.5, 2.0, 3.0])
    calls = []
    for name in ("fill_serial", "fill_blocks"):
        kernel = getattr(sk, name)
        monkeypatch.setattr(sk, name, lambda *a, kernel=kernel, name=name: (
            calls.append(name), kernel(*a))[1])
    args = (cam, light, sample, image.rgb, image.valid, image.variance, cal, 0.02)
    threaded = pixel_samples(*args)
    assert calls == (["fill_blocks"] if numba.get_num_threads() > 1 else ["fill_serial"])
    geo = pixel_geometry(cam, light, sample, backend="numpy")
    ref = frame_samples(image, geo, cal, 0, 0.02)  # type: ignore[arg-type]
    assert ref.count > 250_000
    assert_same_samples(threaded, (ref.wi, ref.wo, ref.brdf, ref.variance, ref.pixels))
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        calls.clear()
        assert_same_samples(pixel_samples(*args), threaded)
        assert calls == ["fill_serial"]
    finally:
        numba.set_num_threads(threads)


def test_a_count_that_disagrees_with_the_fill_stops_it(monkeypatch) -> None:
    """The blocks never write past their rows: a count off by one is an error, not samples
    overwritten or left out."""
    cam, light, sample = scene(5, 20.0, 40.0, "sphere")
    image = random_image(5, True)
    count = sk.count_rows

    def off_by(delta):
        def wrong(frame, spans, bounds, counts):
            count(frame, spans, bounds, counts)
            counts[np.flatnonzero(counts)[0]] += delta
        return wrong

    for delta in (-1, 1):
        monkeypatch.setattr(sk, "count_rows", off_by(delta))
        with pytest.raises(RuntimeError, match="a bug"):
            pixel_samples(cam, light, sample, image.rgb, image.valid, image.variance,
                          np.ones(3), 0.0, blocks=2)


def samples_digest(shape: str, blocks: int) -> str:
    """SHA-256 of pixel_samples' arrays on a fixed scene."""
    cam, light, sample = scene(9, 55.0, 40.0, shape)
    image = random_image(9, True)
    got = pixel_samples(cam, light, sample, image.rgb, image.valid, image.variance,
                        np.array([0.5, 2.0, 3.0]), 0.0, blocks=blocks)
    arrays = [*got[:4], *got[4]]
    return hashlib.sha256(b"".join(np.ascontiguousarray(a).tobytes() for a in arrays)).hexdigest()


def test_scalar_code_gives_the_simd_code_s_bits(tmp_path) -> None:
    """Compiled for a generic x86-64 (SSE2, no AVX) in a fresh process, on one thread, the
    kernel gives the same bits as here (AVX2 or AVX-512 where the CPU has them; two blocks of
    rows on the threads), sphere and flat."""
    env = {**os.environ, "NUMBA_CPU_NAME": "x86-64", "NUMBA_CPU_FEATURES": "",
           "NUMBA_CACHE_DIR": str(tmp_path)}
    code = ("import sys; sys.path.insert(0, sys.argv[1]); import test_imaging_kernels as t; "
            "print(t.samples_digest('sphere', 1), t.samples_digest('flat', 1))")
    run = subprocess.run([sys.executable, "-c", code, str(Path(__file__).parent)], env=env,
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    assert run.stdout.split()[-2:] == [samples_digest("sphere", 2), samples_digest("flat", 2)]
