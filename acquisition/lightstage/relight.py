"""Image-based relighting of a reflectance field under a lat-long environment map.

Lights add linearly, so the sample under an environment is the field's images weighted by the
light each dome light stands for:

    L(p) = Σ_k R_k(p) · E_k,     E_k = Ω_k · mean of the environment over light k's cell

with Ω_k the light's solid angle (its hemisphere Voronoi cell, :mod:`acquisition.config.dome`) and
the mean taken over the environment pixels nearest to light k (solid-angle weighted). A cell
no environment pixel falls in (a coarse map) takes the map's value at the light's direction.
Light from below the horizon is outside the dome's reach and ignored.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from acquisition.formats.envmap import latlong_directions
from acquisition.lightstage.field import ReflectanceField, load_field
from calibration.exr import exr_has, read_exr, write_exr
from drivers.errors import ConfigError
from drivers.storage import check_output


def light_weights(directions: np.ndarray, solid_angles_sr: np.ndarray,
                  env: np.ndarray) -> np.ndarray:
    """E_k (N, 3): Ω_k × the environment's mean radiance over light k's cell."""
    env = np.asarray(env, dtype=np.float64)
    if env.ndim != 3 or env.shape[2] < 3 or min(env.shape[:2]) < 1:
        raise ConfigError(f"environment map must be an (H, W, ≥3) RGB image, got {env.shape}")
    env = env[..., :3]
    dirs, omega = latlong_directions(env.shape[:2])
    d = np.asarray(directions, dtype=float)
    up = dirs[..., 2] > 0
    nearest = np.argmax(dirs[up] @ d.T, axis=1)
    area = np.bincount(nearest, omega[up], minlength=len(d))
    rad = env[up] * omega[up][:, None]
    total = np.stack([np.bincount(nearest, rad[:, c], minlength=len(d)) for c in range(3)], -1)
    mean = np.empty_like(total)
    has = area > 0
    mean[has] = total[has] / area[has, None]
    if not has.all():  # sample the map at the light's direction
        h, w = env.shape[:2]
        theta = np.arccos(np.clip(d[~has, 2], -1, 1))
        phi = np.arctan2(d[~has, 1], d[~has, 0]) % (2 * np.pi)
        i = np.minimum((theta / np.pi * h).astype(int), h - 1)
        j = np.minimum((phi / (2 * np.pi) * w).astype(int), w - 1)
        mean[~has] = env[i, j]
    return mean * np.asarray(solid_angles_sr, dtype=float)[:, None]


def relight(field: ReflectanceField, env_latlong: np.ndarray) -> np.ndarray:
    """The sample under ``env_latlong`` (H, W, 3 radiance): an (h, w, 3) radiance image."""
    weights = light_weights(field.directions, field.solid_angles_sr, env_latlong)
    return np.einsum("khwc,kc->hwc", field.images.astype(np.float64), weights)


WHAT = "relit image"
is_relit_image = exr_has("gonio:relit_from")
"""True for a relit image gonio wrote (it may be replaced)."""


def relight_files(field_dir: str | Path, env_path: str | Path, out_path: str | Path) -> np.ndarray:
    """``gonio relight``: read the field and the map, write the relit EXR; returns the image.

    The output may replace a previous relit image, never an input or any other file."""
    inputs = (env_path, field_dir, *Path(field_dir).glob("light-*.exr"))
    check_output(out_path, what=WHAT, ours=is_relit_image, inputs=inputs)
    field = load_field(field_dir)
    env, _ = read_exr(env_path)
    image = relight(field, env)
    write_exr(out_path, image, {
        "gonio:relit_from": str(Path(field_dir).resolve()),
        "gonio:environment": str(Path(env_path).resolve()),
        "gonio:lights": len(field),
        "gonio:units": "radiance, in the environment map's units",
    }, what=WHAT, ours=is_relit_image, inputs=inputs)
    return image
