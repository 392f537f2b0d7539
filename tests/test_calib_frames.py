"""calibration.dark, .flat, .noise: master darks, bad pixels, flat fields, photon transfer.

Frames are real DNGs from the simulated sensor, read back through rawpy (calibration.raw).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from calibration.dark import bad_pixel_map, master_dark
from calibration.flat import flat_field
from calibration.linearize import linearize
from calibration.noise import photon_transfer
from calibration.raw import RawFrame, load_raw
from drivers.errors import CalibrationError
from simulators.camera import SimCamera
from simulators.dng import write_dng
from simulators.sensor import SensorModel

SENSOR = SensorModel(width=128, height=96, dark_current_e_per_s=40.0, prnu_sigma=0.01,
                     vignetting_focal_px=150.0, seed=11)


def _frames(tmp_path: Path, radiance, exposure_s: float, n: int, *, seed: int = 0,
            sensor: SensorModel = SENSOR, tag: str = "f") -> list[RawFrame]:
    camera = SimCamera(sensor, lambda: radiance, seed=seed)
    out = []
    for i in range(n):
        path = tmp_path / f"{tag}-{exposure_s:g}-{i}.dng"
        camera.capture(path, exposure_s, 100)
        out.append(load_raw(path))
    return out


def _write(path: Path, mosaic: np.ndarray, exposure_s: float) -> RawFrame:
    write_dng(path, mosaic, black_level=SENSOR.black_level_dn, white_level=SENSOR.white_level_dn(100),
              exposure_s=exposure_s, iso=100, f_number=SENSOR.f_number)
    return load_raw(path)


def test_master_dark_is_the_median_and_rejects_a_cosmic_ray(tmp_path: Path) -> None:
    frames = _frames(tmp_path, np.zeros(3), 1.0, 8)
    spiked = frames[0].mosaic.astype(np.uint16)
    spiked[10, 20] = 9000  # a cosmic-ray hit in one frame only
    frames[0] = _write(tmp_path / "spiked.dng", spiked, 1.0)
    dark = master_dark(frames)
    expected = SENSOR.black_level_dn + SENSOR.dark_current_e_per_s * 1.0 / SENSOR.gain_at(100)
    assert dark.shape == (SENSOR.height, SENSOR.width)
    assert abs(float(dark.mean()) - expected) < 0.2
    assert abs(float(dark[10, 20]) - expected) < 20  # the median ignores the spike
    assert abs(float(np.mean(frames[1].mosaic)) - float(dark.mean())) < 0.2


def test_master_dark_needs_eight_frames_of_one_setting(tmp_path: Path) -> None:
    frames = _frames(tmp_path, np.zeros(3), 0.5, 8)
    with pytest.raises(CalibrationError, match="≥ 8 frames"):
        master_dark(frames[:7])
    other = _frames(tmp_path, np.zeros(3), 0.25, 1, tag="other")
    with pytest.raises(CalibrationError, match="group frames by exposure"):
        master_dark(frames[:7] + other)


def test_bad_pixel_map_finds_hot_and_dead_pixels(tmp_path: Path) -> None:
    hot = [(5, 7), (40, 90), (61, 2)]
    frames = []
    for i, f in enumerate(_frames(tmp_path, np.zeros(3), 1.0, 8)):
        m = f.mosaic.astype(np.uint16)
        for r, c in hot:
            m[r, c] += 400
        frames.append(_write(tmp_path / f"hot-{i}.dng", m, 1.0))
    dark = master_dark(frames)
    flat_frames = _frames(tmp_path, np.full(3, 0.5), 1.0, 4, tag="flat")
    dead = (30, 31)
    flats = []
    for i, f in enumerate(flat_frames):
        m = f.mosaic.astype(np.uint16)
        m[dead] = SENSOR.black_level_dn
        flats.append(_write(tmp_path / f"dead-{i}.dng", m, 1.0))
    flat = flat_field(flats, dark=dark)
    bad = bad_pixel_map("RGGB", dark=dark, flat=flat)
    found = set(zip(*np.nonzero(bad), strict=True))
    assert found == {*hot, dead}


def test_flat_field_recovers_vignetting_and_prnu(tmp_path: Path) -> None:
    radiance = np.full(3, 0.6)  # about half the well at 2.5 s
    flat_frames = _frames(tmp_path, radiance, 2.5, 16, tag="flat")
    dark = master_dark(_frames(tmp_path, np.zeros(3), 2.5, 8, tag="dark"))
    flat = flat_field(flat_frames, dark=dark)
    truth = SENSOR.response / SENSOR.response.mean()  # equal quantum sensitivity: one mean
    assert abs(float(flat[0::2, 0::2].mean()) - 1) < 1e-6
    assert float(np.std(flat / truth)) < 0.003  # shot noise of 16 frames only
    assert float(flat.min()) < 0.8  # the corners really are vignetted
    image = linearize(_frames(tmp_path, radiance, 2.5, 1, seed=3, tag="test")[0], dark=dark, flat=flat)
    raw_image = linearize(flat_frames[0], dark=dark)
    assert np.std(image.rgb[..., 1]) / np.mean(image.rgb[..., 1]) < 0.01
    assert np.std(raw_image.rgb[..., 1]) / np.mean(raw_image.rgb[..., 1]) > 0.05


def test_flat_field_refuses_clipped_frames(tmp_path: Path) -> None:
    with pytest.raises(CalibrationError, match="clipped"):
        flat_field(_frames(tmp_path, np.full(3, 50.0), 1.0, 2))


def test_photon_transfer_recovers_gain_and_read_noise(tmp_path: Path) -> None:
    sensor = SensorModel(width=128, height=96, prnu_sigma=0.01, seed=2, gain_e_per_dn=2.0,
                         read_noise_e=4.0, black_noise_dn=1.0)
    pairs = []
    for t in (0.001, 0.05, 0.1, 0.2, 0.4, 0.8, 1.6):
        radiance = np.full(3, 0.0 if t == 0.001 else 1.5)
        a, b = _frames(tmp_path, radiance, t, 2, seed=int(t * 1000), sensor=sensor)
        pairs.append((a, b))
    ptc = photon_transfer(pairs)
    gain, read = ptc.model.per_colour()
    expected_read = np.sqrt((4.0 / 2.0) ** 2 + 1.0**2 + 1 / 12)  # read, black noise, rounding
    np.testing.assert_allclose(gain, 2.0, rtol=0.04)
    np.testing.assert_allclose(read, expected_read, rtol=0.08)
    assert ptc.model.iso == 100
    assert ptc.mean_dn.shape == (7, 3) and np.all(ptc.residual_rms < 0.1)
