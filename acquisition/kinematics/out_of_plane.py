"""Out-of-plane arcs: light arm in the x–z plane, camera arc turning about z, optional turntable.

Joints (degrees):

``light_theta``
    Light arm angle from the zenith in the x–z plane; positive towards +x, negative towards −x.
    The light direction is (sin t, 0, cos t).
``camera_theta``
    Camera arc angle from the zenith (θr), ≥ 0.
``camera_phi``
    Azimuth of the camera arc about z, from +x.
``sample_phi`` (optional turntable)
    Rotation of the sample about its normal; the isotropic pose does not depend on it.

Δφ is the camera azimuth minus the light azimuth, so a pose has two solutions: the light on the
+x side with ``camera_phi = Δφ``, or on the −x side with ``camera_phi = Δφ + 180``.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from .base import Geometry, Joints, Kinematics, Pose, wrap_deg


class OutOfPlaneArcs(Kinematics):
    """Light elevation arc, camera elevation arc with azimuth, optional sample turntable."""

    name = "out-of-plane-arcs"
    joint_names = ("light_theta", "camera_theta", "camera_phi")

    def __init__(self, limits, light_distance_m, camera_distance_m) -> None:  # type: ignore[no-untyped-def]
        if "sample_phi" in limits:
            self.joint_names = (*OutOfPlaneArcs.joint_names, "sample_phi")
        super().__init__(limits, light_distance_m, camera_distance_m)

    def forward_geometry(self, joints: Mapping[str, float]) -> Geometry:
        lt = np.radians(joints["light_theta"])
        ct = np.radians(joints["camera_theta"])
        cp = np.radians(joints["camera_phi"])
        sp = np.radians(joints.get("sample_phi", 0.0))
        light = np.array([np.sin(lt), 0.0, np.cos(lt)])
        camera = np.array([np.sin(ct) * np.cos(cp), np.sin(ct) * np.sin(cp), np.cos(ct)])
        # World → sample frame: rotate by −sample_phi about z.
        c, s = np.cos(-sp), np.sin(-sp)
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return Geometry(rot @ light, rot @ camera, self.light_distance_m, self.camera_distance_m)

    def inverse_candidates(self, pose: Pose) -> list[Joints]:
        out: list[Joints] = []
        for light_sign, phi_offset in ((1.0, 0.0), (-1.0, 180.0)):
            base = wrap_deg(pose.delta_phi + phi_offset)
            for phi in (base, base - 360.0, base + 360.0):
                joints = {
                    "light_theta": light_sign * pose.theta_i,
                    "camera_theta": pose.theta_r,
                    "camera_phi": phi,
                }
                if "sample_phi" in self.joint_names:
                    joints["sample_phi"] = 0.0
                out.append(joints)
        return out
