"""Opening a light stage: DMX widgets and light controller, camera, sample holder, clock.

For ``"sim"`` ports the simulated stage (:mod:`acquisition.simworld.lightstage`) is started:
widgets on pseudo-terminals opened by :class:`drivers.dmx.DmxWidget` exactly as USB widgets,
on an event-stepped clock. :class:`drivers.lights.LightController` drives every universe and
confirms each light state by timing.

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
import time
from collections.abc import Callable, Iterator, Mapping
from contextlib import AbstractContextManager, ExitStack, contextmanager, nullcontext
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from acquisition.config.rig import RigConfig
from acquisition.config.stage import SIM_PORT, StageConfig, stage_config
from acquisition.devices.rig import CAMERA_DRIVERS, OperatorPrompt, require_operator
from acquisition.simworld.lightstage import LightImages, open_simulated_stage
from acquisition.simworld.scene import SampleHolder
from drivers.camera import Camera, CaptureInfo
from drivers.dmx import Clock, DmxWidget, MonotonicClock
from drivers.errors import ConfigError, HardwareError
from drivers.gphoto2 import GPhoto2Camera
from drivers.lights import Level, LightController, LightState

if TYPE_CHECKING:
    from simulators.clock import SimClock
    from simulators.dmx import SimDmxWidget
    from simulators.materials import Material


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

    stopped = "every light switched off"
    """What :meth:`stop_motion` leaves (the engine's Ctrl-C message says so)."""

    def __init__(self, rig: RigConfig, stage: StageConfig, lights: LightController,
                 camera: Camera, holder: SampleHolder | None, clock: SimClock | None,
                 sims: Mapping[int, SimDmxWidget], images: LightImages | None = None, *,
                 prompt: OperatorPrompt | None = None, timer: Clock | None = None,
                 seeded_camera: bool = False,
                 true_emission: Callable[[float], np.ndarray] | None = None) -> None:
        self.rig = rig
        self.seeded_camera = seeded_camera
        self.true_emission = true_emission
        """``true_emission(t)``: (N, 3) RGB emission of every LED at device time t (simulated)."""
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


    # -- CaptureDevices ------------------------------------------------------------------------
    def move_to(self, joints: dict[str, float]) -> dict[str, float]:
        """A light stage does not move: ``{"light": k}`` lights LED k alone."""
        levels = np.zeros(len(self.stage))
        levels[int(round(joints["light"]))] = 1.0
        self.set_levels(levels)
        return dict(joints)

    def capture(self, path: Path, exposure_s: float, iso: int, frame_seed: int) -> CaptureInfo:
        """Expose one frame; raises HardwareError unless the whole exposure lay under the
        commanded, settled light state. Returns what the camera reports of it."""
        if self.seeded_camera:
            info = self.camera.capture(path, exposure_s, iso, frame_seed=frame_seed)  # type: ignore[call-arg]
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
        return info

    def present(self, target: str) -> None:
        """Put ``target`` under the dome: the simulated holder, else the operator (lights off
        while they work)."""
        if self.holder is not None:
            self.holder.present(target)
            return
        self.lights.all_off(wait=False)
        if self.prompt is None:
            raise ConfigError(
                f"{self.rig.path}: the operator must put the {target} under the dome, but no "
                "operator prompt was given: run gonio in a terminal, or pass prompt= to the API"
            )
        self.prompt(target)

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
        require_operator(rig, prompt)
        with _open_hardware(rig, stage, prompt) as devices:
            yield devices
        return
    if not stage.simulated:
        raise ConfigError(f"{rig.path}: [dmx] ports: a simulated camera needs simulated widgets "
                          f"(port \"{SIM_PORT}\") to know which LEDs are on")
    if material is None:
        raise ConfigError(f"{rig.path}: a simulated light stage needs a material (--material)")
    with open_simulated_stage(rig, stage, material, seed) as sim:
        yield LightStageDevices(rig, stage, sim.lights, sim.camera, sim.holder, sim.clock,
                                sim.sims, sim.images, seeded_camera=True,
                                true_emission=sim.true_emission)


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
        yield LightStageDevices(rig, stage, lights, camera, None, None, {}, prompt=prompt,
                                timer=clock)
