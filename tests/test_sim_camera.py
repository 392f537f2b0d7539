"""simulators.sensor and simulators.camera: physical noise model, determinism, real DNG output."""

from __future__ import annotations

import math

import numpy as np
import pytest
import rawpy

from drivers.camera import Camera, CameraError, CaptureInfo
from drivers.errors import ConfigError, StorageError
from simulators.camera import SimCamera
from simulators.clock import SimClock
from simulators.sensor import SensorModel

SMALL = {"width": 64, "height": 48}


def _sensor(**overrides) -> SensorModel:
    return SensorModel(**{**SMALL, **overrides})


# --- SensorModel ---------------------------------------------------------------------------


def test_from_dict_round_trip_and_integral_floats():
    sensor = SensorModel.from_dict({"width": 64.0, "height": 48, "vignetting_focal_px": 900.0})
    assert sensor.width == 64 and isinstance(sensor.width, int)
    assert SensorModel.from_dict(sensor.to_dict()) == sensor


@pytest.mark.parametrize(
    ("params", "match"),
    [
        ({"widht": 64}, "unknown sensor parameter.*widht"),
        ({"width": 63}, "'width'.*even"),
        ({"bits": 20}, "'bits'"),
        ({"gain_e_per_dn": 0}, "'gain_e_per_dn'"),
        ({"black_level_dn": 20000}, "'black_level_dn'"),
        ({"quantum_sensitivity": [1, 1]}, "quantum_sensitivity"),
        ({"read_noise_e": "x"}, "read_noise_e|invalid"),
    ],
)
def test_from_dict_rejects_bad_parameters(params, match):
    with pytest.raises(ConfigError, match=match) as info:
        SensorModel.from_dict(params, where="rig.toml [camera.sensor]")
    assert str(info.value).startswith("rig.toml [camera.sensor]")
    assert "\n" not in str(info.value)


def test_expose_depends_only_on_seeds_and_inputs():
    sensor = _sensor()
    rad = np.full((24, 32, 3), 0.05)
    a = sensor.expose(rad, 0.1, 100, frame_seed=7)
    assert a.dtype == np.uint16 and a.shape == (48, 64)
    assert np.array_equal(a, _sensor().expose(rad, 0.1, 100, frame_seed=7))
    assert not np.array_equal(a, sensor.expose(rad, 0.1, 100, frame_seed=8))
    assert not np.array_equal(a, _sensor(seed=1).expose(rad, 0.1, 100, frame_seed=7))


def test_flat_field_mean_and_photon_transfer():
    # Mean DN and variance follow the model: μ = b + μ_e / g, σ² = μ_e / g² + σ_read².
    sensor = SensorModel(width=512, height=512, prnu_sigma=0.0, dark_current_e_per_s=0.0)
    radiance, t, iso = 0.4, 0.5, 200
    mosaic = sensor.expose(np.array([radiance] * 3), t, iso, frame_seed=1).astype(np.float64)
    gain = sensor.gain_at(iso)
    mean_e = radiance * sensor.electrons_per_radiance_s * t
    expected_mean = sensor.black_level_dn + mean_e / gain
    expected_var = mean_e / gain**2 + (sensor.read_noise_e / gain) ** 2 + sensor.black_noise_dn**2
    n = mosaic.size
    assert mosaic.mean() == pytest.approx(expected_mean, abs=4 * math.sqrt(expected_var / n))
    assert mosaic.var() == pytest.approx(expected_var, rel=0.02)


def test_dark_current_grows_with_exposure():
    sensor = SensorModel(width=256, height=256, dark_current_e_per_s=50.0, read_noise_e=1.0)
    dark = np.zeros(3)
    short = sensor.expose(dark, 0.01, 100, frame_seed=1).mean()
    long = sensor.expose(dark, 10.0, 100, frame_seed=1).mean()
    gain = sensor.gain_at(100)
    assert short == pytest.approx(sensor.black_level_dn + 0.5 / gain, abs=0.1)
    assert long == pytest.approx(sensor.black_level_dn + 500 / gain, abs=0.5)


def test_full_well_and_adc_saturation():
    sensor = _sensor()
    bright = np.full(3, 1e6)
    base = sensor.expose(bright, 1.0, 100, frame_seed=1)
    # At ISO 100 the full well clips first; the declared white level sits at that point.
    white = sensor.white_level_dn(100)
    assert white < sensor.adc_max
    assert abs(base.astype(float).mean() - white) < 1.0
    # At ISO 800 the ADC ceiling clips first.
    high = sensor.expose(bright, 1.0, 800, frame_seed=1)
    assert sensor.white_level_dn(800) == sensor.adc_max
    assert np.all(high == sensor.adc_max)


def test_prnu_is_fixed_pattern():
    sensor = SensorModel(width=256, height=256, prnu_sigma=0.02, read_noise_e=0.0,
                         black_noise_dn=0.0)
    rad = np.full(3, 2.0)
    a = sensor.expose(rad, 1.0, 100, frame_seed=1).astype(float)
    b = sensor.expose(rad, 1.0, 100, frame_seed=2).astype(float)
    # Frames share the fixed pattern: their pixel deviations correlate strongly.
    corr = np.corrcoef((a - a.mean()).ravel(), (b - b.mean()).ravel())[0, 1]
    assert corr > 0.7
    assert np.std(sensor.response / sensor.electrons_per_radiance_s) == pytest.approx(0.02, rel=0.05)


def test_vignetting_follows_cos4():
    f_px = 200.0
    sensor = SensorModel(width=400, height=300, prnu_sigma=0.0, vignetting_focal_px=f_px)
    resp = sensor.response / sensor.electrons_per_radiance_s
    corner = math.hypot(199.5, 149.5)
    assert resp[0, 0] == pytest.approx(math.cos(math.atan(corner / f_px)) ** 4, rel=1e-9)
    assert resp[150, 200] == pytest.approx(1.0, abs=1e-4)


def test_quantum_sensitivity_per_channel():
    sensor = SensorModel(width=128, height=128, prnu_sigma=0.0, quantum_sensitivity=(0.5, 1.0, 0.25))
    m = sensor.expose(np.full(3, 1.0), 1.0, 100, frame_seed=3).astype(float) - sensor.black_level_dn
    r, g, b = m[0::2, 0::2].mean(), m[0::2, 1::2].mean(), m[1::2, 1::2].mean()
    assert r / g == pytest.approx(0.5, rel=0.01)
    assert b / g == pytest.approx(0.25, rel=0.01)


def test_expose_rejects_bad_input():
    sensor = _sensor()
    with pytest.raises(ValueError, match="superpixel grid"):
        sensor.expose(np.zeros((48, 64, 3)), 1.0)
    with pytest.raises(ValueError, match="finite"):
        sensor.expose(np.full(3, -1.0), 1.0)
    with pytest.raises(ValueError, match="exposure_s"):
        sensor.expose(np.zeros(3), 0.0)


# --- SimCamera -----------------------------------------------------------------------------


class _Scene:
    """Radiance that depends on simulated time, recording when it was rendered."""

    def __init__(self, clock: SimClock | None) -> None:
        self.clock = clock
        self.calls: list[float] = []

    def __call__(self) -> np.ndarray:
        if self.clock is not None:
            self.calls.append(self.clock.now())
        return np.full((24, 32, 3), 0.02)


def _read(path) -> np.ndarray:
    with rawpy.imread(str(path)) as raw:
        return raw.raw_image_visible.copy()


def test_capture_writes_dng_and_advances_clock(tmp_path):
    clock = SimClock(time_scale=1.0)
    scene = _Scene(clock)
    cam = SimCamera(_sensor(), scene, clock, seed=5)
    assert isinstance(cam, Camera)
    before = clock.now()
    info = cam.capture(tmp_path / "a.dng", 2.5, 400)
    assert isinstance(info, CaptureInfo)
    assert info.path == tmp_path / "a.dng" and info.exposure_s == 2.5 and info.iso == 400
    assert before <= info.timestamp == scene.calls[0]
    # Rendering and writing cost no simulated time; the exposure costs exactly 2.5 s.
    assert clock.now() - info.timestamp == pytest.approx(2.5, abs=0.05)
    with rawpy.imread(str(info.path)) as raw:
        assert raw.raw_image_visible.shape == (48, 64)
        assert raw.white_level == cam.sensor.white_level_dn(400)
        assert raw.black_level_per_channel == [512] * 4
    assert cam.frames_taken == 1


def test_frames_are_reproducible(tmp_path):
    def shoot(name: str, seed: int, **kw) -> np.ndarray:
        cam = SimCamera(_sensor(), _Scene(None), None, seed=seed)
        return _read(cam.capture(tmp_path / name, 0.1, 100, **kw).path)

    a = shoot("a.dng", 1)
    assert a.tobytes() == shoot("b.dng", 1).tobytes()
    assert a.tobytes() != shoot("c.dng", 2).tobytes()
    # Consecutive frames differ; an explicit frame seed does not depend on the frame count.
    cam = SimCamera(_sensor(), _Scene(None), None, seed=1)
    first = _read(cam.capture(tmp_path / "d.dng", 0.1).path)
    second = _read(cam.capture(tmp_path / "e.dng", 0.1).path)
    assert first.tobytes() == a.tobytes() and second.tobytes() != first.tobytes()
    again = _read(cam.capture(tmp_path / "f.dng", 0.1, frame_seed=0).path)
    assert again.tobytes() == first.tobytes()


def test_describe_names_the_sensor():
    cam = SimCamera(_sensor(bits=12), _Scene(None), seed=3)
    desc = cam.describe()
    assert desc["source"] == "simulator"
    assert (desc["width_px"], desc["height_px"], desc["bits"]) == (64, 48, 12)
    assert desc["cfa_pattern"] == "RGGB"
    assert SensorModel.from_dict(desc["sensor"]) == cam.sensor


@pytest.mark.parametrize(("exposure", "iso"), [(0.0, 100), (-1.0, 100), (math.inf, 100),
                                               (1.0, 10), (1.0, math.nan)])
def test_capture_refuses_bad_settings(tmp_path, exposure, iso):
    cam = SimCamera(_sensor(), _Scene(None))
    with pytest.raises(CameraError):
        cam.capture(tmp_path / "x.dng", exposure, iso)
    assert not (tmp_path / "x.dng").exists()


def test_capture_into_missing_folder_is_storage_error(tmp_path):
    clock = SimClock()
    cam = SimCamera(_sensor(), _Scene(clock), clock)
    with pytest.raises(StorageError, match="missing"):
        cam.capture(tmp_path / "missing" / "x.dng", 1.0)
    assert cam.frames_taken == 0
    assert clock.now() < 1.0  # a failed capture does not consume the exposure


def test_optical_black_border_reaches_the_loader(tmp_path):
    from calibration.raw import BlackLevelWarning, load_raw

    sensor = _sensor(optical_black_px=8)
    assert sensor.raw_shape == (56, 72)
    cam = SimCamera(sensor, _Scene(None))
    frame = load_raw(cam.capture(tmp_path / "a.dng", 1.0).path)
    assert frame.mosaic.shape == (48, 64) and frame.visible_origin == (8, 8)
    assert frame.cfa_pattern == "RGGB"
    assert frame.mosaic.mean() > 600  # the lit area, not the border
    assert frame.optical_black["G"] == pytest.approx(512, abs=1)
    # Masked pixels still collect dark current: a long, warm exposure lifts them above the
    # stated black level and the loader says so.
    warm = SimCamera(_sensor(optical_black_px=8, dark_current_e_per_s=100.0), _Scene(None))
    with pytest.warns(BlackLevelWarning) as record:
        load_raw(warm.capture(tmp_path / "b.dng", 2.0).path)
    assert record[0].filename == __file__  # the warning names the line that loaded the file


def test_optical_black_border_must_be_even():
    with pytest.raises(ConfigError, match="optical_black_px"):
        SensorModel.from_dict({"optical_black_px": 3})
