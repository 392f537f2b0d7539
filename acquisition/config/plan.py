"""Plan files: which (θi, θr, Δφ) poses to measure, how to bin them, capture settings.

A plan is data: :func:`load_plan` parses a TOML file into a :class:`PlanSpec` whose
``poses()`` expands the sampling into candidate poses (degrees). Which candidates are safe and
useful, and in what order to take them, is the planner's job (:mod:`acquisition.planning.planner`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from acquisition.config.toml import Section, load_toml
from acquisition.geometry import sampling
from acquisition.geometry.kinematics import Pose

PLAN_FORMAT_VERSION = 1


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
    """``key = { start = .., stop = .., step = .. }`` in degrees within [lo, hi]."""
    r = sec.section(key)
    r.check_keys({"start", "stop", "step"})
    rng = AxisRange(r.number("start", min=lo, max=hi), r.number("stop", min=lo, max=hi),
                    r.number("step", min=1e-6))
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
    step = sec.number("bin_deg", default_deg, min=0.1, max=90)
    edges = np.unique(np.clip(np.arange(0, 90 + step, step), 0, 90))
    return TableSpec(edges, edges.copy(), np.unique(np.clip(np.arange(0, 180 + step, step), 0, 180)))


def _grid(sec: Section) -> tuple[np.ndarray, TableSpec]:
    sec.check_keys(COMMON_KEYS | {"theta_i", "theta_r", "delta_phi"})
    ti = parse_range(sec, "theta_i", 0, 90)
    tr = parse_range(sec, "theta_r", 0, 90)
    dp = parse_range(sec, "delta_phi", -180, 360)
    poses = sampling.grid(ti.values(), tr.values(), dp.values())
    if "bin_deg" in sec:
        return poses, _binned_table(sec)
    return poses, TableSpec(ti.edges(), tr.edges(), dp.edges())


def _list(sec: Section) -> tuple[np.ndarray, TableSpec]:
    sec.check_keys(COMMON_KEYS | {"poses", "csv"})
    if "csv" in sec:
        csv_path = Path(sec.source).parent / sec.get("csv", str)
        try:
            poses = sampling.read_pose_csv(csv_path)
        except ValueError as exc:
            raise sec.error("csv", str(exc)) from None
        except OSError as exc:
            raise sec.error("csv", f"cannot read {csv_path} ({exc.strerror})") from None
    else:
        rows = sec.get("poses", list)
        if not all(isinstance(r, list) and len(r) == 3 for r in rows):
            raise sec.error("poses", "must list [theta_i, theta_r, delta_phi] triples in degrees")
        poses = np.array(rows, dtype=float).reshape(-1, 3)
    if not len(poses):
        raise sec.error("poses", "must list [theta_i, theta_r, delta_phi] triples in degrees")
    return poses, _binned_table(sec)


def _uniform(sec: Section) -> tuple[np.ndarray, TableSpec]:
    sec.check_keys(COMMON_KEYS | {"light_count", "camera_count", "max_theta_deg"})
    poses = sampling.uniform_solid_angle(
        sec.integer("light_count", min=1, max=1000),
        sec.integer("camera_count", min=1, max=100000),
        sec.number("max_theta_deg", 90.0, min=1, max=90),
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
    ti = parse_range(sec, "theta_i", 0, 90)
    step = sec.number("step_deg", 10.0, min=0.01, max=90)
    min_step = sec.number("min_step_deg", step / 4, min=0.01, max=step)
    poses = sampling.specular_refined(
        ti.values(), step, min_step, spread=sec.number("spread", 2.0, min=0.0),
        max_theta_r_deg=sec.number("max_theta_r_deg", 90.0, min=1, max=90),
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
    top = Section(load_toml(path, "plan file"), str(path))
    top.check_keys({"format_version", "name", "description", "sampling", "constraints",
                    "capture"})
    version = top.integer("format_version")
    if version != PLAN_FORMAT_VERSION:
        raise top.error("format_version", f"is {version}; this gonio reads version {PLAN_FORMAT_VERSION}")
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
    return PlanSpec(
        path=path,
        name=top.get("name", str, path.stem),
        sampling=kind,
        candidate_poses=tuple(poses),
        table=table,
        reciprocal=reciprocal,
        capture=CaptureSettings(
            exposure_s=cap.number("exposure_s", None, min=1e-6),
            iso=cap.integer("iso", None, min=1),
            reference_every=cap.integer("reference_every", 0, min=0),
            hdr=cap.get("hdr", bool, False),
            target_snr=cap.number("target_snr", 20.0, min=1.0),
        ),
        shadow_cone_deg=cons.number("shadow_cone_deg", None, min=0, max=90),
        max_elevation_deg=cons.number("max_elevation_deg", None, min=1, max=90),
        raw=top.data,
    )


