"""Compare two BRDFs: tables, MERL files or material specs, over the bins both measured.

A side is an isotropic table (``.h5``), a MERL file (``.binary``) or an analytic material
spec (``ggx:albedo=0.2,alpha=0.3,f0=0.04``, any spec the simulated camera takes). The bins
compared are those of the first table side (two tables must share their edges: bins measured
in both); a MERL file or a spec is evaluated at those bins' mean angles (a MERL file's
unmeasured bins are left out). Without a table side, the MERL grid's measured bins (or, for
two specs, a 2.5° isotropic grid) are used.

Reported: relative error |B − A| / |A| (median, mean, 95th percentile, max, per channel and
over all), the log ratio's RMS, the metrics of :mod:`acquisition.analysis.metrics` with A as
reference, z-scores where the sides carry uncertainties, each side's coverage and the worst
bins.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from acquisition.analysis.fitdata import bin_solid_angles
from acquisition.analysis.metrics import metrics
from acquisition.formats.merl import MERL_FILE_BYTES, MerlBRDF, read_merl
from acquisition.geometry.halfdiff import angles_from_halfdiff
from acquisition.tables import IsotropicTable
from drivers.errors import ConfigError, MaterialError

WORST = 5


@dataclass
class Side:
    """One side of a comparison."""

    label: str
    kind: str
    """``"table"``, ``"merl"`` or ``"material"``."""
    table: IsotropicTable | None = None
    evaluate: Callable[[np.ndarray], np.ndarray] | None = None
    """(N, 3) angles (θi, θr, Δφ) in degrees → (N, 3) BRDF, NaN where unknown."""
    coverage: float = 1.0
    """Fraction of its own bins measured (tables, MERL files); 1 for a material."""


def open_side(source: str | Path | IsotropicTable,
              material: Callable[[str], Callable[..., np.ndarray]]) -> Side:
    """A side from a table object, a ``.h5`` table, a MERL file or a material spec, which
    ``material`` parses into a callable BRDF(θi, θr, Δφ in degrees) → (…, 3) sr⁻¹."""
    if isinstance(source, IsotropicTable):
        return _table_side(source, "table")
    path = Path(str(source))
    if path.is_file():
        if path.stat().st_size == MERL_FILE_BYTES:
            return _merl_side(read_merl(path), str(path))
        return _table_side(IsotropicTable.load_h5(path), str(path))
    if ":" not in str(source):
        raise ConfigError(f"{source} is neither a file nor a material spec: give a table (.h5), "
                          "a MERL file or a spec such as ggx:albedo=0.2,alpha=0.3,f0=0.04")
    try:
        brdf = material(str(source))
    except MaterialError as exc:
        raise ConfigError(str(exc)) from None
    return Side(str(source), "material", evaluate=lambda a: np.asarray(brdf(*a.T), float))


def _table_side(table: IsotropicTable, label: str) -> Side:
    ti, tr, _ = np.meshgrid(*table.centers(), indexing="ij")
    above = (ti < 90) & (tr < 90)
    return Side(label, "table", table=table,
                coverage=float(((table.count > 0) & above).sum() / max(int(above.sum()), 1)))


def _merl_side(brdf: MerlBRDF, label: str) -> Side:
    def evaluate(a: np.ndarray) -> np.ndarray:
        v = np.asarray(brdf(*a.T), float)
        return np.where(v < 0, np.nan, v)

    return Side(label, "merl", evaluate=evaluate, coverage=float(brdf.measured.mean()))


@dataclass
class Comparison:
    """What :func:`compare` found."""

    a: Side
    b: Side
    bins: int
    relative: dict[str, dict[str, float]]
    """Statistic (median, mean, p95, max) → channel (R, G, B, all) → relative error."""
    log_rms: float
    metrics: dict[str, float]
    z: dict[str, float] | None
    worst: list[dict[str, Any]] = field(default_factory=list)
    angles: np.ndarray = field(default_factory=lambda: np.empty((0, 3)), repr=False)
    values_a: np.ndarray = field(default_factory=lambda: np.empty((0, 3)), repr=False)
    values_b: np.ndarray = field(default_factory=lambda: np.empty((0, 3)), repr=False)

    def to_dict(self) -> dict[str, Any]:
        return {"a": {"source": self.a.label, "kind": self.a.kind, "coverage": self.a.coverage},
                "b": {"source": self.b.label, "kind": self.b.kind, "coverage": self.b.coverage},
                "bins": self.bins, "relative_error": self.relative, "log_rms": self.log_rms,
                "metrics": self.metrics, "z": self.z, "worst": self.worst}

    def lines(self) -> list[str]:
        rel = self.relative
        out = [f"A {self.a.label} ({self.a.kind}, {self.a.coverage:.0%} covered) vs "
               f"B {self.b.label} ({self.b.kind}, {self.b.coverage:.0%} covered): {self.bins} bins",
               "relative error |B − A| / A: median {:.3g} %, mean {:.3g} %, 95th percentile "
               "{:.3g} %, max {:.3g} %".format(*(100 * rel[s]["all"]
                                                 for s in ("median", "mean", "p95", "max"))),
               "metrics (A as the reference): "
               + ", ".join(f"{k} {v:.4g}" for k, v in self.metrics.items())]
        if self.z is not None:
            out.append(f"z = (B − A)/u: median |z| {self.z['median_abs']:.2f}, "
                       f"{self.z['beyond_3']:.1%} of values beyond 3")
        for w in self.worst:
            out.append("  worst: θi {:.1f}° θr {:.1f}° Δφ {:.1f}° ({}): A {:.4g}, B {:.4g} sr⁻¹ "
                       "({:+.2f} %)".format(*w["angles_deg"], w["channel"], w["a"], w["b"],
                                            100 * w["relative"]))
        return out


def _grid(a: Side, b: Side) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None,
                                     np.ndarray | None, np.ndarray]:
    """(angles, values A, values B, u A, u B, weights) over the bins to compare."""
    tables = [s for s in (a, b) if s.table is not None]
    if tables:
        ref = tables[0].table
        assert ref is not None
        keep = ref.count > 0
        if a.table is not None and b.table is not None:
            for name in ("theta_i_edges", "theta_r_edges", "delta_phi_edges"):
                if not np.array_equal(getattr(a.table, name), getattr(b.table, name)):
                    raise ConfigError(f"the two tables are binned differently ({name}): compare "
                                      "tables reduced with the same plan")
            keep &= b.table.count > 0
        angles = ref.mean_angles[keep]
        weights = bin_solid_angles(ref)[keep]

        def values(s: Side) -> tuple[np.ndarray, np.ndarray | None]:
            if s.table is not None:
                u = s.table.std_error[keep] if s.table.tracks_uncertainty else None
                return s.table.mean[keep], u
            assert s.evaluate is not None
            return s.evaluate(angles), None

        (va, ua), (vb, ub) = values(a), values(b)
        return angles, va, vb, ua, ub, weights
    if a.kind == "merl" or b.kind == "merl":
        from acquisition.formats.export import merl_bin_centres

        th, td, pd = (x.ravel() for x in merl_bin_centres())
        ti, tr, dp = angles_from_halfdiff(th, td, pd)
    else:
        c = np.arange(1.25, 90, 2.5)
        ti, tr, dp = (x.ravel() for x in np.meshgrid(c, c, np.arange(1.25, 180, 2.5), indexing="ij"))
    angles = np.stack([ti, tr, dp], -1)
    angles = angles[(angles[:, 0] < 89) & (angles[:, 1] < 89)]
    w = np.sin(np.radians(angles[:, 0])) * np.sin(np.radians(angles[:, 1]))
    assert a.evaluate is not None and b.evaluate is not None
    return angles, a.evaluate(angles), b.evaluate(angles), None, None, w


def compare(a: Side, b: Side) -> Comparison:
    """Compare ``b`` against ``a`` (the reference) over the bins both know."""
    angles, va, vb, ua, ub, w = _grid(a, b)
    ok = np.all(np.isfinite(va) & np.isfinite(vb) & (np.abs(va) > 0), axis=1)
    if not ok.any():
        raise ConfigError(f"{a.label} and {b.label} share no measured bin: nothing to compare")
    angles, va, vb, w = angles[ok], va[ok], vb[ok], w[ok]
    rel = np.abs(vb - va) / np.abs(va)
    stats = {"median": np.median, "mean": np.mean, "p95": lambda x, **k: np.percentile(x, 95, **k),
             "max": np.max}
    relative = {name: {**{c: float(fn(rel[:, k])) for k, c in enumerate("RGB")},
                       "all": float(fn(rel))} for name, fn in stats.items()}
    pos = (va > 0) & (vb > 0)
    log_rms = float(np.sqrt(np.mean(np.log(vb[pos] / va[pos]) ** 2))) if pos.any() else float("nan")
    z = None
    if ua is not None or ub is not None:
        u2 = sum(u[ok] ** 2 for u in (ua, ub) if u is not None)
        zz = np.abs(vb - va) / np.sqrt(u2)
        z = {"median_abs": float(np.median(zz)), "beyond_3": float(np.mean(zz > 3))}
    order = np.argsort(-np.max(rel, axis=1))[:WORST]
    channel = np.argmax(rel, axis=1)
    shown = angles.copy()
    shown[:, 2] = np.abs((shown[:, 2] + 180.0) % 360.0 - 180.0)  # Δφ folded into [0°, 180°]
    worst = [{"angles_deg": shown[k].tolist(), "channel": "RGB"[channel[k]],
              "a": float(va[k, channel[k]]), "b": float(vb[k, channel[k]]),
              "relative": float((vb[k, channel[k]] - va[k, channel[k]]) / va[k, channel[k]])}
             for k in order]
    return Comparison(a, b, int(ok.sum()), relative, log_rms,
                      metrics(va, vb, np.cos(np.radians(angles[:, 0])), w), z, worst,
                      angles, va, vb)
