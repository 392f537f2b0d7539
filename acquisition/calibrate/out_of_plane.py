"""The geometric calibration's configurations on an out-of-plane-arcs rig.

1. Mirror: for each incidence of :data:`INCIDENCES_DEG`, with the light on the −x side, the
   camera's elevation and then its azimuth are scanned across the specular peak, coarse then
   fine (:func:`~acquisition.calibrate.scans.locate_peak`); with the light on the +x side (at
   :data:`PLUS_X_INCIDENCES_DEG`), where the camera's azimuth limit keeps it just off the
   mirror plane, its elevation is scanned. Each configuration is measured twice, every target
   approached from below and then from above (the two directions captures use), so the
   backlash of every axis is measured and the zero offsets are those of the centre of the play.
2. Mirror peaks see the light arm's offset only as ``light_theta − 2·tilt_about_y``; the white
   target's cos θi fall-off across the light arm (the light at ± :data:`WHITE_ANGLES_DEG`, the
   camera :data:`WHITE_CAMERA` off the normal out of the light's plane, both approaches) is the
   absolute reference that separates them.
"""

from __future__ import annotations

import math

from acquisition.calibrate import mirror_model as mm
from acquisition.calibrate.scans import COARSE, FINE, Procedure, Scope, locate_peak, scan_points
from acquisition.config.rig import RigConfig

AXES = ("light_theta", "camera_theta", "camera_phi")
INCIDENCES_DEG = (30.0, 60.0)
"""Light elevations of the mirror configurations with the light on −x."""
PLUS_X_INCIDENCES_DEG = (30.0, 60.0)
"""Those with the light on +x, where the camera azimuth's limit keeps the camera just off the
mirror plane (a lamp of finite size then shifts an elevation peak by ≈ 0.005° at 60°, a little
unlike in the plane: part of :data:`~acquisition.calibrate.scans.PEAK_FLOOR_DEG`)."""
WHITE_ANGLES_DEG = (50.0, 62.0, 74.0)
"""Light elevations (both sides) of the white fall-off."""
PHI_EDGE_DEG = 1.5
"""How far inside its limit the camera azimuth stays for the +x configurations."""
WHITE_CAMERA = {"camera_theta": 10.0, "camera_phi": 90.0}
"""The camera's joints (deg) during the white fall-off: out of the light's plane (the two
sides see it alike), and off the normal, where a camera's image would turn over as a zero
offset moves it across (the image's up is the normal projected: an image-based rig's region of
interest would jump between two points of the target)."""


def expected_frames(rig: RigConfig) -> int:
    coarse, fine = scan_points(*COARSE), scan_points(*FINE)
    minus, plus = 2 * (coarse + fine) + 2 * fine, coarse + fine + 2
    return 2 * (len(INCIDENCES_DEG) * minus + len(PLUS_X_INCIDENCES_DEG) * plus) \
        + 4 * len(WHITE_ANGLES_DEG)


def mirror_peaks(scope: Scope, rig: RigConfig) -> list[mm.PeakObservation]:
    """Every mirror configuration, approached from below and from above."""
    return [obs for ti in INCIDENCES_DEG for s in (1, -1)
            for obs in _mirror_configurations(scope, rig, ti, s)]


def _mirror_configurations(scope: Scope, rig: RigConfig, theta: float, s: int
                           ) -> list[mm.PeakObservation]:
    """The −x configuration (elevation and azimuth peaks) and the +x one (elevation) at light
    elevation ``theta``, every axis approached from side ``s``."""
    approach = dict.fromkeys(AXES, s)
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


def white_falloff(scope: Scope, rig: RigConfig) -> list[mm.WhiteObservation]:
    """The white target's signal with the light at ± each of :data:`WHITE_ANGLES_DEG`, the
    camera at :data:`WHITE_CAMERA` (approached from below), the light approached from both
    sides."""
    noise = math.radians(rig.axes["light_theta"].position_noise_deg)
    scope.exposure_s = rig.camera.exposure_s
    out = []
    for s in (1, -1):
        for theta in WHITE_ANGLES_DEG:
            for side in (1, -1):
                lt = side * theta
                approach = {"light_theta": s, **dict.fromkeys(WHITE_CAMERA, 1)}
                joints = scope.go({"light_theta": lt, **WHITE_CAMERA}, approach)
                r = scope.read()
                rel = math.hypot(r.rel_sigma, math.tan(math.radians(theta)) * noise)
                out.append(mm.WhiteObservation(joints, approach, math.log(r.signal), rel))
    return out


PROCEDURE = Procedure("mirror peaks + white fall-off", mirror_peaks, white_falloff,
                      expected_frames)
