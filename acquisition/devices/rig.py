"""Opening a rig's devices — real or simulated — behind one interface for the session engine.

For a bus declared ``simulated = true`` the servo simulator is started in-process on a
pseudo-terminal and the driver opens that path through ``dynamixel_sdk``, exactly as it would
open a USB adapter (:mod:`acquisition.devices.servos`). A simulated camera renders the scene
from the simulator's *true* servo angles (:mod:`acquisition.simworld.camera`). Every move
passes the planner's guard before the motion controller sends it, and the servos' temperature
and supply voltage before that (:class:`~acquisition.devices.health.HealthGuard`). On a real
rig the operator swaps the sample and the white reference, asked through a prompt callback.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import AbstractContextManager, contextmanager, nullcontext
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from acquisition.config.rig import RigConfig
from acquisition.devices.health import HealthGuard, HealthLimits
from acquisition.devices.servos import open_servos, routed_move
from acquisition.planning.planner import Planner
from acquisition.simworld.camera import simulated_camera
from acquisition.simworld.servos import make_clock
from calibration.linearize import linearize
from calibration.raw import load_raw
from drivers.camera import Camera, CaptureInfo
from drivers.dynamixel import MotionController
from drivers.errors import ConfigError
from drivers.gphoto2 import GPhoto2Camera

if TYPE_CHECKING:
    from acquisition.simworld.scene import SampleHolder
    from simulators.clock import SimClock
    from simulators.materials import Material

OperatorPrompt = Callable[[str], None]
"""Asks the operator to put a target (``"sample"`` or ``"white"``) in place; returns once it is
there (raise to abort)."""


def require_operator(rig: RigConfig, prompt: OperatorPrompt | None) -> None:
    """Refuse, before anything is opened, a rig whose targets the operator must swap when there
    is no one to ask.

    Raises
    ------
    ConfigError
        ``prompt`` is None (no ``prompt=`` given, or the CLI found no terminal on stdin).
    """
    if prompt is None:
        raise ConfigError(
            f"{rig.path}: this rig needs the operator to swap the sample and the white reference, "
            "but there is no one to ask (stdin is not a terminal, or no prompt= was given): "
            "run it in a terminal or pass prompt= to the API"
        )


class RigDevices:
    """An open rig: motion controller, camera, sample holder, and (simulated) clock.

    ``seeded_camera``: the camera takes a ``frame_seed`` (a simulated camera's noise, so a
    resumed run re-shoots identical frames). ``prompt`` asks the operator to present a target
    where no simulated sample holder does it.
    """

    stopped = "all axes stopped, torque on"
    """What :meth:`stop_motion` leaves (the engine's Ctrl-C message says so)."""

    def __init__(
        self,
        rig: RigConfig,
        motion: MotionController,
        camera: Camera,
        holder: SampleHolder | None,
        clock: SimClock | None,
        *,
        health: HealthGuard | None = None,
        seeded_camera: bool = False,
        prompt: OperatorPrompt | None = None,
        planner: Planner | None = None,
        sim_collisions: Callable[[], list[str]] | None = None,
        ports: Mapping[str, str] | None = None,
    ) -> None:
        self.rig = rig
        self.planner = planner or Planner(rig)
        self.ports = dict(ports or {})
        """``{axis: port}`` of the bus each axis' servo is on (a simulated bus: its pty)."""
        self._sim_collisions = sim_collisions
        self.motion = motion
        self.camera = camera
        self.holder = holder
        self.clock = clock
        self.health = health
        self.seeded_camera = seeded_camera
        self.prompt = prompt

    def move_to(self, joints: Mapping[str, float], *, routed: bool = True) -> dict[str, float]:
        """Health-checked, guarded, readback-confirmed move, routed round the other arm when
        the direct one is not safe; returns the read-back joints (deg) of every axis.
        ``routed=False`` moves only the named axes, straight: a move the guard finds unsafe is
        refused (one line, nothing sent) instead of routed.

        Before the move the servos' temperature and supply voltage are read; out of range, the
        move waits (see :class:`HealthGuard`) and raises :class:`ServoHealthError` if they do
        not recover in time.
        """
        if self.health is not None:
            self.health.wait_until_healthy()
        if routed:
            readback = routed_move(self.motion, self.planner, joints)
        else:
            self.motion.move_to(joints)
            readback = self.motion.where_deg()
        if self.rig.settle_s:
            if self.clock is not None:
                self.clock.sleep(self.rig.settle_s)
            else:  # pragma: no cover - hardware
                time.sleep(self.rig.settle_s)
        return dict(readback)

    def capture(self, path: Path, exposure_s: float, iso: int, frame_seed: int) -> CaptureInfo:
        """Expose one RAW frame; ``frame_seed`` fixes a simulated camera's noise (resumes
        re-shoot identical frames) and is meaningless to a real one."""
        if self.seeded_camera:
            return self.camera.capture(path, exposure_s, iso, frame_seed=frame_seed)  # type: ignore[call-arg]
        return self.camera.capture(path, exposure_s, iso)

    def present(self, target: str) -> None:
        """Put ``target`` (``"sample"`` or ``"white"``) in front of the camera."""
        if self.holder is not None:
            self.holder.present(target)
        elif self.prompt is not None:
            self.prompt(target)
        else:
            raise ConfigError(
                f"{self.rig.path}: the operator must put the {target} on the stage, but no "
                "operator prompt was given: run gonio in a terminal, or pass prompt= to the API"
            )

    def light(self, on: bool) -> None:
        """Switch the rig's light (dark frames). Simulated rigs only, for now."""
        if self.holder is None:
            raise ConfigError(
                f"{self.rig.path}: this rig declares no light controller, so dark frames need "
                "the lamp switched by hand: remove Dark steps or take darks with `gonio calibrate dark`"
            )
        self.holder.light_on = on

    def stop_motion(self) -> None:
        self.motion.stop()

    def link_stats(self) -> dict[str, dict[str, int]]:
        """Per axis: requests, retries and goal resends on its bus since the rig was opened."""
        return {axis: {"requests": s.requests, "retries": s.retries, "resends": s.resends}
                for axis, s in self.motion.link_stats().items()}

    def collisions(self) -> list[str]:
        """Every contact of the arms the simulator saw (simulated rigs), one line each."""
        return self._sim_collisions() if self._sim_collisions is not None else []

    def device_time_s(self) -> float | None:
        return None if self.clock is None else self.clock.now()

    def host_work(self) -> AbstractContextManager[None]:
        """Stops the simulated clock during host-only work (no effect on real hardware)."""
        return self.clock.frozen() if self.clock is not None else nullcontext()

    def roi_saturated(self, frame: Path) -> bool:
        """True when any pixel of the region of interest is clipped."""
        image = linearize(load_raw(frame))
        x0, y0, x1, y1 = self.rig.camera.roi
        height, width = image.valid.shape
        if x1 > width or y1 > height:  # a real camera's size is known from its first frame
            raise ConfigError(
                f"{self.rig.path}: [camera] roi {list(self.rig.camera.roi)} reaches beyond the "
                f"camera's {width}×{height} superpixels (end exclusive): move the ROI inside"
            )
        return not bool(np.all(image.valid[y0:y1, x0:x1]))


CAMERA_DRIVERS = ("simulated", "gphoto2")
"""``[camera] driver`` values: the simulated RAW camera, or a DSLR/mirrorless body over gphoto2."""


def check_camera_driver(rig: RigConfig) -> None:
    """Refuse camera drivers gonio lacks, and a simulated camera on real servos."""
    driver = rig.camera.driver
    if driver not in CAMERA_DRIVERS:
        raise ConfigError(
            f"{rig.path}: [camera] driver '{driver}' is unknown: use one of {', '.join(CAMERA_DRIVERS)}"
        )
    if driver == "simulated" and not all(b.simulated for b in rig.buses.values()):
        raise ConfigError(
            f"{rig.path}: a simulated camera renders from the simulator's true servo angles; "
            "set simulated = true on every [buses.*] or use driver = 'gphoto2'"
        )


@contextmanager
def open_devices(
    rig: RigConfig,
    planner: Planner,
    *,
    material: Material | None,
    seed: int = 0,
    sim_faults: Sequence[str] = (),
    health_limits: HealthLimits | None = None,
    prompt: OperatorPrompt | None = None,
) -> Iterator[RigDevices]:
    """Open (and for simulated devices, start) everything the rig file declares.

    ``prompt`` asks the operator to swap targets on a rig without a simulated sample holder.
    """
    check_camera_driver(rig)
    any_sim = any(b.simulated for b in rig.buses.values()) or rig.camera.driver == "simulated"
    clock = make_clock(rig) if any_sim else None
    with open_servos(rig, planner, clock=clock, sim_faults=sim_faults, seed=seed,
                     health_limits=health_limits) as servos:
        ports = {name: servos.bus_of(name).port_name for name in rig.axes}
        if rig.camera.driver == "gphoto2":
            require_operator(rig, prompt)
            with GPhoto2Camera(rig.camera.port) as real_camera:
                yield RigDevices(rig, servos.motion, real_camera, None, clock,
                                 health=servos.health, prompt=prompt, planner=planner,
                                 ports=ports)
            return
        assert clock is not None
        camera, holder = simulated_camera(rig, servos.true_joints, material,
                                          clock, seed)
        yield RigDevices(rig, servos.motion, camera, holder, clock, health=servos.health,
                         seeded_camera=True, prompt=prompt, planner=planner,
                         sim_collisions=servos.sim_collisions, ports=ports)
