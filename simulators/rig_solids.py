"""The solid parts of a simulated gonioreflectometer: the arms as capsules, with geometry of its own.

A simulator is a referee: it models the physical rig with code of its own and never calls the
code it judges (gonio's kinematics plug-ins and planner). This module is that model for the
arms. Input is plain data (:class:`SolidRig`), built by hand or from a parsed rig file
(:func:`solid_rig_from_toml`); nothing here imports :mod:`acquisition`.

Geometry
--------
Each arm's solid part is a capsule: a sphere of ``radius_m`` swept along the arm's direction from
``from_m`` to ``to_m`` metres from the sample centre (the point every arm turns about). The arm's
direction comes from the joints (degrees) with the rig kind's forward kinematics:

``out-of-plane-arcs``
    light ``(sin lt, 0, cos lt)`` with ``lt = light_theta``; camera
    ``(sin ct cos cp, sin ct sin cp, cos ct)`` with ``ct = camera_theta``, ``cp = camera_phi``.
    ``sample_phi`` turns the sample only.
``coaxial-arms``
    light ``(cos a, sin a, 0)`` with ``a = light_azimuth``, camera likewise with
    ``camera_azimuth``. ``stage_tilt`` and ``stage_rotation`` move the sample only (its normal is
    ``(cos t, 0, sin t)``).
``light-stage``
    nothing moves: no solids.

Two capsules touch when the distance between their axis segments is at most the sum of their
radii (:meth:`SolidRig.gap_m` ≤ 0). There is no clearance margin: that is the planner's business.

Defaults of ``[arms]``
----------------------
The same numbers gonio's rig parser states (duplicated on purpose, so that the simulator never
imports it): ``radius_m`` 0.02 m (light) and 0.025 m (camera); ``from_m`` 0.8 × the arm's
distance (``[geometry] light_distance_m`` / ``camera_distance_m``); ``to_m`` the distance plus
the radius. ``clearance_m`` is read by the planner only. Other defaults used here: ``zero_tick``
2048, ``direction`` 1, a bus's ``baud`` 57600, and the white-reference pose θi 0°, θr 45°,
Δφ 180° (the park pose, :meth:`SolidRig.park_deg`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from drivers.errors import ConfigError

Vec = tuple[float, float, float]

TICKS_PER_REV = 4096
"""X-series encoder ticks per revolution in position mode."""
DEFAULT_ARM_RADIUS_M = {"light": 0.02, "camera": 0.025}
"""Capsule radius (m) of each arm when ``[arms]`` gives none (as gonio's rig parser)."""
DEFAULT_ARM_FROM_FRACTION = 0.8
"""Capsule start as a fraction of the arm's distance when ``[arms]`` gives none."""
DEFAULT_WHITE_REFERENCE_DEG = (0.0, 45.0, 180.0)
"""(θi, θr, Δφ) of ``[white_reference]`` when the rig file gives none (deg)."""
ARMS = ("light", "camera")


# ---------------------------------------------------------------------- vector helpers
def _sub(a: Vec, b: Vec) -> Vec:
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def _dot(a: Vec, b: Vec) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _along(p: Vec, d: Vec, s: float) -> Vec:
    return (p[0] + d[0] * s, p[1] + d[1] * s, p[2] + d[2] * s)


def _clamp01(x: float) -> float:
    return 0.0 if x < 0.0 else 1.0 if x > 1.0 else x


def closest_points(p1: Vec, q1: Vec, p2: Vec, q2: Vec) -> tuple[float, Vec, Vec]:
    """Closest points of segments p1–q1 and p2–q2: (distance m, point on the first, on the second).

    Minimises ``|p1 + s (q1 − p1) − p2 − t (q2 − p2)|`` over s, t in [0, 1]: the unconstrained
    minimum of the quadratic, clamped to the square edge by edge (degenerate segments are
    points; parallel ones take s = 0 and the matching t).
    """
    d1, d2, r = _sub(q1, p1), _sub(q2, p2), _sub(p1, p2)
    a, e, f = _dot(d1, d1), _dot(d2, d2), _dot(d2, r)
    tiny = 1e-18
    if a <= tiny and e <= tiny:
        s = t = 0.0
    elif a <= tiny:
        s, t = 0.0, _clamp01(f / e)
    else:
        c = _dot(d1, r)
        if e <= tiny:
            s, t = _clamp01(-c / a), 0.0
        else:
            b = _dot(d1, d2)
            denom = a * e - b * b
            s = _clamp01((b * f - c * e) / denom) if denom > 1e-12 * a * e else 0.0
            t = (b * s + f) / e
            if t < 0.0:
                s, t = _clamp01(-c / a), 0.0
            elif t > 1.0:
                s, t = _clamp01((b - c) / a), 1.0
    c1, c2 = _along(p1, d1, s), _along(p2, d2, t)
    return math.dist(c1, c2), c1, c2


# ---------------------------------------------------------------------- rig kinds
def _rad(joints: Mapping[str, float], name: str) -> float:
    return math.radians(joints.get(name, 0.0))


def _wrap_deg(angle: float) -> float:
    wrapped = (angle + 180.0) % 360.0 - 180.0
    return 180.0 if wrapped == -180.0 else wrapped


class ArmKinematics:
    """Forward kinematics of one rig kind (directions only; distances come from the capsules)."""

    kind = "abstract"
    joints: tuple[str, ...] = ()
    optional: tuple[str, ...] = ()
    arm_joints: Mapping[str, tuple[str, ...]] = {}
    """Joints that move each arm (``{"light": (...), "camera": (...)}``)."""

    def arm_directions(self, joints_deg: Mapping[str, float]) -> tuple[Vec, Vec]:
        """Unit vectors from the sample centre along the light and the camera arm (world frame)."""
        raise NotImplementedError

    def sample_directions(self, joints_deg: Mapping[str, float]) -> tuple[Vec, Vec]:
        """Light and camera directions in the sample's frame (normal +z)."""
        raise NotImplementedError

    def candidates(self, pose_deg: tuple[float, float, float]) -> list[dict[str, float]]:
        """Joint sets (deg, optional joints at 0) that realise (θi, θr, Δφ), best first."""
        return []


def pose_deg_of(kin: ArmKinematics, joints_deg: Mapping[str, float]) -> tuple[float, float, float]:
    """(θi, θr, Δφ) in degrees of ``joints_deg`` (Δφ = camera azimuth − light azimuth)."""
    light, camera = kin.sample_directions(joints_deg)

    def theta_phi(v: Vec) -> tuple[float, float]:
        return (math.degrees(math.atan2(math.hypot(v[0], v[1]), v[2])),
                math.degrees(math.atan2(v[1], v[0])))

    (ti, pl), (tr, pc) = theta_phi(light), theta_phi(camera)
    return ti, tr, _wrap_deg(pc - pl)


class OutOfPlaneArcs(ArmKinematics):
    """Light arc in the x–z plane; camera arc at ``camera_phi`` about z; optional turntable."""

    kind = "out-of-plane-arcs"
    joints = ("light_theta", "camera_theta", "camera_phi")
    optional = ("sample_phi",)
    arm_joints = {"light": ("light_theta",), "camera": ("camera_theta", "camera_phi")}

    def arm_directions(self, joints_deg: Mapping[str, float]) -> tuple[Vec, Vec]:
        lt, ct, cp = (_rad(joints_deg, n) for n in self.joints)
        return ((math.sin(lt), 0.0, math.cos(lt)),
                (math.sin(ct) * math.cos(cp), math.sin(ct) * math.sin(cp), math.cos(ct)))

    def sample_directions(self, joints_deg: Mapping[str, float]) -> tuple[Vec, Vec]:
        sp = _rad(joints_deg, "sample_phi")
        c, s = math.cos(sp), math.sin(sp)
        light, camera = self.arm_directions(joints_deg)
        return tuple((c * v[0] + s * v[1], -s * v[0] + c * v[1], v[2])  # type: ignore[return-value]
                     for v in (light, camera))

    def candidates(self, pose_deg: tuple[float, float, float]) -> list[dict[str, float]]:
        ti, tr, dp = pose_deg
        out = []
        for light_sign, phi_offset in ((1.0, 0.0), (-1.0, 180.0)):  # light on +x, then on −x
            phi = _wrap_deg(dp + phi_offset)
            for turn in (0.0, -360.0, 360.0):
                out.append({"light_theta": light_sign * ti, "camera_theta": tr,
                            "camera_phi": phi + turn})
        return out


class CoaxialArms(ArmKinematics):
    """Both arms turn about the vertical axis in the horizontal plane; the sample tilts."""

    kind = "coaxial-arms"
    joints = ("light_azimuth", "camera_azimuth", "stage_tilt")
    optional = ("stage_rotation",)
    arm_joints = {"light": ("light_azimuth",), "camera": ("camera_azimuth",)}

    def arm_directions(self, joints_deg: Mapping[str, float]) -> tuple[Vec, Vec]:
        al, ac = _rad(joints_deg, "light_azimuth"), _rad(joints_deg, "camera_azimuth")
        return (math.cos(al), math.sin(al), 0.0), (math.cos(ac), math.sin(ac), 0.0)

    def sample_directions(self, joints_deg: Mapping[str, float]) -> tuple[Vec, Vec]:
        t, psi = _rad(joints_deg, "stage_tilt"), _rad(joints_deg, "stage_rotation")
        # Sample axes in the world: z = the tilted normal, x0 = z turned up by 90°, y0 = z × x0.
        ez = (math.cos(t), 0.0, math.sin(t))
        ex0, ey0 = (-math.sin(t), 0.0, math.cos(t)), (0.0, -1.0, 0.0)
        cp, sp = math.cos(psi), math.sin(psi)
        ex = tuple(cp * a + sp * b for a, b in zip(ex0, ey0, strict=True))
        ey = tuple(-sp * a + cp * b for a, b in zip(ex0, ey0, strict=True))
        light, camera = self.arm_directions(joints_deg)
        return tuple((_dot(v, ex), _dot(v, ey), _dot(v, ez))  # type: ignore[arg-type, return-value]
                     for v in (light, camera))

    def candidates(self, pose_deg: tuple[float, float, float]) -> list[dict[str, float]]:
        # Arms in the horizontal plane, normal n = (cos t, 0, sin t): cos θ = cos(azimuth) cos t
        # for each arm, and the arms' azimuths differ by the angle γ between light and camera.
        # Eliminating the azimuths gives cos² t = (ci² + cr² − 2 ci cr cos γ) / sin² γ.
        ti, tr, dp = (math.radians(v) for v in pose_deg)
        ci, cr = math.cos(ti), math.cos(tr)
        cos_g = ci * cr + math.sin(ti) * math.sin(tr) * math.cos(dp)
        sin2_g = 1.0 - cos_g * cos_g
        # Light and camera along one line (sin γ = 0): any plane through it, take t = 0.
        u2 = 1.0 if sin2_g < 1e-12 else (ci * ci + cr * cr - 2.0 * ci * cr * cos_g) / sin2_g
        if not 0.0 < u2 <= 1.0 + 1e-9:
            return []
        u = min(1.0, math.sqrt(u2))
        al0 = math.degrees(math.acos(max(-1.0, min(1.0, ci / u))))
        ac0 = math.degrees(math.acos(max(-1.0, min(1.0, cr / u))))
        tilt = math.degrees(math.acos(u))
        out = []
        for t in (tilt, -tilt):
            for s1 in (1.0, -1.0):
                for s2 in (1.0, -1.0):
                    joints = {"light_azimuth": s1 * al0, "camera_azimuth": s2 * ac0,
                              "stage_tilt": t}
                    if _same_pose(pose_deg, pose_deg_of(self, joints)):
                        for turn_l in (0.0, -360.0, 360.0):
                            for turn_c in (0.0, -360.0, 360.0):
                                out.append({**joints,
                                            "light_azimuth": joints["light_azimuth"] + turn_l,
                                            "camera_azimuth": joints["camera_azimuth"] + turn_c})
        return out


def _same_pose(a: Sequence[float], b: Sequence[float], tol_deg: float = 1e-6) -> bool:
    if abs(a[0] - b[0]) > tol_deg or abs(a[1] - b[1]) > tol_deg:
        return False
    if min(a[0], a[1]) < 1e-6:  # a direction on the normal: Δφ is undefined
        return True
    return abs(_wrap_deg(a[2] - b[2])) <= tol_deg


class _NoArms(ArmKinematics):
    kind = "light-stage"


KINDS: dict[str, ArmKinematics] = {k.kind: k for k in (OutOfPlaneArcs(), CoaxialArms(), _NoArms())}
"""Rig-file ``kinematics`` name → the simulator's own forward kinematics."""


# ---------------------------------------------------------------------- the rig's solids
@dataclass(frozen=True)
class SolidAxis:
    """One joint's servo: ``deg = direction × (ticks − zero_tick) × 360 / ticks_per_rev``.

    ``min_deg``/``max_deg`` are the rig's soft limits (the simulator sets the servo's position
    limit registers from them); ``bus`` names the bus the servo is on.
    """

    servo_id: int
    zero_tick: float = 2048.0
    direction: int = 1
    ticks_per_rev: int = TICKS_PER_REV
    min_deg: float = -180.0
    max_deg: float = 180.0
    bus: str = "main"

    def deg(self, ticks: float) -> float:
        """Joint angle (deg) at Present Position ``ticks``."""
        return self.direction * (ticks - self.zero_tick) * 360.0 / self.ticks_per_rev

    def ticks(self, deg: float) -> float:
        """Present Position (ticks, not rounded) at joint angle ``deg``."""
        return self.zero_tick + self.direction * deg * self.ticks_per_rev / 360.0


@dataclass(frozen=True)
class Capsule:
    """An arm's solid part: radius (m), swept along its direction from ``from_m`` to ``to_m``."""

    radius_m: float
    from_m: float
    to_m: float

    def __post_init__(self) -> None:
        if self.radius_m < 0 or self.from_m < 0 or self.to_m < self.from_m:
            raise ConfigError(f"capsule needs radius_m ≥ 0 and 0 ≤ from_m ≤ to_m, got {self}")


@dataclass(frozen=True)
class Contact:
    """The arms' closest approach: gap (m, ≤ 0 when they touch) and the closest points (m) on
    the light's and the camera's capsule axis."""

    gap_m: float
    light_point_m: Vec
    camera_point_m: Vec


@dataclass(frozen=True)
class SolidRig:
    """The rig's solid parts as plain data.

    Parameters
    ----------
    kind:
        Rig kind (``"out-of-plane-arcs"``, ``"coaxial-arms"``, ``"light-stage"``).
    axes:
        ``{joint name: SolidAxis}`` for every servo-driven joint.
    arms:
        ``{"light": Capsule, "camera": Capsule}`` (empty for a light stage).
    bauds:
        ``{bus name: baud (bit/s)}``.
    white_reference_deg:
        (θi, θr, Δφ) of the white reference, the park pose (deg).
    """

    kind: str
    axes: Mapping[str, SolidAxis]
    arms: Mapping[str, Capsule] = field(default_factory=dict)
    bauds: Mapping[str, int] = field(default_factory=lambda: {"main": 57600})
    white_reference_deg: tuple[float, float, float] = DEFAULT_WHITE_REFERENCE_DEG

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ConfigError(f"rig kind '{self.kind}' is not simulated; use one of "
                              f"{', '.join(KINDS)}")
        kin = KINDS[self.kind]
        if self.arms:
            missing = [j for j in kin.joints if j not in self.axes]
            if missing or set(self.arms) != set(ARMS):
                raise ConfigError(f"{self.kind} solids need axes {list(kin.joints)} and arms "
                                  f"{list(ARMS)}; missing axes {missing}, arms {sorted(self.arms)}")

    @property
    def kinematics(self) -> ArmKinematics:
        """The simulator's forward kinematics for :attr:`kind`."""
        return KINDS[self.kind]

    @property
    def arm_axes(self) -> dict[str, tuple[str, ...]]:
        """``{arm: joints that move it}`` (empty without solids)."""
        return dict(self.kinematics.arm_joints) if self.arms else {}

    def segments(self, joints_deg: Mapping[str, float]) -> dict[str, tuple[Vec, Vec]]:
        """Each arm's capsule axis (start, end) in metres, world frame."""
        out = {}
        for arm, d in zip(ARMS, self.kinematics.arm_directions(joints_deg), strict=True):
            cap = self.arms[arm]
            out[arm] = ((d[0] * cap.from_m, d[1] * cap.from_m, d[2] * cap.from_m),
                        (d[0] * cap.to_m, d[1] * cap.to_m, d[2] * cap.to_m))
        return out

    def contact(self, joints_deg: Mapping[str, float]) -> Contact:
        """Gap (m) between the arms' capsules and the closest points; ``inf`` without solids."""
        if not self.arms:
            return Contact(math.inf, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
        seg = self.segments(joints_deg)
        dist, pl, pc = closest_points(*seg["light"], *seg["camera"])
        return Contact(dist - self.arms["light"].radius_m - self.arms["camera"].radius_m, pl, pc)

    def gap_m(self, joints_deg: Mapping[str, float]) -> float:
        """Distance (m) between the arms' surfaces; ≤ 0 when they touch."""
        return self.contact(joints_deg).gap_m

    def reach_m(self, arm: str) -> float:
        """Farthest point (m) of ``arm``'s capsule axis from the sample centre."""
        return self.arms[arm].to_m

    def park_deg(self) -> dict[str, float]:
        """Joints (deg) of the white-reference pose: the first solution within every axis'
        limits with the arms apart; optional joints at 0° (clamped into their limits).

        Raises
        ------
        ConfigError
            No solution fits the limits (give start positions explicitly).
        """
        rest = {n: min(max(0.0, a.min_deg), a.max_deg) for n, a in self.axes.items()}
        for cand in self.kinematics.candidates(self.white_reference_deg):
            joints = {**rest, **cand}
            inside = all(self.axes[n].min_deg - 1e-9 <= v <= self.axes[n].max_deg + 1e-9
                         for n, v in cand.items() if n in self.axes)
            if inside and self.gap_m(joints) > 0:
                return joints
        if not self.kinematics.joints:
            return rest
        raise ConfigError(
            f"the white-reference pose {self.white_reference_deg} has no joint solution within "
            f"the axis limits of this {self.kind} rig; give the start positions explicitly")


# ---------------------------------------------------------------------- from a rig file
def load_rig_toml(path: str | Path) -> dict[str, Any]:
    """A rig file parsed with :mod:`tomllib` (no validation: gonio's rig parser does that)."""
    import tomllib

    path = Path(path)
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ConfigError(f"cannot read rig file {path}: {exc.strerror or exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"rig file {path} is not valid TOML: {exc}") from None


def _table(data: Mapping[str, Any], key: str, where: str) -> Mapping[str, Any]:
    value = data.get(key, {})
    if not isinstance(value, Mapping):
        raise ConfigError(f"{where}: [{key}] must be a table")
    return value


def _number(table: Mapping[str, Any], key: str, where: str, default: float | None = None) -> float:
    value = table.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigError(f"{where}: {key} must be a number, got {value!r}")
    return float(value)


def solid_rig_from_toml(data: Mapping[str, Any], where: str = "rig file") -> SolidRig:
    """The :class:`SolidRig` of a parsed rig file (``tomllib`` dict), with the defaults stated
    in the module docstring. Only the keys the simulator needs are read."""
    kind = data.get("kinematics")
    if kind not in KINDS:
        raise ConfigError(f"{where}: kinematics {kind!r} is not simulated; use one of "
                          f"{', '.join(KINDS)}")
    bauds = {name: int(_number(b, "baud", f"{where} [buses.{name}]", 57600))
             for name, b in _table(data, "buses", where).items()}
    axes = {}
    for name, a in _table(data, "axes", where).items():
        w = f"{where} [axes.{name}]"
        if "id" not in a or "bus" not in a:
            raise ConfigError(f"{w}: needs id and bus")
        if a["bus"] not in bauds:
            raise ConfigError(f"{w}: bus '{a['bus']}' is not declared in [buses]")
        axes[name] = SolidAxis(
            servo_id=int(_number(a, "id", w)), zero_tick=_number(a, "zero_tick", w, 2048),
            direction=int(_number(a, "direction", w, 1)), min_deg=_number(a, "min_deg", w),
            max_deg=_number(a, "max_deg", w), bus=str(a["bus"]))
    arms: dict[str, Capsule] = {}
    if KINDS[kind].joints:
        geo = _table(data, "geometry", where)
        distance = {"light": _number(geo, "light_distance_m", f"{where} [geometry]"),
                    "camera": _number(geo, "camera_distance_m", f"{where} [geometry]")}
        arms_sec = _table(data, "arms", where)
        for arm in ARMS:
            sec = _table(arms_sec, arm, f"{where} [arms]")
            w = f"{where} [arms.{arm}]"
            radius = _number(sec, "radius_m", w, DEFAULT_ARM_RADIUS_M[arm])
            arms[arm] = Capsule(radius,
                                _number(sec, "from_m", w, DEFAULT_ARM_FROM_FRACTION * distance[arm]),
                                _number(sec, "to_m", w, distance[arm] + radius))
    wr = _table(data, "white_reference", where)
    white = tuple(_number(wr, key, f"{where} [white_reference]", default)
                  for key, default in zip(("theta_i_deg", "theta_r_deg", "delta_phi_deg"),
                                          DEFAULT_WHITE_REFERENCE_DEG, strict=True))
    return SolidRig(kind=kind, axes=axes, arms=arms, bauds=bauds,
                    white_reference_deg=white)  # type: ignore[arg-type]
