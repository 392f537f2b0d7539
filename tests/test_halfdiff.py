"""Half/difference coordinates and MERL bin indices."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from acquisition.geometry.halfdiff import (
    MERL_SHAPE,
    angles_from_halfdiff,
    halfdiff_from_angles,
    halfdiff_from_vectors,
    merl_bin_edges,
    merl_flat_index,
    merl_flat_index_rad,
    merl_indices,
    vectors_from_halfdiff,
)
from acquisition.tables import MerlTable
from simulators.materials import directions_from_angles


def _unit_pairs(rng, n):
    ti, tr, dp = rng.uniform(0, 89, n), rng.uniform(0, 89, n), rng.uniform(-180, 180, n)
    phi0 = rng.uniform(-180, 180, n)
    wi, wo = directions_from_angles(ti, tr, dp)
    c, s = np.cos(np.radians(phi0)), np.sin(np.radians(phi0))
    rot = np.stack([np.stack([c, -s, 0 * c], -1), np.stack([s, c, 0 * c], -1),
                    np.stack([0 * c, 0 * c, 1 + 0 * c], -1)], -2)
    return np.einsum("nij,nj->ni", rot, wi), np.einsum("nij,nj->ni", rot, wo)


def test_known_configurations():
    # Mirror: h is the normal, θd = θi.
    th, td, _ = halfdiff_from_angles(35.0, 35.0, 180.0)
    assert th == pytest.approx(0.0, abs=1e-6) and td == pytest.approx(35.0)
    # Retro-reflection: wi = wo, so θd = 0 and θh = θi.
    th, td, _ = halfdiff_from_vectors(*directions_from_angles(50.0, 50.0, 0.0))
    assert th == pytest.approx(50.0) and td == pytest.approx(0.0, abs=1e-6)
    # Light at the normal, view at θr in the plane: θh = θd = θr/2, φd = 180°.
    th, td, pd = halfdiff_from_vectors(*directions_from_angles(0.0, 40.0, 0.0))
    assert (th, td, abs(pd)) == pytest.approx((20.0, 20.0, 180.0))
    # Out of the plane of incidence, φd = ±90°.
    th, td, pd = halfdiff_from_vectors(*directions_from_angles(30.0, 30.0, 90.0))
    assert abs(pd) == pytest.approx(90.0)


def test_vector_and_reference_angle_paths_agree():
    rng = np.random.default_rng(0)
    ti, tr, dp = rng.uniform(0, 89, 5000), rng.uniform(0, 89, 5000), rng.uniform(-180, 180, 5000)
    a = halfdiff_from_angles(ti, tr, dp)
    b = halfdiff_from_vectors(*directions_from_angles(ti, tr, dp))
    for x, y in zip(a, b, strict=True):
        np.testing.assert_allclose(x, y, atol=1e-7)


def test_rotation_about_the_normal_changes_nothing():
    rng = np.random.default_rng(1)
    wi, wo = _unit_pairs(rng, 2000)
    ti = np.degrees(np.arccos(wi[:, 2]))
    tr = np.degrees(np.arccos(wo[:, 2]))
    dp = np.degrees(np.arctan2(wo[:, 1], wo[:, 0]) - np.arctan2(wi[:, 1], wi[:, 0]))
    for x, y in zip(halfdiff_from_vectors(wi, wo), halfdiff_from_angles(ti, tr, dp), strict=True):
        np.testing.assert_allclose(x, y, atol=1e-7)


@settings(max_examples=200, deadline=None)
@given(
    st.floats(0.5, 89.0), st.floats(0.5, 89.0), st.floats(-179.0, 179.0), st.floats(-180, 180)
)
def test_inverse_round_trip(theta_h, theta_d, phi_d, phi_h):
    wi, wo = vectors_from_halfdiff(theta_h, theta_d, phi_d, phi_h)
    np.testing.assert_allclose(np.linalg.norm(wi), 1.0)
    np.testing.assert_allclose(np.linalg.norm(wo), 1.0)
    back = halfdiff_from_vectors(wi, wo)
    np.testing.assert_allclose(back, (theta_h, theta_d, phi_d), atol=1e-6)


def test_angles_from_halfdiff_inverts_halfdiff_from_angles():
    rng = np.random.default_rng(2)
    ti, tr, dp = rng.uniform(1, 89, 1000), rng.uniform(1, 89, 1000), rng.uniform(-179, 179, 1000)
    back = angles_from_halfdiff(*halfdiff_from_angles(ti, tr, dp))
    np.testing.assert_allclose(back, (ti, tr, dp), atol=1e-6)


def test_swapping_light_and_view_keeps_the_bin():
    rng = np.random.default_rng(3)
    wi, wo = _unit_pairs(rng, 5000)
    th, td, pd = halfdiff_from_vectors(wi, wo)
    th2, td2, pd2 = halfdiff_from_vectors(wo, wi)
    np.testing.assert_allclose(th, th2, atol=1e-9)
    np.testing.assert_allclose(td, td2, atol=1e-9)
    np.testing.assert_allclose(np.mod(pd - pd2, 360.0), 180.0, atol=1e-7)
    a = merl_flat_index(th, td, pd, clamp=False)
    b = merl_flat_index(th2, td2, pd2, clamp=False)
    assert np.mean(a == b) > 0.999  # differ only when a value sits on a bin boundary


def test_index_formulas_on_hand_values():
    # θh: square-root spacing; bin k starts at 90°·(k/90)².
    edges_h, edges_d, edges_p = merl_bin_edges()
    assert edges_h[1] == pytest.approx(90 / 8100) and edges_h[45] == pytest.approx(22.5)
    ih, idd, ip = merl_indices([0.0, 0.01, 0.012, 22.6, 89.99, 90.0], 0.0, 0.0)
    assert list(ih) == [0, 0, 1, 45, 89, 89]
    _, idd, _ = merl_indices(0.0, [0.0, 0.99, 1.0, 45.5, 90.0, 95.0], 0.0)
    assert list(idd) == [0, 0, 1, 45, 89, 89]
    _, _, ip = merl_indices(0.0, 0.0, [0.0, 0.5, 1.0, 179.5, -0.5, -179.5, 180.0])
    assert list(ip) == [0, 0, 1, 179, 179, 0, 179]
    assert len(edges_d) == 91 and len(edges_p) == 181


def test_unclamped_indices_mark_out_of_range():
    flat = merl_flat_index([10.0, -1.0, 91.0, 10.0, np.nan, 10.0], [10, 10, 10, 91, 10, 10],
                           [0, 0, 0, 0, 0, 540.5], clamp=False)
    assert list(flat[1:5]) == [-1, -1, -1, -2]  # −1 outside, −2 NaN
    ih, idd, ip = merl_indices(10.0, 10.0, [0.0, 540.5])
    assert flat[0] == (ih[0] * 90 + idd[0]) * 180 + ip[0]
    assert flat[5] % 180 == 0  # 540.5° folds to 0.5°
    clamped = merl_flat_index([-1.0, 91.0, np.nan], [10.0, 10.0, np.nan], 0.0)
    assert list(clamped // (90 * 180)) == [0, 89, 0]
    assert ((clamped >= 0) & (clamped < np.prod(MERL_SHAPE))).all()


def test_fast_unclamped_index_equals_general_path():
    rng = np.random.default_rng(6)
    n = 300_000  # several internal chunks; some chunks hold bad values, most do not
    th, td = rng.uniform(0, 90, n), rng.uniform(0, 90, n)
    pd = rng.uniform(-180, 180, n)
    pd[:1000:7] = 180.0
    th[150_000:150_100] = rng.uniform(-5, 95, 100)
    pd[200_000:200_010] = np.nan
    pd[250_000:250_010] = 400.5  # folded by whole half turns (not on a bin edge)
    fast = merl_flat_index(th, td, pd, clamp=False)
    ih, idd, ip = merl_indices(th, td, pd, clamp=False)
    general = np.where(ih < 0, ih, (ih * 90 + idd) * 180 + ip)
    np.testing.assert_array_equal(fast, general)
    # Inside the table (and φd in (−180, 180], which the reference folds only once) the
    # reference's clamped index agrees.
    inside = (fast >= 0) & (pd <= 180.0)
    np.testing.assert_array_equal(fast[inside], merl_flat_index(th, td, pd)[inside])
    assert (fast == -2).sum() == 10 and (fast == -1).sum() > 0


def test_degree_and_radian_index_paths_agree_on_exact_edges():
    # Bin edges given in degrees: the degree path converts like np.radians, as the reference's
    # callers and the numba kernel do, so a value on an edge gets the radian path's bin.
    edges_h, edges_d, _ = merl_bin_edges()
    th, td, pd = (a.reshape(-1) for a in np.meshgrid(
        edges_h, edges_d, [-180.0, -90.5, -0.0, 0.0, 1.0, 90.0, 179.5, 180.0], indexing="ij"))
    every_phi = np.arange(-180.0, 180.5, 0.5)
    th = np.concatenate([th, np.resize(edges_h, every_phi.size)])
    td = np.concatenate([td, np.resize(edges_d[::-1], every_phi.size)])
    pd = np.concatenate([pd, every_phi])
    deg = merl_flat_index(th, td, pd, clamp=False)
    rad = merl_flat_index_rad(np.radians(th), np.radians(td), np.radians(pd), clamp=False)
    np.testing.assert_array_equal(deg, rad)
    inside = pd > -180.0
    np.testing.assert_array_equal(deg[inside], merl_flat_index(th, td, pd)[inside])
    # Conversion does move some integer degrees below their edge (θd = k° → bin k − 1).
    assert ((deg // 180) % 90 != np.minimum(td, 89)).any()


def test_retro_reflection_is_theta_d_bin_zero_never_nan():
    # θi = θr, Δφ = 0: d_z may round just past 1, where acos is NaN; the reference's (int) cast
    # reads NaN as bin 0, which is where acos(1) = 0 puts it: the sample is kept.
    t = np.arange(90.0)
    th, td, _ = halfdiff_from_angles(t, t, 0.0)
    assert np.isfinite(td).all() and (td < 1e-5).all()
    np.testing.assert_allclose(th, t, atol=1e-9)
    for backend in ("numba", "numpy"):
        table = MerlTable(backend=backend)
        assert table.add_angles(t, t, 0.0, np.ones((90, 3))) == 90
        assert table.count[:, 0, :].sum() == 90 and table.n_dropped_nan == 0
