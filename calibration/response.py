"""Response-curve recovery and HDR merge for cameras without RAW (8-bit JPEG/TIFF).

Debevec & Malik (SIGGRAPH 1997): a pixel value ``Z = f(E · t)`` of an unknown monotonic camera
response ``f``; with ``g = ln f⁻¹``, every sample i seen in frame j gives

    g(Z_ij) = ln E_i + ln t_j.

:func:`recover_response` solves this for ``g`` over all 256 levels and ``ln E_i`` at a few
hundred sample pixels in the least-squares sense, with a hat weight ``w(z)`` that trusts
mid-range values, a smoothness term ``λ · w(z) · g''(z)`` and ``g(128) = 0`` fixing the scale
(colours are solved independently, so each channel's scale is relative). :func:`merge_ldr`
then gives the relative radiance ``E = exp(Σ w (g(Z) − ln t) / Σ w)`` per pixel.

Clipped values (0 and 255) get weight 0; a pixel clipped in every frame is NaN.
"""

from __future__ import annotations

import os
from collections.abc import Sequence

import numpy as np

from drivers.errors import CalibrationError, RawFormatError

LEVELS = 256
MID_LEVEL = LEVELS // 2


def hat_weights(levels: int = LEVELS) -> np.ndarray:
    """Triangle weights over pixel values: 0 at both ends, largest in the middle."""
    z = np.arange(levels, dtype=np.float64)
    w = np.minimum(z, levels - 1 - z)
    return w / w.max()


def _stack(images: Sequence[np.ndarray], exposures_s: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    if len(images) != len(exposures_s) or len(images) < 2:
        raise CalibrationError(
            f"need ≥ 2 images with one exposure time each, got {len(images)} images and "
            f"{len(exposures_s)} exposures"
        )
    arrs = [np.asarray(im) for im in images]
    if any(a.dtype != np.uint8 for a in arrs):
        raise CalibrationError("response recovery takes 8-bit images (uint8); convert 16-bit TIFFs "
                               "or use the RAW pipeline")
    shapes = {a.shape for a in arrs}
    if len(shapes) != 1:
        raise CalibrationError(f"images differ in size: {sorted(shapes)}")
    stack = np.stack([a if a.ndim == 3 else a[..., None] for a in arrs])  # (N, H, W, C)
    t = np.asarray(exposures_s, dtype=np.float64)
    if np.any(~np.isfinite(t)) or np.any(t <= 0):
        raise CalibrationError(f"exposure times must be > 0 s, got {list(t)}")
    return stack, t


def recover_response(
    images: Sequence[np.ndarray],
    exposures_s: Sequence[float],
    *,
    samples: int = 200,
    smoothness: float = 10.0,
    seed: int = 0,
) -> np.ndarray:
    """Recover ``g = ln f⁻¹`` per colour from a bracket of 8-bit images of a static scene.

    Parameters
    ----------
    images:
        N images (H×W or H×W×C, uint8) of the same scene.
    exposures_s:
        Exposure time of each image, s.
    samples:
        Pixel positions used (chosen at random, seeded, among pixels not clipped everywhere).
    smoothness:
        λ of the second-difference penalty.

    Returns
    -------
    numpy.ndarray
        (256, C) ``g(z)``, natural log of relative exposure, ``g(128) = 0``.
    """
    stack, t = _stack(images, exposures_s)
    n, h, w, c = stack.shape
    flat = stack.reshape(n, h * w, c)
    rng = np.random.default_rng(seed)
    weights = hat_weights()
    log_t = np.log(t)
    g_all = np.empty((LEVELS, c))
    for ch in range(c):
        z = flat[:, :, ch]
        usable = np.flatnonzero(((z > 0) & (z < LEVELS - 1)).any(axis=0))
        if usable.size < 2:
            raise CalibrationError("too few unclipped pixels to recover a response; change exposures")
        pick = rng.choice(usable, size=min(samples, usable.size), replace=False)
        zs = z[:, pick].T.astype(np.intp)  # (P, N)
        g_all[:, ch] = _solve(zs, log_t, weights, smoothness)
    return g_all


def _solve(zs: np.ndarray, log_t: np.ndarray, weights: np.ndarray, smoothness: float) -> np.ndarray:
    """Least-squares g (LEVELS,) for samples ``zs`` (P, N): sparse normal equations."""
    from scipy import sparse
    from scipy.sparse.linalg import spsolve

    p, n = zs.shape
    wz = weights[zs].ravel()
    k_data = np.arange(p * n)
    sample = np.repeat(np.arange(p), n)
    rows = [k_data, k_data, [p * n]]
    cols = [zs.ravel(), LEVELS + sample, [MID_LEVEL]]
    vals = [wz, -wz, [1.0]]
    levels = np.arange(1, LEVELS - 1)
    k_smooth = p * n + 1 + np.arange(levels.size)
    wl = smoothness * weights[levels]
    for offset, factor in ((-1, 1.0), (0, -2.0), (1, 1.0)):
        rows.append(k_smooth)
        cols.append(levels + offset)
        vals.append(factor * wl)
    b = np.zeros(p * n + 1 + levels.size)
    b[k_data] = wz * np.tile(log_t, p)
    a = sparse.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
        shape=(b.size, LEVELS + p),
    )
    normal = (a.T @ a).tocsc()
    # Levels never seen and never smoothed (the clipped ends) are pinned by a tiny ridge.
    normal = normal + sparse.identity(normal.shape[0], format="csc") * 1e-10
    g = np.asarray(spsolve(normal, a.T @ b))[:LEVELS]
    return g - g[MID_LEVEL]  # the gauge g(128) = 0 exactly


def merge_ldr(
    images: Sequence[np.ndarray], exposures_s: Sequence[float], response: np.ndarray,
    *, weights: np.ndarray | None = None,
) -> np.ndarray:
    """Relative radiance (H×W×C float64) from a bracket and a recovered ``g`` (256×C).

    ``weights`` (256,) replaces :func:`hat_weights` (which gives clipped values weight 0).
    NaN where every frame's weight is 0 (with the default, clipped in every frame).
    """
    stack, t = _stack(images, exposures_s)
    g = np.asarray(response, dtype=np.float64)
    if g.shape != (LEVELS, stack.shape[-1]):
        raise CalibrationError(f"response shape {g.shape} does not fit {stack.shape[-1]} colour(s)")
    weights = hat_weights() if weights is None else np.asarray(weights, dtype=np.float64)
    num = np.zeros(stack.shape[1:])
    den = np.zeros(stack.shape[1:])
    channels = np.arange(stack.shape[-1])
    for j in range(stack.shape[0]):
        z = stack[j].astype(np.intp)
        wz = weights[z]
        num += wz * (g[z, channels] - np.log(t[j]))
        den += wz
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.exp(num / den)
    out[den == 0] = np.nan
    return out


def load_ldr(path: str | os.PathLike[str]) -> tuple[np.ndarray, float | None]:
    """An 8-bit JPEG/TIFF (H×W×C uint8) and its exposure time (s, from EXIF; None if absent)."""
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise RawFormatError(f"{path}: cannot open image ({oiio.geterror()}); check the file")
    try:
        spec = inp.spec()
        data = inp.read_image(oiio.UINT8)
        exposure = spec.getattribute("ExposureTime")
    finally:
        inp.close()
    if data is None:
        raise RawFormatError(f"{path}: cannot decode image; check the file")
    arr = np.asarray(data, dtype=np.uint8).reshape(spec.height, spec.width, spec.nchannels)
    return arr, (float(exposure) if exposure else None)
