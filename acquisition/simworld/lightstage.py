"""The simulated light stage: DMX widgets on pseudo-terminals, the LEDs' true emission, and the
camera's images of the sample under a set of lit LEDs, or under an environment.

:func:`open_simulated_stage` starts a :class:`simulators.dmx.SimDmxWidget` per universe and
opens it with :class:`drivers.dmx.DmxWidget` exactly as a USB widget; the simulated camera
renders the LEDs the widgets are *outputting* when the exposure starts (``sim_state_at``), with
each LED's true intensity and colour, so a light state that was not yet on shows in the frame.
Time is event-stepped (:class:`simulators.clock.SteppedClock`): a widget stamps each frame
with the clock when its thread parses it, and :class:`SyncedSimWidget` waits for that parse
after every write, before anything can advance the clock.

The camera sees the sum over LEDs of each LED's single-light image (lights add linearly):
LED k at DMX level v_k (0–1), true relative intensity g_k and colour c_k contributes
``v_k · g_k · c_k ·`` the image under a point light of the rig's nominal intensity at
``light_distance_m`` along its direction (:func:`acquisition.simworld.scene.render_view`).

:func:`render_environment` renders the same sample under distant light from a lat-long
environment map restricted to the dome's hemisphere (z > 0 in the sample frame): the
reference a relit reflectance field is compared with.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass

import numpy as np

from acquisition.config.rig import RigConfig
from acquisition.config.sensor import simulated_sensor
from acquisition.config.stage import StageConfig
from acquisition.simworld.optics import SurfaceView, latlong_cells, surface_view
from acquisition.simworld.scene import SampleHolder, render_view, white_material
from drivers.dmx import DmxWidget
from drivers.lights import Fixture, LightController
from simulators.camera import SimCamera
from simulators.clock import SteppedClock
from simulators.dmx import SimDmxWidget
from simulators.materials import Material


class LightImages:
    """Single-LED radiance images (h, w, 3), W·sr⁻¹·m⁻², rendered once and cached.

    Parameters
    ----------
    rig:
        The light stage's rig (camera, sample, nominal LED intensity).
    directions, camera_dir:
        LED directions (N, 3) and camera direction (3,), sample frame.
    shape:
        Image size in superpixels.
    """

    def __init__(self, rig: RigConfig, directions: np.ndarray, camera_dir: np.ndarray,
                 shape: tuple[int, int]) -> None:
        self.rig = rig
        self.directions = np.asarray(directions, dtype=float)
        self.camera_dir = np.asarray(camera_dir, dtype=float)
        self.shape = shape
        self._cache: dict[tuple[int, int, str | None], np.ndarray] = {}
        self._views: dict[str | None, SurfaceView] = {}

    def image(self, k: int, material: Material, target: str | None = None) -> np.ndarray:
        """LED ``k``'s image of ``material`` (``target="flat"``: the white plate)."""
        key = (k, id(material), target)
        img = self._cache.get(key)
        if img is None:
            view = self._views.get(target)
            if view is None:  # the camera does not move: one view per target
                view = self._views[target] = surface_view(self.rig, self.camera_dir, self.shape,
                                                          target)
            light = self.directions[k][None] * self.rig.light_distance_m
            img = render_view(view, light, material,
                              self.rig.light_intensity_w_per_sr).astype(np.float32)
            self._cache[key] = img
        return img

    def lit(self, weights: np.ndarray, material: Material, target: str | None = None) -> np.ndarray:
        """Radiance image for LED weights (N, 3) = level × gain × colour (0 rows skipped)."""
        out = np.zeros((*self.shape, 3))
        for k in np.flatnonzero(np.any(weights > 0, axis=1)):
            out += self.image(int(k), material, target) * weights[k]
        return out


def render_environment(rig: RigConfig, camera_dir: np.ndarray, material: Material,
                       env: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Radiance image (h, w, 3) of the sample lit by ``env`` from the upper hemisphere.

    ``env`` is a lat-long map (H, W, 3) of radiance (the convention of
    :mod:`acquisition.formats.envmap`; directions and solid angles from the simulator's own
    :func:`~acquisition.simworld.optics.latlong_cells`); every env pixel above the horizon is
    a distant light of its solid angle:
    L(p) = Σ_j env_j · Ω_j · f(wi_j, wo) · max(cos θi_j, 0).
    """
    view = surface_view(rig, camera_dir, shape)
    dirs, omega = latlong_cells(env.shape[:2])
    up = dirs[..., 2] > 0
    d, radiance = dirs[up], env[up] * omega[up][:, None]  # (M, 3), (M, 3)
    out = np.zeros((len(view.wo), 3))
    for start in range(0, len(out), 256):  # bounded memory: 256 pixels × M directions
        frames = view.frames[start:start + 256]
        wi = np.einsum("pij,mj->pmi", frames, d)
        wo = np.broadcast_to(view.wo[start:start + 256, None, :], wi.shape)
        f = material.eval_vectors(wi, wo)
        cos = np.clip(wi[..., 2], 0.0, None)
        out[start:start + 256] = np.einsum("pmc,pm,mc->pc", f, cos, radiance)
    return view.scatter(out)


class SyncedSimWidget:
    """A :class:`DmxWidget` on a simulated widget: each write returns once the widget parsed it.

    Implements :class:`drivers.lights.UniverseOutput`.
    """

    def __init__(self, widget: DmxWidget, sim: SimDmxWidget) -> None:
        self.widget = widget
        self.sim = sim

    @property
    def port(self) -> str:
        return self.widget.port

    def send_universe(self, levels: bytes) -> float:
        t = self.widget.send_universe(levels)
        self.sim.sim_wait_idle()
        return t

    def ready_at(self, sent_at_s: float, n_channels: int | None = None) -> float:
        return self.widget.ready_at(sent_at_s, n_channels)

    def close(self) -> None:
        self.widget.close()


def fixture_emission(fixture: Fixture, universe: bytes) -> np.ndarray:
    """RGB emission (3,) of ``fixture`` relative to full white, from the universe it shows."""

    def level(role: str) -> float:
        i = fixture.start_channel + fixture.channels[role] - 1
        return universe[i] / 255.0 if i < len(universe) else 0.0

    intensity = level("intensity") if "intensity" in fixture.channels else 1.0
    if fixture.has_colour:
        return intensity * np.array([level("r"), level("g"), level("b")])
    if "w" in fixture.channels and "intensity" not in fixture.channels:
        intensity = level("w")
    return np.full(3, intensity)


@dataclass
class SimulatedStage:
    """A running simulated light stage: light controller over simulated widgets, sample holder,
    clock, the widgets by universe (``sim_unplug()`` pulls a cable) and the camera's images."""

    stage: StageConfig
    lights: LightController
    holder: SampleHolder
    clock: SteppedClock
    sims: dict[int, SimDmxWidget]
    images: LightImages
    camera: SimCamera | None = None

    def true_emission(self, t: float) -> np.ndarray:
        """(N, 3) RGB emission of every LED at time ``t`` (s): the simulated widgets' output ×
        the LEDs' true intensity and colour."""
        universes = {u: sim.sim_state_at(t) for u, sim in self.sims.items()}
        e = np.array([fixture_emission(f, universes.get(f.universe, b""))
                      for f in self.stage.fixtures])
        return e * self.stage.led_gain[:, None] * self.stage.led_colour


@contextmanager
def open_simulated_stage(rig: RigConfig, stage: StageConfig, material: Material,
                         seed: int) -> Iterator[SimulatedStage]:
    """Start the simulated widgets, lights and camera of a light stage (``"sim"`` ports)."""
    clock = SteppedClock()
    with ExitStack() as stack:
        sims: dict[int, SimDmxWidget] = {}
        widgets: dict[int, SyncedSimWidget] = {}
        for universe in sorted(stage.ports):
            sim = SimDmxWidget(clock=clock, refresh_rate_hz=stage.refresh_rate_hz,
                               serial_number=10_000_000 + universe)
            path = sim.start()
            stack.callback(sim.stop)
            widget = DmxWidget(path, settle_s=stage.settle_s, clock=clock)
            stack.callback(widget.close)
            sims[universe] = sim
            widgets[universe] = SyncedSimWidget(widget, sim)
        lights = LightController(widgets, stage.fixtures, duty_limit=stage.duty, clock=clock)
        stack.callback(lights.close)  # runs before the widgets close: lights off first
        holder = SampleHolder(material, white_material(rig))
        sensor = simulated_sensor(rig)
        images = LightImages(rig, stage.directions, stage.camera_dir, sensor.superpixel_shape)
        world = SimulatedStage(stage, lights, holder, clock, sims, images)

        def scene() -> np.ndarray:
            weights = world.true_emission(clock.now())
            target = None if holder.current == "sample" else "flat"
            return images.lit(weights, holder.material, target)

        world.camera = SimCamera(sensor, scene, clock, seed=seed)
        yield world


