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

Real hardware (``[camera] driver = "gphoto2"`` and a device path for every ``[dmx]`` port):
one :class:`drivers.dmx.DmxWidget` per universe and a :class:`drivers.gphoto2.GPhoto2Camera`,
all on the host's monotonic clock. The widgets cannot report what they output, so a frame is
confirmed by timing: the exposure interval is the host time from the capture call to its
return, widened to the camera's reported exposure if that lies outside
(:func:`exposure_interval`), and it must lie entirely under the settled commanded state
(:meth:`drivers.lights.LightController.covers`). The sample and the white reference are
swapped by the operator, through a prompt callback (:data:`OperatorPrompt`).
"""

from __future__ import annotations

import contextlib
import sys
import time
from collections.abc import Callable, Iterator, Mapping
from contextlib import AbstractContextManager, ExitStack, contextmanager, nullcontext
from pathlib import Path

import numpy as np

from acquisition.config.rig import RigConfig
from acquisition.devices.rig import CAMERA_DRIVERS
from acquisition.lightstage.config import SIM_PORT, StageConfig, stage_config
from acquisition.lightstage.render import LightImages
from acquisition.simworld.scene import SampleHolder, white_material
from drivers.camera import Camera, CaptureInfo
from drivers.dmx import Clock, DmxWidget, MonotonicClock
from drivers.errors import ConfigError, HardwareError
from drivers.gphoto2 import GPhoto2Camera
from drivers.lights import Fixture, Level, LightController, LightState
from simulators.camera import SimCamera
from simulators.clock import SimClock, SteppedClock
from simulators.dmx import SimDmxWidget
from simulators.materials import Material
from simulators.sensor import SensorModel

OperatorPrompt = Callable[[str], None]
"""Asks the operator to put a target (``"sample"`` or ``"white"``) under the dome; returns
once it is there (raise to abort the capture)."""


def terminal_prompt(target: str) -> None:
    """The interactive :data:`OperatorPrompt`: ask on the terminal and wait for Enter."""
    input(f"Put the {target} under the dome and press Enter… ")


def operator_prompt(rig: RigConfig, prompt: OperatorPrompt | None) -> OperatorPrompt:
    """``prompt``, else :func:`terminal_prompt` when stdin is a terminal.

    Raises
    ------
    ConfigError
        No prompt was given and stdin is not a terminal (CI, a pipe, a service).
    """
    if prompt is not None:
        return prompt
    stdin = sys.stdin
    if stdin is None or not stdin.isatty():
        raise ConfigError(
            f"{rig.path}: a real light stage needs the operator to swap the sample and the white "
            "reference, but stdin is not a terminal; run it in a terminal or pass prompt= to "
            "capture_lightstage/resume_lightstage"
        )
    return terminal_prompt


def exposure_interval(info: CaptureInfo, called_s: float, returned_s: float, *,
                      wall_minus_host_s: float) -> tuple[float, float]:
    """Host-clock interval (s) surely containing a real camera's exposure.

    The exposure happened between the capture call (``called_s``) and its return
    (``returned_s``); a reported exposure (``info.timestamp``, Unix time, converted with
    ``wall_minus_host_s`` = Unix time − host time) outside that bracket, e.g. a stale frame
    from the camera's buffer, widens it, so such a frame is refused rather than trusted.
    """
    start = info.timestamp - wall_minus_host_s
    return min(called_s, start), max(returned_s, start + info.exposure_s)


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
    """An open light stage (implements :class:`acquisition.session.engine.CaptureDevices`).

    Attributes
    ----------
    stage, lights, camera, holder, clock:
        Settings, light controller, camera, sample holder and simulated clock (holder and
        clock are None on real hardware).
    sims:
        Universe → simulated widget (``sim_unplug()`` pulls its cable); empty on hardware.
    images:
        The simulated camera's single-LED images (simulation checks).
    prompt:
        Asks the operator to swap targets (real hardware).
    timer:
        The lights' clock, used to time a real camera's exposure (host monotonic).
    """

    def __init__(self, rig: RigConfig, stage: StageConfig, lights: LightController,
                 camera: SimCamera | Camera, holder: SampleHolder | None, clock: SimClock | None,
                 sims: Mapping[int, SimDmxWidget], images: LightImages | None = None, *,
                 prompt: OperatorPrompt | None = None, timer: Clock | None = None) -> None:
        self.rig = rig
        self.prompt = prompt
        self.timer: Clock = timer if timer is not None else MonotonicClock()
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
        if isinstance(self.camera, SimCamera):
            info = self.camera.capture(path, exposure_s, iso, frame_seed=frame_seed)
            start, end = info.timestamp, info.timestamp + info.exposure_s
        else:
            called = self.timer.now()
            info = self.camera.capture(path, exposure_s, iso)
            returned = self.timer.now()
            start, end = exposure_interval(info, called, returned,
                                           wall_minus_host_s=time.time() - time.monotonic())
        if not self.lights.covers(start, end):
            raise HardwareError(
                f"frame {Path(path).name} was exposed while the light state was not surely on "
                "(DMX timing); resume the session to retake it"
            )

    def present(self, target: str) -> None:
        """Put ``target`` under the dome: the simulated holder, else the operator (lights off
        while they work)."""
        if self.holder is not None:
            self.holder.present(target)
            return
        self.lights.all_off(wait=False)
        (self.prompt or terminal_prompt)(target)

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
                    stage: StageConfig | None = None,
                    prompt: OperatorPrompt | None = None) -> Iterator[LightStageDevices]:
    """Open (and for ``"sim"`` ports, start) the light stage's widgets, lights and camera.

    With ``[camera] driver = "gphoto2"`` the real widgets on the ``[dmx]`` ports and the
    camera are opened on the host clock (``material`` and ``seed`` are unused) and ``prompt``
    (default: the terminal, see :func:`operator_prompt`) swaps the targets. Lights go off and
    every port closes on exit, also on error.
    """
    stage = stage or stage_config(rig)
    if rig.camera.driver not in CAMERA_DRIVERS:
        raise ConfigError(f"{rig.path}: [camera] driver '{rig.camera.driver}' is unknown: use "
                          f"one of {', '.join(CAMERA_DRIVERS)}")
    if rig.camera.driver != "simulated":
        with _open_hardware(rig, stage, prompt) as devices:
            yield devices
        return
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


@contextmanager
def _open_hardware(rig: RigConfig, stage: StageConfig,
                   prompt: OperatorPrompt | None) -> Iterator[LightStageDevices]:
    """Real widgets on every ``[dmx]`` port and the gphoto2 camera, on the host clock."""
    sim = sorted(u for u, port in stage.ports.items() if port == SIM_PORT)
    if sim:
        raise ConfigError(
            f"{rig.path}: [dmx] ports: universe {sim[0]} is \"{SIM_PORT}\" but the camera is "
            f"real ({rig.camera.driver}); give it the widget's device path (e.g. /dev/ttyUSB0)"
        )
    ask = operator_prompt(rig, prompt)
    clock = MonotonicClock()
    with ExitStack() as stack:
        # the camera first, so a missing camera fails before a light is touched; on exit the
        # lights go off first, then the widgets and the camera close
        camera = stack.enter_context(GPhoto2Camera(rig.camera.port))
        widgets: dict[int, DmxWidget] = {}
        for universe in sorted(stage.ports):
            widget = DmxWidget(stage.ports[universe], settle_s=stage.settle_s, clock=clock)
            stack.callback(widget.close)
            widgets[universe] = widget
        lights = LightController(widgets, stage.fixtures, duty_limit=stage.duty, clock=clock)
        stack.callback(lights.close)
        yield LightStageDevices(rig, stage, lights, camera, None, None, {}, prompt=ask,
                                timer=clock)
