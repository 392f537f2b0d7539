"""Energy bounds of the analytic lobes: the largest directional albedo over θi, by quadrature.

The directional albedo of a BRDF at incidence θi is ρ(θi) = ∫ f(ωi, ωo) cos θo dωo over the
upper hemisphere, dω = sin θ dθ dφ. Energy conservation asks ρ(θi) ≤ 1 for every θi. The
fitter keeps every model inside that region by construction: each specular lobe's weight is
bounded by its *largest* albedo over θi, and the diffuse albedo gets the room the lobes leave
(:mod:`acquisition.analysis.models.library`). This module computes those largest albedos.

Quadratures (Gauss–Legendre, numpy; radians inside):

* microfacet lobes and Blinn-Phong in half-vector space, dωo = 4 (ωo·h) dωh, with
  θh = atan(s·x), x = t/(1 − t) so the nodes follow the lobe's width s (α, or √(2/(e + 2)));
* Phong about the mirror direction ωr (the lobe depends on ωr·ωo only);
* Oren–Nayar over ωo directly (the factor is smooth).

A microfacet lobe's albedo is linear in its Fresnel term F(cos θd), so it is tabulated once per
(distribution, masking) against a hat-function basis on cos θd ∈ [0, 1]: any Fresnel law then
costs one dot product. Largest values are taken over a grid of θi and of the shape parameter
(interpolated linearly between the two neighbouring nodes, in log for roughness and exponents,
so the bound moves smoothly with the parameter and a fit does not stick to the nodes), then
raised by :data:`MARGIN`; the tests check the bounds against an independent quadrature in ωo
space.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import numpy as np

from acquisition.analysis.models import terms

MARGIN = 1.01
"""Relative safety factor on every tabulated largest albedo (grid and quadrature error)."""
THETA_I_GRID_DEG = np.concatenate([np.arange(0.0, 88.0, 2.0), [88.0, 89.0, 89.5, 89.9]])
"""Incidence angles over which the largest albedo is taken, degrees."""
ALPHA_GRID = np.geomspace(0.005, 1.0, 49)
"""Roughness nodes of the microfacet tables (the fitter's α lies within them)."""
EXPONENT_GRID = np.geomspace(0.25, 40000.0, 61)
"""Phong / Blinn-Phong exponent nodes (the fitter's e lies within them)."""
SIGMA_GRID_DEG = np.linspace(0.0, 90.0, 46)
"""Oren–Nayar σ nodes, degrees."""
FRESNEL_NODES = np.linspace(0.0, 1.0, 33)
"""cos θd nodes of the hat basis a microfacet lobe's Fresnel term is expanded on."""

_N_RADIAL = 96
_N_AZIMUTH = 64


def _gauss(n: int, lo: float, hi: float) -> tuple[np.ndarray, np.ndarray]:
    x, w = np.polynomial.legendre.leggauss(n)
    half = 0.5 * (hi - lo)
    return lo + half * (x + 1.0), half * w


def _lobe_nodes(width: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Nodes (θ, φ) and weights (including sin θ) over a hemisphere about a lobe's axis, dense
    within ``width`` of it: θ = atan(width·t/(1 − t)), φ ∈ [0, π] (mirror symmetry, ×2)."""
    t, wt = _gauss(_N_RADIAL, 0.0, 1.0)
    x = t / (1.0 - t)
    theta = np.arctan(width * x)
    dtheta = width / (1.0 + (width * x) ** 2) / (1.0 - t) ** 2 * wt
    phi, wphi = _gauss(_N_AZIMUTH, 0.0, np.pi)
    th, ph = np.meshgrid(theta, phi, indexing="ij")
    weight = np.outer(dtheta * np.sin(theta), 2.0 * wphi)
    return th.ravel(), ph.ravel(), weight.ravel(), np.cos(th).ravel()


def _half_vector_terms(theta_i: np.ndarray, width: float
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """For each θi (rad) × quadrature node of h: cos θh, cos θd, cos θo, the weight
    dωo = 4 cos θd dωh (zero where ωo is below the horizon), and cos θi."""
    th, ph, w, cos_h = _lobe_nodes(width)
    ci = np.cos(theta_i)[:, None]
    si = np.sin(theta_i)[:, None]
    cos_d = si * np.sin(th) * np.cos(ph) + ci * cos_h
    cos_o = 2.0 * cos_d * cos_h - ci
    ok = (cos_d > 0) & (cos_o > 0)
    weight = np.where(ok, 4.0 * cos_d * w, 0.0)
    return np.broadcast_to(cos_h, cos_d.shape), cos_d, np.where(ok, cos_o, 0.0), weight, ci


def _project_on_hats(integrand: np.ndarray, cos_d: np.ndarray) -> np.ndarray:
    """Σ over nodes of ``integrand`` × each hat function of cos θd on :data:`FRESNEL_NODES`:
    (rows, nodes) → (rows, J)."""
    n_hat = FRESNEL_NODES.size
    u = np.clip(cos_d, 0.0, 1.0) * (n_hat - 1)
    j = np.minimum(u.astype(int), n_hat - 2)
    frac = u - j
    rows = np.arange(integrand.shape[0])[:, None] * n_hat
    size = integrand.shape[0] * n_hat
    low = np.bincount((rows + j).ravel(), (integrand * (1.0 - frac)).ravel(), size)
    high = np.bincount((rows + j + 1).ravel(), (integrand * frac).ravel(), size)
    return (low + high).reshape(integrand.shape[0], n_hat)


@functools.lru_cache(maxsize=8)
def microfacet_basis(distribution: str, masking: str) -> np.ndarray:
    """K[α node, θi node, j]: directional albedo of D·G·F/(4 cos θi cos θo) for F = the j-th
    hat function of cos θd, so that ρ(θi) = Σ_j F(c_j) K[…, j]."""
    d_fn, lam_fn = terms.DISTRIBUTION_TERMS[distribution]
    theta_i = np.radians(THETA_I_GRID_DEG)
    out = np.empty((ALPHA_GRID.size, theta_i.size, FRESNEL_NODES.size))
    for a, alpha in enumerate(ALPHA_GRID):
        cos_h, cos_d, cos_o, weight, ci = _half_vector_terms(theta_i, float(alpha))
        g = terms.smith_g(lam_fn(ci, alpha), lam_fn(np.maximum(cos_o, 1e-300), alpha), masking)
        # f cos θo dωo = D G F / (4 cos θi cos θo) · cos θo · 4 cos θd dωh
        integrand = d_fn(cos_h, alpha) * g / (4.0 * ci) * weight
        out[a] = _project_on_hats(integrand, cos_d)
    return out


def _largest_over_nodes(grid: np.ndarray, values_at_nodes: Callable[[int], np.ndarray],
                        x: float, *, log: bool = True) -> np.ndarray:
    """MARGIN × a tabulated quantity interpolated linearly (in log x where ``log``) between
    the two grid nodes around x (clamped to the grid's ends)."""
    k = int(np.clip(np.searchsorted(grid, x), 1, grid.size - 1))
    a, b = (np.log(grid[k - 1]), np.log(grid[k])) if log else (grid[k - 1], grid[k])
    u = float(np.clip(((np.log(x) if log else x) - a) / (b - a), 0.0, 1.0))
    return MARGIN * ((1.0 - u) * values_at_nodes(k - 1) + u * values_at_nodes(k))


def microfacet_max_albedo(distribution: str, masking: str, alpha: float,
                          fresnel_at_nodes: np.ndarray) -> np.ndarray:
    """Largest directional albedo over θi of one microfacet lobe of roughness ``alpha`` whose
    Fresnel term takes the values ``fresnel_at_nodes`` (…, J) at :data:`FRESNEL_NODES`."""
    basis = microfacet_basis(distribution, masking)
    f = np.asarray(fresnel_at_nodes, dtype=np.float64)
    return _largest_over_nodes(ALPHA_GRID, lambda k: np.max(f @ basis[k].T, axis=-1), alpha)


@functools.lru_cache(maxsize=4)
def _exponent_table(kind: str) -> np.ndarray:
    """Largest directional albedo over θi of the unit ``"phong"`` or ``"blinn-phong"`` lobe
    at each node of :data:`EXPONENT_GRID`."""
    theta_i = np.radians(THETA_I_GRID_DEG)
    out = np.empty(EXPONENT_GRID.size)
    for n, e in enumerate(EXPONENT_GRID):
        width = float(np.sqrt(2.0 / (e + 2.0)))
        if kind == "blinn-phong":  # over half vectors h
            cos_h, _, cos_o, weight, _ = _half_vector_terms(theta_i, width)
            value = terms.blinn_phong_lobe(cos_h, e) * cos_o * weight
        else:  # over directions at angle a from the mirror direction ωr, azimuth p about it
            a, p, w, cos_a = _lobe_nodes(width)
            ci, si = np.cos(theta_i)[:, None], np.sin(theta_i)[:, None]
            cos_o = ci * cos_a + si * np.sin(a) * np.cos(p)
            value = terms.phong_lobe(cos_a, e) * np.maximum(cos_o, 0.0) * w
        out[n] = np.max(np.sum(value, axis=-1))
    return out


def blinn_phong_max_albedo(e: float) -> float:
    """Largest directional albedo over θi of the unit Blinn-Phong lobe of exponent ``e``."""
    table = _exponent_table("blinn-phong")
    return float(_largest_over_nodes(EXPONENT_GRID, lambda k: table[k], e))


def phong_max_albedo(e: float) -> float:
    """Largest directional albedo over θi of the unit (normalised) Phong lobe of exponent e."""
    table = _exponent_table("phong")
    return float(_largest_over_nodes(EXPONENT_GRID, lambda k: table[k], e))


@functools.lru_cache(maxsize=2)
def _oren_nayar_table() -> np.ndarray:
    theta_i = np.radians(THETA_I_GRID_DEG)
    to, wo = _gauss(64, 0.0, np.pi / 2)
    po, wp = _gauss(64, 0.0, np.pi)
    t, p = np.meshgrid(to, po, indexing="ij")
    w = np.outer(wo * np.sin(to) * np.cos(to), 2.0 * wp).ravel()
    cos_o, cos_p = np.cos(t).ravel(), np.cos(p).ravel()
    out = np.empty(SIGMA_GRID_DEG.size)
    for n, sigma in enumerate(np.radians(SIGMA_GRID_DEG)):
        factor = terms.oren_nayar(np.cos(theta_i)[:, None], cos_o, cos_p, sigma)
        out[n] = np.max(np.sum(factor / np.pi * w, axis=-1))
    return out


def oren_nayar_max_albedo(sigma_deg: float) -> float:
    """Largest directional albedo over θi of Oren–Nayar with ρ = 1 and slope deviation σ."""
    table = _oren_nayar_table()
    return float(_largest_over_nodes(SIGMA_GRID_DEG, lambda k: table[k], sigma_deg, log=False))
