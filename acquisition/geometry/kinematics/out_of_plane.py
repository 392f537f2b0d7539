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
+x side with ``camera_phi = Δφ``, or on the −x side with ``camera_phi = Δφ + 180`` (each also
with ``camera_phi`` ± 360° where the limits allow).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from acquisition.geometry.kinematics.base import JointLimits, Kinematics, wrap_deg_array


class OutOfPlaneArcs(Kinematics):
    """Light elevation arc, camera elevation arc with azimuth, optional sample turntable."""

    name = "out-of-plane-arcs"
    joint_names = ("light_theta", "camera_theta", "camera_phi")

    def __init__(
        self, limits: Mapping[str, JointLimits], light_distance_m: float, camera_distance_m: float
    ) -> None:
        if "sample_phi" in limits:
            self.joint_names = (*OutOfPlaneArcs.joint_names, "sample_phi")
            self.free_joints = ("sample_phi",)
        super().__init__(limits, light_distance_m, camera_distance_m)

    def arm_directions_array(self, joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        lt, ct, cp = (np.radians(joints[:, k]) for k in range(3))
        light = np.column_stack([np.sin(lt), np.zeros_like(lt), np.cos(lt)])
        camera = np.column_stack([np.sin(ct) * np.cos(cp), np.sin(ct) * np.sin(cp), np.cos(ct)])
        return light, camera

    def forward_array(self, joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        light, camera = self.arm_directions_array(joints)
        if len(self.joint_names) == 3:
            return light, camera
        # World → sample frame: rotate by −sample_phi about z.
        sp = np.radians(joints[:, 3])
        c, s = np.cos(sp), np.sin(sp)

        def to_sample(v: np.ndarray) -> np.ndarray:
            return np.column_stack([c * v[:, 0] + s * v[:, 1], -s * v[:, 0] + c * v[:, 1], v[:, 2]])

        return to_sample(light), to_sample(camera)

    def inverse_array(self, poses: np.ndarray, hold: Mapping[str, float] | None = None) -> np.ndarray:
        n = len(poses)
        rows = []
        for light_sign, phi_offset in ((1.0, 0.0), (-1.0, 180.0)):
            base = wrap_deg_array(poses[:, 2] + phi_offset)
            for wrap in (0.0, -360.0, 360.0):
                cols = [light_sign * poses[:, 0], poses[:, 1], base + wrap]
                if len(self.joint_names) == 4:
                    cols.append(np.full(n, float((hold or {}).get("sample_phi", 0.0))))
                rows.append(np.column_stack(cols))
        return np.stack(rows, axis=1)
