"""Write Bayer mosaics as real DNG files that LibRaw (rawpy) and OpenImageIO read.

The tag set is the minimum LibRaw needs to read a synthetic Bayer file correctly (see
``shared/notes/platform-facts.md``) plus the capture metadata OpenImageIO reads from IFD0:
``ExposureTime``, ``FNumber`` and ``ISOSpeedRatings`` (LibRaw does not read ISO from IFD0; gonio
reads capture metadata through OpenImageIO). Samples are stored uncompressed in 16-bit words;
the sensor's bit depth shows in the white level.

A masked border can be written around the active area: ``active_area`` becomes the DNG
``ActiveArea`` tag (LibRaw's visible area) and ``masked_areas`` the ``MaskedAreas`` tag
(optical-black rectangles). The CFA pattern is stated for the active area's top-left corner,
as DNG specifies. Note that LibRaw replaces the black level by the mean of the masked areas
when they are declared.
"""

from __future__ import annotations

import datetime as _dt
import os
from collections.abc import Sequence
from fractions import Fraction
from pathlib import Path

import numpy as np
import tifffile

CFA_PATTERNS: tuple[str, ...] = ("RGGB", "GRBG", "GBRG", "BGGR")
"""The four Bayer layouts, each the 2×2 colours of the top-left corner read row by row."""

MIN_SIZE_PX = 22
"""LibRaw refuses images (visible areas) narrower or lower than this."""

_CFA_CODE = {"R": 0, "G": 1, "B": 2}  # TIFF/EP CFAPattern colour codes

# Tag codes (TIFF/EP, EXIF and DNG 1.4).
_EXPOSURE_TIME = 33434
_F_NUMBER = 33437
_ISO_SPEED_RATINGS = 34855
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


def _rational(value: float, signed: bool = False) -> tuple[int, int]:
    frac = Fraction(float(value)).limit_denominator(1_000_000 if abs(value) < 2000 else 1000)
    if not signed and frac < 0:
        raise ValueError(f"DNG value {value} must be ≥ 0")
    return frac.numerator, frac.denominator


def _rationals(values: Sequence[float], signed: bool = False) -> tuple[int, ...]:
    return tuple(v for x in values for v in _rational(x, signed))


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
        Capture metadata in seconds, ISO arithmetic speed, f-number; omitted when None.
    make, model:
        Camera make and model (also form ``UniqueCameraModel``).
    as_shot_neutral:
        Camera neutral (R, G, B), the inverse of the white-balance multipliers.
    color_matrix:
        ``ColorMatrix1`` (XYZ → camera, 3×3 row-major); identity when None.
    datetime:
        Capture time written as ``DateTime``; the current time when None.
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
    mosaic = np.asarray(mosaic)
    if mosaic.ndim != 2 or mosaic.dtype != np.uint16:
        raise ValueError(f"mosaic must be a 2-D uint16 array, got {mosaic.dtype} {mosaic.shape}")
    if cfa_pattern not in CFA_PATTERNS:
        raise ValueError(f"cfa_pattern must be one of {', '.join(CFA_PATTERNS)}, got {cfa_pattern!r}")
    height, width = mosaic.shape
    if min(height, width) < MIN_SIZE_PX:
        raise ValueError(f"mosaic {height}×{width} px is below LibRaw's minimum of {MIN_SIZE_PX} px")
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

    black_tag = (_BLACK_LEVEL, "I", 4, tuple(int(v) for v in black.ravel()), True)
    unique = f"{make} {model}"
    tags: list[tuple[int, str, int, object, bool]] = [
        (_DNG_VERSION, "B", 4, (1, 4, 0, 0), True),
        (_DNG_BACKWARD_VERSION, "B", 4, (1, 1, 0, 0), True),
        (_UNIQUE_CAMERA_MODEL, "s", len(unique) + 1, unique, True),
        (_CFA_REPEAT_PATTERN_DIM, "H", 2, (2, 2), True),
        (_CFA_PATTERN, "B", 4, tuple(_CFA_CODE[c] for c in cfa_pattern), True),
        (_CFA_PLANE_COLOR, "B", 3, (0, 1, 2), True),
        (_BLACK_LEVEL_REPEAT_DIM, "H", 2, (2, 2), True),
        black_tag,
        (_WHITE_LEVEL, "I", 1, int(white_level), True),
        (_COLOR_MATRIX_1, "2i", 9, _rationals(matrix.ravel(), signed=True), True),
        (_CALIBRATION_ILLUMINANT_1, "H", 1, _D65, True),
        (_AS_SHOT_NEUTRAL, "2I", 3, _rationals(neutral), True),
    ]
    if exposure_s is not None:
        if not exposure_s > 0:
            raise ValueError(f"exposure_s must be > 0 s, got {exposure_s}")
        max_den = min(1_000_000_000, int(4e9 // max(1.0, float(exposure_s))))
        frac = Fraction(float(exposure_s)).limit_denominator(max_den)
        tags.append((_EXPOSURE_TIME, "2I", 1, (frac.numerator, frac.denominator), True))
    if f_number is not None:
        tags.append((_F_NUMBER, "2I", 1, _rational(f_number), True))
    if iso is not None:
        tags.append((_ISO_SPEED_RATINGS, "H", 1, int(round(iso)), True))
    if active_area is not None:
        top, left, bottom, right = (int(v) for v in active_area)
        if not (0 <= top < bottom <= height and 0 <= left < right <= width):
            raise ValueError(f"active_area {active_area} lies outside the {height}×{width} mosaic")
        if min(bottom - top, right - left) < MIN_SIZE_PX:
            raise ValueError(f"active_area {active_area} is below LibRaw's minimum of {MIN_SIZE_PX} px")
        tags.append((_ACTIVE_AREA, "I", 4, (top, left, bottom, right), True))
    if masked_areas:
        if len(masked_areas) > 8:
            raise ValueError(f"at most 8 masked areas, got {len(masked_areas)}")
        flat: list[int] = []
        for area in masked_areas:
            top, left, bottom, right = (int(v) for v in area)
            if not (0 <= top < bottom <= height and 0 <= left < right <= width):
                raise ValueError(f"masked area {area} lies outside the {height}×{width} mosaic")
            flat += [top, left, bottom, right]
        tags.append((_MASKED_AREAS, "I", len(flat), tuple(flat), True))

    if datetime is None:
        datetime = _dt.datetime.now()
    path = Path(path)
    with open(path, "wb") as fh:
        with tifffile.TiffWriter(fh) as tw:
            tw.write(
                mosaic,
                photometric=_PHOTOMETRIC_CFA,
                subfiletype=0,
                metadata=None,
                software="gonio",
                datetime=datetime,
                extratags=[*tags, (271, "s", 0, make, True), (272, "s", 0, model, True)],
            )
        if fsync:
            fh.flush()
            os.fsync(fh.fileno())
    return path
