"""Plan files: which (θi, θr, Δφ) poses to measure, how to bin them, capture settings.

A plan is data: :func:`load_plan` parses a TOML file into a :class:`PlanSpec` whose
``poses()`` expands the sampling into candidate poses (degrees). Which candidates are safe and
useful, and in what order to take them, is the planner's job (:mod:`acquisition.planner`).
"""

from __future__ import annotations

import csv
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .config import Section, load_toml
from .kinematics import Pose

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

    def poses(self) -> list[Pose]:
        return list(self.candidate_poses)


Sampler = Callable[[Section], tuple[list[Pose], TableSpec]]


def _grid(sec: Section) -> tuple[list[Pose], TableSpec]:
    sec.check_keys({"kind", "theta_i", "theta_r", "delta_phi"})
    ti = parse_range(sec, "theta_i", 0, 90)
    tr = parse_range(sec, "theta_r", 0, 90)
    dp = parse_range(sec, "delta_phi", -180, 360)
    poses = [
        Pose(float(a), float(b), float(c))
        for a in ti.values() for b in tr.values() for c in dp.values()
    ]
    return poses, TableSpec(ti.edges(), tr.edges(), dp.edges())


def _list(sec: Section) -> tuple[list[Pose], TableSpec]:
    sec.check_keys({"kind", "poses", "csv", "bin_deg"})
    rows: list[list[float]] = []
    if "csv" in sec:
        csv_path = Path(sec.source).parent / sec.get("csv", str)
        try:
            with open(csv_path, newline="") as fh:
                for lineno, row in enumerate(csv.reader(fh), 1):
                    if not row or row[0].lstrip().startswith("#") or row[0].strip() == "theta_i":
                        continue
                    try:
                        rows.append([float(x) for x in row[:3]])
                    except ValueError:
                        problem = f"{csv_path}:{lineno}: expected 3 numbers, got {row}"
                        raise sec.error("csv", problem) from None
        except OSError as exc:
            raise sec.error("csv", f"cannot read {csv_path} ({exc.strerror})") from None
    else:
        rows = [list(map(float, p)) for p in sec.get("poses", list)]
    if any(len(r) != 3 for r in rows) or not rows:
        raise sec.error("poses", "must list [theta_i, theta_r, delta_phi] triples in degrees")
    poses = [Pose(*r) for r in rows]
    step = sec.number("bin_deg", 5.0, min=0.1)
    return poses, TableSpec(
        np.arange(0, 90 + step / 2, step), np.arange(0, 90 + step / 2, step),
        np.arange(0, 180 + step / 2, step),
    )


SAMPLERS: dict[str, Sampler] = {"grid": _grid, "list": _list}
"""``[sampling] kind`` → function expanding the table into candidate poses and table bins."""


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
    poses, table = SAMPLERS[kind](sampling)
    cons = top.section("constraints", {})
    cons.check_keys({"shadow_cone_deg", "max_elevation_deg"})
    cap = top.section("capture", {})
    cap.check_keys({"exposure_s", "iso", "reference_every"})
    if not poses:
        raise sampling.error(None, "expands to no pose: check the ranges")
    return PlanSpec(
        path=path,
        name=top.get("name", str, path.stem),
        sampling=kind,
        candidate_poses=tuple(poses),
        table=table,
        capture=CaptureSettings(
            exposure_s=cap.number("exposure_s", None, min=1e-6),
            iso=cap.integer("iso", None, min=1),
            reference_every=cap.integer("reference_every", 0, min=0),
        ),
        shadow_cone_deg=cons.number("shadow_cone_deg", None, min=0, max=90),
        max_elevation_deg=cons.number("max_elevation_deg", None, min=1, max=90),
        raw=top.data,
    )


