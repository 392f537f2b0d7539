"""Write Bayer mosaics as real DNG files that LibRaw (rawpy), OpenImageIO and EXIF readers read.

The tag set is the minimum LibRaw needs to read a synthetic Bayer file correctly (see
``shared/notes/platform-facts.md``). Capture metadata — ``ExposureTime``, ``FNumber``,
``ISOSpeedRatings`` (EXIF 2.3 ``PhotographicSensitivity``) and the capture time — live in an
EXIF IFD (``ExifIFD`` pointer, tag 34665) as EXIF and TIFF/EP specify, where exiftool, LibRaw
(which ignores ISO in IFD0 of a DNG) and OpenImageIO look for them. tifffile cannot write an
EXIF IFD (it filters tag 34665), so :func:`write_dng` has it write a placeholder tag with the
next code (34666, unassigned, so the entries stay sorted), appends the EXIF IFD and turns the
placeholder into the ``ExifIFD`` pointer. Samples are stored uncompressed in 16-bit words; the
sensor's bit depth shows in the white level.

A masked border can be written around the active area: ``active_area`` becomes the DNG
``ActiveArea`` tag (LibRaw's visible area) and ``masked_areas`` the ``MaskedAreas`` tag
(optical-black rectangles). The CFA pattern is stated for the active area's top-left corner,
as DNG specifies. Note that LibRaw replaces the black level by the mean of the masked areas
when they are declared.
"""

from __future__ import annotations

import datetime as _dt
import os
import struct
from collections.abc import Sequence
from fractions import Fraction
from pathlib import Path
from typing import BinaryIO

import numpy as np
import tifffile

CFA_PATTERNS: tuple[str, ...] = ("RGGB", "GRBG", "GBRG", "BGGR")
"""The four Bayer layouts, each the 2×2 colours of the top-left corner read row by row."""

MIN_SIZE_PX = 22
"""LibRaw refuses images (visible areas) narrower or lower than this."""

EXIF_VERSION = b"0230"
"""EXIF version the EXIF IFD declares (2.3: ``PhotographicSensitivity`` naming)."""

_CFA_CODE = {"R": 0, "G": 1, "B": 2}  # TIFF/EP CFAPattern colour codes

# Tag codes (TIFF 6, TIFF/EP, EXIF 2.3 and DNG 1.4).
_MAKE = 271
_MODEL = 272
_EXIF_IFD = 34665
_EXIF_PLACEHOLDER = 34666  # unassigned: tifffile refuses to write 34665 itself
_EXPOSURE_TIME = 33434
_F_NUMBER = 33437
_ISO_SPEED_RATINGS = 34855
_EXIF_VERSION = 36864
_DATE_TIME_ORIGINAL = 36867
_DATE_TIME_DIGITIZED = 36868
_FLASHPIX_VERSION = 40960
_COLOR_SPACE = 40961
_CFA_REPEAT_PATTERN_DIM = 33421
_CFA_PATTERN = 33422
_DNG_VERSION = 50706
_DNG_BACKWARD_VERSION = 50707
_UNIQUE_CAMERA_MODEL = 50708
_CFA_PLANE_COLOR = 50710
_BLACK_LEVEL_REPEAT_DIM = 50713
_BLACK_LEVEL = 50714
_WHITE_LEVEL = 50717
_COLOR_MATRIX_1 = 50721
_AS_SHOT_NEUTRAL = 50728
_CALIBRATION_ILLUMINANT_1 = 50778
_ACTIVE_AREA = 50829
_MASKED_AREAS = 50830
_PHOTOMETRIC_CFA = 32803
_D65 = 21
_STAMP_FORMAT = "%Y:%m:%d %H:%M:%S"
_UNCALIBRATED = 0xFFFF  # EXIF ColorSpace: not sRGB (camera-native raw data)

# TIFF field types and their sizes (bytes).
_ASCII, _SHORT, _LONG, _RATIONAL, _UNDEFINED = 2, 3, 4, 5, 7
_TYPE_SIZE = {_ASCII: 1, _SHORT: 2, _LONG: 4, _RATIONAL: 8, _UNDEFINED: 1}

Tag = tuple[int, str, int, object, bool]
"""A tifffile extra tag: (code, dtype, count, value, write once)."""
ExifEntry = tuple[int, int, int, bytes]
"""An EXIF IFD entry: (code, TIFF type, count, little-endian value bytes)."""


def _rational(value: float, signed: bool = False) -> tuple[int, int]:
    frac = Fraction(float(value)).limit_denominator(1_000_000 if abs(value) < 2000 else 1000)
    if not signed and frac < 0:
        raise ValueError(f"DNG value {value} must be ≥ 0")
    return frac.numerator, frac.denominator


def _rationals(values: Sequence[float], signed: bool = False) -> tuple[int, ...]:
    return tuple(v for x in values for v in _rational(x, signed))


def _exposure_rational(exposure_s: float) -> tuple[int, int]:
    """Exposure time as an unsigned 32-bit rational, as fine as the value allows."""
    max_den = min(1_000_000_000, int(4e9 // max(1.0, float(exposure_s))))
    frac = Fraction(float(exposure_s)).limit_denominator(max_den)
    return frac.numerator, frac.denominator


def _black_2x2(black_level: float | Sequence[Sequence[float]] | np.ndarray) -> np.ndarray:
    black = np.asarray(black_level, dtype=np.float64)
    if black.shape == ():
        black = np.full((2, 2), float(black))
    if black.shape != (2, 2):
        raise ValueError(f"black_level must be a scalar or 2×2 per CFA position, got {black.shape}")
    if np.any(black < 0) or np.any(black != np.round(black)):
        # LibRaw truncates fractional black levels, so only whole DN round-trip.
        raise ValueError(f"black_level must be whole DN ≥ 0, got {black.tolist()}")
    return black


def _stamp(datetime: _dt.datetime | str | None) -> str:
    """TIFF/EXIF date-time text ``YYYY:MM:DD HH:MM:SS`` (now when None)."""
    if isinstance(datetime, str):
        try:
            _dt.datetime.strptime(datetime, _STAMP_FORMAT)
        except ValueError:
            raise ValueError(f"datetime must read YYYY:MM:DD HH:MM:SS, got {datetime!r}") from None
        return datetime
    return (_dt.datetime.now() if datetime is None else datetime).strftime(_STAMP_FORMAT)


def _check_mosaic(mosaic: np.ndarray, cfa_pattern: str) -> np.ndarray:
    mosaic = np.asarray(mosaic)
    if mosaic.ndim != 2 or mosaic.dtype != np.uint16:
        raise ValueError(f"mosaic must be a 2-D uint16 array, got {mosaic.dtype} {mosaic.shape}")
    if cfa_pattern not in CFA_PATTERNS:
        raise ValueError(f"cfa_pattern must be one of {', '.join(CFA_PATTERNS)}, got {cfa_pattern!r}")
    height, width = mosaic.shape
    if min(height, width) < MIN_SIZE_PX:
        raise ValueError(f"mosaic {height}×{width} px is below LibRaw's minimum of {MIN_SIZE_PX} px")
    return mosaic


def _area(area: Sequence[int], shape: tuple[int, int], what: str) -> tuple[int, int, int, int]:
    """``(top, left, bottom, right)`` checked to lie inside a mosaic of ``shape``."""
    top, left, bottom, right = (int(v) for v in area)
    height, width = shape
    if not (0 <= top < bottom <= height and 0 <= left < right <= width):
        raise ValueError(f"{what} {tuple(area)} lies outside the {height}×{width} mosaic")
    return top, left, bottom, right


def _level_tags(
    black_level: float | Sequence[Sequence[float]] | np.ndarray,
    white_level: int,
    as_shot_neutral: Sequence[float],
    color_matrix: Sequence[float] | np.ndarray | None,
) -> list[Tag]:
    """BlackLevel, WhiteLevel, ColorMatrix1 and AsShotNeutral, checked."""
    if not 0 < int(white_level) <= 65535:
        raise ValueError(f"white_level must be in 1…65535 DN, got {white_level}")
    black = _black_2x2(black_level)
    if np.any(black >= white_level):
        raise ValueError(f"black_level {black.tolist()} must be below white_level {white_level}")
    matrix = np.eye(3) if color_matrix is None else np.asarray(color_matrix, dtype=np.float64)
    if matrix.size != 9:
        raise ValueError(f"color_matrix must have 9 entries, got {matrix.size}")
    neutral = [float(v) for v in as_shot_neutral]
    if len(neutral) != 3 or min(neutral) <= 0:
        raise ValueError(f"as_shot_neutral must be 3 positive values, got {as_shot_neutral}")
    return [
        (_BLACK_LEVEL_REPEAT_DIM, "H", 2, (2, 2), True),
        (_BLACK_LEVEL, "I", 4, tuple(int(v) for v in black.ravel()), True),
        (_WHITE_LEVEL, "I", 1, int(white_level), True),
        (_COLOR_MATRIX_1, "2i", 9, _rationals(matrix.ravel(), signed=True), True),
        (_CALIBRATION_ILLUMINANT_1, "H", 1, _D65, True),
        (_AS_SHOT_NEUTRAL, "2I", 3, _rationals(neutral), True),
    ]


def _area_tags(
    shape: tuple[int, int],
    active_area: tuple[int, int, int, int] | None,
    masked_areas: Sequence[tuple[int, int, int, int]],
) -> list[Tag]:
    """ActiveArea and MaskedAreas, checked against the mosaic's ``shape``."""
    tags: list[Tag] = []
    if active_area is not None:
        top, left, bottom, right = _area(active_area, shape, "active_area")
        if min(bottom - top, right - left) < MIN_SIZE_PX:
            raise ValueError(f"active_area {active_area} is below LibRaw's minimum of {MIN_SIZE_PX} px")
        tags.append((_ACTIVE_AREA, "I", 4, (top, left, bottom, right), True))
    if masked_areas:
        if len(masked_areas) > 8:
            raise ValueError(f"at most 8 masked areas, got {len(masked_areas)}")
        flat = [v for area in masked_areas for v in _area(area, shape, "masked area")]
        tags.append((_MASKED_AREAS, "I", len(flat), tuple(flat), True))
    return tags


def _exif_entries(
    exposure_s: float | None, f_number: float | None, iso: float | None, stamp: str
) -> list[ExifEntry]:
    """The EXIF IFD: capture settings (those given), capture time and the EXIF basics."""
    entries: list[ExifEntry] = []
    if exposure_s is not None:
        if not exposure_s > 0:
            raise ValueError(f"exposure_s must be > 0 s, got {exposure_s}")
        entries.append((_EXPOSURE_TIME, _RATIONAL, 1, struct.pack("<2I", *_exposure_rational(exposure_s))))
    if f_number is not None:
        if not f_number > 0:
            raise ValueError(f"f_number must be > 0, got {f_number}")
        entries.append((_F_NUMBER, _RATIONAL, 1, struct.pack("<2I", *_rational(f_number))))
    if iso is not None:
        if not 1 <= round(iso) <= 65535:
            raise ValueError(f"iso must be 1–65535 (EXIF ISOSpeedRatings is 16-bit), got {iso}")
        entries.append((_ISO_SPEED_RATINGS, _SHORT, 1, struct.pack("<H", int(round(iso)))))
    when = stamp.encode("ascii") + b"\0"
    entries += [
        (_EXIF_VERSION, _UNDEFINED, 4, EXIF_VERSION),
        (_DATE_TIME_ORIGINAL, _ASCII, len(when), when),
        (_DATE_TIME_DIGITIZED, _ASCII, len(when), when),
        (_FLASHPIX_VERSION, _UNDEFINED, 4, b"0100"),
        (_COLOR_SPACE, _SHORT, 1, struct.pack("<H", _UNCALIBRATED)),
    ]
    return entries


def _encode_ifd(entries: Sequence[ExifEntry], offset: int) -> bytes:
    """A little-endian classic-TIFF IFD placed at file ``offset`` (even), values after it."""
    entries = sorted(entries)
    values_at = offset + 2 + 12 * len(entries) + 4
    table, values = bytearray(struct.pack("<H", len(entries))), bytearray()
    for code, kind, count, value in entries:
        if len(value) != count * _TYPE_SIZE[kind]:
            raise AssertionError(f"EXIF tag {code}: {len(value)} bytes for {count} × type {kind}")
        if len(value) <= 4:
            field = value.ljust(4, b"\0")
        else:
            field = struct.pack("<I", values_at + len(values))
            values += value + b"\0" * (len(value) % 2)  # values start on word boundaries
        table += struct.pack("<HHI", code, kind, count) + field
    return bytes(table + struct.pack("<I", 0) + values)  # 0: no next IFD


def _append_exif_ifd(fh: BinaryIO, entries: Sequence[ExifEntry]) -> None:
    """Append the EXIF IFD to tifffile's little-endian classic TIFF and point IFD0 at it.

    IFD0's placeholder entry (code 34666, LONG, count 1) becomes ``ExifIFD`` (34665) with the
    EXIF IFD's offset as its value; no entry has code 34665, so IFD0 stays sorted.
    """
    fh.seek(0)
    header = fh.read(8)
    if header[:4] != b"II*\0":
        raise AssertionError("tifffile did not write a little-endian classic TIFF")
    (ifd0,) = struct.unpack("<I", header[4:])
    fh.seek(ifd0)
    (n,) = struct.unpack("<H", fh.read(2))
    table = fh.read(12 * n)
    found = [i for i in range(n) if struct.unpack_from("<H", table, 12 * i)[0] == _EXIF_PLACEHOLDER]
    if len(found) != 1 or struct.unpack_from("<HI", table, 12 * found[0] + 2) != (_LONG, 1):
        raise AssertionError("tifffile did not write the EXIF placeholder as one inline LONG")
    end = fh.seek(0, os.SEEK_END)
    offset = end + end % 2  # IFDs start on a word boundary
    fh.write(b"\0" * (offset - end) + _encode_ifd(entries, offset))
    fh.seek(ifd0 + 2 + 12 * found[0])
    fh.write(struct.pack("<HHII", _EXIF_IFD, _LONG, 1, offset))


def write_dng(
    path: str | os.PathLike[str],
    mosaic: np.ndarray,
    *,
    cfa_pattern: str = "RGGB",
    black_level: float | Sequence[Sequence[float]] | np.ndarray = 0,
    white_level: int = 65535,
    exposure_s: float | None = None,
    iso: float | None = None,
    f_number: float | None = None,
    make: str = "gonio",
    model: str = "SimCam",
    as_shot_neutral: Sequence[float] = (1.0, 1.0, 1.0),
    color_matrix: Sequence[float] | np.ndarray | None = None,
    datetime: _dt.datetime | str | None = None,
    active_area: tuple[int, int, int, int] | None = None,
    masked_areas: Sequence[tuple[int, int, int, int]] = (),
    fsync: bool = False,
) -> Path:
    """Write a uint16 Bayer mosaic as an uncompressed DNG.

    Parameters
    ----------
    path:
        Output file (overwritten). Writing to a temporary name and renaming is the caller's job.
    mosaic:
        Raw samples (H×W, uint16, DN), including any masked border; at least
        :data:`MIN_SIZE_PX` on each side (LibRaw refuses smaller images).
    cfa_pattern:
        2×2 colours of the active area's top-left corner, row by row (one of :data:`CFA_PATTERNS`).
    black_level:
        Black level in whole DN (LibRaw truncates fractions): a scalar, or 2×2 per CFA position
        (same layout as ``cfa_pattern``).
    white_level:
        Saturation level in DN (e.g. 2¹⁴ − 1 for a 14-bit sensor).
    exposure_s, iso, f_number:
        Capture metadata in seconds, ISO arithmetic speed (1–65535), f-number; written to the
        EXIF IFD, omitted when None.
    make, model:
        Camera make and model (also form ``UniqueCameraModel``).
    as_shot_neutral:
        Camera neutral (R, G, B), the inverse of the white-balance multipliers.
    color_matrix:
        ``ColorMatrix1`` (XYZ → camera, 3×3 row-major); identity when None.
    datetime:
        Capture time (``DateTime``, EXIF ``DateTimeOriginal``); the current time when None.
        A string must read ``YYYY:MM:DD HH:MM:SS``.
    active_area:
        ``(top, left, bottom, right)`` of the visible area in the mosaic; whole mosaic when None.
    masked_areas:
        ``(top, left, bottom, right)`` rectangles of optical-black pixels (at most 8).
    fsync:
        Flush the file to disk before returning.

    Returns
    -------
    Path
        The written path.
    """
    mosaic = _check_mosaic(mosaic, cfa_pattern)
    unique = f"{make} {model}"
    tags: list[Tag] = [
        (_MAKE, "s", 0, make, True),
        (_MODEL, "s", 0, model, True),
        (_DNG_VERSION, "B", 4, (1, 4, 0, 0), True),
        (_DNG_BACKWARD_VERSION, "B", 4, (1, 1, 0, 0), True),
        (_UNIQUE_CAMERA_MODEL, "s", len(unique) + 1, unique, True),
        (_CFA_REPEAT_PATTERN_DIM, "H", 2, (2, 2), True),
        (_CFA_PATTERN, "B", 4, tuple(_CFA_CODE[c] for c in cfa_pattern), True),
        (_CFA_PLANE_COLOR, "B", 3, (0, 1, 2), True),
        *_level_tags(black_level, white_level, as_shot_neutral, color_matrix),
        *_area_tags(mosaic.shape, active_area, masked_areas),
        (_EXIF_PLACEHOLDER, "I", 1, 0, True),  # becomes ExifIFD in _append_exif_ifd
    ]
    stamp = _stamp(datetime)
    exif = _exif_entries(exposure_s, f_number, iso, stamp)
    return _write_file(Path(path), mosaic, tags, stamp, exif, fsync)


def _write_file(
    path: Path, mosaic: np.ndarray, tags: list[Tag], stamp: str, exif: list[ExifEntry], fsync: bool
) -> Path:
    """IFD0 and the strip through tifffile, then the EXIF IFD; optionally fsync'ed."""
    with open(path, "w+b") as fh:
        with tifffile.TiffWriter(fh, byteorder="<", bigtiff=False) as tw:
            tw.write(mosaic, photometric=_PHOTOMETRIC_CFA, subfiletype=0, metadata=None,
                     software="gonio", datetime=stamp, extratags=tags)
        _append_exif_ifd(fh, exif)
        if fsync:
            fh.flush()
            os.fsync(fh.fileno())
    return path
