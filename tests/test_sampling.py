"""Sample sets: counts, spacing and coverage of each kind, and their plan-file forms."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from acquisition.config.plan import load_plan
from acquisition.geometry import sampling
from acquisition.geometry.halfdiff import halfdiff_from_angles
from drivers.errors import ConfigError


def test_grid_is_every_combination_theta_i_slowest() -> None:
    poses = sampling.grid(np.array([0, 10]), np.array([5, 15, 25]), np.array([0, 90]))
    assert poses.shape == (12, 3)
    assert poses[0].tolist() == [0, 5, 0] and poses[1].tolist() == [0, 5, 90]
    assert poses[-1].tolist() == [10, 25, 90]


def test_equal_area_directions_have_nearly_equal_solid_angles() -> None:
    dirs = sampling.equal_area_directions(400, 90.0, 180.0)
    assert 360 <= len(dirs) <= 440
    # Count per ring × ring solid angle: each cell's share stays near 1/len(dirs).
    thetas, counts = np.unique(np.round(dirs[:, 0], 9), return_counts=True)
    edges = np.linspace(0, np.pi / 2, len(thetas) + 1)
    area = np.pi * (np.cos(edges[:-1]) - np.cos(edges[1:]))
    cell = area / counts
    assert cell.max() / cell.min() < 1.6
    assert np.all((dirs[:, 1] > 0) & (dirs[:, 1] < 180))


def test_uniform_solid_angle_light_bands_are_equal_area() -> None:
    poses = sampling.uniform_solid_angle(4, 50)
    ti = np.unique(poses[:, 0])
    assert len(ti) == 4
    mu = np.cos(np.radians(ti))
    assert np.allclose(np.sort(mu)[::-1], [0.875, 0.625, 0.375, 0.125])


def test_merl_set_has_square_root_theta_h_spacing() -> None:
    poses = sampling.merl_half_diff(10, 6, 4)
    assert poses.shape == (240, 3)
    th, td, pd = halfdiff_from_angles(poses[:, 0], poses[:, 1], poses[:, 2])
    assert np.allclose(np.unique(np.round(th, 6)), 90 * ((np.arange(10) + 0.5) / 10) ** 2, atol=1e-6)
    assert np.allclose(np.unique(np.round(td, 6)), (np.arange(6) + 0.5) * 15, atol=1e-6)
    folded = np.where(pd < 0, pd + 180, pd)
    assert np.allclose(np.unique(np.round(folded, 6)), (np.arange(4) + 0.5) * 45, atol=1e-6)
    # Square-root spacing: denser near θh = 0 (the specular peak).
    steps = np.diff(np.unique(np.round(th, 6)))
    assert np.all(np.diff(steps) > 0)


def test_specular_refinement_is_dense_near_the_mirror_only() -> None:
    poses = sampling.specular_refined(np.array([30.0]), 10.0, 1.25)
    coarse = sampling.specular_refined(np.array([30.0]), 10.0, 10.0)
    assert len(coarse) == 10 * 19  # 9×18 cells → 10×19 corners
    tr, dp = poses[:, 1], poses[:, 2]
    ti = np.radians(30)
    cos_d = np.cos(np.radians(tr)) * np.cos(ti) - np.sin(np.radians(tr)) * np.sin(ti) * np.cos(np.radians(dp))
    dist = np.degrees(np.arccos(np.clip(cos_d, -1, 1)))
    near = np.sum(dist < 5)
    far = np.sum((dist > 40) & (dist < 45))
    assert near > 3 * far  # a 5° disc holds far more poses than a wider 5° ring far away
    assert np.isclose(np.min(dist), 0, atol=1e-9)  # the mirror direction itself is sampled
    with pytest.raises(ValueError):
        sampling.specular_refined(np.array([30.0]), 5.0, 6.0)


def test_pose_csv_skips_comments_and_header_and_names_bad_lines(tmp_path: Path) -> None:
    good = tmp_path / "poses.csv"
    good.write_text("# my poses\ntheta_i,theta_r,delta_phi\n10,20,30\n\n40,50,60\n")
    assert sampling.read_pose_csv(good).tolist() == [[10, 20, 30], [40, 50, 60]]
    bad = tmp_path / "bad.csv"
    bad.write_text("10,20,30\n10,x,30\n")
    with pytest.raises(ValueError, match=r"bad.csv:2"):
        sampling.read_pose_csv(bad)


def write_plan(tmp_path: Path, sampling_toml: str) -> Path:
    path = tmp_path / "plan.toml"
    path.write_text(f'format_version = 1\nname = "t"\n\n[sampling]\n{sampling_toml}\n')
    return path


@pytest.mark.parametrize(
    ("toml", "count"),
    [
        ("kind = 'merl'\ntheta_h_count = 5\ntheta_d_count = 4\nphi_d_count = 3", 60),
        ("kind = 'uniform'\nlight_count = 3\ncamera_count = 20", None),
        ("kind = 'specular'\ntheta_i = { start = 10, stop = 30, step = 10 }\nstep_deg = 15", None),
        ("kind = 'list'\nposes = [[10, 20, 30], [40, 50, 60]]", 2),
    ],
)
def test_plan_kinds_load(tmp_path: Path, toml: str, count: int | None) -> None:
    plan = load_plan(write_plan(tmp_path, toml))
    if count is not None:
        assert len(plan.poses()) == count
    assert plan.reciprocal == "once" and plan.mirror_delta_phi


def test_plan_csv_and_reciprocal_option(tmp_path: Path) -> None:
    (tmp_path / "p.csv").write_text("10,20,30\n")
    plan = load_plan(write_plan(tmp_path, "kind = 'list'\ncsv = 'p.csv'\nreciprocal = 'both'"))
    assert plan.reciprocal == "both" and [p.as_tuple() for p in plan.poses()] == [(10, 20, 30)]
    with pytest.raises(ConfigError, match="reciprocal"):
        load_plan(write_plan(tmp_path, "kind = 'list'\ncsv = 'p.csv'\nreciprocal = 'twice'"))
    with pytest.raises(ConfigError, match="theta_h_count"):
        load_plan(write_plan(tmp_path, "kind = 'merl'\ntheta_h_count = 0"))
