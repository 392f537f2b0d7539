"""RGL-EPFL measured materials (``.bsdf``, Dupuy & Jakob 2018), the format Mitsuba 3's
``measured`` plug-in loads: write a BRDF into one, read and evaluate one.

A ``.bsdf`` is a tensor file (:mod:`acquisition.formats.tensorfile`) whose fields describe a
BRDF reparameterised by a microfacet distribution D. For each direction ωa (``theta_i``,
``phi_i``) the visible normals m, with density ∝ ⟨ωa, m⟩ D(m) (the ``vndf``, tabulated over
u = (√(θm / 90°), (φm − φa + 180°) / 360°)), are warped from the unit square by a continuous
marginal/conditional warp (:mod:`acquisition.formats.marginal2d`); the data (``rgb``) are
tabulated on a regular grid of that unit square, and the direction they belong to is ωb,
ωa mirrored about m. The renderer evaluates

    eval(ωa, ωb) = rgb(warp⁻¹(u(m))) · D(m) / (4 σ(ωa))     (``jacobian`` = 1)

with m = normalize(ωa + ωb), D the ``ndf`` field and σ (``sigma``) the projected area;
eval = f(ωa, ωb) cos θb, Mitsuba's BSDF value (ωa is its ``si.wi``, towards the viewer; ωb
its ``wo``, towards the light). ``luminance`` is the rgb data's luminance, which the
renderer samples before the VNDF. Every table is interpolated linearly in θa between the
``theta_i`` values. See docs/formats.md for the fields and sizes gonio writes.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from acquisition.formats.interpolate import Brdf
from acquisition.formats.marginal2d import Marginal2D
from acquisition.formats.ndf import Ndf, retro_ndf
from acquisition.formats.tensorfile import is_tensor_file, read_tensor_file, write_tensor_file
from drivers.errors import ConfigError

WHAT = "RGL .bsdf file"
GENERATOR = "gonio"
LUMINANCE_RGB = np.array([0.212671, 0.715160, 0.072169])
"""Rec. 709 / sRGB luminance weights (linear RGB)."""


@dataclass(frozen=True)
class Grid:
    """The sizes gonio writes (docs/formats.md)."""

    theta_i_count: int = 46
    """``theta_i`` values, evenly spaced over 0–90°."""
    warp_res: int = 64
    """``ndf``, ``sigma`` and ``vndf`` grids: warp_res × warp_res."""
    data_res: int = 64
    """``rgb`` and ``luminance`` grids: data_res × data_res."""


DEFAULT_GRID = Grid()


# ------------------------------------------------------------------------------ angles
def elevation(d: np.ndarray) -> np.ndarray:
    """θ of unit vectors (…, 3), radians, computed from the chord to +z (stable near 0)."""
    dist = np.sqrt(d[..., 0] ** 2 + d[..., 1] ** 2 + (d[..., 2] - 1.0) ** 2)
    return 2.0 * np.arcsin(np.clip(0.5 * dist, -1.0, 1.0))


def theta_to_u(theta_rad: np.ndarray) -> np.ndarray:
    return np.sqrt(np.maximum(theta_rad, 0.0) * (2.0 / np.pi))


def phi_to_u(phi_rad: np.ndarray) -> np.ndarray:
    return (phi_rad + np.pi) / (2.0 * np.pi)


def spherical(theta_rad: np.ndarray, phi_rad: np.ndarray) -> np.ndarray:
    st = np.sin(theta_rad)
    return np.stack([st * np.cos(phi_rad), st * np.sin(phi_rad), np.cos(theta_rad)], axis=-1)


def directions(theta_i_deg: Any, theta_r_deg: Any, delta_phi_deg: Any) -> tuple[np.ndarray, np.ndarray]:
    """Unit light and view vectors for (θi, θr, Δφ) in degrees: light at azimuth 0, view at Δφ."""
    ti, tr, dp = np.broadcast_arrays(*(np.radians(np.asarray(a, float))
                                       for a in (theta_i_deg, theta_r_deg, delta_phi_deg)))
    return spherical(ti, np.zeros_like(ti)), spherical(tr, dp)


# ------------------------------------------------------------------------------ reading
_REQUIRED = {"theta_i": 1, "phi_i": 1, "ndf": 2, "sigma": 2, "vndf": 4, "luminance": 4,
             "description": 1, "jacobian": 1}


def _check_fields(fields: dict[str, np.ndarray], path: Path | str) -> None:
    """The structure Mitsuba's ``measured`` plug-in checks before loading; one line on failure."""
    if "wavelengths" in fields:
        raise ConfigError(f"{path} is a spectral .bsdf: gonio reads the RGB version of a "
                          "material (the RGL database's '_rgb.bsdf' file)")
    missing = [n for n in (*_REQUIRED, "rgb") if n not in fields]
    if missing:
        raise ConfigError(f"{path}: not an RGL .bsdf file (missing field(s) {', '.join(missing)})")
    ni, np_ = fields["theta_i"].size, fields["phi_i"].size
    rgb, lum, vndf = fields["rgb"], fields["luminance"], fields["vndf"]
    problems = [f"{n} must have rank {r}" for n, r in _REQUIRED.items() if fields[n].ndim != r]
    problems += [f"{n} must be float32" for n in ("theta_i", "phi_i", "ndf", "sigma", "vndf",
                                                 "luminance", "rgb")
                 if fields[n].dtype != np.float32]
    problems += [f"{n} must be uint8" for n in ("description", "jacobian")
                 if fields[n].dtype != np.uint8]
    if rgb.ndim != 5 or rgb.shape[:3] != (np_, ni, 3) or rgb.shape[3] != rgb.shape[4]:
        problems.append(f"rgb is shaped {rgb.shape}, expected ({np_}, {ni}, 3, N, N)")
    if lum.ndim == 4 and rgb.ndim == 5 and lum.shape != (np_, ni, *rgb.shape[3:]):
        problems.append(f"luminance is shaped {lum.shape}, expected ({np_}, {ni}, N, N)")
    if vndf.ndim == 4 and vndf.shape[:2] != (np_, ni):
        problems.append(f"vndf is shaped {vndf.shape}, expected ({np_}, {ni}, H, W)")
    if fields["jacobian"].size != 1:
        problems.append("jacobian must hold one value")
    if problems:
        raise ConfigError(f"{path}: malformed RGL .bsdf file ({problems[0]}); export it again")


class RglBsdf:
    """A ``.bsdf`` material, evaluated from its RGL fields alone as the reference evaluator
    does (module docstring)."""

    def __init__(self, fields: dict[str, np.ndarray], path: str | os.PathLike[str] | None = None
                 ) -> None:
        _check_fields(fields, path or "<fields>")
        self.fields = fields
        self.path = None if path is None else Path(path)
        f64 = {k: np.asarray(v, np.float64) for k, v in fields.items() if v.dtype == np.float32}
        self.phi_i, self.theta_i = f64["phi_i"], f64["theta_i"]
        self.isotropic = self.phi_i.size <= 2
        self.reduction = 0 if self.isotropic else int(np.rint(
            2 * np.pi / (self.phi_i[-1] - self.phi_i[0])))
        self.jacobian = bool(fields["jacobian"][0])
        params = [self.phi_i, self.theta_i]
        self.ndf = Marginal2D(f64["ndf"], normalize=False, sampling=False)
        self.sigma = Marginal2D(f64["sigma"], normalize=False, sampling=False)
        self.vndf = Marginal2D(f64["vndf"], params)
        self.rgb = Marginal2D(f64["rgb"], [*params, np.arange(3.0)], normalize=False,
                              sampling=False)

    @property
    def description(self) -> str:
        return bytes(self.fields["description"]).decode("utf-8", "replace")

    @property
    def provenance(self) -> dict[str, Any]:
        """The description as JSON when gonio wrote it, else ``{"description": text}``."""
        try:
            value = json.loads(self.description)
        except json.JSONDecodeError:
            return {"description": self.description}
        return value if isinstance(value, dict) else {"description": self.description}

    def _reduce(self, wa: np.ndarray, wb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Fold both directions into the tabulated azimuth range (symmetric anisotropic data)."""
        if self.reduction < 2:
            return wa, wb
        sy = wa[:, 1].copy()
        sx = wa[:, 0].copy() if self.reduction == 4 else sy
        flip = np.stack([np.where(np.signbit(sx), 1.0, -1.0), np.where(np.signbit(sy), 1.0, -1.0),
                         np.ones(len(wa))], axis=-1)
        return wa * flip, wb * flip

    def eval_cos(self, wa: np.ndarray, wb: np.ndarray) -> np.ndarray:
        """The renderer's value f(ωa, ωb) cos θb (N, 3) for unit vectors ωa (viewer side) and
        ωb (light side), (N, 3) each; 0 where either is at or below the horizon."""
        wa = np.asarray(wa, float).reshape(-1, 3)
        wb = np.asarray(wb, float).reshape(-1, 3)
        active = (wa[:, 2] > 0) & (wb[:, 2] > 0)
        wa, wb = self._reduce(wa, wb)
        h = wa + wb
        m = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
        theta_a, phi_a = elevation(wa), np.arctan2(wa[:, 1], wa[:, 0])
        phi_m = np.arctan2(m[:, 1], m[:, 0]) - (phi_a if self.isotropic else 0.0)
        u_m = np.stack([theta_to_u(elevation(m)), phi_to_u(phi_m)], axis=-1)
        u_m[:, 1] -= np.floor(u_m[:, 1])
        params = np.stack([phi_a, theta_a], axis=-1)
        sample, _ = self.vndf.invert(u_m, params)
        out = np.stack([self.rgb.eval(sample, np.column_stack([params, np.full(len(wa), c)]))
                        for c in range(3)], axis=-1)
        if self.jacobian:
            u_a = np.stack([theta_to_u(theta_a), phi_to_u(phi_a)], axis=-1)
            out *= (self.ndf.eval(u_m) / (4.0 * self.sigma.eval(u_a)))[:, None]
        return np.where(active[:, None], out, 0.0)

    def eval_vectors(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """BRDF (…, 3) in sr⁻¹ for unit light ``wi`` and view ``wo`` vectors (…, 3), normal +z;
        0 at or below the horizon."""
        wi, wo = np.broadcast_arrays(np.asarray(wi, float), np.asarray(wo, float))
        shape = wi.shape[:-1]
        cos_light = wi.reshape(-1, 3)[:, 2]
        value = self.eval_cos(wo.reshape(-1, 3), wi.reshape(-1, 3))
        with np.errstate(invalid="ignore", divide="ignore"):
            brdf = np.where(cos_light[:, None] > 0, value / cos_light[:, None], 0.0)
        return brdf.reshape(*shape, 3)

    def __call__(self, theta_i_deg: Any, theta_r_deg: Any, delta_phi_deg: Any) -> np.ndarray:
        """BRDF (…, 3) in sr⁻¹ at (θi, θr, Δφ) in degrees (light at azimuth 0, view at Δφ)."""
        return self.eval_vectors(*directions(theta_i_deg, theta_r_deg, delta_phi_deg))


def read_bsdf(path: str | os.PathLike[str]) -> RglBsdf:
    """Read an RGB ``.bsdf`` file; :class:`ConfigError` naming what is wrong."""
    return RglBsdf(read_tensor_file(path), path)


def is_gonio_bsdf(path: str | os.PathLike[str]) -> bool:
    """True for a ``.bsdf`` file gonio wrote (one it may replace)."""
    if not is_tensor_file(path):
        return False
    try:
        text = bytes(read_tensor_file(path).get("description", b"")).decode("utf-8")
        return json.loads(text).get("generator") == GENERATOR
    except (ConfigError, UnicodeDecodeError, json.JSONDecodeError, AttributeError):
        return False


# ------------------------------------------------------------------------------ writing
def _vndf_density(ndf_row: np.ndarray, theta_a: np.ndarray, res: int) -> np.ndarray:
    """The VNDF ⟨ωa, m⟩⁺ D(m) as a density of u (× dω_m/du = 2π² u sin θm), unnormalised, on
    the res × res u-grid, for each θa: (1, Nθ, res, res)."""
    u = np.linspace(0.0, 1.0, res)
    tm = u[None, :] ** 2 * (np.pi / 2)
    pm = (2.0 * u[:, None] - 1.0) * np.pi
    m = spherical(np.broadcast_to(tm, (res, res)), np.broadcast_to(pm, (res, res)))
    wa = spherical(theta_a, np.zeros_like(theta_a))
    cos = np.maximum(np.einsum("kc,yxc->kyx", wa, m), 0.0)
    jac = 2 * np.pi ** 2 * u[None, :] * np.sin(tm)          # dω_m / du
    return (cos * (ndf_row[None, :] * jac)[None])[None]


def _node_directions(warp: Marginal2D, theta_a: np.ndarray, nodes: int
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Where the warp sends the data grid's nodes s = (j, k) / (nodes − 1) for each θa (φa = 0):
    (θa per node, u of m, ωa, ωb), nodes ordered θa, then rows (k), then columns (j)."""
    s = np.linspace(0.0, 1.0, nodes)
    sx, sy = np.meshgrid(s, s)
    n = theta_a.size * nodes * nodes
    ta = np.repeat(theta_a, nodes * nodes)
    pts = np.tile(np.column_stack([sx.ravel(), sy.ravel()]), (theta_a.size, 1))
    u_m, _ = warp.sample(pts, np.column_stack([np.zeros(n), ta]))
    m = spherical(u_m[:, 0] ** 2 * (np.pi / 2), (2.0 * u_m[:, 1] - 1.0) * np.pi)
    wa = spherical(ta, np.zeros(n))
    wb = 2.0 * np.sum(wa * m, axis=-1, keepdims=True) * m - wa
    return ta, u_m, wa, wb


def resample(brdf: Brdf, ndf: Ndf, grid: Grid = DEFAULT_GRID) -> dict[str, np.ndarray]:
    """Every field but ``description``: ``brdf`` (θi light, θr view, Δφ in degrees → (…, 3)
    sr⁻¹) on the RGL grid, its values exact at the grid's nodes."""
    res, nd = grid.warp_res, grid.data_res
    u = np.linspace(0.0, 1.0, res)
    theta_i = np.radians(np.linspace(0.0, 90.0, grid.theta_i_count)).astype(np.float32)
    phi_i = np.zeros(1, np.float32)
    ndf_grid = np.tile(ndf(u ** 2 * (np.pi / 2)), (res, 1)).astype(np.float32)
    sigma_grid = np.tile(ndf.sigma(u ** 2 * (np.pi / 2)), (res, 1)).astype(np.float32)
    vndf = _vndf_density(ndf_grid[0].astype(np.float64), theta_i.astype(np.float64), res)
    vndf = vndf.astype(np.float32)
    # The reader's own warp and interpolants, from the float32 fields as written.
    warp = Marginal2D(vndf.astype(np.float64), [phi_i, theta_i.astype(np.float64)])
    ta, u_m, wa, wb = _node_directions(warp, theta_i.astype(np.float64), nd)
    f = np.asarray(brdf(np.minimum(np.degrees(elevation(wb)), 90.0), np.degrees(ta),
                        -np.degrees(np.arctan2(wb[:, 1], wb[:, 0]))), float)
    d = Marginal2D(ndf_grid.astype(np.float64), normalize=False, sampling=False).eval(u_m)
    sig = Marginal2D(sigma_grid.astype(np.float64), normalize=False, sampling=False).eval(
        np.column_stack([theta_to_u(ta), np.full(ta.size, 0.5)]))
    value = np.nan_to_num(f) * np.maximum(wb[:, 2], 0.0)[:, None] * (4.0 * sig / d)[:, None]
    rgb = np.maximum(value, 0.0).reshape(1, theta_i.size, nd, nd, 3).transpose(0, 1, 4, 2, 3)
    lum = np.einsum("c,pkcyx->pkyx", LUMINANCE_RGB, rgb)
    lum = np.maximum(lum, 1e-4 * lum.max(axis=(2, 3), keepdims=True) + 1e-30)
    return {"theta_i": theta_i, "phi_i": phi_i, "ndf": ndf_grid, "sigma": sigma_grid,
            "vndf": vndf, "luminance": lum.astype(np.float32), "rgb": rgb.astype(np.float32),
            "jacobian": np.ones(1, np.uint8)}


def write_bsdf(path: str | os.PathLike[str], brdf: Brdf, description: dict[str, Any], *,
               ndf: Ndf | None = None, grid: Grid = DEFAULT_GRID,
               inputs: Iterable[str | os.PathLike[str]] = ()) -> Ndf:
    """Write ``brdf`` as an RGB ``.bsdf`` through :func:`drivers.storage.atomic_output` (an
    earlier gonio ``.bsdf`` may be replaced; ``inputs`` and other files are refused). ``ndf``
    defaults to the BRDF's retro-reflection (:func:`acquisition.formats.ndf.retro_ndf`);
    ``description`` (gonio's provenance) is stored as JSON. Returns the D used."""
    ndf = ndf if ndf is not None else retro_ndf(brdf, nodes=grid.warp_res)
    fields = resample(brdf, ndf, grid)
    text = json.dumps({"generator": GENERATOR, **description, "ndf": ndf.source,
                       "grid": {"theta_i": grid.theta_i_count, "warp": grid.warp_res,
                                "data": grid.data_res}}, default=str)
    fields["description"] = np.frombuffer(text.encode("utf-8"), dtype=np.uint8)
    write_tensor_file(path, fields, what=WHAT, ours=is_gonio_bsdf, inputs=inputs)
    return ndf
