"""HDR per pose: auto-exposure bracketing and inverse-variance merging with a noise model.

:func:`bracket` takes frames through a ``capture_fn(exposure_s) -> frame path`` until

1. the region of interest has no saturated pixel in the shortest exposure (it divides the
   exposure by ``step`` while any ROI cell clips), and
2. the darkest valid superpixel of the merged ROI reaches ``target_snr`` (it multiplies the
   longest exposure by ``step`` while it does not),

within the exposure limits and a frame budget. :func:`merge` combines linear images (DN/s)
with weights 1/variance; saturated or bad samples get weight 0. Each frame's variance is
re-predicted from the noise model at the merged value (a weight taken from a sample's own
noisy value would bias the mean low), and the merged variance is 1/Σ weights.

Wiring into a capture step::

    result = bracket(lambda t: take_frame(t), roi, noise, start_exposure_s=rig_exposure,
                     dark_for=bundle.dark_for, flat=bundle.flat, bad_pixels=bundle.bad_pixels)
    signal, variance, n = roi_mean(result.merged, roi)
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calibration.linearize import LinearImage, NoiseModel, linearize
from calibration.raw import load_raw
from drivers.errors import CalibrationError

RoiBox = tuple[int, int, int, int]
"""(x, y, width, height) in superpixels."""


@dataclass(frozen=True)
class BracketPolicy:
    """When bracketing stops.

    Attributes
    ----------
    target_snr:
        SNR the darkest valid ROI superpixel must reach in the merge (every colour).
    step:
        Exposure ratio between successive frames (> 1).
    min_exposure_s, max_exposure_s:
        Exposure limits of the camera, s.
    max_frames:
        Most frames per bracket.
    saturation:
        Fraction of (white − black) from which a pixel counts as clipped.
    """

    target_snr: float = 20.0
    step: float = 4.0
    min_exposure_s: float = 1e-5
    max_exposure_s: float = 30.0
    max_frames: int = 8
    saturation: float = 0.99


@dataclass(frozen=True)
class Bracket:
    """A bracketed, merged capture.

    Attributes
    ----------
    exposures_s, frames:
        Exposure (s) and file of each frame, in capture order.
    merged:
        The merged :class:`LinearImage` (DN/s) with its variance.
    min_snr:
        SNR of the darkest valid ROI superpixel in ``merged``.
    reached_target:
        False when the exposure limit or the frame budget stopped the bracket first.
    """

    exposures_s: tuple[float, ...]
    frames: tuple[Path, ...]
    merged: LinearImage
    min_snr: float
    reached_target: bool


def _roi(a: np.ndarray, roi: RoiBox) -> np.ndarray:
    x, y, w, h = roi
    return a[y : y + h, x : x + w]


def merge(images: Sequence[LinearImage], noise: NoiseModel | None = None,
          *, iterations: int = 2) -> LinearImage:
    """Inverse-variance merge of linear images of one scene (same units and shape).

    Parameters
    ----------
    images:
        Linearized frames with variances (``linearize(..., noise=...)``).
    noise:
        The noise model used for the variances; with it, each frame's variance is
        re-predicted at the merged value for ``iterations`` passes (removes the bias of
        self-weighting). Without it, each sample's own variance is its weight.

    Returns
    -------
    LinearImage
        ``rgb`` = Σ wₖxₖ / Σ wₖ, ``variance`` = 1 / Σ wₖ, ``valid`` where some frame was valid;
        ``exposure_s`` is the longest exposure, ``scale`` NaN.
    """
    if not images:
        raise CalibrationError("HDR merge: no image given")
    if any(im.variance is None for im in images):
        raise CalibrationError("HDR merge needs variances: linearize the frames with a noise model")
    units = {im.units for im in images}
    if len(units) != 1:
        raise CalibrationError(f"HDR merge: images mix units {sorted(units)}")
    shape = images[0].rgb.shape
    if any(im.rgb.shape != shape for im in images):
        raise CalibrationError("HDR merge: images differ in size")
    xs = [np.where(im.valid[..., None], im.rgb, 0.0) for im in images]
    vs = [np.where(im.valid[..., None], im.variance, np.inf) for im in images]  # type: ignore[arg-type]
    weights = [im.valid[..., None] / v for im, v in zip(images, vs, strict=True)]

    def combine() -> tuple[np.ndarray, np.ndarray]:
        wsum = np.sum(weights, axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            est = np.sum([w * x for w, x in zip(weights, xs, strict=True)], axis=0) / wsum
        return est, wsum

    est, wsum = combine()
    if noise is not None:
        gain, read = noise.per_colour()
        for _ in range(iterations):
            x_hat = np.maximum(np.nan_to_num(est), 0.0)
            for k, im in enumerate(images):
                c = im.scale
                own = c * np.maximum(xs[k], 0.0) / gain + c**2 * read**2
                at_est = c * x_hat / gain + c**2 * read**2
                with np.errstate(invalid="ignore", divide="ignore"):
                    weights[k] = im.valid[..., None] / (vs[k] * at_est / own)
            est, wsum = combine()
    valid = np.any([im.valid for im in images], axis=0)
    with np.errstate(divide="ignore"):
        variance = np.where(valid[..., None], 1.0 / wsum, np.nan)
    rgb = np.where(valid[..., None], est, np.nan)
    longest = max(images, key=lambda im: im.exposure_s)
    return LinearImage(rgb=rgb, valid=valid, variance=variance, units=images[0].units,
                       scale=math.nan, exposure_s=longest.exposure_s, iso=longest.iso,
                       f_number=longest.f_number, path=None)


def min_snr(image: LinearImage, roi: RoiBox) -> float:
    """SNR (value / σ) of the darkest valid superpixel and colour in the ROI (0 if none)."""
    valid = _roi(image.valid, roi)
    if not valid.any() or image.variance is None:
        return 0.0
    value = _roi(image.rgb, roi)[valid]
    sigma = np.sqrt(_roi(image.variance, roi)[valid])
    with np.errstate(divide="ignore", invalid="ignore"):
        snr = np.where(sigma > 0, value / sigma, np.inf)
    return float(np.min(snr))


def bracket(
    capture_fn: Callable[[float], Path],
    roi: RoiBox,
    noise: NoiseModel,
    *,
    start_exposure_s: float,
    policy: BracketPolicy = BracketPolicy(),
    dark_for: Callable[[float, float], np.ndarray | None] | None = None,
    flat: np.ndarray | None = None,
    bad_pixels: np.ndarray | None = None,
) -> Bracket:
    """Capture and merge a bracket until the ROI is unclipped and the darkest pixel is exposed.

    Parameters
    ----------
    capture_fn:
        ``capture_fn(exposure_s) -> path`` takes one RAW frame at that exposure.
    roi:
        (x, y, width, height) in superpixels.
    noise:
        Noise model of the camera at the ISO used.
    start_exposure_s:
        First exposure, s (e.g. the rig's nominal exposure).
    policy:
        Stop criteria and limits.
    dark_for:
        ``dark_for(exposure_s, iso)`` → master dark or None (e.g. ``bundle.dark_for``).
    flat, bad_pixels:
        Flat field and bad-pixel map for :func:`calibration.linearize.linearize`.

    Raises
    ------
    CalibrationError
        The ROI still clips at the shortest exposure allowed.
    """
    if not policy.step > 1:
        raise CalibrationError(f"bracket step must be > 1, got {policy.step}")
    frames = _BracketFrames(capture_fn, noise, policy, dark_for, flat)
    _shorten_until_unclipped(frames, roi, policy, start_exposure_s)
    merged, snr = _lengthen_until_exposed(frames, roi, noise, policy)
    if bad_pixels is not None:
        merged = _without_bad_pixels(merged, bad_pixels)
        snr = min_snr(merged, roi)
    return Bracket(tuple(frames.exposures_s), tuple(frames.paths), merged, snr,
                   snr >= policy.target_snr)


class _BracketFrames:
    """The frames of one bracket so far: takes and linearizes one per requested exposure."""

    def __init__(
        self,
        capture_fn: Callable[[float], Path],
        noise: NoiseModel,
        policy: BracketPolicy,
        dark_for: Callable[[float, float], np.ndarray | None] | None,
        flat: np.ndarray | None,
    ) -> None:
        self.capture_fn, self.noise, self.policy = capture_fn, noise, policy
        self.dark_for, self.flat = dark_for, flat
        self.exposures_s: list[float] = []
        self.paths: list[Path] = []
        self.images: list[LinearImage] = []

    def take(self, exposure_s: float) -> LinearImage:
        """Capture at ``exposure_s`` (s), linearize with variances, and keep the frame."""
        path = Path(self.capture_fn(exposure_s))
        frame = load_raw(path)
        used = frame.exposure_s or exposure_s
        dark = (self.dark_for(used, frame.iso)
                if self.dark_for is not None and frame.iso else None)
        # The file's exposure is what the camera really used (a real body rounds to its
        # nearest shutter speed); the requested one only where the file has none.
        image = linearize(frame, dark=dark, flat=self.flat, noise=self.noise,
                          saturation=self.policy.saturation,
                          exposure_s=None if frame.exposure_s else exposure_s)
        self.exposures_s.append(exposure_s)
        self.paths.append(path)
        self.images.append(image)
        return image


def _shorten_until_unclipped(
    frames: _BracketFrames, roi: RoiBox, policy: BracketPolicy, start_exposure_s: float
) -> None:
    """Take frames from the start exposure (clamped to the limits), dividing it by the step
    until the ROI has no clipped cell; CalibrationError at the shortest exposure or budget."""
    t = min(max(start_exposure_s, policy.min_exposure_s), policy.max_exposure_s)
    image = frames.take(t)
    while not _roi(image.valid, roi).all():
        if t / policy.step < policy.min_exposure_s or len(frames.images) >= policy.max_frames:
            raise CalibrationError(
                f"the region of interest still clips at {t:g} s; dim the light, stop down or "
                "allow shorter exposures"
            )
        t /= policy.step
        image = frames.take(t)


def _lengthen_until_exposed(
    frames: _BracketFrames, roi: RoiBox, noise: NoiseModel, policy: BracketPolicy
) -> tuple[LinearImage, float]:
    """Merge, then multiply the longest exposure by the step while the darkest ROI pixel is
    below the target SNR (within the exposure limit and frame budget); the merge and its SNR."""
    merged = merge(frames.images, noise)  # clipped samples of the longer frames weigh 0
    snr = min_snr(merged, roi)
    longest = max(frames.exposures_s)
    while (snr < policy.target_snr and longest * policy.step <= policy.max_exposure_s
           and len(frames.images) < policy.max_frames):
        longest *= policy.step
        frames.take(longest)
        merged = merge(frames.images, noise)
        snr = min_snr(merged, roi)
    return merged, snr


def _without_bad_pixels(merged: LinearImage, bad_pixels: np.ndarray) -> LinearImage:
    """The merge with the superpixels on a pixel or superpixel bad-pixel map made invalid."""
    bad = bad_pixels
    if bad.shape != merged.valid.shape:
        bad = bad.reshape(bad.shape[0] // 2, 2, bad.shape[1] // 2, 2).any(axis=(1, 3))
    valid = merged.valid & ~bad
    return LinearImage(
        rgb=np.where(valid[..., None], merged.rgb, np.nan), valid=valid,
        variance=np.where(valid[..., None], merged.variance, np.nan),
        units=merged.units, scale=merged.scale, exposure_s=merged.exposure_s,
        iso=merged.iso, f_number=merged.f_number,
    )
