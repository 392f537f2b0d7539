"""MERL half/difference table: streaming 90 × 90 × 180 × RGB statistics over (θh, θd, φd)."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from acquisition.geometry.halfdiff import (
    DEG2RAD,
    MERL_SHAPE,
    NAN_INDEX,
    OUT_OF_RANGE_INDEX,
    PHI_D_BINS,
    flat_index_unclamped_into,
    halfdiff_rad_from_vectors,
    halfdiff_rad_reference,
    merl_bin_edges,
)
from acquisition.tables.accumulator import (
    CHUNK,
    DROP_NAN,
    DROP_OUT_OF_RANGE,
    BinAccumulator,
    TableStatistics,
)
from acquisition.tables.angles import as_flat_float64, contiguous
from acquisition.tables.backend import kernels
from acquisition.tables.partial import PartialError, TablePartial
from drivers.errors import ConfigError

# The index codes of acquisition.geometry.halfdiff are the accumulator's drop codes.
assert (NAN_INDEX, OUT_OF_RANGE_INDEX) == (DROP_NAN, DROP_OUT_OF_RANGE)


class MerlTable(TableStatistics):
    """Streaming BRDF table on the MERL grid (θh square-root spaced, θd, φd folded by 180°).

    Bins are those of the MERL reference reader (see :mod:`acquisition.geometry.halfdiff`): a sample
    lands in the bin the reference lookup (libm arithmetic in IEEE double) reads for its
    angles, exact bin edges included, on any CPU. Samples with a direction at or below the
    horizon, or θh/θd outside [0°, 90°], are dropped as out of range; samples with NaN as NaN.
    ``flat_index_*`` give the bin of each sample without binning it.

    Parameters
    ----------
    provenance
        Free metadata kept with the table (exported by the callers that write files).
    backend
        ``"numba"`` (fused compiled index + accumulation) or ``"numpy"``; default from
        ``$GONIO_BINNING_BACKEND``, else numba. Both give bit-identical tables whatever the
        batch split (same bins, counts, sums, sums of squares and drop tallies).
    """

    shape = MERL_SHAPE

    def __init__(
        self, provenance: Mapping[str, Any] | None = None, *, backend: str | None = None
    ) -> None:
        self.provenance: dict[str, Any] = dict(provenance or {})
        self._acc = BinAccumulator(MERL_SHAPE, 3, backend=backend)

    # ------------------------------------------------------------------ accumulation
    def add_vectors(self, wi: np.ndarray, wo: np.ndarray, rgb: np.ndarray) -> int:
        """Bin samples given unit light ``wi`` and view ``wo`` vectors (N, 3), normal +z.

        ``rgb`` (N, 3) is the BRDF in sr⁻¹. Returns the number of samples kept.
        """
        wi, wo = _as_vectors(wi, wo)
        rgb = _as_rgb(rgb, wi.shape[0])
        if self.backend == "numba":
            index, (wi, wo) = kernels().merl_flat_index_vectors, contiguous(wi, wo)
            return self._acc.add_indexed(rgb, lambda a, b, flat: index(wi[a:b], wo[a:b], flat))
        return self._acc.add_indexed(rgb, lambda a, b, flat: _index_vectors(wi[a:b], wo[a:b], flat))

    def add_angles(
        self,
        theta_i_deg: np.ndarray | float,
        theta_r_deg: np.ndarray | float,
        delta_phi_deg: np.ndarray | float,
        rgb: np.ndarray,
    ) -> int:
        """Bin samples at isotropic (θi, θr, Δφ) in degrees (light at azimuth 0).

        Uses the reference reader's own angle conversion with libm's arithmetic, so each
        sample lands exactly where the reference lookup at the same angles reads (exact bin
        edges and in-plane poses included). θi or θr outside [0°, 90°] is dropped. Returns the
        number kept.
        """
        ti, tr, dp = as_flat_float64(theta_i_deg, theta_r_deg, delta_phi_deg)
        rgb = _as_rgb(rgb, ti.size)
        fill = kernels().merl_flat_index_angles if self.backend == "numba" else _index_angles
        ti, tr, dp = contiguous(ti, tr, dp)
        return self._acc.add_indexed(rgb, lambda a, b, flat: fill(ti[a:b], tr[a:b], dp[a:b], flat))

    def add_halfdiff(
        self,
        theta_h_deg: np.ndarray | float,
        theta_d_deg: np.ndarray | float,
        phi_d_deg: np.ndarray | float,
        rgb: np.ndarray,
    ) -> int:
        """Bin samples given directly as (θh, θd, φd) in degrees. Returns the number kept.

        The fastest entry point. Angles are converted like ``np.radians`` and binned with the
        reference reader's arithmetic, so a sample lands where the reference lookup at those
        angles reads (even on a bin edge). θh or θd outside [0°, 90°] is dropped; φd outside
        (−180°, 180°] is folded by whole half turns.
        """
        th, td, pd = as_flat_float64(theta_h_deg, theta_d_deg, phi_d_deg)
        rgb = _as_rgb(rgb, th.size)
        fill = kernels().merl_flat_index_deg if self.backend == "numba" else _index_halfdiff
        th, td, pd = contiguous(th, td, pd)
        return self._acc.add_indexed(rgb, lambda a, b, flat: fill(th[a:b], td[a:b], pd[a:b], flat))

    # ------------------------------------------------------------------ bin of each sample
    def flat_index_vectors(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """Flat bin index per light/view pair, as :meth:`add_vectors` bins it with this
        table's backend: −1 out of range (or below the horizon), −2 NaN."""
        wi, wo = _as_vectors(wi, wo)
        if self.backend == "numba":
            out = np.empty(wi.shape[0], dtype=np.int64)
            kernels().merl_flat_index_vectors(*contiguous(wi, wo), out)
            return out
        return _index_chunked(wi.shape[0], lambda a, b, f: _index_vectors(wi[a:b], wo[a:b], f))

    def flat_index_angles(
        self,
        theta_i_deg: np.ndarray | float,
        theta_r_deg: np.ndarray | float,
        delta_phi_deg: np.ndarray | float,
    ) -> np.ndarray:
        """Flat bin index per (θi, θr, Δφ) in degrees, as :meth:`add_angles` bins it."""
        ti, tr, dp = as_flat_float64(theta_i_deg, theta_r_deg, delta_phi_deg)
        if self.backend == "numba":
            out = np.empty(ti.size, dtype=np.int64)
            kernels().merl_flat_index_angles(*contiguous(ti, tr, dp), out)
            return out
        return _index_chunked(ti.size, lambda a, b, f: _index_angles(ti[a:b], tr[a:b], dp[a:b], f))

    def flat_index_halfdiff(
        self,
        theta_h_deg: np.ndarray | float,
        theta_d_deg: np.ndarray | float,
        phi_d_deg: np.ndarray | float,
    ) -> np.ndarray:
        """Flat bin index per (θh, θd, φd) in degrees, as :meth:`add_halfdiff` bins it."""
        th, td, pd = as_flat_float64(theta_h_deg, theta_d_deg, phi_d_deg)
        if self.backend == "numba":
            out = np.empty(th.size, dtype=np.int64)
            kernels().merl_flat_index_deg(*contiguous(th, td, pd), out)
            return out
        return _index_chunked(th.size, lambda a, b, f: _index_halfdiff(th[a:b], td[a:b], pd[a:b], f))

    def add_flat(self, flat_index: np.ndarray, rgb: np.ndarray) -> int:
        """Bin samples by precomputed flat MERL index (negative = drop). Returns the number kept."""
        return self._acc.add_flat(flat_index, rgb)

    def merge(self, other: MerlTable) -> MerlTable:
        """New table holding the samples of both."""
        if not isinstance(other, MerlTable):
            raise ConfigError("a MERL table merges only with another MERL table")
        new = MerlTable(self.provenance, backend=self.backend)
        new._acc.merge_from(self._acc)
        new._acc.merge_from(other._acc)
        return new

    def __add__(self, other: MerlTable) -> MerlTable:
        return self.merge(other)

    def partial(self) -> TablePartial:
        """This table's exact sums (a partial table: see :mod:`acquisition.tables.partial`)."""
        return TablePartial("merl", self._acc.partial(), (self.n_dropped_nan, self.n_dropped_range))

    def merge_partial(self, part: TablePartial) -> None:
        """Add a partial MERL table's sums."""
        if part.kind != "merl":
            raise PartialError(f"cannot merge a {part.kind} partial table into a MERL table")
        self._acc.merge_partial(part.values, part.dropped)

    def fold_mirror_symmetry(self) -> MerlTable:
        """New table pooling φd bins k and 179 − k (bilateral symmetry of isotropic BRDFs).

        Reciprocity itself is already folded by the grid (φd and φd + 180° share a bin);
        mirroring the pair about the plane of the normal and h maps φd to −φd ≡ 180° − φd.
        """
        new = MerlTable(self.provenance, backend=self.backend)
        mirror = np.arange(PHI_D_BINS)[::-1]
        new._acc.pool_from(self._acc, lambda x: x + x[..., mirror])
        return new

    # ------------------------------------------------------------------ statistics
    # count, mean, variance, variance_of_mean, n_samples, n_dropped_*: see TableStatistics.
    @property
    def measured(self) -> np.ndarray:
        """Bins holding at least one sample, bool [90, 90, 180]."""
        return self._acc.count > 0

    @staticmethod
    def edges() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Bin edges (θh, θd, φd) in degrees."""
        return merl_bin_edges()

    @classmethod
    def from_statistics(cls, count: np.ndarray, mean: np.ndarray, variance: np.ndarray,
                        provenance: Mapping[str, Any] | None = None) -> MerlTable:
        """A table rebuilt from stored count, mean and variance (as a file holds them)."""
        table = cls(provenance)
        if np.shape(count) != MERL_SHAPE or np.shape(mean) != MERL_SHAPE + (3,):
            raise ConfigError(f"MERL statistics must be shaped {MERL_SHAPE} (+ RGB), got "
                              f"{np.shape(count)} and {np.shape(mean)}")
        table._acc = BinAccumulator.from_statistics(count, mean, variance, backend=table.backend)
        return table


# ---------------------------------------------------------------------------- numpy backend
def _index_vectors(wi: np.ndarray, wo: np.ndarray, flat: np.ndarray) -> bool:
    """Flat indices of light/view pairs into ``flat``; True when all are known valid."""
    th, td, pd = halfdiff_rad_from_vectors(wi, wo)
    valid = flat_index_unclamped_into(th, td, pd, flat)
    if not (wi[:, 2].min() > 0.0 and wo[:, 2].min() > 0.0):  # False on NaN too
        valid = False
        below = (wi[:, 2] <= 0.0) | (wo[:, 2] <= 0.0)
        given_nan = np.isnan(wi).any(axis=1) | np.isnan(wo).any(axis=1)
        # wi = −wo has no half vector (NaN angles): still below the horizon.
        flat[below & ~given_nan] = DROP_OUT_OF_RANGE
    return valid


def _index_angles(ti: np.ndarray, tr: np.ndarray, dp: np.ndarray, flat: np.ndarray) -> bool:
    """Flat indices of (θi, θr, Δφ) in degrees into ``flat``; returns False (not checked)."""
    th, td, pd = halfdiff_rad_reference(ti * DEG2RAD, 0.0, tr * DEG2RAD, dp * DEG2RAD)
    flat_index_unclamped_into(th, td, pd, flat)
    with np.errstate(invalid="ignore"):
        outside = (ti < 0.0) | (ti > 90.0) | (tr < 0.0) | (tr > 90.0)
    flat[outside & (flat != DROP_NAN)] = DROP_OUT_OF_RANGE
    return False


def _index_halfdiff(th: np.ndarray, td: np.ndarray, pd: np.ndarray, flat: np.ndarray) -> bool:
    """Flat indices of (θh, θd, φd) in degrees into ``flat``; True when all are valid."""
    return flat_index_unclamped_into(th, td, pd, flat, 180.0)


def _index_chunked(n: int, fill: Callable[[int, int, np.ndarray], bool]) -> np.ndarray:
    out = np.empty(n, dtype=np.int64)
    for a in range(0, n, CHUNK):
        b = min(a + CHUNK, n)
        fill(a, b, out[a:b])
    return out


def _as_vectors(wi: np.ndarray, wo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return (
        np.asarray(wi, dtype=np.float64).reshape(-1, 3),
        np.asarray(wo, dtype=np.float64).reshape(-1, 3),
    )


def _as_rgb(rgb: np.ndarray, n: int) -> np.ndarray:
    arr = np.asarray(rgb, dtype=np.float64)
    if arr.size != 3 * n:
        raise ValueError(f"expected {n} RGB samples (shape ({n}, 3)), got shape {arr.shape}")
    return arr.reshape(n, 3)
