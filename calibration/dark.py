"""Master darks and bad-pixel maps.

A master dark is the per-pixel median of ≥ :data:`MIN_DARK_FRAMES` frames taken with the lens
capped at one (exposure, ISO): the median rejects cosmic-ray hits and random telegraph spikes
that a mean would keep. It holds black level + dark current + fixed-pattern offsets (DN) and
replaces the stated black level in :func:`calibration.linearize.linearize`.

Bad pixels are outliers against their own colour's robust spread (median ± k · 1.4826 · MAD):
hot pixels in the master dark, dead or hot pixels in the flat field.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from calibration.raw import RawFrame
from drivers.errors import CalibrationError

MIN_DARK_FRAMES = 8
"""Fewest dark frames a master dark is made from."""

_ROWS_PER_BLOCK = 256  # median over the stack in row blocks: bounds the working memory


def check_same_settings(frames: Sequence[RawFrame], what: str) -> tuple[float | None, float | None]:
    """Raise unless all frames share size, exposure time and ISO; return (exposure s, ISO)."""
    first = frames[0]
    for f in frames[1:]:
        if f.mosaic.shape != first.mosaic.shape:
            raise CalibrationError(
                f"{f.path}: {what} frames differ in size ({f.mosaic.shape} vs "
                f"{first.mosaic.shape}); take them all with one camera and one crop"
            )
        same_t = (f.exposure_s is None and first.exposure_s is None) or (
            f.exposure_s is not None and first.exposure_s is not None
            and math.isclose(f.exposure_s, first.exposure_s, rel_tol=1e-6))
        if not same_t or f.iso != first.iso:
            raise CalibrationError(
                f"{f.path}: {what} frame at {f.exposure_s} s ISO {f.iso} among frames at "
                f"{first.exposure_s} s ISO {first.iso}; group frames by exposure and ISO"
            )
    return first.exposure_s, first.iso


def master_dark(frames: Sequence[RawFrame], *, min_frames: int = MIN_DARK_FRAMES) -> np.ndarray:
    """Per-pixel median of dark frames (H×W float32, DN, black level included).

    Raises
    ------
    CalibrationError
        Fewer than ``min_frames`` frames, or frames of different size, exposure or ISO.
    """
    if len(frames) < min_frames:
        raise CalibrationError(
            f"a master dark needs ≥ {min_frames} frames, got {len(frames)}; take more darks"
        )
    check_same_settings(frames, "dark")
    h, w = frames[0].mosaic.shape
    out = np.empty((h, w), dtype=np.float32)
    for a in range(0, h, _ROWS_PER_BLOCK):
        b = min(a + _ROWS_PER_BLOCK, h)
        stack = np.stack([f.mosaic[a:b] for f in frames])
        np.median(stack, axis=0, out=out[a:b])
    return out


def _robust_outliers(values: np.ndarray, pattern_mask: np.ndarray, k: float, floor: float) -> np.ndarray:
    sel = values[pattern_mask]
    med = float(np.median(sel))
    spread = max(1.4826 * float(np.median(np.abs(sel - med))), floor)
    return pattern_mask & (np.abs(values - med) > k * spread)


def colour_masks(cfa_pattern: str, shape: tuple[int, int]) -> dict[str, np.ndarray]:
    """Boolean H×W masks of the R, G and B pixels for a 2×2 ``cfa_pattern``."""
    out = {c: np.zeros(shape, dtype=bool) for c in "RGB"}
    for i, c in enumerate(cfa_pattern):
        r, col = divmod(i, 2)
        out[c][r::2, col::2] = True
    return out


def bad_pixel_map(
    cfa_pattern: str,
    *,
    dark: np.ndarray | None = None,
    flat: np.ndarray | None = None,
    dark_k: float = 8.0,
    dark_floor_dn: float = 2.0,
    flat_k: float = 8.0,
    flat_floor: float = 0.01,
) -> np.ndarray:
    """Pixels (H×W bool) that are hot in the master dark or dead/hot in the flat field.

    Parameters
    ----------
    cfa_pattern:
        The frames' 2×2 CFA pattern (outliers are judged within each colour).
    dark, flat:
        Master dark (DN) and flat field (mean 1 per colour); at least one.
    dark_k, flat_k:
        Threshold in robust standard deviations.
    dark_floor_dn, flat_floor:
        Smallest spread used (DN; relative), so a noiseless simulated sensor flags nothing
        ordinary.
    """
    if dark is None and flat is None:
        raise CalibrationError("a bad-pixel map needs a master dark, a flat field or both")
    shape = (dark if dark is not None else flat).shape
    masks = colour_masks(cfa_pattern, shape)
    bad = np.zeros(shape, dtype=bool)
    for m in masks.values():
        if dark is not None:
            bad |= _robust_outliers(dark, m, dark_k, dark_floor_dn)
        if flat is not None:
            bad |= _robust_outliers(flat, m, flat_k, flat_floor)
            bad |= m & ~(flat > 0)
    return bad
