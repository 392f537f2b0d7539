"""``[simulation.errors]``: the misalignments a simulated rig injects into its own world.

Real rigs are never aligned. A simulated rig may say how its world differs from the rig file's
model; the simulators then move the arms and render the camera from that TRUE geometry, while
gonio (the driver, the planner, the reduction) sees only ticks and the rig file::

    [simulation.errors]
    zero_offset_deg = { light_theta = 0.8, camera_theta = -0.6, camera_phi = 1.0 }
    sample_tilt_deg = [0.5, -0.3]       # the sample normal turned about x, then about y
    sample_height_m = 0.0               # the sample surface along its normal, m
    backlash_deg = { light_theta = 0.2, camera_theta = 0.2, camera_phi = 0.2 }
    position_noise_deg = { light_theta = 0.02 }   # 1σ per move, each axis named
    source_diameter_m = 0.005           # the lamp's disc (integrated over, not a point)
    camera_pointing_deg = [0.0, 0.0]   # image-based rigs: the optical axis off the arm
    seed = 0                            # of the position noise (with the run's --seed)

Every key is optional and zero by default; an unknown key, an axis the rig does not have, or
``[simulation.errors]`` on a rig that is not simulated is refused in one line naming the field.
The same table also states the simulated instrument's specifications: an axis' ``backlash_deg``
and ``position_noise_deg`` default its ``[axes.NAME]`` values (see :class:`AxisConfig`), which
the reduction's angular uncertainty uses.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from acquisition.config.toml import Section

ERROR_KEYS = ("zero_offset_deg", "sample_tilt_deg", "sample_height_m", "backlash_deg",
              "position_noise_deg", "source_diameter_m", "camera_pointing_deg", "seed")
"""The keys of ``[simulation.errors]``."""

ZERO_OFFSET_RANGE_DEG = 10.0
"""|zero offset| of an axis, deg."""
TILT_RANGE_DEG = 10.0
"""|sample tilt| about x or y, deg."""
HEIGHT_RANGE_M = 0.01
"""|sample height offset|, m."""
BACKLASH_RANGE_DEG = (0.0, 5.0)
POSITION_NOISE_RANGE_DEG = (0.0, 2.0)
SOURCE_DIAMETER_RANGE_M = (0.0, 0.2)
POINTING_RANGE_DEG = 5.0
"""|camera pointing error| about either image axis, deg."""


@dataclass(frozen=True)
class SimErrors:
    """The TRUE misalignments of a simulated rig (all zero: the rig file's ideal rig)."""

    zero_offset_deg: Mapping[str, float] = field(default_factory=dict)
    """Per axis: true arm angle − the angle the rig file's zero tick gives, deg."""
    sample_tilt_deg: tuple[float, float] = (0.0, 0.0)
    """The sample normal's rotation about the holder's x axis, then about its y axis, deg."""
    sample_height_m: float = 0.0
    """The sample surface's offset along its normal from the arms' common point, m."""
    backlash_deg: Mapping[str, float] = field(default_factory=dict)
    """Per axis: the play between the servo and its arm (a reversal loses this much), deg."""
    position_noise_deg: Mapping[str, float] = field(default_factory=dict)
    """Per axis: 1σ of the arm's angle about where the servo stops, drawn anew every move, deg."""
    source_diameter_m: float = 0.0
    """Diameter of the lamp's emitting disc, m (0: a point)."""
    camera_pointing_deg: tuple[float, float] = (0.0, 0.0)
    """Image-based rigs: the optical axis turned towards the image's +x, then +y, deg."""
    seed: int = 0
    """Seed of the position noise (combined with the run's seed)."""

    @property
    def any(self) -> bool:
        """True when any error is non-zero."""
        return any((any(self.zero_offset_deg.values()), any(self.sample_tilt_deg),
                    self.sample_height_m, any(self.backlash_deg.values()),
                    any(self.position_noise_deg.values()), self.source_diameter_m,
                    any(self.camera_pointing_deg)))


def parse_sim_errors(sim: Section, axes: Mapping[str, object], *, simulated: bool,
                     image_based: bool) -> SimErrors | None:
    """``[simulation.errors]`` of a rig file (None when absent); raises ConfigError naming the
    field: an unknown key or axis, a value out of its range, errors on a real rig."""
    if "errors" not in sim:
        return None
    sec = sim.section("errors")
    sec.check_keys(set(ERROR_KEYS))
    if not simulated:
        first = next(iter(sec.names()), None)
        raise sec.error(first, "a real (non-simulated) rig has no simulated errors: remove "
                               "[simulation.errors], or set simulated = true on every bus and "
                               'driver = "simulated" for the camera')
    if "camera_pointing_deg" in sec and not image_based:
        raise sec.error("camera_pointing_deg", "only an image-based rig ([sample] image_based = "
                                               "true) renders through its camera's pointing: "
                                               "remove it")
    return SimErrors(
        zero_offset_deg=_per_axis(sec, "zero_offset_deg", axes, -ZERO_OFFSET_RANGE_DEG,
                                  ZERO_OFFSET_RANGE_DEG),
        sample_tilt_deg=_pair(sec, "sample_tilt_deg", TILT_RANGE_DEG, "[about_x, about_y]"),
        sample_height_m=sec.number("sample_height_m", 0.0, min=-HEIGHT_RANGE_M,
                                   max=HEIGHT_RANGE_M, unit="m"),
        backlash_deg=_per_axis(sec, "backlash_deg", axes, *BACKLASH_RANGE_DEG),
        position_noise_deg=_per_axis(sec, "position_noise_deg", axes, *POSITION_NOISE_RANGE_DEG),
        source_diameter_m=sec.number("source_diameter_m", 0.0, min=SOURCE_DIAMETER_RANGE_M[0],
                                     max=SOURCE_DIAMETER_RANGE_M[1], unit="m"),
        camera_pointing_deg=_pair(sec, "camera_pointing_deg", POINTING_RANGE_DEG, "[x, y]"),
        seed=sec.integer("seed", 0, min=0),
    )


def _per_axis(sec: Section, key: str, axes: Mapping[str, object], lo: float, hi: float
              ) -> dict[str, float]:
    """``key = { AXIS = deg, … }``: each named axis must exist, each value lie in [lo, hi]."""
    if key not in sec:
        return {}
    table = sec.section(key)
    out = {}
    for name in table.names():
        if name not in axes:
            raise table.error(name, f"names no axis of this rig (axes: {', '.join(axes)})")
        out[name] = table.angle(name, min=lo, max=hi)
    return out


def _pair(sec: Section, key: str, limit: float, shape: str) -> tuple[float, float]:
    """``key = [a, b]`` in degrees, each within ±limit."""
    if key not in sec:
        return (0.0, 0.0)
    value = sec.get(key, list)
    if len(value) != 2 or not all(isinstance(v, int | float) and not isinstance(v, bool)
                                  for v in value):
        raise sec.error(key, f"must be {shape} in degrees, got {value!r}")
    if any(abs(v) > limit for v in value):
        raise sec.error(key, f"must lie within ±{limit:g}° each, got {value!r}")
    return (float(value[0]), float(value[1]))
