"""The pieces of the lecture's analytic BRDFs, vectorised over cosines and parameters.

Every function broadcasts its arguments (numpy), so a parameter may be a scalar or carry a
trailing colour axis. Angles enter as cosines; roughness α is the slope scale of the
microfacet distribution (GGX / Trowbridge–Reitz or Beckmann).

Normalisations (each checked by quadrature in the tests):

* microfacet distributions D: ∫ D(h) cos θh dωh = 1 (projected area);
* Phong lobe (e + 2)/(2π) · (ωr·ωo)^e: directional albedo 1 at normal incidence;
* Blinn-Phong lobe (e + 2)/(2π) · cos^e θh: the *half-vector distribution* is normalised
  (∫ lobe · cos θh dωh = 1), not the BRDF, whose directional albedo reaches ≈ 4 for large e —
  the fitter's bounds account for it (:mod:`acquisition.analysis.models.energy`).
"""

from __future__ import annotations

import numpy as np
from scipy.special import erf

_TINY = 1e-300
MASKING = ("separable", "height-correlated")
"""Smith masking–shadowing forms: G1(ωi)·G1(ωo), or 1 / (1 + Λ(ωi) + Λ(ωo))."""
DISTRIBUTIONS = ("ggx", "beckmann")
ON_A_CONSTANT = 0.3
"""The constant in the lecture's Oren–Nayar A (Oren & Nayar's 1994 paper print 0.33)."""


def _tan2(cos: np.ndarray) -> np.ndarray:
    c2 = np.clip(cos * cos, _TINY, 1.0)
    return (1.0 - c2) / c2


def ggx_d(cos_h: np.ndarray, alpha: np.ndarray | float) -> np.ndarray:
    """GGX (Trowbridge–Reitz) distribution α² / (π (cos²θh (α² − 1) + 1)²), sr⁻¹."""
    a2 = np.asarray(alpha, dtype=np.float64) ** 2
    c2 = cos_h * cos_h
    return np.where(cos_h > 0, a2 / (np.pi * (c2 * (a2 - 1.0) + 1.0) ** 2), 0.0)


def beckmann_d(cos_h: np.ndarray, alpha: np.ndarray | float) -> np.ndarray:
    """Beckmann distribution exp(−tan²θh / α²) / (π α² cos⁴θh), sr⁻¹."""
    a2 = np.asarray(alpha, dtype=np.float64) ** 2
    c = np.maximum(cos_h, _TINY)
    with np.errstate(over="ignore"):
        value = np.exp(-_tan2(c) / a2) / (np.pi * a2 * c**4)
    return np.where(cos_h > 0, value, 0.0)


def ggx_lambda(cos: np.ndarray, alpha: np.ndarray | float) -> np.ndarray:
    """Smith Λ of GGX: (−1 + √(1 + α² tan²θ)) / 2."""
    a2 = np.asarray(alpha, dtype=np.float64) ** 2
    return 0.5 * (np.sqrt(1.0 + a2 * _tan2(cos)) - 1.0)


def beckmann_lambda(cos: np.ndarray, alpha: np.ndarray | float) -> np.ndarray:
    """Smith Λ of Beckmann (exact): (erf(a) − 1)/2 + exp(−a²)/(2a√π), a = 1/(α tan θ)."""
    a = 1.0 / (np.asarray(alpha, dtype=np.float64) * np.sqrt(_tan2(cos)) + _TINY)
    with np.errstate(over="ignore", under="ignore"):
        return np.maximum(0.5 * (erf(a) - 1.0) + np.exp(-a * a) / (2.0 * a * np.sqrt(np.pi)), 0.0)


DISTRIBUTION_TERMS = {"ggx": (ggx_d, ggx_lambda), "beckmann": (beckmann_d, beckmann_lambda)}
"""Name → (D, Λ)."""


def smith_g(lam_i: np.ndarray, lam_o: np.ndarray, masking: str) -> np.ndarray:
    """Smith masking–shadowing from Λ(ωi), Λ(ωo) (:data:`MASKING`)."""
    if masking == "separable":
        return 1.0 / ((1.0 + lam_i) * (1.0 + lam_o))
    if masking == "height-correlated":
        return 1.0 / (1.0 + lam_i + lam_o)
    raise ValueError(f"masking must be one of {', '.join(MASKING)}, got {masking!r}")


def fresnel_schlick(cos_d: np.ndarray, f0: np.ndarray | float) -> np.ndarray:
    """Schlick's approximation f0 + (1 − f0)(1 − cos θd)⁵."""
    return f0 + (1.0 - np.asarray(f0, dtype=np.float64)) * (1.0 - np.clip(cos_d, 0.0, 1.0)) ** 5


def fresnel_dielectric(cos_d: np.ndarray, eta: np.ndarray | float) -> np.ndarray:
    """Unpolarised Fresnel reflectance of a smooth dielectric of relative index η (from the
    lecture: F = (ρ∥² + ρ⊥²)/2); total internal reflection (η < 1) gives 1."""
    eta = np.asarray(eta, dtype=np.float64)
    c1 = np.clip(cos_d, 0.0, 1.0)
    sin2_t = (1.0 - c1 * c1) / (eta * eta)
    c2 = np.sqrt(np.clip(1.0 - sin2_t, 0.0, 1.0))
    par = (eta * c1 - c2) / np.maximum(eta * c1 + c2, _TINY)
    perp = (c1 - eta * c2) / np.maximum(c1 + eta * c2, _TINY)
    return np.where(sin2_t >= 1.0, 1.0, 0.5 * (par * par + perp * perp))


def fresnel_conductor(cos_d: np.ndarray, eta: np.ndarray | float,
                      k: np.ndarray | float) -> np.ndarray:
    """Unpolarised Fresnel reflectance of a conductor with complex index η + ik (exact, from
    the complex form of the lecture's ρ∥, ρ⊥)."""
    n = np.asarray(eta, dtype=np.float64) + 1j * np.asarray(k, dtype=np.float64)
    c1 = np.clip(cos_d, 0.0, 1.0).astype(np.complex128)
    c2 = np.sqrt(1.0 - (1.0 - c1 * c1) / (n * n))
    par = (n * c1 - c2) / (n * c1 + c2)
    perp = (c1 - n * c2) / (c1 + n * c2)
    return 0.5 * (np.abs(par) ** 2 + np.abs(perp) ** 2)


def phong_lobe(cos_mirror: np.ndarray, e: np.ndarray | float) -> np.ndarray:
    """Normalised Phong lobe (e + 2)/(2π) · max(0, ωr·ωo)^e, sr⁻¹."""
    e = np.asarray(e, dtype=np.float64)
    return (e + 2.0) / (2.0 * np.pi) * np.maximum(cos_mirror, 0.0) ** e


def blinn_phong_lobe(cos_h: np.ndarray, e: np.ndarray | float) -> np.ndarray:
    """Blinn-Phong lobe (e + 2)/(2π) · max(0, cos θh)^e, sr⁻¹ (normalised as a half-vector
    distribution, see the module docstring)."""
    e = np.asarray(e, dtype=np.float64)
    return (e + 2.0) / (2.0 * np.pi) * np.maximum(cos_h, 0.0) ** e


def oren_nayar(cos_i: np.ndarray, cos_o: np.ndarray, cos_dphi: np.ndarray,
               sigma_rad: np.ndarray | float) -> np.ndarray:
    """The lecture's Oren–Nayar factor A + B·max(0, cos(φi − φo))·sin α·tan β (multiply by
    ρ/π), α = max(θi, θo), β = min(θi, θo), σ the facet slope deviation in radians, with the
    lecture's A = 1 − σ²/(2(σ² + 0.3)) and B = 0.45σ²/(σ² + 0.09)."""
    s2 = np.asarray(sigma_rad, dtype=np.float64) ** 2
    a = 1.0 - s2 / (2.0 * (s2 + ON_A_CONSTANT))
    b = 0.45 * s2 / (s2 + 0.09)
    ti = np.arccos(np.clip(cos_i, -1.0, 1.0))
    to = np.arccos(np.clip(cos_o, -1.0, 1.0))
    alpha, beta = np.maximum(ti, to), np.minimum(ti, to)
    return a + b * np.maximum(cos_dphi, 0.0) * np.sin(alpha) * np.tan(beta)


def microfacet(cos_i: np.ndarray, cos_o: np.ndarray, cos_h: np.ndarray,
               fresnel: np.ndarray, alpha: np.ndarray | float, distribution: str,
               masking: str) -> np.ndarray:
    """Cook–Torrance specular term D·G·F / (4 cos θi cos θo), sr⁻¹ (0 below the horizon)."""
    d_fn, lam_fn = DISTRIBUTION_TERMS[distribution]
    ci, co = np.maximum(cos_i, _TINY), np.maximum(cos_o, _TINY)
    g = smith_g(lam_fn(ci, alpha), lam_fn(co, alpha), masking)
    value = d_fn(cos_h, alpha) * g * fresnel / (4.0 * ci * co)
    return np.where((cos_i > 0) & (cos_o > 0), value, 0.0)
