"""BRDF tables into the field's formats (MERL binary, CSV, EXR slices, RGL ``.bsdf``) and
table summaries.

Inputs are a ``gonio-isotropic-brdf`` HDF5 table (``gonio reduce``), a MERL ``.binary``
file or an RGL ``.bsdf`` file (evaluated on the MERL grid for MERL, CSV and EXR). See
docs/formats.md for every output layout.
"""

from __future__ import annotations

import csv
import json
import os
from collections.abc import Iterable
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np

from acquisition.formats.merl import (
    MERL_FILE_BYTES,
    MERL_SCALES,
    MerlBRDF,
    is_merl_file,
    read_merl,
    write_merl,
)
from acquisition.formats.merl import WHAT as MERL_WHAT
from acquisition.formats.rgl import WHAT as BSDF_WHAT
from acquisition.formats.rgl import RglBsdf, is_gonio_bsdf, read_bsdf
from acquisition.formats.tensorfile import is_tensor_file
from acquisition.geometry.halfdiff import MERL_BINS, MERL_SHAPE, angles_from_halfdiff, merl_bin_edges
from acquisition.tables import IsotropicTable, MerlTable
from acquisition.tables.isotropic import load_merl_h5
from calibration.exr import exr_has, write_exr
from drivers.errors import ConfigError
from drivers.storage import atomic_output, check_folder, check_output, ensure_folder

Table = IsotropicTable | MerlBRDF


class ExportFormat(StrEnum):
    """``gonio export --format`` values."""

    MERL = "merl"
    CSV = "csv"
    EXR = "exr"
    BSDF = "bsdf"
    """RGL-EPFL tensor file for Mitsuba 3's ``measured`` plug-in (:mod:`acquisition.formats.rgl`)."""


DEFAULT_SUFFIX = {ExportFormat.MERL: ".binary", ExportFormat.CSV: ".csv", ExportFormat.EXR: "-exr",
                  ExportFormat.BSDF: ".bsdf"}


def load_table(path: str | os.PathLike[str]) -> Table | RglBsdf:
    """An isotropic HDF5 table, a MERL file or an RGL ``.bsdf``, told apart by content (MERL:
    exact size; ``.bsdf``: the tensor-file magic)."""
    path = Path(path)
    if path.is_dir():
        raise ConfigError(f"{path} is a folder: give its table (`gonio reduce {path}` writes "
                          f"{path / 'brdf.h5'}), a MERL .binary or an RGL .bsdf file")
    if not path.is_file():
        raise ConfigError(f"table {path} does not exist: give a .h5 table, a MERL .binary or an "
                          "RGL .bsdf file")
    if path.stat().st_size == MERL_FILE_BYTES:
        return read_merl(path)
    if is_tensor_file(path):
        return read_bsdf(path)
    return IsotropicTable.load_h5(path)


# ------------------------------------------------------------------------------ MERL
def merl_bin_centres() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centres (θh, θd, φd) in degrees of every MERL bin, each shaped (90, 90, 180).

    θh is centred in index space (square-root spacing), θd and φd linearly.
    """
    _, d, p = merl_bin_edges()
    k = (np.arange(MERL_SHAPE[0]) + 0.5) / MERL_SHAPE[0]
    th = 90.0 * k**2
    td = 0.5 * (d[:-1] + d[1:])
    pd = 0.5 * (p[:-1] + p[1:])
    return np.meshgrid(th, td, pd, indexing="ij")  # type: ignore[return-value]


def isotropic_to_merl(table: IsotropicTable) -> np.ndarray:
    """Resample an isotropic table onto the MERL grid, (90, 90, 180, 3) in sr⁻¹, NaN unmeasured.

    Each MERL bin takes the value of the isotropic bin holding its centre (nearest bin, no
    interpolation); bins whose centre is below the horizon, outside the table or in an empty
    bin stay unmeasured.
    """
    th, td, pd = merl_bin_centres()
    ti, tr, dp = (a.reshape(-1) for a in angles_from_halfdiff(th, td, pd))
    below = (ti >= 90.0) | (tr >= 90.0)
    mean = table.mean.reshape(-1, 3)
    count = table.count.reshape(-1)
    out = np.full((ti.size, 3), np.nan)
    todo = ~below
    # A MERL bin holds both (wi, wo) and (wo, wi) (reciprocity): take the table's bin for the
    # centre's own order, else the swapped one.
    for a, b in ((ti, tr), (tr, ti)):
        flat = table.flat_index(a, b, dp)
        ok = todo & (flat >= 0)
        ok[ok] = count[flat[ok]] > 0
        out[ok] = mean[flat[ok]]
        todo &= ~ok
    return out.reshape(*MERL_SHAPE, 3)


Inputs = Iterable[str | os.PathLike[str]]


def export_merl(table: Table | MerlTable, out: Path, inputs: Inputs = ()) -> int:
    """Write a MERL binary; returns the number of MERL bins holding a value. A MERL table
    (an image-based session's, kept in its ``.h5``) is written as measured; an isotropic
    table is copied onto the MERL grid by nearest bin (:func:`isotropic_to_merl`)."""
    if isinstance(table, MerlBRDF):
        write_merl(out, table, inputs=inputs)  # byte for byte what was read
        return int(table.measured.sum())
    if isinstance(table, MerlTable):
        write_merl(out, table, inputs=inputs)
        return int(table.measured.sum())
    values = isotropic_to_merl(table)
    write_merl(out, values, inputs=inputs)
    return int(np.isfinite(values).all(axis=-1).sum())


@dataclass(frozen=True)
class Exported:
    """What :func:`export_table` wrote: where, and how much of it is measured."""

    path: Path
    format: str
    count: int
    """Images (EXR), rows (CSV) or MERL bins holding a value (MERL)."""
    measured_bins: int
    """Bins of the source table that hold a measurement."""
    filled_bins: int = 0
    """MERL bins given a value by the nearest measured isotropic bin (not measured there)."""
    note: str = ""
    """What else the line says (``.bsdf``: where the NDF came from; a ``.bsdf`` source: the
    MERL grid it was evaluated on)."""

    def line(self) -> str:
        """The one-line report (``gonio export``)."""
        if self.format == ExportFormat.BSDF:
            what = f"{self.measured_bins} measured bins" if self.measured_bins else "a .bsdf"
            return (f"{self.path}: {what} resampled onto {self.count:,} RGL "
                    f"nodes; NDF {self.note}")
        if self.note:
            return f"{self.path}: {self.count:,} values from {self.note}"
        if self.format == ExportFormat.EXR:
            return f"{self.path}: {self.count} images of {self.measured_bins} measured bins"
        if self.filled_bins:
            return (f"{self.path}: {self.measured_bins} measured isotropic bins, copied by "
                    f"nearest bin onto {self.filled_bins:,} of {MERL_BINS:,} MERL bins "
                    "(none of them measured on the MERL grid itself)")
        return f"{self.path}: {self.measured_bins} measured bins"


# ------------------------------------------------------------------------------ CSV
ISO_CSV_HEADER = ("theta_i_deg", "theta_r_deg", "delta_phi_deg", "R_per_sr", "G_per_sr",
                  "B_per_sr", "var_R", "var_G", "var_B", "count")
MERL_CSV_HEADER = ("theta_h_deg", "theta_d_deg", "phi_d_deg", "R_per_sr", "G_per_sr", "B_per_sr")


CSV_WHAT = "CSV export"


def _csv_header(path: str | os.PathLike[str]) -> str | None:
    try:
        with open(path, "rb") as fh:
            return fh.readline(512).decode("ascii").rstrip("\r\n")
    except (OSError, UnicodeDecodeError):
        return None


def is_csv_export(path: str | os.PathLike[str]) -> bool:
    """True when ``path`` starts with the header row of a gonio CSV export (it may be replaced)."""
    return _csv_header(path) in {",".join(ISO_CSV_HEADER), ",".join(MERL_CSV_HEADER)}


def export_csv(table: Table, out: Path, inputs: Inputs = ()) -> int:
    """One row per measured bin (bin centres in degrees); returns the row count."""
    if isinstance(table, MerlBRDF):
        header = MERL_CSV_HEADER
        th, td, pd = merl_bin_centres()
        sel = table.measured
        rows = np.column_stack([th[sel], td[sel], pd[sel], table.values[sel]])
    else:
        header = ISO_CSV_HEADER
        ci, cr, cp = np.meshgrid(*table.centers(), indexing="ij")
        sel = table.count > 0
        rows = np.column_stack([ci[sel], cr[sel], cp[sel], table.mean[sel], table.variance[sel],
                                table.count[sel]])
    fmt = ["%.10g"] * len(header)
    if header is ISO_CSV_HEADER:
        fmt[-1] = "%d"

    def verify(tmp: Path) -> None:
        with open(tmp, "rb") as fh:
            lines = sum(1 for _ in fh)
        if _csv_header(tmp) != ",".join(header) or lines != rows.shape[0] + 1:
            raise ValueError(f"{lines} lines read back, wrote {rows.shape[0] + 1}")

    with atomic_output(out, what=CSV_WHAT, verify=verify, ours=is_csv_export,
                       inputs=inputs) as tmp, open(tmp, "w", newline="") as fh:
        csv.writer(fh).writerow(header)
        np.savetxt(fh, rows, fmt=fmt, delimiter=",")
    return int(rows.shape[0])


# ------------------------------------------------------------------------------ EXR
def _provenance(table: Table) -> dict[str, Any]:
    if isinstance(table, MerlBRDF):
        return {"source": str(table.path) if table.path else None, "format": "MERL"}
    return dict(table.provenance)


EXR_WHAT = "EXR slice"
is_exr_slice = exr_has("gonio:quantity", "brdf")
"""True for a BRDF slice gonio exported (it may be replaced)."""


def export_exr(table: Table, out: Path, inputs: Inputs = ()) -> list[Path]:
    """One float32 EXR per first-axis bin (θi, or θh for MERL) in the folder ``out``.

    Image rows run over the second axis (θr / θd), columns over the third (Δφ / φd);
    channels R, G, B (sr⁻¹, NaN unmeasured) and ``count``. Units, bin edges and provenance
    are EXR attributes (``gonio:*``).
    """
    if isinstance(table, MerlBRDF):
        names = ("theta_h", "theta_d", "phi_d")
        edges = merl_bin_edges()
        mean = np.where(table.measured[..., None], table.values, np.nan)
        count = table.measured.astype(np.float32)
    else:
        names = ("theta_i", "theta_r", "delta_phi")
        edges = (table.theta_i_edges, table.theta_r_edges, table.delta_phi_edges)
        mean = table.mean
        count = table.count.astype(np.float32)
    paths = [out / f"{names[0]}_{k:03d}.exr" for k in range(mean.shape[0])]
    ensure_folder(out, what="EXR folder", inputs=inputs)
    for path in paths:  # refuse before writing any
        check_output(path, what=EXR_WHAT, ours=is_exr_slice, inputs=inputs)
    common: dict[str, object] = {
        "gonio:units": "1/sr", "gonio:quantity": "brdf", "gonio:slice_axis": names[0],
        "gonio:rows_axis": names[1], "gonio:columns_axis": names[2],
        **{f"gonio:{name}_edges_deg": e for name, e in zip(names[1:], edges[1:], strict=True)},
        "gonio:provenance": json.dumps(_provenance(table)),
    }
    for k, path in enumerate(paths):
        lo, hi = float(edges[0][k]), float(edges[0][k + 1])
        pixels = np.concatenate([mean[k], count[k][..., None]], axis=-1)
        write_exr(path, pixels, {**common, f"gonio:{names[0]}_deg": 0.5 * (lo + hi),
                                 f"gonio:{names[0]}_range_deg": [lo, hi]},
                  what=EXR_WHAT, channels=("R", "G", "B", "count"), ours=is_exr_slice,
                  inputs=inputs)
    return paths


_WHAT = {ExportFormat.MERL: (MERL_WHAT, is_merl_file), ExportFormat.CSV: (CSV_WHAT, is_csv_export),
         ExportFormat.BSDF: (BSDF_WHAT, is_gonio_bsdf)}


def export_table(
    table_path: str | os.PathLike[str], fmt: ExportFormat | str, out: str | os.PathLike[str] | None
) -> Exported:
    """Export ``table_path`` as ``fmt`` to ``out`` (default beside the table)."""
    try:
        fmt = ExportFormat(fmt)
    except ValueError:
        raise ConfigError(f"unknown export format {fmt!r}: use "
                          + ", ".join(f.value for f in ExportFormat)) from None
    src = Path(table_path)
    dest = Path(out) if out else src.with_name(src.stem + DEFAULT_SUFFIX[fmt])
    inputs = (src,)
    if fmt is ExportFormat.EXR:
        check_folder(dest, what="EXR folder", inputs=inputs)
    else:  # refuse before loading the table
        check_output(dest, what=_WHAT[fmt][0], ours=_WHAT[fmt][1], inputs=inputs)
    loaded = load_table(src)
    if fmt is ExportFormat.BSDF:
        from acquisition.formats.rgl_export import export_bsdf

        measured = (int((loaded.count > 0).sum()) if isinstance(loaded, IsotropicTable)
                    else int(loaded.measured.sum()) if isinstance(loaded, MerlBRDF) else 0)
        nodes, ndf_source = export_bsdf(loaded, dest, src, inputs)
        return Exported(dest, fmt.value, nodes, measured, note=ndf_source)
    note = ""
    if isinstance(loaded, RglBsdf):
        from acquisition.formats.rgl_export import bsdf_as_merl

        loaded, note = bsdf_as_merl(loaded), f"the .bsdf evaluated at the MERL bin centres of {src}"
    table: Table = loaded
    measured = int(table.measured.sum()) if isinstance(table, MerlBRDF) else int((table.count > 0).sum())
    if fmt is ExportFormat.MERL:
        merl = load_merl_h5(src) if isinstance(table, IsotropicTable) else None
        if merl is not None:  # an image-based session's own MERL table: measured, not filled
            n = export_merl(merl, dest, inputs)
            return Exported(dest, fmt.value, n, n, 0)
        n = export_merl(table, dest, inputs)
        filled = 0 if isinstance(table, MerlBRDF) else n
        return Exported(dest, fmt.value, n, measured, filled, note)
    if fmt is ExportFormat.CSV:
        return Exported(dest, fmt.value, export_csv(table, dest, inputs), measured, note=note)
    return Exported(dest, fmt.value, len(export_exr(table, dest, inputs)), measured, note=note)


# ------------------------------------------------------------------------------ info
@dataclass(frozen=True)
class TableInfo:
    """What ``gonio info TABLE`` prints."""

    path: Path
    format: str
    shape: tuple[int, ...]
    axes: dict[str, tuple[float, float]]
    """Axis name → (first edge, last edge), degrees."""
    measured_bins: int
    units: str
    samples: int | None
    provenance: dict[str, Any]
    value_range: tuple[float, float] | None
    """Min and max measured BRDF over all channels, sr⁻¹."""

    @property
    def coverage_pct(self) -> float:
        return 100.0 * self.measured_bins / int(np.prod(self.shape))

    def lines(self) -> list[str]:
        out = [f"table     {self.path} ({self.format})",
               "bins      " + " × ".join(str(n) for n in self.shape) + "  ("
               + ", ".join(f"{k} {a:g}…{b:g}°" for k, (a, b) in self.axes.items()) + ")",
               f"coverage  {self.measured_bins} measured bins, {self.coverage_pct:.1f} %"]
        if self.samples is not None:
            out.append(f"samples   {self.samples}")
        out.append(f"units     {self.units}")
        if self.value_range is not None:
            out.append(f"values    {self.value_range[0]:.4g} … {self.value_range[1]:.4g} sr⁻¹")
        for k, v in self.provenance.items():
            out.append(f"{'provenance' if k == next(iter(self.provenance)) else '':9} {k} = {v}")
        return out


def table_info(path: str | os.PathLike[str]) -> TableInfo:
    """Coverage, units and provenance of an isotropic table, a MERL file or an RGL ``.bsdf``."""
    path = Path(path)
    table = load_table(path)
    if isinstance(table, RglBsdf):
        from acquisition.formats.rgl_export import bsdf_summary

        about = bsdf_summary(table)
        return TableInfo(path, "RGL .bsdf (tensor file, RGB)", about["shape"], about["axes"],
                         about["nodes"], "rgb = f · cos θ(light) · 4σ/D on the warped grid "
                         "(the renderer's value f · cos θ, sr⁻¹)", None, about["provenance"], None)
    if isinstance(table, MerlBRDF):
        meas = table.measured
        vals = table.values[meas]
        h, d, p = merl_bin_edges()
        scales = ", ".join(f"{s:.6g}" for s in MERL_SCALES)
        return TableInfo(
            path, "MERL binary", MERL_SHAPE,
            {"θh": (h[0], h[-1]), "θd": (d[0], d[-1]), "φd": (p[0], p[-1])},
            int(meas.sum()), f"1/sr (stored value × scale, scales R,G,B = {scales})", None,
            {"header": list(table.header), "unmeasured": "negative stored values"},
            (float(vals.min()), float(vals.max())) if vals.size else None,
        )
    meas = table.count > 0
    vals = table.mean[meas]
    return TableInfo(
        path, f"gonio-isotropic-brdf v{_h5_version(path)} (HDF5)", table.shape,
        {"θi": (table.theta_i_edges[0], table.theta_i_edges[-1]),
         "θr": (table.theta_r_edges[0], table.theta_r_edges[-1]),
         "Δφ": (table.delta_phi_edges[0], table.delta_phi_edges[-1])},
        int(meas.sum()), "1/sr", int(table.count.sum()), dict(table.provenance),
        (float(np.nanmin(vals)), float(np.nanmax(vals))) if vals.size else None,
    )


def _h5_version(path: Path) -> int:
    """The format version a table file states."""
    import h5py

    with h5py.File(path, "r") as f:
        return int(f.attrs.get("version", 1))
