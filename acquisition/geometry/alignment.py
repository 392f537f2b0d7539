"""A rig's measured alignment: the axes' zero offsets and the sample's tilt on its holder.

The geometric calibration (``gonio calibrate geometry``) measures how the real rig differs from
its rig file's model, and the planner and the reduction apply it through
:class:`~acquisition.geometry.kinematics.calibrated.CalibratedKinematics`. Conventions:

* zero offset of an axis: the arm's true angle minus the angle the servo's ticks give through
  the rig file (``deg = direction × (ticks − zero_tick) × 360 / 4096``), degrees;
* sample tilt ``(about_x, about_y)``: the sample's true axes are the holder's (the nominal
  sample frame of the kinematics; on a coaxial rig the stage's, which turns with the stage
  rotation) turned about x by ``about_x``, then about the holder's y by ``about_y``: the true
  normal is ``Ry(about_y) · Rx(about_x) · z ≈ (about_y, −about_x, 1)``;
* backlash of an axis: the width of its gears' play (deg); an arm stops ``backlash / 2``
  short of the centre of its play, behind the side it came from. Captures approach every
  target from the side :func:`~acquisition.geometry.approach.approach_signs` gives, so the
  arms stand at the joints plus :meth:`Alignment.effective_offsets`;
* camera pointing (image-based rigs): the optical axis turned towards the image's +x, then
  +y (deg) (:mod:`acquisition.geometry.pinhole`), from where the sphere's centre falls in the
  image;
* parameters, in :attr:`Alignment.param_names` order: one offset per calibrated axis (named
  by the axis), ``tilt_about_x`` and ``tilt_about_y``, ``backlash:AXIS`` per measured
  backlash and, where the calibration fitted it with the rest, the pointing's
  :data:`POINTING_PARAMS`; :attr:`Alignment.covariance_deg2` is their covariance (deg²).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from acquisition.geometry.approach import approach_signs

TILT_PARAMS = ("tilt_about_x", "tilt_about_y")
"""Names of the sample-tilt parameters (deg)."""
BACKLASH_PREFIX = "backlash:"
"""Prefix of a backlash parameter's name (``backlash:light_theta``)."""
POINTING_PARAMS = ("camera_pointing_x", "camera_pointing_y")
"""Names of the camera pointing's parameters (image-based rigs), deg."""


def tilt_matrix(about_x_deg: float, about_y_deg: float) -> np.ndarray:
    """Ry(about_y) · Rx(about_x): its columns are the sample's true axes in the holder frame."""
    a, b = math.radians(about_x_deg), math.radians(about_y_deg)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(a), -math.sin(a)],
                   [0.0, math.sin(a), math.cos(a)]])
    ry = np.array([[math.cos(b), 0.0, math.sin(b)], [0.0, 1.0, 0.0],
                   [-math.sin(b), 0.0, math.cos(b)]])
    return ry @ rx


@dataclass(frozen=True)
class Alignment:
    """Zero offsets (deg, by axis), sample tilt (deg) and backlash (deg, by axis), with
    their covariance (see the module docstring)."""

    zero_offset_deg: Mapping[str, float] = field(default_factory=dict)
    sample_tilt_deg: tuple[float, float] = (0.0, 0.0)
    param_names: tuple[str, ...] = ()
    covariance_deg2: np.ndarray | None = None
    backlash_deg: Mapping[str, float] = field(default_factory=dict)
    camera_pointing_deg: tuple[float, float] = (0.0, 0.0)
    camera_pointing_sigma_deg: tuple[float, float] = (0.0, 0.0)

    @property
    def values(self) -> np.ndarray:
        """The parameters (deg) in :attr:`param_names` order."""
        return np.array([self.value(n) for n in self.param_names], float)

    def value(self, name: str) -> float:
        """Parameter ``name`` (deg)."""
        if name in TILT_PARAMS:
            return self.sample_tilt_deg[TILT_PARAMS.index(name)]
        if name in POINTING_PARAMS:
            return self.camera_pointing_deg[POINTING_PARAMS.index(name)]
        if name.startswith(BACKLASH_PREFIX):
            return self.backlash_deg.get(name.removeprefix(BACKLASH_PREFIX), 0.0)
        return self.zero_offset_deg.get(name, 0.0)

    def sigma(self, name: str) -> float:
        """1σ of parameter ``name`` (deg); 0 without a covariance."""
        if self.covariance_deg2 is None or name not in self.param_names:
            return 0.0
        k = self.param_names.index(name)
        return float(math.sqrt(max(self.covariance_deg2[k, k], 0.0)))

    def offsets(self, joint_names: Sequence[str]) -> np.ndarray:
        """Zero offsets (deg) in ``joint_names`` order (0 for axes not calibrated)."""
        return np.array([self.zero_offset_deg.get(n, 0.0) for n in joint_names], float)

    def effective_offsets(self, joint_names: Sequence[str], joints: np.ndarray,
                          lower_deg: np.ndarray) -> np.ndarray:
        """Where the arms stand relative to joints (N, J) approached as captures approach
        them: zero offset − side × backlash / 2, deg (N, J)."""
        half = np.array([self.backlash_deg.get(n, 0.0) for n in joint_names], float) / 2.0
        return self.offsets(joint_names) - approach_signs(joints, lower_deg) * half

    def rotation(self) -> np.ndarray:
        """:func:`tilt_matrix` of the sample tilt."""
        return tilt_matrix(*self.sample_tilt_deg)

    def shifted(self, name: str, delta_deg: float) -> Alignment:
        """A copy with parameter ``name`` changed by ``delta_deg`` (for Jacobians)."""
        if name in TILT_PARAMS:
            tilt = list(self.sample_tilt_deg)
            tilt[TILT_PARAMS.index(name)] += delta_deg
            return replace(self, sample_tilt_deg=(tilt[0], tilt[1]))
        if name in POINTING_PARAMS:
            pointing = list(self.camera_pointing_deg)
            pointing[POINTING_PARAMS.index(name)] += delta_deg
            return replace(self, camera_pointing_deg=(pointing[0], pointing[1]))
        if name.startswith(BACKLASH_PREFIX):
            axis = name.removeprefix(BACKLASH_PREFIX)
            backlash = dict(self.backlash_deg)
            backlash[axis] = backlash.get(axis, 0.0) + delta_deg
            return replace(self, backlash_deg=backlash)
        offsets = dict(self.zero_offset_deg)
        offsets[name] = offsets.get(name, 0.0) + delta_deg
        return replace(self, zero_offset_deg=offsets)

    @property
    def is_identity(self) -> bool:
        return not any(self.zero_offset_deg.values()) and not any(self.sample_tilt_deg) and \
            not any(self.backlash_deg.values())

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON types (a calibration bundle's ``geometry`` section)."""
        cov = None if self.covariance_deg2 is None else [
            [float(v) if math.isfinite(v) else None for v in row]  # null: not determined
            for row in np.asarray(self.covariance_deg2, float).tolist()]
        return {"zero_offset_deg": {k: float(v) for k, v in self.zero_offset_deg.items()},
                "sample_tilt_deg": {"about_x": self.sample_tilt_deg[0],
                                    "about_y": self.sample_tilt_deg[1]},
                "backlash_deg": {k: float(v) for k, v in self.backlash_deg.items()},
                "camera_pointing_deg": {"x": self.camera_pointing_deg[0],
                                        "y": self.camera_pointing_deg[1],
                                        "sigma_x": self.camera_pointing_sigma_deg[0],
                                        "sigma_y": self.camera_pointing_sigma_deg[1]},
                "parameters": list(self.param_names), "covariance_deg2": cov}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Alignment:
        """Inverse of :meth:`to_dict`; raises KeyError/TypeError/ValueError on a malformed one."""
        tilt = data.get("sample_tilt_deg", {})
        cov = data.get("covariance_deg2")
        names = tuple(str(n) for n in data.get("parameters", ()))
        covariance = None if cov is None else np.array(
            [[math.inf if v is None else float(v) for v in row] for row in cov],
            float).reshape(len(names), len(names))
        pointing = data.get("camera_pointing_deg", {})
        return cls({str(k): float(v) for k, v in data.get("zero_offset_deg", {}).items()},
                   (float(tilt.get("about_x", 0.0)), float(tilt.get("about_y", 0.0))),
                   names, covariance,
                   {str(k): float(v) for k, v in data.get("backlash_deg", {}).items()},
                   (float(pointing.get("x", 0.0)), float(pointing.get("y", 0.0))),
                   (float(pointing.get("sigma_x", 0.0)), float(pointing.get("sigma_y", 0.0))))
