"""What the simulated camera sees: the sample under the point light, from the TRUE joint angles.

The scene reads the simulator's true servo positions (not the driver's belief), turns them
into light/camera directions through the rig's kinematics, evaluates the material, and returns
the radiance image (W·sr⁻¹·m⁻²) per superpixel. The flat sample covers a rectangle around the
region of interest; the background is black.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from simulators.materials import Lambert, Material

from .kinematics import Kinematics
from .rig import RigConfig

SAMPLE_MARGIN_SUPERPIXELS = 4
"""Sample extent beyond the region of interest on each side."""


@dataclass
class SampleHolder:
    """Which target sits on the stage: the sample material or the white reference."""

    sample: Material
    white: Material
    current: str = "sample"

    def present(self, target: str) -> None:
        """Put ``target`` ("sample" or "white") on the stage (instantaneous in simulation)."""
        if target not in ("sample", "white"):
            raise ValueError(f"unknown target {target!r}")
        self.current = target

    @property
    def material(self) -> Material:
        return self.sample if self.current == "sample" else self.white


def white_material(rig: RigConfig) -> Material:
    """The rig's white reference as a (grey) Lambertian material."""
    return Lambert(float(np.mean(rig.white_reference.reflectance)))


def radiance_at(
    kinematics: Kinematics, joints: Mapping[str, float], material: Material, intensity_w_per_sr: float
) -> np.ndarray:
    """Radiance (3,) leaving the sample centre towards the camera, W·sr⁻¹·m⁻²."""
    g = kinematics.forward_geometry(joints)
    f = material.eval_vectors(g.light_dir, g.camera_dir)
    irradiance = intensity_w_per_sr * max(g.light_dir[2], 0.0) / g.light_distance_m**2
    return f * irradiance


def make_scene(
    rig: RigConfig,
    kinematics: Kinematics,
    true_joints: Callable[[], dict[str, float]],
    holder: SampleHolder,
    shape_superpixels: tuple[int, int],
) -> Callable[[], np.ndarray]:
    """A zero-argument callable giving the radiance image (h, w, 3) the camera sees now."""
    h, w = shape_superpixels
    x0, y0, x1, y1 = rig.camera.roi
    m = SAMPLE_MARGIN_SUPERPIXELS
    ys = slice(max(y0 - m, 0), min(y1 + m, h))
    xs = slice(max(x0 - m, 0), min(x1 + m, w))

    def scene() -> np.ndarray:
        image = np.zeros((h, w, 3))
        image[ys, xs] = radiance_at(
            kinematics, true_joints(), holder.material, rig.light_intensity_w_per_sr
        )
        return image

    return scene
