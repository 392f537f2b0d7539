"""Rig files: the TOML description of a rig's ports, servos, axes, limits and geometry.

``load_rig(path)`` parses and validates a rig file into a frozen :class:`RigConfig`; nothing
is opened. Opening devices (real or simulated) is :mod:`acquisition.devices`' job.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from drivers.errors import ConfigError

from .config import Section, load_toml
from .kinematics import KINEMATICS, JointLimits, Kinematics

RIG_FORMAT_VERSION = 1

XM430_POSITION_TICKS = 4096
"""Ticks per revolution of an X-series servo in position mode."""


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


@dataclass(frozen=True)
class WhiteReference:
    """Diffuse reference target measured by the same pipeline to set the absolute scale."""

    reflectance: tuple[float, float, float]
    theta_i: float
    theta_r: float
    delta_phi: float


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
    raw: dict[str, Any]

    @property
    def simulated(self) -> bool:
        """True when every bus and the camera are simulated."""
        return all(b.simulated for b in self.buses.values()) and self.camera.driver == "simulated"

    def kinematics(self) -> Kinematics:
        """The kinematics plug-in with this rig's joint limits and distances."""
        limits = {name: JointLimits(a.min_deg, a.max_deg) for name, a in self.axes.items()}
        cls = KINEMATICS[self.kinematics_name]
        try:
            return cls(limits, self.light_distance_m, self.camera_distance_m)
        except ValueError as exc:
            raise ConfigError(f"{self.path}: {exc}: add the missing [axes.*] tables") from None


def load_rig(path: str | Path) -> RigConfig:
    """Parse and validate a rig file; raises :class:`ConfigError` naming file and field."""
    path = Path(path)
    top = Section(load_toml(path, "rig file"), str(path))
    top.check_keys({"format_version", "name", "kinematics", "simulation", "buses", "axes",
                    "geometry", "light", "camera", "white_reference"})
    version = top.integer("format_version")
    if version != RIG_FORMAT_VERSION:
        raise top.error("format_version", f"is {version}; this gonio reads version {RIG_FORMAT_VERSION}")
    kin = top.get("kinematics", str)
    if kin not in KINEMATICS:
        raise top.error("kinematics", f"unknown '{kin}' (known: {', '.join(KINEMATICS)})")

    sim = top.section("simulation", {})
    time_scale = sim.number("time_scale", 1.0, min=1e-3)

    buses_sec = top.section("buses")
    if not buses_sec.names():
        raise buses_sec.error(None, "declares no bus: add e.g. [buses.main] with port and baud")
    buses = {}
    for name in buses_sec.names():
        b = buses_sec.section(name)
        b.check_keys({"port", "baud", "simulated"})
        buses[name] = BusConfig(
            name=name,
            port=b.get("port", str, "sim"),
            baud=b.integer("baud", 57600, min=9600),
            simulated=b.get("simulated", bool, False),
        )

    axes_sec = top.section("axes")
    axes = {}
    ids_seen: dict[tuple[str, int], str] = {}
    for name in axes_sec.names():
        a = axes_sec.section(name)
        a.check_keys({"bus", "id", "zero_tick", "direction", "min_deg", "max_deg",
                      "profile_velocity", "profile_acceleration", "tolerance_deg"})
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
        min_deg, max_deg = a.number("min_deg"), a.number("max_deg")
        if not min_deg < max_deg:
            raise a.error("max_deg", f"must exceed min_deg ({min_deg:g} ≥ {max_deg:g})")
        zero = a.integer("zero_tick", 2048, min=0, max=XM430_POSITION_TICKS - 1)
        for label, deg in (("min_deg", min_deg), ("max_deg", max_deg)):
            tick = zero + direction * deg * XM430_POSITION_TICKS / 360.0
            if not 0 <= tick <= XM430_POSITION_TICKS - 1:
                raise a.error(label, f"{deg:g}° maps to tick {tick:.0f}, outside the servo's 0–4095")
        axes[name] = AxisConfig(
            name=name, bus=bus, servo_id=sid, zero_tick=zero, direction=direction,
            min_deg=min_deg, max_deg=max_deg,
            profile_velocity=a.integer("profile_velocity", 100, min=1, max=32767),
            profile_acceleration=a.integer("profile_acceleration", 20, min=1, max=32767),
            tolerance_deg=a.number("tolerance_deg", 0.5, min=0.0),
        )

    geo = top.section("geometry")
    geo.check_keys({"light_distance_m", "camera_distance_m", "shadow_cone_deg",
                    "max_elevation_deg", "settle_s"})
    light = top.section("light", {})
    light.check_keys({"intensity_w_per_sr"})

    cam = top.section("camera")
    cam.check_keys({"driver", "exposure_s", "iso", "roi", "sensor", "max_exposure_retries"})
    roi = cam.get("roi", list)
    if len(roi) != 4 or not all(isinstance(v, int) for v in roi) or not (
        roi[0] < roi[2] and roi[1] < roi[3]
    ):
        raise cam.error("roi", f"must be [x0, y0, x1, y1] integers with x0 < x1, y0 < y1; got {roi}")
    camera = CameraConfig(
        driver=cam.get("driver", str, "simulated"),
        exposure_s=cam.number("exposure_s", 0.01, min=1e-6),
        iso=cam.integer("iso", 100, min=1),
        roi=tuple(roi),  # type: ignore[arg-type]
        sensor=cam.get("sensor", dict, {}),
        max_exposure_retries=cam.integer("max_exposure_retries", 4, min=0),
    )

    wr = top.section("white_reference", {})
    wr.check_keys({"reflectance", "theta_i_deg", "theta_r_deg", "delta_phi_deg"})
    refl = wr.get("reflectance", (float, list), 0.99)
    refl_rgb = tuple(float(v) for v in (refl if isinstance(refl, list) else [refl] * 3))
    if len(refl_rgb) != 3 or not all(0 < v <= 1 for v in refl_rgb):
        raise wr.error("reflectance", f"must be one number or [R, G, B] in (0, 1], got {refl}")
    white = WhiteReference(
        reflectance=refl_rgb,  # type: ignore[arg-type]
        theta_i=wr.number("theta_i_deg", 0.0, min=0, max=89),
        theta_r=wr.number("theta_r_deg", 45.0, min=0, max=89),
        delta_phi=wr.number("delta_phi_deg", 180.0, min=-180, max=360),
    )

    return RigConfig(
        path=path,
        name=top.get("name", str, path.stem),
        kinematics_name=kin,
        buses=buses,
        axes=axes,
        light_distance_m=geo.number("light_distance_m", min=1e-3),
        camera_distance_m=geo.number("camera_distance_m", min=1e-3),
        light_intensity_w_per_sr=light.number("intensity_w_per_sr", 1.0, min=1e-9),
        shadow_cone_deg=geo.number("shadow_cone_deg", 8.0, min=0, max=90),
        max_elevation_deg=geo.number("max_elevation_deg", 85.0, min=1, max=90),
        settle_s=geo.number("settle_s", 0.05, min=0),
        camera=camera,
        white_reference=white,
        time_scale=time_scale,
        raw=top.data,
    )
