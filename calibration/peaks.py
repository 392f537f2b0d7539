"""Locating a peak in a scan: where a signal is largest along one axis, with its 1σ.

The geometric calibration scans an axis across a mirror's specular peak; near its top the
logarithm of the signal is a parabola, ``ln S ≈ c − (x − x₀)² / (2 w²)``, whose vertex is the
peak (deg) and whose curvature gives the peak's width ``w`` (deg). :func:`fit_peak` fits it by
least squares to the points within :data:`TOP_FRACTION` of the maximum, weighting each by its
signal's relative uncertainty, and scales the vertex's uncertainty by the fit's scatter (so a
rig's position noise, which moves the points sideways, shows in it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from drivers.errors import CalibrationError

TOP_FRACTION = 0.45
"""Points above this fraction of the scan's maximum enter the vertex fit."""
MIN_POINTS = 5


@dataclass(frozen=True)
class Peak:
    """A fitted peak: its position, 1σ and width (deg), and how many points fixed it."""

    centre_deg: float
    sigma_deg: float
    width_deg: float
    points: int


def fit_peak(x_deg: np.ndarray, signal: np.ndarray, rel_sigma: np.ndarray | float = 1e-3,
             *, what: str = "scan") -> Peak:
    """The peak of ``signal`` (> 0) along ``x_deg``; ``rel_sigma``: each point's relative
    uncertainty. Raises CalibrationError naming ``what`` when the scan shows no peak (its
    maximum at an end, or too few points near the top)."""
    x = np.asarray(x_deg, float)
    s = np.asarray(signal, float)
    order = np.argsort(x)
    x, s = x[order], s[order]
    rel = np.broadcast_to(np.asarray(rel_sigma, float), s.shape)[order]
    k = int(np.argmax(s))
    if not np.isfinite(s[k]) or s[k] <= 0:
        raise CalibrationError(f"{what}: no signal: check the target and the exposure")
    if k in (0, len(s) - 1):
        raise CalibrationError(f"{what}: the signal is largest at the scan's end ({x[k]:.2f}°): "
                               "the peak lies outside the scanned range; check the target and "
                               "the axes' zero ticks")
    top = (s >= TOP_FRACTION * s[k]) & (s > 0)
    if top.sum() < MIN_POINTS:
        top = np.zeros_like(top)
        top[max(k - 2, 0):k + 3] = True
    xt, yt = x[top], np.log(s[top])
    wt = 1.0 / np.maximum(rel[top], 1e-9)
    x0 = float(x[k])
    a = np.column_stack([np.ones_like(xt), xt - x0, (xt - x0) ** 2]) * wt[:, None]
    coef, *_ = np.linalg.lstsq(a, yt * wt, rcond=None)
    c2 = float(coef[2])
    if c2 >= 0:
        raise CalibrationError(f"{what}: the signal has no maximum near {x0:.2f}° (flat or "
                               "saturated): check the exposure")
    centre = x0 - coef[1] / (2.0 * c2)
    dof = max(int(top.sum()) - 3, 1)
    resid = a @ coef - yt * wt
    scale = max(float(resid @ resid) / dof, 1.0)
    cov = np.linalg.pinv(a.T @ a) * scale
    grad = np.array([0.0, -1.0 / (2 * c2), coef[1] / (2 * c2**2)])
    sigma = math.sqrt(max(float(grad @ cov @ grad), 0.0))
    return Peak(float(centre), sigma, math.sqrt(-1.0 / (2.0 * c2)), int(top.sum()))
