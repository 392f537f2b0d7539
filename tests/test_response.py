"""calibration.response: Debevec–Malik response recovery and merge, against a known camera
response and against OpenCV's implementation (opencv-python-headless, a test dependency)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import OpenImageIO as oiio
import pytest

from calibration.response import LEVELS, load_ldr, merge_ldr, recover_response
from drivers.errors import CalibrationError

TIMES = np.array([1 / 4, 1, 4, 16, 64, 256])
Z = np.arange(LEVELS)
WELL_EXPOSED = (Z >= 30) & (Z <= 225)


def _bracket(seed: int = 1, grey: bool = False) -> tuple[np.ndarray, list[np.ndarray]]:
    """A static scene over 3 decades of radiance, shot through a γ = 2.2 response."""
    rng = np.random.default_rng(seed)
    radiance = np.exp(rng.uniform(np.log(1e-3), 0.0, (48, 64, 1 if grey else 3)))
    radiance = np.broadcast_to(radiance, (48, 64, 3))
    images = []
    for t in TIMES:
        x = radiance * t / 4 + rng.normal(0, 2e-4, (48, 64, 1 if grey else 3))
        images.append(np.round(255 * np.clip(x, 0, 1) ** (1 / 2.2)).astype(np.uint8))
    return radiance, images


def _true_g() -> np.ndarray:
    g = 2.2 * np.log(np.maximum(Z, 1) / 255.0)
    return g - g[128]


def test_recovered_response_matches_the_true_curve_and_opencv() -> None:
    _, images = _bracket()
    g = recover_response(images, TIMES)
    assert g.shape == (LEVELS, 3) and np.all(g[128] == pytest.approx(0.0, abs=1e-9))
    err = np.abs(g[WELL_EXPOSED] - _true_g()[WELL_EXPOSED, None])
    g_cv = np.log(cv2.createCalibrateDebevec().process(images, TIMES.astype(np.float32))[:, 0, :])
    g_cv = g_cv - g_cv[128]
    err_cv = np.abs(g_cv[WELL_EXPOSED] - _true_g()[WELL_EXPOSED, None])
    assert err.max() < 0.1  # < 10 % in relative exposure over the well-exposed range
    assert np.median(err) <= np.median(err_cv) + 0.01  # at least as good as OpenCV's 70 samples
    assert np.median(np.abs(g[WELL_EXPOSED] - g_cv[WELL_EXPOSED])) < 0.05
    assert np.all(np.diff(g[WELL_EXPOSED], axis=0) > 0)  # monotonic


def test_merge_equals_opencv_merge_with_the_same_response() -> None:
    # OpenCV (5.x) weighs by the same hat (z, 255 − z) but averages it over a pixel's colours;
    # on a grey scene that equals the per-colour weight used here.
    _, images = _bracket(2, grey=True)
    response = cv2.createCalibrateDebevec().process(images, TIMES.astype(np.float32))
    ours = merge_ldr(images, TIMES, np.log(response[:, 0, :].astype(np.float64)))
    theirs = cv2.createMergeDebevec().process(images, TIMES.astype(np.float32), response)
    np.testing.assert_allclose(ours, theirs, rtol=1e-5)


def test_default_merge_ignores_clipped_values_and_beats_opencv_on_radiance() -> None:
    radiance, images = _bracket(3)
    g = recover_response(images, TIMES)
    ours = merge_ldr(images, TIMES, g)
    response = cv2.createCalibrateDebevec().process(images, TIMES.astype(np.float32))
    theirs = cv2.createMergeDebevec().process(images, TIMES.astype(np.float32), response)

    def log_scatter(m: np.ndarray) -> float:
        r = np.log(radiance / m)
        return float(np.std(r - np.median(r, axis=(0, 1))))

    assert log_scatter(ours) < 0.08
    assert log_scatter(ours) < log_scatter(theirs)
    clipped = [im.copy() for im in images[:2]]
    clipped[0][0, 0] = clipped[1][0, 0] = 255
    assert np.all(np.isnan(merge_ldr(clipped, TIMES[:2], g)[0, 0]))


def test_bad_inputs_are_refused() -> None:
    _, images = _bracket()
    with pytest.raises(CalibrationError, match="8-bit"):
        recover_response([im.astype(np.uint16) for im in images], TIMES)
    with pytest.raises(CalibrationError, match="one exposure time each"):
        recover_response(images, TIMES[:3])


def test_load_ldr_reads_pixels_and_exif_exposure(tmp_path: Path) -> None:
    _, images = _bracket()
    path = tmp_path / "frame.tif"
    spec = oiio.ImageSpec(64, 48, 3, oiio.UINT8)
    spec.attribute("ExposureTime", 0.004)
    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), spec)
    out.write_image(images[2])
    out.close()
    pixels, exposure = load_ldr(path)
    np.testing.assert_array_equal(pixels, images[2])
    assert exposure == pytest.approx(0.004)
