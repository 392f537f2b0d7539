"""The geometric calibration's configurations on a coaxial-arms rig.

Both arms turn in the horizontal plane, so a mirror on the stage reflects the light into the
camera only when its true normal lies in that plane, along the arms' bisector:

* a scan of the stage tilt peaks where the true normal is horizontal, wherever the arms stand:
  it sees ``stage_tilt + tilt_about_y·cos ψ + tilt_about_x·sin ψ`` (ψ the stage rotation);
* a scan of the camera azimuth peaks where the arms' bisector meets the normal's azimuth: it
  sees ``light_azimuth + camera_azimuth − 2·(tilt_about_x·cos ψ − tilt_about_y·sin ψ)`` — only
  the sum of the arms' offsets (the light turned by +ε and the camera by −ε move no peak).

At one stage rotation a common offset of both arm azimuths with a tilt about x, and the stage
tilt's offset with a tilt about y, move every peak alike. The sample's tilt turns with the
stage rotation and the offsets do not, so the mirror is measured at the rotations
:data:`ROTATIONS_DEG`: coarse then fine scans of the stage tilt and of the camera azimuth, the
arms :data:`MIRROR_HALF_ANGLE_DEG` either side of the normal, every calibrated axis approached
from below and then from above (the stage rotation always from below, as captures approach
it). The arms' difference needs an absolute reference: the white target's cos θi fall-off
across the light arm (the light at ± :data:`WHITE_ANGLES_DEG` about the normal, the camera at
:data:`WHITE_CAMERA_DEG` beyond them, both approaches) measures the light's offset against the
normal. The arms turn in one plane and cannot pass each other: every configuration keeps them
in the order they stand in when the procedure starts.

Left to convention, and named as such (``not_measured``): the stage rotation's zero. It only
turns the sample's tilt about the normal, which no measurement of an isotropic sample sees, so
the tilt is stated in the frame of the commanded rotation (its backlash turns a 0.5° tilt by
< 0.001°). A rig without a stage rotation cannot separate the pairs above: the fit names them.
"""

from __future__ import annotations

import math

from acquisition.calibrate import mirror_model as mm
from acquisition.calibrate.scans import COARSE, FINE, Procedure, Scope, locate_peak, scan_points
from acquisition.config.rig import RigConfig

AXES = ("light_azimuth", "camera_azimuth", "stage_tilt")
ROTATION = "stage_rotation"
MIRROR_HALF_ANGLE_DEG = 30.0
"""The light at −30° and the camera at +30° azimuth about the normal (θi = θr = 30°)."""
ROTATIONS_DEG = (0.0, 85.0, -85.0)
"""Stage rotations of the mirror configurations (kept :data:`ROTATION_MARGIN_DEG` inside the
axis' limits)."""
ROTATION_MARGIN_DEG = 2.0
TILT_STRETCH = 0.5
"""Tilting the normal by δ turns the mirror direction by 2δ: scan widths on the sphere × ½."""
WHITE_ANGLES_DEG = (25.0, 40.0, 55.0)
"""Light azimuths (both sides of the normal) of the white fall-off."""
WHITE_CAMERA_DEG = 75.0
"""The camera's azimuth (on its side of the light) during the white fall-off: 20° beyond the
light's farthest, so the arms keep their clearance."""


def _rotations(rig: RigConfig) -> tuple[float | None, ...]:
    """The stage rotations to measure at (None: the rig has no rotation stage)."""
    if ROTATION not in rig.axes:
        return (None,)
    lim = rig.axes[ROTATION]
    lo, hi = lim.min_deg + ROTATION_MARGIN_DEG, lim.max_deg - ROTATION_MARGIN_DEG
    return tuple(dict.fromkeys(min(max(psi, lo), hi) for psi in ROTATIONS_DEG))


def expected_frames(rig: RigConfig) -> int:
    """Frames of a usual run: the second approach's fine scans start a backlash off the peak
    and are repeated once about it."""
    coarse, fine = scan_points(*COARSE), scan_points(*FINE)
    return len(_rotations(rig)) * (2 * (coarse + fine) + 4 * fine) + 4 * len(WHITE_ANGLES_DEG)


def _approach(s: int, psi: float | None) -> dict[str, int]:
    """Every calibrated axis from side ``s``, the stage rotation from below."""
    return {**dict.fromkeys(AXES, s), **({} if psi is None else {ROTATION: 1})}


def _order(scope: Scope) -> int:
    """+1 when the camera arm stands at a larger azimuth than the light arm, else −1."""
    where = scope.dev.motion.where_deg()
    return 1 if where["camera_azimuth"] > where["light_azimuth"] else -1


def _pose(light_deg: float, camera_deg: float, psi: float | None) -> dict[str, float]:
    joints = {"light_azimuth": light_deg, "camera_azimuth": camera_deg, "stage_tilt": 0.0}
    return joints if psi is None else {**joints, ROTATION: psi}


def mirror_peaks(scope: Scope, rig: RigConfig) -> list[mm.PeakObservation]:
    """At each stage rotation: the stage tilt's and the camera azimuth's peaks, approached
    from below (coarse, then fine) and then from above (fine, about the first peaks)."""
    noise = rig.axes["light_azimuth"].position_noise_deg
    half = _order(scope) * MIRROR_HALF_ANGLE_DEG
    out = []
    for psi in _rotations(rig):
        joints = _pose(-half, half, psi)
        for s in (1, -1):
            approach = _approach(s, psi)
            _, sigma, joints = locate_peak(scope, joints, "stage_tilt", approach,
                                           stretch=TILT_STRETCH, coarse=s == 1, recentre=2)
            out.append(mm.PeakObservation(dict(joints), "stage_tilt", approach, sigma))
            _, sigma, joints = locate_peak(scope, joints, "camera_azimuth", approach,
                                           coarse=s == 1, recentre=2)
            # the light's position noise moves the bisector's peak one for one
            out.append(mm.PeakObservation(dict(joints), "camera_azimuth", approach,
                                          math.hypot(sigma, noise)))
    return out


def white_falloff(scope: Scope, rig: RigConfig) -> list[mm.WhiteObservation]:
    """The white target's signal with the light at ± each of :data:`WHITE_ANGLES_DEG` about
    the normal, the camera beyond them, every axis approached from both sides."""
    noise = math.radians(rig.axes["light_azimuth"].position_noise_deg)
    psi = _rotations(rig)[0]
    order = _order(scope)
    scope.exposure_s = rig.camera.exposure_s
    out = []
    for s in (1, -1):
        approach = _approach(s, psi)
        for theta in WHITE_ANGLES_DEG:
            for side in (1, -1):
                joints = scope.go(_pose(side * theta, order * WHITE_CAMERA_DEG, psi), approach)
                r = scope.read()
                rel = math.hypot(r.rel_sigma, math.tan(math.radians(theta)) * noise)
                out.append(mm.WhiteObservation(joints, approach, math.log(r.signal), rel))
    return out


PROCEDURE = Procedure("mirror peaks of the stage tilt and the camera azimuth at each stage "
                      "rotation + white fall-off", mirror_peaks, white_falloff, expected_frames)
