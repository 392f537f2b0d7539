"""Coaxial arms and a tilting sample: both arms turn about one vertical axis, in the horizontal plane.

World frame: z up; the arms lie in the horizontal plane through the sample centre. Joints
(degrees):

``light_azimuth``, ``camera_azimuth``
    Azimuth of each arm about the vertical axis, from +x towards +y. The light direction is
    (cos a, sin a, 0).
``stage_tilt``
    Tilt of the sample normal out of the horizontal plane, about the world y axis: the normal
    is (cos t, 0, sin t), so at 0° the sample faces the arm at azimuth 0.
``stage_rotation`` (optional)
    Rotation of the sample about its own normal; the isotropic pose does not depend on it.

Inverse: the light and camera directions span a plane that must become the horizontal plane.
With p the unit normal of that plane in the sample frame, the tilt is ±asin(p_z) — the two
solutions, mirror images through the horizontal plane — and the arm azimuths are the
directions' angles within the plane, measured from the projection of the sample normal.
Retro-reflection (light and camera parallel) leaves p free; any p ⊥ the light is used.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from acquisition.geometry.kinematics.base import JointLimits, Kinematics, directions_from_poses


class CoaxialArms(Kinematics):
    """Light and camera arms on one vertical axis, sample on a tilt (+ rotation) stage."""

    name = "coaxial-arms"
    joint_names = ("light_azimuth", "camera_azimuth", "stage_tilt")

    def __init__(
        self, limits: Mapping[str, JointLimits], light_distance_m: float, camera_distance_m: float
    ) -> None:
        if "stage_rotation" in limits:
            self.joint_names = (*CoaxialArms.joint_names, "stage_rotation")
            self.free_joints = ("stage_rotation",)
        super().__init__(limits, light_distance_m, camera_distance_m)

    def arm_directions_array(self, joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        al, ac = np.radians(joints[:, 0]), np.radians(joints[:, 1])
        zero = np.zeros_like(al)
        return (np.column_stack([np.cos(al), np.sin(al), zero]),
                np.column_stack([np.cos(ac), np.sin(ac), zero]))

    def stage_axes(self, joints: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Sample-frame axes x, y, z (each (N, 3)) expressed in the world frame."""
        t = np.radians(joints[:, 2])
        psi = np.radians(joints[:, 3]) if len(self.joint_names) == 4 else np.zeros_like(t)
        ct, st, cp, sp = np.cos(t), np.sin(t), np.cos(psi), np.sin(psi)
        zero = np.zeros_like(t)
        ez = np.column_stack([ct, zero, st])
        ex0 = np.column_stack([-st, zero, ct])
        ey0 = np.column_stack([zero, -np.ones_like(t), zero])
        ex = cp[:, None] * ex0 + sp[:, None] * ey0
        ey = -sp[:, None] * ex0 + cp[:, None] * ey0
        return ex, ey, ez

    def forward_array(self, joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        light_w, camera_w = self.arm_directions_array(joints)
        ex, ey, ez = self.stage_axes(joints)

        def to_sample(v: np.ndarray) -> np.ndarray:
            return np.column_stack([np.sum(v * ex, 1), np.sum(v * ey, 1), np.sum(v * ez, 1)])

        return to_sample(light_w), to_sample(camera_w)

    def inverse_array(self, poses: np.ndarray, hold: Mapping[str, float] | None = None) -> np.ndarray:
        wi, wo = directions_from_poses(poses)
        p = np.cross(wi, wo)
        norm = np.linalg.norm(p, axis=1)
        retro = norm < 1e-12
        # Retro-reflection: any plane through the light works; take the one containing y.
        p[retro] = np.column_stack([-wi[retro, 2], np.zeros(retro.sum()), wi[retro, 0]])
        p /= np.linalg.norm(p, axis=1, keepdims=True)
        q_len = np.hypot(p[:, 0], p[:, 1])
        with np.errstate(invalid="ignore", divide="ignore"):
            q = np.column_stack([-p[:, 2] * p[:, 0], -p[:, 2] * p[:, 1], q_len**2]) / q_len[:, None]
        n = len(poses)
        rows = []
        for s in (1.0, -1.0):
            tilt = np.degrees(np.arctan2(s * p[:, 2], q_len))
            y_axis = s * np.cross(p, q)
            al = np.degrees(np.arctan2(np.sum(wi * y_axis, 1), np.sum(wi * q, 1)))
            ac = np.degrees(np.arctan2(np.sum(wo * y_axis, 1), np.sum(wo * q, 1)))
            for wl in (0.0, -360.0, 360.0):
                for wc in (0.0, -360.0, 360.0):
                    cols = [al + wl, ac + wc, tilt]
                    if len(self.joint_names) == 4:
                        cols.append(np.full(n, float((hold or {}).get("stage_rotation", 0.0))))
                    rows.append(np.column_stack(cols))
        out = np.stack(rows, axis=1)
        out[q_len < 1e-12] = np.nan  # both directions in the sample plane: no tilt realises it
        return out
