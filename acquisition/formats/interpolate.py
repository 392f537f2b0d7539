"""A continuous BRDF from an isotropic table: what gonio renders (the report's lit sphere) and
what it writes into formats that need values between bins (RGL ``.bsdf``).

Trilinear interpolation between bin centres; each unmeasured bin takes the value of the
nearest measured one (Euclidean distance in bin indices) first; angles beyond the outer bin
centres take the outer centres' values; negative results are clipped to 0.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from acquisition.tables import IsotropicTable

Brdf = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]
"""(θi, θr, Δφ) in degrees (arrays of one shape) → (…, 3) sr⁻¹."""


def table_interpolant(table: IsotropicTable) -> Brdf:
    """The table's continuous BRDF (module docstring); all zero for an empty table."""
    from scipy.interpolate import RegularGridInterpolator
    from scipy.ndimage import distance_transform_edt

    mean = table.mean
    measured = table.count > 0
    if not measured.any():
        return lambda ti, tr, dp: np.zeros(np.shape(ti) + (3,))
    idx = distance_transform_edt(~measured, return_distances=False, return_indices=True)
    filled = mean[tuple(idx)]
    axes = table.centers()
    interp = RegularGridInterpolator(axes, filled, method="linear", bounds_error=False,
                                     fill_value=None)

    def evaluate(ti: np.ndarray, tr: np.ndarray, dp: np.ndarray) -> np.ndarray:
        pts = np.stack(np.broadcast_arrays(ti, tr, table.normalise_delta_phi(dp)), axis=-1)
        for k, ax in enumerate(axes):
            pts[..., k] = np.clip(pts[..., k], ax[0], ax[-1])
        return np.maximum(interp(pts.reshape(-1, 3)).reshape(pts.shape), 0.0)

    return evaluate
