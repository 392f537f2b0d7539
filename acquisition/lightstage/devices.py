"""Opening a light stage: DMX widgets and light controller, camera, sample holder, clock.

For a universe whose port is ``"sim"`` a :class:`simulators.dmx.SimDmxWidget` is started
in-process on a pseudo-terminal and :class:`drivers.dmx.DmxWidget` opens that path exactly as
it would open a USB widget; :class:`drivers.lights.LightController` drives every universe and
confirms each light state by timing. The simulated camera renders the LEDs the simulated
widgets are *outputting* at the moment the exposure starts (``sim_state_at``), with each
LED's true intensity and colour, so a light state that was not yet on shows in the frame.

Simulated time is event-stepped (:class:`simulators.clock.SteppedClock`): it passes only in the devices' own
waits (the DMX refresh limit, the lights' settle, the exposure), never while the host computes,
so a run's rig time is the hardware timeline whatever the host's load. A simulated widget
stamps each frame with the clock when its thread parses it; :class:`SyncedSimWidget` waits
for that parse after every write, before anything can advance the clock.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Mapping
from contextlib import AbstractContextManager, ExitStack, contextmanager, nullcontext
from pathlib import Path

import numpy as np

from drivers.dmx import DmxWidget
from drivers.errors import ConfigError, HardwareError
from drivers.lights import Fixture, Level, LightController, LightState
from simulators.camera import SimCamera
from simulators.clock import SimClock, SteppedClock
from simulators.dmx import SimDmxWidget
from simulators.materials import Material
from simulators.sensor import SensorModel

from ..rig import RigConfig
from ..simscene import SampleHolder, white_material
from .config import SIM_PORT, StageConfig, stage_config
from .render import LightImages


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


class LightStageDevices:
    """An open light stage (implements :class:`acquisition.session.CaptureDevices`).

    Attributes
    ----------
    stage, lights, camera, holder, clock:
        Settings, light controller, camera, sample holder and simulated clock.
    sims:
        Universe → simulated widget (``sim_unplug()`` pulls its cable).
    images:
        The simulated camera's single-LED images (simulation checks).
    """

    def __init__(self, rig: RigConfig, stage: StageConfig, lights: LightController,
                 camera: SimCamera, holder: SampleHolder | None, clock: SimClock | None,
                 sims: Mapping[int, SimDmxWidget], images: LightImages | None = None) -> None:
        self.rig = rig
        self.images = images
        self.stage = stage
        self.lights = lights
        self.camera = camera
        self.holder = holder
        self.clock = clock
        self.sims = dict(sims)

    # -- light states --------------------------------------------------------------------------
    def set_levels(self, levels: np.ndarray | tuple[float, ...], hold_s: float = 0.0) -> LightState:
        """Light LED k at ``levels[k]`` (0–1), all others off; returns once on and settled."""
        names = [f.name for f in self.stage.fixtures]
        state: dict[str, Level] = {n: float(v) for n, v in zip(names, levels, strict=True) if v > 0}
        return self.lights.set_state(state, hold_s=hold_s)

    def true_emission(self, t: float) -> np.ndarray:
        """(N, 3) RGB emission of every LED at time ``t`` (simulated widgets' output × the LEDs'
        true intensity and colour)."""
        universes = {u: sim.sim_state_at(t) for u, sim in self.sims.items()}
        e = np.array([fixture_emission(f, universes.get(f.universe, b""))
                      for f in self.stage.fixtures])
        return e * self.stage.led_gain[:, None] * self.stage.led_colour

    # -- CaptureDevices ------------------------------------------------------------------------
    def move_to(self, joints: dict[str, float]) -> dict[str, float]:
        """A light stage does not move: ``{"light": k}`` lights LED k alone."""
        levels = np.zeros(len(self.stage))
        levels[int(round(joints["light"]))] = 1.0
        self.set_levels(levels)
        return dict(joints)

    def capture(self, path: Path, exposure_s: float, iso: int, frame_seed: int) -> None:
        """Expose one frame; raises HardwareError unless the whole exposure lay under the
        commanded, settled light state."""
        info = self.camera.capture(path, exposure_s, iso, frame_seed=frame_seed)
        start = info.timestamp
        if not self.lights.covers(start, start + info.exposure_s):
            raise HardwareError(
                f"frame {Path(path).name} was exposed while the light state was not surely on "
                "(DMX timing); resume the session to retake it"
            )

    def present(self, target: str) -> None:
        if self.holder is None:  # pragma: no cover - hardware: the operator swaps targets
            input(f"Put the {target} under the dome and press Enter… ")
        else:
            self.holder.present(target)

    def stop_motion(self) -> None:
        """Nothing moves; switch every light off (best effort)."""
        with contextlib.suppress(Exception):  # cleanup must not mask the error that got us here
            self.lights.all_off(wait=False)

    def device_time_s(self) -> float | None:
        return None if self.clock is None else self.clock.now()

    def host_work(self) -> AbstractContextManager[None]:
        return self.clock.frozen() if self.clock is not None else nullcontext()


@contextmanager
def open_lightstage(rig: RigConfig, *, material: Material | None, seed: int = 0,
                    stage: StageConfig | None = None) -> Iterator[LightStageDevices]:
    """Open (and for ``"sim"`` ports, start) the light stage's widgets, lights and camera.

    Lights go off and every port closes on exit, also on error.
    """
    stage = stage or stage_config(rig)
    if rig.camera.driver != "simulated":
        raise ConfigError(f"{rig.path}: [camera] driver '{rig.camera.driver}' is not available "
                          "here; use 'simulated'")
    if not stage.simulated:
        raise ConfigError(f"{rig.path}: [dmx] ports: a simulated camera needs simulated widgets "
                          f"(port \"{SIM_PORT}\") to know which LEDs are on")
    if material is None:
        raise ConfigError(f"{rig.path}: a simulated light stage needs a material (--material)")
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
        sensor = SensorModel.from_dict(rig.camera.sensor, where=f"{rig.path} [camera.sensor]")
        images = LightImages(rig, stage.directions, stage.camera_dir, sensor.superpixel_shape)
        devices: LightStageDevices

        def scene() -> np.ndarray:
            weights = devices.true_emission(clock.now())
            target = None if holder.current == "sample" else "flat"
            return images.lit(weights, holder.material, target)

        camera = SimCamera(sensor, scene, clock, seed=seed)
        devices = LightStageDevices(rig, stage, lights, camera, holder, clock, sims, images)
        yield devices
