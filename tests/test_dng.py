"""simulators.dng: DNG files that LibRaw reads bit-exactly and OpenImageIO, exiftool and LibRaw's
tools read capture metadata from (an EXIF IFD)."""

from __future__ import annotations

import datetime as dt
import shutil
import subprocess

import numpy as np
import OpenImageIO as oiio
import pytest
import rawpy
import tifffile
from hypothesis import given, settings
from hypothesis import strategies as st

from calibration.raw import _capture_metadata, load_raw
from simulators.dng import CFA_PATTERNS, write_dng

BLACK = np.array([[500, 501], [502, 503]])


def _mosaic(h: int = 32, w: int = 48, seed: int = 0, high: int = 16383) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, high + 1, (h, w), dtype=np.uint16)


def _libraw_pattern(raw: rawpy.RawPy) -> str:
    desc = raw.color_desc.decode()
    return "".join(desc[i] for i in raw.raw_pattern.ravel())


@pytest.mark.parametrize("pattern", CFA_PATTERNS)
def test_round_trip_through_rawpy(tmp_path, pattern):
    mosaic = _mosaic()
    path = write_dng(
        tmp_path / "f.dng", mosaic, cfa_pattern=pattern, black_level=BLACK, white_level=16383
    )
    with rawpy.imread(str(path)) as raw:
        assert raw.raw_type == rawpy.RawType.Flat
        assert np.array_equal(raw.raw_image_visible, mosaic)
        assert _libraw_pattern(raw) == pattern
        assert raw.white_level == 16383
        # LibRaw lists black by colour index; map our per-position levels through its pattern.
        by_index = raw.black_level_per_channel
        got = [[by_index[c] for c in row] for row in raw.raw_pattern]
    assert np.array_equal(got, BLACK)


def test_scalar_black_and_low_white(tmp_path):
    path = write_dng(tmp_path / "f.dng", _mosaic(high=4095), black_level=256, white_level=4095)
    with rawpy.imread(str(path)) as raw:
        assert raw.black_level_per_channel == [256, 256, 256, 256]
        assert raw.white_level == 4095


def test_openimageio_reads_capture_metadata(tmp_path):
    path = write_dng(
        tmp_path / "f.dng",
        _mosaic(),
        exposure_s=1 / 250,
        iso=400,
        f_number=5.6,
        make="Acme",
        model="Cam 1",
        datetime=dt.datetime(2024, 5, 6, 7, 8, 9),
    )
    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    spec = inp.spec()
    inp.close()
    assert spec.getattribute("ExposureTime") == pytest.approx(1 / 250, rel=1e-6)
    assert spec.getattribute("FNumber") == pytest.approx(5.6, rel=1e-6)
    # from the EXIF IFD OpenImageIO reads ISO as a one-element uint16 array, as for camera files
    assert spec.get_int_attribute("Exif:ISOSpeedRatings") == 400
    assert spec.getattribute("Make") == "Acme"
    assert spec.getattribute("Model") == "Cam 1"
    assert spec.getattribute("DateTime") == "2024:05:06 07:08:09"
    assert spec.getattribute("Exif:DateTimeOriginal") == "2024:05:06 07:08:09"
    frame = load_raw(path)  # gonio's own loader
    assert (frame.exposure_s, frame.iso, frame.f_number) == pytest.approx((1 / 250, 400, 5.6))
    # the OpenImageIO side alone reads the ISO too (not only LibRaw's fallback)
    assert _capture_metadata(path)["iso"] == 400


CAPTURE = {"exposure_s": 1 / 250, "iso": 400, "f_number": 5.6, "datetime": "2024:05:06 07:08:09"}


def test_capture_metadata_live_in_the_exif_ifd(tmp_path):
    path = write_dng(tmp_path / "f.dng", _mosaic(), **CAPTURE)
    with tifffile.TiffFile(path) as tif:
        ifd0 = tif.pages.first.tags
        exif = ifd0[34665].value  # ExifIFD pointer, decoded by tifffile
    assert not {33434, 33437, 34855} & set(ifd0.keys())  # nothing left in IFD0
    assert exif["ExposureTime"] == (1, 250) and exif["FNumber"] == (28, 5)
    assert exif["ISOSpeedRatings"] == 400
    assert exif["ExifVersion"] == "0230" and exif["DateTimeOriginal"] == CAPTURE["datetime"]


def test_libraw_reads_exif_capture_metadata(tmp_path):
    mosaic = _mosaic()
    path = write_dng(tmp_path / "f.dng", mosaic, **CAPTURE)
    with rawpy.imread(str(path)) as raw:
        other = raw.other
        assert np.array_equal(raw.raw_image_visible, mosaic)  # still bit-exact
    assert other.iso_speed == 400  # LibRaw ignores ISO in IFD0 of a DNG
    assert other.shutter_speed == pytest.approx(1 / 250, rel=1e-6)
    assert other.aperture == pytest.approx(5.6, rel=1e-6)
    assert other.timestamp == dt.datetime(2024, 5, 6, 7, 8, 9)


def _tool(name: str) -> str:
    path = shutil.which(name)
    if path is None:
        pytest.skip(f"{name} is not installed (Debian: apt-get install libimage-exiftool-perl "
                    "libraw-bin; .ci/run does it when run as root)")
    return path


def test_raw_identify_reads_iso(tmp_path):
    path = write_dng(tmp_path / "f.dng", _mosaic(), **CAPTURE)
    out = subprocess.run([_tool("raw-identify"), "-v", str(path)], capture_output=True,
                         text=True, check=True).stdout
    lines = {k.strip(): v.strip() for k, _, v in (ln.partition(":") for ln in out.splitlines())}
    assert lines["ISO speed"] == "400"
    assert lines["Shutter"] == "1/250.0" and lines["Aperture"] == "f/5.6"


@pytest.mark.parametrize(
    "kwargs",
    [
        CAPTURE,
        {},  # no capture settings: the EXIF IFD still holds version and time
        {**CAPTURE, "black_level": 512, "white_level": 16383, "active_area": (4, 0, 32, 48),
         "masked_areas": [(0, 0, 4, 48)], "cfa_pattern": "GBRG"},
    ],
    ids=["capture", "bare", "masked"],
)
def test_exiftool_validates_without_warnings(tmp_path, kwargs):
    path = write_dng(tmp_path / "f.dng", _mosaic(), **kwargs)
    out = subprocess.run([_tool("exiftool"), "-validate", "-warning", "-error", "-a", "-G1", "-s",
                          str(path)], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["[ExifTool]", "Validate", ":", "OK"], out
    if kwargs.get("iso"):
        tags = subprocess.run([_tool("exiftool"), "-a", "-G1", "-s", "-ExposureTime", "-FNumber",
                               "-ISO", str(path)], capture_output=True, text=True, check=True).stdout
        assert tags.split("\n")[:3] == ["[ExifIFD]       ExposureTime                    : 1/250",
                                        "[ExifIFD]       FNumber                         : 5.6",
                                        "[ExifIFD]       ISO                             : 400"]


@settings(max_examples=25, deadline=None)
@given(exposure=st.floats(1e-5, 3600), f_number=st.floats(1.0, 64.0))
def test_exposure_and_aperture_rationals(tmp_path_factory, exposure, f_number):
    path = tmp_path_factory.mktemp("dng") / "f.dng"
    write_dng(path, _mosaic(24, 24), exposure_s=exposure, f_number=f_number, iso=100)
    inp = oiio.ImageInput.open(str(path))
    spec = inp.spec()
    inp.close()
    assert spec.getattribute("ExposureTime") == pytest.approx(exposure, rel=1e-6)
    assert spec.getattribute("FNumber") == pytest.approx(f_number, rel=1e-6)


def test_active_area_is_libraw_visible_area(tmp_path):
    mosaic = _mosaic(40, 60)
    path = write_dng(
        tmp_path / "f.dng", mosaic, cfa_pattern="GBRG", active_area=(4, 6, 38, 58)
    )
    with rawpy.imread(str(path)) as raw:
        assert np.array_equal(raw.raw_image, mosaic)
        assert np.array_equal(raw.raw_image_visible, mosaic[4:38, 6:58])
        assert (raw.sizes.top_margin, raw.sizes.left_margin) == (4, 6)
        assert _libraw_pattern(raw) == "GBRG"  # stated for the active area's corner


def test_masked_areas_reach_libraw(tmp_path):
    mosaic = np.full((40, 60), 3000, np.uint16)
    mosaic[:4] = 520  # optical black rows
    path = write_dng(
        tmp_path / "f.dng",
        mosaic,
        black_level=512,
        white_level=16383,
        active_area=(4, 0, 40, 60),
        masked_areas=[(0, 0, 4, 60)],
    )
    with rawpy.imread(str(path)) as raw:
        # LibRaw measures black from the declared masked area (DNG semantics).
        assert raw.black_level_per_channel == [520, 520, 520, 520]


def test_fsync_writes_complete_file(tmp_path):
    path = write_dng(tmp_path / "f.dng", _mosaic(), fsync=True)
    with rawpy.imread(str(path)) as raw:
        assert raw.raw_image_visible.shape == (32, 48)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"cfa_pattern": "RGBG"}, "cfa_pattern"),
        ({"black_level": 16383, "white_level": 16383}, "below white_level"),
        ({"black_level": 10.5}, "whole DN"),
        ({"black_level": [1, 2, 3]}, "2×2"),
        ({"white_level": 70000}, "white_level"),
        ({"exposure_s": 0}, "exposure_s"),
        ({"f_number": 0}, "f_number"),
        ({"iso": 70000}, "iso"),
        ({"datetime": "2024-05-06"}, "datetime"),
        ({"active_area": (0, 0, 33, 48)}, "active_area"),
        ({"active_area": (0, 0, 21, 48)}, "minimum"),
        ({"masked_areas": [(0, 0, 2, 49)]}, "masked area"),
        ({"as_shot_neutral": (1, 0, 1)}, "as_shot_neutral"),
    ],
)
def test_invalid_arguments(tmp_path, kwargs, match):
    with pytest.raises(ValueError, match=match):
        write_dng(tmp_path / "f.dng", _mosaic(), **kwargs)


def test_rejects_too_small_for_libraw(tmp_path):
    with pytest.raises(ValueError, match="minimum of 22"):
        write_dng(tmp_path / "f.dng", _mosaic(21, 48))


def test_rejects_non_uint16(tmp_path):
    with pytest.raises(ValueError, match="uint16"):
        write_dng(tmp_path / "f.dng", _mosaic().astype(np.int32))
