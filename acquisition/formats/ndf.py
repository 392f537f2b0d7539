"""Isotropic microfacet distributions D(θm) for the RGL ``.bsdf`` parameterisation, and their
projected area σ(θ) = ∫ ⟨ω, m⟩⁺ D(m) dm.

The RGL format (Dupuy & Jakob 2018) reparameterises a BRDF by the visible normals of a
microfacet distribution: D only shapes the grid (the BRDF's values are kept exactly at the
grid's nodes), so it need not be the material's true D, only close to it. gonio takes it, as
the RGL pipeline does, from the BRDF's retro-reflection: for a microfacet BRDF
f(ω, ω) = F(0) D(ω) G1(ω) / (4 cos² θ) with G1 = cos θ / σ, so D(ω) ∝ f(ω, ω) cos θ σ(ω),
solved by fixed-point iteration since σ depends on D. A gonioreflectometer's shadow cone
removes true retro-reflection (the camera would block the light), so a table's f(ω, ω) is its
interpolant extrapolated from the nearest measured near-retro bins. (A fitted model's D —
GGX α from ``gonio fit`` — was tried as well: it leaves out the diffuse part of the BRDF, so
the grid is too sparse away from the specular lobe and the resampled values are less
accurate; a caller may still pass any :class:`Ndf` to :func:`acquisition.formats.rgl.write_bsdf`.)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from acquisition.formats.interpolate import Brdf

FLOOR = 1e-4
"""Smallest D kept, relative to the largest: the grid must reach every direction."""
_QUADRATURE = 2048
RETRO_LABEL = "from the BRDF's retro-reflection"
MIN_KNOWN = 0.25
"""Fraction of the retro-reflection profile that must be known (finite, > 0); the gaps are
interpolated in θ."""


@dataclass(frozen=True)
class Ndf:
    """D sampled at θm = u² · 90° for u = k / (n − 1), normalised so ∫ D cos θm dm = 1."""

    values_per_sr: np.ndarray
    source: str
    """Where D comes from, for the file's description."""
    label: str = ""
    """The same in a few words, for ``gonio export``'s line."""

    @property
    def u(self) -> np.ndarray:
        return np.linspace(0.0, 1.0, self.values_per_sr.size)

    def __call__(self, theta_m_rad: np.ndarray) -> np.ndarray:
        """D at θm (radians), linear in u between the nodes as the renderer interpolates it."""
        u = np.sqrt(np.clip(np.asarray(theta_m_rad, float), 0.0, np.pi / 2) / (np.pi / 2))
        return np.interp(u, self.u, self.values_per_sr)

    def sigma(self, theta_rad: np.ndarray) -> np.ndarray:
        """Projected area σ(θ) = ∫ ⟨ω, m⟩⁺ D(m) dm of the microsurface seen from θ."""
        theta = np.asarray(theta_rad, float)
        tm = (np.linspace(0.0, 1.0, _QUADRATURE) ** 2) * (np.pi / 2)
        a = np.cos(theta)[..., None] * np.cos(tm)
        b = np.sin(theta)[..., None] * np.sin(tm)
        with np.errstate(invalid="ignore", divide="ignore"):
            partial = 2.0 * (a * np.arccos(np.clip(-a / b, -1.0, 1.0))
                             + np.sqrt(np.maximum(b * b - a * a, 0.0)))
        azimuthal = np.where(b <= np.abs(a), 2.0 * np.pi * np.maximum(a, 0.0), partial)
        y = self(tm) * np.sin(tm) * azimuthal
        return 0.5 * ((y[..., 1:] + y[..., :-1]) * np.diff(tm)).sum(axis=-1)


def _normalised(values: np.ndarray, source: str, label: str) -> Ndf:
    values = np.maximum(np.nan_to_num(values, nan=0.0, posinf=0.0), 0.0)
    if not values.any():
        values = np.ones_like(values)
    values = np.maximum(values, FLOOR * values.max())
    ndf = Ndf(values, source, label)
    return Ndf(values / float(ndf.sigma(np.array(0.0))), source, label)


def retro_ndf(brdf: Brdf, nodes: int = 64, iterations: int = 12) -> Ndf:
    """D from the BRDF's retro-reflection, D ∝ f(ω, ω) cos θ σ(ω) (module docstring); the
    channels' mean f is used, NaN (unmeasured) values are interpolated over."""
    tm = np.linspace(0.0, 1.0, nodes) ** 2 * (np.pi / 2)
    deg = np.degrees(tm)
    retro = np.asarray(brdf(deg, deg, np.zeros_like(deg)), float).mean(axis=-1)
    known = np.isfinite(retro) & (retro > 0)
    if known.sum() < MIN_KNOWN * nodes:  # no usable retro-reflection: a uniform D
        return _normalised(np.ones(nodes), "uniform (the BRDF has too little retro-reflection "
                                           "data to derive one)",
                           "uniform (too little retro-reflection data)")
    shape = np.interp(tm, tm[known], retro[known]) * np.cos(tm)
    source = ("retro-reflection f(w, w) of the BRDF, D proportional to f(w, w) cos(theta) "
              "sigma(w) by fixed-point iteration (a gonio table's f(w, w) is its interpolant, "
              "extrapolated from the nearest measured near-retro bins: the shadow cone hides "
              "true retro-reflection)")
    label = RETRO_LABEL
    ndf = _normalised(shape, source, label)
    for _ in range(iterations):
        ndf = _normalised(shape * ndf.sigma(tm), source, label)
    return ndf
