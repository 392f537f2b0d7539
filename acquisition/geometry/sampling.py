"""Sample sets: which (θi, θr, Δφ) poses a plan asks for, as (N, 3) arrays in degrees.

Every function here is pure: it turns a few numbers into candidate poses. Whether a pose is
reachable, safe and useful is the planner's question; which order to take them in too.

* :func:`grid` — nested regular ranges of θi, θr, Δφ.
* :func:`uniform_solid_angle` — light and camera directions each spread evenly over the
  hemisphere (equal solid angle per sample).
* :func:`merl_half_diff` — the MERL half/difference set: θh on the square-root spacing of
  the MERL table (dense near the specular peak), θd and φd uniform.
* :func:`specular_refined` — a (θr, Δφ) quadtree per θi, refined around the mirror direction.
* :func:`read_pose_csv` — an explicit list.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from acquisition.geometry.halfdiff import angles_from_halfdiff


def grid(theta_i: np.ndarray, theta_r: np.ndarray, delta_phi: np.ndarray) -> np.ndarray:
    """Every combination of the given angles (degrees), θi slowest, Δφ fastest; (N, 3)."""
    ti, tr, dp = np.meshgrid(theta_i, theta_r, delta_phi, indexing="ij")
    return np.column_stack([ti.ravel(), tr.ravel(), dp.ravel()]).astype(float)


def equal_area_thetas(n: int, max_theta_deg: float = 90.0) -> np.ndarray:
    """``n`` zenith angles (deg) at the solid-angle midpoints of ``n`` equal-area bands
    covering θ ∈ [0, max_theta_deg]."""
    mu_min = np.cos(np.radians(max_theta_deg))
    mu = 1.0 - (np.arange(n) + 0.5) / n * (1.0 - mu_min)
    return np.degrees(np.arccos(mu))


def equal_area_directions(n: int, max_theta_deg: float = 90.0,
                          max_phi_deg: float = 180.0) -> np.ndarray:
    """About ``n`` (θ, φ) pairs (deg) in cells of nearly equal solid angle over θ ≤ max_theta,
    φ ∈ [0, max_phi]: rings of equal angular width, each with as many azimuths as its
    share of the solid angle asks for (at least one); (M, 2)."""
    if n < 1:
        raise ValueError("need at least one direction")
    t_max = np.radians(max_theta_deg)
    phi_span = np.radians(max_phi_deg)
    area_total = phi_span * (1.0 - np.cos(t_max))
    cell = area_total / n
    # Ring width ≈ the side of a square cell.
    rings = max(1, int(round(t_max / np.sqrt(cell))))
    edges = np.linspace(0.0, t_max, rings + 1)
    out = []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        area = phi_span * (np.cos(lo) - np.cos(hi))
        k = max(1, int(round(area / cell)))
        theta = np.arccos(0.5 * (np.cos(lo) + np.cos(hi)))  # solid-angle midpoint of the ring
        phis = (np.arange(k) + 0.5) / k * phi_span
        out.extend((np.degrees(theta), np.degrees(p)) for p in phis)
    return np.array(out)


def uniform_solid_angle(n_light: int, n_camera: int, max_theta_deg: float = 90.0) -> np.ndarray:
    """Light zenith angles on ``n_light`` equal-area bands and, for each, about ``n_camera``
    camera directions in equal-solid-angle cells of the half hemisphere Δφ ∈ [0°, 180°]
    (an isotropic BRDF needs no other half); (N, 3) degrees."""
    ti = equal_area_thetas(n_light, max_theta_deg)
    cam = equal_area_directions(n_camera, max_theta_deg, 180.0)
    return np.column_stack([
        np.repeat(ti, len(cam)), np.tile(cam[:, 0], len(ti)), np.tile(cam[:, 1], len(ti)),
    ])


def merl_theta_h(n: int) -> np.ndarray:
    """θh (deg) at the centres of ``n`` bins with the MERL square-root spacing:
    bin k spans 90°·(k/n)² to 90°·((k+1)/n)²."""
    return 90.0 * ((np.arange(n) + 0.5) / n) ** 2


def merl_half_diff(n_theta_h: int, n_theta_d: int, n_phi_d: int) -> np.ndarray:
    """The MERL-style half/difference set as (θi, θr, Δφ) rows (deg), (N, 3).

    θh takes the square-root-spaced bin centres (:func:`merl_theta_h`), θd the centres of
    ``n_theta_d`` uniform bins on [0°, 90°], φd the centres of ``n_phi_d`` bins on [0°, 180°)
    (reciprocity covers the other half). Directions below the horizon are kept: the planner
    rejects them with a reason. Δφ is returned in (−180°, 180°].
    """
    th = merl_theta_h(n_theta_h)
    td = (np.arange(n_theta_d) + 0.5) * 90.0 / n_theta_d
    pd = (np.arange(n_phi_d) + 0.5) * 180.0 / n_phi_d
    hh, dd, pp = np.meshgrid(th, td, pd, indexing="ij")
    ti, tr, dphi = angles_from_halfdiff(hh.ravel(), dd.ravel(), pp.ravel())
    return np.column_stack([ti, tr, dphi])


def _mirror_distance_deg(theta_i: float, theta_r: np.ndarray, delta_phi: np.ndarray) -> np.ndarray:
    """Angle (deg) between camera directions (θr, Δφ) and the mirror direction of θi."""
    ti, tr, dp = np.radians(theta_i), np.radians(theta_r), np.radians(delta_phi)
    c = np.cos(tr) * np.cos(ti) - np.sin(tr) * np.sin(ti) * np.cos(dp)
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def specular_refined(
    theta_i: np.ndarray,
    step_deg: float,
    min_step_deg: float,
    *,
    max_theta_r_deg: float = 90.0,
    spread: float = 2.0,
) -> np.ndarray:
    """Adaptive refinement around the specular direction; (N, 3) degrees.

    For each θi a quadtree over (θr ∈ [0, max_theta_r], Δφ ∈ [0, 180]) starts from cells of
    ``step_deg``; a cell is split in four while its side is at least ``2·min_step_deg`` and
    its centre lies within ``spread`` cell sides (plus its half-diagonal) of the mirror
    direction. The poses are the corners of the final cells: fine near the specular peak,
    coarse elsewhere.
    """
    if not 0 < min_step_deg <= step_deg:
        raise ValueError("need 0 < min_step_deg ≤ step_deg")
    out = []
    for ti in np.atleast_1d(theta_i):
        n_r = max(1, int(np.ceil(max_theta_r_deg / step_deg - 1e-9)))
        n_p = max(1, int(np.ceil(180.0 / step_deg - 1e-9)))
        r0, p0 = np.meshgrid(np.arange(n_r) * step_deg, np.arange(n_p) * step_deg, indexing="ij")
        cells = np.column_stack([r0.ravel(), p0.ravel(), np.full(r0.size, step_deg)])
        leaves = []
        while len(cells):
            h = cells[:, 2]
            dist = _mirror_distance_deg(ti, cells[:, 0] + h / 2, cells[:, 1] + h / 2)
            split = (h >= 2 * min_step_deg - 1e-9) & (dist <= spread * h + h / np.sqrt(2))
            leaves.append(cells[~split])
            s = cells[split]
            half = s[:, 2:3] / 2
            cells = np.vstack([
                np.column_stack([s[:, 0] + dr * half[:, 0], s[:, 1] + dp * half[:, 0], half[:, 0]])
                for dr in (0, 1) for dp in (0, 1)
            ]) if len(s) else np.zeros((0, 3))
        leaf = np.vstack(leaves)
        corners = np.vstack([
            np.column_stack([leaf[:, 0] + dr * leaf[:, 2], leaf[:, 1] + dp * leaf[:, 2]])
            for dr in (0, 1) for dp in (0, 1)
        ])
        corners[:, 0] = np.minimum(corners[:, 0], max_theta_r_deg)
        corners[:, 1] = np.minimum(corners[:, 1], 180.0)
        corners = np.unique(np.round(corners, 9), axis=0)
        out.append(np.column_stack([np.full(len(corners), float(ti)), corners]))
    return np.vstack(out)


def read_pose_csv(path: str | Path) -> np.ndarray:
    """(θi, θr, Δφ) rows (deg) from a CSV file; ``#`` comments and a header row are skipped.

    Raises
    ------
    ValueError
        Naming the file and line of a row that is not three numbers.
    OSError
        When the file cannot be read.
    """
    rows: list[list[float]] = []
    with open(path, newline="") as fh:
        for lineno, row in enumerate(csv.reader(fh), 1):
            if not row or not "".join(row).strip() or row[0].lstrip().startswith("#"):
                continue
            if row[0].strip().lower() in ("theta_i", "theta_i_deg"):
                continue
            try:
                values = [float(x) for x in row]
            except ValueError:
                raise ValueError(f"{path}:{lineno}: expected 3 numbers, got {row}") from None
            if len(values) != 3:
                raise ValueError(f"{path}:{lineno}: expected 3 numbers, got {len(values)}")
            rows.append(values)
    return np.array(rows, dtype=float).reshape(-1, 3)
