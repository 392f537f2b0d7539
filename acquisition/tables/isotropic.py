"""Isotropic BRDF table over (θi, θr, Δφ) bins and its HDF5 file (``gonio-isotropic-brdf`` v2;
version-1 files still read).

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
std_error          float64 [Ni,Nr,Nφ,3]  standard uncertainty of the bin mean, sr⁻¹ (v2):
                   the root sum of squares of the terms in ``uncertainty/``; NaN empty
mean_theta_i_deg   float64 [Ni,Nr,Nφ]  mean θi of the bin's samples (read-back), degrees (v2)
mean_theta_r_deg   float64 [Ni,Nr,Nφ]  mean θr, degrees (v2)
mean_delta_phi_deg float64 [Ni,Nr,Nφ]  mean Δφ as binned (folded or wrapped), degrees (v2)
angle_covariance_deg2  float64 [Ni,Nr,Nφ,6]  covariance of the samples' (θi, θr, Δφ):
                   θiθi, θrθr, ΔφΔφ, θiθr, θiΔφ, θrΔφ, deg² (v2; zero for one sample)
uncertainty/NAME   float64 [Ni,Nr,Nφ,3]  one term of the budget, sr⁻¹ (v2), with attributes
                   ``correlated`` (common to the bins, e.g. the white reference) and
                   ``description``
merl/count         int64 [90,90,180]  optional (image-based sessions): the MERL
merl/mean          float64 [90,90,180,3]  half/difference table reduced beside the isotropic
merl/variance      float64 [90,90,180,3]  one (gzip-compressed), sr⁻¹; NaN where empty
@units             "1/sr"
@quantity          "brdf"
@channels          "R,G,B"
@format            "gonio-isotropic-brdf"
@version           2
@provenance        JSON string given by the writer
@scatter_ratio     observed / predicted scatter of repeated samples (NaN: no repeats) (v2)
@scatter_bins      bins with ≥ 2 samples that ratio is taken over (v2)
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
from acquisition.tables.angles import as_flat_float64, contiguous, fold_delta_phi, wrap_delta_phi
from acquisition.tables.backend import kernels
from acquisition.tables.merl_table import MerlTable
from acquisition.tables.partial import BudgetPartial, PartialError, TablePartial
from acquisition.tables.uncertainty import (
    BINNING_DESCRIPTION,
    BINNING_TERM,
    Term,
    UncertaintySums,
    binning_variance_sums,
    scatter_ratio,
    total_std_error,
)
from drivers.errors import ConfigError
from drivers.storage import atomic_output

FORMAT = "gonio-isotropic-brdf"
VERSION = 2
READS = (1, 2)
"""Format versions :meth:`IsotropicTable.load_h5` reads."""
_DATASETS = ("theta_i_edges", "theta_r_edges", "delta_phi_edges", "mean", "variance", "count")
_MEAN_ANGLES = ("mean_theta_i_deg", "mean_theta_r_deg", "mean_delta_phi_deg")
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
        self._unc: UncertaintySums | None = None
        self._stored_scatter: tuple[float, int] | None = None

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
        −2 for a NaN angle. What :meth:`add` bins, with this table's backend (both give the
        same indices)."""
        ti, tr, dp = as_flat_float64(theta_i_deg, theta_r_deg, delta_phi_deg)
        out = np.empty(ti.size, np.int64)
        self._index_into(ti, tr, dp, out)
        return out

    def _index_into(self, ti: np.ndarray, tr: np.ndarray, dp: np.ndarray, out: np.ndarray) -> None:
        """:meth:`flat_index` of flat float64 angles into ``out``, with this table's backend."""
        if self.backend == "numba":
            kernels().iso_flat_index(*contiguous(ti, tr, dp), self.theta_i_edges,
                                     self.theta_r_edges, self.delta_phi_edges,
                                     bool(self.fold_delta_phi), out)
        else:
            out[:] = self._numpy_index(ti, tr, dp)

    def _numpy_index(self, ti: np.ndarray, tr: np.ndarray, dp: np.ndarray) -> np.ndarray:
        """The numpy path of :meth:`flat_index`."""
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
        *,
        at: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
        variances: Mapping[str, np.ndarray] | None = None,
        uncertainties: Mapping[str, np.ndarray] | None = None,
    ) -> int:
        """Bin samples: angles in degrees (broadcast to N), ``rgb`` (N, 3) BRDF in sr⁻¹.

        Samples outside the edges or with any NaN are dropped and counted
        (:attr:`n_dropped_range`, :attr:`n_dropped_nan`). Returns the number kept.

        A table that tracks uncertainty (:meth:`track_uncertainty`) also takes each sample's
        independent ``variances`` and correlated ``uncertainties`` by term name ((N, 3) each),
        and ``at``: the (θi, θr, Δφ) in degrees where each sample really lies (default: the
        binning angles), averaged per bin into :attr:`mean_angles`.
        """
        rgb = np.asarray(rgb, dtype=np.float64).reshape(-1, 3)
        ti, tr, dp = as_flat_float64(theta_i_deg, theta_r_deg, delta_phi_deg)
        n = rgb.shape[0]
        if ti.size == 1 and n != 1:
            ti, tr, dp = (np.broadcast_to(a, (n,)) for a in (ti, tr, dp))
        elif ti.size != n:
            raise ValueError(f"{ti.size} angle samples but {n} RGB samples")
        self._stored = None
        self._stored_scatter = None
        if self._unc is not None:
            self._acc.check_values(rgb)  # nothing changes unless everything fits
            idx = self._add_uncertainty(ti, tr, dp, rgb, at, variances, uncertainties)
            return self._acc.add_flat(idx, rgb, checked=True)  # the same bins, indexed once
        return self._acc.add_indexed(
            rgb, lambda a, b, flat: self._index_into(ti[a:b], tr[a:b], dp[a:b], flat))

    def track_uncertainty(self, independent: Mapping[str, str],
                          correlated: Mapping[str, str]) -> None:
        """Keep each bin's uncertainty budget from now on: term name → description, for the
        independent (per-sample variance) and correlated (common standard uncertainty) terms
        (:mod:`acquisition.tables.uncertainty`). Call before the first :meth:`add`."""
        if self.n_samples:
            raise ConfigError("track_uncertainty must be called before samples are added")
        self._unc = UncertaintySums(int(np.prod(self.shape)), independent, correlated,
                                    backend=self.backend)

    def _add_uncertainty(self, ti: np.ndarray, tr: np.ndarray, dp: np.ndarray, rgb: np.ndarray,
                         at: tuple[np.ndarray, np.ndarray, np.ndarray] | None,
                         variances: Mapping[str, np.ndarray] | None,
                         uncertainties: Mapping[str, np.ndarray] | None) -> np.ndarray:
        """Add the samples' budget (their values are checked); returns their flat bins, NaN
        values marked :data:`DROP_NAN` (as the accumulator counts them)."""
        assert self._unc is not None
        if variances is None or uncertainties is None:
            raise ConfigError("this table tracks uncertainty: add() needs variances= and "
                              "uncertainties= for every term")
        idx = self.flat_index(ti, tr, dp)
        with np.errstate(invalid="ignore"):  # checked values: only NaN or ±inf make a NaN sum
            idx[~np.isfinite(rgb.sum(axis=1))] = DROP_NAN  # as the accumulator drops them
        ai, ar, ap = (ti, tr, dp) if at is None else as_flat_float64(*at)
        angles = np.stack(np.broadcast_arrays(ai, ar, self.normalise_delta_phi(ap)), axis=-1)
        self._unc.add(idx, angles.reshape(-1, 3), variances, uncertainties)
        return idx

    def merge(self, other: IsotropicTable) -> IsotropicTable:
        """New table holding the samples of both (edges must be equal); the uncertainty budget
        is kept when both tables track the same terms."""
        self._check_same_edges(other)
        new = self._empty_like()
        new._acc.merge_from(self._acc)
        new._acc.merge_from(other._acc)
        if self._unc is not None and other._unc is not None:
            new._unc = self._unc.copy()
            new._unc.merge_from(other._unc)
        return new

    def __add__(self, other: IsotropicTable) -> IsotropicTable:
        return self.merge(other)

    # ------------------------------------------------------------------ partials
    @property
    def grid(self) -> dict[str, Any]:
        """The bins: edges (degrees) and whether Δφ is folded."""
        return {"theta_i_edges": self.theta_i_edges, "theta_r_edges": self.theta_r_edges,
                "delta_phi_edges": self.delta_phi_edges,
                "fold_delta_phi": bool(self.fold_delta_phi)}

    def _budget_terms(self) -> tuple[tuple[tuple[str, str], ...], tuple[tuple[str, str], ...]]:
        """(independent, correlated) (name, description) pairs summed per sample."""
        u = self._unc
        if u is None:
            return (), ()
        return (tuple((k, u.descriptions[k]) for k in u.independent if k not in u._final),
                tuple((k, u.descriptions[k]) for k in u.correlated))

    def partial(self) -> TablePartial:
        """This table's exact sums (and its budget's, terms set at the end excepted): merged
        with other partials of the same grid, then :meth:`merge_partial` into a table, they
        give the table of all their samples, bit for bit."""
        budget = None
        if self._unc is not None:
            budget = BudgetPartial(*self._budget_terms(), self._unc.partial())
        return TablePartial("isotropic", self._acc.partial(),
                            (self.n_dropped_nan, self.n_dropped_range), self.grid, budget)

    def merge_partial(self, part: TablePartial) -> None:
        """Add a partial table's sums (same grid; its budget's terms those this table tracks,
        or it tracks none and has no sample yet)."""
        same_grid = all(np.array_equal(np.asarray(v), np.asarray(part.grid.get(k)))
                        for k, v in self.grid.items())
        if part.kind != "isotropic" or not same_grid:
            raise PartialError(f"cannot merge a {part.kind} partial table of another grid into "
                               "this isotropic table: bin both with the same edges")
        budget = part.budget
        if budget is not None and self._unc is None and not self.n_samples:
            self.track_uncertainty(dict(budget.independent), dict(budget.correlated))
        theirs = () if budget is None else (budget.independent, budget.correlated)
        ours = () if self._unc is None else self._budget_terms()
        if theirs != ours:
            raise PartialError("cannot merge a partial table whose uncertainty terms differ "
                               "from this table's")
        self._stored = None
        self._stored_scatter = None
        self._acc.merge_partial(part.values, part.dropped)
        if budget is not None and self._unc is not None:
            self._unc.merge_partial(budget.sums)

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

    def add_binning_term(self) -> None:
        """Add the budget's ``binning`` term (:func:`~acquisition.tables.uncertainty.
        binning_variance_sums`): for bins filled by many samples spread over the bin (an image's
        pixels), the bin mean depends on where they fell as much as on their noise."""
        if self._unc is None:
            raise ConfigError("add_binning_term needs a table that tracks uncertainty")
        self._unc.set_independent(BINNING_TERM, BINNING_DESCRIPTION, binning_variance_sums(
            self._unc, self._acc.variance(), self._acc.count))

    def set_bin_term(self, name: str, description: str, bin_uncertainty: np.ndarray, *,
                     correlated: bool = False) -> None:
        """Add (or replace) a term of the budget known per bin once every sample is in: the
        standard uncertainty of each bin's mean, ``shape + (3,)``, sr⁻¹
        (:meth:`~acquisition.tables.uncertainty.UncertaintySums.set_term`)."""
        if self._unc is None:
            raise ConfigError("set_bin_term needs a table that tracks uncertainty")
        self._unc.set_term(name, description, bin_uncertainty, correlated)

    def scale_bins(self, factor: np.ndarray) -> None:
        """Multiply every sample of each bin by ``factor`` (``shape + (3,)``; NaN: 1): a
        correction known per bin (the budget's terms are kept as they are)."""
        f = np.nan_to_num(np.asarray(factor, float).reshape(-1, 3), nan=1.0)
        self._acc.scale(f)
        self._stored = None
        self._stored_scatter = None

    @property
    def tracks_uncertainty(self) -> bool:
        """True when the table holds an uncertainty budget (reduced by gonio, or a v2 file)."""
        return self._unc is not None

    @property
    def uncertainty_terms(self) -> dict[str, Term]:
        """The budget: term name → :class:`Term` (bin-mean standard uncertainty, sr⁻¹); empty
        when the table does not track uncertainty."""
        return {} if self._unc is None else self._unc.terms(self.shape)

    @property
    def std_error(self) -> np.ndarray:
        """Standard uncertainty of each bin's mean, sr⁻¹, ``shape + (3,)``: the root sum of
        squares of the budget's terms; NaN where unmeasured or untracked."""
        terms = self.uncertainty_terms
        if not terms:
            return np.full(self.shape + (3,), np.nan)
        return total_std_error(terms)

    @property
    def mean_angles(self) -> np.ndarray:
        """Mean (θi, θr, Δφ) of each bin's samples in degrees, ``shape + (3,)``; the bin
        centres where the table does not track where its samples lie; NaN where empty."""
        if self._unc is not None:
            return self._unc.mean_angles(self.shape)
        grids = np.meshgrid(*self.centers(), indexing="ij")
        out = np.stack(grids, axis=-1)
        out[self.count == 0] = np.nan
        return out

    @property
    def angle_covariance(self) -> np.ndarray:
        """Covariance of each bin's sample angles, deg², ``shape + (6,)`` (θiθi, θrθr, ΔφΔφ,
        θiθr, θiΔφ, θrΔφ); zero where untracked, NaN where empty."""
        if self._unc is not None:
            return self._unc.angle_covariance(self.shape)
        out = np.zeros(self.shape + (6,))
        out[self.count == 0] = np.nan
        return out

    @property
    def scatter(self) -> tuple[float, int]:
        """(observed / predicted scatter of repeated samples, bins with repeats); (NaN, 0)
        without repeats or without a budget."""
        if self._stored_scatter is not None:
            return self._stored_scatter
        if self._unc is None:
            return float("nan"), 0
        return scatter_ratio(self._unc, self.variance, self.count)

    # ------------------------------------------------------------------ HDF5
    def save_h5(
        self, path: str | os.PathLike[str], provenance: Mapping[str, Any] | None = None, *,
        inputs: Iterable[str | os.PathLike[str]] = (), merl: MerlTable | None = None,
    ) -> None:
        """Write the table through :func:`drivers.storage.atomic_output` (temporary file in the
        same folder, re-opened with h5py, fsync, rename).

        ``provenance`` (default: :attr:`provenance`) is stored as a JSON string attribute. An
        existing table may be replaced; any other existing file, and ``inputs``, are refused
        (:class:`OutputRefused`). Raises :class:`StorageError` when the file cannot be written.
        ``merl``: a MERL half/difference table reduced from the same samples, kept in the file
        (``merl/``; :func:`load_merl_h5` reads it back).
        """
        path = Path(path)
        prov = json.dumps(dict(self.provenance if provenance is None else provenance))
        with atomic_output(path, what=WHAT, verify=_verify_table(self.shape), ours=is_table_file,
                           inputs=inputs) as tmp, h5py.File(tmp, "w") as f:
            if merl is not None:
                group = f.create_group("merl")
                for name, data in (("count", merl.count), ("mean", merl.mean),
                                   ("variance", merl.variance)):
                    group.create_dataset(name, data=data, compression="gzip",
                                         compression_opts=4, shuffle=True)
            f.create_dataset("theta_i_edges", data=self.theta_i_edges)
            f.create_dataset("theta_r_edges", data=self.theta_r_edges)
            f.create_dataset("delta_phi_edges", data=self.delta_phi_edges)
            f.create_dataset("mean", data=self.mean.astype(np.float64))
            f.create_dataset("variance", data=self.variance.astype(np.float64))
            f.create_dataset("count", data=self.count.astype(np.int64))
            self._write_uncertainty(f)
            f.attrs["units"] = "1/sr"
            f.attrs["quantity"] = "brdf"
            f.attrs["channels"] = "R,G,B"
            f.attrs["format"] = FORMAT
            f.attrs["version"] = np.int64(VERSION)
            f.attrs["provenance"] = prov

    def _write_uncertainty(self, f: h5py.File) -> None:
        """The v2 datasets: std_error, mean angles, the budget's terms, the scatter ratio."""
        f.create_dataset("std_error", data=self.std_error)
        angles = self.mean_angles
        for k, name in enumerate(_MEAN_ANGLES):
            f.create_dataset(name, data=angles[..., k])
        f.create_dataset("angle_covariance_deg2", data=self.angle_covariance)
        group = f.create_group("uncertainty")
        for name, term in self.uncertainty_terms.items():
            d = group.create_dataset(name, data=term.values)
            d.attrs["correlated"] = bool(term.correlated)
            d.attrs["description"] = term.description
        ratio, bins = self.scatter
        f.attrs["scatter_ratio"] = float(ratio)
        f.attrs["scatter_bins"] = np.int64(bins)

    @classmethod
    def load_h5(cls, path: str | os.PathLike[str]) -> IsotropicTable:
        """Read a ``gonio-isotropic-brdf`` v1 or v2 file; raises :class:`ConfigError` if it is
        not one. A v2 file's uncertainty budget and mean angles come back with it.

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
            if version is None or np.ndim(version) != 0 or version not in READS:
                shown = version.item() if isinstance(version, np.generic) else version
                raise ConfigError(
                    f"table {path}: version {shown!r} unsupported (this gonio reads "
                    f"{FORMAT} versions {', '.join(map(str, READS))}); upgrade gonio"
                )
            missing = [name for name in _DATASETS if name not in f]
            if missing:
                raise ConfigError(f"table {path}: missing dataset(s) {', '.join(missing)}")
            data = {name: f[name][()] for name in _DATASETS}
            prov_text = _attr_str(f.attrs.get("provenance")) or "{}"
            budget = _read_uncertainty(f, path) if int(version) >= 2 else None
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
        if budget is not None:
            terms, angles, cov, scatter = budget
            if terms:
                table._unc = UncertaintySums.from_terms(data["count"], terms, angles, cov)
            table._stored_scatter = scatter
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


def load_merl_h5(path: str | os.PathLike[str]) -> MerlTable | None:
    """The MERL table a ``gonio-isotropic-brdf`` file holds beside its isotropic one (image-based
    sessions), or None."""
    with h5py.File(path, "r") as f:
        if "merl" not in f:
            return None
        g = f["merl"]
        prov = _attr_str(f.attrs.get("provenance")) or "{}"
        return MerlTable.from_statistics(g["count"][()], g["mean"][()], g["variance"][()],
                                         json.loads(prov))


def _read_uncertainty(f: h5py.File, path: Path
                      ) -> tuple[dict[str, Term], np.ndarray, np.ndarray | None, tuple[float, int]]:
    """A v2 file's budget terms, mean angles (…, 3), angle covariance (…, 6) and (scatter
    ratio, bins)."""
    missing = [n for n in ("std_error", *_MEAN_ANGLES, "uncertainty") if n not in f]
    if missing:
        raise ConfigError(f"table {path}: version 2 but missing {', '.join(missing)}")
    terms = {name: Term(np.asarray(d[()], np.float64), bool(d.attrs.get("correlated", False)),
                        _attr_str(d.attrs.get("description")) or "")
             for name, d in f["uncertainty"].items()}
    angles = np.stack([np.asarray(f[n][()], np.float64) for n in _MEAN_ANGLES], axis=-1)
    scatter = (float(f.attrs.get("scatter_ratio", np.nan)), int(f.attrs.get("scatter_bins", 0)))
    cov = np.asarray(f["angle_covariance_deg2"][()], np.float64) if "angle_covariance_deg2" in f else None
    return terms, angles, cov, scatter


def _attr_str(value: Any) -> str | None:
    if value is None:
        return None
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    return str(value)
