"""MERL BRDF database files (``.binary``, Matusik et al. 2003) as simulated materials.

The file, as the database's reference reader (``BRDFRead.cpp``) reads it:

* three int32 (90, 90, 180): the θh, θd and φd resolutions (the reader checks only that their
  product is 1,458,000);
* 3 × 1,458,000 float64, channel-major: the R plane, then G, then B, each C-ordered over
  (θh, θd, φd) with φd fastest;
* BRDF (sr⁻¹) = stored value × channel scale, R 1/1500, G 1.15/1500, B 1.66/1500.

A lookup takes the nearest bin below (no interpolation) of Rusinkiewicz's half/difference
angles of the light direction ωi and the view direction ωo (unit, normal +z):

* h = (ωi + ωo) / |ωi + ωo|, θh = acos h_z, φh = atan2(h_y, h_x);
* d = Ry(−θh) · Rz(−φh) · ωi, ωi seen from the frame whose pole is h; θd = acos d_z,
  φd = atan2(d_y, d_x);
* θh index ⌊90 · √(θh / 90°)⌋ (square-root spacing: fine bins near the specular peak), θd
  index ⌊θd / 1°⌋, φd index ⌊φd / 1°⌋ after the reciprocity fold φd → φd + 180° for φd < 0;
  each clamped into its range.

Unmeasured entries: the reference returns a bin's stored values × scale as they are and prints
"Below horizon." when any channel of the lookup is negative. A lookup here returns the same
values (:meth:`MerlFile.lookup`); the material renders such a bin (a channel negative or not
a number) black in all three channels: a surface reflects no negative light.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drivers.errors import MaterialError
from simulators.materials import Material
from simulators.measured.files import read_material_bytes

RESOLUTION = (90, 90, 180)
"""(θh, θd, φd) bins."""
N_BINS = RESOLUTION[0] * RESOLUTION[1] * RESOLUTION[2]
SCALES = np.array([1.0, 1.15, 1.66]) / 1500.0
"""BRDF (sr⁻¹) per stored unit, R, G, B."""
FILE_BYTES = 3 * 4 + 3 * N_BINS * 8
CHUNK = 1 << 16
"""Directions evaluated at once (bounds the per-sample rotation matrices' memory)."""


# ---------------------------------------------------------------------------- geometry
def _rotation_about_z(angle_rad: np.ndarray) -> np.ndarray:
    """Rz(angle), (…, 3, 3): turns x towards y."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    o, i = np.zeros_like(c), np.ones_like(c)
    return np.stack([np.stack([c, -s, o], -1), np.stack([s, c, o], -1),
                     np.stack([o, o, i], -1)], -2)


def _rotation_about_y(angle_rad: np.ndarray) -> np.ndarray:
    """Ry(angle), (…, 3, 3): turns z towards x."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    o, i = np.zeros_like(c), np.ones_like(c)
    return np.stack([np.stack([c, o, s], -1), np.stack([o, i, o], -1),
                     np.stack([-s, o, c], -1)], -2)


def half_difference_rad(wi: np.ndarray, wo: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rusinkiewicz's (θh, θd, φd) in radians of unit light ``wi`` and view ``wo`` vectors
    (N, 3), normal +z (module docstring); φd ∈ [−π, π]."""
    h = wi + wo
    h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    theta_h = np.arccos(np.clip(h[:, 2], -1.0, 1.0))
    phi_h = np.arctan2(h[:, 1], h[:, 0])
    d = _rotation_about_y(-theta_h) @ (_rotation_about_z(-phi_h) @ wi[:, :, None])
    d = d[:, :, 0]
    theta_d = np.arccos(np.clip(d[:, 2], -1.0, 1.0))
    return theta_h, theta_d, np.arctan2(d[:, 1], d[:, 0])


def bin_index(theta_h_rad: np.ndarray, theta_d_rad: np.ndarray, phi_d_rad: np.ndarray) -> np.ndarray:
    """Flat MERL bin ``(ih·90 + id)·180 + ip`` of half/difference angles in radians."""
    n_h, n_d, n_p = RESOLUTION
    quarter_turn = np.pi / 2
    ih = np.floor(n_h * np.sqrt(np.maximum(theta_h_rad, 0.0) / quarter_turn))
    id_ = np.floor(theta_d_rad / quarter_turn * n_d)
    folded = np.where(phi_d_rad < 0.0, phi_d_rad + np.pi, phi_d_rad)  # reciprocity
    ip = np.floor(folded / np.pi * n_p)
    ih, id_, ip = (np.clip(np.nan_to_num(i), 0, n - 1).astype(np.int64)
                   for i, n in ((ih, n_h), (id_, n_d), (ip, n_p)))
    return (ih * n_d + id_) * n_p + ip


# ---------------------------------------------------------------------------- file
@dataclass(frozen=True, eq=False)
class MerlFile:
    """A MERL file's values: ``brdf`` (1,458,000, 3) in sr⁻¹, stored value × scale, indexed by
    flat bin (negative where the file marks a bin unmeasured)."""

    brdf: np.ndarray
    path: Path | None = None

    def lookup(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """The reference lookup (…, 3) in sr⁻¹ for unit light ``wi`` and view ``wo`` vectors
        (…, 3), normal +z: the nearest bin's values as stored × scale, negative ones included."""
        wi, wo = np.broadcast_arrays(np.asarray(wi, np.float64), np.asarray(wo, np.float64))
        shape = wi.shape[:-1]
        wi, wo = wi.reshape(-1, 3), wo.reshape(-1, 3)
        index = np.empty(len(wi), dtype=np.int64)
        with np.errstate(invalid="ignore", divide="ignore"):
            for a in range(0, len(wi), CHUNK):
                index[a:a + CHUNK] = bin_index(*half_difference_rad(wi[a:a + CHUNK], wo[a:a + CHUNK]))
        return self.brdf[index].reshape(*shape, 3)


def read_merl_file(path: str | Path) -> MerlFile:
    """Read a MERL ``.binary`` file; :class:`MaterialError` naming what is wrong."""
    path = Path(path)
    raw = read_material_bytes(path, "MERL file")
    dims = np.frombuffer(raw[:12], dtype="<i4") if len(raw) >= 12 else np.zeros(0)
    if dims.size != 3 or int(np.prod(dims, dtype=np.int64)) != N_BINS:
        raise MaterialError(f"MERL file {path}: header {tuple(int(d) for d in dims)} does not hold "
                            "90 x 90 x 180 bins; give a MERL BRDF .binary file")
    if len(raw) != FILE_BYTES:
        raise MaterialError(f"MERL file {path} is {len(raw)} bytes, expected {FILE_BYTES}: "
                            "truncated or not a MERL BRDF; download it again")
    planes = np.frombuffer(raw, dtype="<f8", offset=12).reshape(3, N_BINS)
    return MerlFile(planes.T * SCALES, path)


# ---------------------------------------------------------------------------- material
class MerlMaterial(Material):
    """A MERL file as the simulated sample: the reference lookup, 0 at or below the horizon
    and in bins the file marks unmeasured (module docstring)."""

    def __init__(self, merl: MerlFile, spec: str) -> None:
        self.merl = merl
        self.spec = spec

    def eval_vectors(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        wi, wo = np.broadcast_arrays(np.asarray(wi, np.float64), np.asarray(wo, np.float64))
        value = self.merl.lookup(wi, wo)
        usable = (wi[..., 2] > 0) & (wo[..., 2] > 0) & np.all(value >= 0, axis=-1)
        return np.where(usable[..., None], value, 0.0)

    def __repr__(self) -> str:
        return f"MerlMaterial({self.spec!r})"
