"""Per-bin uncertainty bookkeeping beside a table's values: the uncertainty budget and the
mean angles of each bin's samples.

A reduction gives every sample its uncertainty as named *terms*:

* independent terms (sensor noise of the sample frame, angular jitter): a variance per
  sample, uncorrelated between samples; the bin mean's variance is Σ var / n²;
* correlated terms (the white reference's noise, a geometric calibration's error): a standard
  uncertainty per sample that is common to many samples and bins (one error of the reference
  scales every value it normalises); within a bin it adds linearly, u = Σ u / n, and between
  bins it is fully correlated — fits treat it as one common-mode error per channel.

The bin's total standard uncertainty ``std_error`` is the root sum of squares of its terms.
Angles are summed as given (Δφ already as the table bins it), with their products, so a bin
also knows where its samples really lie (read-back poses sit off the bin centres) and how they
spread (an image's pixels fill the bin: a fit evaluates the model's average over that spread).

Every one of these per-bin sums is exact (:class:`~acquisition.tables.exact.ExactSums`: each
variance, standard uncertainty, angle and angle product — rounded once as a float64 — held as a
fixed-point integer), so the budget, like the table's values, does not depend on how the
samples were split, ordered or merged (:meth:`UncertaintySums.partial`). Variances and standard
uncertainties must be below 2^40 ((sr⁻¹)², sr⁻¹) and angles below 2^20 degrees in magnitude.
A term known only once every sample is in (the ``binning`` term) is set at the end as float
sums and is not part of a partial.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from acquisition.tables.exact import ExactSums, SparseSums, largest_finite
from acquisition.tables.fixedpoint import VALUE_LIMIT, check_range
from drivers.errors import ConfigError

ANGLE_LIMIT = 2.0**20
"""Largest |angle| in degrees (exclusive) the budget sums (its products stay below 2^40)."""


@dataclass(frozen=True)
class Term:
    """One term of a bin's uncertainty budget: standard uncertainty of the bin mean (shape of
    the table + RGB, sr⁻¹) and whether it is common to the bins (correlated)."""

    values: np.ndarray
    correlated: bool
    description: str = ""


class UncertaintySums:
    """Running per-bin sums of the samples' uncertainty terms and angles (flat bins), exact.

    Sums, in order: 3 per independent term (Σ var), 3 per correlated term (Σ u), the 3 angles
    and their 6 products; the store counts the samples with a finite budget (``_n``).
    """

    def __init__(self, n_bins: int, independent: Mapping[str, str],
                 correlated: Mapping[str, str], *, backend: str | None = None) -> None:
        self.n_bins = n_bins
        self.descriptions = {**independent, **correlated}
        self.independent = tuple(independent)
        self.correlated = tuple(correlated)
        self._summed = (*self.independent, *self.correlated)
        self._sums = ExactSums(n_bins, 3 * len(self._summed) + 9, backend=backend,
                               capacity=min(n_bins, 1 << 16))
        self._final: dict[str, np.ndarray] = {}
        """Terms given whole once every sample is in (:meth:`set_independent`, :meth:`set_term`):
        Σ var (independent) or Σ u (correlated) per flat bin (n_bins, 3)."""
        self._nan: dict[str, np.ndarray] = {}
        """Bins (n_bins, 3) where a term read from a file was NaN: it stays NaN."""
        self._shared: set[str] = set()
        """Independent terms given per bin (:meth:`set_term`): shared by a bin's samples,
        so no part of their scatter."""

    def add(self, flat_index: np.ndarray, angles_deg: np.ndarray,
            variances: Mapping[str, np.ndarray], uncertainties: Mapping[str, np.ndarray]) -> None:
        """Add samples by flat bin index (negative: dropped, as the table drops them).

        ``angles_deg`` (N, 3) are (θi, θr, Δφ) as the table bins them; ``variances`` the
        independent terms' variances (N, 3), (sr⁻¹)²; ``uncertainties`` the correlated terms'
        standard uncertainties (N, 3), sr⁻¹. A sample with a non-finite term is dropped.
        """
        idx = np.asarray(flat_index, dtype=np.int64).reshape(-1)
        if set(variances) != set(self.independent) or set(uncertainties) != set(self.correlated):
            raise ConfigError(f"uncertainty terms {sorted(variances) + sorted(uncertainties)} "
                              f"do not match {sorted(self._summed)}")
        terms = {**variances, **uncertainties}
        t = np.concatenate([np.asarray(terms[k], float).reshape(-1, 3) for k in self._summed],
                           axis=1)
        a = np.ascontiguousarray(np.asarray(angles_deg, float).reshape(-1, 3))
        if self._sums.backend == "numba":
            self._add_compiled(idx, t, a)
            return
        values = np.concatenate([t, a, a[:, _PAIRS[0]] * a[:, _PAIRS[1]]], axis=1)
        with np.errstate(invalid="ignore"):
            keep = (idx >= 0) & np.isfinite(values).all(axis=1)
        values = values[keep]
        if largest_finite(values, self._sums.backend) >= VALUE_LIMIT:
            self._range_error(values)
        self._sums.add_values(idx[keep], values, checked=True)

    def _add_compiled(self, idx: np.ndarray, terms: np.ndarray, angles: np.ndarray) -> None:
        """numba path of :meth:`add`: one compiled pass builds, checks and adds the sums."""
        from acquisition.tables import exact_kernels

        big_term, big_angle = exact_kernels.budget_largest(idx, terms, angles)
        check_range(angles[:0], ANGLE_LIMIT, "sample angle", "°", big_angle)
        if big_term >= VALUE_LIMIT:
            keep = (idx >= 0) & np.isfinite(terms).all(axis=1) & np.isfinite(angles).all(axis=1)
            self._range_error(np.concatenate([terms, angles], axis=1)[keep])
        self._sums.run_kernel(exact_kernels.add_budget, (idx, terms, angles), idx.size,
                              np.zeros(4, np.int64))

    def _range_error(self, values: np.ndarray) -> None:
        """The one-line error naming what is out of range in a batch of sums."""
        n = 3 * len(self._summed)
        check_range(values[:, n:n + 3], ANGLE_LIMIT, "sample angle", "°")
        for k, name in enumerate(self._summed):
            check_range(values[:, 3 * k:3 * k + 3], VALUE_LIMIT, f"uncertainty term {name!r}", "")
        check_range(values, VALUE_LIMIT, "uncertainty sum", "")

    def partial(self) -> SparseSums:
        """The canonical exact sums (without terms set at the end): a partial budget."""
        return self._sums.sparse()

    def merge_partial(self, part: SparseSums) -> None:
        """Add a partial budget's sums (same terms and bins)."""
        self._sums.merge(part)

    def merge_from(self, other: UncertaintySums) -> None:
        """Add ``other``'s sums (same terms and bins)."""
        if (other.n_bins, other.independent, other.correlated) != (
                self.n_bins, self.independent, self.correlated):
            raise ConfigError("cannot merge uncertainty budgets with different terms or bins")
        self.merge_partial(other.partial())
        for k, v in other._final.items():
            self._final[k] = self._final.get(k, 0.0) + v
        for k, v in other._nan.items():
            self._nan[k] = self._nan.get(k, False) | v

    def set_independent(self, name: str, description: str, sum_of_variances: np.ndarray) -> None:
        """Add (or replace) an independent term given directly as Σ var per flat bin (n_bins,
        3): a term known only once every sample is in (:func:`binning_variance_sums`)."""
        if name in self._summed:
            raise ConfigError(f"uncertainty term {name!r} is summed per sample: it cannot be set")
        if name not in self.independent:
            self.independent = (*self.independent, name)
        self.descriptions[name] = description
        self._final[name] = np.asarray(sum_of_variances, float).reshape(self.n_bins, 3).copy()

    def set_term(self, name: str, description: str, bin_uncertainty: np.ndarray,
                 correlated: bool) -> None:
        """Add (or replace) a term given as each bin mean's standard uncertainty (n_bins, 3),
        sr⁻¹ (NaN or empty bins: 0): one that only the bin as a whole has, its samples sharing
        it (the pixels of one frame share its joint error). An independent one (uncorrelated
        between bins) counts in no sample's predicted scatter."""
        u = np.nan_to_num(np.asarray(bin_uncertainty, float).reshape(self.n_bins, 3))
        n = self._n.astype(float)[:, None]
        if correlated:
            if name in self._summed:
                raise ConfigError(f"uncertainty term {name!r} is summed per sample: it cannot be set")
            if name not in self.correlated:
                self.correlated = (*self.correlated, name)
            self._final[name] = u * n
            self.descriptions[name] = description
        else:
            self.set_independent(name, description, (u * n) ** 2)
            self._shared.add(name)

    def copy(self) -> UncertaintySums:
        """An independent copy."""
        new = UncertaintySums(self.n_bins, {k: self.descriptions[k] for k in self._summed
                                            if k in self.independent},
                              {k: self.descriptions[k] for k in self._summed
                               if k in self.correlated},
                              backend=self._sums.backend)
        new.merge_partial(self.partial())
        new.independent, new.correlated = self.independent, self.correlated
        new.descriptions = dict(self.descriptions)
        new._final = {k: v.copy() for k, v in self._final.items()}
        new._nan = {k: v.copy() for k, v in self._nan.items()}
        new._shared = set(self._shared)
        return new

    # ------------------------------------------------------------------ reading
    @property
    def _n(self) -> np.ndarray:
        """Samples with a finite budget per flat bin, int64 (n_bins,)."""
        return self._sums.dense()[0]

    def _column(self, first: int, width: int) -> np.ndarray:
        """Sums ``first … first + width − 1`` per flat bin, (n_bins, width), rounded once."""
        return self._sums.dense()[1][first:first + width].T

    def _term(self, name: str) -> np.ndarray:
        """Σ var or Σ u of a term per flat bin (n_bins, 3), read-only (the sums are the
        store's: add samples to change them)."""
        if name in self._final:
            out = self._final[name].view()
        else:
            out = self._column(3 * self._summed.index(name), 3).copy()
            if name in self._nan:
                out[self._nan[name]] = np.nan
        out.flags.writeable = False
        return out

    @property
    def _var(self) -> dict[str, np.ndarray]:
        """Σ var per flat bin (n_bins, 3) of each independent term."""
        return {k: self._term(k) for k in self.independent}

    @property
    def _u(self) -> dict[str, np.ndarray]:
        """Σ u per flat bin (n_bins, 3) of each correlated term."""
        return {k: self._term(k) for k in self.correlated}

    @property
    def _angles(self) -> np.ndarray:
        return self._column(3 * len(self._summed), 3)

    @property
    def _products(self) -> np.ndarray:
        return self._column(3 * len(self._summed) + 3, 6)

    def terms(self, shape: tuple[int, ...]) -> dict[str, Term]:
        """Each term's standard uncertainty of the bin mean, NaN where a bin has no sample."""
        n = self._n.astype(float)[:, None]
        var, u = self._var, self._u
        out = {}
        with np.errstate(invalid="ignore", divide="ignore"):
            for k in self.independent:
                out[k] = Term(np.sqrt(var[k] / n**2).reshape(*shape, 3), False,
                              self.descriptions[k])
            for k in self.correlated:
                out[k] = Term((u[k] / n).reshape(*shape, 3), True, self.descriptions[k])
        return out

    def mean_angles(self, shape: tuple[int, ...]) -> np.ndarray:
        """Mean (θi, θr, Δφ) of each bin's samples, degrees, ``shape + (3,)``; NaN if empty."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return (self._angles / self._n[:, None]).reshape(*shape, 3)

    def angle_covariance(self, shape: tuple[int, ...]) -> np.ndarray:
        """Covariance of each bin's sample angles, deg², ``shape + (6,)`` in the order
        (θiθi, θrθr, ΔφΔφ, θiθr, θiΔφ, θrΔφ); NaN where empty."""
        with np.errstate(invalid="ignore", divide="ignore"):
            n = self._n[:, None].astype(float)
            mean = self._angles / n
            cov = self._products / n - mean[:, _PAIRS[0]] * mean[:, _PAIRS[1]]
        cov[:, :3] = np.maximum(cov[:, :3], 0.0)  # rounding
        return cov.reshape(*shape, 6)

    def predicted_sample_variance(self, exclude: tuple[str, ...] = ()) -> np.ndarray:
        """Mean predicted variance of one sample per flat bin, independent terms (but
        ``exclude`` and those the bin's samples share, :meth:`set_term`), (n_bins, 3)."""
        total = sum((v for k, v in self._var.items() if k not in exclude and k not in self._shared),
                    np.zeros((self.n_bins, 3)))
        with np.errstate(invalid="ignore", divide="ignore"):
            return total / self._n[:, None]

    @classmethod
    def from_terms(cls, count: np.ndarray, terms: Mapping[str, Term], mean_angles: np.ndarray,
                   angle_covariance: np.ndarray | None = None) -> UncertaintySums:
        """Rebuild the sums from a stored budget (inverse of :meth:`terms`); a term stored as
        NaN in a measured bin stays NaN."""
        independent = {k: t.description for k, t in terms.items() if not t.correlated}
        correlated = {k: t.description for k, t in terms.items() if t.correlated}
        n = np.asarray(count, dtype=np.int64).reshape(-1)
        nf = n.astype(float)[:, None]
        m = np.nan_to_num(mean_angles.reshape(-1, 3))
        cov = (np.zeros((n.size, 6)) if angle_covariance is None
               else np.nan_to_num(angle_covariance.reshape(-1, 6)))
        columns = {k: (terms[k].values.reshape(-1, 3) * nf) ** 2 for k in independent}
        columns.update({k: terms[k].values.reshape(-1, 3) * nf for k in correlated})
        sums = cls(n.size, independent, correlated)
        stacked = np.concatenate([*(columns[k] for k in sums._summed), m * nf,
                                  (cov + m[:, _PAIRS[0]] * m[:, _PAIRS[1]]) * nf], axis=1)
        sums._sums = ExactSums.from_dense(n, stacked.T)
        sums._nan = {k: ~np.isfinite(c) & (n > 0)[:, None] for k, c in columns.items()}
        return sums


_PAIRS = (np.array([0, 1, 2, 0, 0, 1]), np.array([0, 1, 2, 1, 2, 2]))
"""Index pairs of the angle products kept per bin: θiθi, θrθr, ΔφΔφ, θiθr, θiΔφ, θrΔφ."""

BINNING_TERM = "binning"
BINNING_DESCRIPTION = ("the BRDF's variation across a bin as sampled by its pixels (observed "
                       "scatter beyond the noise), independent")


def binning_variance_sums(sums: UncertaintySums, variance: np.ndarray,
                          count: np.ndarray) -> np.ndarray:
    """Σ var of the binning term per flat bin: n × max(observed variance of the bin's samples −
    their predicted noise variance, 0), so its standard uncertainty of the mean is
    √(excess / n). Bins with fewer than 2 samples get 0 (a single sample has no scatter)."""
    n = np.asarray(count).reshape(-1).astype(float)
    observed = np.nan_to_num(np.asarray(variance, float).reshape(-1, 3))
    predicted = np.nan_to_num(sums.predicted_sample_variance(exclude=(BINNING_TERM,)))
    excess = np.where((n >= 2)[:, None], np.maximum(observed - predicted, 0.0), 0.0)
    return excess * n[:, None]


def total_std_error(terms: Mapping[str, Term]) -> np.ndarray:
    """Root sum of squares of every term (the bin mean's standard uncertainty), sr⁻¹."""
    return np.sqrt(sum(t.values**2 for t in terms.values()))


def scatter_ratio(sums: UncertaintySums, variance: np.ndarray, count: np.ndarray
                  ) -> tuple[float, int]:
    """Observed over predicted scatter of repeated samples: √(Σ observed var / Σ predicted var)
    over bins with ≥ 2 samples (independent terms but the binning one, which is made of that
    scatter), and how many bins that is."""
    repeated = np.asarray(count).reshape(-1) >= 2
    observed = np.asarray(variance, float).reshape(-1, 3)[repeated]
    predicted = sums.predicted_sample_variance(exclude=(BINNING_TERM,))[repeated]
    ok = np.all(np.isfinite(observed), 1) & np.all(np.isfinite(predicted), 1)
    if not ok.any() or predicted[ok].sum() <= 0:
        return float("nan"), 0
    return float(np.sqrt(observed[ok].sum() / predicted[ok].sum())), int(ok.sum())
