"""A light stage's settings from its rig file: dome, DMX wiring, timing and simulation.

The lights' directions come from the rig file's ``[light_stage]`` table (what the
``light-stage`` kinematics uses); their solid angles are the dome's hemisphere Voronoi cells
(:func:`acquisition.config.dome.solid_angles_sr`). The DMX wiring is read from an optional ``[dmx]``
table of the rig file's data::

    [dmx]
    ports = { 1 = "sim" }          # universe → port ("sim": a simulated widget on a pty)
    channels = { intensity = 0 }   # role → offset from each LED's start channel
    settle_s = 0.005               # LED settle after its DMX frame (default [geometry] settle_s)
    refresh_rate_hz = 40           # simulated widgets' output rate (packets/s)
    duty_max_on_fraction = 0.5     # thermal limit: largest on-fraction ...
    duty_window_s = 60.0           # ... over this sliding window (s)
    duty_policy = "wait"           # "wait" (lights off until cool) or "raise"

LEDs are addressed one after another (:func:`drivers.lights.pack_fixtures`), spilling into
the next universe. Simulator-only settings sit in ``[simulation]``: ``led_intensity_error``
(fraction; each LED's true intensity is off by a uniform ±error, to be calibrated out),
``led_error_seed`` and ``led_colours`` (optional list of [r, g, b] gains per LED).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from acquisition.config.dome import solid_angles_sr
from acquisition.config.rig import RigConfig
from acquisition.geometry.kinematics.lightstage import LightStage
from drivers.errors import ConfigError
from drivers.lights import DutyCycleLimit, DutyPolicy, Fixture, pack_fixtures

SIM_PORT = "sim"
"""Port name that starts a simulated widget for the universe."""
DEFAULT_DUTY = (0.5, 60.0)
"""Default thermal limit: an LED may be on at most 50 % of any 60 s."""


@dataclass(frozen=True)
class StageConfig:
    """Everything the light-stage capture needs beyond the rig's camera and sample.

    Attributes
    ----------
    directions:
        (N, 3) unit vectors from the sample to each LED, sample frame (normal +z).
    solid_angles_sr:
        (N,) solid angle each LED stands for (sr, sums to 2π).
    camera_dir:
        (3,) unit vector from the sample to the camera.
    fixtures:
        The DMX fixtures, ``fixtures[k]`` is LED k.
    ports:
        Universe → port (``"sim"`` starts a simulated widget).
    settle_s:
        LED settle time after its frame is on the wire (s).
    refresh_rate_hz:
        Output rate of simulated widgets (packets/s).
    duty:
        Per-LED thermal duty-cycle limit.
    led_gain:
        (N,) true relative intensity of each LED (simulation; 1 = nominal).
    led_colour:
        (N, 3) true RGB gain of each LED (simulation).
    """

    directions: np.ndarray
    solid_angles_sr: np.ndarray
    camera_dir: np.ndarray
    fixtures: tuple[Fixture, ...]
    ports: Mapping[int, str]
    settle_s: float
    refresh_rate_hz: int
    duty: DutyCycleLimit
    led_gain: np.ndarray
    led_colour: np.ndarray

    def __len__(self) -> int:
        return len(self.directions)

    @property
    def simulated(self) -> bool:
        """True when every universe is driven by a simulated widget."""
        return all(p == SIM_PORT for p in self.ports.values())


_DMX_KEYS = {"ports", "channels", "settle_s", "refresh_rate_hz", "duty_max_on_fraction",
             "duty_window_s", "duty_policy"}


def stage_config(rig: RigConfig) -> StageConfig:
    """The light-stage settings of ``rig`` (its kinematics must be ``light-stage``).

    Raises
    ------
    ConfigError
        Naming the rig file and the offending field.
    """
    if rig.kinematics_name != LightStage.name or rig.light_stage is None:
        raise ConfigError(
            f"{rig.path}: kinematics '{rig.kinematics_name}' is not a light stage: capture on "
            f"this rig with `gonio capture --rig {rig.path} --plan PLAN --out DIR`, or use a rig "
            "file with kinematics = \"light-stage\" and a [light_stage] table"
        )
    where = f"{rig.path}: [dmx]"
    dmx = rig.raw.get("dmx", {})
    if not isinstance(dmx, Mapping):
        raise ConfigError(f"{where} must be a table")
    unknown = set(dmx) - _DMX_KEYS
    if unknown:
        raise ConfigError(f"{where} has unknown keys {sorted(unknown)} (allowed: "
                          f"{', '.join(sorted(_DMX_KEYS))})")
    directions = np.asarray(rig.light_stage.light_dirs, dtype=float)
    try:
        fixtures = pack_fixtures(directions, channels=dmx.get("channels"))
        ports = {int(u): str(p) for u, p in dict(dmx.get("ports", {1: SIM_PORT})).items()}
        settle = float(dmx.get("settle_s", rig.settle_s))
        rate = int(dmx.get("refresh_rate_hz", 40))
        policy = DutyPolicy(str(dmx.get("duty_policy", "wait")))
        duty = DutyCycleLimit(float(dmx.get("duty_max_on_fraction", DEFAULT_DUTY[0])),
                              float(dmx.get("duty_window_s", DEFAULT_DUTY[1])), policy)
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where} is malformed ({exc}); check its field types") from None
    missing = sorted({f.universe for f in fixtures} - set(ports))
    if missing:
        raise ConfigError(f"{where} ports: universe {missing[0]} has {len(fixtures)} LEDs' "
                          "channels but no port; add it to ports")
    if settle < 0 or not 1 <= rate <= 40:
        raise ConfigError(f"{where}: settle_s must be ≥ 0 and refresh_rate_hz 1–40")
    gain, colour = _simulated_leds(rig, len(directions))
    return StageConfig(
        directions=directions,
        solid_angles_sr=solid_angles_sr(directions),
        camera_dir=np.asarray(rig.light_stage.camera_dir, dtype=float),
        fixtures=tuple(fixtures),
        ports=ports,
        settle_s=settle,
        refresh_rate_hz=rate,
        duty=duty,
        led_gain=gain,
        led_colour=colour,
    )


def _simulated_leds(rig: RigConfig, n: int) -> tuple[np.ndarray, np.ndarray]:
    sim = rig.raw.get("simulation", {})
    where = f"{rig.path}: [simulation]"
    try:
        error = float(sim.get("led_intensity_error", 0.0))
        seed = int(sim.get("led_error_seed", 0))
        colours = np.asarray(sim.get("led_colours", [[1.0, 1.0, 1.0]]), dtype=float)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where} LED settings are malformed ({exc})") from None
    if not 0 <= error < 1:
        raise ConfigError(f"{where} led_intensity_error must be in [0, 1), got {error}")
    if colours.ndim != 2 or colours.shape[1] != 3 or len(colours) not in (1, n) or (
        colours <= 0
    ).any():
        raise ConfigError(f"{where} led_colours must be one or {n} positive [r, g, b] triples")
    gain = 1.0 + np.random.default_rng(seed).uniform(-error, error, n)
    return gain, np.broadcast_to(colours, (n, 3)).copy()
