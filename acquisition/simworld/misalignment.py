"""The simulated world's TRUE measurement geometry, misalignments included.

The camera of a simulated rig renders what the real rig would show: the arms at their true
angles (the servo simulators' gears: zero offsets, backlash, noise), the sample turned and
raised on its holder and the lamp a disc, as ``[simulation.errors]`` states
(:mod:`acquisition.config.simerrors`). Like the servo simulator this is a referee: it computes
the geometry with code of its own — the simulator's forward kinematics
(:data:`simulators.rig_solids.KINDS`) and the rotations below — never with the kinematics
plug-ins, the alignment model or the calibration it judges.

Conventions (the ones :mod:`acquisition.geometry.alignment` documents for the calibration):
the tilt turns the sample about the holder's x axis by ``about_x``, then about its y axis by
``about_y``; the height moves the sample surface along its normal; the lamp is a uniform disc
of ``source_diameter_m`` facing the sample, integrated over :data:`SOURCE_POINTS` points
(:func:`disc_offsets`; the disc's radiant intensity is the rig's ``intensity_w_per_sr``); the
camera of an image-based rig turns its optical axis towards the image's +x, then +y, by
``camera_pointing_deg``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from acquisition.config.rig import RigConfig
from acquisition.config.simerrors import SimErrors
from simulators.materials import Material
from simulators.rig_solids import KINDS

SOURCE_POINTS = 37
"""Points of the lamp's disc the radiance is averaged over (a sunflower pattern)."""
IMAGE_SOURCE_POINTS = 7
"""The same for a per-pixel (image-based) render, which costs a frame per point."""


def _rotation(about_x_deg: float, about_y_deg: float) -> np.ndarray:
    """Ry · Rx; columns: the sample's true axes in the holder frame."""
    a, b = math.radians(about_x_deg), math.radians(about_y_deg)
    ca, sa, cb, sb = math.cos(a), math.sin(a), math.cos(b), math.sin(b)
    return np.array([[cb, sb * sa, sb * ca], [0.0, ca, -sa], [-sb, cb * sa, cb * ca]])


def disc_offsets(diameter_m: float, n: int) -> np.ndarray:
    """(n, 2) points of equal weight standing for a uniform disc of ``diameter_m`` (one point
    at 0 when 0): its centre and rings of 6, 12, 18, … points evenly spaced, each ring at the
    r.m.s. radius of the annulus whose share of the area it stands for. Their mean is the
    disc's centre and their spread isotropic, with the disc's mean squared radius (d/2)²/2 but
    for the centre point's share (1/n² of it). ``n`` is a centred hexagonal number (1, 7, 19,
    37, …). (A sunflower of 7 points has its mean 0.2 mm off the centre of a 5 mm disc: a lamp
    turned by 0.025° at 0.5 m.)"""
    rings = int(round((math.sqrt(12 * n - 3) - 3) / 6))
    if 1 + 3 * rings * (rings + 1) != n:
        raise ValueError(f"a disc is drawn with 1, 7, 19, 37, … points, not {n}")
    if diameter_m <= 0:
        return np.zeros((1, 2))
    points = [np.zeros((1, 2))]
    inner = 1
    for j in range(1, rings + 1):
        outer = inner + 6 * j
        r = diameter_m / 2.0 * math.sqrt((inner + outer) / (2.0 * n))
        a = 2.0 * math.pi * (np.arange(6 * j) + 0.5 * (j % 2)) / (6 * j)
        points.append(np.column_stack([r * np.cos(a), r * np.sin(a)]))
        inner = outer
    return np.vstack(points)


class TrueGeometry:
    """Where the light and the camera really are, seen from the real sample."""

    def __init__(self, rig: RigConfig) -> None:
        self.rig = rig
        self.errors = rig.sim_errors or SimErrors()
        self.kinematics = KINDS[rig.kinematics_name]
        self.rotation = _rotation(*self.errors.sample_tilt_deg)

    def directions(self, true_joints: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray]:
        """Unit light and camera directions in the TRUE sample frame for the arms' true
        joint angles (deg)."""
        light, camera = self.kinematics.sample_directions(true_joints)
        return np.asarray(light) @ self.rotation, np.asarray(camera) @ self.rotation

    def light_points(self, light_dir: np.ndarray, n: int) -> np.ndarray:
        """(m, 3) points of the lamp's disc (sample frame, m), facing the sample."""
        centre = light_dir * self.rig.light_distance_m
        helper = np.array([0.0, 0.0, 1.0]) if abs(light_dir[2]) < 0.9 else np.array([1.0, 0, 0])
        u = np.cross(light_dir, helper)
        u /= np.linalg.norm(u)
        v = np.cross(light_dir, u)
        d = disc_offsets(self.errors.source_diameter_m, n)
        return centre + d[:, :1] * u + d[:, 1:] * v

    def radiance(self, true_joints: Mapping[str, float], material: Material,
                 intensity_w_per_sr: float) -> np.ndarray:
        """Radiance (3,) the camera sees from the point of the sample its line of sight meets
        (W·sr⁻¹·m⁻²), averaged over the lamp's disc."""
        light, camera = self.directions(true_joints)
        if camera[2] <= 0:
            return np.zeros(3)
        viewed = camera * self.errors.sample_height_m / camera[2] + [0.0, 0.0, 0.0]
        viewed[2] = self.errors.sample_height_m
        wo = camera * self.rig.camera_distance_m - viewed
        wo /= np.linalg.norm(wo)
        to_light = self.light_points(light, SOURCE_POINTS) - viewed
        r2 = np.sum(to_light**2, axis=1)
        wi = to_light / np.sqrt(r2)[:, None]
        local_wo = np.broadcast_to(wo, wi.shape)
        f = material.eval_vectors(wi, local_wo)
        cos_i = np.maximum(wi[:, 2], 0.0)
        return np.mean(f * (intensity_w_per_sr * cos_i / r2)[:, None], axis=0)
