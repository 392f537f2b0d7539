"""calibration.hdr: auto-exposure bracketing and noise-model merge on real DNGs of SimCamera."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from calibration.hdr import BracketPolicy, bracket, merge, min_snr
from calibration.linearize import NoiseModel, linearize
from calibration.raw import load_raw
from drivers.errors import CalibrationError
from simulators.camera import SimCamera
from simulators.materials import directions_from_angles, material_from_spec
from simulators.sensor import SensorModel

SENSOR = SensorModel(width=64, height=48, prnu_sigma=0.0, dark_current_e_per_s=0.5, seed=3)


def _ggx_scene() -> tuple[np.ndarray, np.ndarray]:
    """Radiance and BRDF of a glossy GGX seen over a grid of view directions around the mirror."""
    h, w = SENSOR.superpixel_shape
    theta_r = np.abs(30.0 + 2.5 * (np.arange(w) - w // 2))
    dphi = 180.0 + 8.0 * (np.arange(h) - h // 2)
    wi, wo = directions_from_angles(30.0, theta_r[None, :], dphi[:, None])
    f = material_from_spec("ggx:albedo=0.02,alpha=0.06,f0=0.9").eval_vectors(wi, wo)
    return f * 100.0, f


def _noise() -> NoiseModel:
    g = SENSOR.gain_at(100)
    return NoiseModel(g, float(np.hypot(SENSOR.read_noise_e / g, SENSOR.black_noise_dn)), 100)


def _truth_dn_per_s(radiance: np.ndarray) -> np.ndarray:
    return (SENSOR.electrons_per_radiance_s * radiance + SENSOR.dark_current_e_per_s) / SENSOR.gain_at(100)


def _capture_fn(tmp_path: Path, radiance: np.ndarray, seed: int = 1):
    camera = SimCamera(SENSOR, lambda: radiance, seed=seed)
    taken: list[float] = []

    def capture(exposure_s: float) -> Path:
        path = tmp_path / f"frame-{seed}-{len(taken)}.dng"
        camera.capture(path, exposure_s, 100)
        taken.append(exposure_s)
        return path

    return capture


def test_bracket_recovers_a_4000x_specular_peak_and_its_diffuse_in_one_capture(tmp_path: Path) -> None:
    radiance, f = _ggx_scene()
    assert f[..., 1].max() / (0.02 / np.pi) > 4000  # peak vs the diffuse level
    h, w = SENSOR.superpixel_shape
    roi = (0, 0, w, h)
    result = bracket(_capture_fn(tmp_path, radiance), roi, _noise(), start_exposure_s=0.01,
                     policy=BracketPolicy(target_snr=30.0))
    assert result.reached_target and result.min_snr >= 30.0
    assert len(result.exposures_s) >= 3
    shortest = linearize(load_raw(result.frames[int(np.argmin(result.exposures_s))]))
    assert shortest.valid.all()  # no saturated pixel in the shortest exposure
    longest = linearize(load_raw(result.frames[int(np.argmax(result.exposures_s))]))
    peak = f[..., 1] > 0.3 * f[..., 1].max()
    assert not longest.valid[peak].any()  # the peak clipped there: those samples weigh 0
    assert result.merged.valid.all()
    rel = np.abs(result.merged.rgb / _truth_dn_per_s(radiance) - 1)
    diffuse = f[..., 1] < 3 * f[..., 1].min()
    assert np.median(rel[peak]) <= 0.03
    assert np.median(rel[diffuse]) <= 0.02
    # A single exposure that keeps the peak unclipped leaves the diffuse far below target SNR.
    assert min_snr(shortest_with_noise(result, radiance), roi) < 10


def shortest_with_noise(result, radiance) -> object:
    i = int(np.argmin(result.exposures_s))
    return linearize(load_raw(result.frames[i]), noise=_noise())


def test_merged_variance_matches_the_scatter(tmp_path: Path) -> None:
    radiance, _ = _ggx_scene()
    h, w = SENSOR.superpixel_shape
    result = bracket(_capture_fn(tmp_path, radiance, seed=5), (0, 0, w, h), _noise(),
                     start_exposure_s=0.004)
    z2 = (result.merged.rgb - _truth_dn_per_s(radiance)) ** 2 / result.merged.variance
    assert 0.8 <= float(np.mean(z2)) <= 1.2  # predicted variance within 20 % of the scatter


def test_noise_model_weights_remove_self_weighting_bias(tmp_path: Path) -> None:
    # Faint uniform scene, 8 equal short frames: weighting each sample by its own noisy value
    # biases the mean low; re-predicting the variance at the merged value does not.
    radiance = np.full(3, 1.0)
    capture = _capture_fn(tmp_path, radiance, seed=9)
    images = [linearize(load_raw(capture(0.001)), noise=_noise()) for _ in range(8)]
    plain = float(np.mean([im.rgb[..., 1].mean() for im in images]))  # unbiased here
    naive = float(np.mean(merge(images).rgb[..., 1]))
    ours = float(np.mean(merge(images, _noise()).rgb[..., 1]))
    assert naive / plain - 1 < -0.02
    assert abs(ours / plain - 1) < 0.002
    truth = float(_truth_dn_per_s(radiance)[1])
    assert abs(plain / truth - 1) < 0.02


def test_bracket_refuses_a_region_that_clips_at_the_shortest_exposure(tmp_path: Path) -> None:
    radiance = np.full(3, 1.0e5)
    h, w = SENSOR.superpixel_shape
    with pytest.raises(CalibrationError, match="still clips"):
        bracket(_capture_fn(tmp_path, radiance), (0, 0, w, h), _noise(), start_exposure_s=1e-3,
                policy=BracketPolicy(min_exposure_s=1e-4))


def test_merge_rejects_images_without_variance(tmp_path: Path) -> None:
    capture = _capture_fn(tmp_path, np.full(3, 1.0))
    with pytest.raises(CalibrationError, match="noise model"):
        merge([linearize(load_raw(capture(0.01)))])
