"""The compiled pass behind :func:`calibration.linearize.linearize`: one read of the mosaic
(LibRaw's own uint16 buffer, or any array) per superpixel, writing RGB, validity and variance.

Per superpixel (2 × 2 Bayer cell) and pixel: the cell is invalid if the pixel reaches its
saturation threshold or is on a per-pixel bad map; the signal is the raw value minus the black
level (or minus a master dark); the variance ``max(s, 0)/g + σ_r²`` is taken on the
black-subtracted signal (the dark current's shot noise counts); a per-pixel flat divides both
(signal by f, variance by f²), and a zero or negative flat makes the cell invalid. R, the mean
of the two greens and B are scaled and divided by a per-superpixel flat; invalid cells are NaN.

The Bayer layout is given by the red pixel's place (``red_at``): blue is diagonal to it and
the greens fill the other two places, so the loop is straight-line for all four layouts.
Optional inputs are passed as arrays of the right rank with size 0 (see :func:`absent`).
"""

from __future__ import annotations

import math

import numba
import numpy as np


def absent(ndim: int, dtype: type = np.float32) -> np.ndarray:
    """The placeholder for an optional input of rank ``ndim``: an empty array."""
    return np.zeros((0,) * ndim, dtype=dtype)


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def linearize_cells(mosaic: np.ndarray, red_at: tuple[int, int], black: np.ndarray,
                    threshold: np.ndarray, dark: np.ndarray, flat_px: np.ndarray,
                    flat_sp: np.ndarray, bad_px: np.ndarray, bad_sp: np.ndarray,
                    gain: np.ndarray, read: np.ndarray, scale: float,
                    rgb: np.ndarray, valid: np.ndarray, variance: np.ndarray) -> None:
    """Fill ``rgb`` (h, w, 3), ``valid`` (h, w) and, when ``gain`` (e⁻/DN per colour) has 3
    entries, ``variance``. ``black`` and ``threshold``: (2, 2) DN per CFA position."""
    h, w = valid.shape
    noise = gain.shape[0] == 3
    use_dark, use_flat_px = dark.shape[0] > 0, flat_px.shape[0] > 0
    use_flat_sp, use_bad_px, use_bad_sp = flat_sp.shape[0] > 0, bad_px.shape[0] > 0, bad_sp.shape[0] > 0
    ri, rj = red_at
    bi, bj = 1 - ri, 1 - rj
    ig = 1.0 / gain if noise else np.zeros(3)
    rd2 = read * read if noise else np.zeros(3)
    factor = np.array([scale, 0.5 * scale, scale])
    for y in numba.prange(h):
        rr, br = 2 * y + ri, 2 * y + bi  # the red pixel's row, the blue pixel's row
        for x in range(w):
            rc, bc = 2 * x + rj, 2 * x + bj
            bad = use_bad_sp and bad_sp[y, x]
            red, v_red, bad = _cell_pixel(mosaic, rr, rc, threshold[ri, rj], black[ri, rj],
                                          dark, flat_px, bad_px, use_dark, use_flat_px,
                                          use_bad_px, ig[0], rd2[0], bad)
            g1, v_g1, bad = _cell_pixel(mosaic, rr, bc, threshold[ri, bj], black[ri, bj],
                                        dark, flat_px, bad_px, use_dark, use_flat_px,
                                        use_bad_px, ig[1], rd2[1], bad)
            g2, v_g2, bad = _cell_pixel(mosaic, br, rc, threshold[bi, rj], black[bi, rj],
                                        dark, flat_px, bad_px, use_dark, use_flat_px,
                                        use_bad_px, ig[1], rd2[1], bad)
            blue, v_blue, bad = _cell_pixel(mosaic, br, bc, threshold[bi, bj], black[bi, bj],
                                            dark, flat_px, bad_px, use_dark, use_flat_px,
                                            use_bad_px, ig[2], rd2[2], bad)
            bad = _store(rgb, variance, flat_sp, y, x, 0, red, v_red, factor[0], noise,
                         use_flat_sp, bad)
            bad = _store(rgb, variance, flat_sp, y, x, 1, g1 + g2, v_g1 + v_g2, factor[1],
                         noise, use_flat_sp, bad)
            bad = _store(rgb, variance, flat_sp, y, x, 2, blue, v_blue, factor[2], noise,
                         use_flat_sp, bad)
            valid[y, x] = not bad
            if bad:
                for k in range(3):
                    rgb[y, x, k] = math.nan
                    if noise:
                        variance[y, x, k] = math.nan


@numba.njit(cache=True, inline="always", error_model="numpy")
def _cell_pixel(mosaic: np.ndarray, r: int, c: int, threshold: float, black: float,
                dark: np.ndarray, flat_px: np.ndarray, bad_px: np.ndarray, use_dark: bool,
                use_flat: bool, use_bad: bool, inv_gain: float, read2: float,
                bad: bool) -> tuple[float, float, bool]:
    """Pixel (r, c): corrected signal (DN), variance (DN²), and ``bad`` updated."""
    raw = float(mosaic[r, c])
    bad = bad or raw >= threshold or (use_bad and bad_px[r, c])
    signal = raw - black
    var = max(signal, 0.0) * inv_gain + read2
    if use_dark:
        signal = raw - float(dark[r, c])
    if use_flat:
        f = float(flat_px[r, c])
        bad = bad or not f > 0.0
        inv_f = 1.0 / f
        signal *= inv_f
        var *= inv_f * inv_f
    return signal, var, bad


@numba.njit(cache=True, inline="always", error_model="numpy")
def _store(rgb: np.ndarray, variance: np.ndarray, flat_sp: np.ndarray, y: int, x: int, k: int,
           signal: float, var: float, factor: float, noise: bool, use_flat: bool,
           bad: bool) -> bool:
    """Write colour ``k`` of cell (y, x), scaled and flat-fielded; returns ``bad`` updated."""
    value, v = signal * factor, var * (factor * factor)
    if use_flat:
        f = float(flat_sp[y, x, k])
        bad = bad or not f > 0.0
        value /= f
        v /= f * f
    rgb[y, x, k] = value
    if noise:
        variance[y, x, k] = v
    return bad
