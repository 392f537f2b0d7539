"""The numba binning kernels against the numpy path they replace (same bins, same statistics).

Counts, sums, sums of squares and drop tallies must be identical, bit for bit. MERL bin indices
are compared per sample with the numpy (reference-arithmetic) index. The reference reader
itself, integer-degree grids and perturbed vector math: see ``test_binning_exact.py``.
"""

from __future__ import annotations

import threading

import numpy as np
import pytest

from acquisition.geometry.halfdiff import (
    MERL_BINS,
    flat_index_unclamped_into,
    halfdiff_rad_from_vectors,
    halfdiff_rad_reference,
    merl_bin_edges,
    merl_flat_index,
    merl_flat_index_rad,
)
from acquisition.tables import BinAccumulator, IsotropicTable, MerlTable, exact_kernels, kernels
from acquisition.tables.backend import ENV_VAR, resolve_backend
from drivers.errors import ConfigError
from simulators.materials import directions_from_angles

# In-plane and pole configurations where φd hangs on signed zeros (θi, θr, Δφ in degrees).
DEGENERATE = np.array([
    (30.0, 30.0, 180.0), (30.0, 30.0, 0.0), (20.0, 50.0, 180.0), (50.0, 20.0, 180.0),
    (0.0, 40.0, 0.0), (40.0, 0.0, 90.0), (0.0, 0.0, 0.0), (45.0, 45.0, 90.0),
    (60.0, 10.0, 0.0), (10.0, 60.0, -180.0), (89.0, 89.0, 180.0), (90.0, 90.0, 180.0),
    (0.0, 90.0, -0.0), (25.0, 25.0, -180.0),
])


def _assert_same_tables(a, b) -> None:
    np.testing.assert_array_equal(a.count, b.count)
    np.testing.assert_array_equal(a._acc._sum, b._acc._sum)
    np.testing.assert_array_equal(a._acc._sumsq, b._acc._sumsq)
    assert a._acc.partial().same_as(b._acc.partial())  # the exact sums, limb for limb
    assert (a.n_dropped_nan, a.n_dropped_range) == (b.n_dropped_nan, b.n_dropped_range)


def _sphere_raster(light_theta_deg: float, res: int = 160) -> tuple[np.ndarray, np.ndarray]:
    """Light/view vectors (local frames) of a sphere's pixels in raster order: image-like order,
    neighbouring samples in neighbouring bins. Includes unlit pixels (light below horizon)."""
    u = (np.arange(res) + 0.5) / res * 2.0 - 1.0
    x, y = np.meshgrid(u, -u)
    on = x * x + y * y < 1.0
    n = np.stack([x[on], y[on], np.sqrt(1.0 - x[on] ** 2 - y[on] ** 2)], axis=-1)
    t = np.radians(light_theta_deg)
    light = 4.0 * np.array([np.sin(t), 0.0, np.cos(t)]) - n
    view = np.array([0.0, 0.0, 10.0]) - n
    light /= np.linalg.norm(light, axis=-1, keepdims=True)
    view /= np.linalg.norm(view, axis=-1, keepdims=True)
    tangent = np.cross([0.0, 1.0, 0.0], n)
    tangent /= np.linalg.norm(tangent, axis=-1, keepdims=True)
    frame = np.stack([tangent, np.cross(n, tangent), n], axis=-2)
    return np.einsum("nij,nj->ni", frame, light), np.einsum("nij,nj->ni", frame, view)


def _numpy_vector_index(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """Flat index the numpy path of MerlTable.add_vectors bins each pair into."""
    th, td, pd = halfdiff_rad_from_vectors(wi, wo)
    flat = np.empty(th.size, dtype=np.int64)
    flat_index_unclamped_into(th, td, pd, flat, np.pi)
    below = (wi[:, 2] <= 0.0) | (wo[:, 2] <= 0.0)
    given_nan = np.isnan(wi).any(axis=1) | np.isnan(wo).any(axis=1)
    flat[below & ~given_nan] = -1
    return flat


# ---------------------------------------------------------------------------- accumulator
@pytest.mark.parametrize("channels", [3, 2, 4])
@pytest.mark.parametrize("order", ["random", "sorted"])
def test_accumulator_backends_agree(channels, order):
    rng = np.random.default_rng(channels)
    n, bins = 20_000, (40, 30, 20)
    idx = rng.integers(-3, 24_000 + 3, n)  # a few −3…−1 codes and indices past the end
    idx[::997] = -2
    if order == "sorted":
        idx.sort()
    vals = rng.normal(1.0, 0.5, (n, channels))
    vals[::613, channels - 1] = np.nan
    vals[5::1009, 0] = np.inf
    accs = {}
    for backend in ("numba", "numpy"):
        acc = BinAccumulator(bins, channels, backend=backend)
        kept = acc.add_flat(idx[:7000], vals[:7000]) + acc.add_flat(idx[7000:], vals[7000:])
        accs[backend] = (acc, kept)
    (a, kept_a), (b, kept_b) = accs["numba"], accs["numpy"]
    assert kept_a == kept_b
    assert kept_a == int(a._count.sum()) and kept_a < n
    np.testing.assert_array_equal(a.count, b.count)
    np.testing.assert_array_equal(a.sum, b.sum)
    np.testing.assert_array_equal(a.sum_of_squares, b.sum_of_squares)
    assert (a.n_dropped_nan, a.n_dropped_range) == (b.n_dropped_nan, b.n_dropped_range)
    assert a.n_dropped_nan > 0 and a.n_dropped_range > 0


def test_backend_choice_argument_environment_and_propagation(monkeypatch, tmp_path):
    monkeypatch.delenv(ENV_VAR, raising=False)
    assert resolve_backend() == "numba" and MerlTable().backend == "numba"
    monkeypatch.setenv(ENV_VAR, "numpy")
    assert MerlTable().backend == "numpy" and BinAccumulator((2,)).backend == "numpy"
    assert MerlTable(backend="numba").backend == "numba"
    monkeypatch.setenv(ENV_VAR, "cuda")
    with pytest.raises(ConfigError, match=ENV_VAR):
        MerlTable()
    with pytest.raises(ConfigError, match="backend argument"):
        BinAccumulator((2,), backend="fortran")
    monkeypatch.setenv(ENV_VAR, "numba")
    edges = np.linspace(0.0, 90.0, 4)
    iso = IsotropicTable(edges, edges, [0.0, 90.0, 180.0], backend="numpy")
    iso.add(10.0, 20.0, 30.0, [[1.0, 2.0, 3.0]])
    assert (iso + iso).backend == iso.fold_reciprocity().backend == "numpy"
    merl = MerlTable(backend="numpy")
    assert (merl + merl).backend == merl.fold_mirror_symmetry().backend == "numpy"
    assert BinAccumulator((3,), backend="numpy").copy().backend == "numpy"
    iso.save_h5(tmp_path / "t.h5")
    assert IsotropicTable.load_h5(tmp_path / "t.h5").backend == "numba"  # from the environment


# ---------------------------------------------------------------------------- MERL
def _halfdiff_edge_cases() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    eh, ed, ep = merl_bin_edges()
    near = lambda e: np.concatenate([e, np.nextafter(e, -1e9), np.nextafter(e, 1e9)])  # noqa: E731
    th = np.concatenate([near(eh), [-0.0, -1e-300]])
    td = np.concatenate([near(ed), [-0.0]])
    pd = np.concatenate([near(ep), -near(ep), [-0.0, 360.0, 540.5, -540.5, -360.0, 1e300]])
    specials = np.array([np.nan, np.inf, -np.inf])
    rng = np.random.default_rng(11)
    k = 4000
    pick = lambda a: np.concatenate([rng.choice(a, k), specials])  # noqa: E731
    return pick(th), pick(td), pick(pd)


def test_merl_halfdiff_index_and_table_match_numpy():
    rng = np.random.default_rng(1)
    n = 50_000
    th = np.concatenate([rng.uniform(-2, 92, n), _halfdiff_edge_cases()[0]])
    td = np.concatenate([rng.uniform(-2, 92, n), _halfdiff_edge_cases()[1]])
    pd = np.concatenate([rng.uniform(-400, 400, n), _halfdiff_edge_cases()[2]])
    got = np.empty(th.size, dtype=np.int64)
    kernels.merl_flat_index_deg(th, td, pd, got)
    rad = [np.radians(a) for a in (th, td, pd)]
    np.testing.assert_array_equal(got, merl_flat_index_rad(*rad, clamp=False))
    np.testing.assert_array_equal(got, merl_flat_index(th, td, pd, clamp=False))  # degrees path
    assert (got == -2).any() and (got == -1).any() and (got >= 0).mean() > 0.8
    # Inside the table it is the reference reader's (clamped) index, bin edges included.
    inside = (got >= 0) & (pd > -180.0) & (pd <= 180.0)
    np.testing.assert_array_equal(got[inside], merl_flat_index_rad(*rad)[inside])
    assert inside.sum() > 20_000
    vals = rng.uniform(0, 2, (th.size, 3))
    vals[::101, 1] = np.nan
    tables = {b: MerlTable(backend=b) for b in ("numba", "numpy")}
    kept = {b: t.add_halfdiff(th, td, pd, vals) for b, t in tables.items()}
    assert kept["numba"] == kept["numpy"] == tables["numba"].n_samples
    _assert_same_tables(tables["numba"], tables["numpy"])


def test_merl_vectors_index_and_table_match_numpy():
    rng = np.random.default_rng(2)
    ti, tr, dp = rng.uniform(0, 90, 30_000), rng.uniform(0, 90, 30_000), rng.uniform(-180, 180, 30_000)
    ti, tr, dp = (np.concatenate([a, DEGENERATE[:, k]]) for k, a in enumerate((ti, tr, dp)))
    wi, wo = directions_from_angles(ti, tr, dp)
    lit = [_sphere_raster(d) for d in (20.0, 70.0)]
    extra_i = np.array([[0, 0, -1.0], [np.nan, 0, 1.0], [0.6, 0, 0.8], [0.6, 0, 0.8], [0, 0, 1.0]])
    extra_o = np.array([[0, 0, 1.0], [0, 0, 1.0], [-0.6, 0, -0.8], [0.6, 0, -0.8], [0, 0, 1.0]])
    wi = np.concatenate([wi, *(a for a, _ in lit), extra_i])
    wo = np.concatenate([wo, *(b for _, b in lit), extra_o])
    got = np.empty(wi.shape[0], dtype=np.int64)
    kernels.merl_flat_index_vectors(wi, wo, got)
    want = _numpy_vector_index(wi, wo)
    # Same arithmetic; near a bin edge numpy's acos/atan2 are redone with libm: same bins.
    np.testing.assert_array_equal(got, want)
    assert list(got[-5:-1]) == [-1, -2, -1, -1] and (got == -1).sum() > 100
    vals = rng.uniform(0, 1, (wi.shape[0], 3))
    tables = {b: MerlTable(backend=b) for b in ("numba", "numpy")}
    for t in tables.values():
        for a in range(0, wi.shape[0], 9000):  # image-sized batches, in order
            t.add_vectors(wi[a:a + 9000], wo[a:a + 9000], vals[a:a + 9000])
    _assert_same_tables(tables["numba"], tables["numpy"])


def test_merl_angles_index_and_table_match_numpy_reference_conversion():
    rng = np.random.default_rng(3)
    # In-plane poses (Δφ = 0, ±180°): φd is ±180° or 0 decided by the sign of a zero.
    plane = rng.choice([0.0, -0.0, 180.0, -180.0], 2000)
    grid = rng.integers(0, 90, (2, 2000)).astype(float)
    ti = np.concatenate([rng.uniform(-1, 91, 20_000), grid[0], DEGENERATE[:, 0], [np.nan, 95.0, 10.0]])
    tr = np.concatenate([rng.uniform(-1, 91, 20_000), grid[1], DEGENERATE[:, 1], [10.0, 10.0, np.nan]])
    dp = np.concatenate([rng.uniform(-360, 360, 20_000), plane, DEGENERATE[:, 2], [0.0, 0.0, 0.0]])
    got = np.empty(ti.size, dtype=np.int64)
    kernels.merl_flat_index_angles(ti, tr, dp, got)
    th, td, pd = halfdiff_rad_reference(np.radians(ti), 0.0, np.radians(tr), np.radians(dp))
    want = np.empty(ti.size, dtype=np.int64)
    flat_index_unclamped_into(th, td, pd, want, np.pi)
    with np.errstate(invalid="ignore"):
        outside = (ti < 0) | (ti > 90) | (tr < 0) | (tr > 90)
    want[outside & (want != -2)] = -1
    np.testing.assert_array_equal(got, want)
    vals = rng.uniform(0, 1, (ti.size, 3))
    tables = {b: MerlTable(backend=b) for b in ("numba", "numpy")}
    for t in tables.values():
        t.add_angles(ti, tr, dp, vals)
    _assert_same_tables(tables["numba"], tables["numpy"])


# ---------------------------------------------------------------------------- isotropic
@pytest.mark.parametrize("fold", [True, False])
def test_isotropic_backends_agree(fold):
    ei = np.array([0.0, 5.0, 12.5, 30.0, 60.0, 90.0])
    er = np.linspace(0.0, 90.0, 19)
    ep = np.linspace(0.0, 180.0, 13) if fold else np.linspace(-180.0, 180.0, 25)
    rng = np.random.default_rng(4)
    n = 30_000
    ti, tr, dp = rng.uniform(-5, 95, n), rng.uniform(-5, 95, n), rng.uniform(-720, 720, n)
    ti[:ei.size], tr[:er.size], dp[:ep.size] = ei, er, ep  # values exactly on edges
    dp[ep.size:ep.size + 6] = [-0.0, 360.0, -180.0, 540.0, np.inf, -360.0]
    ti[100:103] = np.nan
    vals = rng.uniform(0, 1, (n, 3))
    vals[200, 0] = np.nan
    tables = {
        b: IsotropicTable(ei, er, ep, fold_delta_phi=fold, backend=b) for b in ("numba", "numpy")
    }
    for t in tables.values():
        assert t.add(ti, tr, dp, vals) == t.n_samples
        t.add(45.0, 45.0, 100.0, vals[:50])  # one direction, many values
        t.add(ti[:10], 30.0, dp[:10], vals[:10])  # broadcast scalars
    got = np.empty(n, dtype=np.int64)
    t = tables["numba"]
    kernels.iso_flat_index(ti, tr, dp, ei, er, ep, fold, got)
    np.testing.assert_array_equal(got, tables["numpy"].flat_index(ti, tr, dp))
    np.testing.assert_array_equal(got, t.flat_index(ti, tr, dp))
    _assert_same_tables(tables["numba"], tables["numpy"])
    with pytest.raises(ValueError, match="3 angle samples but 2 RGB"):
        t.add([1.0, 2.0, 3.0], 1.0, 1.0, vals[:2])


# ---------------------------------------------------------------------------- compiled code
def test_each_kernel_compiles_once_whatever_the_input_layout():
    rng = np.random.default_rng(5)
    th, td, pd = rng.uniform(0, 90, (3, 64, 3))  # strided columns below
    vals32 = rng.uniform(0, 1, (64, 3)).astype(np.float32)
    table = MerlTable(backend="numba")
    table.add_halfdiff(th[:, 0], td[:, 1], pd[:, 2], vals32)
    table.add_halfdiff(list(th[:, 0]), 10, 20.0, vals32.T.copy().T)
    table.add_flat(np.arange(64, dtype=np.int32), vals32[:, :3])
    assert table.n_samples == 192
    for kernel in (kernels.merl_flat_index_deg, exact_kernels.add_flat):
        assert len(kernel.signatures) == 1, kernel.signatures


def test_threads_bin_into_separate_tables_then_merge():
    wi, wo = _sphere_raster(40.0)
    vals = np.random.default_rng(6).uniform(0, 1, (wi.shape[0], 3))
    whole = MerlTable(backend="numba")
    whole.add_vectors(wi, wo, vals)
    parts = [MerlTable(backend="numba") for _ in range(2)]
    half = wi.shape[0] // 2
    spans = [(0, half), (half, wi.shape[0])]
    threads = [
        threading.Thread(target=p.add_vectors, args=(wi[a:b], wo[a:b], vals[a:b]))
        for p, (a, b) in zip(parts, spans, strict=True)
    ]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    merged = parts[0] + parts[1]
    np.testing.assert_array_equal(merged.count, whole.count)
    np.testing.assert_array_equal(merged.mean, whole.mean)  # exact sums: split-independent
    np.testing.assert_array_equal(merged.variance, whole.variance)
    assert 0 < merged.n_samples < MERL_BINS
