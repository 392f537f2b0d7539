"""What the simulated camera sees: the sample under the light, from the TRUE geometry.

The scene reads the arms' true angles from the servo simulator (not the driver's belief: zero
offsets, backlash and position noise included), turns them into light/camera directions in the
sample's true frame (tilted, raised, the lamp a disc: :mod:`acquisition.simworld.misalignment`,
with the simulator's own kinematics), evaluates the material, and returns the radiance image
(W·sr⁻¹·m⁻²) per superpixel, on a black background.

Two renderers, chosen by the rig file's ``[sample] image_based``:

* region of interest (default): the flat sample covers a rectangle around the region of
  interest with one uniform radiance, that of the sample's centre;
* image-based: every superpixel is rendered with its own TRUE geometry, computed by the
  simulated camera's own optics (:mod:`acquisition.simworld.optics`: pinhole camera, flat or
  spherical sample, the lamp's points), never by the reduction it judges, so the radiance is
  f(wi, wo) · I cos θi / r² per pixel. The white reference is a flat Lambertian plate of the
  sample's ``size_m`` in the sample's place (raised with it), rendered the same way.

Calibration targets (:meth:`SampleHolder.present`): ``"cap"`` (the lens cap: a black frame),
``"uniform"`` (a uniform white target filling the frame, at the white reference's radiance
for the current geometry) and ``"mirror"`` (a metal mirror in the sample's place, for the
geometric calibration: a specular lobe :data:`MIRROR_SPEC` about 2.5° wide at half maximum).

Light drift: the rig file's ``[simulation]`` may make the lamp's intensity a function of the
device clock t (s), a factor on every lit frame (see :class:`LightDrift`)::

    light_drift_pct = 2.0          # total change, % (negative: the lamp dims)
    light_drift_s = 600.0          # duration (linear) or time constant (warmup), s
    light_drift_shape = "linear"   # 1 + p·min(t / s, 1); "warmup": 1 + p·(1 − exp(−t / s))
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from acquisition.config.rig import RigConfig
from acquisition.config.toml import Section
from acquisition.simworld.misalignment import IMAGE_SOURCE_POINTS, TrueGeometry
from acquisition.simworld.optics import SurfaceView, surface_view
from simulators.clock import SimClock
from simulators.material_kernels import packed_material
from simulators.materials import Lambert, Material, material_from_spec

SAMPLE_MARGIN_SUPERPIXELS = 4
"""Sample extent beyond the region of interest on each side."""
TARGETS = ("sample", "white", "cap", "uniform", "mirror")
"""What :meth:`SampleHolder.present` accepts."""
MIRROR_SPEC = "ggx:albedo=0,alpha=0.02,f0=0.9"
"""The ``"mirror"`` target: a metal mirror (90 % reflectance) whose surface is flat to about
1° (GGX α 0.02), so a coarse scan finds its peak."""
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
        ``"white"`` (reference), ``"cap"`` (lens cap), ``"uniform"`` (flat-field target) or
        ``"mirror"`` (geometric calibration)."""
        if target not in TARGETS:
            raise ValueError(f"unknown target {target!r}: use one of {', '.join(TARGETS)}")
        self.current = target

    @property
    def material(self) -> Material:
        if self.current == "mirror":
            return material_from_spec(MIRROR_SPEC)
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


def make_scene(
    rig: RigConfig,
    true_joints: Callable[[], dict[str, float]],
    holder: SampleHolder,
    shape_superpixels: tuple[int, int],
) -> Callable[[], np.ndarray]:
    """A zero-argument callable giving the radiance image (h, w, 3) the camera sees now."""
    truth = TrueGeometry(rig)
    if rig.sample.image_based:
        return make_image_scene(rig, truth, true_joints, holder, shape_superpixels)
    h, w = shape_superpixels
    x0, y0, x1, y1 = rig.camera.roi
    m = SAMPLE_MARGIN_SUPERPIXELS
    ys = slice(max(y0 - m, 0), min(y1 + m, h))
    xs = slice(max(x0 - m, 0), min(x1 + m, w))

    def scene() -> np.ndarray:
        image = np.zeros((h, w, 3))
        if holder.current == "cap":
            return image
        rad = truth.radiance(true_joints(), holder.material,
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
    *,
    light_points: np.ndarray | None = None,
    pointing_deg: tuple[float, float] = (0.0, 0.0),
    sample_height_m: float = 0.0,
) -> np.ndarray:
    """Radiance image (h, w, 3), W·sr⁻¹·m⁻², of the sample (or, with ``target_shape="flat"``,
    the white plate) for arm directions in the sample frame; black off the sample.

    ``light_points`` (m, 3): the lamp as points sharing its intensity (default: a point at
    the light's distance); ``pointing_deg``: the camera's pointing error; ``sample_height_m``:
    the sample (and plate) above its nominal place, m. Analytic materials are rendered by the
    compiled renderer (:mod:`acquisition.simworld.render_kernel`), others by
    :func:`render_image_numpy`."""
    points = (np.asarray(light_dir, float)[None] * rig.light_distance_m if light_points is None
              else light_points)
    packed = packed_material(material)
    if packed is not None:  # the compiled renderer (one pass, no per-pixel arrays)
        from acquisition.simworld.render_kernel import render_frame

        return render_frame(rig, camera_dir, shape_superpixels, target_shape, points, packed,
                            rig.light_intensity_w_per_sr, pointing_deg=pointing_deg,
                            height_m=sample_height_m)
    return render_image_numpy(rig, camera_dir, material, shape_superpixels, target_shape,
                              points, pointing_deg=pointing_deg, sample_height_m=sample_height_m)


def render_image_numpy(
    rig: RigConfig,
    camera_dir: np.ndarray,
    material: Material,
    shape_superpixels: tuple[int, int],
    target_shape: str | None,
    light_points: np.ndarray,
    *,
    pointing_deg: tuple[float, float] = (0.0, 0.0),
    sample_height_m: float = 0.0,
) -> np.ndarray:
    """:func:`render_image` by the numpy path (:func:`surface_view`, :func:`render_view`):
    the compiled renderer's reference, and the renderer of materials without a compiled
    evaluator (measured ones)."""
    view = surface_view(rig, camera_dir, shape_superpixels, target_shape,
                        pointing_deg=pointing_deg, height_m=sample_height_m)
    return render_view(view, light_points, material, rig.light_intensity_w_per_sr)


def render_view(view: SurfaceView, light_points: np.ndarray, material: Material,
                intensity_w_per_sr: float) -> np.ndarray:
    """Radiance image (h, w, 3), W·sr⁻¹·m⁻², of what ``view`` sees under a lamp of
    ``intensity_w_per_sr`` made of ``light_points`` (m, 3) (m), which share its intensity."""
    radiance = np.zeros((len(view.wo), 3))
    for point in light_points:
        lit, wi, irradiance = view.lit_by(point)
        f = material.eval_vectors(wi, view.wo[lit])
        radiance[lit] += f * (intensity_w_per_sr * irradiance)[:, None]
    return view.scatter(radiance / len(light_points))


def make_image_scene(
    rig: RigConfig,
    truth: TrueGeometry,
    true_joints: Callable[[], dict[str, float]],
    holder: SampleHolder,
    shape_superpixels: tuple[int, int],
) -> Callable[[], np.ndarray]:
    """Per-pixel scene of an image-based rig, from the TRUE geometry at each call."""
    errors = truth.errors

    def scene() -> np.ndarray:
        if holder.current in ("cap", "uniform"):
            image = np.zeros((*shape_superpixels, 3))
            if holder.current == "uniform":
                image[:] = truth.radiance(true_joints(), holder.white,
                                          rig.light_intensity_w_per_sr * holder.lamp())
            return image
        lamp = holder.lamp()
        if lamp == 0.0:  # the lamp is off: a dark frame
            return np.zeros((*shape_superpixels, 3))
        light, camera = truth.directions(true_joints())
        target = None if holder.current == "sample" else "flat"
        image = render_image(rig, light, camera, holder.material, shape_superpixels, target,
                             light_points=truth.light_points(light, IMAGE_SOURCE_POINTS),
                             pointing_deg=errors.camera_pointing_deg,
                             sample_height_m=errors.sample_height_m)
        if lamp != 1.0:
            image *= lamp
        return image

    return scene
