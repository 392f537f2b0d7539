"""Light stage: a fixed camera and lights at fixed directions; a pose is a light index.

The single joint ``light`` is the index of the light that is on (a float holding an integer,
so that light stages fit the same joint-array code as moving rigs). Nothing moves: switching
lights has zero travel. A pose is reachable when some light realises it within
``tolerance_deg`` (in θi, θr and Δφ); the inverse returns every such light.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np

from acquisition.geometry.kinematics.base import (
    JointLimits,
    Kinematics,
    poses_from_directions,
    wrap_deg_array,
)

if TYPE_CHECKING:
    from acquisition.config.rig import RigConfig


class LightStage(Kinematics):
    """Fixed camera, lights at fixed directions (sample frame, normal +z)."""

    name = "light-stage"
    joint_names = ("light",)
    moving_arms = False

    def __init__(
        self,
        light_dirs: np.ndarray,
        camera_dir: np.ndarray,
        light_distance_m: float,
        camera_distance_m: float,
        tolerance_deg: float = 1e-6,
    ) -> None:
        dirs = np.asarray(light_dirs, dtype=float).reshape(-1, 3)
        if len(dirs) == 0:
            raise ValueError("light-stage kinematics needs at least one light direction")
        self.light_dirs = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
        cam = np.asarray(camera_dir, dtype=float)
        self.camera_dir = cam / np.linalg.norm(cam)
        self.tolerance_deg = tolerance_deg
        super().__init__({"light": JointLimits(0.0, float(len(dirs) - 1))}, light_distance_m,
                         camera_distance_m)
        self.light_poses = poses_from_directions(
            self.light_dirs, np.broadcast_to(self.camera_dir, self.light_dirs.shape)
        )
        """(θi, θr, Δφ) of every light, degrees."""

    @classmethod
    def from_rig(cls, rig: RigConfig) -> Kinematics:
        stage = rig.light_stage
        if stage is None:
            raise ValueError("light-stage kinematics needs a [light_stage] table")
        return cls(np.array(stage.light_dirs), np.array(stage.camera_dir), rig.light_distance_m,
                   rig.camera_distance_m, stage.tolerance_deg)

    def forward_array(self, joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        idx = np.rint(joints[:, 0]).astype(int)
        return self.light_dirs[idx], np.broadcast_to(self.camera_dir, (len(idx), 3)).copy()

    def inverse_array(self, poses: np.ndarray, hold: Mapping[str, float] | None = None) -> np.ndarray:
        lp = self.light_poses
        d_ti = np.abs(poses[:, None, 0] - lp[None, :, 0])
        d_tr = np.abs(poses[:, None, 1] - lp[None, :, 1])
        d_dp = np.abs(wrap_deg_array(poses[:, None, 2] - lp[None, :, 2]))
        # Δφ is meaningless when either direction is the normal.
        polar = (np.minimum(poses[:, None, 0], poses[:, None, 1]) < self.tolerance_deg) | (
            np.minimum(lp[None, :, 0], lp[None, :, 1]) < self.tolerance_deg
        )
        tol = self.tolerance_deg
        match = (d_ti <= tol) & (d_tr <= tol) & ((d_dp <= tol) | polar)
        k = max(int(match.sum(axis=1).max(initial=0)), 1)
        out = np.full((len(poses), k, 1), np.nan)
        rows, cols = np.nonzero(match)
        slot = np.zeros(len(rows), dtype=int)
        if len(rows):
            # position of each match within its row
            first = np.searchsorted(rows, rows)
            slot = np.arange(len(rows)) - first
        out[rows, slot, 0] = cols
        return out

    def native_poses(self) -> np.ndarray:
        """(θi, θr, Δφ) rows of every light, degrees: the poses this rig can take."""
        return self.light_poses.copy()
