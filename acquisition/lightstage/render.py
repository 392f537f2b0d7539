"""Simulated light-stage images: the sample under a set of lit LEDs, and under an environment.

The camera sees the sum over LEDs of each LED's single-light image (lights add linearly):
LED k at DMX level v_k (0–1), true relative intensity g_k and colour c_k contributes
``v_k · g_k · c_k ·`` the image under a point light of the rig's nominal intensity at
``light_distance_m`` along its direction (:func:`acquisition.simworld.scene.render_image`).

:func:`render_environment` renders the same sample under distant light from a lat-long
environment map restricted to the dome's hemisphere (z > 0 in the sample frame): the
reference a relit reflectance field is compared with.
"""

from __future__ import annotations

import numpy as np

from acquisition.config.rig import RigConfig
from acquisition.lightstage.envmap import latlong_directions
from acquisition.reduction.imaging import PinholeCamera, camera_intrinsics, intersect, tangent_frames
from acquisition.simworld.scene import render_image
from simulators.materials import Material


class LightImages:
    """Single-LED radiance images (h, w, 3), W·sr⁻¹·m⁻², rendered once and cached.

    Parameters
    ----------
    rig:
        The light stage's rig (camera, sample, nominal LED intensity).
    directions, camera_dir:
        LED directions (N, 3) and camera direction (3,), sample frame.
    shape:
        Image size in superpixels.
    """

    def __init__(self, rig: RigConfig, directions: np.ndarray, camera_dir: np.ndarray,
                 shape: tuple[int, int]) -> None:
        self.rig = rig
        self.directions = np.asarray(directions, dtype=float)
        self.camera_dir = np.asarray(camera_dir, dtype=float)
        self.shape = shape
        self._cache: dict[tuple[int, int, str | None], np.ndarray] = {}

    def image(self, k: int, material: Material, target: str | None = None) -> np.ndarray:
        """LED ``k``'s image of ``material`` (``target="flat"``: the white plate)."""
        key = (k, id(material), target)
        img = self._cache.get(key)
        if img is None:
            img = render_image(self.rig, self.directions[k], self.camera_dir, material,
                               self.shape, target).astype(np.float32)
            self._cache[key] = img
        return img

    def lit(self, weights: np.ndarray, material: Material, target: str | None = None) -> np.ndarray:
        """Radiance image for LED weights (N, 3) = level × gain × colour (0 rows skipped)."""
        out = np.zeros((*self.shape, 3))
        for k in np.flatnonzero(np.any(weights > 0, axis=1)):
            out += self.image(int(k), material, target) * weights[k]
        return out


def render_environment(rig: RigConfig, camera_dir: np.ndarray, material: Material,
                       env: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Radiance image (h, w, 3) of the sample lit by ``env`` from the upper hemisphere.

    ``env`` is a lat-long map (H, W, 3) of radiance (see :mod:`acquisition.lightstage.envmap`);
    every env pixel above the horizon is a distant light of its solid angle:
    L(p) = Σ_j env_j · Ω_j · f(wi_j, wo) · max(cos θi_j, 0).
    """
    camera = PinholeCamera.looking_at_origin(camera_intrinsics(rig, shape), shape, camera_dir,
                                             rig.camera_distance_m)
    hits = intersect(rig.sample, camera.position, camera.ray_directions())
    n = hits.normals
    wo_world = camera.position - hits.points
    wo_world /= np.linalg.norm(wo_world, axis=-1, keepdims=True)
    t, b = tangent_frames(np.ascontiguousarray(n))
    frame = np.stack([t, b, n], axis=1)  # (P, 3, 3): rows are the local axes
    wo = np.einsum("pij,pj->pi", frame, wo_world)
    dirs, omega = latlong_directions(env.shape[:2])
    up = dirs[..., 2] > 0
    d, radiance = dirs[up], env[up] * omega[up][:, None]  # (M, 3), (M, 3)
    out = np.zeros((len(n), 3))
    for start in range(0, len(n), 256):  # bounded memory: 256 pixels × M directions
        fr = frame[start:start + 256]
        wi = np.einsum("pij,mj->pmi", fr, d)
        wo_b = np.broadcast_to(wo[start:start + 256, None, :], wi.shape)
        f = material.eval_vectors(wi, wo_b)
        cos = np.clip(wi[..., 2], 0.0, None)
        out[start:start + 256] = np.einsum("pmc,pm,mc->pc", f, cos, radiance)
    visible = wo[:, 2] > 0
    image = np.zeros((*shape, 3))
    image[hits.hit] = np.where(visible[:, None], out, 0.0)
    return image
