"""Streaming per-bin statistics: count, Σx and Σx² per channel, summed exactly.

A session never holds all its samples: each batch is added into the running sums and then
dropped. The sums are exact (fixed-point integers, :mod:`acquisition.tables.fixedpoint`) and
stored for the bins that hold samples (:class:`~acquisition.tables.exact.ExactSums`): each x
and each x² (rounded once, as a float64) is converted exactly, sums are integer additions, and
each is rounded to float64 once when read. So a table is bit-identical whatever the backend,
however the samples were split into batches, in whatever order and grouping they were added
or merged (:meth:`BinAccumulator.partial`, :meth:`BinAccumulator.merge_partial`).

Sample values must have |x| < 2^20 ≈ 1.05e6 (sr⁻¹ in a BRDF table), so that x² < 2^40; a
larger finite value raises :class:`~acquisition.tables.fixedpoint.OutOfRangeError` before the
sums change.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from acquisition.tables.backend import resolve_backend
from acquisition.tables.exact import ExactSums, SparseSums, largest_finite
from acquisition.tables.fixedpoint import check_range, limbs_first
from drivers.errors import ConfigError

DROP_OUT_OF_RANGE = -1
"""Flat index marking a sample outside the table (dropped, counted in ``n_dropped_range``)."""
DROP_NAN = -2
"""Flat index marking a sample with a NaN coordinate (dropped, counted in ``n_dropped_nan``)."""
SAMPLE_LIMIT = 2.0**20
"""Largest |value| (exclusive) of a sample: its square stays below the fixed-point range."""
CHUNK = 1 << 16
"""Samples indexed per step by :meth:`BinAccumulator.add_indexed` (buffers stay cache-sized)."""


class BinAccumulator:
    """Count, Σx and Σx² per bin and channel over a table of ``shape`` bins.

    Parameters
    ----------
    shape
        Bin grid shape, e.g. ``(90, 90, 180)``.
    channels
        Values per sample (3 for RGB).
    backend
        ``"numba"`` (compiled kernel) or ``"numpy"``; default from ``$GONIO_BINNING_BACKEND``,
        else numba (see :mod:`acquisition.tables.backend`).

    Notes
    -----
    Samples are added by flat (C-order) bin index. A negative index drops the sample:
    :data:`DROP_NAN` counts it as NaN, any other negative index as out of range. Samples whose
    value is not finite (NaN or ±inf in any channel) are dropped as NaN.
    """

    def __init__(
        self, shape: tuple[int, ...], channels: int = 3, *, backend: str | None = None
    ) -> None:
        self.backend = resolve_backend(backend)
        self.shape = tuple(int(s) for s in shape)
        self.channels = int(channels)
        self.n_bins = math.prod(self.shape)
        self._sums = ExactSums(self.n_bins, 2 * self.channels, backend=self.backend,
                               capacity=min(self.n_bins, 1 << 16))
        self.n_dropped_nan = 0
        self.n_dropped_range = 0
        self._factor: np.ndarray | None = None
        """Per-bin factor (n_bins, channels) applied when the sums are read (:meth:`scale`)."""

    # ------------------------------------------------------------------ accumulation
    def add_flat(
        self, flat_index: np.ndarray, values: np.ndarray, *, index_valid: bool = False,
        checked: bool = False,
    ) -> int:
        """Add samples by flat bin index; returns how many were kept.

        Parameters
        ----------
        flat_index
            (N,) integer bin indices in C order; negative entries drop the sample.
        values
            (N, channels) sample values.
        index_valid
            The caller guarantees every index lies in [0, n_bins) (skips that check).
        checked
            The caller has checked the values' range (:meth:`check_values`).
        """
        idx = np.asarray(flat_index).reshape(-1)
        vals = np.asarray(values, dtype=np.float64).reshape(idx.size, self.channels)
        if idx.size == 0:
            return 0
        if not checked:
            self.check_values(vals)
        if self.backend == "numba":
            return self._add_compiled(np.ascontiguousarray(idx, np.int64), vals)
        if idx.dtype != np.intp:
            idx = idx.astype(np.intp)
        with np.errstate(over="ignore", invalid="ignore"):
            all_finite = bool(np.isfinite(vals.sum()))
        if all_finite and (index_valid or (idx.min() >= 0 and idx.max() < self.n_bins)):
            self._accumulate(idx, vals)
            return idx.size
        with np.errstate(invalid="ignore", over="ignore"):
            finite = np.isfinite(vals.sum(axis=1))  # NaN/inf propagate through the row sum
        in_table = (idx >= 0) & (idx < self.n_bins)
        nan = ~finite | (idx == DROP_NAN)
        keep = ~nan & in_table
        self.n_dropped_nan += int(np.count_nonzero(nan))
        self.n_dropped_range += int(np.count_nonzero(~nan & ~in_table))
        self._accumulate(idx[keep], vals[keep])
        return int(np.count_nonzero(keep))

    def add_indexed(self, values: np.ndarray,
                    fill: Callable[[int, int, np.ndarray], bool | None]) -> int:
        """Add (N, channels) ``values`` whose bins a table computes chunk by chunk:
        ``fill(a, b, flat)`` writes the flat indices of samples [a, b) into ``flat`` (and may
        say whether all are known valid). Every value is checked first, so an out-of-range one
        changes nothing; index buffers stay cache-sized (:data:`CHUNK`). Returns the number
        kept."""
        vals = np.asarray(values, dtype=np.float64).reshape(-1, self.channels)
        self.check_values(vals)
        n = vals.shape[0]
        buf = np.empty(min(CHUNK, n), dtype=np.int64)
        kept = 0
        for a in range(0, n, CHUNK):
            b = min(a + CHUNK, n)
            flat = buf[: b - a]
            valid = bool(fill(a, b, flat))
            kept += self.add_flat(flat, vals[a:b], index_valid=valid, checked=True)
        return kept

    def _add_compiled(self, idx: np.ndarray, vals: np.ndarray) -> int:
        """numba path of :meth:`add_flat` (:func:`acquisition.tables.exact_kernels.add_flat`);
        records the drops, returns the number kept."""
        from acquisition.tables import exact_kernels

        tally = np.zeros(4, np.int64)
        self._sums.run_kernel(exact_kernels.add_flat, (idx, np.ascontiguousarray(vals)),
                              idx.size, tally)
        self.n_dropped_nan += int(tally[1])
        self.n_dropped_range += int(tally[2])
        return int(tally[0])

    def check_values(self, values: np.ndarray) -> None:
        """Raise :class:`~acquisition.tables.fixedpoint.OutOfRangeError` when a finite sample
        value has |x| ≥ 2^20 (what :meth:`add_flat` and :meth:`add_with` refuse)."""
        vals = np.ascontiguousarray(values, dtype=np.float64).reshape(-1, self.channels)
        self._check_values(vals, largest_finite(vals, self.backend))

    @staticmethod
    def _check_values(vals: np.ndarray, largest: float | None = None) -> None:
        check_range(vals, SAMPLE_LIMIT, "sample value", " sr⁻¹", largest)

    def _accumulate(self, idx: np.ndarray, vals: np.ndarray) -> None:
        """numpy path: add in-range, finite samples (no checks): x then x² per channel, as
        limbs, with ``np.add.at`` (the numba kernel adds the same integers)."""
        def limbs_of(a: int, b: int) -> np.ndarray:
            v = vals[a:b]
            return limbs_first(np.concatenate([v, v * v], axis=1))

        self._sums.add_limbs(np.asarray(idx, np.intp), limbs_of)

    # ------------------------------------------------------------------ merging
    def _check_compatible(self, other: BinAccumulator) -> None:
        if self.shape != other.shape or self.channels != other.channels:
            raise ConfigError(
                f"cannot merge tables of shape {self.shape}x{self.channels} and "
                f"{other.shape}x{other.channels}: bin them with the same edges"
            )

    def partial(self) -> SparseSums:
        """The canonical exact sums (count, Σx, Σx² of the bins touched): a partial table."""
        self._refuse_if_scaled("take a partial of")
        return self._sums.sparse()

    def merge_partial(self, part: SparseSums, dropped: tuple[int, int] = (0, 0)) -> None:
        """Add a partial's sums and its (NaN, out-of-range) drop tallies."""
        self._refuse_if_scaled("merge into")
        self._sums.merge(part)
        self.n_dropped_nan += int(dropped[0])
        self.n_dropped_range += int(dropped[1])

    def merge_from(self, other: BinAccumulator) -> None:
        """Add ``other``'s statistics into this accumulator (in place)."""
        self._check_compatible(other)
        self.merge_partial(other.partial(), (other.n_dropped_nan, other.n_dropped_range))

    def copy(self) -> BinAccumulator:
        """Independent copy (same backend, same read-out factor)."""
        new = BinAccumulator(self.shape, self.channels, backend=self.backend)
        new._sums.merge(self._sums.sparse())
        new.n_dropped_nan, new.n_dropped_range = self.n_dropped_nan, self.n_dropped_range
        new._factor = None if self._factor is None else self._factor.copy()
        return new

    def pool_from(self, other: BinAccumulator, pool: Callable[[np.ndarray], np.ndarray]) -> None:
        """Replace this accumulator's statistics by ``pool`` of ``other``'s (drops copied).

        ``pool`` gets each of ``other``'s arrays shaped ``shape`` (count) or ``(k,) + shape``
        (the exact sums' limbs), so it should index bin axes from the end (``x[..., k]``) and
        only add and copy entries; it returns a new array of the same shape.
        """
        self._check_compatible(other)
        count, limbs = other._sums.dense_limbs()
        k = limbs.shape[0] * limbs.shape[1]
        pooled = pool(limbs.reshape(k, *self.shape)).reshape(limbs.shape)
        self._sums = ExactSums.from_dense(pool(count.reshape(self.shape)), limbs=pooled,
                                          backend=self.backend)
        self.n_dropped_nan = other.n_dropped_nan
        self.n_dropped_range = other.n_dropped_range

    def scale(self, factor: np.ndarray) -> None:
        """Multiply every sample of each bin by ``factor`` (n_bins, channels) — Σx by it, Σx²
        by its square — as the sums are read: a correction known once every sample is in. The
        exact sums stay as added, so a scaled accumulator takes no more partials and gives none.
        """
        f = np.asarray(factor, dtype=np.float64).reshape(self.n_bins, self.channels)
        self._factor = f.copy() if self._factor is None else self._factor * f

    def _refuse_if_scaled(self, what: str) -> None:
        if self._factor is not None:
            raise ConfigError(f"cannot {what} a table whose bins were scaled (a finished "
                              "table): merge the partials before correcting the bins")

    def _touched(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(bins, counts, sums (2·channels, u)) of the touched bins, read-out factor applied."""
        bins, n, sums = self._sums.touched()
        if self._factor is not None:
            f = self._factor[bins].T
            sums = np.concatenate([sums[: self.channels] * f, sums[self.channels:] * f * f])
        return bins, n, sums

    # ------------------------------------------------------------------ statistics
    @property
    def n_samples(self) -> int:
        """Samples added."""
        return int(self._sums.count[: self._sums.n_used].sum())

    @property
    def _count(self) -> np.ndarray:
        """Samples per flat bin, int64 (n_bins,)."""
        bins, n, _ = self._sums.touched()
        out = np.zeros(self.n_bins, np.int64)
        out[bins] = n
        return out

    def _dense_sums(self) -> np.ndarray:
        """Σx then Σx² per channel and flat bin, (2·channels, n_bins), read-out factor applied."""
        bins, _, sums = self._touched()
        out = np.zeros((2 * self.channels, self.n_bins))
        out[:, bins] = sums
        return out

    @property
    def _sum(self) -> np.ndarray:
        """Σx per channel and flat bin, (channels, n_bins), each rounded once."""
        return self._dense_sums()[: self.channels]

    @property
    def _sumsq(self) -> np.ndarray:
        """Σx² per channel and flat bin, (channels, n_bins), each rounded once."""
        return self._dense_sums()[self.channels:]

    @property
    def count(self) -> np.ndarray:
        """Samples per bin, int64, ``shape``."""
        return self._count.reshape(self.shape)

    @property
    def sum(self) -> np.ndarray:
        """Σx per bin, float64, ``shape + (channels,)``."""
        return self._spread(lambda n, s: s[: self.channels], 0.0)

    @property
    def sum_of_squares(self) -> np.ndarray:
        """Σx² per bin, float64, ``shape + (channels,)``."""
        return self._spread(lambda n, s: s[self.channels:], 0.0)

    def _spread(self, per_bin: Callable[[np.ndarray, np.ndarray], np.ndarray],
                empty: float) -> np.ndarray:
        """``per_bin(count (u,), sums (2·channels, u))`` → (channels, u) over the touched bins,
        spread over ``shape + (channels,)`` with ``empty`` elsewhere (no grid-sized sums)."""
        bins, n, sums = self._touched()
        out = np.full((self.n_bins, self.channels), empty)
        with np.errstate(invalid="ignore", divide="ignore"):
            out[bins] = per_bin(n.astype(np.float64), sums).T
        return out.reshape(*self.shape, self.channels)

    def mean(self) -> np.ndarray:
        """Mean per bin and channel, ``shape + (channels,)``; NaN where the bin is empty."""
        return self._spread(lambda n, s: s[: self.channels] / n, np.nan)

    def variance(self) -> np.ndarray:
        """Unbiased sample variance (ddof = 1) per bin; NaN where count < 2.

        Computed as (Σx² − (Σx)²/n) / (n − 1) from the rounded sums, clipped at 0 against
        rounding.
        """
        c = self.channels

        def var(n: np.ndarray, s: np.ndarray) -> np.ndarray:
            v = np.maximum((s[c:] - s[:c] * s[:c] / n) / (n - 1.0), 0.0)
            v[:, n < 2] = np.nan
            return v

        return self._spread(var, np.nan)

    @classmethod
    def from_statistics(
        cls,
        count: np.ndarray,
        mean: np.ndarray,
        variance: np.ndarray,
        *,
        backend: str | None = None,
    ) -> BinAccumulator:
        """Rebuild running sums from stored count, mean and variance (inverse of the above).

        Bins with count 0 get zero sums; bins with count 1 (variance NaN) get Σx² = x². The
        float sums m·n and v·(n − 1) + n·m² are then held exactly.
        """
        count = np.asarray(count, dtype=np.int64)
        acc = cls(count.shape, np.shape(mean)[-1], backend=backend)
        n = count.reshape(-1).astype(np.float64)
        m = np.moveaxis(np.asarray(mean, dtype=np.float64).reshape(-1, acc.channels), 0, -1)
        v = np.moveaxis(np.asarray(variance, dtype=np.float64).reshape(-1, acc.channels), 0, -1)
        m = np.where(n > 0, m, 0.0)
        v = np.where(n > 1, v, 0.0)
        sums = np.concatenate([m * n, v * np.maximum(n - 1.0, 0.0) + n * m * m])
        acc._sums = ExactSums.from_dense(count.reshape(-1), sums, backend=acc.backend)
        return acc


class TableStatistics:
    """Per-bin statistics of a table that keeps its samples in a :class:`BinAccumulator`.

    Mixed into :class:`~acquisition.tables.isotropic.IsotropicTable` and
    :class:`~acquisition.tables.merl_table.MerlTable`; the host sets ``self._acc``. Arrays have
    the table's bin shape (plus a trailing RGB axis for values); values are BRDF in sr⁻¹.
    """

    _acc: BinAccumulator

    @property
    def backend(self) -> str:
        """Binning implementation in use, ``"numba"`` or ``"numpy"``."""
        return self._acc.backend

    @property
    def count(self) -> np.ndarray:
        """Samples per bin, int64, the table's shape."""
        return self._acc.count

    @property
    def mean(self) -> np.ndarray:
        """Mean BRDF per bin, float64 ``shape + (3,)`` in sr⁻¹; NaN where unmeasured."""
        return self._acc.mean()

    @property
    def variance(self) -> np.ndarray:
        """Sample variance (ddof 1) of the values in each bin, (sr⁻¹)²; NaN where count < 2."""
        return self._acc.variance()

    @property
    def variance_of_mean(self) -> np.ndarray:
        """Variance of the bin mean, ``variance / count``, (sr⁻¹)²; NaN where count < 2."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return self.variance / self.count[..., None]

    @property
    def n_samples(self) -> int:
        """Samples binned so far."""
        return self._acc.n_samples

    @property
    def n_dropped_nan(self) -> int:
        """Samples dropped because an angle, direction or value was NaN (or ±inf)."""
        return self._acc.n_dropped_nan

    @property
    def n_dropped_range(self) -> int:
        """Samples dropped outside the table (outside the edges, or below the horizon)."""
        return self._acc.n_dropped_range
