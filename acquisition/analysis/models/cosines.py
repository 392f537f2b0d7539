"""The cosines an analytic BRDF needs, from isotropic angles (θi, θr, Δφ) in degrees.

Computed from the angles with spherical trigonometry (no direction vectors):

* cos 2θd = ωi·ωo = cos θi cos θr + sin θi sin θr cos Δφ;
* cos θd = √((1 + ωi·ωo) / 2) (θd: angle between ωi and the half vector);
* cos θh = (cos θi + cos θr) / (2 cos θd) (θh: half vector from the normal);
* ωr·ωo = cos θi cos θr − sin θi sin θr cos Δφ, with ωr the mirror direction of ωi.

The light sits at azimuth 0 and the view at Δφ, so Δφ = 180° with θi = θr is the mirror pose.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

_TINY = 1e-300


@dataclass(frozen=True)
class Cosines:
    """Cosines of one or many (θi, θr, Δφ) configurations (arrays of one shape)."""

    cos_i: np.ndarray
    cos_o: np.ndarray
    sin_i: np.ndarray
    sin_o: np.ndarray
    cos_dphi: np.ndarray
    cos_h: np.ndarray
    """cos θh, the half vector's angle from the normal."""
    cos_d: np.ndarray
    """cos θd = ωi·h = ωo·h."""
    cos_mirror: np.ndarray
    """ωr·ωo: cosine between the view and the light's mirror direction."""

    @classmethod
    def of(cls, theta_i_deg: np.ndarray | float, theta_r_deg: np.ndarray | float,
           delta_phi_deg: np.ndarray | float) -> Cosines:
        ti, tr, dp = (np.radians(np.asarray(a, dtype=np.float64))
                      for a in np.broadcast_arrays(theta_i_deg, theta_r_deg, delta_phi_deg))
        ci, co, si, so, cdp = np.cos(ti), np.cos(tr), np.sin(ti), np.sin(tr), np.cos(dp)
        in_out = ci * co + si * so * cdp
        cos_d = np.sqrt(np.clip(0.5 * (1.0 + in_out), 0.0, 1.0))
        cos_h = np.clip((ci + co) / np.maximum(2.0 * cos_d, _TINY), -1.0, 1.0)
        return cls(ci, co, si, so, cdp, cos_h, cos_d, ci * co - si * so * cdp)

    @property
    def above(self) -> np.ndarray:
        """True where both directions lie above the surface (cos > 0)."""
        return (self.cos_i > 0) & (self.cos_o > 0)
