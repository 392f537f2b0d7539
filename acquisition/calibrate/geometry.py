"""``gonio calibrate geometry``: measure the rig's zero offsets and the sample's tilt, on the rig.

The procedure (an out-of-plane-arcs rig; :mod:`acquisition.calibrate.mirror_model` is its
measurement model):

1. A mirror stands in the sample's place (the simulated holder's ``"mirror"`` target; the
   operator is asked on a real rig). For each incidence of :data:`INCIDENCES_DEG`, with the
   light on the −x side, the camera's elevation and then its azimuth are scanned across the
   specular peak, coarse then fine (:func:`locate_peak`); with the light on the +x side (at
   :data:`PLUS_X_INCIDENCES_DEG`), where the camera's azimuth limit keeps it just off the mirror
   plane, its elevation is scanned. Each
   configuration is measured twice, every target approached from below and then from above
   (the two directions captures use), so the backlash of every axis is measured and the zero
   offsets are those of the centre of the play.
2. Mirror peaks see the light arm's offset only as ``light_theta − 2·tilt_about_y``; the white
   target's cos θi fall-off across the light arm (the light at ± :data:`WHITE_ANGLES_DEG`, the
   camera at the zenith, both approaches) is the absolute reference that separates them.
3. One weighted least-squares fit (:func:`calibration.lsq.solve`) of every zero offset, the
   tilt, the backlash and the white amplitude gives their 1σ, the residual, the rank and the
   condition number of the problem, and names any combination still unobservable.
4. The result goes into the calibration bundle's ``geometry`` section, with its provenance.
"""

from __future__ import annotations

import math
import tempfile
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from acquisition.calibrate import mirror_model as mm
from acquisition.calibrate.pointing import Pointing, measure_pointing
from acquisition.calibrate.scans import Scan, Scope, scan
from acquisition.config.rig import RigConfig, load_rig
from acquisition.devices.rig import OperatorPrompt, open_devices, require_operator
from acquisition.geometry.alignment import TILT_PARAMS, Alignment
from acquisition.geometry.kinematics import OutOfPlaneArcs
from acquisition.planning.planner import Planner
from acquisition.simworld.scene import white_material
from calibration.bundle import CalibrationBundle, provenance
from calibration.lsq import LsqResult, solve
from calibration.peaks import fit_peak
from drivers.errors import ConfigError

INCIDENCES_DEG = (30.0, 60.0)
"""Light elevations of the mirror configurations with the light on −x."""
PLUS_X_INCIDENCES_DEG = (30.0, 60.0)
"""Those with the light on +x, where the camera azimuth's limit keeps the camera just off the
mirror plane (a lamp of finite size then shifts an elevation peak by ≈ 0.005° at 60°, a little
unlike in the plane: part of :data:`PEAK_FLOOR_DEG`)."""
WHITE_ANGLES_DEG = (50.0, 62.0, 74.0)
"""Light elevations (both sides) of the white fall-off."""
COARSE = (4.0, 0.5)
"""Half width and step (deg, on the sphere) of the coarse scans around the expected peak."""
FINE = (0.9, 0.15)
"""Half width and step (deg, on the sphere) of the fine scans around the coarse peak."""
PEAK_FLOOR_DEG = 0.006
"""Added in quadrature to every fitted peak's 1σ: what the model leaves out (the lamp's size
pulls an elevation peak by a few thousandths of a degree; the mirror's flatness)."""
PHI_EDGE_DEG = 1.5
"""How far inside its limit the camera azimuth stays for the +x configurations."""

Progress = Callable[[int, int], None]


@dataclass
class GeometryRun:
    """What ``gonio calibrate geometry`` found (``to_json`` is what ``--json`` prints)."""

    bundle: Path
    frames: int
    alignment: Alignment
    fit: LsqResult
    residual_deg: float
    extra: dict[str, Any] = field(default_factory=dict)

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


def calibrate_geometry(rig_path: str | Path, bundle_path: str | Path, *, seed: int = 0,
                       progress: Progress | None = None,
                       prompt: OperatorPrompt | None = None) -> GeometryRun:
    """Run the procedure (module docstring) and store its result in the bundle. On an
    image-based rig the camera's pointing is measured first (:mod:`acquisition.calibrate.
    pointing`)."""
    rig = load_rig(rig_path)
    if rig.kinematics_name != OutOfPlaneArcs.name:
        raise ConfigError(f"{rig.path}: gonio calibrate geometry measures out-of-plane-arcs rigs "
                          f"(this one is {rig.kinematics_name}): calibrate its geometry by hand")
    if rig.camera.driver != "simulated":
        require_operator(rig, prompt)
    planner = Planner(rig, approach=False)  # the procedure approaches from both sides itself
    with open_devices(rig, planner, material=white_material(rig), seed=seed,
                      prompt=prompt) as dev, tempfile.TemporaryDirectory(prefix="gonio-geo-") as tmp:
        bundle = CalibrationBundle.create(bundle_path, camera=dev.camera.describe())
        scope = Scope(dev, rig, Path(tmp), rig.camera.exposure_s, progress, _expected_frames())
        pointing = measure_pointing(scope, rig, planner) if rig.sample.image_based else None
        dev.present("mirror")
        peaks = [obs for ti in INCIDENCES_DEG for s in (1, -1)
                 for obs in _mirror_configurations(scope, rig, ti, s)]
        dev.present("white")
        whites = _white_falloff(scope, rig)
        dev.present("sample")
    fit = solve(lambda x: mm.residuals(x, peaks, whites), _start(whites), mm.NAMES, mm.SCALES)
    run = _result(bundle.path, scope.count, fit, peaks, pointing)
    bundle.set_geometry({**run.alignment.to_dict(), "fit": _finite(run.to_json())},
                        provenance(rig=str(rig.path), rig_name=rig.name, seed=seed,
                                   procedure="mirror peaks + white fall-off"
                                             + (" + sphere pointing" if pointing else ""),
                                   peaks=len(peaks), white_frames=len(whites)))
    return run


def _finite(value: Any) -> Any:
    """``value`` with every non-finite number (an undetermined σ) as None (JSON null)."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_finite(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _expected_frames() -> int:
    coarse = int(round(2 * COARSE[0] / COARSE[1])) + 1
    fine = int(round(2 * FINE[0] / FINE[1])) + 1
    minus, plus = 2 * (coarse + fine) + 2 * fine, coarse + fine + 2
    return 2 * (len(INCIDENCES_DEG) * minus + len(PLUS_X_INCIDENCES_DEG) * plus) \
        + 4 * len(WHITE_ANGLES_DEG)


def _start(whites: list[mm.WhiteObservation]) -> np.ndarray:
    x = np.zeros(len(mm.NAMES))
    x[mm.NAMES.index(mm.AMPLITUDE)] = float(np.mean([
        w.log_signal - math.log(math.cos(math.radians(w.joints["light_theta"])))
        for w in whites]))
    return x


def locate_peak(scope: Scope, joints: Mapping[str, float], axis: str, approach: Mapping[str, int],
                *, stretch: float = 1.0, coarse: bool = True) -> tuple[float, float, dict]:
    """Scan ``axis`` across the peak near ``joints[axis]`` (coarse then fine; ``stretch``
    turns widths on the sphere into the axis' degrees); (peak deg, 1σ deg, joints there).

    A camera elevation's signals are multiplied by cos θ first: a BRDF is radiance over
    irradiance per projected solid angle, so a mirror's radiance carries a 1/cos θr that would
    pull the peak of the facet distribution towards grazing by w²·tan θ."""
    centre = joints[axis]
    what = f"mirror peak of {axis} near {centre:.1f}°"
    if coarse:
        s = scan(scope, joints, axis, centre, COARSE[0] * stretch, COARSE[1] * stretch, approach)
        centre = fit_peak(s.x_deg, _facet_signal(s), s.rel_sigma, what=what).centre_deg
        scope.expose_for(float(np.max(s.signal)))
    s = scan(scope, joints, axis, centre, FINE[0] * stretch, FINE[1] * stretch, approach)
    peak = fit_peak(s.x_deg, _facet_signal(s), s.rel_sigma, what=what)
    value = peak.centre_deg
    return value, math.hypot(peak.sigma_deg, PEAK_FLOOR_DEG), {**s.joints, axis: value}


def _facet_signal(s: Scan) -> np.ndarray:
    """The scan's signals, times cos θ of the camera's elevation for an elevation scan."""
    if s.axis != "camera_theta":
        return s.signal
    return s.signal * np.cos(np.radians(s.x_deg))


def _mirror_configurations(scope: Scope, rig: RigConfig, theta: float, s: int
                           ) -> list[mm.PeakObservation]:
    """The −x configuration (elevation and azimuth peaks) and the +x one (elevation) at light
    elevation ``theta``, every axis approached from side ``s``."""
    approach = {a: s for a in mm.AXES}
    out = []
    joints = {"light_theta": -theta, "camera_theta": theta, "camera_phi": 0.0}
    stretch = 1.0 / math.sin(math.radians(theta))
    ct, _, joints = locate_peak(scope, joints, "camera_theta", approach)
    cp, _, joints = locate_peak(scope, joints, "camera_phi", approach, stretch=stretch)
    ct, sct, joints = locate_peak(scope, joints, "camera_theta", approach, coarse=False)
    out.append(mm.PeakObservation(dict(joints), "camera_theta", approach,
                                  math.hypot(sct, _light_noise_deg(rig))))
    cp, scp, joints = locate_peak(scope, joints, "camera_phi", approach, stretch=stretch,
                                  coarse=False)
    out.append(mm.PeakObservation(dict(joints), "camera_phi", approach, scp))
    if theta in PLUS_X_INCIDENCES_DEG:
        out.append(_plus_x(scope, rig, theta, s))
    return out


def _plus_x(scope: Scope, rig: RigConfig, theta: float, s: int) -> mm.PeakObservation:
    """The light on +x: the camera azimuth just inside its limit on the brighter side of 180°
    (approached from inside), its elevation scanned across the peak."""
    lim = rig.axes["camera_phi"]
    sides = [(lim.max_deg - PHI_EDGE_DEG, 1), (lim.min_deg + PHI_EDGE_DEG, -1)]
    best, best_signal = sides[0], -1.0
    for cp, side in sides:
        scope.go({"light_theta": theta, "camera_theta": theta, "camera_phi": cp},
                 {"light_theta": s, "camera_theta": s, "camera_phi": side})
        reading = scope.read()
        if reading.signal > best_signal:
            best, best_signal = (cp, side), reading.signal
    approach = {"light_theta": s, "camera_theta": s, "camera_phi": best[1]}
    joints = {"light_theta": theta, "camera_theta": theta, "camera_phi": best[0]}
    _, sigma, joints = locate_peak(scope, joints, "camera_theta", approach)
    return mm.PeakObservation(dict(joints), "camera_theta", approach,
                              math.hypot(sigma, _light_noise_deg(rig)))


def _light_noise_deg(rig: RigConfig) -> float:
    """The light arm's stated position noise: it moves an elevation peak one for one (the
    scan's own axis shows its noise in the fit's scatter)."""
    return rig.axes["light_theta"].position_noise_deg


def _white_falloff(scope: Scope, rig: RigConfig) -> list[mm.WhiteObservation]:
    """The white target's signal with the light at ± each of :data:`WHITE_ANGLES_DEG`, the
    camera at the zenith, the light approached from both sides."""
    noise = math.radians(rig.axes["light_theta"].position_noise_deg)
    scope.exposure_s = rig.camera.exposure_s
    out = []
    for s in (1, -1):
        for theta in WHITE_ANGLES_DEG:
            for side in (1, -1):
                lt = side * theta
                joints = scope.go({"light_theta": lt, "camera_theta": 0.0, "camera_phi": 0.0},
                                  {"light_theta": s})
                r = scope.read()
                rel = math.hypot(r.rel_sigma, math.tan(math.radians(theta)) * noise)
                out.append(mm.WhiteObservation(joints, {"light_theta": s}, math.log(r.signal),
                                               rel))
    return out


def _result(bundle: Path, frames: int, fit: LsqResult, peaks: list[mm.PeakObservation],
            pointing: Pointing | None) -> GeometryRun:
    """The alignment (offsets, tilt, backlash, their covariance; the camera's pointing) and
    the fit's figures."""
    values = dict(zip(fit.names, fit.values.tolist(), strict=True))
    names = (*mm.AXES, *TILT_PARAMS, *mm.BACKLASH)
    idx = [fit.names.index(n) for n in names]
    p = pointing
    alignment = Alignment({a: values[a] for a in mm.AXES},
                          (values[TILT_PARAMS[0]], values[TILT_PARAMS[1]]), names,
                          fit.covariance[np.ix_(idx, idx)],
                          {a: values[f"backlash:{a}"] for a in mm.AXES},
                          (0.0, 0.0) if p is None else (p.x_deg, p.y_deg),
                          (0.0, 0.0) if p is None else (p.sigma_x_deg, p.sigma_y_deg))
    resid = [fit.residuals[k] * o.sigma_deg for k, o in enumerate(peaks)]
    extra = {} if p is None else {"sphere_radius_px": p.radius_px,
                                  "camera_distance_m": p.camera_distance_m}
    return GeometryRun(bundle, frames, alignment, fit,
                       float(np.sqrt(np.mean(np.square(resid)))) if resid else 0.0, extra)
