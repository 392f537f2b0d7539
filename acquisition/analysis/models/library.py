"""The lecture's BRDF models, ready to evaluate and fit (angles in degrees at the API).

=================  ==============================================================  ==========
name               f(ωi, ωo), sr⁻¹                                                  parameters
=================  ==============================================================  ==========
``lambert``        ρ/π                                                              albedo
``oren-nayar``     ρ/π · (A + B max(0, cos Δφ) sin α tan β)                         albedo, sigma_deg
``phong``          ρ/π + Σ ks · (e + 2)/(2π) (ωr·ωo)^e                              albedo, ks, e
``blinn-phong``    ρ/π + Σ ks · (e + 2)/(2π) cos^e θh                               albedo, ks, e
``ggx``            ρ/π + D G F / (4 cos θi cos θo), GGX D                           albedo, alpha, f0
``beckmann``       as ``ggx`` with Beckmann's D and Λ                               albedo, alpha, f0
=================  ==============================================================  ==========

Microfacet (Cook–Torrance) models take ``masking`` (Smith, ``separable`` — the ``ggx:``
material's form — or ``height-correlated``) and ``fresnel``: ``schlick`` (f0 per channel),
``dielectric`` (exact, real index ``eta``) or ``conductor`` (exact, complex index
``eta`` + i ``k`` per channel). ``lobes=2`` adds a second specular lobe: ``ks2``, ``e2`` for
the Phong family, ``alpha2`` and the mixing fraction ``mix`` for microfacets (the lobes share
the Fresnel term: f_s = (1 − mix)·M(α) + mix·M(α2)).

Every model is reciprocal, and keeps ρ(θi) ≤ 1 everywhere inside its fit box: the lobes take
at most the room :mod:`~acquisition.analysis.models.energy` proves they may, and the diffuse
albedo the room they leave.
"""

from __future__ import annotations

import numpy as np

from acquisition.analysis.models import energy, terms
from acquisition.analysis.models.base import Model, Param, Values, rgb, spec_value
from acquisition.analysis.models.cosines import Cosines

MODEL_NAMES = ("lambert", "oren-nayar", "phong", "blinn-phong", "ggx", "beckmann")
FRESNEL = ("schlick", "dielectric", "conductor")
ALPHA_RANGE = (0.01, 1.0)
"""Microfacet roughness α the fitter searches (inside the energy tables' nodes)."""
EXPONENT_RANGE = (0.5, 20000.0)
"""Phong / Blinn-Phong exponents the fitter searches."""
SIGMA_RANGE_DEG = (0.0, 60.0)
ETA_DIELECTRIC_RANGE = (1.0, 3.0)
ETA_CONDUCTOR_RANGE = (0.05, 6.0)
K_CONDUCTOR_RANGE = (0.0, 10.0)

_ALBEDO = Param("albedo", True, 0.0, 1.0, coupled=True)


def _diffuse(p: Values) -> np.ndarray:
    return rgb(p["albedo"]) / np.pi


def _spec(name: str, p: Values, keys: tuple[str, ...]) -> str:
    return f"{name}:" + ",".join(f"{k}={spec_value(p[k])}" for k in keys if k in p)


class Lambert(Model):
    """ρ/π."""

    name = "lambert"
    params = (Param("albedo", True, 0.0, 1.0),)

    def evaluate(self, cos: Cosines, p: Values) -> np.ndarray:
        return np.broadcast_to(_diffuse(p), cos.cos_i.shape + (3,)).copy()

    def spec(self, p: Values) -> str:
        return _spec("lambert", p, ("albedo",))


class OrenNayar(Model):
    """ρ/π · (A + B max(0, cos Δφ) sin α tan β), σ in degrees."""

    name = "oren-nayar"
    params = (_ALBEDO, Param("sigma_deg", False, *SIGMA_RANGE_DEG, unit="deg"))

    def _room(self, sigma_deg: float) -> float:
        return min(1.0, 1.0 / energy.oren_nayar_max_albedo(sigma_deg))

    def physical(self, fit: Values) -> dict[str, np.ndarray | float]:
        return {"albedo": rgb(fit["albedo"]) * self._room(float(fit["sigma_deg"])),
                "sigma_deg": float(fit["sigma_deg"])}

    def fit_values(self, p: Values) -> dict[str, np.ndarray | float]:
        return {"albedo": rgb(p["albedo"]) / self._room(float(p["sigma_deg"])),
                "sigma_deg": float(p["sigma_deg"])}

    def evaluate(self, cos: Cosines, p: Values) -> np.ndarray:
        factor = terms.oren_nayar(cos.cos_i, cos.cos_o, cos.cos_dphi,
                                  np.radians(float(p["sigma_deg"])))
        return factor[..., None] * _diffuse(p)

    def spec(self, p: Values) -> str:
        return _spec("oren-nayar", p, ("albedo", "sigma_deg"))


class PhongFamily(Model):
    """Lambert plus one or two normalised Phong (about ωr) or Blinn-Phong (about h) lobes."""

    def __init__(self, kind: str, lobes: int = 1) -> None:
        if kind not in ("phong", "blinn-phong"):
            raise ValueError(f"kind must be phong or blinn-phong, got {kind!r}")
        self.name = kind
        self.lobes = lobes
        self._suffixes = ("", "2")[:lobes]
        self.params = (_ALBEDO,) + tuple(
            q for s in self._suffixes
            for q in (Param(f"ks{s}", True, 0.0, 1.0, coupled=True),
                      Param(f"e{s}", False, *EXPONENT_RANGE, log=True)))
        self._max_albedo = (energy.phong_max_albedo if kind == "phong"
                            else energy.blinn_phong_max_albedo)

    def physical(self, fit: Values) -> dict[str, np.ndarray | float]:
        out: dict[str, np.ndarray | float] = {}
        used = np.zeros(3)
        for s in self._suffixes:
            e = float(fit[f"e{s}"])
            share = rgb(fit[f"ks{s}"]) * (1.0 - used)  # of the largest albedo
            out[f"ks{s}"], out[f"e{s}"] = share / self._max_albedo(e), e
            used = used + share
        out["albedo"] = rgb(fit["albedo"]) * (1.0 - used)
        return out

    def fit_values(self, p: Values) -> dict[str, np.ndarray | float]:
        out: dict[str, np.ndarray | float] = {}
        used = np.zeros(3)
        for s in self._suffixes:
            e = float(p[f"e{s}"])
            share = rgb(p[f"ks{s}"]) * self._max_albedo(e)
            with np.errstate(divide="ignore", invalid="ignore"):
                out[f"ks{s}"] = np.where(used < 1, share / (1.0 - used), 0.0)
            out[f"e{s}"] = e
            used = used + share
        with np.errstate(divide="ignore", invalid="ignore"):
            out["albedo"] = np.where(used < 1, rgb(p["albedo"]) / (1.0 - used), 0.0)
        return out

    def evaluate(self, cos: Cosines, p: Values) -> np.ndarray:
        value = np.broadcast_to(_diffuse(p), cos.cos_i.shape + (3,)).copy()
        for s in self._suffixes:
            e = float(p[f"e{s}"])
            lobe = (terms.phong_lobe(cos.cos_mirror, e) if self.name == "phong"
                    else terms.blinn_phong_lobe(cos.cos_h, e))
            value += lobe[..., None] * rgb(p[f"ks{s}"])
        return value

    def spec(self, p: Values) -> str:
        return _spec(self.name, p, ("albedo", "ks", "e", "ks2", "e2"))


class Microfacet(Model):
    """Lambert plus one or two Cook–Torrance lobes D·G·F / (4 cos θi cos θo)."""

    def __init__(self, distribution: str = "ggx", masking: str = "separable",
                 fresnel: str = "schlick", lobes: int = 1) -> None:
        if distribution not in terms.DISTRIBUTIONS:
            raise ValueError(f"distribution must be one of {', '.join(terms.DISTRIBUTIONS)}")
        if masking not in terms.MASKING:
            raise ValueError(f"masking must be one of {', '.join(terms.MASKING)}")
        if fresnel not in FRESNEL:
            raise ValueError(f"fresnel must be one of {', '.join(FRESNEL)}")
        self.name, self.masking, self.fresnel, self.lobes = distribution, masking, fresnel, lobes
        fresnel_params = {
            "schlick": (Param("f0", True, 0.0, 1.0),),
            "dielectric": (Param("eta", False, *ETA_DIELECTRIC_RANGE),),
            "conductor": (Param("eta", True, *ETA_CONDUCTOR_RANGE, start=1.0),
                          Param("k", True, *K_CONDUCTOR_RANGE, start=3.0)),
        }[fresnel]
        second = (Param("alpha2", False, *ALPHA_RANGE, log=True), Param("mix", False, 0.0, 1.0))
        self.params = ((_ALBEDO, Param("alpha", False, *ALPHA_RANGE, log=True)) + fresnel_params
                       + (second if lobes == 2 else ()))

    def fresnel_term(self, cos_d: np.ndarray, p: Values) -> np.ndarray:
        """F (…, 3) at cos θd for physical parameters ``p``."""
        c = np.asarray(cos_d, dtype=np.float64)[..., None]
        if self.fresnel == "schlick":
            return terms.fresnel_schlick(c, rgb(p["f0"]))
        if self.fresnel == "dielectric":
            return np.broadcast_to(terms.fresnel_dielectric(c, float(p["eta"])),
                                   c.shape[:-1] + (3,))
        return terms.fresnel_conductor(c, rgb(p["eta"]), rgb(p["k"]))

    def _mixture(self, p: Values) -> list[tuple[float, float]]:
        """(weight, α) of each lobe."""
        if self.lobes == 1:
            return [(1.0, float(p["alpha"]))]
        mix = float(p["mix"])
        return [(1.0 - mix, float(p["alpha"])), (mix, float(p["alpha2"]))]

    def specular_max_albedo(self, p: Values) -> np.ndarray:
        """Upper bound (3,) of the lobes' directional albedo over θi."""
        f_nodes = self.fresnel_term(energy.FRESNEL_NODES, p).T  # (3, J)
        return sum(w * energy.microfacet_max_albedo(self.name, self.masking, a, f_nodes)
                   for w, a in self._mixture(p))

    def physical(self, fit: Values) -> dict[str, np.ndarray | float]:
        out = dict(fit)
        out["albedo"] = rgb(fit["albedo"]) * np.maximum(1.0 - self.specular_max_albedo(fit), 0.0)
        return out

    def fit_values(self, p: Values) -> dict[str, np.ndarray | float]:
        out = dict(p)
        room = 1.0 - self.specular_max_albedo(p)
        with np.errstate(divide="ignore", invalid="ignore"):
            out["albedo"] = np.where(room > 0, rgb(p["albedo"]) / room, np.inf)
        return out

    def evaluate(self, cos: Cosines, p: Values) -> np.ndarray:
        f = self.fresnel_term(cos.cos_d, p)
        value = np.broadcast_to(_diffuse(p), f.shape).copy()
        for w, a in self._mixture(p):
            lobe = terms.microfacet(cos.cos_i, cos.cos_o, cos.cos_h, 1.0, a, self.name,
                                    self.masking)
            value += w * lobe[..., None] * f
        return value

    def spec(self, p: Values) -> str:
        keys = ("albedo", "alpha", "f0", "eta", "k", "alpha2", "mix")
        text = _spec(self.name, p, keys)
        if self.masking != "separable":
            text += f",masking={self.masking}"
        if self.fresnel != "schlick":
            text += f",fresnel={self.fresnel}"
        return text


def make_model(name: str, *, lobes: int = 1, masking: str = "separable",
               fresnel: str = "schlick") -> Model:
    """The model called ``name`` (:data:`MODEL_NAMES`); ValueError naming the choices."""
    if lobes not in (1, 2):
        raise ValueError(f"lobes must be 1 or 2, got {lobes}")
    if name in ("ggx", "beckmann"):
        return Microfacet(name, masking, fresnel, lobes)
    if masking != "separable" or fresnel != "schlick":
        raise ValueError(f"masking and fresnel apply to the microfacet models (ggx, beckmann), "
                         f"not {name}")
    if name in ("phong", "blinn-phong"):
        return PhongFamily(name, lobes)
    if lobes != 1:
        raise ValueError(f"{name} has no specular lobe: lobes must be 1")
    if name == "lambert":
        return Lambert()
    if name == "oren-nayar":
        return OrenNayar()
    raise ValueError(f"unknown model {name!r}: use one of {', '.join(MODEL_NAMES)}")
