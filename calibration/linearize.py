"""Turn a :class:`~calibration.raw.RawFrame` into linear RGB proportional to radiance.

Per 2×2 CFA cell (superpixel), :func:`linearize`

1. masks the cell if any of its four pixels is saturated (raw − black ≥ ``saturation`` ×
   (white − black); default 0.99, so pixels a little below a noisy clipping level count too),
   or is flagged in ``bad_pixels``;
2. subtracts the black level per CFA position (or a master ``dark`` frame, which replaces it);
3. divides by a ``flat`` field (per pixel or per superpixel), if given;
4. forms R, the mean of the two greens, and B;
5. scales by ``1 / exposure_s`` (DN/s) and optionally by ``100 / ISO`` and ``f_number²``.

Convention: with both normalisations the value is ``DN · N² / (t · ISO/100)``, proportional
to scene radiance independently of exposure time, ISO and aperture (raw DN ∝ L · t · ISO /
N²). Masked cells are NaN in ``rgb`` and False in ``valid``.

With a :class:`NoiseModel` (conversion gain e⁻/DN and read noise DN per colour), each
superpixel also gets a variance: per pixel ``max(s, 0) / g + σ_r²`` (``s`` the black-subtracted
signal in DN, dark current included), divided by flat², averaged over the greens (÷ 4 for the
pair), times the scale².
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calibration import recycling
from calibration.linearize_kernel import linearize_cells
from calibration.raw import RawFrame
from drivers.errors import CalibrationError


@dataclass(frozen=True)
class NoiseModel:
    """Sensor noise at one ISO: variance (DN²) = signal (DN) / gain + read_noise².

    Attributes
    ----------
    gain_e_per_dn:
        Conversion gain, e⁻/DN: one value or (R, G, B).
    read_noise_dn:
        Read noise including black-level noise, DN rms: one value or (R, G, B).
    iso:
        ISO at which the model holds; None = any (frames at another ISO are refused).
    """

    gain_e_per_dn: float | Sequence[float]
    read_noise_dn: float | Sequence[float]
    iso: float | None = None

    def per_colour(self) -> tuple[np.ndarray, np.ndarray]:
        """Gain (e⁻/DN) and read noise (DN) as arrays of 3 (R, G, B)."""
        gain = np.broadcast_to(np.asarray(self.gain_e_per_dn, dtype=np.float64), (3,)).copy()
        read = np.broadcast_to(np.asarray(self.read_noise_dn, dtype=np.float64), (3,)).copy()
        if np.any(gain <= 0) or np.any(read < 0):
            raise CalibrationError(
                f"noise model needs gain > 0 e⁻/DN and read noise ≥ 0 DN, got {gain} and {read}"
            )
        return gain, read


@dataclass(frozen=True, eq=False)
class LinearImage:
    """Linear RGB per superpixel.

    Attributes
    ----------
    rgb:
        (H/2)×(W/2)×3 float32 in ``units`` (computed in float64; float32's 7 digits lie far
        below any frame's noise and halve the memory traffic); NaN where not ``valid``.
    valid:
        (H/2)×(W/2) bool: no saturated or bad pixel in the cell.
    variance:
        Variance of ``rgb`` (units², float32), same shape, when a noise model was given; else
        None.
    units:
        ``"DN/s"``, optionally ``"at ISO 100"`` and ``"· f²"`` (see module docstring).
    scale:
        Factor applied to black-subtracted DN to get ``rgb``.
    exposure_s, iso, f_number:
        Capture metadata used (None where unknown and not needed).
    path:
        Source file.
    """

    rgb: np.ndarray
    valid: np.ndarray
    variance: np.ndarray | None
    units: str
    scale: float
    exposure_s: float
    iso: float | None
    f_number: float | None
    path: Path | None = None


def linearize(
    frame: RawFrame,
    *,
    dark: np.ndarray | None = None,
    flat: np.ndarray | None = None,
    bad_pixels: np.ndarray | None = None,
    noise: NoiseModel | None = None,
    normalize_iso: bool = False,
    normalize_f_number: bool = False,
    saturation: float = 0.99,
    exposure_s: float | None = None,
) -> LinearImage:
    """Black-subtract, mask, flat-field, superpixel and scale a RAW frame.

    Parameters
    ----------
    frame:
        The loaded RAW frame.
    dark:
        Master dark (H×W, DN, black level included) for this exposure and ISO; replaces the
        per-channel black level.
    flat:
        Flat field normalised to mean 1 per channel: H×W per pixel or (H/2)×(W/2)×3.
    bad_pixels:
        True where a pixel (H×W) or superpixel ((H/2)×(W/2)) must not be used.
    noise:
        Noise model; when given, ``variance`` is computed.
    normalize_iso, normalize_f_number:
        Also scale by 100 / ISO and by f-number² (both must be known).
    saturation:
        Fraction of (white − black) from which a pixel counts as saturated (0 < s ≤ 1).
    exposure_s:
        Overrides the file's exposure time, s.

    Raises
    ------
    CalibrationError
        Missing exposure/ISO/f-number metadata, or calibration data of the wrong shape.
    """
    t = _exposure_time_s(frame, exposure_s)
    if not 0 < saturation <= 1:
        raise CalibrationError(f"saturation fraction must be in (0, 1], got {saturation}")
    scale, units = _scale_and_units(frame, t, normalize_iso, normalize_f_number)
    rgb, valid, variance = _run_kernel(frame, dark, flat, bad_pixels, noise, saturation, scale)
    return LinearImage(
        rgb=rgb,
        valid=valid,
        variance=variance,
        units=units,
        scale=scale,
        exposure_s=float(t),
        iso=frame.iso,
        f_number=frame.f_number,
        path=frame.path,
    )


def _exposure_time_s(frame: RawFrame, exposure_s: float | None) -> float:
    """The exposure time to normalise by, s: ``exposure_s`` if given, else the file's."""
    t = exposure_s if exposure_s is not None else frame.exposure_s
    if t is None or not (math.isfinite(t) and t > 0):
        raise CalibrationError(
            f"{frame.path}: exposure time unknown or not positive ({t}); pass exposure_s explicitly"
        )
    return t


def _scale_and_units(
    frame: RawFrame, exposure_s: float, normalize_iso: bool, normalize_f_number: bool
) -> tuple[float, str]:
    """Factor from black-subtracted DN to output units, and the units' name."""
    scale = 1.0 / exposure_s
    units = "DN/s"
    if normalize_iso:
        if frame.iso is None:
            raise CalibrationError(f"{frame.path}: ISO unknown, cannot normalise by ISO/100")
        scale *= 100.0 / frame.iso
        units += " at ISO 100"
    if normalize_f_number:
        if frame.f_number is None:
            raise CalibrationError(f"{frame.path}: f-number unknown, cannot normalise by f-number²")
        scale *= frame.f_number**2
        units += " · f²"
    return scale, units


def _check_dark(frame: RawFrame, dark: np.ndarray | None) -> None:
    """Refuse a master dark whose size is not the frame's."""
    mosaic = frame.mosaic
    if dark is not None and dark.shape != mosaic.shape:
        raise CalibrationError(
            f"{frame.path}: master dark is {dark.shape[0]}×{dark.shape[1]} px but the frame is "
            f"{mosaic.shape[0]}×{mosaic.shape[1]}; use a dark taken with this camera"
        )


def _flat_is_per_pixel(frame: RawFrame, flat: np.ndarray | None) -> bool:
    """True for an H×W flat, False for a superpixel one (or none); refuses other shapes."""
    mosaic = frame.mosaic
    hh, ww = mosaic.shape[0] // 2, mosaic.shape[1] // 2
    flat_per_pixel = flat is not None and flat.shape == mosaic.shape
    if flat is not None and not flat_per_pixel and flat.shape != (hh, ww, 3):
        raise CalibrationError(
            f"{frame.path}: flat field shape {flat.shape} fits neither the mosaic {mosaic.shape} "
            f"nor its superpixels {(hh, ww, 3)}"
        )
    return flat_per_pixel


def _bad_is_per_pixel(frame: RawFrame, bad_pixels: np.ndarray | None) -> bool:
    """True for an H×W bad-pixel map, False for a superpixel one (or none); refuses others."""
    mosaic = frame.mosaic
    hh, ww = mosaic.shape[0] // 2, mosaic.shape[1] // 2
    bad_per_pixel = bad_pixels is not None and bad_pixels.shape == mosaic.shape
    if bad_pixels is not None and not bad_per_pixel and bad_pixels.shape != (hh, ww):
        raise CalibrationError(
            f"{frame.path}: bad-pixel map shape {bad_pixels.shape} fits neither the mosaic "
            f"{mosaic.shape} nor its superpixels {(hh, ww)}"
        )
    return bad_per_pixel


def _noise_arrays(
    frame: RawFrame, noise: NoiseModel | None
) -> tuple[np.ndarray, np.ndarray] | None:
    """Gain (e⁻/DN) and read noise (DN) per colour, or None; refuses a model for another ISO."""
    if noise is None:
        return None
    if noise.iso is not None and frame.iso is not None and noise.iso != frame.iso:
        raise CalibrationError(
            f"{frame.path}: noise model is for ISO {noise.iso:g} but the frame is ISO "
            f"{frame.iso:g}; measure a noise model at this ISO"
        )
    return noise.per_colour()


def _run_kernel(
    frame: RawFrame,
    dark: np.ndarray | None,
    flat: np.ndarray | None,
    bad_pixels: np.ndarray | None,
    noise: NoiseModel | None,
    saturation: float,
    scale: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Check the calibration data (shapes, then the noise model's ISO), then run the compiled
    pass (:func:`calibration.linearize_kernel.linearize_cells`): rgb, valid, variance."""
    mosaic = frame.mosaic
    hh, ww = mosaic.shape[0] // 2, mosaic.shape[1] // 2
    _check_dark(frame, dark)
    flat_per_pixel = _flat_is_per_pixel(frame, flat)
    bad_per_pixel = _bad_is_per_pixel(frame, bad_pixels)
    noise_arrays = _noise_arrays(frame, noise)
    black = frame.black_per_position.astype(np.float32)
    threshold = (frame.black_per_position
                 + saturation * (frame.white_per_position - frame.black_per_position)
                 ).astype(np.float32)
    red_at = divmod(frame.cfa_pattern.index("R"), 2)  # a Bayer layout (the loader checks)
    gain, read = noise_arrays if noise_arrays is not None else (None, None)
    rgb = recycling.empty((hh, ww, 3), np.float32)  # an earlier frame's memory: no page faults
    valid = recycling.empty((hh, ww), bool)
    variance = recycling.empty((hh, ww, 3), np.float32) if noise_arrays is not None else None
    bad = None if bad_pixels is None else bad_pixels.astype(bool, copy=False)
    linearize_cells(
        mosaic, red_at, black.astype(np.float64), threshold.astype(np.float64), dark,
        flat if flat_per_pixel else None,
        flat if flat is not None and not flat_per_pixel else None,
        bad if bad_per_pixel else None,
        bad if bad is not None and not bad_per_pixel else None,
        gain, read, float(scale), rgb, valid, variance)
    return rgb, valid, variance


@dataclass(frozen=True)
class Roi:
    """A rectangle of superpixels: columns ``x … x + width − 1``, rows ``y … y + height − 1``."""

    x: int
    y: int
    width: int
    height: int


def roi_mean(
    image: LinearImage, roi: Roi | tuple[int, int, int, int]
) -> tuple[np.ndarray, np.ndarray, int]:
    """Mean RGB over the valid superpixels of a rectangle.

    Parameters
    ----------
    image:
        A linearized image.
    roi:
        :class:`Roi` or ``(x, y, width, height)`` in superpixels; must lie inside the image.

    Returns
    -------
    mean_rgb:
        (3,) mean in ``image.units``; NaN if no valid superpixel.
    var_of_mean_rgb:
        (3,) variance of that mean: from the noise model (Σ var / n²) when the image has a
        variance, else the scatter (sample variance / n; NaN below 2 samples).
    n_valid:
        Number of valid superpixels used.
    """
    x, y, w, h = (int(v) for v in (roi if isinstance(roi, tuple) else
                                   (roi.x, roi.y, roi.width, roi.height)))
    rows, cols = image.valid.shape
    if w < 1 or h < 1 or x < 0 or y < 0 or x + w > cols or y + h > rows:
        raise CalibrationError(
            f"region of interest x={x}, y={y}, {w}×{h} superpixels lies outside the "
            f"{cols}×{rows} image; fix the ROI in the rig file"
        )
    valid = image.valid[y : y + h, x : x + w]
    n = int(np.count_nonzero(valid))
    if n == 0:
        nan = np.full(3, np.nan)
        return nan, nan.copy(), 0
    values = image.rgb[y : y + h, x : x + w][valid]
    mean = values.mean(axis=0)
    if image.variance is not None:
        var_of_mean = image.variance[y : y + h, x : x + w][valid].sum(axis=0) / n**2
    elif n > 1:
        var_of_mean = values.var(axis=0, ddof=1) / n
    else:
        var_of_mean = np.full(3, np.nan)
    return mean, var_of_mean, n
