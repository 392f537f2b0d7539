"""Plan files: which (θi, θr, Δφ) poses to measure, how to bin them, capture settings.

A plan is data: :func:`load_plan` parses a TOML file into a :class:`PlanSpec` whose
``poses()`` expands the sampling into candidate poses (degrees). Which candidates are safe and
useful, and in what order to take them, is the planner's job (:mod:`acquisition.planning.planner`).

Angles are degrees unless the plan says ``units = "rad"``; radians are converted to degrees
as the file is read, so a :class:`PlanSpec` is always in degrees. A degree plan whose angles
all lie within ±2π warns (:class:`UnitsWarning`): it is probably in radians.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from acquisition.config.rig import (
    EXPOSURE_RANGE_S,
    ISO_RANGE,
    MAX_ELEVATION_RANGE_DEG,
    SHADOW_CONE_RANGE_DEG,
    SIM_ISO_RANGE,
    RigConfig,
)
from acquisition.config.toml import ANGLE_UNITS, RAD_SNAP, TWO_PI, Section, load_toml
from acquisition.geometry import sampling
from acquisition.geometry.kinematics import Pose
from drivers.errors import ConfigError

PLAN_FORMAT_VERSION = 1

THETA_RANGE_DEG = (0.0, 90.0)
"""θi and θr a plan may name (grid ranges, list and CSV poses), degrees."""
DELTA_PHI_RANGE_DEG = (-180.0, 360.0)
"""Δφ a plan may name, degrees."""
MIN_STEP_DEG = 0.01
"""Smallest grid or specular step, degrees (finer steps expand to millions of poses)."""


class UnitsWarning(UserWarning):
    """Angles that look like radians where degrees are expected (a plan, a move)."""


def warn_if_radians(angles: Iterable[float], what: str, fix: str, *, stacklevel: int = 2) -> bool:
    """Warn (:class:`UnitsWarning`) when every angle of ``angles`` lies within ±2π and one is not
    zero: degrees that small are more likely radians. ``what`` names where they come from,
    ``fix`` says what to do; returns whether it warned."""
    values = [float(a) for a in angles]
    if not values or not any(values) or max(abs(a) for a in values) > TWO_PI:
        return False
    largest = max(values, key=abs)
    warnings.warn(f"{what}: every angle lies within ±2π (largest {largest:g}), read as degrees: "
                  f"if they are radians, {fix}", UnitsWarning, stacklevel=stacklevel + 1)
    return True


@dataclass(frozen=True)
class AxisRange:
    """Inclusive range of angles in degrees: start, start+step, …, ≤ stop."""

    start: float
    stop: float
    step: float

    def values(self) -> np.ndarray:
        n = int(np.floor((self.stop - self.start) / self.step + 1e-9)) + 1
        return self.start + self.step * np.arange(n)

    def edges(self) -> np.ndarray:
        """Bin edges centred on the values (so bin centres are exactly the grid's angles)."""
        v = self.values()
        return np.concatenate([[v[0] - self.step / 2], v + self.step / 2])


def parse_range(sec: Section, key: str, lo: float, hi: float) -> AxisRange:
    """``key = { start = .., stop = .., step = .. }`` (the plan's units) within [lo, hi]°."""
    r = sec.section(key)
    r.check_keys({"start", "stop", "step"})
    rng = AxisRange(r.angle("start", min=lo, max=hi), r.angle("stop", min=lo, max=hi),
                    r.angle("step", min=MIN_STEP_DEG, width=True))
    if rng.stop < rng.start:
        raise r.error("stop", f"must be ≥ start ({rng.stop:g} < {rng.start:g})")
    return rng


@dataclass(frozen=True)
class TableSpec:
    """Bin edges (degrees) of the isotropic table a session is reduced into."""

    theta_i_edges: np.ndarray
    theta_r_edges: np.ndarray
    delta_phi_edges: np.ndarray


@dataclass(frozen=True)
class CaptureSettings:
    """Per-plan overrides of the rig's camera settings; None keeps the rig's value."""

    exposure_s: float | None = None
    iso: int | None = None
    reference_every: int = 0
    """Capture the white reference every N poses as well as first and last (0 = first/last)."""
    hdr: bool = False
    """Bracket every pose automatically (:class:`acquisition.session.steps.ExposeHDR`)."""
    target_snr: float = 20.0
    """HDR: SNR the darkest valid ROI superpixel of each pose's merge must reach."""


@dataclass(frozen=True)
class PlanSpec:
    """A validated plan file."""

    path: Path
    name: str
    sampling: str
    candidate_poses: tuple[Pose, ...]
    table: TableSpec
    capture: CaptureSettings
    shadow_cone_deg: float | None = None
    max_elevation_deg: float | None = None
    raw: dict[str, Any] = field(default_factory=dict)
    reciprocal: str = "once"
    """"once": a pose and its reciprocal (θi ↔ θr) are measured once; "both": each."""
    units: str = "deg"
    """The file's ``units`` (every angle here is degrees, converted if it was "rad")."""

    def poses(self) -> list[Pose]:
        return list(self.candidate_poses)

    @property
    def mirror_delta_phi(self) -> bool:
        """True when the table folds Δφ into [0°, 180°], so Δφ and −Δφ measure the same bin."""
        edges = self.table.delta_phi_edges
        return bool(edges[-1] - edges[0] <= 270.0)


Sampler = Callable[[Section], tuple[np.ndarray, TableSpec]]

COMMON_KEYS = {"kind", "reciprocal", "bin_deg"}
"""Keys every ``[sampling]`` table may have besides its kind's own."""

RECIPROCAL_CHOICES = ("once", "both")
"""``[sampling] reciprocal``: measure a pose and its reciprocal (θi ↔ θr) once or both."""


def _binned_table(sec: Section, default_deg: float = 5.0) -> TableSpec:
    """A table of ``bin_deg`` bins on θi, θr ∈ [0°, 90°] and Δφ ∈ [0°, 180°]."""
    step = sec.angle("bin_deg", default_deg, min=0.1, max=90, width=True)
    edges = np.unique(np.clip(np.arange(0, 90 + step, step), 0, 90))
    return TableSpec(edges, edges.copy(), np.unique(np.clip(np.arange(0, 180 + step, step), 0, 180)))


def _grid(sec: Section) -> tuple[np.ndarray, TableSpec]:
    sec.check_keys(COMMON_KEYS | {"theta_i", "theta_r", "delta_phi"})
    ti = parse_range(sec, "theta_i", *THETA_RANGE_DEG)
    tr = parse_range(sec, "theta_r", *THETA_RANGE_DEG)
    dp = parse_range(sec, "delta_phi", *DELTA_PHI_RANGE_DEG)
    poses = sampling.grid(ti.values(), tr.values(), dp.values())
    if "bin_deg" in sec:
        return poses, _binned_table(sec)
    return poses, TableSpec(ti.edges(), tr.edges(), dp.edges())


def _list(sec: Section) -> tuple[np.ndarray, TableSpec]:
    sec.check_keys(COMMON_KEYS | {"poses", "csv"})
    key = "csv" if "csv" in sec else "poses"
    if key == "csv":
        csv_path = Path(sec.source).parent / sec.get("csv", str)
        try:
            poses = sampling.read_pose_csv(csv_path)
        except ValueError as exc:
            raise sec.error("csv", str(exc)) from None
        except OSError as exc:
            raise sec.error("csv", f"cannot read {csv_path} ({exc.strerror})") from None
    else:
        rows = sec.get("poses", list)
        if not all(isinstance(r, list) and len(r) == 3 and all(
                isinstance(v, int | float) and not isinstance(v, bool) for v in r) for r in rows):
            raise sec.error("poses", f"must list [theta_i, theta_r, delta_phi] triples of numbers "
                                     f"({sec.units})")
        poses = np.array(rows, dtype=float).reshape(-1, 3)
    if not len(poses):
        raise sec.error(key, f"must list [theta_i, theta_r, delta_phi] triples ({sec.units})")
    return _checked_poses(sec, key, poses), _binned_table(sec)


def _checked_poses(sec: Section, key: str, written: np.ndarray) -> np.ndarray:
    """Poses (N, 3) as written (the plan's units) → degrees, each within the limits a grid
    plan has (:data:`THETA_RANGE_DEG`, :data:`DELTA_PHI_RANGE_DEG`); else a ConfigError naming
    the first pose outside them."""
    rad = sec.units == "rad"
    poses = np.degrees(written) if rad else written.astype(float)
    limits = (THETA_RANGE_DEG, THETA_RANGE_DEG, DELTA_PHI_RANGE_DEG)
    for col, (name, (lo, hi)) in enumerate(zip(("θi", "θr", "Δφ"), limits, strict=True)):
        v = poses[:, col]
        if rad:  # π/2 written as 1.5708 is 90°
            snap = np.degrees(RAD_SNAP)
            v[(v < lo) & (v >= lo - snap)] = lo
            v[(v > hi) & (v <= hi + snap)] = hi
        bad = ~np.isfinite(v) | (v < lo) | (v > hi)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            entry = "[" + ", ".join(f"{x:g}" for x in written[i]) + "]"
            shown = f"{written[i, col]:g} rad ({v[i]:.4g}°)" if rad else f"{v[i]:g}°"
            raise sec.error(key, f"pose {i + 1} {entry} has {name} = {shown}, outside "
                                 f"{lo:g}…{hi:g}° (the limits of a grid plan)")
    sec.angles.extend(written.ravel().tolist())
    return poses


def _uniform(sec: Section) -> tuple[np.ndarray, TableSpec]:
    sec.check_keys(COMMON_KEYS | {"light_count", "camera_count", "max_theta_deg"})
    poses = sampling.uniform_solid_angle(
        sec.integer("light_count", min=1, max=1000),
        sec.integer("camera_count", min=1, max=100000),
        sec.angle("max_theta_deg", 90.0, min=1, max=90),
    )
    return poses, _binned_table(sec)


def _merl(sec: Section) -> tuple[np.ndarray, TableSpec]:
    sec.check_keys(COMMON_KEYS | {"theta_h_count", "theta_d_count", "phi_d_count"})
    poses = sampling.merl_half_diff(
        sec.integer("theta_h_count", 90, min=1, max=90),
        sec.integer("theta_d_count", 90, min=1, max=90),
        sec.integer("phi_d_count", 180, min=1, max=180),
    )
    return poses, _binned_table(sec)


def _specular(sec: Section) -> tuple[np.ndarray, TableSpec]:
    sec.check_keys(COMMON_KEYS | {"theta_i", "step_deg", "min_step_deg", "spread", "max_theta_r_deg"})
    ti = parse_range(sec, "theta_i", *THETA_RANGE_DEG)
    step = sec.angle("step_deg", 10.0, min=MIN_STEP_DEG, max=90, width=True)
    min_step = sec.angle("min_step_deg", step / 4, min=MIN_STEP_DEG, max=step, width=True)
    poses = sampling.specular_refined(
        ti.values(), step, min_step, spread=sec.number("spread", 2.0, min=0.0, max=10.0),
        max_theta_r_deg=sec.angle("max_theta_r_deg", 90.0, min=1, max=90),
    )
    return poses, _binned_table(sec)


SAMPLERS: dict[str, Sampler] = {
    "grid": _grid,
    "list": _list,
    "uniform": _uniform,
    "merl": _merl,
    "specular": _specular,
}
"""``[sampling] kind`` → function expanding the table into candidate poses (N, 3) and bins."""


def load_plan(path: str | Path) -> PlanSpec:
    """Parse and validate a plan file; raises :class:`ConfigError` naming file and field."""
    path = Path(path)
    top = Section(load_toml(path, "plan file"), str(path), units_key=True)
    top.check_keys({"format_version", "name", "description", "units", "sampling", "constraints",
                    "capture"})
    version = top.integer("format_version")
    if version != PLAN_FORMAT_VERSION:
        raise top.error("format_version", f"is {version}; this gonio reads version {PLAN_FORMAT_VERSION}")
    top.units = top.get("units", str, "deg")
    if top.units not in ANGLE_UNITS:
        raise top.error("units", f"must be one of {', '.join(ANGLE_UNITS)}, got '{top.units}'")
    sampling = top.section("sampling")
    kind = sampling.get("kind", str)
    if kind not in SAMPLERS:
        raise sampling.error("kind", f"unknown '{kind}' (known: {', '.join(SAMPLERS)})")
    reciprocal = sampling.get("reciprocal", str, "once")
    if reciprocal not in RECIPROCAL_CHOICES:
        raise sampling.error("reciprocal", f"must be one of {', '.join(RECIPROCAL_CHOICES)}, "
                                           f"got '{reciprocal}'")
    array, table = SAMPLERS[kind](sampling)
    poses = [Pose(float(a), float(b), float(c)) for a, b, c in array]
    cons = top.section("constraints", {})
    cons.check_keys({"shadow_cone_deg", "max_elevation_deg"})
    cap = top.section("capture", {})
    cap.check_keys({"exposure_s", "iso", "reference_every", "hdr", "target_snr"})
    if not poses:
        raise sampling.error(None, "expands to no pose: check the ranges")
    shadow = cons.angle("shadow_cone_deg", None, min=SHADOW_CONE_RANGE_DEG[0],
                        max=SHADOW_CONE_RANGE_DEG[1])
    elevation = cons.angle("max_elevation_deg", None, min=MAX_ELEVATION_RANGE_DEG[0],
                           max=MAX_ELEVATION_RANGE_DEG[1])
    settings = CaptureSettings(
        exposure_s=cap.number("exposure_s", None, min=EXPOSURE_RANGE_S[0],
                              max=EXPOSURE_RANGE_S[1], unit="s"),
        iso=cap.integer("iso", None, min=ISO_RANGE[0], max=ISO_RANGE[1]),
        reference_every=cap.integer("reference_every", 0, min=0, max=1_000_000),
        hdr=cap.get("hdr", bool, False),
        target_snr=cap.number("target_snr", 20.0, min=1.0, max=10_000.0),
    )
    if top.units == "deg":
        warn_if_radians(top.angles, str(path), 'set units = "rad" in the plan', stacklevel=2)
    return PlanSpec(
        path=path,
        name=top.get("name", str, path.stem),
        sampling=kind,
        candidate_poses=tuple(poses),
        table=table,
        reciprocal=reciprocal,
        capture=settings,
        shadow_cone_deg=shadow,
        max_elevation_deg=elevation,
        raw=top.data,
        units=top.units,
    )


def check_plan_on_rig(plan: PlanSpec, rig: RigConfig) -> None:
    """What a plan asks of this rig's devices, checked before anything is created: an
    ``[capture] iso`` the simulated camera takes."""
    iso = plan.capture.iso
    lo, hi = SIM_ISO_RANGE
    if rig.camera.driver == "simulated" and iso is not None and not lo <= iso <= hi:
        raise ConfigError(f"{plan.path}: [capture] iso: the simulated camera of {rig.path} takes "
                          f"ISO {lo}–{hi}, got {iso}")
