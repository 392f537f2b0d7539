"""The signal of a frame file: linearized (with a calibration bundle's corrections, if given)
and averaged over a region of interest."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from calibration.linearize import linearize, roi_mean
from calibration.raw import load_raw

if TYPE_CHECKING:
    from calibration.bundle import CalibrationBundle


def roi_signal(path: str | Path, roi: tuple[int, int, int, int],
               bundle: CalibrationBundle | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """(mean, variance of the mean, valid superpixels) over ``roi`` = (x0, y0, x1, y1)
    superpixels, end exclusive, in DN/s per channel.

    The variance is the noise model's when the bundle has one for the frame's ISO, else the
    scatter over the ROI.
    """
    frame = load_raw(path)
    image = linearize(frame) if bundle is None else bundle.linearize(frame)
    x0, y0, x1, y1 = roi
    mean, var, n = roi_mean(image, (x0, y0, x1 - x0, y1 - y0))
    return np.asarray(mean, float), np.asarray(var, float), int(n)
