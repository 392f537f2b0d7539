"""What the simulated camera sees: the sample under the point light, from the TRUE joint angles.

The scene reads the simulator's true servo positions (not the driver's belief), turns them
into light/camera directions through the rig's kinematics, evaluates the material, and returns
the radiance image (W·sr⁻¹·m⁻²) per superpixel, on a black background.

Two renderers, chosen by the rig file's ``[sample] image_based``:

* region of interest (default): the flat sample covers a rectangle around the region of
  interest with one uniform radiance, that of the sample's centre;
* image-based: every superpixel is rendered with its own geometry
  (:mod:`acquisition.imaging`: pinhole camera, flat or spherical sample, point light), so
  the radiance is f(wi, wo) · I cos θi / r² per pixel. The white reference is a flat
  Lambertian plate of the sample's ``size_m`` at the origin, rendered the same way.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from simulators.materials import Lambert, Material

from .imaging import frame_geometry
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
    light_on: bool = True
    """Whether the simulated lamp is lit (off for dark frames)."""

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
    if rig.sample.image_based:
        return make_image_scene(rig, kinematics, true_joints, holder, shape_superpixels)
    h, w = shape_superpixels
    x0, y0, x1, y1 = rig.camera.roi
    m = SAMPLE_MARGIN_SUPERPIXELS
    ys = slice(max(y0 - m, 0), min(y1 + m, h))
    xs = slice(max(x0 - m, 0), min(x1 + m, w))

    def scene() -> np.ndarray:
        image = np.zeros((h, w, 3))
        image[ys, xs] = radiance_at(
            kinematics, true_joints(), holder.material, rig.light_intensity_w_per_sr * holder.light_on
        )
        return image

    return scene


def render_image(
    rig: RigConfig,
    light_dir: np.ndarray,
    camera_dir: np.ndarray,
    material: Material,
    shape_superpixels: tuple[int, int],
    target_shape: str | None = None,
) -> np.ndarray:
    """Radiance image (h, w, 3), W·sr⁻¹·m⁻², of the sample (or, with ``target_shape="flat"``,
    the white plate) for arm directions in the sample frame; black off the sample."""
    geo = frame_geometry(rig, light_dir, camera_dir, shape_superpixels, target_shape)
    f = material.eval_vectors(geo.wi, geo.wo)
    return geo.scatter(f * (rig.light_intensity_w_per_sr * geo.irradiance)[:, None])


def make_image_scene(
    rig: RigConfig,
    kinematics: Kinematics,
    true_joints: Callable[[], dict[str, float]],
    holder: SampleHolder,
    shape_superpixels: tuple[int, int],
) -> Callable[[], np.ndarray]:
    """Per-pixel scene of an image-based rig, from the TRUE joint angles at each call."""

    def scene() -> np.ndarray:
        g = kinematics.forward_geometry(true_joints())
        target = None if holder.current == "sample" else "flat"
        image = render_image(rig, g.light_dir, g.camera_dir, holder.material,
                             shape_superpixels, target)
        return image if holder.light_on else np.zeros_like(image)

    return scene
