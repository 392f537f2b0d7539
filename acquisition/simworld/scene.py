"""What the simulated camera sees: the sample under the point light, from the TRUE joint angles.

The scene reads the simulator's true servo positions (not the driver's belief), turns them
into light/camera directions through the rig's kinematics, evaluates the material, and returns
the radiance image (W·sr⁻¹·m⁻²) per superpixel, on a black background.

Two renderers, chosen by the rig file's ``[sample] image_based``:

* region of interest (default): the flat sample covers a rectangle around the region of
  interest with one uniform radiance, that of the sample's centre;
* image-based: every superpixel is rendered with its own geometry
  (:mod:`acquisition.reduction.imaging`: pinhole camera, flat or spherical sample, point light), so
  the radiance is f(wi, wo) · I cos θi / r² per pixel. The white reference is a flat
  Lambertian plate of the sample's ``size_m`` at the origin, rendered the same way.

Calibration targets (:meth:`SampleHolder.present`): ``"cap"`` (the lens cap: a black frame)
and ``"uniform"`` (a uniform white target filling the frame, at the white reference's radiance
for the current geometry).

Light drift: the rig file's ``[simulation]`` may make the lamp's intensity a function of the
device clock t (s), a factor on every lit frame (see :class:`LightDrift`)::

    light_drift_pct = 2.0          # total change, % (negative: the lamp dims)
    light_drift_s = 600.0          # duration (linear) or time constant (warmup), s
    light_drift_shape = "linear"   # 1 + p·min(t / s, 1); "warmup": 1 + p·(1 − exp(−t / s))
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from acquisition.config.rig import RigConfig
from acquisition.config.toml import Section
from acquisition.geometry.kinematics import Kinematics
from acquisition.reduction.imaging import frame_geometry
from simulators.clock import SimClock
from simulators.materials import Lambert, Material

SAMPLE_MARGIN_SUPERPIXELS = 4
"""Sample extent beyond the region of interest on each side."""
TARGETS = ("sample", "white", "cap", "uniform")
"""What :meth:`SampleHolder.present` accepts."""
DRIFT_SHAPES = ("linear", "warmup")


@dataclass(frozen=True)
class LightDrift:
    """The simulated lamp's intensity factor over device time (``[simulation] light_drift_*``).

    Attributes
    ----------
    pct:
        Total change, % (2.0: the lamp ends 2 % brighter).
    duration_s:
        ``"linear"``: time over which the change accrues, s (constant after it);
        ``"warmup"``: time constant of 1 − exp(−t/τ), s.
    shape:
        ``"linear"`` or ``"warmup"``.
    """

    pct: float = 0.0
    duration_s: float = 600.0
    shape: str = "linear"

    def factor(self, t_s: float) -> float:
        """Intensity at device time ``t_s`` (s) relative to t = 0."""
        if not self.pct:
            return 1.0
        t = max(t_s, 0.0) / self.duration_s
        ramp = min(t, 1.0) if self.shape == "linear" else 1.0 - math.exp(-t)
        return 1.0 + self.pct / 100.0 * ramp

    @classmethod
    def from_rig(cls, rig: RigConfig) -> LightDrift:
        """The rig file's drift (none when it states none); raises ConfigError naming the key."""
        sim = Section(rig.raw.get("simulation", {}), str(rig.path), "simulation")
        shape = sim.get("light_drift_shape", str, "linear")
        if shape not in DRIFT_SHAPES:
            raise sim.error("light_drift_shape", f"is '{shape}': use one of {', '.join(DRIFT_SHAPES)}")
        return cls(sim.number("light_drift_pct", 0.0, min=-50.0, max=50.0),
                   sim.number("light_drift_s", 600.0, min=1e-6), shape)


@dataclass
class SampleHolder:
    """Which target sits on the stage, whether the lamp is lit, and the lamp's drift.

    ``clock`` (the rig's device clock) drives ``drift``; without a clock the lamp is steady.
    """

    sample: Material
    white: Material
    current: str = "sample"
    light_on: bool = True
    """Whether the simulated lamp is lit (off for dark frames)."""
    clock: SimClock | None = None
    drift: LightDrift | None = None

    def present(self, target: str) -> None:
        """Put ``target`` on the stage (instantaneous in simulation): ``"sample"``,
        ``"white"`` (reference), ``"cap"`` (lens cap) or ``"uniform"`` (flat-field target)."""
        if target not in TARGETS:
            raise ValueError(f"unknown target {target!r}: use one of {', '.join(TARGETS)}")
        self.current = target

    @property
    def material(self) -> Material:
        return self.sample if self.current == "sample" else self.white

    def lamp(self) -> float:
        """The lamp's intensity factor now: 0 when off, else the drift at the device clock."""
        if not self.light_on:
            return 0.0
        if self.drift is None or self.clock is None:
            return 1.0
        return self.drift.factor(self.clock.now())

    def sim_attach(self, rig: RigConfig, clock: Any) -> None:
        """Drive the lamp by ``clock`` (device s) with the rig file's drift."""
        self.clock = clock
        self.drift = LightDrift.from_rig(rig)


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
        if holder.current == "cap":
            return image
        rad = radiance_at(kinematics, true_joints(), holder.material,
                          rig.light_intensity_w_per_sr * holder.lamp())
        if holder.current == "uniform":
            image[:] = rad
        else:
            image[ys, xs] = rad
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
        if holder.current in ("cap", "uniform"):
            image = np.zeros((*shape_superpixels, 3))
            if holder.current == "uniform":
                image[:] = radiance_at(kinematics, true_joints(), holder.white,
                                       rig.light_intensity_w_per_sr * holder.lamp())
            return image
        g = kinematics.forward_geometry(true_joints())
        target = None if holder.current == "sample" else "flat"
        image = render_image(rig, g.light_dir, g.camera_dir, holder.material,
                             shape_superpixels, target)
        return image * holder.lamp()

    return scene
