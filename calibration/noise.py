"""Photon transfer: conversion gain and read noise per colour from pairs of flat frames.

For a pair of frames of the same uniform target at one exposure, the difference removes the
fixed pattern (PRNU, flat non-uniformity), so ``var(a − b) / 2`` is the temporal noise at the
pair's mean signal ``s`` (DN above black). A sensor follows ``var = s / g + σ_r²``; a straight
line through (s, var) over a series of exposures (a dark pair included) gives the conversion
gain ``g`` (e⁻/DN, the inverse slope) and the read noise ``σ_r`` (DN, the root of the
intercept), per colour.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from calibration.dark import check_same_settings, colour_masks
from calibration.linearize import NoiseModel
from calibration.raw import COLOURS, RawFrame
from drivers.errors import CalibrationError


@dataclass(frozen=True)
class PhotonTransfer:
    """A photon-transfer fit.

    Attributes
    ----------
    model:
        The fitted :class:`NoiseModel` (gain e⁻/DN, read noise DN, ISO).
    mean_dn, variance_dn2:
        (pairs, 3) mean signal above black (DN) and temporal variance (DN²) per colour.
    residual_rms:
        (3,) rms of the fit's relative residuals per colour.
    """

    model: NoiseModel
    mean_dn: np.ndarray
    variance_dn2: np.ndarray
    residual_rms: np.ndarray


def pair_statistics(
    a: RawFrame, b: RawFrame, roi_px: tuple[int, int, int, int] | None = None,
    *, saturation: float = 0.9,
) -> tuple[np.ndarray, np.ndarray]:
    """Mean signal above black (DN) and temporal variance (DN²) per colour of one pair.

    ``roi_px`` = (x0, y0, x1, y1) in mosaic pixels (even), None = the whole frame. Pixels above
    ``saturation`` × (white − black) in either frame are left out.
    """
    check_same_settings([a, b], "photon-transfer pair")
    ys, xs = slice(None), slice(None)
    if roi_px is not None:
        x0, y0, x1, y1 = roi_px
        ys, xs = slice(y0, y1), slice(x0, x1)
    ma, mb = a.mosaic[ys, xs].astype(np.float64), b.mosaic[ys, xs].astype(np.float64)
    h, w = ma.shape
    black = np.tile(a.black_per_position, (h // 2 + 1, w // 2 + 1))[:h, :w]
    white = np.tile(a.white_per_position, (h // 2 + 1, w // 2 + 1))[:h, :w]
    ok = (ma < black + saturation * (white - black)) & (mb < black + saturation * (white - black))
    mean, var = np.empty(3), np.empty(3)
    for k, (colour, m) in enumerate(colour_masks(a.cfa_pattern, (h, w)).items()):
        sel = m & ok
        if np.count_nonzero(sel) < 16:
            raise CalibrationError(
                f"{a.path}: fewer than 16 unclipped {colour} pixels in the pair; shorten the "
                "exposure or enlarge the region"
            )
        mean[k] = 0.5 * (ma[sel] + mb[sel]).mean() - black[sel].mean()
        var[k] = np.var(ma[sel] - mb[sel], ddof=1) / 2.0
    return mean, var


def photon_transfer(
    pairs: Sequence[tuple[RawFrame, RawFrame]],
    roi_px: tuple[int, int, int, int] | None = None,
) -> PhotonTransfer:
    """Fit ``var = s / g + σ_r²`` per colour over pairs at several exposures (one ISO).

    Raises
    ------
    CalibrationError
        Fewer than 3 pairs, mixed ISOs, too small a signal range, or a non-physical fit.
    """
    if len(pairs) < 3:
        raise CalibrationError(
            f"photon transfer needs ≥ 3 pairs at different exposures, got {len(pairs)}"
        )
    isos = {p[0].iso for p in pairs} | {p[1].iso for p in pairs}
    if len(isos) != 1:
        raise CalibrationError(f"photon-transfer pairs mix ISOs {sorted(map(str, isos))}; use one ISO")
    stats = [pair_statistics(a, b, roi_px) for a, b in pairs]
    mean = np.array([s[0] for s in stats])
    var = np.array([s[1] for s in stats])
    if np.ptp(mean, axis=0).min() < 10.0:
        raise CalibrationError("photon-transfer pairs span < 10 DN of signal; vary the exposure")
    gain, read, resid = np.empty(3), np.empty(3), np.empty(3)
    for k in range(3):
        # Weighted least squares: each variance estimate has a relative error ~ √(2/n).
        wts = 1.0 / var[:, k]
        slope, intercept = np.polyfit(mean[:, k], var[:, k], 1, w=wts)
        if not slope > 0:
            raise CalibrationError(
                f"photon transfer: {COLOURS[k]} variance does not grow with signal; check the "
                "target is lit and the frames are not clipped"
            )
        gain[k] = 1.0 / slope
        read[k] = float(np.sqrt(max(intercept, 0.0)))
        fit = mean[:, k] * slope + intercept
        resid[k] = float(np.sqrt(np.mean(((var[:, k] - fit) / fit) ** 2)))
    iso = pairs[0][0].iso
    return PhotonTransfer(NoiseModel(tuple(gain), tuple(read), iso), mean, var, resid)
