"""calibration.linearize: black, saturation, flat, superpixel, scaling and variance."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from calibration.linearize import LinearImage, NoiseModel, Roi, linearize, roi_mean
from calibration.raw import RawFrame, load_raw
from drivers.errors import CalibrationError
from simulators.camera import SimCamera
from simulators.dng import CFA_PATTERNS, write_dng
from simulators.sensor import SensorModel


def _reference(mosaic, pattern, black, white, t, saturation=0.99):
    """Plain-loop superpixel reference: (rgb, valid)."""
    h, w = mosaic.shape[0] // 2, mosaic.shape[1] // 2
    rgb = np.full((h, w, 3), np.nan)
    valid = np.zeros((h, w), bool)
    for y in range(h):
        for x in range(w):
            cell = mosaic[2 * y : 2 * y + 2, 2 * x : 2 * x + 2].astype(float)
            if np.any(cell - black >= saturation * (white - black)):
                continue
            valid[y, x] = True
            sig = (cell - black) / t
            for k, c in enumerate("RGB"):
                rgb[y, x, k] = np.mean([sig[divmod(i, 2)] for i, p in enumerate(pattern) if p == c])
    return rgb, valid


def _frame(mosaic, pattern="RGGB", black=64, white=4095, t=0.5, iso=100.0, f_number=4.0,
           as_is=False):
    black = np.broadcast_to(np.asarray(black, float), (2, 2)).copy()
    return RawFrame(
        path=Path("mem.dng"), mosaic=mosaic if as_is else mosaic.astype(np.float32),
        cfa_pattern=pattern,
        black_per_position=black, white_per_position=np.full((2, 2), float(white)),
        optical_black=None, camera_whitebalance={}, exposure_s=t, iso=iso, f_number=f_number,
        make=None, model=None, raw_shape=mosaic.shape, visible_origin=(0, 0),
    )


@pytest.mark.parametrize("pattern", CFA_PATTERNS)
def test_matches_reference_through_dng(tmp_path, pattern):
    rng = np.random.default_rng(1)
    black = np.array([[60, 62], [61, 63]])
    mosaic = rng.integers(0, 4096, (26, 34), dtype=np.uint16)
    path = write_dng(tmp_path / "f.dng", mosaic, cfa_pattern=pattern, black_level=black,
                     white_level=4095, exposure_s=0.125)
    image = linearize(load_raw(path))
    ref_rgb, ref_valid = _reference(mosaic, pattern, black, 4095, 0.125)
    assert np.array_equal(image.valid, ref_valid)
    np.testing.assert_allclose(image.rgb, ref_rgb, rtol=1e-6, equal_nan=True)
    assert image.units == "DN/s" and image.scale == 8.0


@settings(max_examples=15, deadline=None)
@given(
    rows=st.integers(1, 300), cols=st.integers(1, 40), pattern=st.sampled_from(CFA_PATTERNS),
    seed=st.integers(0, 2**32 - 1),
)
def test_odd_sizes_and_every_layout_match_reference(rows, cols, pattern, seed):
    rng = np.random.default_rng(seed)
    mosaic = rng.integers(0, 1024, (2 * rows + 1, 2 * cols + 1), dtype=np.uint16)  # odd: cropped
    image = linearize(_frame(mosaic, pattern, black=16, white=1000, t=2.0))
    ref_rgb, ref_valid = _reference(mosaic[: 2 * rows, : 2 * cols], pattern, 16, 1000, 2.0)
    assert image.rgb.shape == (rows, cols, 3)
    assert np.array_equal(image.valid, ref_valid)
    np.testing.assert_allclose(image.rgb, ref_rgb, rtol=1e-6, equal_nan=True)


@pytest.mark.parametrize("pattern", ["RGGB", "GBRG"])
def test_thread_pool_and_one_thread_give_the_same_bits(monkeypatch, pattern):
    """Big frames go to numba's thread pool, small ones stay on one thread: both give the same
    bits, every optional input in use (dark, per-pixel flat, bad pixels, noise model)."""
    from calibration import linearize_kernel

    rng = np.random.default_rng(7)
    mosaic = rng.integers(0, 4096, (240, 322), dtype=np.uint16)
    dark = rng.uniform(50, 70, mosaic.shape).astype(np.float32)
    flat = rng.uniform(0.9, 1.1, mosaic.shape).astype(np.float32)
    flat[3, 5] = 0.0
    bad = rng.random(mosaic.shape) < 0.01
    kwargs = {"dark": dark, "flat": flat, "bad_pixels": bad,
              "noise": NoiseModel(gain_e_per_dn=1.5, read_noise_dn=2.0)}
    images = []
    for threshold in (0, 10**9):  # every frame threaded, then none
        monkeypatch.setattr(linearize_kernel, "PARALLEL_MIN_CELLS", threshold)
        images.append(linearize(_frame(mosaic, pattern), **kwargs))
    threaded, serial = images
    assert 0 < serial.valid.sum() < serial.valid.size
    for a, b in ((threaded.rgb, serial.rgb), (threaded.variance, serial.variance),
                 (threaded.valid, serial.valid)):
        assert a.tobytes() == b.tobytes()


def test_a_view_into_wider_rows_gives_the_bits_of_a_contiguous_copy():
    """LibRaw's visible area is a view into the sensor's full rows (margins left and right):
    read in place as one run of memory, it gives the bits of the same pixels copied out."""
    rng = np.random.default_rng(3)
    full = rng.integers(0, 4096, (130, 170), dtype=np.uint16)
    view = full[3:123, 11:161]  # 120 × 150 px, margins on every side
    assert not view.flags.c_contiguous
    flat = rng.uniform(0.9, 1.1, view.shape).astype(np.float32)
    noise = NoiseModel(gain_e_per_dn=1.5, read_noise_dn=2.0)
    a = linearize(_frame(view, "GRBG", as_is=True), flat=flat, noise=noise)
    b = linearize(_frame(np.ascontiguousarray(view), "GRBG", as_is=True), flat=flat, noise=noise)
    assert a.rgb.tobytes() == b.rgb.tobytes() and a.variance.tobytes() == b.variance.tobytes()
    assert np.array_equal(a.valid, b.valid) and a.valid.any()


def test_saturation_masks_whole_superpixel_near_white():
    mosaic = np.full((24, 24), 1000, np.uint16)
    mosaic[0, 1] = 4095          # at white: cell (0, 0)
    mosaic[5, 4] = 4095 - 20     # within 1 % of (white − black): cell (2, 2)
    mosaic[9, 9] = 64 + 0.98 * (4095 - 64)  # just below the threshold: cell (4, 4) stays
    image = linearize(_frame(mosaic))
    expected = np.ones((12, 12), bool)
    expected[0, 0] = expected[2, 2] = False
    assert np.array_equal(image.valid, expected)
    assert np.all(np.isnan(image.rgb[~expected]))
    assert np.all(np.isfinite(image.rgb[expected]))
    strict = linearize(_frame(mosaic), saturation=1.0)
    assert strict.valid.sum() == 143  # only the pixel at the white level


def test_simulated_flat_field_recovers_radiance(tmp_path):
    # A uniform target of known radiance: DN/s = L · k · q / g (+ dark), in every channel.
    sensor = SensorModel(width=400, height=300, quantum_sensitivity=(0.6, 1.0, 0.8),
                         dark_current_e_per_s=2.0, prnu_sigma=0.01)
    radiances = (0.05, 0.2)
    results = []
    for n, radiance in enumerate(radiances):
        cam = SimCamera(sensor, lambda r=radiance: np.full((150, 200, 3), r), seed=2)
        info = cam.capture(tmp_path / f"flat{n}.dng", 0.4, 200)
        frame = load_raw(info.path)
        image = linearize(frame, normalize_iso=True, normalize_f_number=True)
        assert image.valid.all()
        mean, var_of_mean, count = roi_mean(image, Roi(0, 0, 200, 150))
        gain = sensor.gain_at(200)
        expected = (
            (radiance * sensor.electrons_per_radiance_s * np.array(sensor.quantum_sensitivity)
             + sensor.dark_current_e_per_s) / gain * 100 / 200 * sensor.f_number**2
        )
        assert count == 30000
        np.testing.assert_allclose(mean, expected, rtol=5e-3)
        results.append(mean)
    # Proportional to radiance once the (known) dark current is removed.
    dark = sensor.dark_current_e_per_s / sensor.gain_at(200) / 2 * sensor.f_number**2
    np.testing.assert_allclose((results[1] - dark) / (results[0] - dark), 4.0, rtol=5e-3)


def test_exposure_and_iso_normalisation_agree():
    sensor = SensorModel(width=256, height=256, prnu_sigma=0.0)
    rad = np.array([0.3, 0.5, 0.4])
    means = []
    for t, iso in [(0.2, 100), (0.05, 400), (0.8, 100)]:
        mosaic = sensor.expose(rad, t, iso, frame_seed=1)
        frame = _frame(mosaic, black=512, white=sensor.white_level_dn(iso), t=t, iso=iso)
        means.append(np.nanmean(linearize(frame, normalize_iso=True).rgb, axis=(0, 1)))
    np.testing.assert_allclose(means[1], means[0], rtol=3e-3)
    np.testing.assert_allclose(means[2], means[0], rtol=3e-3)


def test_variance_predicts_scatter():
    sensor = SensorModel(width=512, height=512, prnu_sigma=0.0, dark_current_e_per_s=0.0)
    iso = 200
    gain = sensor.gain_at(iso)
    read_dn = math.hypot(sensor.read_noise_e / gain, sensor.black_noise_dn)
    noise = NoiseModel(gain_e_per_dn=gain, read_noise_dn=read_dn, iso=iso)
    rad = np.array([0.05, 0.2, 0.1])
    mosaic = sensor.expose(rad, 0.3, iso, frame_seed=4)
    frame = _frame(mosaic, black=512, white=sensor.white_level_dn(iso), t=0.3, iso=iso)
    image = linearize(frame, noise=noise)
    scatter = image.rgb.reshape(-1, 3).var(axis=0)
    predicted = image.variance.reshape(-1, 3).mean(axis=0)
    np.testing.assert_allclose(predicted, scatter, rtol=0.03)
    mean, var_of_mean, n = roi_mean(image, (10, 20, 100, 50))
    assert n == 5000
    np.testing.assert_allclose(var_of_mean, predicted / n, rtol=0.02)


def test_noise_model_for_another_iso_is_refused():
    image_frame = _frame(np.full((24, 24), 100, np.uint16), iso=800)
    with pytest.raises(CalibrationError, match="ISO 100.*ISO 800"):
        linearize(image_frame, noise=NoiseModel(2.0, 1.5, iso=100))


def test_dark_replaces_black_and_flat_divides():
    rng = np.random.default_rng(3)
    dark = rng.uniform(60, 70, (24, 24)).astype(np.float32)
    flat_px = rng.uniform(0.8, 1.2, (24, 24))
    signal = 400.0
    mosaic = np.rint(dark + signal * flat_px).astype(np.uint16)
    frame = _frame(mosaic, black=0, t=1.0)
    out = linearize(frame, dark=dark, flat=flat_px)
    np.testing.assert_allclose(out.rgb, signal, atol=0.7)  # rounding of the mosaic only
    flat_sp = np.ones((12, 12, 3))
    flat_sp[..., 2] = 2.0
    half = linearize(_frame(np.full((24, 24), 164, np.uint16), black=64, t=1.0), flat=flat_sp)
    np.testing.assert_allclose(half.rgb[..., 0], 100.0)
    np.testing.assert_allclose(half.rgb[..., 2], 50.0)


def test_bad_pixels_and_zero_flat_are_masked():
    frame = _frame(np.full((24, 24), 500, np.uint16))
    bad = np.zeros((24, 24), bool)
    bad[3, 3] = True
    flat = np.ones((24, 24))
    flat[10, 11] = 0.0
    image = linearize(frame, bad_pixels=bad, flat=flat)
    assert not image.valid[1, 1] and not image.valid[5, 5]
    assert image.valid.sum() == 142
    sp_bad = np.zeros((12, 12), bool)
    sp_bad[7, 2] = True
    assert not linearize(frame, bad_pixels=sp_bad).valid[7, 2]


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"dark": np.zeros((10, 10))}, "master dark"),
        ({"flat": np.ones((5, 5))}, "flat field"),
        ({"bad_pixels": np.zeros((3, 3), bool)}, "bad-pixel"),
        ({"saturation": 0.0}, "saturation"),
    ],
)
def test_wrong_calibration_data_is_refused(kwargs, match):
    with pytest.raises(CalibrationError, match=match):
        linearize(_frame(np.zeros((24, 24), np.uint16)), **kwargs)


def test_missing_metadata_is_refused():
    frame = _frame(np.zeros((24, 24), np.uint16), t=None, iso=None, f_number=None)
    with pytest.raises(CalibrationError, match="exposure time unknown"):
        linearize(frame)
    assert linearize(frame, exposure_s=2.0).scale == 0.5
    with pytest.raises(CalibrationError, match="ISO unknown"):
        linearize(frame, exposure_s=1.0, normalize_iso=True)
    with pytest.raises(CalibrationError, match="f-number unknown"):
        linearize(frame, exposure_s=1.0, normalize_f_number=True)


def test_roi_mean_without_noise_model_uses_scatter():
    rgb = np.arange(4 * 6 * 3, dtype=float).reshape(4, 6, 3)
    valid = np.ones((4, 6), bool)
    valid[1, 1] = False
    rgb[1, 1] = np.nan
    image = LinearImage(rgb=rgb, valid=valid, variance=None, units="DN/s", scale=1.0,
                        exposure_s=1.0, iso=None, f_number=None)
    mean, var_of_mean, n = roi_mean(image, Roi(0, 0, 3, 2))
    values = rgb[:2, :3][valid[:2, :3]]
    assert n == 5
    np.testing.assert_allclose(mean, values.mean(axis=0))
    np.testing.assert_allclose(var_of_mean, values.var(axis=0, ddof=1) / 5)
    empty_mean, empty_var, zero = roi_mean(image, Roi(1, 1, 1, 1))
    assert zero == 0 and np.all(np.isnan(empty_mean)) and np.all(np.isnan(empty_var))
    with pytest.raises(CalibrationError, match="outside"):
        roi_mean(image, Roi(5, 0, 2, 1))
