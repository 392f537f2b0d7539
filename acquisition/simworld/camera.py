"""The simulated camera of a servo rig: a RAW sensor rendering the scene the simulated arms'
true angles make (misalignments included), with the sample holder (sample, white or a
calibration target, lamp drift) in front of it."""

from __future__ import annotations

from collections.abc import Callable

from acquisition.config.rig import RigConfig
from acquisition.config.sensor import simulated_sensor
from acquisition.simworld.scene import SampleHolder, make_scene, white_material
from simulators.camera import SimCamera
from simulators.clock import SimClock
from simulators.materials import Material


def simulated_camera(
    rig: RigConfig,
    true_joints: Callable[[], dict[str, float]],
    material: Material | None,
    clock: SimClock,
    seed: int,
) -> tuple[SimCamera, SampleHolder | None]:
    """The rig's simulated camera and, when a material is given, the sample holder it sees.

    ``true_joints()`` gives the arms' true joint angles (deg) at the moment of exposure; the
    scene adds the rest of the rig's ``[simulation.errors]`` (:mod:`acquisition.simworld.scene`).
    """
    holder = None
    if material is not None:
        holder = SampleHolder(material, white_material(rig))
        holder.sim_attach(rig, clock)  # the lamp follows the device clock (light drift)
    sensor = simulated_sensor(rig)
    scene = make_scene(rig, true_joints, holder, sensor.superpixel_shape)
    return SimCamera(sensor, scene, clock, seed=seed), holder
