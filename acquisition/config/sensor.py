"""The simulated camera's sensor as the rig file declares it (``[camera.sensor]``), and the
nominal noise model that follows from it.

The sensor's parameters are part of a simulated rig's file, so reading them is configuration;
the camera that renders with them is started in :mod:`acquisition.simworld`.
"""

from __future__ import annotations

import math

from acquisition.config.rig import RigConfig
from calibration.linearize import NoiseModel
from simulators.sensor import SensorModel


def simulated_sensor(rig: RigConfig) -> SensorModel:
    """The rig's ``[camera.sensor]`` table, validated (ConfigError naming the field)."""
    return SensorModel.from_dict(rig.camera.sensor, where=f"{rig.path} [camera.sensor]")


def nominal_noise_model(rig: RigConfig, iso: float) -> NoiseModel:
    """The simulated sensor's nominal noise at ``iso``: gain (e⁻/DN) and read noise (DN),
    including the black-level noise and the quantisation step (1/12 DN²)."""
    sensor = simulated_sensor(rig)
    gain = sensor.gain_at(iso)
    read = math.sqrt((sensor.read_noise_e / gain) ** 2 + sensor.black_noise_dn**2 + 1 / 12)
    return NoiseModel(gain, read, iso)
