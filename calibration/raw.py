"""Load any LibRaw-readable Bayer RAW file (DNG, NEF, CR2, ARW, ...) for radiometry.

:func:`load_raw` returns the visible area of the mosaic with the levels the file states:

- the CFA pattern of the visible area's top-left 2×2 corner (RGGB, GRBG, GBRG or BGGR);
- black level per CFA position and per colour, as the file states it. For DNGs that declare
  ``MaskedAreas`` LibRaw replaces the stated level by the masked pixels' mean; the loader
  reads the stated ``BlackLevel`` tag instead and uses the masked pixels as a cross-check;
- white level per channel as the file states it (LibRaw's per-channel linear limit where the
  camera has one), read before any processing, so never LibRaw's data-adjusted maximum;
- a cross-check of the black level against optical-black pixels where the sensor has them
  (DNG ``MaskedAreas``; otherwise dark left/top margins of other formats), with a
  :class:`BlackLevelWarning` when they disagree by more than 2 DN;
- camera white balance as metadata only (as stored: not normalised to green = 1);
- exposure time, ISO and f-number through OpenImageIO, falling back to LibRaw's values.

Non-Bayer files (stacked scanners, X-Trans, foveon, 4-colour CFAs) and corrupt files raise
:class:`drivers.errors.RawFormatError`.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

from drivers.errors import RawFormatError

if TYPE_CHECKING:
    import rawpy
    import tifffile

T = TypeVar("T")

COLOURS: tuple[str, str, str] = ("R", "G", "B")
BLACK_TOLERANCE_DN = 2.0
"""Largest accepted gap between the stated black level and the optical-black pixels, DN."""

_DNG_VERSION = 50706
_BLACK_LEVEL_REPEAT_DIM = 50713
_BLACK_LEVEL = 50714
_ACTIVE_AREA = 50829
_MASKED_AREAS = 50830
_PHOTOMETRIC_CFA = 32803
_MARGIN_GUARD_PX = 2  # margin pixels next to the active area, skipped (light leaks in)
_MIN_MARGIN_PX = 4  # narrower margins are not used as optical black
_DARK_FRACTION = 0.05  # a margin counts as optical black only if this dark (of white − black)


class BlackLevelWarning(UserWarning):
    """The stated black level disagrees with the sensor's optical-black pixels."""


@dataclass(frozen=True, eq=False)
class RawFrame:
    """One Bayer RAW frame, visible area only, with the levels its file states.

    Attributes
    ----------
    path:
        The file read.
    mosaic:
        Raw values of the visible area (H×W float32, DN, black level included).
    cfa_pattern:
        Colours of the visible area's top-left 2×2, row by row (e.g. ``"RGGB"``).
    black_per_position:
        Black level of each 2×2 CFA position (2×2 float64, DN), same layout as ``cfa_pattern``.
    white_per_position:
        Saturation level of each 2×2 CFA position (2×2 float64, DN).
    optical_black:
        Mean of the optical-black pixels per colour ``{"R", "G", "B"}`` (DN), None where the
        sensor has none.
    camera_whitebalance:
        As-shot multipliers ``{"R", "G", "B", "G2"}`` as stored (metadata only, not applied).
    exposure_s, iso, f_number:
        Capture metadata (s, ISO speed, f-number); None when unknown.
    make, model:
        Camera make and model; None when unknown.
    raw_shape:
        Full sensor size (rows, columns) including masked margins, px.
    visible_origin:
        (top, left) of the visible area in the full sensor, px.
    """

    path: Path
    mosaic: np.ndarray
    cfa_pattern: str
    black_per_position: np.ndarray
    white_per_position: np.ndarray
    optical_black: dict[str, float] | None
    camera_whitebalance: dict[str, float]
    exposure_s: float | None
    iso: float | None
    f_number: float | None
    make: str | None
    model: str | None
    raw_shape: tuple[int, int]
    visible_origin: tuple[int, int]

    @property
    def height(self) -> int:
        """Visible rows, px."""
        return int(self.mosaic.shape[0])

    @property
    def width(self) -> int:
        """Visible columns, px."""
        return int(self.mosaic.shape[1])

    def positions(self, colour: str) -> list[tuple[int, int]]:
        """The (row, column) CFA positions of ``colour`` ("R", "G" or "B") in the 2×2 cell."""
        return [divmod(i, 2) for i, c in enumerate(self.cfa_pattern) if c == colour]

    @property
    def black_per_colour(self) -> dict[str, float]:
        """Mean black level of each colour, DN."""
        return _per_colour(self.black_per_position, self.cfa_pattern)

    @property
    def white_per_colour(self) -> dict[str, float]:
        """Lowest saturation level of each colour, DN."""
        return {
            c: float(min(self.white_per_position[p] for p in self.positions(c))) for c in COLOURS
        }

    @property
    def white_level(self) -> float:
        """Lowest saturation level over all channels, DN."""
        return float(self.white_per_position.min())


def _per_colour(per_position: np.ndarray, pattern: str) -> dict[str, float]:
    return {
        c: float(np.mean([per_position[divmod(i, 2)] for i, p in enumerate(pattern) if p == c]))
        for c in COLOURS
    }


def _fail(path: Path, why: str) -> RawFormatError:
    return RawFormatError(f"{path}: {why}")


def _bayer_layout(raw: rawpy.RawPy, path: Path) -> tuple[str, np.ndarray]:
    """CFA pattern string and the 2×2 colour indices; RawFormatError if not an RGB Bayer."""
    import rawpy

    fix = "gonio reads Bayer RAW files only"
    if raw.raw_type != rawpy.RawType.Flat:
        raise _fail(path, f"not a Bayer mosaic (LibRaw raw type {raw.raw_type.name}: a stacked "
                          f"or linear sensor such as a film scanner or Foveon); {fix}")
    pattern = raw.raw_pattern
    if pattern is None:
        raise _fail(path, f"not a colour-filter-array image (no CFA pattern); {fix}")
    pattern = np.asarray(pattern)
    desc = raw.color_desc.decode("ascii", "replace")
    if pattern.shape != (2, 2):
        kind = "X-Trans" if pattern.shape == (6, 6) else f"{pattern.shape[0]}×{pattern.shape[1]}"
        raise _fail(path, f"{kind} colour filter array, not a 2×2 Bayer; {fix}")
    letters = "".join(desc[int(i)] if int(i) < len(desc) else "?" for i in pattern.ravel())
    if sorted(letters) != ["B", "G", "G", "R"]:
        raise _fail(path, f"CFA colours {letters!r} (from {desc!r}) are not R, G, G, B; {fix}")
    return letters, pattern


def _tag_values(tag: tifffile.TiffTag) -> np.ndarray:
    values = np.atleast_1d(np.asarray(tag.value, dtype=np.float64)).ravel()
    if tag.dtype in (5, 10):  # (S)RATIONAL: numerator, denominator pairs
        pairs = values.reshape(-1, 2)
        values = pairs[:, 0] / pairs[:, 1]
    return values


@contextmanager
def open_tiff_quietly(path: str | os.PathLike[str]) -> Iterator[tifffile.TiffFile]:
    """A TIFF (DNG) file opened with tifffile, its own log lines about damage silenced (gonio
    reports the damage in one line of its own)."""
    import tifffile

    quiet = logging.getLogger("tifffile")
    was, quiet.disabled = quiet.disabled, True
    try:
        with tifffile.TiffFile(path) as tif:
            yield tif
    finally:
        quiet.disabled = was


def _dng_tags(path: Path) -> dict[int, np.ndarray] | None:
    """Black-level and area tags of a DNG's CFA image IFD; None if the file is not a DNG."""
    try:
        with open_tiff_quietly(path) as tif:
            first = tif.pages.first
            if _DNG_VERSION not in first.tags:
                return None
            for ifd in [first, *(getattr(first, "pages", None) or [])]:
                if ifd.tags.valueof(262) == _PHOTOMETRIC_CFA:
                    return {
                        code: _tag_values(ifd.tags[code])
                        for code in (_BLACK_LEVEL_REPEAT_DIM, _BLACK_LEVEL, _ACTIVE_AREA,
                                     _MASKED_AREAS)
                        if code in ifd.tags
                    }
            return {}
    except Exception:  # not a TIFF container (CR3, RAF, ...): not a DNG either
        return None


def _dng_stated_black(tags: dict[int, np.ndarray], origin: tuple[int, int]) -> np.ndarray | None:
    """Black per visible CFA position from the DNG ``BlackLevel`` tag (deltas ignored)."""
    if _BLACK_LEVEL not in tags:
        return None
    values = tags[_BLACK_LEVEL]
    rows, cols = (int(v) for v in tags.get(_BLACK_LEVEL_REPEAT_DIM, (1, 1)))
    if rows < 1 or cols < 1 or values.size != rows * cols:
        return None
    grid = values.reshape(rows, cols)
    aa_top, aa_left = (int(v) for v in tags.get(_ACTIVE_AREA, (0, 0, 0, 0))[:2])
    out = np.empty((2, 2))
    for i in range(2):
        for j in range(2):
            out[i, j] = grid[(origin[0] + i - aa_top) % rows, (origin[1] + j - aa_left) % cols]
    return out


def optical_black_means(
    raw: np.ndarray,
    regions: list[tuple[int, int, int, int]],
    pattern: str,
    origin: tuple[int, int],
) -> dict[str, float] | None:
    """Mean raw value per colour over ``(top, left, bottom, right)`` regions of the full mosaic.

    ``pattern`` is the CFA of the visible area whose top-left pixel sits at ``origin`` (row,
    column) of ``raw``. Returns None when some colour has no pixel in the regions.
    """
    sums = dict.fromkeys(COLOURS, 0.0)
    counts = dict.fromkeys(COLOURS, 0)
    for top, left, bottom, right in regions:
        for k, colour in enumerate(pattern):
            i, j = divmod(k, 2)
            r0 = top + (origin[0] + i - top) % 2
            c0 = left + (origin[1] + j - left) % 2
            block = raw[r0:bottom:2, c0:right:2]
            sums[colour] += float(block.sum(dtype=np.float64))
            counts[colour] += block.size
    if min(counts.values()) == 0:
        return None
    return {c: sums[c] / counts[c] for c in COLOURS}


def _margin_regions(
    raw_shape: tuple[int, int], origin: tuple[int, int], size: tuple[int, int]
) -> list[tuple[int, int, int, int]]:
    """Left and top margins wide enough to hold optical black, minus a guard band."""
    top, left = origin
    height, width = size
    regions = []
    if left - _MARGIN_GUARD_PX >= _MIN_MARGIN_PX:
        regions.append((top, 0, top + height, left - _MARGIN_GUARD_PX))
    if top - _MARGIN_GUARD_PX >= _MIN_MARGIN_PX:
        regions.append((0, left, top - _MARGIN_GUARD_PX, left + width))
    return regions


@dataclass(frozen=True, eq=False)
class _Decoded:
    """What :func:`_decode` reads of an open file (``mosaic``: a view of LibRaw's buffer)."""

    pattern: str
    indices: np.ndarray
    origin: tuple[int, int]
    raw_shape: tuple[int, int]
    mosaic: np.ndarray
    black_by_index: list[float]
    white_by_index: Any
    white_scalar: float
    wb: list[float]
    other: Any
    optical: dict[str, float] | None
    ob_gate: bool
    """True when ``optical`` comes from plain margins and must be dark to count."""


def load_raw(path: str | os.PathLike[str]) -> RawFrame:
    """Read a Bayer RAW file: visible mosaic (copied out as float32 DN), CFA pattern, levels
    and capture metadata.

    Raises
    ------
    RawFormatError
        The file is missing, corrupt, unsupported, or not an RGB Bayer mosaic.

    Warns
    -----
    BlackLevelWarning
        The optical-black pixels differ from the stated black level by more than 2 DN.
    """
    return read_raw(path, _copied, stacklevel=3)


def _copied(frame: RawFrame) -> RawFrame:
    """The frame with its mosaic copied out of LibRaw's buffer, as float32 DN."""
    return dataclasses.replace(frame, mosaic=np.array(frame.mosaic, dtype=np.float32))


def read_raw(path: str | os.PathLike[str], use: Callable[[RawFrame], T], *,
             stacklevel: int = 2) -> T:
    """Decode a Bayer RAW file and return ``use(frame)``, called while LibRaw holds the file:
    ``frame.mosaic`` is LibRaw's own visible buffer (uint16 DN, read-only), valid only during
    the call, so a consumer such as :func:`calibration.linearize.linearize` reads it once with
    no copy. Errors and warnings as :func:`load_raw` (``stacklevel`` as in
    :func:`warnings.warn`, seen from here: 2 blames the caller)."""
    import rawpy

    path = Path(path)
    if not path.is_file():
        raise _fail(path, "no such RAW file; check the path")
    dng = _dng_tags(path)
    meta = _capture_metadata(path)
    try:
        with rawpy.imread(str(path)) as raw:
            d = _decode(raw, path, dng)
            frame = _frame(path, d, dng, meta, stacklevel + 2)
            return use(frame)
    except rawpy.LibRawError as exc:
        raise _decode_failure(path, exc) from None
    except MemoryError:
        raise _fail(path, "RAW file too large to load into memory") from None


def _frame(path: Path, d: _Decoded, dng: dict[int, np.ndarray] | None, meta: dict[str, Any],
           stacklevel: int) -> RawFrame:
    """The :class:`RawFrame` of a decoded file, its levels checked."""
    black = _black_per_position(d, dng)
    white = _white_per_position(d)
    if np.any(white <= black):
        raise _fail(path, f"white level {white.min():g} DN is not above black level "
                          f"{black.max():g} DN; the file's metadata are inconsistent")
    optical = _checked_optical_black(path, d, black, white, stacklevel)
    meta = dict(meta)
    _fill_from_libraw(meta, d.other)
    return RawFrame(
        path=path,
        mosaic=d.mosaic,
        cfa_pattern=d.pattern,
        black_per_position=black,
        white_per_position=white,
        optical_black=optical,
        camera_whitebalance=dict(zip(("R", "G", "B", "G2"), d.wb, strict=False)),
        exposure_s=meta.get("exposure_s"),
        iso=meta.get("iso"),
        f_number=meta.get("f_number"),
        make=meta.get("make"),
        model=meta.get("model"),
        raw_shape=d.raw_shape,
        visible_origin=d.origin,
    )


def _decode(raw: rawpy.RawPy, path: Path, dng: dict[int, np.ndarray] | None) -> _Decoded:
    """The layout, levels and optical-black means of an open file, and a view of its visible
    mosaic (LibRaw's buffer: valid while the file is open)."""
    pattern, indices = _bayer_layout(raw, path)
    sizes = raw.sizes
    origin = (int(sizes.top_margin), int(sizes.left_margin))
    raw_shape = (int(sizes.raw_height), int(sizes.raw_width))
    mosaic = raw.raw_image_visible
    mosaic.setflags(write=False)
    size = (int(mosaic.shape[0]), int(mosaic.shape[1]))
    ob_regions, ob_gate = _optical_black_regions(dng, raw_shape, origin, size)
    optical = (optical_black_means(raw.raw_image, ob_regions, pattern, origin)
               if ob_regions else None)
    return _Decoded(pattern, indices, origin, raw_shape, mosaic,
                    list(raw.black_level_per_channel), raw.camera_white_level_per_channel,
                    float(raw.white_level), [float(v) for v in raw.camera_whitebalance],
                    raw.other, optical, ob_gate)


def _decode_failure(path: Path, exc: Exception) -> RawFormatError:
    """The error for a file LibRaw cannot decode, with LibRaw's reason."""
    detail = exc.args[0].decode(errors="replace") if exc.args and isinstance(
        exc.args[0], bytes) else str(exc)
    return _fail(path, f"cannot decode as a RAW file ({type(exc).__name__}: {detail}); "
                       "the file is corrupt, truncated or of an unsupported kind")


def _optical_black_regions(
    dng: dict[int, np.ndarray] | None, raw_shape: tuple[int, int], origin: tuple[int, int],
    size: tuple[int, int],
) -> tuple[list[tuple[int, int, int, int]], bool]:
    """Optical-black regions of the full mosaic and whether they must be gated as dark:
    a DNG's ``MaskedAreas`` (trusted), a non-DNG's margins (gated), else none."""
    if dng is not None and _MASKED_AREAS in dng:
        flat = [int(v) for v in np.ravel(dng[_MASKED_AREAS])]
        regions = [
            tuple(flat[k : k + 4]) for k in range(0, len(flat) - 3, 4) if flat[k + 3] > 0
        ]
        return regions, False  # type: ignore[return-value]
    if dng is None:
        return _margin_regions(raw_shape, origin, size), True
    return [], False


def _black_per_position(d: _Decoded, dng: dict[int, np.ndarray] | None) -> np.ndarray:
    """Black level (DN) per visible CFA position: LibRaw's, or a masked DNG's stated tag."""
    black = np.array([[d.black_by_index[int(c)] for c in row] for row in d.indices], np.float64)
    if dng is not None and _MASKED_AREAS in dng:
        stated = _dng_stated_black(dng, d.origin)
        if stated is not None:
            black = stated
    return black


def _white_per_position(d: _Decoded) -> np.ndarray:
    """Saturation level (DN) per visible CFA position: per channel if stated, else the scalar."""
    if d.white_by_index is not None and all(w > 0 for w in d.white_by_index):
        return np.array([[float(d.white_by_index[int(c)]) for c in row] for row in d.indices])
    return np.full((2, 2), d.white_scalar)


def _checked_optical_black(
    path: Path, d: _Decoded, black: np.ndarray, white: np.ndarray, stacklevel: int
) -> dict[str, float] | None:
    """The optical-black means, dropped if a gated margin is lit; warns
    (:class:`BlackLevelWarning`, attributed to :func:`load_raw`'s caller) if they disagree
    with the stated black by more than :data:`BLACK_TOLERANCE_DN`."""
    optical = d.optical
    black_colour = _per_colour(black, d.pattern)
    if optical is not None and d.ob_gate:
        span = float(white.min() - black.max())
        if any(optical[c] > black_colour[c] + _DARK_FRACTION * span for c in COLOURS):
            optical = None  # lit or junk margin, not optical black
    if optical is not None:
        gaps = {c: optical[c] - black_colour[c] for c in COLOURS}
        if max(abs(g) for g in gaps.values()) > BLACK_TOLERANCE_DN:
            warnings.warn(
                f"{path}: optical-black pixels read "
                + ", ".join(f"{c} {optical[c]:.1f}" for c in COLOURS)
                + " DN but the file states black "
                + ", ".join(f"{c} {black_colour[c]:.1f}" for c in COLOURS)
                + f" DN (> {BLACK_TOLERANCE_DN:g} DN apart); subtract a master dark frame",
                BlackLevelWarning,
                stacklevel=stacklevel,  # the caller of load_raw or read_raw
            )
    return optical


def _fill_from_libraw(meta: dict[str, Any], other: Any) -> None:
    """Fill exposure (s), ISO and f-number that OpenImageIO did not find from LibRaw's values."""
    if meta.get("exposure_s") is None and other.shutter_speed > 0:
        meta["exposure_s"] = float(other.shutter_speed)
    if meta.get("iso") is None and other.iso_speed > 0:
        meta["iso"] = float(other.iso_speed)
    if meta.get("f_number") is None and other.aperture > 0:
        meta["f_number"] = float(other.aperture)


def _positive(value: Any) -> float | None:
    """A positive finite number, shortest-printed at float32 precision (OpenImageIO's); a
    one-element tuple (how OpenImageIO returns EXIF arrays such as ISOSpeedRatings) is unwrapped."""
    if isinstance(value, tuple) and len(value) == 1:
        value = value[0]
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    if not (math.isfinite(number) and number > 0):
        return None
    return float(str(np.float32(number))) if isinstance(value, float) else number


def _capture_metadata(path: Path) -> dict[str, Any]:
    """Exposure (s), ISO, f-number, make and model as OpenImageIO reads them (None if absent)."""
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        oiio.geterror()  # clear the pending error message
        return {}
    try:
        spec = inp.spec()
        iso = spec.getattribute("Exif:ISOSpeedRatings")
        if iso is None:
            iso = spec.getattribute("Exif:PhotographicSensitivity")
        make = spec.getattribute("Make")
        model = spec.getattribute("Model")
        return {
            "exposure_s": _positive(spec.getattribute("ExposureTime")),
            "iso": _positive(iso),
            "f_number": _positive(spec.getattribute("FNumber")),
            "make": str(make).strip() or None if make is not None else None,
            "model": str(model).strip() or None if model is not None else None,
        }
    finally:
        inp.close()


def _plain(value: float | None) -> float | int | None:
    if value is None:
        return None
    return int(value) if float(value).is_integer() else float(value)


def inspect_raw(path: str | os.PathLike[str]) -> dict[str, Any]:
    """What the loader sees, as ``gonio inspect FILE --json`` prints it.

    Returns
    -------
    dict
        ``{"pattern", "black": {"R", "G", "B"}, "white", "width", "height", "exposure_s",
        "iso", "f_number"}``; unknown metadata are None.
    """
    frame = load_raw(path)
    return {
        "pattern": frame.cfa_pattern,
        "black": {c: _plain(v) for c, v in frame.black_per_colour.items()},
        "white": _plain(frame.white_level),
        "width": frame.width,
        "height": frame.height,
        "exposure_s": _plain(frame.exposure_s),
        "iso": _plain(frame.iso),
        "f_number": _plain(frame.f_number),
    }


def format_inspection(info: dict[str, Any]) -> str:
    """Human-readable lines for a dict from :func:`inspect_raw`."""

    def show(value: Any, unit: str = "") -> str:
        return "unknown" if value is None else f"{value:g}{unit}"

    black = info["black"]
    return "\n".join(
        [
            f"pattern    {info['pattern']}",
            f"size       {info['width']} × {info['height']} px (visible area)",
            "black      " + "  ".join(f"{c} {show(black[c])}" for c in COLOURS) + " DN",
            f"white      {show(info['white'], ' DN')}",
            f"exposure   {show(info['exposure_s'], ' s')}",
            f"ISO        {show(info['iso'])}",
            "f-number   " + ("unknown" if info["f_number"] is None else f"f/{info['f_number']:g}"),
        ]
    )
