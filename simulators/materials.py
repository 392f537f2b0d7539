"""Reference materials with known BRDFs, for the simulated camera and for checking results.

Every material is a callable ``material(theta_i_deg, theta_r_deg, delta_phi_deg)`` returning
the BRDF in sr⁻¹ with a trailing RGB axis, and offers :meth:`Material.eval_vectors` for unit
light/view vectors in the sample's frame (normal +z). Build one from a spec string with
:func:`material_from_spec`::

    lambert:albedo=0.5
    ggx:albedo=0.2,alpha=0.3,f0=0.04
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from drivers.errors import MaterialError


def directions_from_angles(
    theta_i_deg: np.ndarray | float, theta_r_deg: np.ndarray | float, delta_phi_deg: np.ndarray | float
) -> tuple[np.ndarray, np.ndarray]:
    """Unit light and view vectors (…, 3) for isotropic coordinates in degrees.

    The light lies in the x–z plane at azimuth 0; the view is at azimuth Δφ, so Δφ = 180° with
    θi = θr is the mirror configuration.
    """
    ti, tr, dp = np.broadcast_arrays(
        np.radians(theta_i_deg), np.radians(theta_r_deg), np.radians(delta_phi_deg)
    )
    wi = np.stack([np.sin(ti), np.zeros_like(ti), np.cos(ti)], axis=-1)
    wo = np.stack([np.sin(tr) * np.cos(dp), np.sin(tr) * np.sin(dp), np.cos(tr)], axis=-1)
    return wi, wo


class Material(ABC):
    """An isotropic BRDF in sr⁻¹ (not cosine-weighted), RGB."""

    spec: str

    @abstractmethod
    def eval_vectors(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """BRDF (…, 3) in sr⁻¹ for unit light ``wi`` and view ``wo`` vectors (…, 3), normal +z.

        Directions below the horizon give 0.
        """

    def __call__(
        self,
        theta_i_deg: np.ndarray | float,
        theta_r_deg: np.ndarray | float,
        delta_phi_deg: np.ndarray | float,
    ) -> np.ndarray:
        """BRDF (…, 3) in sr⁻¹ at (θi, θr, Δφ) in degrees."""
        wi, wo = directions_from_angles(theta_i_deg, theta_r_deg, delta_phi_deg)
        return self.eval_vectors(wi, wo)


def _above_horizon(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    return (wi[..., 2] > 0) & (wo[..., 2] > 0)


@dataclass(frozen=True)
class Lambert(Material):
    """Ideal diffuse reflector: f = albedo / π."""

    albedo: float

    @property
    def spec(self) -> str:  # type: ignore[override]
        return f"lambert:albedo={self.albedo:g}"

    def eval_vectors(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        value = np.where(_above_horizon(wi, wo), self.albedo / np.pi, 0.0)
        return np.repeat(value[..., None], 3, axis=-1)


@dataclass(frozen=True)
class GGX(Material):
    """Lambertian base plus a GGX microfacet specular lobe.

    f = albedo/π + D·G·F / (4 cosθi cosθr) with the GGX distribution D of roughness
    ``alpha``, the separable Smith G = G1(l)·G1(v) and Schlick's Fresnel with ``f0``.
    """

    albedo: float
    alpha: float
    f0: float

    @property
    def spec(self) -> str:  # type: ignore[override]
        return f"ggx:albedo={self.albedo:g},alpha={self.alpha:g},f0={self.f0:g}"

    def eval_vectors(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        a2 = self.alpha**2
        cos_i = wi[..., 2]
        cos_o = wo[..., 2]
        ok = _above_horizon(wi, wo)
        h = wi + wo
        h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
        n_h = h[..., 2]
        h_l = np.clip(np.sum(h * wi, axis=-1), 0.0, 1.0)
        d = a2 / (np.pi * (n_h**2 * (a2 - 1.0) + 1.0) ** 2)

        def g1(c: np.ndarray) -> np.ndarray:
            c = np.maximum(c, 1e-12)
            return 2.0 * c / (c + np.sqrt(a2 + (1.0 - a2) * c**2))

        g = g1(cos_i) * g1(cos_o)
        f = self.f0 + (1.0 - self.f0) * (1.0 - h_l) ** 5
        with np.errstate(divide="ignore", invalid="ignore"):
            spec = d * g * f / (4.0 * cos_i * cos_o)
        value = np.where(ok, self.albedo / np.pi + np.where(ok, spec, 0.0), 0.0)
        return np.repeat(value[..., None], 3, axis=-1)


def _parse_params(model: str, text: str, required: tuple[str, ...]) -> dict[str, float]:
    params: dict[str, float] = {}
    for item in filter(None, (p.strip() for p in text.split(","))):
        key, sep, raw = item.partition("=")
        if not sep:
            raise MaterialError(f"material '{model}': parameter '{item}' is not key=value")
        try:
            params[key.strip()] = float(raw)
        except ValueError:
            raise MaterialError(f"material '{model}': {key.strip()}='{raw}' is not a number") from None
    unknown = set(params) - set(required)
    missing = set(required) - set(params)
    if unknown or missing:
        raise MaterialError(
            f"material '{model}' takes {', '.join(required)}"
            + (f"; unknown: {', '.join(sorted(unknown))}" if unknown else "")
            + (f"; missing: {', '.join(sorted(missing))}" if missing else "")
        )
    return params


def _lambert(text: str) -> Material:
    p = _parse_params("lambert", text, ("albedo",))
    if not 0 <= p["albedo"] <= 1:
        raise MaterialError(f"lambert: albedo must lie in [0, 1], got {p['albedo']}")
    return Lambert(p["albedo"])


def _ggx(text: str) -> Material:
    p = _parse_params("ggx", text, ("albedo", "alpha", "f0"))
    if not (0 <= p["albedo"] <= 1 and 0 < p["alpha"] <= 1 and 0 <= p["f0"] <= 1):
        raise MaterialError(
            "ggx: need 0 ≤ albedo ≤ 1, 0 < alpha ≤ 1, 0 ≤ f0 ≤ 1; "
            f"got albedo={p['albedo']}, alpha={p['alpha']}, f0={p['f0']}"
        )
    return GGX(p["albedo"], p["alpha"], p["f0"])


MATERIAL_PARSERS: dict[str, Callable[[str], Material]] = {"lambert": _lambert, "ggx": _ggx}
"""Spec prefix → parser of the text after the colon. Other modules may register more."""


def material_from_spec(spec: str) -> Material:
    """Parse ``model:key=value,...`` into a :class:`Material`; raises :class:`MaterialError`."""
    model, _, rest = spec.strip().partition(":")
    parser = MATERIAL_PARSERS.get(model.strip().lower())
    if parser is None:
        raise MaterialError(
            f"unknown material '{spec}': use one of "
            + ", ".join(f"{name}:..." for name in MATERIAL_PARSERS)
            + " (e.g. lambert:albedo=0.5)"
        )
    return parser(rest)


from simulators import material_models  # noqa: E402, F401  (registers the analytic models' specs)
