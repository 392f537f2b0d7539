"""Analysis through the API: open a table (a file or a session), fit models, check the
physics, compare, report."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from acquisition.analysis.checks import Check, check_table
from acquisition.analysis.compare import Comparison, open_side
from acquisition.analysis.compare import compare as compare_sides
from acquisition.analysis.fit import FitResult, fit_model
from acquisition.analysis.fitdata import bin_data
from acquisition.analysis.models import make_model
from acquisition.tables import IsotropicTable
from drivers.errors import ConfigError


def open_table(source: str | Path | IsotropicTable, *,
               calibration: str | Path | None = None) -> IsotropicTable:
    """The isotropic table of ``source``: an ``IsotropicTable``, a ``.h5`` table file, or a
    session folder (reduced in memory, nothing written; ``calibration`` applies a bundle)."""
    if isinstance(source, IsotropicTable):
        return source
    path = Path(source)
    if path.is_dir():
        from acquisition.api.sessions import refuse_calibration_of_lightstage
        from acquisition.lightstage.reduce import is_lightstage_session, reduce_lightstage_session
        from acquisition.reduction.point import reduce_session

        if is_lightstage_session(path):
            refuse_calibration_of_lightstage(path, calibration)
            return reduce_lightstage_session(path).table
        return reduce_session(path, bundle=calibration).table
    if not path.exists():
        raise ConfigError(f"{path} does not exist: give a table (.h5) or a session folder")
    return IsotropicTable.load_h5(path)


def median_relative_uncertainty(table: IsotropicTable) -> float:
    """Median over measured bins and channels of std_error / |mean|, in % (NaN untracked)."""
    measured = table.count > 0
    if not table.tracks_uncertainty or not measured.any():
        return float("nan")
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = table.std_error[measured] / np.abs(table.mean[measured])
    return float(np.nanmedian(rel) * 100.0)


def fit(source: str | Path | IsotropicTable, model: str = "ggx", *, lobes: int = 1,
        masking: str = "separable", fresnel: str = "schlick",
        calibration: str | Path | None = None) -> FitResult:
    """Fit ``model`` (:data:`acquisition.analysis.models.MODEL_NAMES`) to a table or session:
    weighted by its per-bin uncertainty, evaluated at each bin's mean angles, with 1σ
    (:mod:`acquisition.analysis.fit`)."""
    try:
        m = make_model(model, lobes=lobes, masking=masking, fresnel=fresnel)
    except ValueError as exc:
        raise ConfigError(f"gonio fit: {exc}") from None
    return fit_model(m, bin_data(open_table(source, calibration=calibration)))


@dataclass
class CheckReport:
    """What :func:`check` found: every check, and whether any failed."""

    source: str
    checks: list[Check]

    @property
    def failed(self) -> list[Check]:
        return [c for c in self.checks if c.passed is False]

    def lines(self) -> list[str]:
        return [c.line for c in self.checks]

    def to_dict(self) -> dict[str, Any]:
        return {"source": self.source, "passed": not self.failed,
                "checks": {c.name: {"passed": c.passed, "line": c.line, **c.details}
                           for c in self.checks}}


def check(source: str | Path | IsotropicTable, *,
          calibration: str | Path | None = None) -> CheckReport:
    """Physical checks of a table or session (:mod:`acquisition.analysis.checks`)."""
    return CheckReport(str(source) if not isinstance(source, IsotropicTable) else "table",
                       check_table(open_table(source, calibration=calibration)))


def compare(a: str | Path | IsotropicTable, b: str | Path | IsotropicTable) -> Comparison:
    """Compare ``b`` with ``a``: each a table (``.h5``), a MERL file or a material spec
    (:mod:`acquisition.analysis.compare`)."""
    from acquisition.simworld.materials import parse_material

    sides = [open_table(s) if Path(str(s)).is_dir() else s for s in (a, b)]
    return compare_sides(*(open_side(s, parse_material) for s in sides))


REPORT_MODELS = ("lambert", "oren-nayar", "blinn-phong", "ggx", "beckmann")
"""Models a report fits by default."""


@dataclass
class ReportResult:
    """Where the report went and what it holds."""

    path: Path
    fits: list[FitResult]
    checks_passed: bool
    warnings: list[str]
    """What the report could not do (a fit, the comparison), as it says inside."""


def report(source: str | Path, out: str | Path, *, models: tuple[str, ...] = REPORT_MODELS,
           reference: str | Path | None = None, calibration: str | Path | None = None,
           table: IsotropicTable | None = None,
           notice: Callable[[str], None] | None = None) -> ReportResult:
    """Write the HTML report of a table or session (:mod:`acquisition.analysis.report`).

    ``reference``: a table, MERL file or material spec to compare with; by default a
    simulated capture is compared with the material the simulated camera rendered.
    ``table``: the session's table when the caller has just reduced it (not reduced again).
    ``notice`` hears what the report is doing (it takes seconds to minutes).
    """
    from acquisition.analysis.report import build_html, report_data, write_report
    from acquisition.simworld.materials import parse_material

    say = notice or (lambda _text: None)
    if Path(out).suffix.lower() not in (".html", ".htm"):
        raise ConfigError(f"report {out}: a report is one HTML file: end the name in .html")
    for name in models:
        try:
            make_model(name)
        except ValueError as exc:
            raise ConfigError(f"--models: {exc}") from None
    path = Path(source)
    if table is None:
        say(f"reading {path}")
        table = open_table(path, calibration=calibration)
    prov = table.provenance
    measured: dict[str, Any] = {"source": str(path)}
    for key in ("rig", "plan", "material", "seed", "calibration_bundle", "noise_model"):
        if prov.get(key) is not None:
            measured[key] = prov[key]
    if "reference_drift_pct" in prov:
        measured["white-reference drift"] = f"{prov['reference_drift_pct']:.3f} %"
    warnings: list[str] = []
    if path.is_dir():
        measured.update(_session_lines(path, warnings))
    fits, fit_errors = [], []
    data = bin_data(table)
    for name in models:
        say(f"fitting {name}")
        try:
            fits.append(fit_model(make_model(name), data))
        except (ConfigError, ValueError) as exc:
            fit_errors.append(f"{name}: not fitted ({exc})")
    spec = reference if reference is not None else prov.get("material")
    comparison = None
    if spec:
        try:
            comparison = compare_sides(open_side(table, parse_material),
                                       open_side(spec, parse_material))
        except ConfigError as exc:
            warnings.append(f"comparison with {spec} skipped: {exc}")
    title = f"BRDF report: {prov.get('plan', path.name)} on {prov.get('rig', 'a rig')}"
    say("drawing the figures")
    rd = report_data(table, title, measured=measured, warnings=warnings, fits=fits,
                     fit_errors=fit_errors, comparison=comparison)
    inputs = [path] + ([Path(reference)] if reference and Path(str(reference)).exists() else [])
    written = write_report(build_html(rd), out, inputs=inputs)
    return ReportResult(written, fits, not any(c.passed is False for c in rd.checks),
                        warnings + fit_errors)


def _session_lines(folder: Path, warnings: list[str]) -> dict[str, Any]:
    """Planned vs actual time, progress and warnings of a session folder."""
    from acquisition.session.status import session_status

    status = session_status(folder, drift=False, verify=False).to_json()
    info = status.get("info", {})
    out: dict[str, Any] = {"steps done": f"{status.get('done')} of {status.get('total')}"}
    if info.get("estimated_s") is not None and status.get("device_s") is not None:
        out["rig time: planned / actual"] = (f"{info['estimated_s']:.1f} s / "
                                            f"{status['device_s']:.1f} s")
    for event in status.get("events", []):
        warnings.append(" ".join(str(e) for e in event[1:]))
    for frame in status.get("bad_frames", []):
        warnings.append(f"bad frame: {frame}")
    for axis, link in status.get("link", {}).items():
        if link.get("retries") or link.get("resends"):
            warnings.append(f"bus {axis}: {link['retries']} retries, {link['resends']} resends "
                            f"in {link['requests']} requests")
    return out
