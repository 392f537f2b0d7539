"""A kinematics plug-in corrected by a measured :class:`~acquisition.geometry.alignment.Alignment`.

Joint arrays are the angles gonio commands and reads back (the rig file's model of the ticks);
the arms stand at those angles plus the axes' zero offsets, less half their backlash on the
side captures approach from (:meth:`~acquisition.geometry.alignment.Alignment.
effective_offsets`), and the sample's true frame is the holder's turned by the sample tilt. So:

* :meth:`CalibratedKinematics.arm_directions_array` — where the arms really are (the motion
  guard checks the commanded joints through it);
* :meth:`CalibratedKinematics.forward_array` — the directions in the true sample frame;
* :meth:`CalibratedKinematics.inverse_array` — the commanded joints that realise a pose on the
  real rig: the plug-in's own solutions less the offsets, refined by Gauss–Newton through the
  tilt. A pose no joints realise exactly (the light on the normal of a sample tilted out of the
  light's plane) keeps the nearest solution when it lies within the tilt's magnitude of it.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from acquisition.geometry.alignment import Alignment
from acquisition.geometry.kinematics.base import (
    Kinematics,
    directions_from_poses,
    wrap_deg_array,
)

NEWTON_STEPS = 6
"""Gauss–Newton iterations of the inverse (each one converges ≈ quadratically)."""
STEP_DEG = 1e-4
"""Finite-difference step of the inverse's Jacobian, deg."""
EXACT_DEG = 1e-6
"""Residual (deg) of an exact inverse solution."""


class CalibratedKinematics(Kinematics):
    """``base`` with zero offsets and sample tilt applied (see the module docstring)."""

    def __init__(self, base: Kinematics, alignment: Alignment) -> None:
        self.base = base
        self.alignment = alignment
        self.name = base.name
        self.joint_names = base.joint_names
        self.free_joints = base.free_joints
        self.moving_arms = base.moving_arms
        super().__init__(base.limits, base.light_distance_m, base.camera_distance_m)
        self._rot = alignment.rotation()
        self._essential = [k for k, n in enumerate(self.joint_names) if n not in self.free_joints]
        self._slack_deg = float(np.hypot(*alignment.sample_tilt_deg)) + EXACT_DEG

    def true_joints(self, joints: np.ndarray) -> np.ndarray:
        """Where the arms stand (deg) for joints (N, J) approached as captures approach them."""
        joints = np.asarray(joints, float)
        return joints + self.alignment.effective_offsets(self.joint_names, joints, self._lo)

    def arm_directions_array(self, joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.base.arm_directions_array(self.true_joints(joints))

    def forward_array(self, joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        light, camera = self.base.forward_array(self.true_joints(joints))
        return light @ self._rot, camera @ self._rot  # v_sample = Rᵀ v_holder, row-wise

    def inverse_array(self, poses: np.ndarray, hold: Mapping[str, float] | None = None) -> np.ndarray:
        start = self.base.inverse_array(poses, hold)
        start = start - self.alignment.offsets(self.joint_names)
        n, k, j = start.shape
        rows = start.reshape(n * k, j)
        target = np.repeat(poses, k, axis=0)
        ok = ~np.any(np.isnan(rows), axis=1)
        solved, residual = self._refine(rows[ok], target[ok])
        out = np.full_like(rows, np.nan)
        good = np.flatnonzero(ok)[residual <= self._slack_deg]
        out[good] = solved[residual <= self._slack_deg]
        return out.reshape(n, k, j)

    def _residual(self, joints: np.ndarray, target: np.ndarray) -> np.ndarray:
        """Smooth residual (≈ deg) of the isotropic pose: the light's and the camera's cos θ,
        their dot product and the z of their cross product against the target's — invariant
        under a turn about the normal, and smooth at the normal, where θ and Δφ are not."""
        light, camera = self.forward_array(joints)
        want_l, want_c = directions_from_poses(target)
        got = np.column_stack([light[:, 2], camera[:, 2], np.sum(light * camera, axis=1),
                               np.cross(light, camera)[:, 2]])
        want = np.column_stack([want_l[:, 2], want_c[:, 2], np.sum(want_l * want_c, axis=1),
                                np.cross(want_l, want_c)[:, 2]])
        return np.degrees(got - want)

    def _pose_error_deg(self, joints: np.ndarray, target: np.ndarray) -> np.ndarray:
        """Largest error (deg) of θi, θr and Δφ·min(sin θi, sin θr) against the target."""
        pose = self.poses_array(joints)
        w = np.minimum(np.sin(np.radians(target[:, 0])), np.sin(np.radians(target[:, 1])))
        return np.max(np.abs(np.column_stack([
            pose[:, 0] - target[:, 0], pose[:, 1] - target[:, 1],
            wrap_deg_array(pose[:, 2] - target[:, 2]) * np.abs(w)])), axis=1)

    def _refine(self, joints: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Gauss–Newton on the essential joints; the solutions and their residuals (deg)."""
        joints = joints.copy()
        if not len(joints):
            return joints, np.zeros(0)
        for _ in range(NEWTON_STEPS):
            r = self._residual(joints, target)
            jac = np.empty((len(joints), r.shape[1], len(self._essential)))
            for col, idx in enumerate(self._essential):
                moved = joints.copy()
                moved[:, idx] += STEP_DEG
                jac[:, :, col] = (self._residual(moved, target) - r) / STEP_DEG
            step = np.einsum("nij,nj->ni", np.linalg.pinv(jac, rcond=1e-9), r)
            joints[:, self._essential] -= step
        return joints, self._pose_error_deg(joints, target)
