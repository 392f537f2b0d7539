"""What a fit or a check reads from a table: the measured bins, where their samples lie,
their values and their uncertainty split into independent and common-mode parts."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from acquisition.tables import IsotropicTable
from drivers.errors import ConfigError


@dataclass(frozen=True)
class BinData:
    """The measured bins of a table, flattened (N bins).

    Attributes
    ----------
    angles_deg:
        (N, 3) mean (θi, θr, Δφ) of each bin's samples, degrees (bin centres for tables that
        do not record them).
    values:
        (N, 3) BRDF, sr⁻¹.
    u_independent:
        (N, 3) standard uncertainty uncorrelated between bins, sr⁻¹.
    u_common:
        (N, 3) standard uncertainty common to all bins (fully correlated per channel), sr⁻¹.
    solid_angle:
        (N,) the bins' measure in (ωi, ωo): sin θi sin θr Δθi Δθr ΔΔφ (rad⁵), for weighted
        metrics.
    angle_cov:
        (N, 6) covariance of each bin's sample angles, deg² (θiθi, θrθr, ΔφΔφ, θiθr, θiΔφ,
        θrΔφ); zero for single samples.
    """

    angles_deg: np.ndarray
    values: np.ndarray
    u_independent: np.ndarray
    u_common: np.ndarray
    solid_angle: np.ndarray
    angle_cov: np.ndarray | None = None

    @property
    def n(self) -> int:
        return int(self.values.shape[0])

    @property
    def cos_i(self) -> np.ndarray:
        return np.cos(np.radians(self.angles_deg[:, 0]))


def bin_solid_angles(table: IsotropicTable) -> np.ndarray:
    """Each bin's measure sin θi sin θr Δθi Δθr ΔΔφ at its centre (rad⁵), table shape."""
    widths = [np.radians(np.diff(e)) for e in
              (table.theta_i_edges, table.theta_r_edges, table.delta_phi_edges)]
    ti, tr, _ = np.meshgrid(*table.centers(), indexing="ij")
    wi, wr, wp = np.meshgrid(*widths, indexing="ij")
    return np.abs(np.sin(np.radians(ti)) * np.sin(np.radians(tr))) * wi * wr * wp


def bin_data(table: IsotropicTable) -> BinData:
    """The bins with samples and a finite, positive uncertainty in every channel.

    Raises ConfigError when the table has no uncertainty budget (a version-1 table, or one
    not reduced by gonio): a weighted fit or a z-score needs one — re-reduce the session.
    """
    if not table.tracks_uncertainty:
        raise ConfigError("the table has no per-bin uncertainty (a version-1 table?): "
                          "reduce the session again with `gonio reduce` to get one")
    terms = table.uncertainty_terms
    indep = np.sqrt(sum((t.values**2 for t in terms.values() if not t.correlated),
                        np.zeros(table.shape + (3,))))
    common = np.sqrt(sum((t.values**2 for t in terms.values() if t.correlated),
                         np.zeros(table.shape + (3,))))
    mean = table.mean
    keep = ((table.count > 0) & np.all(np.isfinite(mean), -1) & np.all(indep > 0, -1)
            & np.all(np.isfinite(indep), -1) & np.all(np.isfinite(common), -1))
    return BinData(table.mean_angles[keep], mean[keep], indep[keep], common[keep],
                   bin_solid_angles(table)[keep], np.nan_to_num(table.angle_covariance[keep]))
