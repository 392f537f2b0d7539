"""Analysis through the API: open a table (a file or a session), fit models, check the
physics, compare, report."""

from __future__ import annotations

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
        from acquisition.reduction.point import reduce_session

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

    return compare_sides(open_side(a, parse_material), open_side(b, parse_material))
