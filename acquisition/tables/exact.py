"""Exact per-bin sums: a sample count and K fixed-point sums per bin, stored for the bins
that hold samples only.

:class:`ExactSums` is the running store a table bins into: a dense map from bin to row
(int32, 4 bytes per bin: 5.8 MB for the MERL grid) and, per touched bin, its count and the
limbs of its K sums (:mod:`acquisition.tables.fixedpoint`, 8 · 3 · K bytes). Memory follows
the bins measured, not the grid: a sphere session touching 8 % of the MERL table holds 8 % of
what a dense layout would.

:class:`SparseSums` is its canonical, mergeable form — a *partial*: the touched bins in
increasing order, their counts and normalised limbs. Merging partials adds integers, so any
split of the samples, in any order and any grouping, merges to the same arrays, and the same
floats when read (:meth:`ExactSums.dense`, one correctly rounded conversion per sum).

Both backends fill a store with the same integers: numba (``add_*`` kernels of
:mod:`acquisition.tables.exact_kernels`) or numpy (``np.add.at`` on the same limbs).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from acquisition.tables.backend import resolve_backend
from acquisition.tables.fixedpoint import (
    CARRY_EVERY,
    LIMBS,
    SET_LIMIT,
    VALUE_LIMIT,
    OutOfRangeError,
    check_range,
    limbs_first,
    max_finite_abs,
    normalize,
    to_float,
    to_limbs,
)
from drivers.errors import ConfigError

ROWS_PER_PASS = 1 << 16
"""Rows converted to float per pass when reading (bounds the temporaries)."""


def largest_finite(values: np.ndarray, backend: str) -> float:
    """Largest |v| over the finite entries of a 2-D float64 array (0 for none), compiled with
    the numba backend (one pass, no temporaries)."""
    if values.size == 0:
        return 0.0
    if backend == "numba":
        from acquisition.tables import exact_kernels

        return float(exact_kernels.max_finite_abs(np.ascontiguousarray(values, np.float64)))
    return max_finite_abs(values)


def _raise_if_overflow(*tallies: np.ndarray) -> None:
    """Raise when a kernel counted an overflowed sum (``tally[3]``)."""
    if any(t[3] for t in tallies):
        raise OutOfRangeError("a bin's exact sum overflowed (|Σ| ≥ 2.3e18): split the data "
                              "into several tables")


@dataclass(frozen=True)
class SparseSums:
    """Canonical exact sums over ``n_bins`` bins: ``bins`` (m,) increasing, ``count`` (m,)
    ≥ 1, ``limbs`` (m, n_sums, 3) normalised (:func:`~acquisition.tables.fixedpoint.normalize`)."""

    n_bins: int
    bins: np.ndarray
    count: np.ndarray
    limbs: np.ndarray

    @property
    def n_sums(self) -> int:
        return int(self.limbs.shape[1])

    @classmethod
    def empty(cls, n_bins: int, n_sums: int) -> SparseSums:
        return cls(int(n_bins), np.zeros(0, np.int64), np.zeros(0, np.int64),
                   np.zeros((0, n_sums, LIMBS), np.int64))

    def merge(self, other: SparseSums) -> SparseSums:
        """The sums of both (integer addition: associative and commutative, exactly)."""
        if (self.n_bins, self.n_sums) != (other.n_bins, other.n_sums):
            raise ConfigError(f"cannot merge exact sums over {self.n_bins} bins × {self.n_sums} "
                              f"with {other.n_bins} bins × {other.n_sums}: not the same table")
        bins, where = np.unique(np.concatenate([self.bins, other.bins]), return_inverse=True)
        count = np.zeros(bins.size, np.int64)
        limbs = np.zeros((bins.size, self.n_sums, LIMBS), np.int64)
        for part, at in ((self, where[:self.bins.size]), (other, where[self.bins.size:])):
            count[at] += part.count  # a partial's bins are unique: no repeated index
            limbs[at] += part.limbs
        return SparseSums(self.n_bins, bins, count, normalize(limbs))

    def same_as(self, other: SparseSums) -> bool:
        """Equal sums, bit for bit."""
        return (self.n_bins == other.n_bins and np.array_equal(self.bins, other.bins)
                and np.array_equal(self.count, other.count)
                and np.array_equal(self.limbs, other.limbs))


class ExactSums:
    """Running count and ``n_sums`` exact sums per bin over ``n_bins`` bins (flat index).

    ``backend``: ``"numba"`` or ``"numpy"`` (default ``$GONIO_BINNING_BACKEND``, else numba);
    both hold the same integers.
    """

    def __init__(self, n_bins: int, n_sums: int, *, backend: str | None = None,
                 capacity: int = 4096) -> None:
        self.backend = resolve_backend(backend)
        self.n_bins = int(n_bins)
        self.n_sums = int(n_sums)
        self.slot = np.full(self.n_bins, -1, dtype=np.int32)
        cap = max(1, min(self.n_bins, int(capacity)))
        self.rows = np.zeros(cap, np.int64)
        self.count = np.zeros(cap, np.int64)
        self.limbs = np.zeros((cap, self.n_sums, LIMBS), np.int64)
        self.used = np.zeros(1, np.int64)
        self._version = 0
        self._dense: tuple[int, np.ndarray, np.ndarray, np.ndarray] | None = None

    # ------------------------------------------------------------------ storage
    @property
    def n_used(self) -> int:
        """Bins holding samples."""
        return int(self.used[0])

    def nbytes(self) -> int:
        """Memory the store holds, bytes."""
        return sum(a.nbytes for a in (self.slot, self.rows, self.count, self.limbs))

    def grow(self, need: int = 1) -> None:
        """Room for at least ``need`` more bins (capacity doubles, up to the grid)."""
        cap, used = self.rows.size, self.n_used
        if cap - used >= need:
            return
        new = min(self.n_bins, max(2 * cap, used + need, 1024))
        for name in ("rows", "count", "limbs"):
            old = getattr(self, name)
            grown = np.zeros((new, *old.shape[1:]), old.dtype)
            grown[:used] = old[:used]
            setattr(self, name, grown)

    def _rows_for(self, idx: np.ndarray) -> np.ndarray:
        """Rows of valid bin indices, new rows for new bins (numpy path)."""
        new = np.unique(idx[self.slot[idx] < 0])
        if new.size:
            self.grow(new.size)
            u = self.n_used
            self.slot[new] = np.arange(u, u + new.size, dtype=np.int32)
            self.rows[u:u + new.size] = new
            self.used[0] = u + new.size
        return self.slot[idx].astype(np.intp)

    def _touch(self) -> None:
        self._version += 1
        self._dense = None

    # ------------------------------------------------------------------ adding
    def run_kernel(self, kernel: Callable[..., Any], args: tuple[Any, ...], n: int,
                   tally: np.ndarray) -> None:
        """Run a compiled ``kernel(*args, slot, rows, count, limbs, used, tally, start)`` over
        ``n`` samples, growing the store each time it fills up; raises when a sum overflowed."""
        self._touch()
        start = 0
        while True:
            start = int(kernel(*args, self.slot, self.rows, self.count, self.limbs, self.used,
                               tally, start))
            if start >= n:
                break
            self.grow(min(n - start, ROWS_PER_PASS))
        _raise_if_overflow(tally)

    def run_paired_kernel(self, other: ExactSums, kernel: Callable[..., Any],
                          args: tuple[Any, ...], n: int, tally: np.ndarray,
                          other_tally: np.ndarray) -> None:
        """:meth:`run_kernel` of a kernel that adds into this store and ``other`` at once:
        ``kernel(*args, <this store's arrays>, tally, <other's arrays>, other_tally, start)``;
        both grow whenever it stops for room."""
        self._touch()
        other._touch()
        start = 0
        while True:
            start = int(kernel(*args, self.slot, self.rows, self.count, self.limbs, self.used,
                               tally, other.slot, other.rows, other.count, other.limbs,
                               other.used, other_tally, start))
            if start >= n:
                break
            for store in (self, other):
                store.grow(min(n - start, ROWS_PER_PASS))
        _raise_if_overflow(tally, other_tally)

    def add_values(self, idx: np.ndarray, values: np.ndarray, what: str = "value",
                   unit: str = "", checked: bool = False) -> int:
        """Add row ``i`` of ``values`` (N, n_sums) to bin ``idx[i]`` (valid indices, finite
        values: the caller drops the others). Raises :class:`OutOfRangeError`, before any sum
        changes, for a value with |v| ≥ 2^40 (unless the caller ``checked``). Returns N."""
        idx = np.ascontiguousarray(idx, dtype=np.int64)
        vals = np.ascontiguousarray(values, dtype=np.float64).reshape(idx.size, self.n_sums)
        if idx.size == 0:
            return 0
        if not checked:
            check_range(vals, VALUE_LIMIT, what, unit, largest_finite(vals, self.backend))
        if self.backend == "numba":
            from acquisition.tables import exact_kernels

            self.run_kernel(exact_kernels.add_sums, (idx, vals), idx.size, np.zeros(4, np.int64))
        else:
            self.add_limbs(idx, lambda a, b: limbs_first(vals[a:b]))
        return idx.size

    def add_limbs(self, idx: np.ndarray, limbs_of: Callable[[int, int], np.ndarray]) -> None:
        """numpy path: add ``limbs_of(a, b)`` ((3, b − a, n_sums) signed limbs, limb axis
        first: :func:`~acquisition.tables.fixedpoint.limbs_first`) to the bins ``idx[a:b]``,
        one sample each, a carry pass after every CARRY_EVERY samples."""
        self._touch()
        for a in range(0, idx.size, CARRY_EVERY):
            b = min(a + CARRY_EVERY, idx.size)
            rows = self._rows_for(idx[a:b])
            limbs = limbs_of(a, b)
            np.add.at(self.count, rows, 1)
            for k in range(self.n_sums):  # 1-D integer add.at: numpy's fast path
                for limb in range(LIMBS):
                    np.add.at(self.limbs[:, k, limb], rows, limbs[limb, :, k])
            touched = np.zeros(self.n_used, bool)
            touched[rows] = True
            touched = np.flatnonzero(touched)
            self.limbs[touched] = normalize(self.limbs[touched])

    # ------------------------------------------------------------------ partials
    def sparse(self) -> SparseSums:
        """The canonical partial of everything added so far."""
        u = self.n_used
        order = np.argsort(self.rows[:u], kind="stable")
        limbs = normalize(self.limbs[:u][order])
        return SparseSums(self.n_bins, self.rows[:u][order].copy(), self.count[:u][order].copy(),
                          limbs)

    def merge(self, part: SparseSums) -> None:
        """Add a partial's sums (same bins and number of sums)."""
        if (part.n_bins, part.n_sums) != (self.n_bins, self.n_sums):
            raise ConfigError(f"cannot merge exact sums over {part.n_bins} bins × {part.n_sums} "
                              f"into {self.n_bins} bins × {self.n_sums}: not the same table")
        if part.bins.size == 0:
            return
        self._touch()
        rows = self._rows_for(part.bins)
        self.count[rows] += part.count
        self.limbs[rows] = normalize(self.limbs[rows] + part.limbs)

    def copy(self) -> ExactSums:
        new = ExactSums(self.n_bins, self.n_sums, backend=self.backend, capacity=self.n_used)
        new.merge(self.sparse())
        return new

    # ------------------------------------------------------------------ reading
    def touched(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(bins (u,), count (u,), sums (n_sums, u) float64) of the u bins holding samples,
        in no particular order: each sum rounded once to the nearest float64. Cached until the
        next change (its size follows the bins touched, not the grid)."""
        if self._dense is not None and self._dense[0] == self._version:
            return self._dense[1], self._dense[2], self._dense[3]
        u = self.n_used
        sums = np.empty((self.n_sums, u), np.float64)
        for a in range(0, u, ROWS_PER_PASS):
            b = min(a + ROWS_PER_PASS, u)
            sums[:, a:b] = to_float(self.limbs[a:b]).T
        self._dense = (self._version, self.rows[:u].copy(), self.count[:u].copy(), sums)
        return self._dense[1], self._dense[2], self._dense[3]

    def dense(self) -> tuple[np.ndarray, np.ndarray]:
        """(count (n_bins,) int64, sums (n_sums, n_bins) float64): :meth:`touched` spread over
        the grid, 0 where a bin is empty."""
        bins, n, values = self.touched()
        count = np.zeros(self.n_bins, np.int64)
        sums = np.zeros((self.n_sums, self.n_bins), np.float64)
        count[bins] = n
        sums[:, bins] = values
        return count, sums

    def dense_limbs(self) -> tuple[np.ndarray, np.ndarray]:
        """(count (n_bins,), limbs (n_sums, 3, n_bins)) normalised, zero where empty."""
        part = self.sparse()
        count = np.zeros(self.n_bins, np.int64)
        limbs = np.zeros((self.n_sums, LIMBS, self.n_bins), np.int64)
        count[part.bins] = part.count
        limbs[..., part.bins] = part.limbs.transpose(1, 2, 0)
        return count, limbs

    @classmethod
    def from_dense(cls, count: np.ndarray, sums: np.ndarray | None = None, *,
                   limbs: np.ndarray | None = None, backend: str | None = None) -> ExactSums:
        """A store holding ``count`` (n_bins,) and either float ``sums`` (n_sums, n_bins),
        each converted exactly to limbs (|sum| < 2^61), or integer ``limbs``
        (n_sums, 3, n_bins); bins with count 0 are left out."""
        count = np.asarray(count, np.int64).reshape(-1)
        bins = np.flatnonzero(count > 0)
        if limbs is None:
            assert sums is not None
            values = np.asarray(sums, np.float64).reshape(-1, count.size)[:, bins].T
            values = np.where(np.isfinite(values), values, 0.0)
            check_range(values, SET_LIMIT, "stored sum", "")
            part_limbs = normalize(to_limbs(values))
        else:
            part_limbs = normalize(np.asarray(limbs, np.int64)[..., bins].transpose(2, 0, 1).copy())
        new = cls(count.size, part_limbs.shape[1], backend=backend, capacity=bins.size)
        new.merge(SparseSums(count.size, bins, count[bins], part_limbs))
        return new
