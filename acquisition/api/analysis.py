"""Analysis through the API: open a table (a file or a session), fit models, check the
physics, compare, report."""

from __future__ import annotations

from pathlib import Path

import numpy as np

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
