"""What every analytic BRDF model offers the fitter: named parameters, bounds, evaluation.

A model's *fit variables* (:class:`Param`) are what the fitter moves, each inside a box;
:meth:`Model.physical` maps them to the *physical parameters* (same names) that
:meth:`Model.evaluate` takes. The map is the identity except where energy conservation
couples parameters: a lobe's weight or the diffuse albedo is fitted as a fraction of the room
the other lobes leave, so every point of the box is a BRDF with directional albedo ≤ 1 at every
incidence (:mod:`acquisition.analysis.models.energy`). Colour parameters (albedo, f0, ks) carry
one value per channel (R, G, B); shape parameters (roughness, exponents) are shared.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from acquisition.analysis.models.cosines import Cosines

CHANNELS = ("R", "G", "B")

Values = Mapping[str, np.ndarray | float]
"""Parameter name → value: a float for shared parameters, (3,) for per-channel ones."""


@dataclass(frozen=True)
class Param:
    """One fit variable.

    Attributes
    ----------
    name:
        Also the physical parameter's name.
    per_channel:
        One value per colour channel (R, G, B), else one shared value.
    lo, hi:
        Bounds of the fit variable (for coupled parameters: of the fraction, 0 … 1).
    log:
        Fitted as log(value) (scale parameters spanning decades: roughness, exponents).
    unit:
        Unit of the physical value ("" for dimensionless, "deg", ...).
    coupled:
        The physical value is the fit variable times the room the model's other lobes leave
        (energy conservation), not the fit variable itself.
    start:
        Where the fit starts for a colour parameter the model is not affine in (a conductor's
        η and k); None: the start solves for it linearly.
    """

    name: str
    per_channel: bool
    lo: float
    hi: float
    log: bool = False
    unit: str = ""
    coupled: bool = False
    start: float | None = None

    @property
    def size(self) -> int:
        return 3 if self.per_channel else 1


class Model(ABC):
    """An isotropic analytic BRDF, RGB, in sr⁻¹."""

    name: str
    params: tuple[Param, ...]

    @abstractmethod
    def evaluate(self, cos: Cosines, p: Values) -> np.ndarray:
        """BRDF (…, 3) in sr⁻¹ at the configurations ``cos`` for physical parameters ``p``."""

    def physical(self, fit: Values) -> dict[str, np.ndarray | float]:
        """Physical parameters from fit variables (identity unless the model couples them)."""
        return dict(fit)

    def fit_values(self, p: Values) -> dict[str, np.ndarray | float]:
        """Fit variables that give physical parameters ``p`` (inverse of :meth:`physical`)."""
        return dict(p)

    @abstractmethod
    def spec(self, p: Values) -> str:
        """A material spec the simulated camera accepts for physical parameters ``p``."""

    def __call__(self, theta_i_deg: np.ndarray | float, theta_r_deg: np.ndarray | float,
                 delta_phi_deg: np.ndarray | float, p: Values) -> np.ndarray:
        """BRDF (…, 3) in sr⁻¹ at (θi, θr, Δφ) in degrees; 0 below the horizon."""
        cos = Cosines.of(theta_i_deg, theta_r_deg, delta_phi_deg)
        value = self.evaluate(cos, p)
        return np.where(cos.above[..., None], value, 0.0)

    def param(self, name: str) -> Param:
        return next(q for q in self.params if q.name == name)


def rgb(value: np.ndarray | float) -> np.ndarray:
    """A per-channel value as a (3,) array (a scalar applies to every channel)."""
    return np.broadcast_to(np.asarray(value, dtype=np.float64), (3,)).copy()


def spec_value(value: np.ndarray | float) -> str:
    """A value as material specs write it: ``0.2``, or ``0.2/0.3/0.4`` per channel (R/G/B)."""
    arr = np.atleast_1d(np.asarray(value, dtype=np.float64))
    if arr.size == 1 or np.all(arr == arr[0]):
        return f"{float(arr[0]):.9g}"
    return "/".join(f"{float(v):.9g}" for v in arr)
