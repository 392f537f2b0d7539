"""More reference materials for the simulated camera: the lecture's analytic BRDFs.

The simulator is the referee of gonio's fits, so these are written here from the formulas,
in vector form, with code of their own (gonio's fitter has its own implementation in
``acquisition.analysis.models``, from angles; tests compare the two). Specs::

    ggx:albedo=0.2,alpha=0.3,f0=0.04                      (today's exact form)
    ggx:albedo=0.2/0.1/0.05,alpha=0.3,f0=0.04,masking=height-correlated
    ggx:albedo=0.1,alpha=0.2,fresnel=dielectric,eta=1.5
    ggx:albedo=0,alpha=0.2,fresnel=conductor,eta=0.2/0.9/1.1,k=3.9/2.4/2.2
    ggx:albedo=0.1,alpha=0.1,f0=0.04,alpha2=0.5,mix=0.3   (two lobes sharing F)
    beckmann:albedo=..,alpha=..,f0=..                      (same keys as ggx)
    phong:albedo=0.3,ks=0.2,e=50[,ks2=..,e2=..]
    blinn-phong:albedo=0.3,ks=0.05,e=100[,ks2=..,e2=..]
    oren-nayar:albedo=0.5,sigma_deg=20

A value ``a/b/c`` gives the R, G and B channels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import erfc

from drivers.errors import MaterialError
from simulators.materials import GGX, MATERIAL_PARSERS, Lambert, Material

_EPS = 1e-300


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.sum(a * b, axis=-1)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), _EPS)


def _tan_sq(cos: np.ndarray) -> np.ndarray:
    c = np.clip(cos, 1e-150, 1.0)
    return (1.0 / (c * c)) - 1.0


def _reflect_about_normal(w: np.ndarray) -> np.ndarray:
    """Mirror direction of ``w`` about the normal +z."""
    r = -w.copy()
    r[..., 2] = w[..., 2]
    return r


# ---------------------------------------------------------------------------- microfacet
def _d(kind: str, cos_h: np.ndarray, alpha: float) -> np.ndarray:
    c2 = np.clip(cos_h, 0.0, 1.0) ** 2
    a2 = alpha * alpha
    if kind == "ggx":
        return a2 / (np.pi * (1.0 + c2 * (a2 - 1.0)) ** 2)
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        d = np.exp((c2 - 1.0) / (a2 * c2)) / (np.pi * a2 * c2 * c2)
    return np.where(c2 > 0, d, 0.0)


def _smith_lambda(kind: str, cos: np.ndarray, alpha: float) -> np.ndarray:
    t2 = _tan_sq(cos)
    if kind == "ggx":
        return (np.sqrt(1.0 + alpha * alpha * t2) - 1.0) / 2.0
    a = 1.0 / np.maximum(alpha * np.sqrt(t2), _EPS)
    with np.errstate(under="ignore", over="ignore"):
        return np.maximum((np.exp(-a * a) / (a * math.sqrt(math.pi)) - erfc(a)) / 2.0, 0.0)


def _fresnel(kind: str, c: np.ndarray, f0: np.ndarray, eta: np.ndarray, k: np.ndarray) -> np.ndarray:
    """(…, 3) reflectance at cos θd ``c`` (…,)."""
    c = np.clip(c, 0.0, 1.0)[..., None]
    if kind == "schlick":
        return f0 + (1.0 - f0) * (1.0 - c) ** 5
    if kind == "dielectric":  # Walter et al. 2007's closed form
        g2 = eta * eta - 1.0 + c * c
        g = np.sqrt(np.maximum(g2, 0.0))
        with np.errstate(divide="ignore", invalid="ignore"):
            a = (g - c) / (g + c)
            b = (c * (g + c) - 1.0) / (c * (g - c) + 1.0)
            f = 0.5 * a * a * (1.0 + b * b)
        return np.where(g2 > 0, f, 1.0)
    # conductor, real arithmetic: a² + b² = √((η² − k² − sin²)² + 4η²k²)
    s2 = 1.0 - c * c
    t0 = eta * eta - k * k - s2
    a2b2 = np.sqrt(t0 * t0 + 4.0 * eta * eta * k * k)
    a = np.sqrt(np.maximum(0.5 * (a2b2 + t0), 0.0))
    rs = (a2b2 + c * c - 2.0 * a * c) / (a2b2 + c * c + 2.0 * a * c)
    t1 = a2b2 * c * c + s2 * s2
    t2 = 2.0 * a * c * s2
    rp = rs * (t1 - t2) / (t1 + t2)
    return 0.5 * (rs + rp)


@dataclass(frozen=True)
class MicrofacetMaterial(Material):
    """Lambert (per channel) plus one or two Cook–Torrance lobes sharing one Fresnel term."""

    albedo: tuple[float, float, float]
    alpha: float
    distribution: str = "ggx"
    masking: str = "separable"
    fresnel: str = "schlick"
    f0: tuple[float, float, float] = (0.04, 0.04, 0.04)
    eta: tuple[float, float, float] = (1.5, 1.5, 1.5)
    k: tuple[float, float, float] = (0.0, 0.0, 0.0)
    alpha2: float | None = None
    mix: float = 0.0
    spec: str = ""

    def _lobe(self, wi: np.ndarray, wo: np.ndarray, alpha: float) -> np.ndarray:
        h = _unit(wi + wo)
        li = _smith_lambda(self.distribution, wi[..., 2], alpha)
        lo = _smith_lambda(self.distribution, wo[..., 2], alpha)
        g = (1.0 / (1.0 + li + lo) if self.masking == "height-correlated"
             else 1.0 / ((1.0 + li) * (1.0 + lo)))
        denom = 4.0 * np.maximum(wi[..., 2], _EPS) * np.maximum(wo[..., 2], _EPS)
        return _d(self.distribution, h[..., 2], alpha) * g / denom

    def eval_vectors(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        wi, wo = np.asarray(wi, float), np.asarray(wo, float)
        up = (wi[..., 2] > 0) & (wo[..., 2] > 0)
        h = _unit(wi + wo)
        f = _fresnel(self.fresnel, _dot(h, wi), np.array(self.f0), np.array(self.eta),
                     np.array(self.k))
        spec = (1.0 - self.mix) * self._lobe(wi, wo, self.alpha)
        if self.alpha2 is not None:
            spec = spec + self.mix * self._lobe(wi, wo, self.alpha2)
        value = np.array(self.albedo) / np.pi + spec[..., None] * f
        return np.where(up[..., None], value, 0.0)


# ---------------------------------------------------------------------------- Phong family
@dataclass(frozen=True)
class PhongMaterial(Material):
    """Lambert plus normalised Phong lobes ks·(e + 2)/(2π)·(ωr·ωo)^e, or with
    ``half_vector`` the Blinn-Phong lobes ks·(e + 2)/(2π)·(n·h)^e."""

    albedo: tuple[float, float, float]
    lobes: tuple[tuple[tuple[float, float, float], float], ...]
    """(ks per channel, e) of each lobe."""
    half_vector: bool = False
    spec: str = ""

    def eval_vectors(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        wi, wo = np.asarray(wi, float), np.asarray(wo, float)
        up = (wi[..., 2] > 0) & (wo[..., 2] > 0)
        c = _unit(wi + wo)[..., 2] if self.half_vector else _dot(_reflect_about_normal(wi), wo)
        value = np.array(self.albedo) / np.pi + np.zeros(c.shape + (3,))
        for ks, e in self.lobes:
            value = value + ((e + 2.0) / (2.0 * np.pi) * np.maximum(c, 0.0) ** e)[..., None] * ks
        return np.where(up[..., None], value, 0.0)


@dataclass(frozen=True)
class OrenNayarMaterial(Material):
    """The lecture's Oren–Nayar: ρ/π (A + B max(0, cos(φi − φo)) sin α tan β)."""

    albedo: tuple[float, float, float]
    sigma_deg: float
    spec: str = ""

    def eval_vectors(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        wi, wo = np.asarray(wi, float), np.asarray(wo, float)
        up = (wi[..., 2] > 0) & (wo[..., 2] > 0)
        s2 = math.radians(self.sigma_deg) ** 2
        a = 1.0 - 0.5 * s2 / (s2 + 0.3)
        b = 0.45 * s2 / (s2 + 0.09)
        ti = np.arccos(np.clip(wi[..., 2], -1.0, 1.0))
        to = np.arccos(np.clip(wo[..., 2], -1.0, 1.0))
        pi_, po = _unit(wi * [1.0, 1.0, 0.0]), _unit(wo * [1.0, 1.0, 0.0])
        cos_phi = np.maximum(_dot(pi_, po), 0.0)
        factor = a + b * cos_phi * np.sin(np.maximum(ti, to)) * np.tan(np.minimum(ti, to))
        value = factor[..., None] * np.array(self.albedo) / np.pi
        return np.where(up[..., None], value, 0.0)


@dataclass(frozen=True)
class ColouredLambert(Material):
    """Ideal diffuse reflector with one albedo per channel: f = ρ/π."""

    albedo: tuple[float, float, float]
    spec: str = ""

    def eval_vectors(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        up = (np.asarray(wi)[..., 2] > 0) & (np.asarray(wo)[..., 2] > 0)
        return np.where(up[..., None], np.array(self.albedo) / np.pi, 0.0)


# ---------------------------------------------------------------------------- specs
_OPTIONS = {"masking": ("separable", "height-correlated"),
            "fresnel": ("schlick", "dielectric", "conductor")}


def _spec_items(model: str, text: str) -> dict[str, str]:
    items: dict[str, str] = {}
    for item in filter(None, (p.strip() for p in text.split(","))):
        key, sep, raw = item.partition("=")
        if not sep:
            raise MaterialError(f"material '{model}': parameter '{item}' is not key=value")
        items[key.strip()] = raw.strip()
    return items


def _number(model: str, key: str, raw: str, lo: float, hi: float) -> float:
    try:
        value = float(raw)
    except ValueError:
        raise MaterialError(f"material '{model}': {key}='{raw}' is not a number") from None
    if not (math.isfinite(value) and lo <= value <= hi):
        raise MaterialError(f"material '{model}': {key} must lie in [{lo:g}, {hi:g}], got {raw}")
    return value


def _colour(model: str, key: str, raw: str, lo: float, hi: float) -> tuple[float, float, float]:
    parts = raw.split("/")
    if len(parts) not in (1, 3):
        raise MaterialError(f"material '{model}': {key}='{raw}' must be one number or R/G/B")
    values = [_number(model, key, p, lo, hi) for p in parts]
    return (values[0],) * 3 if len(values) == 1 else (values[0], values[1], values[2])


def _check_keys(model: str, items: dict[str, str], required: set[str], optional: set[str]) -> None:
    unknown, missing = set(items) - required - optional, required - set(items)
    if unknown or missing:
        raise MaterialError(
            f"material '{model}' takes {', '.join(sorted(required))}"
            + (f" (optional: {', '.join(sorted(optional))})" if optional else "")
            + (f"; unknown: {', '.join(sorted(unknown))}" if unknown else "")
            + (f"; missing: {', '.join(sorted(missing))}" if missing else ""))


def _option(model: str, items: dict[str, str], key: str) -> str:
    value = items.get(key, _OPTIONS[key][0])
    if value not in _OPTIONS[key]:
        raise MaterialError(f"material '{model}': {key} must be one of {', '.join(_OPTIONS[key])}, "
                            f"got {value!r}")
    return value


def _microfacet_parser(distribution: str):  # noqa: ANN202 - returns a spec parser
    def parse(text: str) -> Material:
        model = distribution
        items = _spec_items(model, text)
        fresnel = _option(model, items, "fresnel")
        fresnel_keys = {"schlick": {"f0"}, "dielectric": {"eta"}, "conductor": {"eta", "k"}}[fresnel]
        two = {"alpha2", "mix"} & set(items)
        _check_keys(model, items, {"albedo", "alpha"} | fresnel_keys | two,
                    {"masking", "fresnel", "alpha2", "mix"})
        if two and two != {"alpha2", "mix"}:
            raise MaterialError(f"material '{model}': a second lobe needs both alpha2 and mix")
        masking = _option(model, items, "masking")
        albedo = _colour(model, "albedo", items["albedo"], 0.0, 1.0)
        alpha = _number(model, "alpha", items["alpha"], 1e-4, 1.0)
        plain = (distribution == "ggx" and masking == "separable" and fresnel == "schlick"
                 and not two and len(set(albedo)) == 1 and "/" not in items["f0"])
        if plain:  # today's exact form
            return GGX(albedo[0], alpha, _number(model, "f0", items["f0"], 0.0, 1.0))
        kwargs: dict[str, object] = {}
        if fresnel == "schlick":
            kwargs["f0"] = _colour(model, "f0", items["f0"], 0.0, 1.0)
        elif fresnel == "dielectric":
            kwargs["eta"] = (_number(model, "eta", items["eta"], 1.0, 10.0),) * 3
        else:
            kwargs["eta"] = _colour(model, "eta", items["eta"], 0.01, 10.0)
            kwargs["k"] = _colour(model, "k", items["k"], 0.0, 20.0)
        if two:
            kwargs["alpha2"] = _number(model, "alpha2", items["alpha2"], 1e-4, 1.0)
            kwargs["mix"] = _number(model, "mix", items["mix"], 0.0, 1.0)
        return MicrofacetMaterial(albedo, alpha, distribution, masking, fresnel,
                                  spec=f"{model}:{text}", **kwargs)  # type: ignore[arg-type]

    return parse


def _phong_parser(model: str):  # noqa: ANN202 - returns a spec parser
    def parse(text: str) -> Material:
        items = _spec_items(model, text)
        two = {"ks2", "e2"} & set(items)
        _check_keys(model, items, {"albedo", "ks", "e"} | two, {"ks2", "e2"})
        if two and two != {"ks2", "e2"}:
            raise MaterialError(f"material '{model}': a second lobe needs both ks2 and e2")
        lobes = tuple((_colour(model, f"ks{s}", items[f"ks{s}"], 0.0, 1.0),
                       _number(model, f"e{s}", items[f"e{s}"], 0.0, 1e6))
                      for s in ("", "2") if f"ks{s}" in items)
        return PhongMaterial(_colour(model, "albedo", items["albedo"], 0.0, 1.0), lobes,
                             half_vector=model == "blinn-phong", spec=f"{model}:{text}")

    return parse


def _oren_nayar(text: str) -> Material:
    items = _spec_items("oren-nayar", text)
    _check_keys("oren-nayar", items, {"albedo", "sigma_deg"}, set())
    return OrenNayarMaterial(_colour("oren-nayar", "albedo", items["albedo"], 0.0, 1.0),
                             _number("oren-nayar", "sigma_deg", items["sigma_deg"], 0.0, 90.0),
                             spec=f"oren-nayar:{text}")


def _lambert(text: str) -> Material:
    items = _spec_items("lambert", text)
    _check_keys("lambert", items, {"albedo"}, set())
    albedo = _colour("lambert", "albedo", items["albedo"], 0.0, 1.0)
    if len(set(albedo)) == 1 and "/" not in items["albedo"]:
        return Lambert(albedo[0])  # today's exact form
    return ColouredLambert(albedo, spec=f"lambert:{text}")


MATERIAL_PARSERS.update({
    "lambert": _lambert,
    "ggx": _microfacet_parser("ggx"),
    "beckmann": _microfacet_parser("beckmann"),
    "phong": _phong_parser("phong"),
    "blinn-phong": _phong_parser("blinn-phong"),
    "oren-nayar": _oren_nayar,
})
