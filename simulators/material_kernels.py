"""Compiled (numba) scalar evaluators of the analytic reference materials, for the simulated
camera's compiled renderer (:mod:`acquisition.simworld.render_kernel`).

Each evaluator is its class's ``eval_vectors`` (:mod:`simulators.materials`,
:mod:`simulators.material_models`) written again for one pair of unit vectors ``wi``, ``wo``
(normal +z), operation for operation and in the same order (but x⁵ by multiplication, not
libm's pow); it returns the BRDF (sr⁻¹) of the R, G and B channels, 0 when either vector is at
or below the horizon. ``eval_vectors`` stays the reference: ``tests/test_material_kernels.py``
holds every evaluator to it to 1e-12 relative over random directions.

:func:`packed_material` packs a material as ``(kind, params)``: one of the ``KIND_*`` codes
and a float64 array laid out as that kind's evaluator states. A material it does not know
(the measured MERL and RGL materials, or a subclass of an analytic one, which may evaluate
differently) packs to None, and the renderer uses the numpy path for it.
:func:`accumulate_packed` runs an evaluator over rows of vectors, in a loop per kind.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numba
import numpy as np

from simulators.material_models import (
    ColouredLambert,
    MicrofacetMaterial,
    OrenNayarMaterial,
    PhongMaterial,
)
from simulators.materials import GGX, Lambert, Material

KIND_DIFFUSE, KIND_GGX, KIND_MICROFACET, KIND_PHONG, KIND_OREN_NAYAR = range(5)
"""Material kinds of :func:`accumulate_packed`."""

_EPS = 1e-300  # the numpy models' floor on norms and cosines
_ZERO = (0.0, 0.0, 0.0)
_LOOP = {"cache": True, "nogil": True, "error_model": "numpy"}
_JIT = {**_LOOP, "inline": "always"}  # the evaluators: inside accumulate_packed's loops


# ---------------------------------------------------------------------------- helpers
@numba.njit(**_JIT)
def _unit(x: float, y: float, z: float) -> tuple[float, float, float]:
    """``x, y, z`` over max(|(x, y, z)|, 1e-300) (the numpy models' ``_unit``)."""
    norm = max(math.sqrt(x * x + y * y + z * z), _EPS)
    return x / norm, y / norm, z / norm


@numba.njit(**_JIT)
def _clip01(x: float) -> float:
    return min(max(x, 0.0), 1.0)


@numba.njit(**_JIT)
def _pow5(x: float) -> float:
    """x⁵ by multiplication (numpy's ``x ** 5`` calls libm's pow, ≤ 2 ulp away): no libm call,
    so a loop of it vectorises."""
    x2 = x * x
    return x2 * x2 * x


# ---------------------------------------------------------------------------- Lambert, GGX
@numba.njit(**_JIT)
def diffuse(p, ix, iy, iz, ox, oy, oz):  # pragma: no cover - compiled
    """Lambert and ColouredLambert: f = ρ/π; ``p`` = (ρr, ρg, ρb)."""
    if not (iz > 0.0 and oz > 0.0):
        return _ZERO
    return p[0] / math.pi, p[1] / math.pi, p[2] / math.pi


@numba.njit(**_JIT)
def _g1(c: float, a2: float) -> float:
    c = max(c, 1e-12)
    return 2.0 * c / (c + math.sqrt(a2 + (1.0 - a2) * (c * c)))


@numba.njit(**_JIT)
def ggx(p, ix, iy, iz, ox, oy, oz):  # pragma: no cover - compiled
    """:class:`simulators.materials.GGX`; ``p`` = (albedo, α², f0)."""
    if not (iz > 0.0 and oz > 0.0):
        return _ZERO
    albedo, a2, f0 = p[0], p[1], p[2]
    hx, hy, hz = _unit(ix + ox, iy + oy, iz + oz)
    h_l = _clip01(hx * ix + hy * iy + hz * iz)
    d = a2 / (math.pi * ((hz * hz) * (a2 - 1.0) + 1.0) ** 2)
    g = _g1(iz, a2) * _g1(oz, a2)
    f = f0 + (1.0 - f0) * _pow5(1.0 - h_l)
    value = albedo / math.pi + d * g * f / (4.0 * iz * oz)
    return value, value, value


# ---------------------------------------------------------------------------- microfacet
@numba.njit(**_JIT)
def _distribution(beckmann: bool, cos_h: float, alpha: float) -> float:
    c = _clip01(cos_h)
    c2 = c * c
    a2 = alpha * alpha
    if not beckmann:
        return a2 / (math.pi * (1.0 + c2 * (a2 - 1.0)) ** 2)
    if not c2 > 0.0:
        return 0.0
    return math.exp((c2 - 1.0) / (a2 * c2)) / (math.pi * a2 * c2 * c2)


@numba.njit(**_JIT)
def _smith_lambda(beckmann: bool, cos: float, alpha: float) -> float:
    c = min(max(cos, 1e-150), 1.0)
    t2 = (1.0 / (c * c)) - 1.0
    if not beckmann:
        return (math.sqrt(1.0 + alpha * alpha * t2) - 1.0) / 2.0
    a = 1.0 / max(alpha * math.sqrt(t2), _EPS)
    return max((math.exp(-a * a) / (a * math.sqrt(math.pi)) - math.erfc(a)) / 2.0, 0.0)


@numba.njit(**_JIT)
def _lobe(p, hz: float, iz: float, oz: float, alpha: float) -> float:
    """One Cook–Torrance lobe D·G / (4 cos θi cos θo) of the microfacet layout ``p``."""
    beckmann = p[6] != 0.0
    li = _smith_lambda(beckmann, iz, alpha)
    lo = _smith_lambda(beckmann, oz, alpha)
    g = 1.0 / (1.0 + li + lo) if p[7] != 0.0 else 1.0 / ((1.0 + li) * (1.0 + lo))
    denom = 4.0 * max(iz, _EPS) * max(oz, _EPS)
    return _distribution(beckmann, hz, alpha) * g / denom


@numba.njit(**_JIT)
def _fresnel(kind: float, c: float, f0: float, eta: float, k: float) -> float:
    """One channel's reflectance at cos θd ``c``: 0 Schlick, 1 dielectric, 2 conductor."""
    c = _clip01(c)
    if kind == 0.0:
        return f0 + (1.0 - f0) * _pow5(1.0 - c)
    if kind == 1.0:
        g2 = eta * eta - 1.0 + c * c
        if not g2 > 0.0:
            return 1.0
        g = math.sqrt(g2)
        a = (g - c) / (g + c)
        b = (c * (g + c) - 1.0) / (c * (g - c) + 1.0)
        return 0.5 * a * a * (1.0 + b * b)
    s2 = 1.0 - c * c
    t0 = eta * eta - k * k - s2
    a2b2 = math.sqrt(t0 * t0 + 4.0 * eta * eta * k * k)
    a = math.sqrt(max(0.5 * (a2b2 + t0), 0.0))
    rs = (a2b2 + c * c - 2.0 * a * c) / (a2b2 + c * c + 2.0 * a * c)
    t1 = a2b2 * c * c + s2 * s2
    t2 = 2.0 * a * c * s2
    rp = rs * (t1 - t2) / (t1 + t2)
    return 0.5 * (rs + rp)


@numba.njit(**_JIT)
def microfacet(p, ix, iy, iz, ox, oy, oz):  # pragma: no cover - compiled
    """:class:`simulators.material_models.MicrofacetMaterial`; ``p`` = (ρr, ρg, ρb, α, α₂,
    mix, Beckmann?, height-correlated?, Fresnel kind, f0 ×3, η ×3, k ×3, second lobe?)."""
    if not (iz > 0.0 and oz > 0.0):
        return _ZERO
    hx, hy, hz = _unit(ix + ox, iy + oy, iz + oz)
    c = hx * ix + hy * iy + hz * iz
    spec = (1.0 - p[5]) * _lobe(p, hz, iz, oz, p[3])
    if p[18] != 0.0:
        spec = spec + p[5] * _lobe(p, hz, iz, oz, p[4])
    r = p[0] / math.pi + spec * _fresnel(p[8], c, p[9], p[12], p[15])
    g = p[1] / math.pi + spec * _fresnel(p[8], c, p[10], p[13], p[16])
    b = p[2] / math.pi + spec * _fresnel(p[8], c, p[11], p[14], p[17])
    return r, g, b


# ---------------------------------------------------------------------------- Phong, Oren–Nayar
@numba.njit(**_JIT)
def phong(p, ix, iy, iz, ox, oy, oz):  # pragma: no cover - compiled
    """:class:`simulators.material_models.PhongMaterial`; ``p`` = (ρr, ρg, ρb, Blinn?,
    lobes, then per lobe ks ×3, e)."""
    if not (iz > 0.0 and oz > 0.0):
        return _ZERO
    c = _unit(ix + ox, iy + oy, iz + oz)[2] if p[3] != 0.0 else -ix * ox + -iy * oy + iz * oz
    r, g, b = p[0] / math.pi, p[1] / math.pi, p[2] / math.pi
    for lobe in range(int(p[4])):
        at = 5 + 4 * lobe
        e = p[at + 3]
        weight = (e + 2.0) / (2.0 * math.pi) * max(c, 0.0) ** e
        r, g, b = r + weight * p[at], g + weight * p[at + 1], b + weight * p[at + 2]
    return r, g, b


@numba.njit(**_JIT)
def oren_nayar(p, ix, iy, iz, ox, oy, oz):  # pragma: no cover - compiled
    """:class:`simulators.material_models.OrenNayarMaterial`; ``p`` = (ρr, ρg, ρb, A, B)."""
    if not (iz > 0.0 and oz > 0.0):
        return _ZERO
    ti = math.acos(min(max(iz, -1.0), 1.0))
    to = math.acos(min(max(oz, -1.0), 1.0))
    pix, piy, _ = _unit(ix, iy, 0.0)
    pox, poy, _ = _unit(ox, oy, 0.0)
    cos_phi = max(pix * pox + piy * poy, 0.0)
    factor = p[3] + p[4] * cos_phi * math.sin(max(ti, to)) * math.tan(min(ti, to))
    return factor * p[0] / math.pi, factor * p[1] / math.pi, factor * p[2] / math.pi


# ---------------------------------------------------------------------------- dispatch
@numba.njit(**_LOOP)
def accumulate_packed(kind, p, n, wi, wo, weight, acc):  # pragma: no cover - compiled
    """``acc[:, q] += f(wi[:, q], wo[:, q]) · weight[q]`` for q < ``n``: the packed material's
    BRDF (sr⁻¹) of unit vectors held by rows (``wi``, ``wo``: 3 × ≥ n), times a weight (0
    leaves ``acc`` as it is). One loop per kind, so that LLVM may vectorise it."""
    if kind == KIND_DIFFUSE:
        for q in range(n):
            _add(acc, q, diffuse(p, wi[0, q], wi[1, q], wi[2, q], wo[0, q], wo[1, q], wo[2, q]),
                 weight[q])
    elif kind == KIND_GGX:
        for q in range(n):
            _add(acc, q, ggx(p, wi[0, q], wi[1, q], wi[2, q], wo[0, q], wo[1, q], wo[2, q]),
                 weight[q])
    elif kind == KIND_MICROFACET:
        for q in range(n):
            _add(acc, q, microfacet(p, wi[0, q], wi[1, q], wi[2, q], wo[0, q], wo[1, q],
                                    wo[2, q]), weight[q])
    elif kind == KIND_PHONG:
        for q in range(n):
            _add(acc, q, phong(p, wi[0, q], wi[1, q], wi[2, q], wo[0, q], wo[1, q], wo[2, q]),
                 weight[q])
    else:
        for q in range(n):
            _add(acc, q, oren_nayar(p, wi[0, q], wi[1, q], wi[2, q], wo[0, q], wo[1, q],
                                    wo[2, q]), weight[q])


@numba.njit(**_JIT)
def _add(acc, q, f, weight):  # pragma: no cover - compiled
    acc[0, q] += f[0] * weight
    acc[1, q] += f[1] * weight
    acc[2, q] += f[2] * weight


@numba.njit(**_LOOP)
def eval_packed_vectors(kind, p, wi, wo):  # pragma: no cover - compiled
    """The packed material's BRDF (N, 3), sr⁻¹, for unit vectors ``wi``, ``wo`` (N, 3), by
    :func:`accumulate_packed` (what the renderer runs) with weight 1."""
    n = wi.shape[0]
    acc = np.zeros((3, n))
    accumulate_packed(kind, p, n, np.ascontiguousarray(wi.T), np.ascontiguousarray(wo.T),
                      np.ones(n), acc)
    return acc.T.copy()


# ---------------------------------------------------------------------------- packing
def _pack_microfacet(m: MicrofacetMaterial) -> np.ndarray:
    fresnel = {"schlick": 0.0, "dielectric": 1.0}.get(m.fresnel, 2.0)  # as _fresnel reads it
    return np.array([*m.albedo, m.alpha, m.alpha2 or 0.0, m.mix, m.distribution != "ggx",
                     m.masking == "height-correlated", fresnel, *m.f0, *m.eta, *m.k,
                     m.alpha2 is not None], dtype=np.float64)


def _pack_oren_nayar(m: OrenNayarMaterial) -> np.ndarray:
    s2 = math.radians(m.sigma_deg) ** 2
    return np.array([*m.albedo, 1.0 - 0.5 * s2 / (s2 + 0.3), 0.45 * s2 / (s2 + 0.09)])


_PACKERS: dict[type, tuple[int, Callable[[object], np.ndarray]]] = {
    Lambert: (KIND_DIFFUSE, lambda m: np.full(3, m.albedo, dtype=np.float64)),
    ColouredLambert: (KIND_DIFFUSE, lambda m: np.array(m.albedo, dtype=np.float64)),
    GGX: (KIND_GGX, lambda m: np.array([m.albedo, m.alpha**2, m.f0], dtype=np.float64)),
    MicrofacetMaterial: (KIND_MICROFACET, _pack_microfacet),
    PhongMaterial: (KIND_PHONG, lambda m: np.array(
        [*m.albedo, m.half_vector, len(m.lobes), *(x for ks, e in m.lobes for x in (*ks, e))],
        dtype=np.float64)),
    OrenNayarMaterial: (KIND_OREN_NAYAR, _pack_oren_nayar),
}


def packed_material(material: Material) -> tuple[int, np.ndarray] | None:
    """``(kind, params)`` of ``material`` for :func:`accumulate_packed`, or None when it has no
    compiled evaluator (measured materials; subclasses of the analytic ones)."""
    entry = _PACKERS.get(type(material))
    if entry is None:
        return None
    kind, pack = entry
    return kind, pack(material)
