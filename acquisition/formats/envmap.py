"""Lat-long environment maps; linear EXR input/output is :mod:`calibration.exr`'s.

Convention (sample frame, normal +z): row i of an (H, W) map is polar angle
θ = π (i + ½) / H from +z (top row = zenith), column j is azimuth φ = 2π (j + ½) / W from
+x towards +y. A pixel holds radiance (W·sr⁻¹·m⁻² or any linear unit) arriving *from* that
direction; its solid angle is the exact area of its latitude band cell,
Ω = (cos θ₀ − cos θ₁) · 2π / W (sr), so a map's Ω sum to 4π.
"""

from __future__ import annotations

import numpy as np

from calibration.exr import read_exr, write_exr

__all__ = ["latlong_directions", "read_exr", "write_exr"]


def latlong_directions(shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Unit directions (H, W, 3) of every pixel centre and their solid angles (H, W), sr."""
    h, w = shape
    theta = np.pi * (np.arange(h) + 0.5) / h
    phi = 2 * np.pi * (np.arange(w) + 0.5) / w
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    dirs = np.stack(np.broadcast_arrays(st * np.cos(phi), st * np.sin(phi), ct), axis=-1)
    edges = np.pi * np.arange(h + 1) / h
    band = (np.cos(edges[:-1]) - np.cos(edges[1:])) * 2 * np.pi / w
    return dirs, np.broadcast_to(band[:, None], (h, w)).copy()
