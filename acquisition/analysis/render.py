"""Render a BRDF on a sphere under a distant point light (the report's lit sphere).

The sphere is seen orthographically from +z (the camera looks down −z); each pixel inside
the disk has the normal n = (x, y, √(1 − x² − y²)). With the light's unit direction ωl and the
view ωv = +z, the local angles are θi = ∠(n, ωl), θr = ∠(n, ωv) and Δφ the angle between
their projections on the tangent plane; the pixel's radiance is f(θi, θr, Δφ) · cos θi · E
with irradiance E = 1 (W·m⁻² on a surface facing the light): relative units, sr⁻¹ · W·m⁻².

A table is evaluated by :func:`table_brdf`: trilinear interpolation between bin centres at
the bins' mean angles' grid, each unmeasured bin filled from the nearest measured one.
"""

from __future__ import annotations

import numpy as np

from acquisition.formats.interpolate import Brdf, table_interpolant
from acquisition.tables import IsotropicTable

__all__ = ["Brdf", "render_sphere", "sphere_angles", "table_brdf"]


def table_brdf(table: IsotropicTable) -> Brdf:
    """A continuous BRDF from a table (module docstring); all zero for an empty table. The
    same interpolant :mod:`acquisition.formats.rgl` resamples into ``.bsdf`` files."""
    return table_interpolant(table)


def sphere_angles(size: int, light_dir: np.ndarray) -> tuple[np.ndarray, ...]:
    """(θi, θr, Δφ) in degrees and cos θi for every pixel of a ``size``² sphere image, and
    the mask of pixels on the sphere (NaN elsewhere)."""
    c = (np.arange(size) + 0.5) / size * 2.0 - 1.0
    x, y = np.meshgrid(c, -c)
    r2 = x * x + y * y
    on = r2 < 1.0
    n = np.stack([x, y, np.sqrt(np.clip(1.0 - r2, 0.0, 1.0))], axis=-1)
    light = np.asarray(light_dir, float) / np.linalg.norm(light_dir)
    view = np.array([0.0, 0.0, 1.0])
    cos_i = n @ light
    cos_r = n[..., 2]

    def tangent(w: np.ndarray) -> np.ndarray:
        t = w - (n @ w)[..., None] * n
        return t / np.maximum(np.linalg.norm(t, axis=-1, keepdims=True), 1e-12)

    cos_phi = np.clip(np.sum(tangent(light) * tangent(view), axis=-1), -1.0, 1.0)
    ti = np.degrees(np.arccos(np.clip(cos_i, -1.0, 1.0)))
    tr = np.degrees(np.arccos(np.clip(cos_r, -1.0, 1.0)))
    dp = np.degrees(np.arccos(cos_phi))
    return ti, tr, dp, cos_i, on


def render_sphere(brdf: Brdf, light_dir: np.ndarray, size: int = 160) -> np.ndarray:
    """Radiance image (size, size, 3) of a sphere of BRDF ``brdf`` lit from ``light_dir``
    (unit vector towards the light, camera at +z); 0 off the sphere and in shadow."""
    ti, tr, dp, cos_i, on = sphere_angles(size, light_dir)
    lit = on & (cos_i > 0) & (tr < 90)
    image = np.zeros((size, size, 3))
    image[lit] = brdf(ti[lit], tr[lit], dp[lit]) * cos_i[lit][:, None]
    return image
