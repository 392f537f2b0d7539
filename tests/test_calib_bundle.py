"""calibration.bundle and calibration.white: EXR + JSON bundle round trip, absolute scale."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

from calibration.bundle import CalibrationBundle, dark_name, provenance
from calibration.linearize import LinearImage, NoiseModel
from calibration.white import WhiteReference, measure_white
from drivers.errors import CalibrationError


def test_bundle_round_trips_images_and_scalars(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    dark = (512 + rng.integers(0, 40, (48, 64))).astype(np.float32)
    flat = (1 + 0.01 * rng.standard_normal((48, 64))).astype(np.float32)
    bad = np.zeros((48, 64), dtype=bool)
    bad[3, 4] = True
    bundle = CalibrationBundle.create(tmp_path / "cal", camera={"model": "SimCam"})
    bundle.add_dark(dark, 0.01, 100, provenance(frames=8))
    bundle.set_flat(flat, provenance(frames=16))
    bundle.set_bad_pixels(bad, provenance())
    bundle.set_noise(NoiseModel((2.0, 2.1, 2.2), (1.8, 1.7, 1.9), 100), provenance(pairs=7))
    white = WhiteReference(np.array([1.0, 2.0, 3.0]), np.full(3, 1e-4), np.full(3, 0.99), 0.0, 0.5)
    bundle.set_white(white.to_dict(), provenance())

    again = CalibrationBundle.open(tmp_path / "cal")
    np.testing.assert_array_equal(again.dark_for(0.01, 100), dark)  # float32 keeps DN exact
    assert again.dark_for(0.02, 100) is None and again.dark_for(0.01, 200) is None
    np.testing.assert_array_equal(again.flat, flat)
    np.testing.assert_array_equal(again.bad_pixels, bad)
    noise = again.noise_for(100)
    assert noise == NoiseModel((2.0, 2.1, 2.2), (1.8, 1.7, 1.9), 100.0)
    assert again.noise_for(400) is None
    back = WhiteReference.from_dict(again.white)
    np.testing.assert_array_equal(back.signal, white.signal)
    scalars = json.loads((tmp_path / "cal" / "bundle.json").read_text())
    assert scalars["darks"][dark_name(0.01, 100)]["provenance"]["frames"] == 8
    assert scalars["camera"] == {"model": "SimCam"}
    # The EXR is a real OpenEXR file carrying its own description.
    inp = oiio.ImageInput.open(str(tmp_path / "cal" / dark_name(0.01, 100)))
    assert inp.format_name() == "openexr"
    assert inp.spec().getattribute("gonio:kind") == "dark"
    inp.close()


def test_opening_a_folder_that_is_not_a_bundle_says_how_to_make_one(tmp_path: Path) -> None:
    with pytest.raises(CalibrationError, match="gonio calibrate"):
        CalibrationBundle.open(tmp_path)
    (tmp_path / "bundle.json").write_text('{"format": "other"}')
    with pytest.raises(CalibrationError, match="not a gonio-calibration-bundle"):
        CalibrationBundle.open(tmp_path)


def _image(value: float, var: float) -> LinearImage:
    rgb = np.full((10, 10, 3), value)
    return LinearImage(rgb, np.ones((10, 10), bool), np.full((10, 10, 3), var), "DN/s", 1.0, 1.0,
                       100, 8.0)


def test_white_reference_gives_brdf_with_cosine_and_distance_corrections() -> None:
    white = measure_white([_image(1000.0, 4.0), _image(1000.0, 4.0)], (0, 0, 10, 10), 0.99,
                          theta_i_deg=0.0, light_distance_m=0.5)
    np.testing.assert_allclose(white.signal, 1000.0)
    np.testing.assert_allclose(white.variance, 4.0 / 100 / 2)
    # A Lambertian 0.18 at θi = 60° and twice the distance gives S = 1000·(0.18/0.99)·cos60/4.
    s = 1000 * 0.18 / 0.99 * 0.5 / 4
    f, var = white.brdf(np.full(3, s), np.full(3, 0.01), 60.0, light_distance_m=1.0)
    np.testing.assert_allclose(f, 0.18 / math.pi)
    np.testing.assert_allclose(var, f**2 * (0.01 / s**2 + 0.02 / 1000**2))
    with pytest.raises(CalibrationError, match="horizon"):
        white.brdf(np.ones(3), np.ones(3), 90.0)
    with pytest.raises(CalibrationError, match="reflectance"):
        measure_white([_image(1.0, 1.0)], (0, 0, 10, 10), 1.2, 0.0)
