"""Isotropic (θi, θr, Δφ) table: binning against a brute-force loop, streaming, HDF5 file."""

from __future__ import annotations

import json
import math

import h5py
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from acquisition.tables import BinAccumulator, IsotropicTable, fold_delta_phi, wrap_delta_phi
from drivers.errors import ConfigError, StorageError

TI = np.array([0.0, 10.0, 25.0, 40.0, 60.0, 90.0])  # deliberately non-uniform
TR = np.linspace(0.0, 90.0, 7)
DP = np.linspace(0.0, 180.0, 10)


def _random_samples(rng: np.random.Generator, n: int) -> tuple[np.ndarray, ...]:
    ti = rng.uniform(-5.0, 95.0, n)
    tr = rng.uniform(0.0, 90.0, n)
    dp = rng.uniform(-400.0, 400.0, n)
    # Exact edges, including the closed upper edges and Δφ = ±180 (mirror plane).
    ti[:6] = TI
    tr[:7] = TR
    dp[:5] = [180.0, -180.0, 0.0, 360.0, 540.0]
    rgb = rng.normal(0.3, 0.1, (n, 3))
    return ti, tr, dp, rgb


def _bin_of(v: float, edges: np.ndarray) -> int | None:
    """Brute force: [e_k, e_k+1) with the last bin closed."""
    for k in range(len(edges) - 1):
        if edges[k] <= v < edges[k + 1] or (k == len(edges) - 2 and v == edges[-1]):
            return k
    return None


def _fold_loop(d: float) -> float:
    """Independent Δφ fold: bring into (−180, 180] by whole turns, then take |Δφ|."""
    while d > 180.0:
        d -= 360.0
    while d <= -180.0:
        d += 360.0
    return abs(d)


def _brute_force(ti, tr, dp, rgb, shape):
    groups: dict[tuple[int, int, int], list[np.ndarray]] = {}
    dropped = 0
    for a, b, c, v in zip(ti, tr, dp, rgb, strict=True):
        if any(math.isnan(x) for x in (a, b, c, *v)):
            dropped += 1
            continue
        key = (_bin_of(a, TI), _bin_of(b, TR), _bin_of(_fold_loop(c), DP))
        if None in key:
            dropped += 1
            continue
        groups.setdefault(key, []).append(v)
    count = np.zeros(shape, np.int64)
    mean = np.full(shape + (3,), np.nan)
    var = np.full(shape + (3,), np.nan)
    for key, vals in groups.items():
        arr = np.array(vals)
        count[key] = len(vals)
        mean[key] = arr.mean(axis=0)
        if len(vals) > 1:
            var[key] = arr.var(axis=0, ddof=1)
    return count, mean, var, dropped


def test_binning_matches_brute_force_loop():
    rng = np.random.default_rng(1)
    ti, tr, dp, rgb = _random_samples(rng, 3000)
    table = IsotropicTable(TI, TR, DP)
    kept = table.add(ti, tr, dp, rgb)
    count, mean, var, dropped = _brute_force(ti, tr, dp, rgb, table.shape)
    np.testing.assert_array_equal(table.count, count)
    np.testing.assert_allclose(table.mean, mean, rtol=1e-12, atol=1e-15, equal_nan=True)
    np.testing.assert_allclose(table.variance, var, rtol=1e-9, atol=1e-15, equal_nan=True)
    assert kept == count.sum() == 3000 - dropped
    assert table.n_dropped_range == dropped
    assert table.count.dtype == np.int64 and table.mean.shape == table.shape + (3,)
    with np.errstate(invalid="ignore"):
        np.testing.assert_allclose(table.variance_of_mean, var / count[..., None], equal_nan=True)


def test_out_of_range_and_nan_are_dropped_and_counted():
    table = IsotropicTable(TI, TR, DP)
    ti = np.array([10.0, -1.0, 91.0, np.nan, 10.0, 10.0, 10.0])
    tr = np.array([10.0, 10.0, 10.0, 10.0, np.nan, 10.0, 95.0])
    dp = np.zeros(7)
    rgb = np.full((7, 3), 0.2)
    rgb[5, 1] = np.nan
    assert table.add(ti, tr, dp, rgb) == 1
    assert table.n_dropped_nan == 3
    assert table.n_dropped_range == 3
    assert table.count.sum() == 1
    assert np.count_nonzero(~np.isnan(table.mean[..., 0])) == 1


@settings(max_examples=25, deadline=None)
@given(st.lists(st.integers(0, 400), min_size=1, max_size=6), st.integers(0, 2**31))
def test_streaming_batches_equal_one_batch(cuts, seed):
    rng = np.random.default_rng(seed)
    ti, tr, dp, rgb = _random_samples(rng, 400)
    whole = IsotropicTable(TI, TR, DP)
    whole.add(ti, tr, dp, rgb)
    streamed = IsotropicTable(TI, TR, DP)
    bounds = [0, *sorted(cuts), 400]
    order = rng.permutation(len(bounds) - 1)  # batch order does not matter either
    for k in order:
        a, b = bounds[k], bounds[k + 1]
        streamed.add(ti[a:b], tr[a:b], dp[a:b], rgb[a:b])
    np.testing.assert_array_equal(streamed.count, whole.count)
    np.testing.assert_allclose(streamed.mean, whole.mean, rtol=1e-12, equal_nan=True)
    np.testing.assert_allclose(streamed.variance, whole.variance, rtol=1e-9, equal_nan=True)
    assert streamed.n_dropped_range == whole.n_dropped_range


def test_merge_equals_adding_everything():
    rng = np.random.default_rng(7)
    ti, tr, dp, rgb = _random_samples(rng, 1000)
    a, b, both = (IsotropicTable(TI, TR, DP) for _ in range(3))
    a.add(ti[:300], tr[:300], dp[:300], rgb[:300])
    b.add(ti[300:], tr[300:], dp[300:], rgb[300:])
    both.add(ti, tr, dp, rgb)
    merged = a + b
    np.testing.assert_array_equal(merged.count, both.count)
    np.testing.assert_allclose(merged.variance, both.variance, rtol=1e-9, equal_nan=True)
    with pytest.raises(ConfigError, match="delta_phi_edges"):
        a.merge(IsotropicTable(TI, TR, np.linspace(0, 180, 5)))


def test_fold_delta_phi_helpers():
    d = np.array([-30.0, 190.0, 360.0, 180.0, -180.0, 0.0, 725.0, -725.0])
    np.testing.assert_allclose(fold_delta_phi(d), [30, 170, 0, 180, 180, 0, 5, 5])
    np.testing.assert_allclose(wrap_delta_phi(d, 0.0), [330, 190, 0, 180, 180, 0, 5, 355])
    assert IsotropicTable(TI, TR, DP).fold_delta_phi
    assert IsotropicTable(TI, TR, [-5.0, 5.0, 175.0, 185.0]).fold_delta_phi
    assert not IsotropicTable(TI, TR, np.linspace(-180, 180, 9)).fold_delta_phi


def test_unfolded_table_keeps_sign_of_delta_phi():
    table = IsotropicTable([0, 90], [0, 90], np.linspace(-180, 180, 5))
    table.add([30, 30, 30], [30, 30, 30], [-100.0, 100.0, 260.0], np.ones((3, 3)))
    # bins [-180,-90), [-90,0), [0,90), [90,180]: 260 wraps to -100.
    np.testing.assert_array_equal(table.count[0, 0], [2, 0, 0, 1])


def test_reciprocity_folding_pools_swapped_bins():
    rng = np.random.default_rng(3)
    ti, tr, dp, rgb = _random_samples(rng, 2000)
    edges = np.linspace(0, 90, 7)
    table = IsotropicTable(edges, edges, DP)
    table.add(ti, tr, dp, rgb)
    folded = table.fold_reciprocity()
    # Reference: a table fed every off-diagonal sample also with θi and θr swapped.
    ref = IsotropicTable(edges, edges, DP)
    ref.add(ti, tr, dp, rgb)
    off = np.array([_bin_of(a, edges) != _bin_of(b, edges) for a, b in zip(ti, tr, strict=True)])
    ref.add(tr[off], ti[off], dp[off], rgb[off])
    np.testing.assert_array_equal(folded.count, ref.count)
    np.testing.assert_allclose(folded.mean, ref.mean, rtol=1e-12, equal_nan=True)
    np.testing.assert_allclose(folded.variance, ref.variance, rtol=1e-9, equal_nan=True)
    np.testing.assert_array_equal(folded.count, folded.count.transpose(1, 0, 2))
    with pytest.raises(ConfigError, match="theta_r_edges"):
        IsotropicTable(TI, TR, DP).fold_reciprocity()


def test_bad_edges_raise_config_error():
    with pytest.raises(ConfigError, match="theta_r_edges"):
        IsotropicTable(TI, [0.0, 50.0, 40.0], DP)
    with pytest.raises(ConfigError, match="delta_phi_edges"):
        IsotropicTable(TI, TR, [0.0])


# ---------------------------------------------------------------------------- HDF5


def _filled_table() -> IsotropicTable:
    rng = np.random.default_rng(11)
    ti, tr, dp, rgb = _random_samples(rng, 500)
    table = IsotropicTable(TI, TR, DP)
    table.add(ti, tr, dp, rgb)
    return table


def test_h5_layout_attributes_dtypes_and_shapes(tmp_path):
    table = _filled_table()
    path = tmp_path / "table.h5"
    table.save_h5(path, provenance={"material": "ggx:albedo=0.2", "frames": 12})
    with h5py.File(path, "r") as f:
        assert set(f.keys()) == {
            "theta_i_edges", "theta_r_edges", "delta_phi_edges", "mean", "variance", "count",
            "std_error", "mean_theta_i_deg", "mean_theta_r_deg", "mean_delta_phi_deg",
            "angle_covariance_deg2", "uncertainty",
        }
        attrs = dict(f.attrs)
        assert np.isnan(attrs.pop("scatter_ratio")) and attrs.pop("scatter_bins") == 0
        assert attrs == {
            "units": "1/sr",
            "quantity": "brdf",
            "channels": "R,G,B",
            "format": "gonio-isotropic-brdf",
            "version": 2,
            "provenance": f.attrs["provenance"],
        }
        assert json.loads(f.attrs["provenance"]) == {"material": "ggx:albedo=0.2", "frames": 12}
        ni, nr, nphi = len(TI) - 1, len(TR) - 1, len(DP) - 1
        for name, edges in (("theta_i_edges", TI), ("theta_r_edges", TR), ("delta_phi_edges", DP)):
            assert f[name].dtype == np.float64
            np.testing.assert_array_equal(f[name][()], edges)
        assert f["mean"].shape == f["variance"].shape == (ni, nr, nphi, 3)
        assert f["mean"].dtype == f["variance"].dtype == np.float64
        assert f["count"].shape == (ni, nr, nphi) and f["count"].dtype == np.int64
        np.testing.assert_array_equal(f["count"][()], table.count)
        np.testing.assert_array_equal(f["mean"][()], table.mean)
        empty = f["count"][()] == 0
        assert empty.any() and np.isnan(f["mean"][()][empty]).all()
        single = f["count"][()] == 1
        assert np.isnan(f["variance"][()][single]).all()
    assert list(tmp_path.iterdir()) == [path]  # no temporary file left behind


def test_h5_round_trip_and_continue_accumulating(tmp_path):
    table = _filled_table()
    path = tmp_path / "t.h5"
    table.provenance = {"run": "a"}
    table.save_h5(path)
    loaded = IsotropicTable.load_h5(path)
    assert loaded.provenance == {"run": "a"}
    for name in ("theta_i_edges", "theta_r_edges", "delta_phi_edges"):
        np.testing.assert_array_equal(getattr(loaded, name), getattr(table, name))
    np.testing.assert_array_equal(loaded.count, table.count)
    np.testing.assert_array_equal(loaded.mean, table.mean)
    np.testing.assert_array_equal(loaded.variance, table.variance)
    # Overwrite in place, then keep binning into the loaded table.
    loaded.save_h5(path)
    rng = np.random.default_rng(12)
    more = _random_samples(rng, 300)
    loaded.add(*more)
    table.add(*more)
    np.testing.assert_array_equal(loaded.count, table.count)
    np.testing.assert_allclose(loaded.mean, table.mean, rtol=1e-12, equal_nan=True)
    np.testing.assert_allclose(loaded.variance, table.variance, rtol=1e-8, equal_nan=True)


@pytest.mark.parametrize(
    ("attr", "value", "match"),
    [("format", "something-else", "format is 'something-else'"), ("version", 3, "version 3")],
)
def test_load_wrong_format_or_version_is_config_error(tmp_path, attr, value, match):
    path = tmp_path / "t.h5"
    _filled_table().save_h5(path)
    with h5py.File(path, "a") as f:
        f.attrs[attr] = value
    with pytest.raises(ConfigError, match=match) as info:
        IsotropicTable.load_h5(path)
    assert "\n" not in str(info.value) and str(path) in str(info.value)


def test_load_missing_or_non_hdf5_is_config_error(tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        IsotropicTable.load_h5(tmp_path / "nope.h5")
    junk = tmp_path / "junk.h5"
    junk.write_bytes(b"not hdf5 at all")
    with pytest.raises(ConfigError, match="not a readable HDF5"):
        IsotropicTable.load_h5(junk)


def test_save_into_missing_folder_is_storage_error(tmp_path):
    with pytest.raises(StorageError, match="cannot write BRDF table .*: folder missing"):
        _filled_table().save_h5(tmp_path / "no" / "such" / "t.h5")


def test_accumulator_rebuilt_from_statistics_matches_sums():
    rng = np.random.default_rng(5)
    acc = BinAccumulator((4, 5), 3)
    idx = rng.integers(0, 20, 200)
    acc.add_flat(idx, rng.random((200, 3)))
    back = BinAccumulator.from_statistics(acc.count, acc.mean(), acc.variance())
    np.testing.assert_array_equal(back.count, acc.count)
    np.testing.assert_allclose(back.sum, acc.sum, rtol=1e-12)
    np.testing.assert_allclose(back.sum_of_squares, acc.sum_of_squares, rtol=1e-12)


def test_add_leaves_the_callers_values_untouched() -> None:
    """Regression: the numpy backend once squared a one-row batch in place."""
    for backend in ("numpy", "numba"):
        table = IsotropicTable([0, 45, 90], [0, 45, 90], [0, 90, 180], backend=backend)
        rgb = np.array([[2.0, 3.0, 4.0]])
        table.add(30, 40, 10, rgb)
        np.testing.assert_array_equal(rgb, [[2.0, 3.0, 4.0]])
        np.testing.assert_array_equal(table.mean[0, 0, 0], [2.0, 3.0, 4.0])
