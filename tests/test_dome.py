"""Light-stage dome geometry: geodesic layout, rig-file loading, per-light solid angles."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from acquisition.config.dome import (
    geodesic_directions,
    geodesic_sphere,
    load_dome,
    nearest_light,
    solid_angles_sr,
)
from drivers.errors import ConfigError


@pytest.mark.parametrize("frequency", [1, 2, 3, 4, 6, 9])
def test_geodesic_sphere_vertex_count_and_spacing(frequency: int) -> None:
    pts = geodesic_sphere(frequency)
    assert len(pts) == 10 * frequency**2 + 2  # Euler: class-I geodesic sphere
    assert np.allclose(np.linalg.norm(pts, axis=1), 1.0)
    dist, _ = cKDTree(pts).query(pts, k=2)
    nearest = dist[:, 1]
    assert nearest.min() > 0.7 * nearest.max()  # no duplicates, near-uniform spacing
    assert np.any(np.all(np.isclose(pts, [0, 0, 1]), axis=1))  # a vertex at the zenith


def test_classic_156_light_dome() -> None:
    d = geodesic_directions()  # default: the classic 156-light layout
    assert d.shape == (156, 3)
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0)
    elevation = np.degrees(np.arcsin(d[:, 2]))
    assert elevation.min() > 10.0  # the 9.9° ring of the frequency-6 sphere is cut
    assert np.allclose(d[0], [0, 0, 1])  # zenith first, then downwards
    assert np.all(np.diff(np.round(elevation, 6)) <= 0)
    # it is the frequency-6 upper hemisphere minus its lowest ring of 10
    f6 = geodesic_directions(frequency=6)
    assert len(f6) == 166
    assert len(geodesic_directions(frequency=6, min_elevation_deg=10.0)) == 156
    # 5-fold symmetry about the normal survives the cut
    rot = np.radians(72.0)
    r = np.array([[np.cos(rot), -np.sin(rot), 0], [np.sin(rot), np.cos(rot), 0], [0, 0, 1]])
    dist, _ = cKDTree(d).query(d @ r.T)
    assert dist.max() < 1e-9


def test_solid_angles_tile_the_hemisphere() -> None:
    d = geodesic_directions(156)
    omega = solid_angles_sr(d)
    assert omega.shape == (156,) and np.all(omega > 0)
    assert omega.sum() == pytest.approx(2 * np.pi, rel=1e-9)
    # near-uniform layout: cells within a factor ~4 of the mean (lowest ring reaches the horizon)
    assert omega.max() / omega.min() < 4.0
    # cells are Voronoi: a random upper-hemisphere direction falls in its nearest light's cell,
    # so Monte Carlo cell fractions match the solid angles
    rng = np.random.default_rng(3)
    v = rng.normal(size=(400_000, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v[:, 2] = np.abs(v[:, 2])
    counts = np.bincount(cKDTree(d).query(v)[1], minlength=156)
    assert np.allclose(counts / len(v) * 2 * np.pi, omega, rtol=0.1)


def test_full_sphere_cells_sum_to_4pi() -> None:
    pts = geodesic_sphere(3)
    assert solid_angles_sr(pts, hemisphere=False).sum() == pytest.approx(4 * np.pi, rel=1e-9)


def test_solid_angles_of_a_symmetric_sparse_dome() -> None:
    # zenith plus four lights at 45° elevation: the four share equally, and the zenith cell is
    # the cap above the great circles bisecting it and each side light
    side = np.array([[np.cos(a), np.sin(a), 1.0] for a in np.radians([0, 90, 180, 270])])
    d = np.vstack([[0, 0, 1], side / np.linalg.norm(side, axis=1, keepdims=True)])
    omega = solid_angles_sr(d)
    assert omega.sum() == pytest.approx(2 * np.pi)
    assert np.allclose(omega[1:], omega[1])
    assert omega[0] < omega[1]  # the side cells reach down to the horizon
    with pytest.raises(ConfigError, match="one great circle"):
        solid_angles_sr(np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 1.0], [0.0, -1.0, 1.0]]))


def test_unreachable_count_names_the_nearest_layouts() -> None:
    with pytest.raises(ConfigError, match="exactly 157 lights; nearest: 156 or 166"):
        geodesic_directions(157)
    with pytest.raises(ConfigError, match="either n_lights or frequency"):
        geodesic_directions(156, frequency=6)


def test_load_dome_from_generator_and_lists() -> None:
    dome = load_dome({"generator": "geodesic", "n_lights": 156, "radius_m": 1.2})
    assert len(dome) == 156 and dome.radius_m == 1.2
    assert dome.solid_angles_sr.sum() == pytest.approx(2 * np.pi)
    assert dome.zenith_deg[0] == pytest.approx(0.0) and dome.elevation_deg.min() > 10.0
    rotated = load_dome({"generator": "geodesic", "azimuth_offset_deg": 36.0})
    assert rotated.azimuth_deg[1] == pytest.approx(36.0)
    explicit = load_dome({"directions": [[0, 0, 2], [1, 0, 1], [-1, 0, 1], [0, 1, 1]]})
    assert np.allclose(explicit.directions[1], [2**-0.5, 0, 2**-0.5])
    by_angle = load_dome({"angles_deg": [[0, 0], [45, 0], [45, 180], [45, 90]]})
    assert np.allclose(by_angle.directions, explicit.directions)
    assert np.allclose(by_angle.solid_angles_sr, explicit.solid_angles_sr)
    assert nearest_light(dome, [0.01, 0, 1]) == 0


@pytest.mark.parametrize(
    ("config", "message"),
    [
        ({}, "exactly one of generator, directions, angles_deg"),
        ({"generator": "geodesic", "directions": [[0, 0, 1]]}, "exactly one"),
        ({"generator": "fibonacci"}, "generator 'fibonacci' is unknown"),
        ({"directions": [[0, 0, 1], [1, 0, -0.1]]}, r"dome.directions\[1\] is not above"),
        ({"directions": [[0, 0, 1], [0, 0, 0]]}, r"dome.directions\[1\] is not a non-zero"),
        ({"directions": [0, 0, 1]}, "list of \\[x, y, z\\] triples"),
        ({"angles_deg": [[0, 0], [95, 0]]}, r"dome.angles_deg\[1\] is not above"),
        ({"directions": [[0, 0, 1]], "frequency": 6}, "apply to the generator only"),
        ({"generator": "geodesic", "radius_m": -1}, "radius_m must be a positive"),
        ({"generator": "geodesic", "lights": 3}, "unknown keys \\['lights'\\]"),
        ({"directions": [[0, 0, 1], [0, 0, 1], [1, 0, 1], [0, 1, 1]]}, "duplicate"),
    ],
)
def test_load_dome_errors_name_the_field(config: dict, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        load_dome(config)
