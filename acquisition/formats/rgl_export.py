"""``gonio export --format bsdf`` (a table or a MERL file into an RGL ``.bsdf``), and ``.bsdf``
files read back into gonio's other formats (MERL, CSV, EXR) and ``gonio info``."""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from acquisition.formats.interpolate import Brdf, table_interpolant
from acquisition.formats.merl import MERL_SCALES, MerlBRDF
from acquisition.formats.ndf import RETRO_LABEL
from acquisition.formats.rgl import DEFAULT_GRID, Grid, RglBsdf, write_bsdf
from acquisition.geometry.halfdiff import MERL_BINS, MERL_SHAPE, angles_from_halfdiff
from acquisition.tables import IsotropicTable

INTERPOLATION = ("trilinear between bin centres, each empty bin filled from the nearest "
                 "measured bin (the interpolant of gonio's lit-sphere render)")
DIRECTIONS = ("theta_i/phi_i: the direction towards the viewer (Mitsuba's si.wi); the warped "
              "direction: towards the light; rgb = f * cos(theta_light) * 4 sigma / D "
              "(jacobian = 1), so the renderer's eval gives f(light, view) * cos(theta_light)")
_CHUNK = 200_000


def source_brdf(table: IsotropicTable | MerlBRDF | RglBsdf) -> tuple[Brdf, dict[str, Any]]:
    """The continuous BRDF a ``.bsdf`` is resampled from, and what to say about it."""
    if isinstance(table, IsotropicTable):
        return table_interpolant(table), {
            "source_format": "gonio-isotropic-brdf", "provenance": dict(table.provenance),
            "measured_bins": int((table.count > 0).sum()), "interpolation": INTERPOLATION}
    if isinstance(table, MerlBRDF):
        def merl(ti: np.ndarray, tr: np.ndarray, dp: np.ndarray) -> np.ndarray:
            value = np.asarray(table(ti, tr, dp), float)
            return np.where(value < 0, np.nan, value)  # unmeasured: NaN, written as 0
        return merl, {"source_format": "MERL binary", "measured_bins": int(table.measured.sum()),
                      "interpolation": "nearest MERL bin (unmeasured bins as 0)"}
    return table, {"source_format": "RGL .bsdf (re-sampled)", "provenance": table.provenance}


def export_bsdf(table: IsotropicTable | MerlBRDF | RglBsdf, out: Path, source: Path,
                inputs: Iterable[str | os.PathLike[str]] = (), grid: Grid = DEFAULT_GRID) -> tuple[int, str]:
    """Write ``table`` as an RGB ``.bsdf``; returns (data nodes written, where D came from, in
    a few words)."""
    brdf, about = source_brdf(table)
    ndf = write_bsdf(out, brdf, {"source": str(source), **about, "directions": DIRECTIONS},
                     grid=grid, inputs=inputs)
    where = ndf.label
    if isinstance(table, IsotropicTable) and ndf.label == RETRO_LABEL:
        where = "from the table's near-retro bins, extrapolated to retro-reflection"
    return grid.theta_i_count * grid.data_res ** 2, where


def bsdf_as_merl(bsdf: RglBsdf) -> MerlBRDF:
    """The ``.bsdf`` evaluated at every MERL bin centre (bins with a direction at or below the
    horizon unmeasured), as a MERL BRDF."""
    from acquisition.formats.export import merl_bin_centres

    th, td, pd = (a.reshape(-1) for a in merl_bin_centres())
    values = np.full((MERL_BINS, 3), np.nan)
    for lo in range(0, MERL_BINS, _CHUNK):
        sl = slice(lo, lo + _CHUNK)
        ti, tr, dp = angles_from_halfdiff(th[sl], td[sl], pd[sl])
        above = (ti < 90.0) & (tr < 90.0)
        values[sl][above] = bsdf(ti[above], tr[above], dp[above])
    stored = np.moveaxis(values.reshape(*MERL_SHAPE, 3) / MERL_SCALES, -1, 0)
    return MerlBRDF(np.where(np.isnan(stored), -1.0, stored))


def bsdf_summary(bsdf: RglBsdf) -> dict[str, Any]:
    """What ``gonio info`` says of a ``.bsdf``: shape, θi range (degrees), nodes, value range."""
    rgb = bsdf.fields["rgb"]
    theta = np.degrees(bsdf.theta_i)
    return {"shape": tuple(int(n) for n in rgb.shape[:2] + rgb.shape[3:]),
            "axes": {"θi": (float(theta[0]), float(theta[-1])),
                     "φi": (float(np.degrees(bsdf.phi_i[0])), float(np.degrees(bsdf.phi_i[-1])))},
            "nodes": int(rgb.size // 3),
            "range": (float(rgb.min()), float(rgb.max())) if rgb.size else None,
            "provenance": bsdf.provenance}
