"""Fit an analytic model to a BRDF table: weighted nonlinear least squares with honest 1σ.

* **Data**: the table's measured bins, each evaluated at the mean angles of its samples
  (read-back poses sit off the bin centres), weighted by its independent uncertainty terms.
  The common-mode terms (the white reference: one error scales every bin of a channel) enter
  as a nuisance scale per channel, (1 + δ_c) × model, with the prior δ_c ~ N(0, r_c²), r_c
  the terms' relative size. Fitting the scale, rather than whitening the data with a
  covariance built from the data, avoids Peelle's pertinent puzzle (a generalised least
  squares fit with a data-based normalisation covariance drifts low on a misfit model); the
  scale's uncertainty reaches the parameters through the Jacobian.
* **Space**: the model's fit variables (:class:`~acquisition.analysis.models.base.Param`):
  log roughness / exponents, linear colour weights, energy-coupled fractions — a box in
  which every point conserves energy. SciPy's ``least_squares`` (trust-region reflective)
  searches it.
* **Spread within a bin**: where a bin gathers samples spread over it (an image's pixels),
  its mean is the model's average over them, f(m) + ½ Σ H_jk C_jk to second order (H the
  model's Hessian in the angles, C the samples' angle covariance the table keeps); the fit
  adds that term, evaluated at the previous solution, and fits again.
* **Start** (no knowledge of the answer): a grid over the shared shape parameters; at each
  node the colour parameters, which enter the model affinely, are solved by bounded linear
  least squares (``lsq_linear``); the best nodes seed the nonlinear fit.
* **Uncertainty**: covariance (JᵀJ)⁻¹ · χ²/dof of the fit variables from the whitened
  Jacobian, propagated to the physical parameters through the Jacobian of the map.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import least_squares, lsq_linear

from acquisition.analysis.fitdata import BinData
from acquisition.analysis.metrics import metrics
from acquisition.analysis.models import CHANNELS, Model
from acquisition.analysis.models.base import Param
from acquisition.analysis.models.cosines import Cosines
from drivers.errors import ConfigError

GRID_NODES_LOG = 9
GRID_NODES_LINEAR = 4
SEEDS = 3
"""Best grid nodes the nonlinear fit starts from."""


@dataclass(frozen=True)
class _Layout:
    """Where each fit variable sits in the flat vector x (log-scaled where the Param says)."""

    params: tuple[Param, ...]

    @property
    def size(self) -> int:
        return sum(p.size for p in self.params)

    def slices(self) -> list[tuple[Param, slice]]:
        out, k = [], 0
        for p in self.params:
            out.append((p, slice(k, k + p.size)))
            k += p.size
        return out

    def values(self, x: np.ndarray) -> dict[str, np.ndarray | float]:
        out: dict[str, np.ndarray | float] = {}
        for p, sl in self.slices():
            v = np.exp(x[sl]) if p.log else np.asarray(x[sl], float)
            out[p.name] = v.copy() if p.per_channel else float(v[0])
        return out

    def vector(self, fit: dict[str, Any]) -> np.ndarray:
        x = np.empty(self.size)
        for p, sl in self.slices():
            v = np.clip(np.broadcast_to(np.asarray(fit[p.name], float), (p.size,)), p.lo, p.hi)
            x[sl] = np.log(np.maximum(v, 1e-300)) if p.log else v
        return x

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = np.empty(self.size), np.empty(self.size)
        for p, sl in self.slices():
            lo[sl], hi[sl] = (np.log(p.lo), np.log(p.hi)) if p.log else (p.lo, p.hi)
        return lo, hi


def common_scale(data: BinData) -> np.ndarray:
    """Relative size r_c (3,) of the common-mode terms per channel (median over bins)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = data.u_common / np.abs(data.values)
    return np.nan_to_num(np.nanmedian(rel, axis=0))


@dataclass
class FitResult:
    """A fitted model: parameters with 1σ, goodness of fit and the literature's metrics."""

    model: Model
    params: dict[str, np.ndarray | float]
    sigma: dict[str, np.ndarray | float]
    chi2_dof: float
    dof: int
    metrics: dict[str, float]
    n_bins: int
    covariance: np.ndarray = field(repr=False)
    """Covariance of the physical parameters, flattened in the model's parameter order."""
    at_bound: tuple[str, ...] = ()
    """Parameters that ended on an edge of the fit box (their 1σ is not meaningful there)."""

    @property
    def poorly_constrained(self) -> tuple[str, ...]:
        """Parameters whose 1σ exceeds their value's magnitude (in any channel): the data
        cannot tell them (e.g. a second lobe the material does not have)."""
        return tuple(p.name for p in self.model.params if p.name not in self.at_bound and np.any(
            np.atleast_1d(self.sigma[p.name]) > np.abs(np.atleast_1d(self.params[p.name]))))

    @property
    def material(self) -> str:
        """A material spec the simulated camera accepts (re-capture the fit)."""
        return self.model.spec(self.params)

    def evaluate(self, theta_i_deg: Any, theta_r_deg: Any, delta_phi_deg: Any) -> np.ndarray:
        """The fitted BRDF (…, 3), sr⁻¹, at (θi, θr, Δφ) in degrees."""
        return self.model(theta_i_deg, theta_r_deg, delta_phi_deg, self.params)

    def to_dict(self) -> dict[str, Any]:
        """``{"model", "params": {P: {"value", "sigma"} | {"R": {..}, "G": {..}, "B": {..}}},
        "chi2_dof", "dof", "bins", "metrics", "material"}``."""
        params: dict[str, Any] = {}
        for p in self.model.params:
            v, s = self.params[p.name], self.sigma[p.name]
            if p.per_channel:
                params[p.name] = {c: {"value": float(v[k]), "sigma": float(s[k])}  # type: ignore[index]
                                  for k, c in enumerate(CHANNELS)}
            else:
                params[p.name] = {"value": float(v), "sigma": float(s)}  # type: ignore[arg-type]
        return {"model": self.model.name, "params": params, "chi2_dof": self.chi2_dof,
                "dof": self.dof, "bins": self.n_bins, "metrics": self.metrics,
                "material": self.material, "at_bound": list(self.at_bound),
                "poorly_constrained": list(self.poorly_constrained)}


class _Problem:
    """The residual function of one model on one table's bins: the model's fit variables,
    then (where the table has common-mode terms) the three nuisance scales δ_c."""

    def __init__(self, model: Model, data: BinData) -> None:
        self.model, self.data = model, data
        self.scale = common_scale(data)
        self.nuisance = bool(np.any(self.scale > 0))
        self.layout = _Layout(model.params)
        self.cos = Cosines.of(*data.angles_deg.T)
        self.correction = np.zeros(data.values.shape)
        """Second-order spread term added to the model (:func:`_spread_correction`)."""

    @property
    def size(self) -> int:
        return self.layout.size + (3 if self.nuisance else 0)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = self.layout.bounds()
        if self.nuisance:
            width = 50.0 * np.maximum(self.scale, 1e-12)
            lo, hi = np.concatenate([lo, -width]), np.concatenate([hi, width])
        return lo, hi

    def physical(self, x: np.ndarray) -> dict[str, np.ndarray | float]:
        return self.model.physical(self.layout.values(x[:self.layout.size]))

    def predict(self, physical: dict[str, np.ndarray | float]) -> np.ndarray:
        return self.model.evaluate(self.cos, physical) + self.correction

    def residuals(self, x: np.ndarray) -> np.ndarray:
        model = self.predict(self.physical(x))
        model = np.where(np.isfinite(model), model, 1e30)  # outside the model's domain
        if not self.nuisance:
            return ((model - self.data.values) / self.data.u_independent).T.ravel()
        delta = x[self.layout.size:]
        r = (model * (1.0 + delta) - self.data.values) / self.data.u_independent
        prior = np.where(self.scale > 0, delta / np.maximum(self.scale, 1e-300), delta * 1e12)
        return np.concatenate([r.T.ravel(), prior])

    def flat_physical(self, x: np.ndarray) -> np.ndarray:
        p = self.physical(x)
        return np.concatenate([np.atleast_1d(np.asarray(p[q.name], float))
                               for q in self.model.params])


def _shared_grid(model: Model) -> list[dict[str, float]]:
    """Nodes over the shared (shape) parameters: geometric for log ones, linear otherwise;
    a second lobe is kept broader than the first."""
    shared = [p for p in model.params if not p.per_channel]
    axes = [np.geomspace(p.lo, p.hi, GRID_NODES_LOG) if p.log
            else np.linspace(p.lo, p.hi, GRID_NODES_LINEAR) for p in shared]
    nodes = [dict(zip([p.name for p in shared], map(float, combo), strict=True))
             for combo in itertools.product(*axes)]
    return [n for n in nodes if n.get("alpha2", np.inf) > n.get("alpha", 0.0)
            and n.get("e2", 0.0) < n.get("e", np.inf)]


def _linear_start(problem: _Problem, shared: dict[str, float]) -> tuple[float, np.ndarray]:
    """At fixed shape parameters, the colour parameters by bounded linear least squares on
    each channel (the model is affine in each of them); returns (cost, fit vector)."""
    model, data = problem.model, problem.data
    fixed = {p.name: np.full(3, p.start) for p in model.params
             if p.per_channel and p.start is not None}
    colour = [p for p in model.params if p.per_channel and p.start is None]
    base = {p.name: np.zeros(3) for p in colour} | fixed | shared
    f0 = problem.predict(base)
    columns = []
    for p in colour:
        unit = dict(base)
        unit[p.name] = np.ones(3)
        columns.append(problem.predict(unit) - f0)
    w = 1.0 / data.u_independent
    physical: dict[str, Any] = dict(shared) | fixed
    for p in colour:
        physical[p.name] = np.zeros(3)
    cost = 0.0
    for c in range(3):
        a = np.stack([col[:, c] for col in columns], axis=1) * w[:, c:c + 1]
        b = (data.values[:, c] - f0[:, c]) * w[:, c]
        sol = lsq_linear(a, b, bounds=(0.0, 1.0))
        cost += float(sol.cost)
        for p, v in zip(colour, sol.x, strict=True):
            physical[p.name][c] = v
    x = np.concatenate([problem.layout.vector(model.fit_values(physical)),
                        np.zeros(problem.size - problem.layout.size)])
    return float(np.sum(problem.residuals(x) ** 2)), x


def _solve(problem: _Problem, x0: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> Any:
    return least_squares(problem.residuals, np.clip(x0, lo, hi), bounds=(lo, hi), method="trf",
                         x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=2000)


def _covariance(problem: _Problem, x: np.ndarray, jac: np.ndarray, chi2_dof: float
                ) -> np.ndarray:
    """Covariance of the physical parameters: J_P (JᵀJ)⁻¹ J_Pᵀ · χ²/dof."""
    cov_x = np.linalg.pinv(jac.T @ jac) * chi2_dof
    lo, hi = problem.bounds()
    jp = np.empty((problem.flat_physical(x).size, x.size))
    for k in range(x.size):
        h = 1e-6 * max(1.0, abs(x[k]))
        up, dn = x.copy(), x.copy()
        up[k], dn[k] = min(x[k] + h, hi[k]), max(x[k] - h, lo[k])
        jp[:, k] = (problem.flat_physical(up) - problem.flat_physical(dn)) / (up[k] - dn[k])
    return jp @ cov_x @ jp.T


SPREAD_STEP_DEG = 0.5
"""Finite-difference step of the Hessian in :func:`_spread_correction`, degrees."""
SPREAD_PASSES = 2


def _spread_correction(model: Model, physical: dict[str, Any], data: BinData) -> np.ndarray:
    """½ Σ_jk H_jk C_jk per bin (N, 3): the model's average over each bin's sample spread minus
    its value at the mean angles, to second order (central differences of SPREAD_STEP_DEG)."""
    cov = data.angle_cov
    assert cov is not None
    h = SPREAD_STEP_DEG
    a = data.angles_deg

    def f(shift: np.ndarray) -> np.ndarray:
        return model.evaluate(Cosines.of(*(a + shift).T), physical)

    unit = np.eye(3) * h
    centre = f(np.zeros(3))
    out = np.zeros_like(centre)
    for j in range(3):
        d2 = (f(unit[j]) - 2.0 * centre + f(-unit[j])) / h**2
        out += 0.5 * d2 * cov[:, j:j + 1]
    for k, (j, m) in enumerate(((0, 1), (0, 2), (1, 2))):
        mixed = (f(unit[j] + unit[m]) - f(unit[j] - unit[m]) - f(-unit[j] + unit[m])
                 + f(-unit[j] - unit[m])) / (4.0 * h**2)
        out += mixed * cov[:, 3 + k:4 + k]
    return np.where(np.isfinite(out), out, 0.0)


def fit_model(model: Model, data: BinData) -> FitResult:
    """Fit ``model`` to the bins ``data`` (see the module docstring)."""
    n_params = _Layout(model.params).size
    dof = 3 * data.n - n_params
    if dof < 1:
        raise ConfigError(f"{data.n} measured bins cannot fit {n_params} parameters of "
                          f"{model.name}: measure more poses or fit a simpler model")
    problem = _Problem(model, data)
    starts = sorted((_linear_start(problem, node) for node in _shared_grid(model)),
                    key=lambda s: s[0])[:SEEDS]
    lo, hi = problem.bounds()
    best = None
    for _, x0 in starts:
        sol = _solve(problem, x0, lo, hi)
        if best is None or sol.cost < best.cost:
            best = sol
    assert best is not None
    spread = data.angle_cov is not None and float(np.max(data.angle_cov[:, :3], initial=0)) > 1e-4
    for _ in range(SPREAD_PASSES if spread else 0):
        problem.correction = _spread_correction(model, problem.physical(best.x), data)
        best = _solve(problem, best.x, lo, hi)
    chi2 = 2.0 * float(best.cost)
    chi2_dof = chi2 / dof
    if not (np.isfinite(chi2) and np.all(np.isfinite(best.jac))):
        raise ConfigError(f"the {model.name} fit did not converge on these {data.n} bins: try "
                          "another model or options")
    cov = _covariance(problem, best.x, best.jac, chi2_dof)
    physical = problem.physical(best.x)
    sigma_flat = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    sigma: dict[str, np.ndarray | float] = {}
    k = 0
    for p in model.params:
        s = sigma_flat[k:k + (3 if p.per_channel else 1)]
        sigma[p.name] = s.copy() if p.per_channel else float(s[0])
        k += s.size
    physical = {q.name: (np.asarray(physical[q.name], float) if q.per_channel
                         else float(physical[q.name])) for q in model.params}
    fitted = problem.predict(physical)
    edge = 1e-6 * np.maximum(hi - lo, 1.0)
    on_edge = (best.x - lo < edge) | (hi - best.x < edge)
    at_bound = tuple(p.name for p, sl in problem.layout.slices() if on_edge[sl].any())
    return FitResult(model, physical, sigma, chi2_dof, dof,
                     metrics(data.values, fitted, data.cos_i, data.solid_angle), data.n, cov,
                     at_bound)
