"""Flat field: vignetting, pixel response and light non-uniformity, normalised to mean 1.

The flat is the mean of frames of a uniform target (dark- or black-subtracted), divided by the
mean of its colour, so applying it keeps each channel's overall level unchanged while removing
the relative response of every pixel. Frames must not clip anywhere: the target should fill
about half the well (averaging N frames cuts the flat's own shot noise by √N).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from calibration.dark import check_same_settings, colour_masks
from calibration.raw import RawFrame
from drivers.errors import CalibrationError


def flat_field(
    frames: Sequence[RawFrame], *, dark: np.ndarray | None = None, saturation: float = 0.99
) -> np.ndarray:
    """Flat field (H×W float32) with mean 1 over each colour's pixels.

    Parameters
    ----------
    frames:
        Frames of a uniform target, one exposure and ISO.
    dark:
        Master dark for that exposure and ISO (DN); None subtracts the stated black level.
    saturation:
        Fraction of (white − black) from which a pixel counts as clipped.

    Raises
    ------
    CalibrationError
        No frames, clipped pixels, or a colour with no signal.
    """
    if not frames:
        raise CalibrationError("a flat field needs at least one frame of a uniform target")
    check_same_settings(frames, "flat")
    first = frames[0]
    h, w = first.mosaic.shape
    black = np.tile(first.black_per_position, (h // 2, w // 2)).astype(np.float32)
    white = np.tile(first.white_per_position, (h // 2, w // 2)).astype(np.float32)
    limit = black + saturation * (white - black)
    acc = np.zeros((h, w), dtype=np.float64)
    for f in frames:
        clipped = int(np.count_nonzero(f.mosaic >= limit))
        if clipped:
            raise CalibrationError(
                f"{f.path}: {clipped} flat-field pixels are clipped; shorten the exposure so "
                "the target fills about half the well"
            )
        acc += f.mosaic
    acc /= len(frames)
    acc -= dark if dark is not None else black
    flat = np.empty((h, w), dtype=np.float32)
    for colour, m in colour_masks(first.cfa_pattern, (h, w)).items():
        mean = float(acc[m].mean())
        if not mean > 0:
            raise CalibrationError(
                f"{first.path}: the flat target gives no {colour} signal; light the target "
                "and check the lens cap is off"
            )
        flat[m] = acc[m] / mean
    return flat
