"""Reduction: a session's RAW frames → linear signals → BRDF samples → isotropic table.

Each frame is linearized (black level, saturation mask, exposure), averaged over the region of
interest, and divided by the white reference interpolated in time between its captures (which
also corrects slow light drift). With the reference's reflectance ρ and its geometry, a sample
signal S at incidence θi gives

    f = (S / S_ref) · (ρ / π) · (cos θi_ref / cos θi)   [sr⁻¹]

because the pixel value is proportional to radiance L = f · E and the point light's
irradiance is E = I cos θi / r² at both geometries.

With a calibration bundle (``bundle=`` or the one copied into the session folder), every
frame is linearized with the bundle's master dark for its exposure and ISO, flat field and
bad-pixel map.

Uncertainty (the table's budget, :mod:`acquisition.tables.uncertainty`). Each frame's ROI mean
gets its variance from a noise model — the bundle's at the frame's ISO, else the simulated
camera's sensor model, else (a real camera without a measured model) the scatter over the
ROI — and every sample carries two terms into its bin:

* ``noise`` (independent): f² · var S / S², the sample frame's own noise;
* ``white_reference`` (correlated: one reference normalises many samples):
  f · √(var S_ref) / S_ref, the noise of the interpolated white reference.

On a rig whose file states backlash, position noise or a lamp of finite size, or with a
geometric calibration applied (:mod:`acquisition.reduction.angular`), a sample also carries

* ``angular`` (independent): the arms' position noise, through the BRDF's local slope;
* ``source_size`` (independent): the uncertainty of the correction for the lamp's blur (the
  value is corrected for it);
* ``geometry_calibration`` (correlated): the calibration's own 1σ;
* ``backlash`` (correlated): the uncertainty of the correction for a backlash the rig file
  states (each arm stands b/2 behind the side every target is approached from: corrected).

With a geometric calibration (the bundle's ``geometry`` section) or a stated backlash the
read-back joints go through the corrected model
(:class:`~acquisition.reduction.samplegeometry.SampleGeometry`): it gives the samples'
angles, cos θi (and the white reference's) and their bins.

Each bin's ``std_error`` is the root sum of squares of its terms;
:attr:`Reduction.predicted_variance` is its square. Each bin also keeps the mean read-back
(θi, θr, Δφ) of its samples.

An HDR session's bracket (journal rows noted ``hdr=<first step>:<k>``) is one sample: its
frames are linearized with variances (the bundle's noise model, else a simulated camera's
nominal one), merged per superpixel with inverse-variance weights (clipped samples weigh 0,
:func:`calibration.hdr.merge`), and the ROI mean is taken of the merge. Only brackets the
journal records as complete are used.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from acquisition.config.plan import PlanSpec
from acquisition.config.rig import RigConfig
from acquisition.config.sensor import nominal_noise_model
from acquisition.geometry.kinematics import Pose
from acquisition.reduction import CHECKPOINT_EVERY
from acquisition.reduction.angular import (
    ANGULAR_TERM,
    BACKLASH_TERM,
    CALIBRATION_TERM,
    SOURCE_CORRECTION_FRACTION,
    SOURCE_TERM,
    AngularSources,
    angular_terms,
)
from acquisition.reduction.badframes import FrameCheck
from acquisition.reduction.checkpoint import reduction_key
from acquisition.reduction.fixedorder import weighted_variance
from acquisition.reduction.samplegeometry import SampleGeometry
from acquisition.session.engine import POSE, REFERENCE
from acquisition.session.folder import SessionFolder
from acquisition.session.hdr import HDR_DONE_META, camera_noise_model, hdr_group
from acquisition.session.journal import StepRecord
from acquisition.tables import IsotropicTable
from acquisition.tables.partial import ReductionPartial
from calibration.bundle import SCALARS_FILE, CalibrationBundle
from calibration.hdr import merge
from calibration.linearize import LinearImage, NoiseModel, linearize, roi_mean
from calibration.raw import RawFrame, read_raw
from calibration.signal import roi_signal
from drivers.errors import SessionError


@dataclass(frozen=True)
class FrameSignal:
    """The region-of-interest mean of one frame, DN/s per channel, and its variance."""

    step: int
    signal: np.ndarray
    variance: np.ndarray
    n_valid: int
    at: float | None = None
    """When the frame was taken (device clock s, else host s); None: use the step number."""


@dataclass
class Reduction:
    """What :func:`reduce_session` produced."""

    table: IsotropicTable
    frames: int
    references: int
    drift_pct: float
    """Peak-to-peak change of the white reference over the session, % of its mean."""
    seconds: float
    predicted_variance: np.ndarray | None = None
    """Predicted variance of each bin's mean (table shape × 3, sr⁻²; NaN for empty bins): the
    square of the table's ``std_error`` (every term of its budget)."""
    bundle: Path | None = None
    """The calibration bundle applied, if any."""


def session_provenance(folder: SessionFolder, rig: RigConfig, plan: PlanSpec,
                       **extra: object) -> dict[str, object]:
    """What a reduced table records about where it came from (session, rig, plan, material,
    seed, time of reduction) plus ``extra`` entries."""
    return {
        "session": str(folder.path.resolve()),
        "rig": rig.name,
        "plan": plan.name,
        "material": folder.info.material,
        "seed": folder.info.seed,
        **extra,
        "reduced_at": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }


def binning_pose(rec: StepRecord) -> Pose:
    """The bin a step's sample goes to without a geometric calibration: its commanded pose.

    The read-back geometry (used for the value's cos θi) lies within the motion tolerance of
    the command; binning by the command keeps poses whose azimuth is degenerate (θ ≈ 0) in
    one deterministic bin, so a resumed session bins exactly like an uninterrupted one
    (:meth:`SampleGeometry.bin_pose` with a calibration).
    """
    return Pose(rec.theta_i, rec.theta_r, rec.delta_phi)


def frame_signal(
    path: Path, roi: tuple[int, int, int, int], step: int,
    bundle: CalibrationBundle | None = None,
) -> FrameSignal:
    """Linearize a frame (with the bundle's corrections, if given) and average its ROI
    (:func:`calibration.signal.roi_signal`)."""
    mean, var, n = roi_signal(path, roi, bundle)
    return FrameSignal(step, mean, var, n)


NOISE_SOURCES = ("calibration bundle", "sensor model", "ROI scatter")
"""Where a frame's variance comes from, in order of preference (:func:`noise_source`)."""


def noise_model(rig: RigConfig, iso: float, bundle: CalibrationBundle | None
                ) -> NoiseModel | None:
    """The noise model of a frame at ``iso``: the bundle's, else the simulated camera's
    nominal sensor model, else None (a real camera without a measured model)."""
    model = bundle.noise_for(iso) if bundle is not None else None
    if model is None and rig.camera.driver == "simulated":
        model = nominal_noise_model(rig, iso)
    return model


def noise_source(rig: RigConfig, iso: float, bundle: CalibrationBundle | None) -> str:
    """Which of :data:`NOISE_SOURCES` gives the variance of frames at ``iso``."""
    if bundle is not None and bundle.noise_for(iso) is not None:
        return NOISE_SOURCES[0]
    return NOISE_SOURCES[1] if rig.camera.driver == "simulated" else NOISE_SOURCES[2]


def sample_signal(path: Path, rig: RigConfig, step: int,
                  bundle: CalibrationBundle | None = None) -> FrameSignal:
    """The ROI mean (DN/s) of a frame and its variance from :func:`noise_model` (the ROI
    scatter where no model is known), with the bundle's corrections."""
    image = linearize_with_variance(path, rig, bundle)
    x0, y0, x1, y1 = rig.camera.roi
    mean, var, n = roi_mean(image, (x0, y0, x1 - x0, y1 - y0))
    return FrameSignal(step, np.asarray(mean, float), np.asarray(var, float), int(n))


def linearize_with_variance(path: Path, rig: RigConfig,
                            bundle: CalibrationBundle | None = None) -> LinearImage:
    """Linearize a frame with the bundle's corrections and a variance per superpixel from
    :func:`noise_model` (no variance where none is known: a real camera, no measured model)."""
    return read_raw(path, lambda frame: _linearized(frame, rig, bundle))


def _linearized(frame: RawFrame, rig: RigConfig, bundle: CalibrationBundle | None
                ) -> LinearImage:
    """:func:`linearize_with_variance` of a frame still held by LibRaw (one pass, no copy)."""
    iso = float(frame.iso or rig.camera.iso)
    if bundle is not None and bundle.noise_for(iso) is not None:
        return bundle.linearize(frame)
    noise = noise_model(rig, iso, None)
    if bundle is None:
        return linearize(frame, noise=noise)
    dark = bundle.dark_for(frame.exposure_s, iso) if frame.exposure_s else None
    return linearize(frame, dark=dark, flat=bundle.flat, bad_pixels=bundle.bad_pixels,
                     noise=noise)


def bracket_signal(
    paths: list[Path], rig: RigConfig, step: int, bundle: CalibrationBundle | None = None,
) -> FrameSignal:
    """The ROI mean (DN/s) and its variance of an HDR bracket's inverse-variance merge."""
    images = [linearize_with_variance(p, rig, bundle) for p in paths]
    iso = float(images[0].iso or rig.camera.iso)
    merged = merge(images, camera_noise_model(rig, iso, bundle))
    x0, y0, x1, y1 = rig.camera.roi
    mean, var, n = roi_mean(merged, (x0, y0, x1 - x0, y1 - y0))
    return FrameSignal(step, np.asarray(mean, float), np.asarray(var, float), int(n))


def reference_curves(
    refs: list[FrameSignal],
) -> tuple[Callable[[int], np.ndarray], Callable[[int], np.ndarray]]:
    """Reference signal and its variance at any time (``FrameSignal.at``, else step number),
    interpolated linearly between captures: with weights w, 1 − w the variance is
    w²·v₀ + (1 − w)²·v₁."""
    steps = np.array([r.step if r.at is None else r.at for r in refs], float)
    values = np.array([r.signal for r in refs])
    variances = np.array([r.variance for r in refs])
    eye = np.eye(len(refs))

    def at(when: float) -> np.ndarray:
        return np.array([np.interp(when, steps, values[:, c]) for c in range(values.shape[1])])

    def var_at(when: float) -> np.ndarray:
        w = np.array([np.interp(when, steps, eye[k]) for k in range(len(refs))])
        return weighted_variance(w, variances)  # no BLAS: the same bits on every CPU

    return at, var_at


def find_bundle(folder: SessionFolder, bundle: str | Path | None) -> CalibrationBundle | None:
    """The bundle given, else the session's copied calibration if it is a bundle, else None."""
    if bundle is not None:
        return CalibrationBundle.open(bundle)
    copied = folder.calibration if hasattr(folder, "calibration") else None
    if copied is not None and (Path(copied) / SCALARS_FILE).is_file():
        return CalibrationBundle.open(copied)
    return None


def reduce_session(
    session_dir: str | Path | SessionFolder,
    progress: Callable[[int, int], None] | None = None,
    *,
    bundle: str | Path | None = None,
    reference_axis: str = "step",
    geometry: bool = True,
    checkpoint: str | Path | None = None,
    checkpoint_every: int = CHECKPOINT_EVERY,
) -> Reduction:
    """Linearize every captured frame of a session and bin it into its plan's table.

    Parameters
    ----------
    session_dir:
        The session folder, or its opened :class:`SessionFolder` (whose rig and plan are
        used as loaded).
    bundle:
        Calibration bundle folder to apply; default the session's own copy, if any.
    reference_axis:
        ``"step"`` interpolates the white reference by step number (reproducible: an
        interrupted and resumed session reduces exactly like an uninterrupted one);
        ``"time"`` by capture time (device clock where it never runs back, else host clock),
        which follows a light drift through uneven step durations.
    geometry:
        Apply the bundle's geometric calibration (default); False reduces with the rig
        file's geometry as if the bundle had none (to see what the calibration changes).
    checkpoint, checkpoint_every:
        An image-based session's checkpoint (:mod:`acquisition.reduction.checkpoint`); a
        point session reads every frame before it bins (the angular budget terms need all
        samples), so it takes none.
    """
    folder = session_dir if isinstance(session_dir, SessionFolder) else SessionFolder(session_dir)
    if folder.rig().sample.image_based:
        from acquisition.reduction.image import reduce_image_session  # imports reduce: load lazily

        return reduce_image_session(folder, progress, bundle=bundle, checkpoint=checkpoint,
                                    checkpoint_every=checkpoint_every)
    return PointReducer.open(folder, bundle, reference_axis, geometry, progress).reduce()


@dataclass
class PointReducer:
    """A point session read once: every sample's value and budget (the angular terms need
    every sample), ready to bin into the plan's table — all at once, or any split of its
    frames into partial tables (:meth:`partial`) that merge to the same table, bit for bit."""

    template: IsotropicTable
    """The empty table: grid, provenance, the budget's terms."""
    binned: list[_Binned]
    key: str
    frames: int
    references: int
    drift_pct: float
    bundle: CalibrationBundle | None
    t0: float

    @classmethod
    def open(cls, session_dir: str | Path | SessionFolder, bundle: str | Path | None = None,
             reference_axis: str = "step", geometry: bool = True,
             progress: Callable[[int, int], None] | None = None,
             signals: Mapping[int, FrameSignal] | None = None) -> PointReducer:
        """Read every frame (``progress(done, total)`` after each) and work out each sample's
        value and budget (see :func:`reduce_session` for the arguments). ``signals``: frames'
        signals already read elsewhere (:func:`read_signal`, e.g. on Dask workers), by
        :attr:`SignalFrame.step`; the frames not in it are read here."""
        if reference_axis not in ("step", "time"):
            raise SessionError(f"reference_axis must be 'step' or 'time', got {reference_axis!r}")
        t0 = time.monotonic()
        folder = session_dir if isinstance(session_dir, SessionFolder) else SessionFolder(session_dir)
        cal = find_bundle(folder, bundle)
        rig, plan = folder.rig(), folder.plan()
        geo = SampleGeometry.of(rig, cal, calibrated=geometry)
        records, complete = _done_records(folder)
        frames = _SessionFrames(folder, rig, cal, _reference_coordinates(records, reference_axis),
                                FrameCheck(folder.path), signals or {})
        refs = _reference_signals(frames, records)
        white = _WhiteScale.of(refs, rig, _reference_cos(geo, records, rig))
        drift = _drift_pct(refs)
        template = _new_table(folder, rig, plan, drift, cal)
        template.provenance["noise_model"] = noise_source(rig, float(rig.camera.iso), cal)
        poses, brackets = _samples(records, complete)
        samples = _collect(poses, frames, brackets, geo, white, progress)
        frames.check.raise_if_any()
        independent, correlated, binned = _budget(samples, rig, geo)
        template.track_uncertainty(independent, correlated)
        if geo.alignment is not None:
            template.provenance["geometry_calibration"] = geo.alignment.to_dict()
        values = np.concatenate([[r.step, *r.signal, *r.variance] for r in refs])
        key = reduction_key("point", folder, cal, values, reference_axis=reference_axis,
                            geometry=geometry, edges=[list(map(float, e)) for e in (
                                template.theta_i_edges, template.theta_r_edges,
                                template.delta_phi_edges)])
        return cls(template, binned, key, len(poses), len(refs), drift, cal, t0)

    @property
    def steps(self) -> list[int]:
        """The journal step of every sample, in order."""
        return [b.step for b in self.binned]

    def new_table(self) -> IsotropicTable:
        """An empty table like :attr:`template` (grid, provenance, budget terms)."""
        t = self.template
        table = IsotropicTable(t.theta_i_edges, t.theta_r_edges, t.delta_phi_edges,
                               fold_delta_phi=t.fold_delta_phi, provenance=t.provenance)
        terms = t.uncertainty_terms
        table.track_uncertainty({k: v.description for k, v in terms.items() if not v.correlated},
                                {k: v.description for k, v in terms.items() if v.correlated})
        return table

    def partial(self, steps: Iterable[int]) -> ReductionPartial:
        """The partial table of the samples of the frames ``steps``."""
        wanted = set(steps)
        table = self.new_table()
        _bin(table, [b for b in self.binned if b.step in wanted])
        held = frozenset(b.step for b in self.binned if b.step in wanted)
        return ReductionPartial(self.key, held, {"isotropic": table.partial()}, len(held))

    def reduction(self, partial: ReductionPartial) -> Reduction:
        """The reduction a (merged) partial of this session's frames finishes into: the table
        :func:`reduce_session` gives for those frames, bit for bit."""
        if partial.key != self.key:
            raise SessionError("this partial belongs to another reduction (session, calibration "
                               "or options differ): reduce its frames again")
        table = self.new_table()
        table.merge_partial(partial.tables["isotropic"])
        return self.result(table)

    def reduce(self) -> Reduction:
        """Every sample binned into the table: the session's reduction."""
        table = self.new_table()
        _bin(table, self.binned)
        return self.result(table)

    def result(self, table: IsotropicTable) -> Reduction:
        """The reduction that ``table`` (every sample binned) finishes."""
        return Reduction(table, self.frames, self.references, self.drift_pct,
                         time.monotonic() - self.t0, table.std_error**2,
                         None if self.bundle is None else self.bundle.path)


@dataclass(frozen=True)
class _Sample:
    """One sample before binning: where it goes, where it lies, its value and noise terms."""

    step: int
    bin_pose: Pose
    read_back: Pose
    joints: dict[str, float]
    value: np.ndarray
    noise_var: np.ndarray
    white_u: np.ndarray


def _collect(poses: list[StepRecord], frames: _SessionFrames, brackets: dict[int, list[StepRecord]],
             geo: SampleGeometry, white: _WhiteScale,
             progress: Callable[[int, int], None] | None) -> list[_Sample]:
    """Every usable sample's value f = S / S_ref · (ρ / π) · (cos θi_ref / cos θi), sr⁻¹, with
    its noise (f² var S / S²) and white-reference (f √var S_ref / S_ref) terms."""
    out = []
    for k, rec in enumerate(poses):
        fs = frames.sample(rec, brackets)
        read_back = geo.read_back(rec)
        cos_i = np.cos(np.radians(read_back.theta_i))
        if fs is not None and fs.n_valid > 0 and cos_i > 0:
            when = frames.when[rec.step]
            ref = white.at(when)
            f = fs.signal / ref * (white.rho / np.pi) * (white.cos_ref / cos_i)
            out.append(_Sample(rec.step, geo.bin_pose(rec), read_back, rec.joints_read or rec.joints_cmd,
                               f, f**2 * fs.variance / fs.signal**2,
                               np.abs(f) * np.sqrt(white.var_at(when)) / ref))
        if progress:
            progress(k + 1, len(poses))
    return out


@dataclass(frozen=True)
class _Binned:
    """One sample as the table bins it: its frame's step, bin pose, read-back pose, value
    (sr⁻¹) and budget (independent variances, correlated standard uncertainties)."""

    step: int
    bin_pose: Pose
    read_back: Pose
    value: np.ndarray
    variances: dict[str, np.ndarray]
    uncertainties: dict[str, np.ndarray]


def _budget(samples: list[_Sample], rig: RigConfig, geo: SampleGeometry
            ) -> tuple[dict[str, str], dict[str, str], list[_Binned]]:
    """(independent terms, correlated terms, each sample with its budget): the noise and
    white-reference terms, and where the rig states backlash or position noise, or a geometric
    calibration is applied, the angular terms (:mod:`acquisition.reduction.angular`, over all
    samples)."""
    sources = AngularSources.of(rig, geo)
    independent, correlated = dict(UNCERTAINTY_TERMS[0]), dict(UNCERTAINTY_TERMS[1])
    for on, term, where in ((sources.independent, ANGULAR_TERM, independent),
                            (sources.source, SOURCE_TERM, independent),
                            (sources.correlated, CALIBRATION_TERM, correlated),
                            (sources.stated_backlash, BACKLASH_TERM, correlated)):
        if on:
            where.update(term)
    names = geo.kinematics.joint_names
    joints = np.array([[s.joints[n] for n in names] for s in samples]).reshape(-1, len(names))
    claimed = np.array([s.read_back.as_tuple() for s in samples]).reshape(-1, 3)
    values = np.array([s.value for s in samples]).reshape(-1, 3)
    ang = angular_terms(sources, geo, joints, claimed, values)
    out = []
    for k, s in enumerate(samples):
        variances = {"noise": s.noise_var[None, :]}
        uncertainties = {"white_reference": s.white_u[None, :]}
        value = s.value / (1.0 + ang.source_bias[k])  # the lamp's blur corrected (0 for a point)
        if sources.independent:
            variances["angular"] = ang.variance[k][None, :]
        if sources.source:
            variances["source_size"] = (SOURCE_CORRECTION_FRACTION * ang.source_bias[k]
                                        * value)[None, :] ** 2
        if sources.correlated:
            uncertainties["geometry_calibration"] = ang.calibration[k][None, :]
        if sources.stated_backlash:
            uncertainties["backlash"] = ang.backlash[k][None, :]
        out.append(_Binned(s.step, s.bin_pose, s.read_back, value, variances, uncertainties))
    return independent, correlated, out


def _bin(table: IsotropicTable, binned: list[_Binned]) -> None:
    """Bin each sample at its bin pose, with its read-back angles and budget."""
    for b in binned:
        p, r = b.bin_pose, b.read_back
        table.add(np.array([p.theta_i]), np.array([p.theta_r]), np.array([p.delta_phi]),
                  b.value[None, :], at=(np.array([r.theta_i]), np.array([r.theta_r]),
                                        np.array([r.delta_phi])),
                  variances=b.variances, uncertainties=b.uncertainties)


def _reference_cos(geo: SampleGeometry, records: list[StepRecord], rig: RigConfig) -> float:
    """cos θi of the white reference: the rig file's angle, or with a corrected geometry (a
    calibration, a stated backlash) the mean over the reference steps' read-back poses."""
    if geo.corrections is None:
        return float(np.cos(np.radians(rig.white_reference.theta_i)))
    refs = [r for r in records if r.kind == REFERENCE]
    return float(np.mean([np.cos(np.radians(geo.read_back(r).theta_i)) for r in refs]))


def _done_records(folder: SessionFolder) -> tuple[list[StepRecord], set[int]]:
    """The journal's captured steps, and the HDR brackets it records as complete."""
    with folder.journal(readonly=True) as journal:
        records = [r for r in journal.steps() if r.status == "done"]
        groups = {g for g in (hdr_group(r.note) for r in records) if g is not None}
        complete = {g for g in groups if journal.meta(f"{HDR_DONE_META}{g}") is not None}
    if not records:
        raise SessionError(f"{folder.path} has no captured frame yet: run or resume the capture first")
    return records, complete


def _reference_coordinates(records: list[StepRecord], reference_axis: str) -> dict[int, float]:
    """Per step, where it sits on the axis the white reference is interpolated along.

    ``"step"``: the step number. ``"time"`` (the light drifts with time, not with step
    number): the device clock where every frame has one and it never runs back (a resumed
    simulated rig restarts its clock), else the host clock, else the step number.
    """
    dev_t = [r.device_time_s for r in sorted(records, key=lambda r: r.step)]
    if reference_axis == "step":
        return {r.step: float(r.step) for r in records}
    if all(t is not None for t in dev_t) and all(np.diff(np.array(dev_t, float)) >= 0):
        return {r.step: float(r.device_time_s) for r in records}  # type: ignore[arg-type]
    if all(r.completed_at is not None for r in records):
        return {r.step: float(r.completed_at) for r in records}  # type: ignore[arg-type]
    return {r.step: float(r.step) for r in records}


@dataclass(frozen=True)
class SignalFrame:
    """One frame a point reduction reads: a white-reference or sample row, or the rows of an
    HDR bracket (``bracket``: merged before the ROI mean)."""

    rows: tuple[StepRecord, ...]
    bracket: bool = False

    @property
    def step(self) -> int:
        """The journal step the frame's signal is known by (a bracket's first row)."""
        return self.rows[0].step


def signal_frames(session_dir: str | Path | SessionFolder) -> list[SignalFrame]:
    """Every frame a point reduction of the session reads: the white references, then the
    samples (plain frames and complete HDR brackets), in journal order."""
    folder = session_dir if isinstance(session_dir, SessionFolder) else SessionFolder(session_dir)
    refs, samples = split_samples(*_done_records(folder))
    return [SignalFrame((r,)) for r in refs] + samples


def split_samples(records: list[StepRecord], complete: set[int]
                  ) -> tuple[list[StepRecord], list[SignalFrame]]:
    """The white-reference rows among done ``records``, and the sample frames (plain frames
    and the HDR brackets recorded ``complete``), in journal order."""
    poses, brackets = _samples(records, complete)
    refs = [r for r in records if r.kind == REFERENCE]
    return refs, [SignalFrame((r,)) if (g := hdr_group(r.note)) is None
                  else SignalFrame(tuple(brackets[g]), bracket=True) for r in poses]


def read_signal(folder: SessionFolder, rig: RigConfig, cal: CalibrationBundle | None,
                frame: SignalFrame, check: FrameCheck) -> FrameSignal | None:
    """The ROI signal of one frame (an HDR bracket's merge), or None when a RAW file cannot be
    decoded (noted in ``check``)."""
    rec = frame.rows[0]
    if not frame.bracket:
        return check.load(rec, lambda: sample_signal(
            folder.frames_dir / str(rec.frame), rig, rec.step, cal))
    return check.load(frame.rows, lambda: bracket_signal(
        [folder.frames_dir / str(r.frame) for r in frame.rows], rig, rec.step, cal))


@dataclass(frozen=True)
class _SessionFrames:
    """Reads a session's frames into ROI signals stamped with their reference coordinate."""

    folder: SessionFolder
    rig: RigConfig
    cal: CalibrationBundle | None
    when: dict[int, float]
    """Reference-interpolation coordinate of each step (:func:`_reference_coordinates`)."""
    check: FrameCheck
    """Where frames that cannot be decoded are noted (None is returned for them)."""
    known: Mapping[int, FrameSignal] = dataclasses.field(default_factory=dict)
    """Signals read elsewhere, by step (:func:`read_signal`)."""

    def read(self, frame: SignalFrame) -> FrameSignal | None:
        """A frame's signal, stamped with its reference coordinate."""
        fs = self.known.get(frame.step)
        if fs is None:
            fs = read_signal(self.folder, self.rig, self.cal, frame, self.check)
        return None if fs is None else dataclasses.replace(fs, at=self.when[frame.step])

    def frame(self, rec: StepRecord) -> FrameSignal | None:
        """The ROI signal of one plain frame."""
        return self.read(SignalFrame((rec,)))

    def sample(self, rec: StepRecord, brackets: dict[int, list[StepRecord]]
               ) -> FrameSignal | None:
        """The ROI signal of a sample: a plain frame, or the merge of its HDR bracket."""
        g = hdr_group(rec.note)
        return self.frame(rec) if g is None else self.read(SignalFrame(tuple(brackets[g]), True))


def _reference_signals(frames: _SessionFrames, records: list[StepRecord]) -> list[FrameSignal]:
    """The white-reference frames' signals; SessionError if none, or one has no valid ROI."""
    refs = [fs for fs in (frames.frame(r) for r in records if r.kind == REFERENCE)
            if fs is not None]
    folder = frames.folder
    if not refs:
        frames.check.raise_if_any()
        raise SessionError(f"{folder.path} has no white-reference frame: resume the capture to take it")
    if any(r.n_valid == 0 for r in refs):
        raise SessionError(f"{folder.path}: a white-reference frame is saturated or dark in the ROI")
    return refs


@dataclass(frozen=True)
class _WhiteScale:
    """What turns a sample's signal into BRDF: the interpolated reference and its geometry."""

    at: Callable[[float], np.ndarray]
    """Reference signal (DN/s) at a reference coordinate."""
    var_at: Callable[[float], np.ndarray]
    """Its variance, (DN/s)²."""
    rho: np.ndarray
    """Reflectance of the reference (R, G, B)."""
    cos_ref: float
    """cos θi of the reference's geometry."""

    @classmethod
    def of(cls, refs: list[FrameSignal], rig: RigConfig, cos_ref: float) -> _WhiteScale:
        """From the reference frames' signals, the rig's reference reflectance and the
        reference's cos θi."""
        at, var_at = reference_curves(refs)
        return cls(at, var_at, np.asarray(rig.white_reference.reflectance, float), cos_ref)


def _drift_pct(refs: list[FrameSignal]) -> float:
    """Peak-to-peak change of the white reference, % of its mean (largest over colours)."""
    ref_signals = np.array([r.signal for r in refs])
    return float(np.max(np.ptp(ref_signals, axis=0) / np.mean(ref_signals, axis=0)) * 100.0)


def _new_table(folder: SessionFolder, rig: RigConfig, plan: PlanSpec, drift_pct: float,
               cal: CalibrationBundle | None) -> IsotropicTable:
    """The plan's empty table, with the session's provenance (and the bundle's, if any)."""
    table = IsotropicTable(
        plan.table.theta_i_edges, plan.table.theta_r_edges, plan.table.delta_phi_edges,
        provenance=session_provenance(folder, rig, plan, reference_drift_pct=drift_pct),
    )
    if cal is not None:
        table.provenance["calibration_bundle"] = str(cal.path.resolve())
    return table


def _samples(
    records: list[StepRecord], complete: set[int],
) -> tuple[list[StepRecord], dict[int, list[StepRecord]]]:
    """One record per sample: each plain pose frame, and the first row of each complete HDR
    bracket; and each such bracket's rows, by group."""
    brackets: dict[int, list[StepRecord]] = {}
    poses = []
    for r in records:
        g = hdr_group(r.note) if r.kind == POSE else None
        if g is None:
            if r.kind == POSE:
                poses.append(r)
        elif g in complete:
            if g not in brackets:
                poses.append(r)
            brackets.setdefault(g, []).append(r)
    return poses, brackets


UNCERTAINTY_TERMS = (
    {"noise": "the sample frame's noise (noise model, else ROI scatter), independent"},
    {"white_reference": "the interpolated white reference's noise, common to the samples it "
                        "normalises"},
)
"""(independent, correlated) terms of a point reduction's budget: name → description."""


