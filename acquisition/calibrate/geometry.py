"""``gonio calibrate geometry``: measure the rig's zero offsets and the sample's tilt, on the rig.

The procedure (on out-of-plane-arcs and coaxial-arms rigs; :mod:`acquisition.calibrate.
out_of_plane` and :mod:`acquisition.calibrate.coaxial` choose each kind's configurations,
:mod:`acquisition.calibrate.mirror_model` is the measurement model of both):

1. A mirror stands in the sample's place (the simulated holder's ``"mirror"`` target; the
   operator is asked on a real rig). Its specular peak is located by coarse-to-fine scans of
   one axis at a time (:func:`~acquisition.calibrate.scans.locate_peak`) in several
   configurations, every target approached from below and then from above (the two directions
   captures use), so the backlash of every axis is measured and the zero offsets are those of
   the centre of the play.
2. Mirror peaks cannot separate every combination (out-of-plane: ``light_theta −
   2·tilt_about_y``; coaxial: the difference of the two arm azimuths' offsets, and at one
   stage rotation the arms' common offset and the stage tilt's offset from the sample tilt,
   which the coaxial procedure separates by turning the stage): the white target's cos θi
   fall-off across the light arm is the absolute reference that separates the rest.
3. One weighted least-squares fit (:func:`calibration.lsq.solve`) of every zero offset, the
   tilt, the backlash and the white amplitude gives their 1σ, the residual, the rank and the
   condition number of the problem, and names any combination still unobservable (and what
   it leaves to convention: the zero of a free joint — a stage rotation, a turntable — which
   only turns the tilt about the normal).
4. The result goes into the calibration bundle's ``geometry`` section, with its provenance.

On an image-based rig the camera's pointing error moves the point of the target a pixel sees
(:mod:`acquisition.calibrate.mirror_model`): the sphere's centre in the image is measured
first (:mod:`acquisition.calibrate.pointing`), the mirror peaks are read in a window of
:data:`MIRROR_WINDOW_PX` superpixels about where it puts the arms' common point, and the
pointing is a parameter of the same fit (the sphere's centre its observation), so its 1σ and
its correlation with the rest are the fit's.

Other kinematics (a light stage: nothing moves) are refused in one line.
"""

from __future__ import annotations

import math
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from acquisition.calibrate import coaxial, out_of_plane
from acquisition.calibrate.mirror_model import CameraOptics, MirrorModel, PeakObservation
from acquisition.calibrate.pointing import Pointing, measure_pointing
from acquisition.calibrate.scans import Procedure, Scope
from acquisition.config.rig import RigConfig, load_rig
from acquisition.devices.rig import OperatorPrompt, open_devices, require_operator
from acquisition.geometry.alignment import POINTING_PARAMS, TILT_PARAMS, Alignment
from acquisition.geometry.kinematics import CoaxialArms, OutOfPlaneArcs
from acquisition.geometry.pinhole import PinholeCamera
from acquisition.planning.planner import Planner
from acquisition.simworld.scene import white_material
from calibration.bundle import CalibrationBundle, provenance
from calibration.lsq import LsqResult, solve
from drivers.errors import ConfigError

PROCEDURES: dict[str, Procedure] = {OutOfPlaneArcs.name: out_of_plane.PROCEDURE,
                                    CoaxialArms.name: coaxial.PROCEDURE}
"""Rig-file ``kinematics`` → its calibration procedure."""

Progress = Callable[[int, int], None]
MIRROR_WINDOW_PX = 5
"""Side (superpixels) of the window an image-based rig reads a mirror peak in."""
WHITE_POINTS = 9
"""Points per side of the region of interest the white signal's model averages over."""


@dataclass
class GeometryRun:
    """What ``gonio calibrate geometry`` found (``to_json`` is what ``--json`` prints)."""

    bundle: Path
    frames: int
    alignment: Alignment
    fit: LsqResult
    residual_deg: float
    extra: dict[str, Any] = field(default_factory=dict)
    not_measured: list[str] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        a, fit = self.alignment, self.fit

        def entry(name: str, value: float) -> dict[str, float]:
            return {"value": value, "sigma": fit.sigma(name)}

        return {
            "zero_offset_deg": {k: entry(k, v) for k, v in a.zero_offset_deg.items()},
            "sample_tilt_deg": {"about_x": entry(TILT_PARAMS[0], a.sample_tilt_deg[0]),
                                "about_y": entry(TILT_PARAMS[1], a.sample_tilt_deg[1])},
            "residual_deg": self.residual_deg,
            "backlash_deg": {k: entry(f"backlash:{k}", v) for k, v in a.backlash_deg.items()},
            "rank": fit.rank, "parameters": len(fit.names), "condition_number": fit.condition,
            "chi2_dof": fit.chi2_dof, "unobservable": list(fit.unobservable),
            "not_measured": list(self.not_measured),
            "frames": self.frames, "bundle": str(self.bundle),
            **self._pointing(),
        }

    def _pointing(self) -> dict[str, Any]:
        """An image-based rig's camera pointing (deg, with 1σ) and the sphere's image."""
        if not self.extra:
            return {}
        a = self.alignment
        return {"camera_pointing_deg": {
            axis: {"value": a.camera_pointing_deg[k], "sigma": a.camera_pointing_sigma_deg[k]}
            for k, axis in enumerate(("x", "y"))}, **self.extra}


def procedure_for(rig: RigConfig) -> Procedure:
    """The rig kind's procedure; raises ConfigError (one line) for a kind it cannot calibrate."""
    if rig.kinematics_name not in PROCEDURES:
        raise ConfigError(f"{rig.path}: gonio calibrate geometry measures "
                          f"{' and '.join(PROCEDURES)} rigs (this one is "
                          f"{rig.kinematics_name}, whose arms do not move): calibrate its "
                          "geometry by hand")
    return PROCEDURES[rig.kinematics_name]


def calibrate_geometry(rig_path: str | Path, bundle_path: str | Path, *, seed: int = 0,
                       progress: Progress | None = None,
                       prompt: OperatorPrompt | None = None) -> GeometryRun:
    """Run the procedure (module docstring) and store its result in the bundle. On an
    image-based rig the camera's pointing is measured first (:mod:`acquisition.calibrate.
    pointing`)."""
    rig = load_rig(rig_path)
    procedure = procedure_for(rig)
    if rig.camera.driver != "simulated":
        require_operator(rig, prompt)
    planner = Planner(rig, approach=False)  # the procedure approaches from both sides itself
    with open_devices(rig, planner, material=white_material(rig), seed=seed,
                      prompt=prompt) as dev, tempfile.TemporaryDirectory(prefix="gonio-geo-") as tmp:
        bundle = CalibrationBundle.create(bundle_path, camera=dev.camera.describe())
        scope = Scope(dev, rig, Path(tmp), rig.camera.exposure_s, progress,
                      procedure.expected_frames(rig))
        pointing = measure_pointing(scope, rig, planner) if rig.sample.image_based else None
        optics = None if pointing is None else camera_optics(rig, pointing)
        dev.present("mirror")
        if optics is not None:
            scope.roi = mirror_window(optics)
        peaks = procedure.mirror_peaks(scope, rig)
        scope.roi = rig.camera.roi
        dev.present("white")
        whites = procedure.white_falloff(scope, rig)
        dev.present("sample")
    model = MirrorModel(scope.kinematics, optics)
    centres = [] if pointing is None else [pointing.centre]
    fit = solve(lambda x: model.residuals(x, peaks, whites, centres),
                model.start(whites, (0.0, 0.0) if pointing is None
                            else (pointing.x_deg, pointing.y_deg)), model.names, model.scales)
    run = _result(bundle.path, scope.count, model, fit, peaks, pointing)
    run.not_measured = [f"{n} zero offset (turns only the sample tilt about the normal: the "
                        "tilt is stated in the frame of the commanded angle)"
                        for n in model.kinematics.free_joints]
    bundle.set_geometry({**run.alignment.to_dict(), "fit": _finite(run.to_json())},
                        provenance(rig=str(rig.path), rig_name=rig.name, seed=seed,
                                   procedure=procedure.description
                                             + (" + sphere pointing" if pointing else ""),
                                   peaks=len(peaks), white_frames=len(whites)))
    return run


def camera_optics(rig: RigConfig, pointing: Pointing) -> CameraOptics:
    """An image-based rig's camera for the model: its mirror window centred on the superpixel
    nearest where the measured pointing puts the arms' common point, the white signal averaged
    over :data:`WHITE_POINTS`² points spanning the region of interest."""
    k = rig.camera.intrinsics
    assert k is not None  # an image-based rig file states them
    intrinsics = k.at(pointing.shape)
    camera = rig.kinematics().forward_geometry(pointing.centre.joints).camera_dir
    origin = PinholeCamera.looking_at_origin(intrinsics, pointing.shape, camera,
                                             rig.camera_distance_m).pointed(
        pointing.x_deg, pointing.y_deg).project(np.zeros(3))
    half = (MIRROR_WINDOW_PX - 1) / 2.0
    corner = [int(round(float(v) - half)) for v in origin]
    x0, y0, x1, y1 = rig.camera.roi
    grid = np.stack(np.meshgrid(np.linspace(x0, x1 - 1, min(WHITE_POINTS, x1 - x0)),
                                np.linspace(y0, y1 - 1, min(WHITE_POINTS, y1 - y0))), axis=-1)
    return CameraOptics(intrinsics, rig.camera_distance_m, rig.light_distance_m,
                        (corner[0] + half, corner[1] + half), grid.reshape(-1, 2),
                        rig.sample.centre_m)


def mirror_window(optics: CameraOptics) -> tuple[int, int, int, int]:
    """The superpixels (x0, y0, x1, y1) the mirror peaks are read in: the
    :data:`MIRROR_WINDOW_PX` square about :attr:`CameraOptics.mirror_pixel`."""
    half = (MIRROR_WINDOW_PX - 1) / 2.0
    x0, y0 = (int(round(v - half)) for v in optics.mirror_pixel)
    return x0, y0, x0 + MIRROR_WINDOW_PX, y0 + MIRROR_WINDOW_PX


def _finite(value: Any) -> Any:
    """``value`` with every non-finite number (an undetermined σ) as None (JSON null)."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_finite(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _result(bundle: Path, frames: int, model: MirrorModel, fit: LsqResult,
            peaks: list[PeakObservation], pointing: Pointing | None) -> GeometryRun:
    """The alignment (offsets, tilt, backlash, their covariance; the camera's pointing) and
    the fit's figures."""
    values = dict(zip(fit.names, fit.values.tolist(), strict=True))
    names = (*model.axes, *TILT_PARAMS, *model.backlash, *model.pointing)
    idx = [fit.names.index(n) for n in names]
    p = pointing
    alignment = Alignment({a: values[a] for a in model.axes},
                          (values[TILT_PARAMS[0]], values[TILT_PARAMS[1]]), names,
                          fit.covariance[np.ix_(idx, idx)],
                          {a: values[f"backlash:{a}"] for a in model.axes},
                          (values.get(POINTING_PARAMS[0], 0.0), values.get(POINTING_PARAMS[1], 0.0)),
                          (0.0, 0.0) if p is None else (fit.sigma(POINTING_PARAMS[0]),
                                                        fit.sigma(POINTING_PARAMS[1])))
    resid = [fit.residuals[k] * o.sigma_deg for k, o in enumerate(peaks)]
    extra = {} if p is None else {"sphere_radius_px": p.radius_px,
                                  "camera_distance_m": p.camera_distance_m}
    return GeometryRun(bundle, frames, alignment, fit,
                       float(np.sqrt(np.mean(np.square(resid)))) if resid else 0.0, extra)
