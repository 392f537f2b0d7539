"""Light-stage reduction: per-LED calibration from the white target, BRDF samples, the table.

Per-LED calibration
-------------------
LED k's white-target frame (a flat Lambertian plate of reflectance ρ, the rig's
``[white_reference]``) gives C_k = K·I_k, camera response times LED intensity, by
:func:`acquisition.reduction.image.white_calibration` over the region of interest, with each plate
pixel's own geometry under that LED. Every LED is therefore calibrated on its own: an LED
10 % brighter than nominal has a C_k 10 % higher, and dividing by it removes the error.

Sample frames
-------------
An OLAT frame of LED k (journal joints ``{"light": k}``) is a frame of the image-based
pipeline with the point light at LED k: each valid sample pixel gives
f = P / (C_k · cos θi / r²) (:func:`acquisition.reduction.image.frame_samples`), binned into the
MERL table and the plan's isotropic table. A dark frame, when the session has one, is
subtracted from every frame first (DN/s).

Uncertainty
-----------
Frames are linearized with a noise variance per superpixel where a noise model is known (the
simulated camera's sensor model; a real camera has none yet), so the table's budget has the
image reduction's terms (:data:`acquisition.reduction.point.UNCERTAINTY_TERMS`): each sample's
``noise`` (independent), C_k's own relative uncertainty from the plate pixels' noise as the
``white_reference`` term (correlated: common to every sample of LED k), and the ``binning``
term of bins filled by many pixels. The mean dark frame's noise is not in the budget.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from acquisition.config.rig import RigConfig
from acquisition.formats.merl import write_merl
from acquisition.reduction.badframes import FrameCheck
from acquisition.reduction.image import (
    DEFAULT_MIN_COS,
    FrameSamples,
    ImageReduction,
    bin_frames,
    frame_samples,
    white_calibration,
    white_relative_uncertainty,
)
from acquisition.reduction.imaging import PixelGeometry, frame_geometry
from acquisition.reduction.point import (
    UNCERTAINTY_TERMS,
    linearize_with_variance,
    noise_source,
    session_provenance,
)
from acquisition.session.folder import SessionFolder
from acquisition.session.journal import StepRecord
from acquisition.session.status import LIGHTSTAGE_META as META_KEY
from acquisition.session.steps import DARK, POSE, REFERENCE
from acquisition.tables import IsotropicTable, MerlTable
from calibration.linearize import LinearImage, linearize
from calibration.raw import load_raw
from drivers.errors import SessionError


def is_lightstage_session(session_dir: str | Path) -> bool:
    """Whether ``session_dir`` was written by a light-stage capture."""
    folder = SessionFolder(session_dir)
    with folder.journal(readonly=True) as journal:
        return journal.meta(META_KEY) is not None


@dataclass(frozen=True)
class LedCalibration:
    """Per-LED calibration C_k = K·I_k from white-target OLAT frames.

    Attributes
    ----------
    scale:
        (N, 3) C_k (DN/s per W·sr⁻¹·m⁻² of nominal radiance… i.e. per unit f·cos θi/r², m⁻²·sr⁻¹);
        NaN for an LED without a white frame.
    pixels:
        (N,) plate pixels used per LED (0 = not calibrated).
    relative_u:
        (N, 3) relative standard uncertainty of C_k from the plate pixels' noise (NaN without
        a noise model).
    """

    scale: np.ndarray
    pixels: np.ndarray
    relative_u: np.ndarray

    @property
    def relative(self) -> np.ndarray:
        """(N, 3) each LED's intensity relative to the mean over calibrated LEDs."""
        return self.scale / np.nanmean(self.scale, axis=0)

    def require(self, k: int, where: str) -> np.ndarray:
        """C_k, or a SessionError naming the LED when it has no calibration."""
        if not self.pixels[k]:
            raise SessionError(
                f"{where}: LED {k} has no white-reference frame with valid plate pixels in the "
                "ROI: resume the capture, or move [camera] roi onto the plate"
            )
        return self.scale[k]


def _done(folder: SessionFolder) -> list[StepRecord]:
    with folder.journal(readonly=True) as journal:
        records = [r for r in journal.steps() if r.status == "done"]
    if not records:
        raise SessionError(f"{folder.path} has no captured frame yet: run or resume the capture")
    return records


def dark_rate(folder: SessionFolder, records: list[StepRecord]) -> np.ndarray | None:
    """Mean dark frame (h, w, 3) in DN/s, or None without a dark frame."""
    darks = [linearize(load_raw(folder.frames_dir / str(r.frame))).rgb
             for r in records if r.kind == DARK]
    return np.nanmean(darks, axis=0) if darks else None


def load_frame(folder: SessionFolder, rec: StepRecord, dark: np.ndarray | None) -> LinearImage:
    """A frame linearized (DN/s) with its noise variance where a model is known, minus the
    dark rate."""
    image = linearize_with_variance(folder.frames_dir / str(rec.frame), folder.rig())
    return image if dark is None else dataclasses.replace(image, rgb=image.rgb - dark)


def light_of(rec: StepRecord) -> int | None:
    """The LED an OLAT frame was lit by, else None."""
    value = rec.joints_cmd.get("light")
    return None if value is None else int(round(value))


def frame_geometry_of(rig: RigConfig, rec: StepRecord, shape: tuple[int, int],
                      target: str | None = None) -> PixelGeometry:
    """Per-pixel geometry of an OLAT frame (``target="flat"``: the white plate)."""
    g = rig.kinematics().forward_geometry(rec.joints_cmd)
    return frame_geometry(rig, g.light_dir, g.camera_dir, shape, target)


def led_calibration(session_dir: str | Path) -> LedCalibration:
    """C_k of every LED from the session's white-target OLAT frames."""
    folder = SessionFolder(session_dir)
    rig = folder.rig()
    records = _done(folder)
    dark = dark_rate(folder, records)
    n = len(rig.light_stage.light_dirs) if rig.light_stage else 0
    scale, pixels = np.full((n, 3), np.nan), np.zeros(n, dtype=int)
    relative_u = np.full((n, 3), np.nan)
    rho = np.asarray(rig.white_reference.reflectance, dtype=np.float64)
    check = FrameCheck(folder.path)
    for rec in records:
        k = light_of(rec)
        if rec.kind != REFERENCE or k is None:
            continue
        image = check.load(rec, lambda rec=rec: load_frame(folder, rec, dark))
        if image is None:
            continue
        geo = frame_geometry_of(rig, rec, image.valid.shape, "flat")
        scale[k], pixels[k] = white_calibration(image, geo, rig.camera.roi, rho)
        relative_u[k] = white_relative_uncertainty(image, geo, rig.camera.roi)
    check.raise_if_any()
    if not pixels.any():
        raise SessionError(f"{folder.path} has no white-reference OLAT frame: resume the capture")
    return LedCalibration(scale, pixels, relative_u)


def iter_lightstage_samples(session_dir: str | Path, *, min_cos: float = DEFAULT_MIN_COS,
                            calibration: LedCalibration | None = None) -> Iterator[FrameSamples]:
    """BRDF samples of every OLAT sample frame, one frame at a time."""
    folder = SessionFolder(session_dir)
    rig = folder.rig()
    cal = calibration or led_calibration(folder.path)
    records = _done(folder)
    dark = dark_rate(folder, records)
    check = FrameCheck(folder.path)
    for rec in records:
        k = light_of(rec)
        if rec.kind != POSE or k is None:
            continue
        image = check.load(rec, lambda rec=rec: load_frame(folder, rec, dark))
        if image is None:
            continue
        geo = frame_geometry_of(rig, rec, image.valid.shape)
        yield frame_samples(image, geo, cal.require(k, str(folder.path)), rec.step, min_cos,
                            cal.relative_u[k])
    check.raise_if_any()


def reduce_lightstage_session(
    session_dir: str | Path,
    progress: Callable[[int, int], None] | None = None,
    *,
    merl_path: str | Path | None = None,
    min_cos: float = DEFAULT_MIN_COS,
) -> ImageReduction:
    """Bin a light-stage session's OLAT sample frames into the MERL and isotropic tables.

    ``drift_pct`` of the result is the spread of the LEDs' calibrated intensities (peak to
    peak, % of the mean), not a drift in time.
    """
    t0 = time.monotonic()
    folder = SessionFolder(session_dir)
    rig, plan = folder.rig(), folder.plan()
    records = _done(folder)
    total = sum(r.kind == POSE and light_of(r) is not None for r in records)
    cal = led_calibration(folder.path)
    spread = float(np.nanmax(np.ptp(cal.relative[cal.pixels > 0], axis=0)) * 100.0)
    provenance = session_provenance(folder, rig, plan, image_based=True, light_stage=True,
                                    sample_shape=rig.sample.shape,
                                    led_intensity_spread_pct=spread)
    provenance["noise_model"] = noise_source(rig, float(rig.camera.iso), None)
    table = IsotropicTable(plan.table.theta_i_edges, plan.table.theta_r_edges,
                           plan.table.delta_phi_edges, provenance=provenance)
    table.track_uncertainty(*UNCERTAINTY_TERMS)
    merl = MerlTable(dict(provenance))
    samples, frames = bin_frames(
        iter_lightstage_samples(folder.path, min_cos=min_cos, calibration=cal),
        table, merl, progress, total)
    table.add_binning_term()
    if merl_path is not None:
        write_merl(merl_path, merl)
    return ImageReduction(table=table, frames=frames, references=int((cal.pixels > 0).sum()),
                          drift_pct=spread, seconds=time.monotonic() - t0, merl=merl,
                          samples=samples)
