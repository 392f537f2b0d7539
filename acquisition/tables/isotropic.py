"""Isotropic BRDF table over (θi, θr, Δφ) bins and its HDF5 file (``gonio-isotropic-brdf`` v1).

File layout (every dataset and attribute is written, nothing else):

=================  ================  =====================================================
name               type / shape      meaning
=================  ================  =====================================================
theta_i_edges      float64 [Ni+1]    bin edges of θi, degrees
theta_r_edges      float64 [Nr+1]    bin edges of θr, degrees
delta_phi_edges    float64 [Nφ+1]    bin edges of Δφ = camera − light azimuth, degrees
mean               float64 [Ni,Nr,Nφ,3]  mean BRDF per bin, sr⁻¹ (not cos-weighted); NaN empty
variance           float64 [Ni,Nr,Nφ,3]  sample variance (ddof 1) of the values; NaN if count<2
count              int64 [Ni,Nr,Nφ]  samples per bin
@units             "1/sr"
@quantity          "brdf"
@channels          "R,G,B"
@format            "gonio-isotropic-brdf"
@version           1
@provenance        JSON string given by the writer
=================  ================  =====================================================
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from acquisition.tables.accumulator import (
    DROP_NAN,
    DROP_OUT_OF_RANGE,
    BinAccumulator,
    TableStatistics,
)
from acquisition.tables.angles import as_flat_float64, fold_delta_phi, wrap_delta_phi
from acquisition.tables.backend import kernels
from drivers.errors import ConfigError
from drivers.storage import atomic_output

FORMAT = "gonio-isotropic-brdf"
VERSION = 1
_DATASETS = ("theta_i_edges", "theta_r_edges", "delta_phi_edges", "mean", "variance", "count")
WHAT = "BRDF table"


def is_table_file(path: str | os.PathLike[str]) -> bool:
    """True when ``path`` is a ``gonio-isotropic-brdf`` HDF5 file (one gonio may replace)."""
    try:
        with h5py.File(path, "r") as f:
            return _attr_str(f.attrs.get("format")) == FORMAT
    except (OSError, ValueError):
        return False


def _verify_table(shape: tuple[int, ...]) -> Any:
    def verify(tmp: Path) -> None:
        with h5py.File(tmp, "r") as f:
            if _attr_str(f.attrs.get("format")) != FORMAT or f["count"].shape != shape:
                raise ValueError("format attribute or count dataset missing")
            f["mean"][(0,) * (len(shape) + 1)]  # data readable
    return verify


def _check_edges(name: str, edges: Any) -> np.ndarray:
    e = np.asarray(edges, dtype=np.float64)
    if e.ndim != 1 or e.size < 2 or not np.all(np.isfinite(e)) or not np.all(np.diff(e) > 0):
        raise ConfigError(
            f"{name}: need at least 2 finite, strictly increasing edges in degrees, got {e!r}"
        )
    return e


def axis_index(values: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Bin index of each value: bins are [e_k, e_k+1), the last one closed; −1 outside."""
    n = edges.size - 1
    idx = np.searchsorted(edges, values, side="right") - 1
    idx[values == edges[-1]] = n - 1
    idx[(idx < 0) | (idx >= n)] = -1
    return idx


class IsotropicTable(TableStatistics):
    """Streaming isotropic BRDF table binned over (θi, θr, Δφ) in degrees.

    Edge rule, the same bit for bit in both backends (IEEE double, no tolerance):

    * Δφ is first brought into the table's range: folded, d = Δφ mod 360 (floor modulo as
      numpy's ``np.mod`` and Python's ``%``: d ∈ [0, 360), −0 → +0, rounding can give 360 for
      a tiny negative Δφ), then 360 − d where d > 180, so −180, 180 and 540 all give 180 and
      360 gives 0; wrapped, d = e₀ + (Δφ − e₀) mod 360;
    * each angle v falls in bin k when e_k ≤ v < e_{k+1}, and in the last bin when v equals
      the last edge; below the first edge or above the last it is out of range;
    * NaN in any angle drops the sample as NaN; ±inf is out of range.

    Parameters
    ----------
    theta_i_edges, theta_r_edges, delta_phi_edges
        Strictly increasing bin edges, degrees. Bins are half-open [e_k, e_k+1) except the last,
        which includes its upper edge (so θ = 90° or a folded Δφ = 180° lands in the last bin).
    fold_delta_phi
        Fold Δφ into [0, 180] before binning (isotropy: f(Δφ) = f(−Δφ)). ``None`` (default)
        folds when the Δφ edges span at most 270° (a half turn such as [0, 180] or
        [−5, 185]); otherwise Δφ is wrapped into [edges[0], edges[0] + 360).
    provenance
        Free metadata (JSON-serialisable) saved with the table.
    backend
        ``"numba"`` (fused compiled index + accumulation) or ``"numpy"``; default from
        ``$GONIO_BINNING_BACKEND``, else numba. Both give bit-identical tables.
    """

    def __init__(
        self,
        theta_i_edges: Any,
        theta_r_edges: Any,
        delta_phi_edges: Any,
        *,
        fold_delta_phi: bool | None = None,
        provenance: Mapping[str, Any] | None = None,
        backend: str | None = None,
    ) -> None:
        self.theta_i_edges = _check_edges("theta_i_edges", theta_i_edges)
        self.theta_r_edges = _check_edges("theta_r_edges", theta_r_edges)
        self.delta_phi_edges = _check_edges("delta_phi_edges", delta_phi_edges)
        span = self.delta_phi_edges[-1] - self.delta_phi_edges[0]
        self.fold_delta_phi = bool(span <= 270.0) if fold_delta_phi is None else fold_delta_phi
        self.provenance: dict[str, Any] = dict(provenance or {})
        self._acc = BinAccumulator(self.shape, 3, backend=backend)
        self._stored: tuple[np.ndarray, np.ndarray] | None = None  # (mean, variance) as loaded

    # ------------------------------------------------------------------ geometry
    @property
    def shape(self) -> tuple[int, int, int]:
        """(Ni, Nr, Nφ)."""
        return (
            self.theta_i_edges.size - 1,
            self.theta_r_edges.size - 1,
            self.delta_phi_edges.size - 1,
        )

    def centers(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Bin centres (θi, θr, Δφ) in degrees, one 1-D array per axis."""
        return tuple(  # type: ignore[return-value]
            0.5 * (e[:-1] + e[1:])
            for e in (self.theta_i_edges, self.theta_r_edges, self.delta_phi_edges)
        )

    def normalise_delta_phi(self, delta_phi_deg: np.ndarray | float) -> np.ndarray:
        """Δφ (deg) as this table bins it: folded into [0, 180] or wrapped from the first edge."""
        if self.fold_delta_phi:
            return fold_delta_phi(delta_phi_deg)
        return wrap_delta_phi(delta_phi_deg, float(self.delta_phi_edges[0]))

    def flat_index(
        self,
        theta_i_deg: np.ndarray | float,
        theta_r_deg: np.ndarray | float,
        delta_phi_deg: np.ndarray | float,
    ) -> np.ndarray:
        """Flat C-order bin index per sample (the class's edge rule); −1 outside the table,
        −2 for a NaN angle. What :meth:`add` bins, with either backend."""
        ti, tr, dp = as_flat_float64(theta_i_deg, theta_r_deg, delta_phi_deg)
        nan = np.isnan(ti) | np.isnan(tr) | np.isnan(dp)
        ii = axis_index(ti, self.theta_i_edges)
        ir = axis_index(tr, self.theta_r_edges)
        with np.errstate(invalid="ignore"):  # ±inf Δφ normalises to NaN: out of range
            ip = axis_index(self.normalise_delta_phi(dp), self.delta_phi_edges)
        _, nr, nphi = self.shape
        flat = (ii * nr + ir) * nphi + ip
        flat[(ii < 0) | (ir < 0) | (ip < 0)] = DROP_OUT_OF_RANGE
        flat[nan] = DROP_NAN
        return flat

    # ------------------------------------------------------------------ accumulation
    def add(
        self,
        theta_i_deg: np.ndarray | float,
        theta_r_deg: np.ndarray | float,
        delta_phi_deg: np.ndarray | float,
        rgb: np.ndarray,
    ) -> int:
        """Bin samples: angles in degrees (broadcast to N), ``rgb`` (N, 3) BRDF in sr⁻¹.

        Samples outside the edges or with any NaN are dropped and counted
        (:attr:`n_dropped_range`, :attr:`n_dropped_nan`). Returns the number kept.
        """
        rgb = np.asarray(rgb, dtype=np.float64).reshape(-1, 3)
        ti, tr, dp = as_flat_float64(theta_i_deg, theta_r_deg, delta_phi_deg)
        n = rgb.shape[0]
        if ti.size == 1 and n != 1:
            ti, tr, dp = (np.broadcast_to(a, (n,)) for a in (ti, tr, dp))
        elif ti.size != n:
            raise ValueError(f"{ti.size} angle samples but {n} RGB samples")
        self._stored = None
        if self.backend == "numpy":
            return self._acc.add_flat(self.flat_index(ti, tr, dp), rgb)
        return self._acc.add_with(
            kernels().iso_add,
            ti,
            tr,
            dp,
            rgb,
            self.theta_i_edges,
            self.theta_r_edges,
            self.delta_phi_edges,
            bool(self.fold_delta_phi),
        )

    def merge(self, other: IsotropicTable) -> IsotropicTable:
        """New table holding the samples of both (edges must be equal)."""
        self._check_same_edges(other)
        new = self._empty_like()
        new._acc.merge_from(self._acc)
        new._acc.merge_from(other._acc)
        return new

    def __add__(self, other: IsotropicTable) -> IsotropicTable:
        return self.merge(other)

    def fold_reciprocity(self) -> IsotropicTable:
        """New table pooling bins (θi, θr, Δφ) and (θr, θi, −Δφ) (Helmholtz reciprocity).

        Both bins of each pair hold the pooled statistics; diagonal bins are unchanged (no
        sample is counted twice within a bin). Needs equal θi and θr edges and Δφ edges that
        map onto themselves under Δφ → −Δφ (always true for a folded [0, 180] table).
        """
        if not np.array_equal(self.theta_i_edges, self.theta_r_edges):
            raise ConfigError("reciprocity folding needs equal theta_i_edges and theta_r_edges")
        centers = self.centers()[2]
        mirror = axis_index(self.normalise_delta_phi(-centers), self.delta_phi_edges)
        if np.any(mirror < 0) or not np.array_equal(np.sort(mirror), np.arange(centers.size)):
            raise ConfigError(
                "reciprocity folding needs delta_phi_edges symmetric under Δφ → −Δφ "
                "(e.g. [0, 180] folded or [-180, 180])"
            )
        shp = self.shape
        selfmirror = np.flatnonzero(mirror == np.arange(centers.size))
        di, dp = np.meshgrid(np.arange(shp[0]), selfmirror, indexing="ij")

        def pool(x: np.ndarray) -> np.ndarray:
            out = x + x.swapaxes(-3, -2)[..., mirror]
            # The diagonal bins (θi bin = θr bin, Δφ bin its own mirror) were added to themselves.
            out[..., di, di, dp] = x[..., di, di, dp]
            return out

        new = self._empty_like()
        new._acc.pool_from(self._acc, pool)
        return new

    # ------------------------------------------------------------------ statistics
    # count, variance_of_mean, n_samples, n_dropped_*: see TableStatistics.
    @property
    def mean(self) -> np.ndarray:
        """Mean BRDF per bin, float64 [Ni, Nr, Nφ, 3] in sr⁻¹; NaN where unmeasured."""
        if self._stored is not None:
            return self._stored[0].copy()
        return self._acc.mean()

    @property
    def variance(self) -> np.ndarray:
        """Sample variance (ddof 1) of the values in each bin, (sr⁻¹)²; NaN where count < 2."""
        if self._stored is not None:
            return self._stored[1].copy()
        return self._acc.variance()

    # ------------------------------------------------------------------ HDF5
    def save_h5(
        self, path: str | os.PathLike[str], provenance: Mapping[str, Any] | None = None, *,
        inputs: Iterable[str | os.PathLike[str]] = (),
    ) -> None:
        """Write the table through :func:`drivers.storage.atomic_output` (temporary file in the
        same folder, re-opened with h5py, fsync, rename).

        ``provenance`` (default: :attr:`provenance`) is stored as a JSON string attribute. An
        existing table may be replaced; any other existing file, and ``inputs``, are refused
        (:class:`OutputRefused`). Raises :class:`StorageError` when the file cannot be written.
        """
        path = Path(path)
        prov = json.dumps(dict(self.provenance if provenance is None else provenance))
        with atomic_output(path, what=WHAT, verify=_verify_table(self.shape), ours=is_table_file,
                           inputs=inputs) as tmp, h5py.File(tmp, "w") as f:
            f.create_dataset("theta_i_edges", data=self.theta_i_edges)
            f.create_dataset("theta_r_edges", data=self.theta_r_edges)
            f.create_dataset("delta_phi_edges", data=self.delta_phi_edges)
            f.create_dataset("mean", data=self.mean.astype(np.float64))
            f.create_dataset("variance", data=self.variance.astype(np.float64))
            f.create_dataset("count", data=self.count.astype(np.int64))
            f.attrs["units"] = "1/sr"
            f.attrs["quantity"] = "brdf"
            f.attrs["channels"] = "R,G,B"
            f.attrs["format"] = FORMAT
            f.attrs["version"] = np.int64(VERSION)
            f.attrs["provenance"] = prov

    @classmethod
    def load_h5(cls, path: str | os.PathLike[str]) -> IsotropicTable:
        """Read a ``gonio-isotropic-brdf`` v1 file; raises :class:`ConfigError` if it is not one.

        The loaded table can take more samples and be merged: its running sums are rebuilt
        from count, mean and variance. Until then :attr:`mean` and :attr:`variance` return the
        stored arrays unchanged.
        """
        path = Path(path)
        try:
            f = h5py.File(path, "r")
        except FileNotFoundError:
            raise ConfigError(f"table {path} does not exist: check the path") from None
        except OSError as exc:
            raise ConfigError(
                f"table {path} is not a readable HDF5 file ({exc}); pass a .h5 table"
            ) from None
        with f:
            fmt = _attr_str(f.attrs.get("format"))
            if fmt != FORMAT:
                raise ConfigError(
                    f"table {path}: format is {fmt!r}, expected {FORMAT!r}; "
                    "pass a table written by 'gonio reduce'"
                )
            version = f.attrs.get("version")
            if version is None or np.ndim(version) != 0 or version != VERSION:
                shown = version.item() if isinstance(version, np.generic) else version
                raise ConfigError(
                    f"table {path}: version {shown!r} unsupported (this gonio reads "
                    f"{FORMAT} version {VERSION}); upgrade gonio"
                )
            missing = [name for name in _DATASETS if name not in f]
            if missing:
                raise ConfigError(f"table {path}: missing dataset(s) {', '.join(missing)}")
            data = {name: f[name][()] for name in _DATASETS}
            prov_text = _attr_str(f.attrs.get("provenance")) or "{}"
        try:
            provenance = json.loads(prov_text)
        except json.JSONDecodeError:
            raise ConfigError(f"table {path}: provenance attribute is not valid JSON") from None
        table = cls(
            data["theta_i_edges"],
            data["theta_r_edges"],
            data["delta_phi_edges"],
            provenance=provenance if isinstance(provenance, dict) else {"value": provenance},
        )
        shp = table.shape
        for name, want in (("mean", shp + (3,)), ("variance", shp + (3,)), ("count", shp)):
            if data[name].shape != want:
                raise ConfigError(
                    f"table {path}: dataset {name} has shape {data[name].shape}, expected {want}"
                )
        mean = np.asarray(data["mean"], dtype=np.float64)
        variance = np.asarray(data["variance"], dtype=np.float64)
        table._acc = BinAccumulator.from_statistics(
            data["count"], mean, variance, backend=table.backend
        )
        table._stored = (mean, variance)
        return table

    # ------------------------------------------------------------------ helpers
    def _empty_like(self) -> IsotropicTable:
        return IsotropicTable(
            self.theta_i_edges,
            self.theta_r_edges,
            self.delta_phi_edges,
            fold_delta_phi=self.fold_delta_phi,
            provenance=self.provenance,
            backend=self.backend,
        )

    def _check_same_edges(self, other: IsotropicTable) -> None:
        for name in ("theta_i_edges", "theta_r_edges", "delta_phi_edges"):
            if not np.array_equal(getattr(self, name), getattr(other, name)):
                raise ConfigError(
                    f"cannot merge tables: {name} differ; bin both with the same edges"
                )


def _attr_str(value: Any) -> str | None:
    if value is None:
        return None
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    return str(value)
