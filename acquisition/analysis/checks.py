"""Physical checks of a measured table: Helmholtz reciprocity, energy conservation (the
directional albedo ρ(θi) = ∫ f cos θr dωr with its uncertainty band), coverage and SNR.

* **Reciprocity**: every pair of measured bins (θi, θr, Δφ) and (θr, θi, Δφ) with θi ≠ θr
  gives z = (f_a − f_b) / √(u_a² + u_b²) per channel, from the bins' independent terms (the
  white reference's error is common to both and cancels). Under reciprocity the Σ z² over
  pairs and channels is χ²-distributed; the check fails when its upper-tail probability is
  below :data:`P_FAIL`.
* **Energy**: per θi bin, ρ = Σ f · ∫∫ cos θr sin θr dθr dΔφ over measured bins (each bin's
  exact projected solid angle, Δφ ∈ [0, 180°] counted twice for the full circle), a lower
  bound of the true albedo wherever the hemisphere is not fully covered; its uncertainty adds
  the independent terms in quadrature and the common ones linearly. The check fails when some
  ρ(θi) exceeds 1 by more than :data:`Z_FAIL` of its uncertainty.
* **Coverage** (measured bins among those above the horizon, per θi the measured fraction of
  the projected hemisphere) and **SNR** (mean / std_error) are reported, never failed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.stats import chi2

from acquisition.tables import IsotropicTable
from drivers.errors import ConfigError

P_FAIL = 1e-3
"""Reciprocity fails when P(χ² ≥ observed) under reciprocity is below this."""
Z_FAIL = 3.0
"""Energy fails when ρ(θi) − 1 exceeds this many of its standard uncertainties."""


@dataclass
class Check:
    """One check's outcome: its name, whether it passed (None: informational), one line."""

    name: str
    passed: bool | None
    line: str
    details: dict[str, Any] = field(default_factory=dict)


def _independent_u(table: IsotropicTable) -> np.ndarray:
    terms = table.uncertainty_terms
    return np.sqrt(sum((t.values**2 for t in terms.values() if not t.correlated),
                       np.zeros(table.shape + (3,))))


def _common_u(table: IsotropicTable) -> np.ndarray:
    terms = table.uncertainty_terms
    return np.sqrt(sum((t.values**2 for t in terms.values() if t.correlated),
                       np.zeros(table.shape + (3,))))


def _where(table: IsotropicTable, idx: tuple[int, int, int]) -> str:
    ti, tr, dp = (c[k] for c, k in zip(table.centers(), idx, strict=True))
    return f"θi {ti:g}° θr {tr:g}° Δφ {dp:g}°"


def reciprocity(table: IsotropicTable) -> Check:
    """Helmholtz reciprocity as a χ² of the pairs' z-scores (module docstring)."""
    if not np.array_equal(table.theta_i_edges, table.theta_r_edges):
        return Check("reciprocity", None, "reciprocity: θi and θr bins differ, no pairs to test")
    mean, u, count = table.mean, _independent_u(table), table.count
    swapped = np.swapaxes(mean, 0, 1)
    u_sw = np.swapaxes(u, 0, 1)
    ii, rr = np.meshgrid(np.arange(table.shape[0]), np.arange(table.shape[1]), indexing="ij")
    pair = (ii < rr)[..., None] & (count > 0) & (np.swapaxes(count, 0, 1) > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        z = (mean - swapped) / np.sqrt(u**2 + u_sw**2)
    zs = z[pair]
    ok = np.all(np.isfinite(zs), axis=1)
    zs = zs[ok]
    if not zs.size:
        return Check("reciprocity", None, "reciprocity: no bin measured both ways (θi ↔ θr)")
    stat, n = float(np.sum(zs**2)), int(zs.size)
    p = float(chi2.sf(stat, n))
    where = np.argwhere(pair)[ok]
    k = int(np.argmax(np.max(np.abs(zs), axis=1)))
    worst = float(np.max(np.abs(zs[k])))
    passed = p >= P_FAIL
    line = (f"reciprocity: {len(zs)} bin pairs, χ²/N {stat / n:.2f} (p = {p:.2g}), worst |z| "
            f"{worst:.1f} at {_where(table, tuple(where[k]))}: "
            + ("pass" if passed else "FAIL, the table is not reciprocal beyond its uncertainty"))
    return Check("reciprocity", passed, line,
                 {"pairs": len(zs), "chi2_per_n": stat / n, "p": p, "worst_z": worst})


def _projected_solid_angle(table: IsotropicTable) -> np.ndarray:
    """Per (θr, Δφ) bin: ∫∫ cos θr sin θr dθr dΔφ (sr), counted twice for a folded Δφ."""
    er = np.radians(np.clip(table.theta_r_edges, 0, 90))
    ring = 0.5 * np.diff(np.sin(er) ** 2)
    e = table.delta_phi_edges
    if table.fold_delta_phi:  # bins beyond [0°, 180°] hold folded samples: count the inside
        dphi = 2.0 * np.radians(np.diff(np.clip(e, 0.0, 180.0)))
    else:
        dphi = np.radians(np.diff(np.clip(e, e[0], e[0] + 360.0)))
    return ring[:, None] * dphi[None, :]


DEGENERATE_DEG = 1.0
"""A (θi, θr) row whose samples lie this close to the normal in θi or θr has no azimuth:
f does not depend on Δφ there (the planner measures one Δφ of it)."""


def _azimuth_filled(table: IsotropicTable) -> tuple[np.ndarray, ...]:
    """Mean, independent and common uncertainty, and the measured mask, with each degenerate
    row's unmeasured Δφ bins given its measured bins' average (:data:`DEGENERATE_DEG`)."""
    measured = table.count > 0
    mean, u_ind, u_com = table.mean, _independent_u(table), _common_u(table)
    angles = table.mean_angles
    nearest = np.where(measured, np.minimum(angles[..., 0], angles[..., 1]), np.inf)
    near = nearest.min(axis=2) < DEGENERATE_DEG
    rows = near & measured.any(axis=2) & ~measured.all(axis=2)
    filled = measured.copy()
    for i, r in np.argwhere(rows):
        have = measured[i, r]
        for arr in (mean, u_ind, u_com):
            arr[i, r, ~have] = arr[i, r, have].mean(axis=0)
        filled[i, r] = True
    return mean, u_ind, u_com, filled


def directional_albedo(table: IsotropicTable) -> dict[str, np.ndarray]:
    """Per θi bin: ``rho`` (Nθi, 3), its standard uncertainty ``u`` (Nθi, 3), the measured
    fraction of the projected hemisphere ``covered`` (Nθi,), and the θi centres. Rows at the
    normal (θi or θr ≈ 0, no azimuth) count for every Δφ."""
    w = _projected_solid_angle(table)[None, :, :, None]
    mean, u_ind, u_com, filled = _azimuth_filled(table)
    measured = filled[..., None]
    rho = np.sum(np.where(measured, mean, 0.0) * w, axis=(1, 2))
    u_i = np.sqrt(np.sum(np.where(measured, u_ind, 0.0) ** 2 * w**2, axis=(1, 2)))
    u_c = np.sum(np.where(measured, u_com, 0.0) * w, axis=(1, 2))
    covered = np.sum(measured[..., 0] * w[..., 0], axis=(1, 2)) / np.pi
    return {"theta_i_deg": table.centers()[0], "rho": rho, "u": np.sqrt(u_i**2 + u_c**2),
            "covered": covered}


def energy(table: IsotropicTable) -> Check:
    """ρ(θi) ≤ 1 within :data:`Z_FAIL` of its uncertainty (module docstring)."""
    alb = directional_albedo(table)
    has = alb["covered"] > 0
    if not has.any():
        return Check("energy", None, "energy: no measured bin")
    rho, u = alb["rho"][has], alb["u"][has]
    with np.errstate(invalid="ignore", divide="ignore"):
        excess = (rho - 1.0) / u
    k = np.unravel_index(int(np.argmax(rho)), rho.shape)
    theta = float(alb["theta_i_deg"][has][k[0]])
    passed = not bool(np.any(excess > Z_FAIL))
    cov = alb["covered"][has]
    line = (f"energy: largest directional albedo ρ = {rho[k]:.3f} ± {u[k]:.2g} at θi {theta:g}° "
            f"({'RGB'[k[1]]}); the measured bins cover {cov.min():.0%}–{cov.max():.0%} of the "
            "projected hemisphere (ρ is a lower bound where not covered): "
            + ("pass" if passed else "FAIL, ρ > 1 beyond its uncertainty: the table reflects "
               "more light than it receives (check the white reference and exposure)"))
    return Check("energy", passed, line,
                 {"theta_i_deg": alb["theta_i_deg"][has], "rho": rho, "u": u, "covered": cov})


def coverage_and_snr(table: IsotropicTable) -> list[Check]:
    """Informational: measured bins and the SNR (mean / std_error) over them."""
    ti, tr, _ = np.meshgrid(*table.centers(), indexing="ij")
    above = (ti < 90) & (tr < 90)
    measured = table.count > 0
    n_meas, n_above = int((measured & above).sum()), int(above.sum())
    checks = [Check("coverage", None, f"coverage: {n_meas} of {n_above} bins above the horizon "
                                      f"measured ({n_meas / max(n_above, 1):.0%})",
                    {"measured": n_meas, "bins": n_above})]
    if table.tracks_uncertainty and measured.any():
        with np.errstate(invalid="ignore", divide="ignore"):
            snr = np.min(table.mean / table.std_error, axis=-1)[measured]
        k = int(np.argmin(snr))
        idx = tuple(np.argwhere(measured)[k])
        checks.append(Check("snr", None, f"SNR: median {np.median(snr):.3g}, lowest "
                                         f"{snr[k]:.3g} at {_where(table, idx)}",
                            {"median": float(np.median(snr)), "lowest": float(snr[k])}))
    return checks


def check_table(table: IsotropicTable) -> list[Check]:
    """Every check of a table (ConfigError when it has no uncertainty budget)."""
    if not table.tracks_uncertainty:
        raise ConfigError("the table has no per-bin uncertainty (a version-1 table?): reduce "
                          "the session again with `gonio reduce` to check it")
    return [reciprocity(table), energy(table), *coverage_and_snr(table)]
