"""calibration.raw: visible area, CFA pattern, levels and metadata from real and synthetic RAWs."""

from __future__ import annotations

import json
import os
import warnings
from pathlib import Path

import numpy as np
import pytest

from calibration.raw import (
    BlackLevelWarning,
    format_inspection,
    inspect_raw,
    load_raw,
    optical_black_means,
)
from drivers.errors import RawFormatError
from simulators.dng import CFA_PATTERNS, write_dng

_CODE = {"R": 1000, "G": 2000, "B": 3000}


def _external_raw_dir() -> Path:
    env = os.environ.get("GONIO_EXTERNAL_DATA")
    base = Path(env) if env else Path(__file__).resolve().parents[2] / "shared" / "data"
    return base / "raw"


RAW_DIR = _external_raw_dir()
needs_external = pytest.mark.skipif(
    not RAW_DIR.is_dir(),
    reason=f"external RAW samples not found at {RAW_DIR} (set GONIO_EXTERNAL_DATA)",
)


def _coded_mosaic(pattern: str, h: int, w: int, origin: tuple[int, int] = (0, 0)) -> np.ndarray:
    """A mosaic whose values name their colour (R 1000…, G 2000…, B 3000…) plus a ramp."""
    rows = (np.arange(h)[:, None] - origin[0]) % 2
    cols = (np.arange(w)[None, :] - origin[1]) % 2
    codes = np.array([_CODE[c] for c in pattern]).reshape(2, 2)
    ramp = np.arange(h * w).reshape(h, w) % 97
    return (codes[rows, cols] + ramp).astype(np.uint16)


# --- real files ----------------------------------------------------------------------------


@needs_external
def test_kodak_kdc_is_grbg_bayer():
    frame = load_raw(RAW_DIR / "RAW_KODAK_DC50.KDC")
    assert frame.cfa_pattern == "GRBG"
    assert frame.mosaic.dtype == np.float32 and frame.mosaic.shape == (512, 768)
    assert frame.black_per_colour == {"R": 0.0, "G": 0.0, "B": 0.0}
    assert frame.white_level == 16383
    assert frame.make == "Eastman Kodak Company"
    assert frame.exposure_s == pytest.approx(0.00435)
    assert frame.f_number == pytest.approx(6.2)
    assert frame.iso == pytest.approx(84)  # LibRaw's value: the file has no EXIF ISO tag


@needs_external
def test_inspect_kdc_json():
    info = inspect_raw(RAW_DIR / "RAW_KODAK_DC50.KDC")
    assert json.loads(json.dumps(info)) == {
        "pattern": "GRBG",
        "black": {"R": 0, "G": 0, "B": 0},
        "white": 16383,
        "width": 768,
        "height": 512,
        "exposure_s": 0.00435,
        "iso": 84,
        "f_number": 6.2,
    }
    text = format_inspection(info)
    assert "GRBG" in text and "768 × 512" in text and "f/6.2" in text


@needs_external
def test_nikon_film_scanner_is_refused():
    path = RAW_DIR / "Nikon_uncompressed.nef"
    with pytest.raises(RawFormatError, match="not a Bayer") as info:
        load_raw(path)
    message = str(info.value)
    assert str(path) in message and "\n" not in message


# --- synthetic DNGs ------------------------------------------------------------------------


@pytest.mark.parametrize("pattern", CFA_PATTERNS)
def test_pattern_and_levels_per_position(tmp_path, pattern):
    black = np.array([[60, 61], [62, 63]])
    mosaic = _coded_mosaic(pattern, 24, 32)
    path = write_dng(tmp_path / "f.dng", mosaic, cfa_pattern=pattern, black_level=black,
                     white_level=4095, exposure_s=0.25, iso=200, f_number=4.0)
    frame = load_raw(path)
    assert frame.cfa_pattern == pattern
    assert np.array_equal(frame.mosaic, mosaic.astype(np.float32))
    assert np.array_equal(frame.black_per_position, black)
    expected = {c: float(np.mean([black[divmod(i, 2)] for i, p in enumerate(pattern) if p == c]))
                for c in "RGB"}
    assert frame.black_per_colour == expected
    assert frame.white_per_colour == {"R": 4095, "G": 4095, "B": 4095}
    assert (frame.exposure_s, frame.iso, frame.f_number) == (0.25, 200, 4.0)
    assert (frame.make, frame.model) == ("gonio", "SimCam")
    # The pattern names what the pixels really are.
    for k, colour in enumerate(pattern):
        i, j = divmod(k, 2)
        assert np.all(frame.mosaic[i::2, j::2] // 1000 * 1000 == _CODE[colour])


@pytest.mark.parametrize("origin", [(4, 6), (3, 5)])
def test_visible_area_excludes_crop_margins(tmp_path, origin):
    h, w = 40, 60
    top, left = origin
    mosaic = _coded_mosaic("RGGB", h, w, origin=origin)
    path = write_dng(tmp_path / "f.dng", mosaic, cfa_pattern="RGGB", active_area=(top, left, h, w))
    frame = load_raw(path)
    vt, vl = frame.visible_origin
    assert (vt, vl) >= (top, left)  # LibRaw may round an odd margin up to keep 2×2 cells
    assert frame.raw_shape == (h, w)
    assert np.array_equal(frame.mosaic, mosaic[vt:, vl:].astype(np.float32))
    for k, colour in enumerate(frame.cfa_pattern):
        i, j = divmod(k, 2)
        assert np.all(frame.mosaic[i::2, j::2] // 1000 * 1000 == _CODE[colour])


def _with_optical_black(tmp_path, ob_level: int) -> Path:
    rng = np.random.default_rng(0)
    mosaic = (512 + rng.normal(0, 3, (40, 64))).round().astype(np.uint16)
    mosaic[8:, :] += 2000  # lit active area below 8 optical-black rows
    mosaic[:8] = (ob_level + rng.normal(0, 3, (8, 64))).round().astype(np.uint16)
    return write_dng(tmp_path / "ob.dng", mosaic, black_level=512, white_level=16383,
                     active_area=(8, 0, 40, 64), masked_areas=[(0, 0, 6, 64)])


def test_optical_black_agrees_silently(tmp_path):
    path = _with_optical_black(tmp_path, 513)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        frame = load_raw(path)
    assert frame.optical_black["G"] == pytest.approx(513, abs=0.5)
    assert frame.black_per_colour == {"R": 512, "G": 512, "B": 512}


def test_optical_black_disagreement_warns_and_keeps_stated_black(tmp_path):
    path = _with_optical_black(tmp_path, 520)
    with pytest.warns(BlackLevelWarning, match="optical-black"):
        frame = load_raw(path)
    # LibRaw would have replaced the black by the masked mean; the stated level is kept.
    assert frame.black_per_colour == {"R": 512, "G": 512, "B": 512}
    assert frame.optical_black["R"] == pytest.approx(520, abs=1)


def test_optical_black_means_follow_the_pattern():
    raw = np.zeros((10, 10))
    raw[0::2, 0::2], raw[0::2, 1::2], raw[1::2, 0::2], raw[1::2, 1::2] = 10, 20, 30, 40
    # Visible origin (3, 1): B sits at raw[3, 1] (40), G at raw[3, 2] (30) and raw[4, 1] (20),
    # R at raw[4, 2] (10). Rows 0–2 hold 10 G pixels of 20 and 5 of 30.
    means = optical_black_means(raw, [(0, 0, 3, 10)], "BGGR", (3, 1))
    assert means == pytest.approx({"R": 10.0, "G": 70 / 3, "B": 40.0})
    assert optical_black_means(raw, [(0, 0, 1, 1)], "RGGB", (0, 0)) is None


def test_white_balance_is_metadata_as_stored(tmp_path):
    path = write_dng(tmp_path / "f.dng", _coded_mosaic("RGGB", 24, 24), as_shot_neutral=(0.5, 1, 0.8))
    wb = load_raw(path).camera_whitebalance
    assert wb["R"] == pytest.approx(2.0) and wb["B"] == pytest.approx(1.25)


def test_inspect_unknown_metadata_is_null(tmp_path):
    path = write_dng(tmp_path / "f.dng", _coded_mosaic("GBRG", 24, 28), cfa_pattern="GBRG",
                     black_level=64,
                     white_level=1023)
    info = inspect_raw(path)
    assert set(info) == {"pattern", "black", "white", "width", "height", "exposure_s", "iso",
                         "f_number"}
    assert info["pattern"] == "GBRG" and info["white"] == 1023
    assert (info["width"], info["height"]) == (28, 24)
    assert info["exposure_s"] is None and info["iso"] is None and info["f_number"] is None
    assert "unknown" in format_inspection(info)


# --- bad files -----------------------------------------------------------------------------


def test_random_bytes_are_refused(tmp_path):
    path = tmp_path / "junk.nef"
    path.write_bytes(np.random.default_rng(0).bytes(50_000))
    with pytest.raises(RawFormatError, match="cannot decode") as info:
        load_raw(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


@pytest.mark.parametrize("keep", [200, 0.6])
def test_truncated_dng_is_refused(tmp_path, keep):
    full = write_dng(tmp_path / "full.dng", _coded_mosaic("RGGB", 256, 256)).read_bytes()
    n = keep if isinstance(keep, int) else int(len(full) * keep)
    path = tmp_path / "cut.dng"
    path.write_bytes(full[:n])
    with pytest.raises(RawFormatError, match="cut.dng"):
        load_raw(path)


def test_missing_file(tmp_path):
    with pytest.raises(RawFormatError, match="no such RAW file"):
        load_raw(tmp_path / "absent.dng")
