"""Rig files: the TOML description of a rig's ports, servos, axes, limits and geometry.

``load_rig(path)`` parses and validates a rig file into a frozen :class:`RigConfig`; nothing
is opened. Opening devices (real or simulated) is :mod:`acquisition.devices.rig`' job.

Every number is checked against a plausible range (the ``*_RANGE_*`` constants below, listed
in docs/formats.md), so a value in the wrong unit (radians for degrees, millimetres for
metres) is refused when the file loads, before anything is created or sent.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from acquisition.config.simerrors import (
    BACKLASH_RANGE_DEG,
    POSITION_NOISE_RANGE_DEG,
    SOURCE_DIAMETER_RANGE_M,
    SimErrors,
    parse_sim_errors,
)
from acquisition.config.toml import Section, load_toml
from acquisition.geometry.kinematics import KINEMATICS, Kinematics, Pose
from acquisition.geometry.kinematics.lightstage import LightStage
from drivers.errors import ConfigError
from simulators.sensor import SensorModel

RIG_FORMAT_VERSION = 1

SIM_CLOCKS = ("stepped", "scaled")
"""Values of ``[simulation] clock`` (see :class:`RigConfig.sim_clock`)."""

XM430_POSITION_TICKS = 4096
"""Ticks per revolution of an X-series servo in position mode."""

# Plausible ranges of rig (and plan) fields: a value outside is refused in one line naming the
# file, the field and the range (docs/formats.md lists them).
DISTANCE_RANGE_M = (0.05, 5.0)
"""``[geometry] light_distance_m`` / ``camera_distance_m``: sample to light / camera, m."""
SHADOW_CONE_RANGE_DEG = (0.5, 45.0)
"""``shadow_cone_deg`` (rig and plan): below 0.5° the camera would stand in the beam."""
MAX_ELEVATION_RANGE_DEG = (5.0, 90.0)
"""``max_elevation_deg`` (rig and plan)."""
SETTLE_RANGE_S = (0.0, 10.0)
EXPOSURE_RANGE_S = (1e-6, 3600.0)
ISO_RANGE = (1, 409600)
SIM_ISO_RANGE = (50, 102400)
"""ISO speeds the simulated camera takes (:meth:`simulators.camera.SimCamera.capture`)."""
JOINT_RANGE_DEG = (-360.0, 360.0)
"""``[axes.*] min_deg`` / ``max_deg``."""
PROFILE_RANGE = (1, 32767)
"""``profile_velocity`` / ``profile_acceleration`` (X-series units). 0, the servo's "no
limit", is refused: the time model and the swept-path checks need a finite profile."""
TOLERANCE_RANGE_DEG = (0.0, 10.0)
TIME_SCALE_RANGE = (1e-3, 1e4)
INTENSITY_RANGE_W_PER_SR = (1e-9, 1e6)
SAMPLE_SIZE_RANGE_M = (1e-3, 1.0)
FOOTPRINT_DIAMETER_RANGE_M = (0.0, 1.0)
"""``[light] spot_diameter_m`` and ``[camera] view_diameter_m``."""
ARM_RADIUS_RANGE_M = (0.0, 0.5)
ARM_EXTENT_RANGE_M = (0.0, 6.0)
"""``[arms.*] from_m`` / ``to_m``, m from the sample centre."""
CLEARANCE_RANGE_M = (0.0, 0.1)
BUS_CYCLE_RANGE_S = (0.0, 1.0)
MAX_EXPOSURE_RETRIES = 20
FOCAL_RANGE_PX = (1e-3, 1e6)
"""``[camera.intrinsics] fx`` / ``fy``, superpixels."""
SENSOR_MAXIMA = {"width": 20000, "height": 20000, "full_well_e": 1e7, "gain_e_per_dn": 1e3,
                 "read_noise_e": 1e3, "black_noise_dn": 1e3, "dark_current_e_per_s": 1e6,
                 "prnu_sigma": 0.5, "electrons_per_radiance_s": 1e12, "f_number": 128.0,
                 "vignetting_focal_px": 1e6}
"""Upper bounds of ``[camera.sensor]`` parameters beyond :class:`SensorModel`'s own checks
(positive, finite, even sizes, 8–16 bits)."""


@dataclass(frozen=True)
class BusConfig:
    """One Dynamixel bus: a serial port (or a simulated one) at a baud rate."""

    name: str
    port: str
    baud: int
    simulated: bool


@dataclass(frozen=True)
class AxisConfig:
    """One joint driven by one servo. Degrees ↔ ticks: ticks = zero_tick + direction·deg·4096/360."""

    name: str
    bus: str
    servo_id: int
    zero_tick: int
    direction: int
    min_deg: float
    max_deg: float
    profile_velocity: int
    """X-series units of 0.229 rev/min."""
    profile_acceleration: int
    """X-series units of 214.577 rev/min²."""
    tolerance_deg: float
    backlash_deg: float = 0.0
    """The instrument's stated play between servo and arm, deg (``[axes.NAME] backlash_deg``;
    a simulated rig's default: its ``[simulation.errors]``): the reduction's angular budget."""
    position_noise_deg: float = 0.0
    """The stated 1σ of the arm's angle about where the servo stops, deg (likewise)."""


@dataclass(frozen=True)
class CameraConfig:
    """The camera: simulated (with its sensor parameters) or a driver name."""

    driver: str
    exposure_s: float
    iso: int
    roi: tuple[int, int, int, int]
    """Region of interest on the sample, superpixels: (x0, y0, x1, y1), end exclusive."""
    sensor: dict[str, Any] = field(default_factory=dict)
    max_exposure_retries: int = 4
    intrinsics: CameraIntrinsics | None = None
    """Pinhole intrinsics (``[camera.intrinsics]``), needed for image-based measurement."""
    port: str | None = None
    """Camera port for real drivers (gphoto2, e.g. "usb:001,004"); None takes the first found."""


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics in superpixels (2×2 CFA cells); None centres the principal point.

    Pixel (row i, column j) has its centre at image coordinates (x, y) = (j, i).
    """

    fx: float
    fy: float
    cx: float | None = None
    cy: float | None = None

    def at(self, shape: tuple[int, int]) -> tuple[float, float, float, float]:
        """(fx, fy, cx, cy) for an image of ``shape`` (rows, columns): a missing principal
        point is the image centre."""
        h, w = shape
        return (self.fx, self.fy, (w - 1) / 2.0 if self.cx is None else self.cx,
                (h - 1) / 2.0 if self.cy is None else self.cy)


SAMPLE_SHAPES = ("flat", "sphere")


@dataclass(frozen=True)
class SampleConfig:
    """The sample's shape (``[sample]``): a flat square facing +z at the origin, or a sphere."""

    shape: str = "flat"
    size_m: float = 0.05
    """Edge of the flat sample, and of the flat white-reference plate, m."""
    radius_m: float = 0.02
    """Radius of a sphere sample, m."""
    centre_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Centre of a sphere sample in the sample frame, m."""
    image_based: bool = False
    """Every valid pixel on the sample is a BRDF sample (acquisition.reduction.image)."""


@dataclass(frozen=True)
class WhiteReference:
    """Diffuse reference target measured by the same pipeline to set the absolute scale."""

    reflectance: tuple[float, float, float]
    theta_i: float
    theta_r: float
    delta_phi: float


@dataclass(frozen=True)
class HomeConfig:
    """``[home]``: the rig's home pose, as a pose or as joints (exactly one is set).

    ``gonio home`` moves there; without a ``[home]`` table the home pose is the park pose
    (the white reference)."""

    pose_deg: tuple[float, float, float] | None = None
    """(θi, θr, Δφ) in degrees; the joints are the kinematics' first safe solution."""
    joints_deg: dict[str, float] | None = None
    """``{axis: deg}`` for every axis."""


@dataclass(frozen=True)
class ArmConfig:
    """One arm's collision volume: a capsule (a sphere of ``radius_m`` swept along the arm's
    direction from ``from_m`` to ``to_m`` metres from the sample centre)."""

    radius_m: float
    from_m: float
    to_m: float


@dataclass(frozen=True)
class ArmsConfig:
    """Collision model of the two arms: their capsules must stay ``clearance_m`` apart."""

    light: ArmConfig
    camera: ArmConfig
    clearance_m: float


@dataclass(frozen=True)
class FootprintConfig:
    """Sizes (m) that bound the grazing angles: the light spot and the camera's measured
    region, both as diameters at normal incidence, must stay on the sample when stretched
    by 1/cos θ."""

    sample_size_m: float
    spot_diameter_m: float
    view_diameter_m: float


@dataclass(frozen=True)
class LightStageConfig:
    """Fixed directions (unit vectors, sample frame) of a light stage's lights and camera."""

    light_dirs: tuple[tuple[float, float, float], ...]
    camera_dir: tuple[float, float, float]
    tolerance_deg: float


@dataclass(frozen=True)
class RigConfig:
    """A validated rig file."""

    path: Path
    name: str
    kinematics_name: str
    buses: dict[str, BusConfig]
    axes: dict[str, AxisConfig]
    light_distance_m: float
    camera_distance_m: float
    light_intensity_w_per_sr: float
    shadow_cone_deg: float
    max_elevation_deg: float
    settle_s: float
    camera: CameraConfig
    white_reference: WhiteReference
    time_scale: float
    """Simulated s per host s of a ``"scaled"`` simulation clock."""
    raw: dict[str, Any]
    arms: ArmsConfig | None = None
    footprint: FootprintConfig | None = None
    light_stage: LightStageConfig | None = None
    bus_cycle_s: float = 0.03
    """Per-move bus time (s): health read, safety read, goal write, and the polls that confirm
    arrival."""
    health_read_s: float = 0.0
    """The share of :attr:`bus_cycle_s` (s) spent on the health read, made once per move: a
    routed or approached move's further legs cost :attr:`leg_bus_s` each."""
    sample: SampleConfig = field(default_factory=SampleConfig)
    home: HomeConfig | None = None
    """``[home]``: the declared home pose; None means the park pose."""
    sim_clock: str = "stepped"
    """``[simulation] clock``: ``"stepped"`` (discrete-event: simulated time is the hardware
    timeline, whatever the host's load) or ``"scaled"`` (``time_scale`` × host time)."""
    sim_errors: SimErrors | None = None
    """``[simulation.errors]``: the TRUE misalignments of a simulated rig (None: none)."""
    light_source_diameter_m: float = 0.0
    """``[light] source_diameter_m``: the lamp's emitting disc, m (0: a point; a simulated
    rig's default: its ``[simulation.errors]``): the reduction's source-size term."""

    @property
    def simulated(self) -> bool:
        """True when every bus and the camera are simulated."""
        return all(b.simulated for b in self.buses.values()) and self.camera.driver == "simulated"

    def kinematics(self) -> Kinematics:
        """The kinematics plug-in with this rig's joint limits and distances."""
        cls = KINEMATICS[self.kinematics_name]
        try:
            return cls.from_rig(self)
        except ValueError as exc:
            raise ConfigError(f"{self.path}: {exc}: add the missing tables to the rig file") from None


def require_servo_rig(rig: RigConfig, command: str) -> None:
    """Refuse a light-stage rig for a gonioreflectometer ``command`` (``"gonio capture"``, …),
    in one line pointing at ``gonio lightstage capture``."""
    if rig.kinematics_name == LightStage.name:
        raise ConfigError(f"{rig.path} is a light-stage rig (kinematics = \"light-stage\"), and "
                          f"{command} is for gonioreflectometer rigs: use `gonio lightstage "
                          f"capture --rig {rig.path} --out DIR` (it prints its time estimate first)")


_RIG_KEYS = {"format_version", "name", "kinematics", "simulation", "buses", "axes", "geometry",
             "light", "camera", "white_reference", "arms", "sample", "light_stage", "timing", "dmx", "home"}


def load_rig(path: str | Path) -> RigConfig:
    """Parse and validate a rig file; raises :class:`ConfigError` naming file and field.

    Sections are checked in a fixed order (a file with several mistakes reports the first).
    """
    path = Path(path)
    top = Section(load_toml(path, "rig file"), str(path))
    top.check_keys(_RIG_KEYS)
    kin = _parse_header(top)
    time_scale, sim_clock = _parse_simulation(top.section("simulation", {}))
    fixed = kin == LightStage.name  # a light stage need not have any servo
    buses = _parse_buses(top.section("buses", {}) if fixed else top.section("buses"), fixed)
    axes = _parse_axes(top.section("axes", {}) if fixed else top.section("axes"), buses)
    geo = top.section("geometry")
    geo.check_keys({"light_distance_m", "camera_distance_m", "shadow_cone_deg",
                    "max_elevation_deg", "settle_s"})
    light = top.section("light", {})
    light.check_keys({"intensity_w_per_sr", "spot_diameter_m", "source_diameter_m"})
    cam = top.section("camera")
    camera = _parse_camera(cam)
    white = _parse_white_reference(top.section("white_reference", {}))
    light_distance = geo.number("light_distance_m", min=DISTANCE_RANGE_M[0],
                                max=DISTANCE_RANGE_M[1], unit="m")
    camera_distance = geo.number("camera_distance_m", min=DISTANCE_RANGE_M[0],
                                 max=DISTANCE_RANGE_M[1], unit="m")
    sample = top.section("sample", {})
    sample.check_keys({"size_m", "shape", "radius_m", "centre_m", "image_based"})
    sample_cfg = _parse_sample(sample, camera)
    footprint = _parse_footprint(sample, light, cam)
    timing = top.section("timing", {})
    timing.check_keys({"bus_cycle_s"})
    home_sec = top.section("home", {})
    home = _parse_home(home_sec, axes, fixed) if "home" in top else None
    errors = _parse_errors(top, axes, buses, camera, sample_cfg, fixed)
    axes = _stated_specs(axes, errors)

    rig = RigConfig(
        path=path,
        name=top.get("name", str, path.stem),
        kinematics_name=kin,
        buses=buses,
        axes=axes,
        light_distance_m=light_distance,
        camera_distance_m=camera_distance,
        light_intensity_w_per_sr=light.number("intensity_w_per_sr", 1.0,
                                              min=INTENSITY_RANGE_W_PER_SR[0],
                                              max=INTENSITY_RANGE_W_PER_SR[1], unit="W/sr"),
        shadow_cone_deg=geo.angle("shadow_cone_deg", 8.0, min=SHADOW_CONE_RANGE_DEG[0],
                                  max=SHADOW_CONE_RANGE_DEG[1]),
        max_elevation_deg=geo.angle("max_elevation_deg", 85.0, min=MAX_ELEVATION_RANGE_DEG[0],
                                    max=MAX_ELEVATION_RANGE_DEG[1]),
        settle_s=geo.number("settle_s", 0.05, min=SETTLE_RANGE_S[0], max=SETTLE_RANGE_S[1],
                            unit="s"),
        camera=camera,
        white_reference=white,
        time_scale=time_scale,
        sim_clock=sim_clock,
        raw=top.data,
        arms=_parse_arms(top.section("arms", {}), light_distance, camera_distance),
        footprint=footprint,
        light_stage=_parse_light_stage(top.section("light_stage", {})) if fixed else None,
        bus_cycle_s=timing.number("bus_cycle_s", move_bus_time_s(buses, axes),
                                  min=BUS_CYCLE_RANGE_S[0], max=BUS_CYCLE_RANGE_S[1], unit="s"),
        health_read_s=health_read_s(buses, axes),
        sample=sample_cfg,
        home=home,
        sim_errors=errors,
        light_source_diameter_m=light.number(
            "source_diameter_m", errors.source_diameter_m if errors else 0.0,
            min=SOURCE_DIAMETER_RANGE_M[0], max=SOURCE_DIAMETER_RANGE_M[1], unit="m"),
    )
    if home is not None and home.pose_deg is not None:
        _check_home_reachable(home_sec, rig, home.pose_deg)
    return rig


def _parse_header(top: Section) -> str:
    """``format_version`` (must be :data:`RIG_FORMAT_VERSION`) and ``kinematics``: its name."""
    version = top.integer("format_version")
    if version != RIG_FORMAT_VERSION:
        raise top.error("format_version", f"is {version}; this gonio reads version {RIG_FORMAT_VERSION}")
    kin = top.get("kinematics", str)
    if kin not in KINEMATICS:
        raise top.error("kinematics", f"unknown '{kin}' (known: {', '.join(KINEMATICS)})")
    return kin


def _parse_errors(top: Section, axes: Mapping[str, AxisConfig], buses: Mapping[str, BusConfig],
                  camera: CameraConfig, sample: SampleConfig, fixed: bool) -> SimErrors | None:
    """``[simulation.errors]`` (:mod:`acquisition.config.simerrors`); a light stage has none."""
    sim = top.section("simulation", {})
    if fixed and "errors" in sim:
        raise sim.error("errors", "a light stage has no arms to misalign: remove "
                                  "[simulation.errors]")
    simulated = all(b.simulated for b in buses.values()) and camera.driver == "simulated"
    return parse_sim_errors(sim, axes, simulated=simulated, image_based=sample.image_based)


def _parse_simulation(sim: Section) -> tuple[float, str]:
    """``[simulation]``: time_scale (simulated s per host s) and clock (:data:`SIM_CLOCKS`)."""
    time_scale = sim.number("time_scale", 1.0, min=TIME_SCALE_RANGE[0], max=TIME_SCALE_RANGE[1])
    sim_clock = sim.get("clock", str, "stepped")
    if sim_clock not in SIM_CLOCKS:
        raise sim.error("clock", f"is '{sim_clock}': use one of {', '.join(SIM_CLOCKS)}")
    return time_scale, sim_clock


def _parse_buses(sec: Section, fixed: bool) -> dict[str, BusConfig]:
    """``[buses.NAME]``: port, baud, simulated; at least one unless the rig is ``fixed``."""
    if not sec.names() and not fixed:
        raise sec.error(None, "declares no bus: add e.g. [buses.main] with port and baud")
    buses = {}
    for name in sec.names():
        b = sec.section(name)
        b.check_keys({"port", "baud", "simulated"})
        buses[name] = BusConfig(
            name=name,
            port=b.get("port", str, "sim"),
            baud=_baud(b),
            simulated=b.get("simulated", bool, False),
        )
    return buses


def _baud(b: Section) -> int:
    """``baud``: one of the rates dynamixel_sdk can set (default 57600)."""
    from drivers.dynamixel.bus import COMMON_BAUD_RATES, SDK_BAUD_RATES

    baud = b.integer("baud", 57600)
    if baud not in SDK_BAUD_RATES:
        raise b.error("baud", f"{baud} is not a rate dynamixel_sdk can set: use one the servos "
                              f"are set to, e.g. {', '.join(map(str, COMMON_BAUD_RATES))}")
    return baud


def _parse_axes(sec: Section, buses: Mapping[str, BusConfig]) -> dict[str, AxisConfig]:
    """``[axes.NAME]``: one axis per servo; a servo id is used once per bus."""
    axes = {}
    ids_seen: dict[tuple[str, int], str] = {}
    for name in sec.names():
        axes[name] = _parse_axis(sec.section(name), name, buses, ids_seen)
    return axes


def _parse_axis(a: Section, name: str, buses: Mapping[str, BusConfig],
                ids_seen: dict[tuple[str, int], str]) -> AxisConfig:
    """``[axes.NAME]``: bus, id (recorded in ``ids_seen``), direction, limits in degrees that
    the servo's tick range can reach, zero tick, profile and tolerance."""
    a.check_keys({"bus", "id", "zero_tick", "direction", "min_deg", "max_deg",
                  "profile_velocity", "profile_acceleration", "tolerance_deg", "backlash_deg",
                  "position_noise_deg"})
    bus = a.get("bus", str)
    if bus not in buses:
        raise a.error("bus", f"names bus '{bus}' that [buses] does not declare")
    sid = a.integer("id", min=0, max=252)
    if (bus, sid) in ids_seen:
        raise a.error("id", f"{sid} is already used by axis '{ids_seen[(bus, sid)]}' on bus '{bus}'")
    ids_seen[(bus, sid)] = name
    direction = a.integer("direction", 1)
    if direction not in (1, -1):
        raise a.error("direction", f"must be 1 or -1, got {direction}")
    min_deg, max_deg = (a.angle(k, min=JOINT_RANGE_DEG[0], max=JOINT_RANGE_DEG[1])
                        for k in ("min_deg", "max_deg"))
    if not min_deg < max_deg:
        raise a.error("max_deg", f"must exceed min_deg ({min_deg:g} ≥ {max_deg:g})")
    zero = a.integer("zero_tick", 2048, min=0, max=XM430_POSITION_TICKS - 1)
    for label, deg in (("min_deg", min_deg), ("max_deg", max_deg)):
        tick = zero + direction * deg * XM430_POSITION_TICKS / 360.0
        if not 0 <= tick <= XM430_POSITION_TICKS - 1:
            raise a.error(label, f"{deg:g}° maps to tick {tick:.0f}, outside the servo's 0–4095")
    return AxisConfig(
        name=name, bus=bus, servo_id=sid, zero_tick=zero, direction=direction,
        min_deg=min_deg, max_deg=max_deg,
        profile_velocity=a.integer("profile_velocity", 100, min=PROFILE_RANGE[0],
                                   max=PROFILE_RANGE[1]),
        profile_acceleration=a.integer("profile_acceleration", 20, min=PROFILE_RANGE[0],
                                       max=PROFILE_RANGE[1]),
        tolerance_deg=a.angle("tolerance_deg", 0.5, min=TOLERANCE_RANGE_DEG[0],
                              max=TOLERANCE_RANGE_DEG[1], width=True),
        backlash_deg=a.angle("backlash_deg", float("nan"), min=BACKLASH_RANGE_DEG[0],
                             max=BACKLASH_RANGE_DEG[1], width=True),
        position_noise_deg=a.angle("position_noise_deg", float("nan"),
                                   min=POSITION_NOISE_RANGE_DEG[0],
                                   max=POSITION_NOISE_RANGE_DEG[1], width=True),
    )


def _stated_specs(axes: Mapping[str, AxisConfig], errors: SimErrors | None
                  ) -> dict[str, AxisConfig]:
    """Axes whose backlash and position noise the file did not state take the simulated
    rig's ``[simulation.errors]`` values (else 0)."""
    out = {}
    for name, a in axes.items():
        backlash = a.backlash_deg if math.isfinite(a.backlash_deg) else (
            errors.backlash_deg.get(name, 0.0) if errors else 0.0)
        noise = a.position_noise_deg if math.isfinite(a.position_noise_deg) else (
            errors.position_noise_deg.get(name, 0.0) if errors else 0.0)
        out[name] = replace(a, backlash_deg=backlash, position_noise_deg=noise)
    return out


def _parse_camera(cam: Section) -> CameraConfig:
    """``[camera]``: driver, port, exposure_s, iso, roi [x0, y0, x1, y1], sensor, retries and
    intrinsics (``view_diameter_m`` belongs to the footprint)."""
    cam.check_keys({"driver", "port", "exposure_s", "iso", "roi", "sensor", "max_exposure_retries",
                    "view_diameter_m", "intrinsics"})
    roi = cam.get("roi", list)
    if len(roi) != 4 or not all(isinstance(v, int) and not isinstance(v, bool) for v in roi) or not (
        0 <= roi[0] < roi[2] and 0 <= roi[1] < roi[3]
    ):
        raise cam.error("roi", "must be [x0, y0, x1, y1] superpixels, whole numbers with "
                               f"0 ≤ x0 < x1 and 0 ≤ y0 < y1; got {roi}")
    driver = cam.get("driver", str, "simulated")
    sensor = cam.get("sensor", dict, {})
    if driver == "simulated" or sensor:
        model = _parse_sensor(cam, sensor)
        width, height = model.width // 2, model.height // 2
        if driver == "simulated" and (roi[2] > width or roi[3] > height):
            raise cam.error("roi", f"{roi} reaches beyond the simulated sensor's {width}×{height} "
                                   "superpixels ([camera.sensor] width/2 × height/2; end "
                                   "exclusive): move the ROI inside")
    iso_range = SIM_ISO_RANGE if driver == "simulated" else ISO_RANGE
    return CameraConfig(
        driver=driver,
        exposure_s=cam.number("exposure_s", 0.01, min=EXPOSURE_RANGE_S[0],
                              max=EXPOSURE_RANGE_S[1], unit="s"),
        iso=cam.integer("iso", 100, min=iso_range[0], max=iso_range[1]),
        roi=tuple(roi),  # type: ignore[arg-type]
        sensor=sensor,
        max_exposure_retries=cam.integer("max_exposure_retries", 4, min=0,
                                         max=MAX_EXPOSURE_RETRIES),
        intrinsics=_parse_intrinsics(cam.section("intrinsics")) if "intrinsics" in cam else None,
        port=cam.get("port", str, None),
    )


def _parse_sensor(cam: Section, sensor: dict[str, Any]) -> SensorModel:
    """``[camera.sensor]`` as a :class:`SensorModel` (its own checks), within
    :data:`SENSOR_MAXIMA`."""
    model = SensorModel.from_dict(sensor, where=cam.where().replace("[camera]", "[camera.sensor]"))
    sec = cam.section("sensor", {})
    for key, top in SENSOR_MAXIMA.items():
        value = getattr(model, key)
        if value is not None and value > top:
            raise sec.error(key, f"must be ≤ {top:g}, got {value:g}: check its unit")
    if max(model.quantum_sensitivity) > 10:
        raise sec.error("quantum_sensitivity", f"must be relative sensitivities ≤ 10, got "
                                               f"{list(model.quantum_sensitivity)}")
    return model


def _parse_white_reference(wr: Section) -> WhiteReference:
    """``[white_reference]``: reflectance (one number or [R, G, B] in (0, 1]) and its geometry."""
    wr.check_keys({"reflectance", "theta_i_deg", "theta_r_deg", "delta_phi_deg"})
    refl = wr.get("reflectance", (float, list), 0.99)
    refl_rgb = tuple(float(v) for v in (refl if isinstance(refl, list) else [refl] * 3))
    if len(refl_rgb) != 3 or not all(0 < v <= 1 for v in refl_rgb):
        raise wr.error("reflectance", f"must be one number or [R, G, B] in (0, 1], got {refl}")
    return WhiteReference(
        reflectance=refl_rgb,  # type: ignore[arg-type]
        theta_i=wr.angle("theta_i_deg", 0.0, min=0, max=89),
        theta_r=wr.angle("theta_r_deg", 45.0, min=0, max=89),
        delta_phi=wr.angle("delta_phi_deg", 180.0, min=-180, max=360),
    )


HOME_POSE_KEYS = ("theta_i_deg", "theta_r_deg", "delta_phi_deg")
"""The pose form of ``[home]``."""


def _parse_home(sec: Section, axes: Mapping[str, AxisConfig], fixed: bool) -> HomeConfig:
    """``[home]``: ``theta_i_deg``, ``theta_r_deg``, ``delta_phi_deg`` (a pose) or
    ``joints = {axis = deg, …}`` naming every axis within its limits; not both."""
    if fixed:
        raise sec.error(None, "the light stage has no moving axes and so no home pose: "
                              "remove the [home] table")
    sec.check_keys({*HOME_POSE_KEYS, "joints"})
    given = [k for k in HOME_POSE_KEYS if k in sec]
    if "joints" in sec:
        if given:
            raise sec.error(given[0], "give the home pose either as theta_i_deg, theta_r_deg, "
                                      "delta_phi_deg or as joints, not both")
        joints = sec.section("joints")
        unknown = [n for n in joints.names() if n not in axes]
        if unknown:
            raise joints.error(unknown[0], f"names no axis of this rig (axes: {', '.join(axes)})")
        missing = [n for n in axes if n not in joints]
        if missing:
            raise joints.error(missing[0], "is missing: give every axis a home angle "
                                           f"({', '.join(axes)})")
        out = {}
        for name, cfg in axes.items():
            out[name] = joints.angle(name, min=cfg.min_deg, max=cfg.max_deg)
        return HomeConfig(joints_deg=out)
    if not given:
        raise sec.error(None, "is empty: give theta_i_deg, theta_r_deg, delta_phi_deg, or "
                              "joints = {axis = deg, …}")
    theta_i = sec.angle("theta_i_deg", min=0, max=89)
    theta_r = sec.angle("theta_r_deg", min=0, max=89)
    delta_phi = sec.angle("delta_phi_deg", min=-180, max=360)
    return HomeConfig(pose_deg=(theta_i, theta_r, delta_phi))


def _check_home_reachable(sec: Section, rig: RigConfig, pose_deg: tuple[float, float, float]) -> None:
    """The home pose must have a joint solution within the axes' limits (safety — arm
    collisions, the shadow cone — is the planner's, checked when a console opens)."""
    kinematics = rig.kinematics()
    if not any(kinematics.within_limits(c) for c in kinematics.inverse_candidates(Pose(*pose_deg))):
        theta_i, theta_r, delta_phi = pose_deg
        raise sec.error(None, f"pose θi={theta_i:g}° θr={theta_r:g}° Δφ={delta_phi:g}° is outside "
                              f"the joint limits of the {kinematics.name} rig: choose a reachable "
                              "home pose")


def _parse_footprint(sample: Section, light: Section, cam: Section) -> FootprintConfig:
    """Sample size (``[sample]``), light spot (``[light]``) and camera view (``[camera]``), m."""
    lo, hi = FOOTPRINT_DIAMETER_RANGE_M
    return FootprintConfig(
        sample_size_m=sample.number("size_m", DEFAULT_SAMPLE_SIZE_M, min=SAMPLE_SIZE_RANGE_M[0],
                                    max=SAMPLE_SIZE_RANGE_M[1], unit="m"),
        spot_diameter_m=light.number("spot_diameter_m", DEFAULT_SPOT_DIAMETER_M, min=lo, max=hi,
                                     unit="m"),
        view_diameter_m=cam.number("view_diameter_m", DEFAULT_VIEW_DIAMETER_M, min=lo, max=hi,
                                   unit="m"),
    )


DEFAULT_BUS_CYCLE_S = 0.03
"""Per-move bus time (s) of a rig without servo buses (a light stage)."""
MOTION_POLL_S = 0.01
"""Pause (s) between the motion controller's control cycles (``acquisition.devices.rig`` uses it)."""
RETURN_DELAY_S = 0.0
"""Return Delay Time before each status reply: gonio sets it to 0 when it opens a rig
(``acquisition.devices.servos.set_low_latency``; the X-series factory value is 250 × 2 µs)."""
_READ_BYTES = {"status": 84, "safety": 7, "motion": 20}
"""Bytes per servo of the driver's sync reads: health status (64–147), torque and hardware
error (64–70), goal/moving/velocity/position (116–135)."""


def sync_read_s(n_servos: int, size: int, baud: int,
                return_delay_s: float = RETURN_DELAY_S) -> tuple[float, float]:
    """Wire time (s) of one Protocol 2.0 SYNC_READ of ``size`` bytes from ``n_servos``.

    Returns ``(instruction_s, replies_s)``: the instruction (14 + n bytes) and the n status
    packets (11 + size bytes each, after each servo's return delay), at 10 bits per byte.
    """
    byte_s = 10.0 / baud
    return ((14 + n_servos) * byte_s,
            n_servos * ((11 + size) * byte_s + return_delay_s))


def _servo_counts(axes: Mapping[str, AxisConfig]) -> dict[str, int]:
    """Servos per bus name."""
    counts: dict[str, int] = {}
    for a in axes.values():
        counts[a.bus] = counts.get(a.bus, 0) + 1
    return counts


def health_read_s(buses: Mapping[str, BusConfig], axes: Mapping[str, AxisConfig],
                  return_delay_s: float = RETURN_DELAY_S) -> float:
    """Wire time (s) of the health guard's status read that starts every move (once per
    move, not per leg)."""
    return sum(sum(sync_read_s(n, _READ_BYTES["status"], buses[name].baud, return_delay_s))
               for name, n in _servo_counts(axes).items())


def move_bus_time_s(buses: Mapping[str, BusConfig], axes: Mapping[str, AxisConfig],
                    poll_s: float = MOTION_POLL_S,
                    return_delay_s: float = RETURN_DELAY_S) -> float:
    """Expected bus time (s) one capture move adds to its motion profile.

    Per bus, before the move: the health guard's status read, the motion controller's safety
    read and its goal SYNC_WRITE (14 + 5n bytes). After the profile ends, the controller's
    polls (one motion read per bus, then ``poll_s``) confirm arrival at the first poll that
    samples the axes at rest: on average half a control cycle later, plus that poll's replies.
    With no servo bus, :data:`DEFAULT_BUS_CYCLE_S`.
    """
    counts = _servo_counts(axes)
    if not counts:
        return DEFAULT_BUS_CYCLE_S
    before = cycle = replies = 0.0
    for name, n in counts.items():
        baud = buses[name].baud
        for kind in ("status", "safety"):
            before += sum(sync_read_s(n, _READ_BYTES[kind], baud, return_delay_s))
        before += (14 + 5 * n) * 10.0 / baud
        instruction, reply = sync_read_s(n, _READ_BYTES["motion"], baud, return_delay_s)
        cycle += instruction + reply
        replies += reply
    return before + (poll_s + cycle) / 2.0 + replies
DEFAULT_SAMPLE_SIZE_M = 0.05
"""Sample edge length (m) when the rig file gives none: a 5 cm coupon."""
DEFAULT_SPOT_DIAMETER_M = 0.004
"""Light spot diameter at normal incidence (m) when the rig file gives none."""
DEFAULT_VIEW_DIAMETER_M = 0.004
"""Diameter (m) of the sample region the camera measures, at normal view, by default."""
DEFAULT_ARM_RADIUS_M = {"light": 0.02, "camera": 0.025}
"""Default capsule radius (m) of each arm's head and boom."""
DEFAULT_ARM_FROM_FRACTION = 0.8
"""Default start of an arm's capsule, as a fraction of its distance from the sample."""
DEFAULT_CLEARANCE_M = 0.005


def _parse_arms(sec: Section, light_distance_m: float, camera_distance_m: float) -> ArmsConfig:
    """``[arms]``: clearance_m and per-arm ``{radius_m, from_m, to_m}`` (defaults: the head
    region from 0.8× the arm's distance to its distance plus the radius)."""
    sec.check_keys({"clearance_m", "light", "camera"})
    arms = {}
    for name, distance in (("light", light_distance_m), ("camera", camera_distance_m)):
        a = sec.section(name, {})
        a.check_keys({"radius_m", "from_m", "to_m"})
        radius = a.number("radius_m", DEFAULT_ARM_RADIUS_M[name], min=ARM_RADIUS_RANGE_M[0],
                          max=ARM_RADIUS_RANGE_M[1], unit="m")
        start = a.number("from_m", DEFAULT_ARM_FROM_FRACTION * distance,
                         min=ARM_EXTENT_RANGE_M[0], max=ARM_EXTENT_RANGE_M[1], unit="m")
        stop = a.number("to_m", distance + radius, min=ARM_EXTENT_RANGE_M[0],
                        max=ARM_EXTENT_RANGE_M[1], unit="m")
        if stop < start:
            raise a.error("to_m", f"must be ≥ from_m ({stop:g} < {start:g})")
        arms[name] = ArmConfig(radius, start, stop)
    return ArmsConfig(arms["light"], arms["camera"],
                      sec.number("clearance_m", DEFAULT_CLEARANCE_M, min=CLEARANCE_RANGE_M[0],
                                 max=CLEARANCE_RANGE_M[1], unit="m"))


def _parse_intrinsics(sec: Section) -> CameraIntrinsics:
    """``[camera.intrinsics]``: fx, fy (default fx), cx, cy in superpixels."""
    sec.check_keys({"fx", "fy", "cx", "cy"})
    fx = sec.number("fx", min=FOCAL_RANGE_PX[0], max=FOCAL_RANGE_PX[1], unit="superpixels")
    cx = sec.number("cx") if "cx" in sec else None
    cy = sec.number("cy") if "cy" in sec else None
    fy = sec.number("fy", fx, min=FOCAL_RANGE_PX[0], max=FOCAL_RANGE_PX[1], unit="superpixels")
    return CameraIntrinsics(fx, fy, cx, cy)


def _parse_sample(sec: Section, camera: CameraConfig) -> SampleConfig:
    """``[sample]``: shape ("flat" | "sphere"), size_m, radius_m, centre_m, image_based."""
    shape = sec.get("shape", str, "flat")
    if shape not in SAMPLE_SHAPES:
        raise sec.error("shape", f"unknown '{shape}' (known: {', '.join(SAMPLE_SHAPES)})")
    centre = sec.get("centre_m", list, [0.0, 0.0, 0.0])
    if len(centre) != 3 or not all(
        isinstance(v, int | float) and not isinstance(v, bool) and abs(v) <= 1.0 for v in centre
    ):
        raise sec.error("centre_m", f"must be [x, y, z] in metres, each within ±1 m, got {centre!r}")
    image_based = sec.get("image_based", bool, False)
    if image_based and camera.intrinsics is None:
        raise sec.error("image_based", "needs the camera's pinhole model: add [camera.intrinsics] fx")
    if shape == "sphere" and not image_based:
        raise sec.error("shape", "a sphere sample is measured per pixel: set image_based = true")
    return SampleConfig(
        shape=shape,
        size_m=sec.number("size_m", DEFAULT_SAMPLE_SIZE_M, min=SAMPLE_SIZE_RANGE_M[0],
                          max=SAMPLE_SIZE_RANGE_M[1], unit="m"),
        radius_m=sec.number("radius_m", 0.02, min=SAMPLE_SIZE_RANGE_M[0] / 2,
                            max=SAMPLE_SIZE_RANGE_M[1] / 2, unit="m"),
        centre_m=tuple(float(v) for v in centre),  # type: ignore[arg-type]
        image_based=image_based,
    )


def _angles_to_dir(theta_deg: float, phi_deg: float) -> tuple[float, float, float]:
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    return (math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t))


def _parse_light_stage(sec: Section) -> LightStageConfig:
    """``[light_stage]``: lights as ``light_angles_deg = [[θ, φ], …]`` or
    ``light_directions = [[x, y, z], …]``, the camera as ``camera_angles_deg = [θ, φ]``."""
    sec.check_keys({"light_angles_deg", "light_directions", "camera_angles_deg", "tolerance_deg"})
    given = [k for k in ("light_angles_deg", "light_directions") if k in sec]
    if len(given) != 1:
        raise sec.error(None, "needs exactly one of light_angles_deg, light_directions")
    rows = sec.get(given[0], list)
    width = 2 if given[0] == "light_angles_deg" else 3
    dirs = []
    for i, row in enumerate(rows):
        if not (isinstance(row, list) and len(row) == width
                and all(isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
                        for v in row)):
            raise sec.error(given[0], f"entry {i} must be {width} finite numbers, got {row!r}")
        if width == 2:
            d = _angles_to_dir(*row)
        else:
            norm = math.sqrt(sum(v * v for v in row))
            if norm == 0:
                raise sec.error(given[0], f"entry {i} is the zero vector: give a direction")
            d = tuple(v / norm for v in row)
        if d[2] <= 1e-9:
            raise sec.error(given[0], f"entry {i} is not above the sample (z ≤ 0): fix that light")
        dirs.append(d)
    if not dirs:
        raise sec.error(given[0], "lists no light: add at least one")
    cam = sec.get("camera_angles_deg", list)
    if len(cam) != 2 or not all(isinstance(v, int | float) and not isinstance(v, bool)
                                and math.isfinite(v) for v in cam) or not (
        0 <= cam[0] < 90 and -360 <= cam[1] <= 360
    ):
        raise sec.error("camera_angles_deg", "must be [theta_deg, phi_deg] with θ in [0, 90) and "
                                             f"φ within ±360, got {cam!r}")
    return LightStageConfig(tuple(dirs), _angles_to_dir(*cam),  # type: ignore[arg-type]
                            sec.angle("tolerance_deg", 1e-6, min=TOLERANCE_RANGE_DEG[0],
                                      max=TOLERANCE_RANGE_DEG[1], width=True))
