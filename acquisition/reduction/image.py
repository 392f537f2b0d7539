"""Image-based reduction: every valid pixel on the sample of every frame is one BRDF sample.

Per frame (RAW → :func:`calibration.linearize.linearize`, in DN/s), the rig's pinhole camera
and point light at the frame's read-back joint angles give each pixel that sees a lit part of
the sample its local (wi, wo) and irradiance term cos θi / r² (:mod:`acquisition.reduction.imaging`).

Absolute scale
--------------
A pixel value is P = K · L with L = f · I · cos θi / r², where K (DN/s per W·sr⁻¹·m⁻²) is the
camera's response and I (W·sr⁻¹) the light's intensity; only the product C = K · I is needed.
The white reference is a flat Lambertian plate of reflectance ρ (f = ρ/π) and edge
``[sample] size_m`` at the origin, captured by the same pipeline at the rig's white-reference
pose. Over the region of interest's valid pixels on the plate,

    C = Σ P_ref / Σ (ρ/π · cos θi / r²)          (per channel, per reference frame)

using each plate pixel's own geometry (for a distant light and camera this reduces to the ROI
formula of :mod:`acquisition.reduction.point`). C is interpolated linearly in step between the
reference frames (correcting slow drift), and every sample pixel gives

    f = P / (C · cos θi / r²)                    [sr⁻¹].

The same calibration serves a flat or a spherical sample, because it measures the camera and
light, not the sample.

With a calibration bundle (``bundle=``, else the one copied into the session folder), every
frame is linearized with its master dark, flat field (the camera's vignetting and pixel
response: the plate's and the sample's pixels are corrected alike), bad-pixel map and noise
model, as in :mod:`acquisition.reduction.point`. An HDR bracket (journal rows noted
``hdr=<first step>:<k>``) is merged per superpixel with inverse-variance weights first and
counts as one frame.

Samples are binned frame by frame into a :class:`~acquisition.tables.MerlTable` and the plan's
:class:`~acquisition.tables.IsotropicTable` (count, sum, sum of squares per bin); no more than
one frame's samples are held at any time.

The isotropic table's budget has the point reduction's terms (each pixel's noise, the white
plate's) and a ``binning`` term: a bin gathers pixels spread over its whole extent, so its
mean depends on where they fell; the observed scatter beyond the noise, over √n, says by how
much (:func:`acquisition.tables.uncertainty.binning_variance_sums`). On a rig whose file
states backlash, position noise or a lamp of finite size, or with a geometric calibration
applied, it has the angular terms too (:mod:`acquisition.reduction.imageangular`):

* ``angular`` (independent between bins): where the arms really stood, through the BRDF's
  local slope; the pixels one frame puts in a bin share their frame's error (it adds linearly
  over them), frames add in quadrature;
* ``source_size`` (independent): 30 % of the correction of each bin's mean for the lamp's
  blur (the MERL table keeps the pixels' values as measured);
* ``geometry_calibration`` (correlated): the calibration's 1σ — zero offsets, sample tilt,
  backlash and the camera's pointing.

Against the material at the very pixels of each bin (where they fell is then no error: the
``binning`` term left aside), a sphere rig's peak bins (truth ≥ half its maximum) have
errors over their standard uncertainty scattering with a standard deviation within 0.7–1.3
(tests/test_image_angular.py).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from acquisition.config.rig import RigConfig
from acquisition.formats.merl import write_merl
from acquisition.geometry.pinhole import PinholeCamera
from acquisition.reduction import CHECKPOINT_EVERY
from acquisition.reduction.badframes import FrameCheck
from acquisition.reduction.checkpoint import Checkpointed, reduction_key
from acquisition.reduction.fixedorder import weighted_variance
from acquisition.reduction.fusedbinning import bin_frame, fits, helper_for, helper_pool
from acquisition.reduction.imageangular import FrameBins, ImageAngular
from acquisition.reduction.imaging import (
    PixelGeometry,
    Pixels,
    frame_camera,
    frame_geometry,
    pixel_samples,
)
from acquisition.reduction.pixelbinning import GeometryJob, bin_pixels
from acquisition.reduction.point import (
    UNCERTAINTY_TERMS,
    Reduction,
    find_bundle,
    linearize_with_variance,
    noise_source,
    session_provenance,
)
from acquisition.reduction.pose_kernels import sample_poses
from acquisition.reduction.samplegeometry import SampleGeometry
from acquisition.session.engine import POSE, REFERENCE
from acquisition.session.folder import SessionFolder
from acquisition.session.hdr import HDR_DONE_META, camera_noise_model, hdr_group
from acquisition.session.journal import StepRecord
from acquisition.tables import IsotropicTable, MerlTable
from acquisition.tables.backend import resolve_backend
from acquisition.tables.partial import PartialError, ReductionPartial
from calibration.bundle import CalibrationBundle
from calibration.hdr import merge
from calibration.linearize import LinearImage
from drivers.errors import SessionError

DEFAULT_MIN_COS = 0.02
"""Samples with cos θi or cos θr below this (beyond ~88.9°) are dropped: at the sample's
silhouette and terminator a pixel's geometry is least certain."""


@dataclass(frozen=True)
class FrameSamples:
    """The BRDF samples of one frame: local unit directions (N, 3) and BRDF (N, 3) in sr⁻¹,
    with each sample's noise variance (N, 3), sr⁻², where the frame has a noise model, the
    relative standard uncertainty (3,) of the calibration C that scaled them, each sample's
    pixel (rows, columns) in the frame of ``shape`` superpixels, and the frame's read-back
    joints (deg; for the angular terms, :mod:`acquisition.reduction.imageangular`)."""

    step: int
    wi: np.ndarray
    wo: np.ndarray
    brdf: np.ndarray
    variance: np.ndarray | None = None
    calibration_rel: np.ndarray | None = None
    pixels: Pixels | None = None
    shape: tuple[int, int] | None = None
    joints: Mapping[str, float] | None = None

    @property
    def count(self) -> int:
        return int(self.wi.shape[0])


@dataclass
class ImageReduction(Reduction):
    """What :func:`reduce_image_session` produced: the isotropic table and the MERL table."""

    merl: MerlTable = field(default_factory=MerlTable)
    samples: int = 0
    """BRDF samples taken from the frames (before binning)."""
    resumed_frames: int = 0
    """Frames taken from a checkpoint (reduced by an earlier, interrupted run)."""


def _linear(folder: SessionFolder, rig: RigConfig, rec: StepRecord,
            bundle: CalibrationBundle | None = None) -> LinearImage:
    """A frame linearized with a variance per superpixel where a noise model is known."""
    return linearize_with_variance(folder.frames_dir / str(rec.frame), rig, bundle)


def _merged(folder: SessionFolder, rig: RigConfig, recs: list[StepRecord],
            bundle: CalibrationBundle | None) -> LinearImage:
    """Inverse-variance merge of an HDR bracket's frames."""
    images = [linearize_with_variance(folder.frames_dir / str(r.frame), rig, bundle)
              for r in recs]
    return merge(images, camera_noise_model(rig, float(images[0].iso or rig.camera.iso), bundle))


def sample_frames(records: list[StepRecord], complete: set[int]) -> list[list[StepRecord]]:
    """The done sample rows as frames: one row each, or the rows of a complete HDR bracket
    (incomplete brackets are left out)."""
    frames: list[list[StepRecord]] = []
    groups: dict[int, list[StepRecord]] = {}
    for r in records:
        if r.kind == REFERENCE:
            continue
        g = hdr_group(r.note) if r.kind == POSE else None
        if g is None:
            frames.append([r])
        elif g in complete:
            if g not in groups:
                groups[g] = []
                frames.append(groups[g])
            groups[g].append(r)
    return frames


def _geometry(rig: RigConfig, rec: StepRecord, shape: tuple[int, int],
              target: str | None = None, model: SampleGeometry | None = None) -> PixelGeometry:
    """A frame's per-pixel geometry, through the geometric calibration's model (arms, tilt,
    the camera's pointing) when ``model`` gives one."""
    model = model or SampleGeometry.of(rig, None)
    g = model.kinematics.forward_geometry(rec.joints_read or rec.joints_cmd)
    return frame_geometry(rig, g.light_dir, g.camera_dir, shape, target,
                          pointing_deg=model.pointing_deg)


def white_calibration(
    image: LinearImage, geo: PixelGeometry, roi: tuple[int, int, int, int],
    reflectance: np.ndarray,
) -> tuple[np.ndarray, int]:
    """C = K·I (3,) from a flat white-plate frame, and the number of pixels used.

    Uses the valid pixels of ``roi`` (x0, y0, x1, y1, superpixels) that see the lit plate.
    """
    x0, y0, x1, y1 = roi
    in_roi = np.zeros(geo.mask.shape, dtype=bool)
    in_roi[y0:y1, x0:x1] = True
    use = (in_roi & image.valid)[geo.mask]
    n = int(use.sum())
    if n == 0:
        return np.full(3, np.nan), 0
    signal = image.rgb[geo.mask][use].sum(axis=0)
    model = geo.irradiance[use].sum() * np.asarray(reflectance, dtype=np.float64) / np.pi
    return signal / model, n


def white_relative_uncertainty(image: LinearImage, geo: PixelGeometry,
                               roi: tuple[int, int, int, int]) -> np.ndarray:
    """Relative standard uncertainty (3,) of :func:`white_calibration`'s C from the plate
    pixels' noise variances (NaN without a noise model)."""
    if image.variance is None:
        return np.full(3, np.nan)
    x0, y0, x1, y1 = roi
    in_roi = np.zeros(geo.mask.shape, dtype=bool)
    in_roi[y0:y1, x0:x1] = True
    use = (in_roi & image.valid)[geo.mask]
    signal = image.rgb[geo.mask][use].sum(axis=0)
    return np.sqrt(image.variance[geo.mask][use].sum(axis=0)) / signal


def frame_samples(
    image: LinearImage, geo: PixelGeometry, calibration: np.ndarray, step: int,
    min_cos: float = DEFAULT_MIN_COS, calibration_rel: np.ndarray | None = None,
) -> FrameSamples:
    """BRDF samples f = P / (C · cos θi / r²) of a frame's valid pixels on the sample, with
    their noise variance var P / (C · cos θi / r²)² where the image has one."""
    keep = image.valid[geo.mask] & (geo.wi[:, 2] >= min_cos) & (geo.wo[:, 2] >= min_cos)
    rgb = image.rgb[geo.mask][keep]
    scale = geo.irradiance[keep][:, None] * calibration
    variance = None if image.variance is None else image.variance[geo.mask][keep] / scale**2
    rows, cols = np.nonzero(geo.mask)
    return FrameSamples(step, geo.wi[keep], geo.wo[keep], rgb / scale, variance,
                        calibration_rel, (rows[keep], cols[keep]), geo.mask.shape)


@dataclass
class ImageReducer:
    """What reducing frames of an image-based session needs, prepared once: the session, the
    calibration, the white reference's scale C at every reference frame, and the sample frames
    (journal rows, an HDR bracket's together). Frames then reduce to partial tables
    (:meth:`partial`), in any split, order or grouping; merged, they give the table a
    sequential reduction gives, bit for bit."""

    folder: SessionFolder
    rig: RigConfig
    cal: CalibrationBundle | None
    model: SampleGeometry
    check: FrameCheck
    frames: list[list[StepRecord]]
    ref_steps: np.ndarray
    ref_cals: np.ndarray
    ref_vars: np.ndarray
    min_cos: float = DEFAULT_MIN_COS
    frame_shape: tuple[int, int] | None = None
    """The last frame's image size (superpixels): the next frame's, to start its geometry
    while it is decoded (:meth:`reduce`)."""

    @classmethod
    def open(cls, session_dir: str | Path | SessionFolder,
             bundle: str | Path | CalibrationBundle | None = None,
             min_cos: float = DEFAULT_MIN_COS) -> ImageReducer:
        """Read the journal and the white-reference frames (SessionError if the session is not
        image-based, has no frame, or no usable white reference)."""
        folder = session_dir if isinstance(session_dir, SessionFolder) else SessionFolder(session_dir)
        reducer = cls.begin(folder, bundle, min_cos)
        with folder.journal(readonly=True) as journal:
            records = [r for r in journal.steps() if r.status == "done"]
            complete = {g for g in {hdr_group(r.note) for r in records} - {None}
                        if journal.meta(f"{HDR_DONE_META}{g}") is not None}
        if not records:
            raise SessionError(f"{folder.path} has no captured frame yet: run or resume the capture first")
        reducer.frames = sample_frames(records, complete)
        reducer._read_references([r for r in records if r.kind == REFERENCE])
        return reducer

    @classmethod
    def begin(cls, folder: SessionFolder, bundle: str | Path | CalibrationBundle | None = None,
              min_cos: float = DEFAULT_MIN_COS) -> ImageReducer:
        """A reducer of no frame and no white reference yet (a capture still running: see
        :mod:`acquisition.reduction.stream`); SessionError if the session is not image-based."""
        rig = folder.rig()
        if not rig.sample.image_based:
            raise SessionError(f"{folder.path}: the rig's [sample] is not image_based: use gonio reduce")
        cb = bundle if isinstance(bundle, CalibrationBundle) else find_bundle(folder, bundle)
        return cls(folder, rig, cb, SampleGeometry.of(rig, cb), FrameCheck(folder.path), [],
                   np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)), min_cos)

    def _read_references(self, refs: list[StepRecord]) -> None:
        """C (3,) and its variance at every readable white-reference frame."""
        got = [(rec.step, *ref) for rec in refs if (ref := self.read_reference(rec)) is not None]
        if not got:
            self.check.raise_if_any()
            raise SessionError(f"{self.folder.path} has no white-reference frame: resume the "
                               "capture to take it")
        self.set_references(got)

    def read_reference(self, rec: StepRecord) -> tuple[np.ndarray, np.ndarray] | None:
        """C (3,) and its variance (3,) from one white-reference frame, or None when its RAW
        cannot be decoded (noted in :attr:`check`); SessionError when no plate pixel is
        valid in the ROI."""
        image = self.check.load(rec, lambda: _linear(self.folder, self.rig, rec, self.cal))
        if image is None:
            return None
        geo = _geometry(self.rig, rec, image.valid.shape, "flat", self.model)
        rho = np.asarray(self.rig.white_reference.reflectance, dtype=np.float64)
        cal, n = white_calibration(image, geo, self.rig.camera.roi, rho)
        if n == 0:
            raise SessionError(
                f"{self.folder.path}: white-reference frame {rec.frame} has no valid pixel on "
                "the plate in the ROI: move [camera] roi onto the plate or shorten the exposure")
        rel = white_relative_uncertainty(image, geo, self.rig.camera.roi)
        return cal, (rel * cal) ** 2

    def set_references(self, refs: Iterable[tuple[int, np.ndarray, np.ndarray]]) -> None:
        """Use these white references: (journal step, C (3,), its variance (3,)) each."""
        got = sorted(refs, key=lambda r: r[0])
        self.ref_steps = np.array([r[0] for r in got], float)
        self.ref_cals = np.array([r[1] for r in got]).reshape(-1, 3)
        self.ref_vars = np.array([r[2] for r in got]).reshape(-1, 3)

    def reference_at(self, step: int) -> tuple[np.ndarray, np.ndarray]:
        """C (3,) at journal step ``step``, linear in step between the white references on
        either side (the nearest beyond the first or last), and its relative standard
        uncertainty (3,). Only those two references enter (a reduction that streams while
        later ones are still to come gets the same bits)."""
        xs = self.ref_steps
        hi = int(np.searchsorted(xs, step, side="right"))
        lo = max(hi - 1, 0)
        hi = min(hi, xs.size - 1)
        pair = slice(lo, hi + 1)
        cal = np.array([np.interp(step, xs[pair], self.ref_cals[pair, c]) for c in range(3)])
        w = np.array([np.interp(step, xs[pair], e) for e in np.eye(hi + 1 - lo)])
        return cal, np.sqrt(weighted_variance(w, self.ref_vars[pair])) / cal

    @property
    def n_references(self) -> int:
        return int(self.ref_steps.size)

    @property
    def drift_pct(self) -> float:
        """The white reference's peak-to-peak change, % of its mean (largest over colours)."""
        cals = self.ref_cals
        return float(np.max(np.ptp(cals, axis=0) / np.mean(cals, axis=0)) * 100.0)

    @property
    def key(self) -> str:
        """What makes this reduction's partials mergeable: the session, the calibration, the
        options, the table grid and the white reference's scale (a resumed capture with new
        reference frames makes earlier partials stale)."""
        plan = self.folder.plan().table
        refs = np.concatenate([self.ref_steps, self.ref_cals.ravel(), self.ref_vars.ravel()])
        return reduction_key("image", self.folder, self.cal, refs, min_cos=self.min_cos,
                             edges=[list(map(float, e)) for e in (plan.theta_i_edges,
                                    plan.theta_r_edges, plan.delta_phi_edges)])

    def images(self, frames: Iterable[list[StepRecord]]
               ) -> Iterator[tuple[StepRecord, LinearImage]]:
        """Each frame (rows of :attr:`frames`) linearized, an HDR bracket merged, with its
        (first) journal row; a frame that cannot be decoded is skipped and noted
        (``check.raise_if_any``)."""
        for recs in frames:
            image = self._load(recs)
            if image is not None:
                yield recs[0], image

    def _load(self, recs: list[StepRecord]) -> LinearImage | None:
        """One frame linearized (an HDR bracket merged), or None when it cannot be read."""
        rec = recs[0]
        plain = len(recs) == 1 and hdr_group(rec.note) is None
        return self.check.load(recs, lambda: (
            _linear(self.folder, self.rig, rec, self.cal) if plain
            else _merged(self.folder, self.rig, recs, self.cal)))

    def samples(self, frames: Iterable[list[StepRecord]]) -> Iterator[FrameSamples]:
        """The BRDF samples of each frame (rows of :attr:`frames`), one frame at a time; a
        frame that cannot be decoded is skipped and noted (``check.raise_if_any``)."""
        for rec, image in self.images(frames):
            yield self.frame_samples(image, rec)

    def reduce(self, frames: Iterable[list[StepRecord]], table: IsotropicTable,
               merl: MerlTable, angular: ImageAngular | None = None
               ) -> Iterator[tuple[int, int, dict[str, np.ndarray] | None]]:
        """Bin each frame into both tables, one frame at a time; yields its step, its
        samples and its frame-bins' angular terms (:func:`frame_angular`, when ``angular``
        is active). A frame goes straight from its pixels into the tables
        (:meth:`bin_image`; the work that needs only its pose starts while it is decoded,
        for the image size of the frame before) where it can, else through
        :meth:`frame_samples` and :func:`bin_frames`: the same tables, bit for bit."""
        pool = helper_pool()
        active = angular is not None and angular.active
        for recs in frames:
            rec = recs[0]
            shape = self.frame_shape
            ahead = None if active or shape is None else self.geometry(rec, shape, table, merl)
            if ahead is not None:
                ahead.start(pool)
            image = self._load(recs)
            if image is None:
                if ahead is not None:
                    ahead.cancel()
                continue
            self.frame_shape = image.valid.shape
            count = None if active else self.bin_image(image, rec, table, merl, pool, ahead)
            if count is not None:
                yield rec.step, count, None
                continue
            fs = self.frame_samples(image, rec)
            bin_frames([fs], table, merl, None, 0)
            yield fs.step, fs.count, frame_angular(angular, fs) if active else None  # type: ignore[arg-type]

    def _camera(self, rec: StepRecord, shape: tuple[int, int]
                ) -> tuple[PinholeCamera, np.ndarray]:
        """The camera and light position (m) of the frame at journal row ``rec``."""
        g = self.model.kinematics.forward_geometry(rec.joints_read or rec.joints_cmd)
        return frame_camera(self.rig, g.light_dir, g.camera_dir, shape,
                            pointing_deg=self.model.pointing_deg)

    def geometry(self, rec: StepRecord, shape: tuple[int, int], table: IsotropicTable,
                 merl: MerlTable) -> GeometryJob | None:
        """The per-pixel work of the frame at ``rec`` that needs only its pose, for images of
        ``shape`` superpixels (None where :meth:`bin_image` would not use it)."""
        if resolve_backend() != "numba" or not fits(table, merl):
            return None
        camera, light = self._camera(rec, shape)
        return GeometryJob(camera, light, self.rig.sample, shape, self.min_cos, table)

    def bin_image(self, image: LinearImage, rec: StepRecord, table: IsotropicTable,
                  merl: MerlTable, pool: ThreadPoolExecutor | None = None,
                  geometry: GeometryJob | None = None) -> int | None:
        """Bin a linearized frame's samples (journal row ``rec``) straight into both tables
        (:func:`~acquisition.reduction.pixelbinning.bin_pixels`, shared with ``pool``'s
        thread; ``geometry``: the frame's :meth:`geometry`, perhaps started); returns the
        samples binned, or None, having changed nothing, where only the reference path
        applies (numpy backend, tables the fused kernels do not fit, a budget near the exact
        sums' range)."""
        if resolve_backend() != "numba":
            if geometry is not None:
                geometry.cancel()
            return None
        calibration, calibration_rel = self.reference_at(rec.step)
        camera, light = self._camera(rec, image.valid.shape)
        return bin_pixels(camera, light, self.rig.sample, image.rgb, image.valid,
                          image.variance, calibration, calibration_rel, self.min_cos, table,
                          merl, pool, geometry)

    def frame_samples(self, image: LinearImage, rec: StepRecord) -> FrameSamples:
        """:func:`frame_samples` of a linearized frame (journal row ``rec``), scaled by the
        white reference interpolated at its step; with the numba backend compiled, row by row
        (:func:`~acquisition.reduction.imaging.pixel_samples`: the same arrays)."""
        calibration, calibration_rel = self.reference_at(rec.step)
        joints = rec.joints_read or rec.joints_cmd
        if resolve_backend() != "numba":
            geo = _geometry(self.rig, rec, image.valid.shape, model=self.model)
            return replace(frame_samples(image, geo, calibration, rec.step, self.min_cos,
                                         calibration_rel), joints=joints)
        camera, light = self._camera(rec, image.valid.shape)
        wi, wo, brdf, variance, pixels = pixel_samples(
            camera, light, self.rig.sample, image.rgb, image.valid, image.variance,
            calibration, self.min_cos)
        return FrameSamples(rec.step, wi, wo, brdf, variance, calibration_rel, pixels,
                            image.valid.shape, joints)

    def new_tables(self, provenance: dict[str, object] | None = None
                   ) -> tuple[IsotropicTable, MerlTable]:
        """The plan's empty isotropic table (tracking the budget) and an empty MERL table."""
        plan = self.folder.plan().table
        table = IsotropicTable(plan.theta_i_edges, plan.theta_r_edges, plan.delta_phi_edges,
                               provenance=provenance)
        table.track_uncertainty(*UNCERTAINTY_TERMS)
        return table, MerlTable(provenance)

    def tables(self) -> tuple[IsotropicTable, MerlTable]:
        """:meth:`new_tables` with the session's provenance (and the noise model's source)."""
        rig, cal = self.rig, self.cal
        provenance = session_provenance(self.folder, rig, self.folder.plan(), image_based=True,
                                        sample_shape=rig.sample.shape)
        if cal is not None:
            provenance["calibration_bundle"] = str(cal.path.resolve())
        table, merl = self.new_tables(provenance)
        table.provenance["noise_model"] = noise_source(rig, float(rig.camera.iso), cal)
        return table, merl

    def finish(self, table: IsotropicTable, merl: MerlTable, done: ReductionPartial,
               t0: float, merl_path: str | Path | None = None, resumed: int = 0
               ) -> ImageReduction:
        """The reduction of the frames ``done`` holds, binned in ``table`` and ``merl``: the
        white reference's drift in their provenance, the budget's binning term, the angular
        terms of ``done``'s frame-bins (in frame order) with the lamp's correction, the MERL
        file (``merl_path``)."""
        drift = self.drift_pct
        for t in (table, merl):
            t.provenance["reference_drift_pct"] = drift
        table.add_binning_term()  # the pixels' scatter: before the terms they share
        ImageAngular(self.rig, self.model, table).apply(
            [FrameBins.from_arrays(done.frame_data[s]) for s in sorted(done.frame_data)])
        if self.model.alignment is not None:
            table.provenance["geometry_calibration"] = self.model.alignment.to_dict()
        if merl_path is not None:
            write_merl(merl_path, merl)
        return ImageReduction(table=table, frames=len(done.steps), references=self.n_references,
                              drift_pct=drift, seconds=time.monotonic() - t0,
                              bundle=None if self.cal is None else self.cal.path, merl=merl,
                              samples=done.samples, resumed_frames=resumed)

    def reduction(self, partial: ReductionPartial, merl_path: str | Path | None = None
                  ) -> ImageReduction:
        """The reduction a (merged) partial of this session's frames finishes into: the same
        tables as :func:`reduce_image_session` of those frames, bit for bit."""
        if partial.key != self.key:
            raise SessionError("this partial belongs to another reduction (session, calibration "
                               "or options differ): reduce its frames again")
        table, merl = self.tables()
        table.merge_partial(partial.tables["isotropic"])
        merl.merge_partial(partial.tables["merl"])
        return self.finish(table, merl, partial, time.monotonic(), merl_path)

    def partial(self, frames: Iterable[list[StepRecord]]) -> ReductionPartial:
        """The partial tables of ``frames`` (rows of :attr:`frames`)."""
        builder = PartialBuilder(self)
        builder.add(frames)
        self.check.raise_if_any()
        return builder.partial()


class PartialBuilder:
    """The partial tables of an image-based session's frames, built as frames come: frames
    added in any order and over many calls give the partial of them all (a Dask worker's
    running sums). Undecodable frames are noted in the reducer's ``check``."""

    def __init__(self, reducer: ImageReducer) -> None:
        self.reducer = reducer
        self.table, self.merl = reducer.new_tables()
        self.angular = ImageAngular(reducer.rig, reducer.model, self.table)
        self.steps: set[int] = set()
        self.samples = 0
        self.data: dict[int, dict[str, np.ndarray]] = {}

    def add(self, frames: Iterable[list[StepRecord]]) -> None:
        """Bin ``frames`` (rows of :attr:`ImageReducer.frames`) into the sums."""
        frames = list(frames)
        for recs in frames:
            if recs[0].step in self.steps:  # e.g. a task run twice on one worker
                raise PartialError(f"frame at step {recs[0].step} was binned twice: each frame "
                                   "must be reduced once")
        for step, count, arrays in self.reducer.reduce(frames, self.table, self.merl,
                                                       self.angular):
            self.steps.add(step)
            self.samples += count
            if arrays is not None:
                self.data[step] = arrays

    def partial(self) -> ReductionPartial:
        """The frames added so far, as a partial."""
        return ReductionPartial(self.reducer.key, frozenset(self.steps),
                                {"isotropic": self.table.partial(), "merl": self.merl.partial()},
                                self.samples, self.data)


def iter_session_samples(
    session_dir: str | Path,
    *,
    min_cos: float = DEFAULT_MIN_COS,
    max_frames: int | None = None,
    drift: list[float] | None = None,
    bundle: str | Path | CalibrationBundle | None = None,
) -> Iterator[FrameSamples]:
    """Yield the BRDF samples of every captured sample frame of an image-based session, one
    frame at a time (at most ``max_frames``). ``drift``, if given, receives the white
    reference's peak-to-peak change in % of its mean. ``bundle``: the calibration bundle to
    apply (default: the session's copy, if any)."""
    reducer = ImageReducer.open(session_dir, bundle, min_cos)
    if drift is not None:
        drift.append(reducer.drift_pct)
    yield from reducer.samples(reducer.frames[:max_frames])
    reducer.check.raise_if_any()


def frame_angular(angular: ImageAngular, fs: FrameSamples) -> dict[str, np.ndarray] | None:
    """A frame's frame-bins with their angular terms, as a partial's frame data (None when
    the rig states no angular error or the frame lacks its pixels or joints)."""
    if fs.pixels is None or not fs.shape or not fs.joints:
        return None
    fb = angular.frame_bins(fs.joints, fs.shape, fs.pixels, fs.wi, fs.wo, fs.brdf)
    return None if fb is None else fb.to_arrays()


def bin_frames(frames: Iterable[FrameSamples], table: IsotropicTable, merl: MerlTable,
               progress: Callable[[int, int], None] | None, total: int, *,
               fused: bool = True, threads: bool = True) -> tuple[int, int]:
    """Bin each frame's per-pixel samples into both tables, one frame at a time (memory does
    not grow with the session); returns (samples, frames) binned. ``fused``: through the
    fused kernels (:mod:`acquisition.reduction.fusedbinning`) where they apply, the MERL
    table and part of the isotropic one in a helper thread (``threads``; frames of
    :data:`~acquisition.reduction.fusedbinning.HELPER_FROM_SAMPLES` samples or more), else
    (and as their reference) through the tables' own ``add`` methods: the same tables bit for
    bit."""
    samples = count = 0
    pool = helper_pool() if threads else None
    for fs in frames:
        if not (fused and bin_frame(fs.wi, fs.wo, fs.brdf, fs.variance, fs.calibration_rel,
                                    table, merl, helper_for(fs.count, pool))):
            _bin_reference(fs, table, merl)
        samples += fs.count
        count += 1
        if progress:
            progress(count, total)
    return samples, count


def _bin_reference(fs: FrameSamples, table: IsotropicTable, merl: MerlTable) -> None:
    """One frame into both tables through their ``add`` methods (the reference path)."""
    merl.add_vectors(fs.wi, fs.wo, fs.brdf)
    angles = sample_poses(fs.wi, fs.wo)  # libm's atan2: the same bits on every CPU
    budget = {}
    if table.tracks_uncertainty:
        nan = np.full(fs.brdf.shape, np.nan)
        rel = np.full(3, np.nan) if fs.calibration_rel is None else fs.calibration_rel
        budget = {"variances": {"noise": nan if fs.variance is None else fs.variance},
                  "uncertainties": {"white_reference": np.abs(fs.brdf) * rel}}
    table.add(angles[:, 0], angles[:, 1], angles[:, 2], fs.brdf, **budget)


def reduce_image_session(
    session_dir: str | Path | SessionFolder,
    progress: Callable[[int, int], None] | None = None,
    *,
    merl_path: str | Path | None = None,
    min_cos: float = DEFAULT_MIN_COS,
    max_frames: int | None = None,
    bundle: str | Path | None = None,
    checkpoint: str | Path | None = None,
    checkpoint_every: int = CHECKPOINT_EVERY,
) -> ImageReduction:
    """Bin every valid sample pixel of an image-based session into the MERL and isotropic tables.

    Parameters
    ----------
    session_dir
        The session folder (its rig file must have ``[sample] image_based = true``), or its
        opened :class:`SessionFolder`.
    progress
        ``progress(done, total)`` after each frame.
    merl_path
        If given, the MERL table's mean is also written there as a MERL ``.binary`` file.
    min_cos
        Drop samples with cos θi or cos θr below this.
    max_frames
        Reduce only the first N sample frames (e.g. of a capture still running).
    bundle
        Calibration bundle folder to apply; default the session's own copy, if any.
    checkpoint, checkpoint_every
        A partial-tables file (:mod:`acquisition.reduction.checkpoint`): the frames it holds
        are taken from it, not reduced again, and it is rewritten every ``checkpoint_every``
        frames (0: only at the end) and once all are binned, so that an interrupted reduction
        resumes there.
    """
    t0 = time.monotonic()
    reducer = ImageReducer.open(session_dir, bundle, min_cos)
    table, merl = reducer.tables()
    angular = ImageAngular(reducer.rig, reducer.model, table)
    frames = reducer.frames[:max_frames]
    run = Checkpointed(reducer.key, {"isotropic": table, "merl": merl}, checkpoint,
                       checkpoint_every, inputs=(reducer.folder.path,))
    held = run.resume(f[0].step for f in frames)
    for step, count, arrays in reducer.reduce((f for f in frames if f[0].step not in held),
                                              table, merl, angular):
        run.frame_done(step, count, arrays)
        if progress:
            progress(len(run.steps), len(frames))
    reducer.check.raise_if_any()
    run.save()
    return reducer.finish(table, merl, run.partial(), t0, merl_path, resumed=run.resumed)
