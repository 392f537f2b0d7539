"""RGL-EPFL measured materials (RGB ``.bsdf`` files, Dupuy & Jakob 2018) as simulated
materials, evaluated as Mitsuba 3's ``measured`` plug-in evaluates them (RGB variants).

The file's fields: ``theta_i`` and ``phi_i`` (radians) at which the tables are given for the
direction ωa on the viewer's side; ``ndf`` D(m) and ``sigma`` σ(ωa) (its projected area), both
H × W grids over u = (√(θ / 90°), (φ + 180°) / 360°); ``vndf`` (φi, θi, H, W), the density of
the visible normals m seen from ωa over the same u (of m, φ relative to ωa's azimuth when the
material is isotropic, i.e. ``phi_i`` holds ≤ 2 values); ``rgb`` (φi, θi, 3, N, N), the
reflectance at the points of the unit square that the VNDF warp sends to m; ``luminance``
(for sampling, unused here) and ``jacobian`` (uint8). With ωb the other direction (the
light) and m = (ωa + ωb) / |ωa + ωb|:

    f(ωa, ωb) cos θb = rgb(warp⁻¹(u(m)); φa, θa) · [D(u(m)) / (4 σ(u(ωa))) if jacobian]

Anisotropic files tabulate ``phi_i`` over a quarter or a half turn (``reduction`` 4 or 2:
2π over the range, rounded); both directions are then mirrored into it first, x and y signs
(4) or both by the sign of y (2). Isotropic files are not mirrored (Mitsuba 3.9 leaves its
reduction uninitialised for them and may mirror by y: no difference for tables symmetric in
relative azimuth, as an isotropic material's are).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from drivers.errors import MaterialError
from simulators.materials import Material
from simulators.measured.tensor import read_tensor_fields
from simulators.measured.warp import BilinearTable, MarginalWarp

FIELD_RANKS = {"theta_i": 1, "phi_i": 1, "ndf": 2, "sigma": 2, "vndf": 4, "luminance": 4,
               "rgb": 5, "description": 1, "jacobian": 1}
"""Every field the evaluation needs (``luminance`` only to match the renderer's checks)."""


def _check_fields(fields: dict[str, np.ndarray], path: Path | str) -> None:
    """What Mitsuba's plug-in checks before loading an RGB file; one line on failure."""
    if "wavelengths" in fields:
        raise MaterialError(f"{path} is a spectral .bsdf: the simulated camera renders RGB, "
                            "give the material's RGB file (the RGL database's '_rgb.bsdf')")
    missing = sorted(set(FIELD_RANKS) - set(fields))
    if missing:
        raise MaterialError(f"{path} is not an RGL .bsdf file: no field {', '.join(missing)}")
    wrong = [n for n, rank in FIELD_RANKS.items() if fields[n].ndim != rank]
    wrong += [n for n in ("theta_i", "phi_i", "ndf", "sigma", "vndf", "rgb")
              if fields[n].dtype != np.float32]
    n_phi, n_theta = fields["phi_i"].size, fields["theta_i"].size
    if not wrong and (fields["vndf"].shape[:2] != (n_phi, n_theta)
                      or fields["rgb"].shape[:3] != (n_phi, n_theta, 3)
                      or fields["jacobian"].size != 1):
        wrong.append("vndf/rgb/jacobian shape")
    if wrong:
        raise MaterialError(f"{path}: malformed RGL .bsdf file (field {wrong[0]}); download or "
                            "export it again")


def _elevation(v: np.ndarray) -> np.ndarray:
    """Polar angle (rad) of unit vectors (n, 3), well conditioned at the pole and horizon."""
    return np.arctan2(np.hypot(v[:, 0], v[:, 1]), v[:, 2])


def _u_of_theta(theta_rad: np.ndarray) -> np.ndarray:
    return np.sqrt(np.maximum(theta_rad, 0.0) / (np.pi / 2))


def _u_of_phi(phi_rad: np.ndarray) -> np.ndarray:
    return (phi_rad + np.pi) / (2 * np.pi)


class RglFile:
    """An RGB ``.bsdf`` file's tables, ready to evaluate (module docstring)."""

    def __init__(self, fields: dict[str, np.ndarray], path: str | Path | None = None) -> None:
        _check_fields(fields, path or "<fields>")
        self.path = None if path is None else Path(path)
        phi_i = fields["phi_i"].astype(np.float64)
        theta_i = fields["theta_i"].astype(np.float64)
        self.isotropic = phi_i.size <= 2
        self.reduction = 0 if self.isotropic else int(np.rint(2 * np.pi / (phi_i[-1] - phi_i[0])))
        self.jacobian = bool(fields["jacobian"].ravel()[0])
        self.ndf = BilinearTable(fields["ndf"])
        self.sigma = BilinearTable(fields["sigma"])
        self.vndf = MarginalWarp(fields["vndf"], (phi_i, theta_i))
        self.rgb = BilinearTable(fields["rgb"], (phi_i, theta_i, np.arange(3.0)))

    def _mirror_into_table(self, wa: np.ndarray, wb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Both directions mirrored so that ωa lies where the tables are (x, y ≤ 0)."""
        if self.reduction < 2:
            return wa, wb
        sign_y = np.where(np.signbit(wa[:, 1]), 1.0, -1.0)
        sign_x = np.where(np.signbit(wa[:, 0]), 1.0, -1.0) if self.reduction == 4 else sign_y
        flip = np.stack([sign_x, sign_y, np.ones_like(sign_x)], axis=-1)
        return wa * flip, wb * flip

    def eval_cos(self, wa: np.ndarray, wb: np.ndarray) -> np.ndarray:
        """f(ωa, ωb) cos θb (n, 3) for unit vectors (n, 3): ωa on the viewer's side (the
        renderer's ``si.wi``), ωb the light's; 0 where either is at or below the horizon."""
        up = (wa[:, 2] > 0) & (wb[:, 2] > 0)
        wa, wb = self._mirror_into_table(wa, wb)
        m = wa + wb
        m = m / np.maximum(np.linalg.norm(m, axis=-1, keepdims=True), 1e-300)
        theta_a, phi_a = _elevation(wa), np.arctan2(wa[:, 1], wa[:, 0])
        phi_m = np.arctan2(m[:, 1], m[:, 0]) - (phi_a if self.isotropic else 0.0)
        u_phi_m = _u_of_phi(phi_m)
        u_m = np.stack([_u_of_theta(_elevation(m)), u_phi_m - np.floor(u_phi_m)], axis=-1)
        params = np.stack([phi_a, theta_a], axis=-1)
        square = self.vndf.invert(u_m, params)
        value = np.stack([self.rgb.eval(square, np.column_stack([params, np.full(len(wa), c)]))
                          for c in range(3)], axis=-1)
        if self.jacobian:
            u_a = np.stack([_u_of_theta(theta_a), _u_of_phi(phi_a)], axis=-1)
            value = value * (self.ndf.eval(u_m) / (4.0 * self.sigma.eval(u_a)))[:, None]
        return np.where(up[:, None], value, 0.0)


def read_rgl_file(path: str | Path) -> RglFile:
    """Read an RGB ``.bsdf`` file; :class:`MaterialError` naming what is wrong."""
    return RglFile(read_tensor_fields(path), path)


class RglMaterial(Material):
    """An RGL ``.bsdf`` file as the simulated sample: f = (f cos θi) / cos θi of the file,
    0 at or below the horizon."""

    def __init__(self, rgl: RglFile, spec: str) -> None:
        self.rgl = rgl
        self.spec = spec

    def eval_vectors(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        wi, wo = np.broadcast_arrays(np.asarray(wi, np.float64), np.asarray(wo, np.float64))
        shape = wi.shape[:-1]
        light, view = wi.reshape(-1, 3), wo.reshape(-1, 3)
        with np.errstate(invalid="ignore", divide="ignore"):
            value = self.rgl.eval_cos(view, light)
            brdf = np.where(light[:, 2:3] > 0, value / light[:, 2:3], 0.0)
        return brdf.reshape(*shape, 3)

    def __repr__(self) -> str:
        return f"RglMaterial({self.spec!r})"
