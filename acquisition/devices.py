"""Opening a rig's devices — real or simulated — behind one interface for the capture engine.

For a bus declared ``simulated = true`` the servo simulator is started in-process on a
pseudo-terminal and the driver opens that path through ``dynamixel_sdk``, exactly as it would
open a USB adapter. A simulated camera renders the scene from the simulator's *true* servo
angles. Every move passes the planner's guard before the motion controller sends it.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import AbstractContextManager, ExitStack, contextmanager, nullcontext
from pathlib import Path

import numpy as np

from calibration.linearize import linearize
from calibration.raw import load_raw
from drivers.dynamixel import Axis, MotionController, ServoBus
from drivers.errors import ConfigError
from simulators.camera import SimCamera
from simulators.clock import SimClock
from simulators.dynamixel import SimServoBus
from simulators.materials import Material
from simulators.sensor import SensorModel

from .kinematics import Pose
from .planner import Planner
from .rig import AxisConfig, RigConfig
from .simscene import SampleHolder, make_scene, white_material


def make_axis(cfg: AxisConfig) -> Axis:
    """The driver's axis for one rig-file axis."""
    return Axis(
        name=cfg.name, servo_id=cfg.servo_id, zero_tick=cfg.zero_tick, direction=cfg.direction,
        min_deg=cfg.min_deg, max_deg=cfg.max_deg, profile_velocity=cfg.profile_velocity,
        profile_acceleration=cfg.profile_acceleration,
    )


class RigDevices:
    """An open rig: motion controller, camera, sample holder, and (simulated) clock."""

    def __init__(
        self,
        rig: RigConfig,
        motion: MotionController,
        camera: SimCamera,
        holder: SampleHolder | None,
        clock: SimClock | None,
    ) -> None:
        self.rig = rig
        self.motion = motion
        self.camera = camera
        self.holder = holder
        self.clock = clock

    def move_to(self, joints: dict[str, float]) -> dict[str, float]:
        """Guarded, readback-confirmed move; returns the read-back joints in degrees."""
        readback = self.motion.move_to(joints)
        if self.rig.settle_s:
            if self.clock is not None:
                self.clock.sleep(self.rig.settle_s)
            else:  # pragma: no cover - hardware
                import time

                time.sleep(self.rig.settle_s)
        return dict(readback)

    def capture(self, path: Path, exposure_s: float, iso: int, frame_seed: int) -> None:
        self.camera.capture(path, exposure_s, iso, frame_seed=frame_seed)

    def present(self, target: str) -> None:
        if self.holder is None:  # pragma: no cover - hardware: the operator swaps targets
            input(f"Put the {target} on the stage and press Enter… ")
        else:
            self.holder.present(target)

    def stop_motion(self) -> None:
        self.motion.stop()

    def device_time_s(self) -> float | None:
        return None if self.clock is None else self.clock.now()

    def host_work(self) -> AbstractContextManager[None]:
        """Stops the simulated clock during host-only work (no effect on real hardware)."""
        return self.clock.frozen() if self.clock is not None else nullcontext()

    def roi_saturated(self, frame: Path) -> bool:
        """True when any pixel of the region of interest is clipped."""
        image = linearize(load_raw(frame))
        x0, y0, x1, y1 = self.rig.camera.roi
        return not bool(np.all(image.valid[y0:y1, x0:x1]))


@contextmanager
def open_devices(
    rig: RigConfig,
    planner: Planner,
    *,
    material: Material | None,
    seed: int = 0,
    sim_faults: Sequence[str] = (),
) -> Iterator[RigDevices]:
    """Open (and for simulated devices, start) everything the rig file declares."""
    if rig.camera.driver != "simulated":
        raise ConfigError(
            f"{rig.path}: [camera] driver '{rig.camera.driver}' is not available here; "
            "use 'simulated' (a gphoto2 driver is planned)"
        )
    any_sim = any(b.simulated for b in rig.buses.values()) or rig.camera.driver == "simulated"
    clock = SimClock(rig.time_scale) if any_sim else None
    axes = {name: make_axis(cfg) for name, cfg in rig.axes.items()}
    wr = rig.white_reference
    park = planner.joints_for(Pose(wr.theta_i, wr.theta_r, wr.delta_phi))
    with ExitStack() as stack:
        sims: dict[str, SimServoBus] = {}
        buses: dict[str, ServoBus] = {}
        for name, bus_cfg in rig.buses.items():
            port = bus_cfg.port
            if bus_cfg.simulated:
                on_bus = [a for a in rig.axes.values() if a.bus == name]
                sim = SimServoBus(
                    [a.servo_id for a in on_bus], baud=bus_cfg.baud, clock=clock,
                    faults=list(sim_faults), seed=seed,
                    positions={a.servo_id: axes[a.name].deg_to_ticks(park[a.name]) for a in on_bus},
                )
                port = sim.start()
                stack.callback(sim.stop)
                sims[name] = sim
            bus = ServoBus(port, bus_cfg.baud, name=name)
            stack.enter_context(bus)
            buses[name] = bus
        motion = MotionController(
            axes.values(),
            {name: buses[cfg.bus] for name, cfg in rig.axes.items()},
            guard=planner.check_joints,
            **({"sleep": clock.sleep} if clock is not None else {}),
        )
        motion.apply_profiles()
        motion.set_torque(True)

        def true_joints() -> dict[str, float]:
            out = {}
            for name, cfg in rig.axes.items():
                ticks = sims[cfg.bus].servos[cfg.servo_id].sim_true_position_ticks()
                out[name] = axes[name].ticks_to_deg(ticks)
            return out

        holder = None
        if material is not None:
            holder = SampleHolder(material, white_material(rig))
        sensor = SensorModel.from_dict(rig.camera.sensor, where=f"{rig.path} [camera.sensor]")
        scene = make_scene(rig, planner.kinematics, true_joints, holder, sensor.superpixel_shape)
        camera = SimCamera(sensor, scene, clock, seed=seed)
        yield RigDevices(rig, motion, camera, holder, clock)
