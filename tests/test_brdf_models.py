"""The lecture's BRDF models (acquisition.analysis.models): the same values as the simulated
camera's own implementation, Helmholtz reciprocity, the stated normalisations, and energy
conservation everywhere inside the fitter's bounds, by a quadrature of the test's own."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from acquisition.analysis.models import MODEL_NAMES, make_model, terms
from acquisition.analysis.models.base import Model
from simulators.materials import material_from_spec

VARIANTS = [
    ("lambert", {}), ("oren-nayar", {}), ("phong", {}), ("phong", {"lobes": 2}),
    ("blinn-phong", {}), ("blinn-phong", {"lobes": 2}),
    ("ggx", {}), ("ggx", {"masking": "height-correlated"}), ("ggx", {"fresnel": "dielectric"}),
    ("ggx", {"fresnel": "conductor"}), ("ggx", {"lobes": 2}),
    ("beckmann", {}), ("beckmann", {"masking": "height-correlated", "fresnel": "dielectric"}),
]
IDS = [name + "".join(f"-{v}" for v in opts.values()) for name, opts in VARIANTS]


def fit_box_points(model: Model, n_random: int, seed: int) -> list[dict]:
    """Fit-variable points: every corner of the box over the shape parameters with the weights
    at their upper bound, and random points inside (per-channel values drawn per channel)."""
    rng = np.random.default_rng(seed)
    points = []
    shape = [q for q in model.params if not q.per_channel]
    for corner in itertools.product(*[(q.lo, q.hi) for q in shape]):
        fit = {q.name: (np.full(3, q.hi) if q.per_channel else 0.0) for q in model.params}
        fit.update({q.name: v for q, v in zip(shape, corner, strict=True)})
        points.append(fit)
    for _ in range(n_random):
        fit = {}
        for q in model.params:
            u = rng.uniform(size=q.size)
            v = np.exp(np.log(q.lo) + u * np.log(q.hi / q.lo)) if q.log else q.lo + u * (q.hi - q.lo)
            fit[q.name] = v if q.per_channel else float(v[0])
        points.append(fit)
    return points


def _panels(breaks: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    x, w = np.polynomial.legendre.leggauss(n)
    b = np.unique(np.clip(breaks, breaks.min(), breaks.max()))
    lo, hi = b[:-1, None], b[1:, None]
    return (lo + (hi - lo) * (x + 1) / 2).ravel(), ((hi - lo) * w / 2).ravel()


def directional_albedo(model: Model, p: dict, theta_i_deg: float, width_rad: float) -> np.ndarray:
    """ρ(θi) = ∫ f cos θo dωo by Gauss–Legendre panels in (θo, φo), refined around the mirror
    direction (θo = θi, φo = 180°) on the scale of the lobe's width."""
    ti = np.radians(theta_i_deg)
    scales = width_rad * np.array([-30, -10, -4, -2, -1, -0.5, 0, 0.5, 1, 2, 4, 10, 30])
    t_breaks = np.concatenate([[0.0, np.pi / 2], np.clip(ti + scales, 0, np.pi / 2)])
    p_breaks = np.concatenate([[0.0, np.pi],
                               np.clip(np.pi + scales / max(np.sin(ti), 1e-3), 0, np.pi)])
    to, wt = _panels(t_breaks, 24)
    po, wp = _panels(p_breaks, 24)
    tt, pp = np.meshgrid(to, po, indexing="ij")
    f = model(theta_i_deg, np.degrees(tt), np.degrees(pp), p)
    weight = np.outer(wt * np.sin(to) * np.cos(to), 2.0 * wp)  # φo ∈ [0, π], mirror symmetric
    return np.einsum("ij,ijc->c", weight, f)


def lobe_width(p: dict) -> float:
    widths = [0.3]
    for key in ("alpha", "alpha2"):
        if key in p:
            widths.append(float(p[key]))
    for key in ("e", "e2"):
        if key in p:
            widths.append(float(np.sqrt(2.0 / (float(p[key]) + 2.0))))
    return min(widths)


@pytest.mark.parametrize(("name", "opts"), VARIANTS, ids=IDS)
def test_models_match_the_simulated_cameras_own_implementation(name: str, opts: dict) -> None:
    model = make_model(name, **opts)
    rng = np.random.default_rng(1)
    ti, tr = rng.uniform(0, 89, 3000), rng.uniform(0, 89, 3000)
    dp = rng.uniform(-180, 360, 3000)
    for fit in fit_box_points(model, 4, seed=2)[-4:]:
        p = model.physical(fit)
        ours, theirs = model(ti, tr, dp, p), material_from_spec(model.spec(p))(ti, tr, dp)
        assert np.allclose(ours, theirs, rtol=1e-6, atol=1e-14), model.spec(p)  # spec: 9 digits


@pytest.mark.parametrize(("name", "opts"), VARIANTS, ids=IDS)
def test_models_are_reciprocal(name: str, opts: dict) -> None:
    model = make_model(name, **opts)
    rng = np.random.default_rng(3)
    ti, tr = rng.uniform(0, 89.9, 2000), rng.uniform(0, 89.9, 2000)
    dp = rng.uniform(0, 180, 2000)
    for fit in fit_box_points(model, 6, seed=4):
        p = model.physical(fit)
        a, b = model(ti, tr, dp, p), model(tr, ti, dp, p)
        assert np.allclose(a, b, rtol=1e-12, atol=1e-300), model.spec(p)


@pytest.mark.parametrize(("name", "opts"), VARIANTS, ids=IDS)
def test_energy_is_conserved_everywhere_inside_the_fit_bounds(name: str, opts: dict) -> None:
    model = make_model(name, **opts)
    worst = 0.0
    for fit in fit_box_points(model, 6, seed=5):
        p = model.physical(fit)
        for theta_i in (0.0, 30.0, 60.0, 75.0, 85.0, 88.0, 89.5):
            rho = directional_albedo(model, p, theta_i, lobe_width(p))
            worst = max(worst, float(rho.max()))
            assert np.all(rho <= 1.0 + 2e-3), f"{model.spec(p)}: ρ({theta_i}°) = {rho}"
    assert worst > 0.5  # the bounds are not trivially tight: the box reaches near ρ = 1


def test_the_box_reaches_the_energy_limit_it_claims() -> None:
    """A GGX lobe at the top of the box leaves the diffuse albedo only the room it proves."""
    model = make_model("ggx")
    p = model.physical({"albedo": np.ones(3), "alpha": 0.3, "f0": np.full(3, 0.04)})
    rho = max(float(directional_albedo(model, p, t, 0.3).max()) for t in range(0, 90, 3))
    assert 0.97 < rho <= 1.0 + 2e-3


def _hemisphere(n: int = 400) -> tuple[np.ndarray, np.ndarray]:
    x, w = np.polynomial.legendre.leggauss(n)
    theta = (x + 1) * np.pi / 4
    return theta, w * np.pi / 4


@pytest.mark.parametrize("alpha", [0.05, 0.3, 1.0])
@pytest.mark.parametrize("dist", ["ggx", "beckmann"])
def test_distributions_are_normalised_in_projected_area(dist: str, alpha: float) -> None:
    theta, w = _panels(np.radians([0, 0.1, 1, 3, 10, 30, 60, 90]), 64)
    d_fn, _ = terms.DISTRIBUTION_TERMS[dist]
    integral = 2 * np.pi * np.sum(d_fn(np.cos(theta), alpha) * np.cos(theta) * np.sin(theta) * w)
    assert integral == pytest.approx(1.0, rel=1e-6)


@pytest.mark.parametrize("e", [1.0, 20.0, 500.0])
def test_phong_and_blinn_phong_normalisations(e: float) -> None:
    theta, w = _panels(np.radians([0, 0.5, 2, 5, 15, 45, 90]), 64)
    proj = np.cos(theta) * np.sin(theta) * w * 2 * np.pi
    # Blinn-Phong: the half-vector distribution integrates to 1 in projected area
    assert np.sum(terms.blinn_phong_lobe(np.cos(theta), e) * proj) == pytest.approx(1.0, rel=1e-6)
    # Phong at normal incidence: the lobe about ωr = n has directional albedo 1
    assert np.sum(terms.phong_lobe(np.cos(theta), e) * proj) == pytest.approx(1.0, rel=1e-6)


def test_blinn_phong_brdf_is_not_normalised_hence_its_bound() -> None:
    """The lecture's (e + 2)/2π normalises the half-vector distribution, not the BRDF: at
    normal incidence a sharp Blinn-Phong lobe reflects ≈ 4× what it is given."""
    model = make_model("blinn-phong")
    p = {"albedo": 0.0, "ks": 1.0, "e": 5000.0}
    assert directional_albedo(model, p, 0.0, lobe_width(p))[0] == pytest.approx(4.0, rel=0.01)
    assert model.physical({"albedo": 0.0, "ks": 1.0, "e": 5000.0})["ks"][0] < 0.26


def test_fresnel_limits() -> None:
    c = np.linspace(0, 1, 11)
    assert terms.fresnel_dielectric(1.0, 1.5) == pytest.approx(0.04)
    assert np.allclose(terms.fresnel_conductor(c, 1.5, 0.0), terms.fresnel_dielectric(c, 1.5))
    assert terms.fresnel_conductor(1.0, 0.2, 3.9) == pytest.approx(
        ((0.2 - 1) ** 2 + 3.9**2) / ((0.2 + 1) ** 2 + 3.9**2))
    assert np.allclose(terms.fresnel_schlick(1.0, 0.3), 0.3)
    assert np.allclose(terms.fresnel_dielectric(0.0, 1.5), 1.0)


def test_oren_nayar_with_smooth_facets_is_lambert() -> None:
    on, lam = make_model("oren-nayar"), make_model("lambert")
    angles = (np.array([10.0, 50.0, 80.0]), np.array([70.0, 20.0, 5.0]), np.array([0.0, 90, 180]))
    assert np.allclose(on(*angles, {"albedo": 0.4, "sigma_deg": 0.0}), lam(*angles, {"albedo": 0.4}))


def test_every_named_model_is_built_and_unknown_ones_are_refused() -> None:
    assert all(make_model(n).name == n for n in MODEL_NAMES)
    with pytest.raises(ValueError, match="unknown model 'torrance'"):
        make_model("torrance")
    with pytest.raises(ValueError, match="masking and fresnel apply to the microfacet"):
        make_model("phong", fresnel="dielectric")
