"""Weighted nonlinear least squares that says what it cannot determine.

:func:`solve` minimises the sum of squared normalised residuals (residual / its 1σ) by
Gauss–Newton with a numerical Jacobian, and reports the parameters' covariance (scaled by
χ²/dof when the fit is worse than its stated uncertainties), the rank and condition number of
the problem (Jacobian columns scaled by each parameter's typical size), and every combination
of parameters the data cannot determine — named, never guessed: steps are taken only within
the observable subspace (the parameters keep their starting values along an unobservable
combination) and every parameter taking part in one gets an infinite σ.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

RANK_TOL = 1e-6
"""A singular value below this fraction of the largest one is a direction the data miss."""
STEPS = 10
NAME_TOL = 0.01
"""Coefficients of an unobservable combination below this (of its largest) are not named."""


@dataclass(frozen=True)
class LsqResult:
    """A least-squares solution (see the module docstring)."""

    names: tuple[str, ...]
    values: np.ndarray
    covariance: np.ndarray
    """(P, P); rows and columns of unobservable parameters are inf."""
    chi2_dof: float
    dof: int
    rank: int
    condition: float
    unobservable: tuple[str, ...]
    """Combinations the data cannot determine, e.g. ``"light_theta − 2·tilt_about_y"``."""
    residuals: np.ndarray
    """Normalised residuals at the solution."""

    def sigma(self, name: str) -> float:
        k = self.names.index(name)
        return float(math.sqrt(self.covariance[k, k]))


def _jacobian(f: Callable[[np.ndarray], np.ndarray], x: np.ndarray, r0: np.ndarray,
              scales: np.ndarray) -> np.ndarray:
    jac = np.empty((r0.size, x.size))
    for k in range(x.size):
        h = 1e-4 * scales[k]
        up, down = x.copy(), x.copy()
        up[k] += h
        down[k] -= h
        jac[:, k] = (f(up) - f(down)) / (2.0 * h)
    return jac


def _combination(vector: np.ndarray, names: Sequence[str]) -> str:
    v = vector / vector[np.argmax(np.abs(vector))]
    parts = []
    for c, n in zip(v, names, strict=True):
        if abs(c) < NAME_TOL:
            continue
        mag = "" if math.isclose(abs(c), 1.0, abs_tol=5e-3) else f"{abs(c):.2g}·"
        parts.append(("− " if c < 0 else "+ ") + mag + n)
    text = " ".join(parts)
    return text[2:] if text.startswith("+ ") else "−" + text[1:]


def solve(residual: Callable[[np.ndarray], np.ndarray], x0: Sequence[float],
          names: Sequence[str], scales: Sequence[float]) -> LsqResult:
    """Minimise Σ residual(x)² (residuals already divided by their 1σ) from ``x0``;
    ``scales``: each parameter's typical size (its unit for rank and conditioning)."""
    x = np.asarray(x0, float).copy()
    sc = np.asarray(scales, float)
    for _ in range(STEPS):
        r = residual(x)
        jac = _jacobian(residual, x, r, sc) * sc
        u, s, vt = np.linalg.svd(jac, full_matrices=False)
        keep = s > RANK_TOL * s[0]
        step = vt[keep].T @ ((u[:, keep].T @ r) / s[keep])
        x -= step * sc
        if np.max(np.abs(step)) < 1e-9:
            break
    r = residual(x)
    jac = _jacobian(residual, x, r, sc) * sc
    _, s, vt = np.linalg.svd(jac)  # full vt: with fewer data than parameters the null space
    rank = int(np.sum(s > RANK_TOL * s[0]))  # has more directions than s has values
    dof = max(r.size - rank, 1)
    chi2 = float(r @ r) / dof
    inv = (vt[:rank].T / s[:rank] ** 2) @ vt[:rank]
    cov = inv * np.outer(sc, sc) * max(chi2, 1.0)
    null = vt[rank:]
    lost = (np.any(np.abs(null) > NAME_TOL * np.abs(null).max(axis=1, keepdims=True), axis=0)
            if len(null) else np.zeros(len(x), bool))
    cov[lost, :] = np.inf
    cov[:, lost] = np.inf
    return LsqResult(tuple(names), x, cov, chi2, dof, rank, float(s[0] / s[rank - 1]),
                     tuple(_combination(v, names) for v in null), r)
