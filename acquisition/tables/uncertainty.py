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
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from drivers.errors import ConfigError


@dataclass(frozen=True)
class Term:
    """One term of a bin's uncertainty budget: standard uncertainty of the bin mean (shape of
    the table + RGB, sr⁻¹) and whether it is common to the bins (correlated)."""

    values: np.ndarray
    correlated: bool
    description: str = ""


class UncertaintySums:
    """Running per-bin sums of the samples' uncertainty terms and angles (flat bins)."""

    def __init__(self, n_bins: int, independent: Mapping[str, str],
                 correlated: Mapping[str, str]) -> None:
        self.n_bins = n_bins
        self.descriptions = {**independent, **correlated}
        self.independent = tuple(independent)
        self.correlated = tuple(correlated)
        self._n = np.zeros(n_bins, dtype=np.int64)
        self._var = {k: np.zeros((n_bins, 3)) for k in self.independent}
        self._u = {k: np.zeros((n_bins, 3)) for k in self.correlated}
        self._angles = np.zeros((n_bins, 3))
        self._products = np.zeros((n_bins, 6))
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
                              f"do not match {sorted(self.descriptions)}")
        arrays = {k: np.asarray(v, float).reshape(-1, 3) for k, v in
                  {**variances, **uncertainties}.items()}
        keep = (idx >= 0) & np.all(np.isfinite(np.asarray(angles_deg, float).reshape(-1, 3)), 1)
        for a in arrays.values():
            keep &= np.all(np.isfinite(a), axis=1)
        i = idx[keep]
        a = np.asarray(angles_deg, float).reshape(-1, 3)[keep]
        np.add.at(self._n, i, 1)
        np.add.at(self._angles, i, a)
        np.add.at(self._products, i, a[:, _PAIRS[0]] * a[:, _PAIRS[1]])
        for k in self.independent:
            np.add.at(self._var[k], i, arrays[k][keep])
        for k in self.correlated:
            np.add.at(self._u[k], i, arrays[k][keep])

    def merge_from(self, other: UncertaintySums) -> None:
        """Add ``other``'s sums (same terms and bins)."""
        if (other.n_bins, other.independent, other.correlated) != (
                self.n_bins, self.independent, self.correlated):
            raise ConfigError("cannot merge uncertainty budgets with different terms or bins")
        self._n += other._n
        self._angles += other._angles
        self._products += other._products
        for k in self.independent:
            self._var[k] += other._var[k]
        for k in self.correlated:
            self._u[k] += other._u[k]

    def set_independent(self, name: str, description: str, sum_of_variances: np.ndarray) -> None:
        """Add (or replace) an independent term given directly as Σ var per flat bin (n_bins,
        3): a term known only once every sample is in (:func:`binning_variance_sums`)."""
        if name not in self.independent:
            self.independent = (*self.independent, name)
        self.descriptions[name] = description
        self._var[name] = np.asarray(sum_of_variances, float).reshape(self.n_bins, 3).copy()

    def set_term(self, name: str, description: str, bin_uncertainty: np.ndarray,
                 correlated: bool) -> None:
        """Add (or replace) a term given as each bin mean's standard uncertainty (n_bins, 3),
        sr⁻¹ (NaN or empty bins: 0): one that only the bin as a whole has, its samples sharing
        it (the pixels of one frame share its joint error). An independent one (uncorrelated
        between bins) counts in no sample's predicted scatter."""
        u = np.nan_to_num(np.asarray(bin_uncertainty, float).reshape(self.n_bins, 3))
        n = self._n.astype(float)[:, None]
        if correlated:
            if name not in self.correlated:
                self.correlated = (*self.correlated, name)
            self._u[name] = u * n
            self.descriptions[name] = description
        else:
            self.set_independent(name, description, (u * n) ** 2)
            self._shared.add(name)

    def copy(self) -> UncertaintySums:
        """An independent copy."""
        new = UncertaintySums(self.n_bins, {k: self.descriptions[k] for k in self.independent},
                              {k: self.descriptions[k] for k in self.correlated})
        new.merge_from(self)
        new._shared = set(self._shared)
        return new

    def terms(self, shape: tuple[int, ...]) -> dict[str, Term]:
        """Each term's standard uncertainty of the bin mean, NaN where a bin has no sample."""
        n = self._n.astype(float)[:, None]
        out = {}
        with np.errstate(invalid="ignore", divide="ignore"):
            for k in self.independent:
                out[k] = Term(np.sqrt(self._var[k] / n**2).reshape(*shape, 3), False,
                              self.descriptions[k])
            for k in self.correlated:
                out[k] = Term((self._u[k] / n).reshape(*shape, 3), True, self.descriptions[k])
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
        """Rebuild the sums from a stored budget (inverse of :meth:`terms`)."""
        independent = {k: t.description for k, t in terms.items() if not t.correlated}
        correlated = {k: t.description for k, t in terms.items() if t.correlated}
        n = np.asarray(count, dtype=np.int64).reshape(-1)
        sums = cls(n.size, independent, correlated)
        nf = n.astype(float)[:, None]
        has = n > 0
        sums._n[:] = n
        m = mean_angles.reshape(-1, 3)
        sums._angles[has] = (m * nf)[has]
        cov = (np.zeros((n.size, 6)) if angle_covariance is None
               else np.nan_to_num(angle_covariance.reshape(-1, 6)))
        sums._products[has] = ((cov + m[:, _PAIRS[0]] * m[:, _PAIRS[1]]) * nf)[has]
        for k in independent:
            sums._var[k][has] = ((terms[k].values.reshape(-1, 3) * nf) ** 2)[has]
        for k in correlated:
            sums._u[k][has] = (terms[k].values.reshape(-1, 3) * nf)[has]
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
