"""Absolute scale from a diffuse white reference (e.g. Spectralon, ρ ≈ 0.99).

A pixel value is proportional to the radiance ``L = f · E`` with the point light's irradiance
``E = I cos θi / r²``. Measuring a Lambertian reference of reflectance ρ (``f = ρ/π``) by the
same pipeline at incidence θi_ref and light distance r_ref gives, for a sample signal S,

    f = (S / S_ref) · (ρ / π) · (cos θi_ref / cos θi) · (r² / r_ref²)     [sr⁻¹]

per colour. Relative variances of S and S_ref add (the reflectance's own uncertainty is a
calibration constant, kept in the bundle's provenance, not in per-bin variances).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from calibration.linearize import LinearImage, roi_mean
from drivers.errors import CalibrationError


@dataclass(frozen=True)
class WhiteReference:
    """The white reference as measured.

    Attributes
    ----------
    signal:
        (3,) ROI mean of the reference, in the images' units (e.g. DN/s).
    variance:
        (3,) variance of that mean (units²).
    reflectance:
        (3,) directional-hemispherical reflectance ρ per colour.
    theta_i_deg:
        Incidence on the reference, deg.
    light_distance_m:
        Light-to-reference distance, m; None when it equals the sample's.
    units:
        Units of ``signal``.
    """

    signal: np.ndarray
    variance: np.ndarray
    reflectance: np.ndarray
    theta_i_deg: float
    light_distance_m: float | None = None
    units: str = "DN/s"

    def brdf(
        self,
        signal: np.ndarray,
        variance: np.ndarray,
        theta_i_deg: float,
        *,
        light_distance_m: float | None = None,
        reference_signal: np.ndarray | None = None,
        reference_variance: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """BRDF (sr⁻¹) and its variance (sr⁻²) of a sample signal at incidence ``theta_i_deg``.

        ``reference_signal``/``reference_variance`` override the stored reference (e.g. the
        reference interpolated in time to correct light drift); ``light_distance_m`` applies
        the 1/r² correction when both distances are known.
        """
        cos_i = math.cos(math.radians(theta_i_deg))
        if not cos_i > 1e-9:
            raise CalibrationError(f"incidence {theta_i_deg}° is at or below the horizon")
        ref = self.signal if reference_signal is None else np.asarray(reference_signal, float)
        ref_var = self.variance if reference_variance is None else np.asarray(reference_variance, float)
        factor = self.reflectance / math.pi * math.cos(math.radians(self.theta_i_deg)) / cos_i
        if light_distance_m is not None and self.light_distance_m is not None:
            factor = factor * (light_distance_m / self.light_distance_m) ** 2
        s = np.asarray(signal, float)
        f = s / ref * factor
        var = f**2 * (np.asarray(variance, float) / s**2 + ref_var / ref**2)
        return f, var

    def to_dict(self) -> dict[str, Any]:
        """Plain scalars for a calibration bundle."""
        return {
            "signal": [float(v) for v in self.signal],
            "variance": [float(v) for v in self.variance],
            "reflectance": [float(v) for v in self.reflectance],
            "theta_i_deg": float(self.theta_i_deg),
            "light_distance_m": self.light_distance_m,
            "units": self.units,
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> WhiteReference:
        """Inverse of :meth:`to_dict` (extra keys such as provenance are ignored)."""
        return cls(
            signal=np.asarray(d["signal"], float),
            variance=np.asarray(d["variance"], float),
            reflectance=np.asarray(d["reflectance"], float),
            theta_i_deg=float(d["theta_i_deg"]),
            light_distance_m=d.get("light_distance_m"),
            units=str(d.get("units", "DN/s")),
        )


def measure_white(
    images: Sequence[LinearImage],
    roi: tuple[int, int, int, int],
    reflectance: float | Sequence[float],
    theta_i_deg: float,
    light_distance_m: float | None = None,
) -> WhiteReference:
    """Average the ROI (x, y, width, height superpixels) of one or more reference images.

    Raises
    ------
    CalibrationError
        No image, mixed units, or an ROI with no valid (unsaturated) superpixel.
    """
    if not images:
        raise CalibrationError("white reference: no image given")
    units = {im.units for im in images}
    if len(units) != 1:
        raise CalibrationError(f"white reference images mix units {sorted(units)}")
    rho = np.broadcast_to(np.asarray(reflectance, float), (3,)).copy()
    if np.any(rho <= 0) or np.any(rho > 1):
        raise CalibrationError(f"white reference reflectance {rho} must lie in (0, 1]")
    means, variances = [], []
    for im in images:
        mean, var, n = roi_mean(im, roi)
        if n == 0:
            raise CalibrationError(
                f"{im.path}: the white reference is saturated everywhere in the ROI; shorten "
                "the exposure"
            )
        means.append(mean)
        variances.append(var)
    k = len(images)
    signal = np.mean(means, axis=0)
    variance = np.sum(variances, axis=0) / k**2
    return WhiteReference(signal, variance, rho, float(theta_i_deg), light_distance_m,
                          images[0].units)
