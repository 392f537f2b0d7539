"""MERL file format, lookup and table, checked against an independent reference reader.

The ``ref_*`` functions below re-implement the MERL reference reader (BRDFRead.cpp) in plain
scalar Python with the ``math`` module, written separately from acquisition.geometry.halfdiff/merl.
"""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest

import acquisition.tables.merl_table as merl_table_module
from acquisition.formats.merl import MERL_FILE_BYTES, read_merl, write_merl
from acquisition.simworld.materials import MerlMaterial
from acquisition.tables import MerlTable
from drivers.errors import ConfigError, MaterialError
from simulators.materials import Material, directions_from_angles, material_from_spec

N_BINS = 90 * 90 * 180
SCALE = (1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0)


# ---------------------------------------------------------------------------- reference
def ref_rotate(v, axis, angle):
    c, s = math.cos(angle), math.sin(angle)
    out = [v[0] * c, v[1] * c, v[2] * c]
    t = (axis[0] * v[0] + axis[1] * v[1] + axis[2] * v[2]) * (1.0 - c)
    out = [out[k] + axis[k] * t for k in range(3)]
    cross = [
        axis[1] * v[2] - axis[2] * v[1],
        axis[2] * v[0] - axis[0] * v[2],
        axis[0] * v[1] - axis[1] * v[0],
    ]
    return [out[k] + cross[k] * s for k in range(3)]


def ref_normalized(v):
    n = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    return [v[0] / n, v[1] / n, v[2] / n]


def ref_half_diff(theta_in, fi_in, theta_out, fi_out):
    vin = [math.sin(theta_in) * math.cos(fi_in), math.sin(theta_in) * math.sin(fi_in),
           math.cos(theta_in)]
    vout = [math.sin(theta_out) * math.cos(fi_out), math.sin(theta_out) * math.sin(fi_out),
            math.cos(theta_out)]
    half = ref_normalized([(vin[k] + vout[k]) / 2.0 for k in range(3)])
    theta_half = math.acos(half[2])
    fi_half = math.atan2(half[1], half[0])
    tmp = ref_rotate(ref_normalized(vin), [0.0, 0.0, 1.0], -fi_half)
    diff = ref_rotate(tmp, [0.0, 1.0, 0.0], -theta_half)
    theta_diff = math.acos(diff[2]) if -1.0 <= diff[2] <= 1.0 else math.nan
    return theta_half, theta_diff, math.atan2(diff[1], diff[0])


def ref_c_int(x):
    """C (int) cast as on x86: truncation, NaN → INT_MIN."""
    return -(2**31) if math.isnan(x) else int(x)


def ref_index(theta_half, theta_diff, phi_diff):
    if theta_half <= 0.0:
        ih = 0
    else:
        ih = ref_c_int(math.sqrt(theta_half / (math.pi / 2.0) * 90 * 90))
        ih = min(max(ih, 0), 89)
    idd = min(max(ref_c_int(theta_diff / (math.pi * 0.5) * 90), 0), 89)
    if phi_diff < 0.0:
        phi_diff += math.pi
    ip = min(max(ref_c_int(phi_diff / math.pi * 360 / 2), 0), 179)
    return ip + idd * 180 + ih * 180 * 90


def ref_read(path):
    with open(path, "rb") as fh:
        blob = fh.read()
    dims = struct.unpack("<3i", blob[:12])
    assert dims[0] * dims[1] * dims[2] == N_BINS
    return np.frombuffer(blob, "<f8", offset=12)


def ref_lookup(brdf, theta_in, fi_in, theta_out, fi_out):
    ind = ref_index(*ref_half_diff(theta_in, fi_in, theta_out, fi_out))
    return [brdf[ind + k * N_BINS] * SCALE[k] for k in range(3)]


def ref_lookup_deg(brdf, ti, tr, dp):
    return ref_lookup(brdf, math.radians(ti), 0.0, math.radians(tr), math.radians(dp))


def _random_angles(rng, n):
    return rng.uniform(0, 89.9, n), rng.uniform(0, 89.9, n), rng.uniform(-180, 180, n)


# Configurations where φd is decided by signed zeros / tiny sin(π) terms.
DEGENERATE = [
    (30.0, 30.0, 180.0), (30.0, 30.0, 0.0), (20.0, 50.0, 180.0), (50.0, 20.0, 180.0),
    (0.0, 40.0, 0.0), (40.0, 0.0, 90.0), (0.0, 0.0, 0.0), (45.0, 45.0, 90.0),
    (60.0, 10.0, 0.0), (10.0, 60.0, -180.0), (89.0, 89.0, 180.0),
]


# ---------------------------------------------------------------------------- files
@pytest.fixture(scope="module")
def synthetic_file(tmp_path_factory):
    """A MERL file made with struct/numpy only: random values, some negative, some odd bits."""
    rng = np.random.default_rng(2024)
    data = rng.uniform(0.0, 3000.0, 3 * N_BINS)
    data[rng.integers(0, data.size, 5000)] *= -1.0
    data[7] = -0.0
    data[11] = np.frombuffer(struct.pack("<Q", 0x7FF8_0000_DEAD_BEEF), "<f8")[0]  # NaN payload
    path = tmp_path_factory.mktemp("merl") / "synthetic.binary"
    path.write_bytes(struct.pack("<3i", 90, 90, 180) + data.astype("<f8").tobytes())
    return path


def test_read_merl_matches_reference_lookup(synthetic_file):
    brdf = read_merl(synthetic_file)
    ref = ref_read(synthetic_file)
    rng = np.random.default_rng(5)
    ti, tr, dp = _random_angles(rng, 1500)
    ti = np.concatenate([ti, [c[0] for c in DEGENERATE]])
    tr = np.concatenate([tr, [c[1] for c in DEGENERATE]])
    dp = np.concatenate([dp, [c[2] for c in DEGENERATE]])
    got = brdf(ti, tr, dp)
    want = np.array([ref_lookup_deg(ref, *a) for a in zip(ti, tr, dp, strict=True)])
    assert got.shape == (ti.size, 3)
    np.testing.assert_array_equal(got, want)
    # Vectorised over any shape; vectors give the same bins away from bin boundaries.
    assert brdf(ti[:6].reshape(2, 3), tr[:6].reshape(2, 3), 10.0).shape == (2, 3, 3)
    wi, wo = directions_from_angles(ti[:1500], tr[:1500], dp[:1500])
    np.testing.assert_array_equal(brdf.eval_vectors(wi, wo), want[:1500])


def test_round_trip_is_byte_for_byte(synthetic_file, tmp_path):
    out = tmp_path / "copy.binary"
    write_merl(out, read_merl(synthetic_file))
    assert out.read_bytes() == synthetic_file.read_bytes()
    assert out.stat().st_size == MERL_FILE_BYTES == 34_992_012
    # A header with the same product (the reference checks only that) is kept too.
    odd = tmp_path / "odd.binary"
    odd.write_bytes(struct.pack("<3i", 180, 90, 90) + synthetic_file.read_bytes()[12:])
    write_merl(out, read_merl(odd))
    assert out.read_bytes() == odd.read_bytes()


def test_malformed_files_raise_config_error(synthetic_file, tmp_path):
    blob = synthetic_file.read_bytes()
    short = tmp_path / "short.binary"
    short.write_bytes(blob[:-8])
    with pytest.raises(ConfigError, match="expected 34992012"):
        read_merl(short)
    bad = tmp_path / "bad.binary"
    bad.write_bytes(struct.pack("<3i", 90, 90, 360) + blob[12:])
    with pytest.raises(ConfigError, match="header"):
        read_merl(bad)
    with pytest.raises(ConfigError, match="does not exist"):
        read_merl(tmp_path / "missing.binary")


# ---------------------------------------------------------------------------- tables → files
def _expected_bin_means(ti, tr, dp, values):
    """Group samples by the reference's own bin index; mean per bin."""
    groups: dict[int, list] = {}
    for a, b, c, v in zip(ti, tr, dp, values, strict=True):
        idx = ref_index(*ref_half_diff(math.radians(a), 0.0, math.radians(b), math.radians(c)))
        groups.setdefault(idx, []).append(v)
    return {k: np.mean(v, axis=0) for k, v in groups.items()}


@pytest.mark.parametrize("via", ["angles", "vectors"])
def test_write_merl_then_reference_lookup_gives_table_values(tmp_path, via):
    rng = np.random.default_rng(17 if via == "angles" else 18)
    ti, tr, dp = _random_angles(rng, 2000)
    # Repeat some directions so several bins hold more than one sample.
    ti, tr, dp = (np.concatenate([x, x[:300]]) for x in (ti, tr, dp))
    values = rng.uniform(0.01, 5.0, (ti.size, 3))
    table = MerlTable()
    if via == "angles":
        assert table.add_angles(ti, tr, dp, values) == ti.size
    else:
        wi, wo = directions_from_angles(ti, tr, dp)
        assert table.add_vectors(wi, wo, values) == ti.size
    path = tmp_path / "table.binary"
    write_merl(path, table)
    assert path.stat().st_size == 34_992_012
    assert struct.unpack("<3i", path.read_bytes()[:12]) == (90, 90, 180)
    ref = ref_read(path)
    expected = _expected_bin_means(ti, tr, dp, values)
    for a, b, c in zip(ti, tr, dp, strict=True):
        idx = ref_index(*ref_half_diff(math.radians(a), 0.0, math.radians(b), math.radians(c)))
        np.testing.assert_allclose(ref_lookup_deg(ref, a, b, c), expected[idx], rtol=1e-14)
    # Every other bin is unmeasured: the reference reads a negative value there.
    assert (ref < 0).sum() == 3 * (N_BINS - len(expected))
    empty = next(
        (a, b, c)
        for a, b, c in zip(*_random_angles(rng, 100), strict=True)
        if ref_index(*ref_half_diff(math.radians(a), 0.0, math.radians(b), math.radians(c)))
        not in expected
    )
    assert all(v < 0 for v in ref_lookup_deg(ref, *empty))


def test_write_merl_accepts_arrays_with_nan_as_unmeasured(tmp_path):
    rng = np.random.default_rng(3)
    values = rng.uniform(0, 2, (90, 90, 180, 3))
    values[0, 0, :5] = np.nan
    path = tmp_path / "a.binary"
    write_merl(path, values, unmeasured=-2.5)
    back = read_merl(path)
    np.testing.assert_allclose(back.values[1:], values[1:], rtol=1e-15)
    np.testing.assert_array_equal(back.stored[:, 0, 0, :5], -2.5)
    assert not back.measured[0, 0, :5].any() and back.measured[0, 0, 5:].all()
    write_merl(path, np.moveaxis(values, -1, 0))  # channel-first layout
    np.testing.assert_allclose(read_merl(path).values[1:], values[1:], rtol=1e-15)
    with pytest.raises(ValueError, match="shaped"):
        write_merl(path, np.zeros((90, 90, 90, 3)))


# ---------------------------------------------------------------------------- MERL table
def test_merl_table_matches_brute_force_statistics():
    rng = np.random.default_rng(9)
    ti, tr, dp = _random_angles(rng, 400)
    ti, tr, dp = (np.concatenate([x, x[:150], x[:50]]) for x in (ti, tr, dp))
    values = rng.normal(1.0, 0.2, (ti.size, 3))
    table = MerlTable()
    table.add_angles(ti, tr, dp, values)
    groups: dict[int, list] = {}
    for a, b, c, v in zip(ti, tr, dp, values, strict=True):
        idx = ref_index(*ref_half_diff(math.radians(a), 0.0, math.radians(b), math.radians(c)))
        groups.setdefault(idx, []).append(v)
    count = table.count.reshape(-1)
    mean = table.mean.reshape(-1, 3)
    var = table.variance.reshape(-1, 3)
    assert count.sum() == ti.size and np.count_nonzero(count) == len(groups)
    for idx, vals in groups.items():
        arr = np.array(vals)
        assert count[idx] == len(vals)
        np.testing.assert_allclose(mean[idx], arr.mean(axis=0), rtol=1e-12)
        if len(vals) > 1:
            np.testing.assert_allclose(var[idx], arr.var(axis=0, ddof=1), rtol=1e-9, atol=1e-15)
        else:
            assert np.isnan(var[idx]).all()
    assert np.isnan(mean[count == 0]).all()


def test_merl_table_streams_in_chunks_and_batches(monkeypatch):
    rng = np.random.default_rng(4)
    ti, tr, dp = _random_angles(rng, 3000)
    wi, wo = directions_from_angles(ti, tr, dp)
    values = rng.uniform(0, 1, (3000, 3))
    whole = MerlTable()
    whole.add_vectors(wi, wo, values)
    monkeypatch.setattr(merl_table_module, "CHUNK", 257)
    parts = MerlTable()
    for a, b in ((2000, 3000), (0, 1000), (1000, 2000)):
        parts.add_vectors(wi[a:b], wo[a:b], values[a:b])
    np.testing.assert_array_equal(parts.count, whole.count)
    np.testing.assert_allclose(parts.mean, whole.mean, rtol=1e-12, equal_nan=True)
    merged = MerlTable()
    merged.add_vectors(wi[:10], wo[:10], values[:10])
    merged = merged + MerlTable().merge(parts)
    assert merged.n_samples == 3010


def test_merl_table_drops_below_horizon_and_nan():
    table = MerlTable()
    wi = np.array([[0, 0, 1.0], [0, 0, -1.0], [np.nan, 0, 1.0], [0.6, 0, 0.8], [0.6, 0, 0.8]])
    wo = np.array([[0, 0, 1.0], [0, 0, 1.0], [0, 0, 1.0], [-0.6, 0, -0.8], [-0.6, 0, 0.8]])
    rgb = np.ones((5, 3))
    rgb[4, 2] = np.nan
    assert table.add_vectors(wi, wo, rgb) == 1
    assert table.n_dropped_range == 2 and table.n_dropped_nan == 2
    assert table.add_halfdiff([10.0, 95.0, np.nan], [10.0, 10.0, 10.0], [370.0, 0, 0], rgb[:3]) == 1
    assert table.n_dropped_range == 3 and table.n_dropped_nan == 3
    assert table.add_angles([10.0, 95.0], [10.0, 10.0], [0.0, 0.0], rgb[:2]) == 1
    assert table.n_dropped_range == 4


def test_merl_mirror_folding_pools_phi_d_bins():
    table = MerlTable()
    table.add_halfdiff([20.0, 20.0, 20.0], [30.0, 30.0, 30.0], [10.5, 169.5, 90.5],
                       [[1, 1, 1], [3, 3, 3], [5, 5, 5]])
    folded = table.fold_mirror_symmetry()
    ih = int(math.sqrt(20 / 90) * 90)
    assert folded.count[ih, 30, 10] == folded.count[ih, 30, 169] == 2
    np.testing.assert_allclose(folded.mean[ih, 30, 10], [2, 2, 2])
    assert folded.count[ih, 30, 90] == 1 and folded.count[ih, 30, 89] == 1


# ---------------------------------------------------------------------------- material
def test_merl_material_spec_renders_file_values(synthetic_file):
    material = material_from_spec(f"merl:{synthetic_file}")
    assert isinstance(material, Material) and isinstance(material, MerlMaterial)
    assert material.spec == f"merl:{synthetic_file}"
    brdf = read_merl(synthetic_file)
    rng = np.random.default_rng(8)
    ti, tr, dp = _random_angles(rng, 500)
    wi, wo = directions_from_angles(ti, tr, dp)
    raw = brdf.eval_vectors(wi, wo)
    measured = (raw >= 0).all(axis=-1)  # the reference: "Below horizon." if any channel < 0
    np.testing.assert_array_equal(material(ti, tr, dp), np.where(measured[:, None], raw, 0.0))
    assert (~measured).any()  # the synthetic file has unmeasured bins: they render as 0
    below = material.eval_vectors(np.array([0.0, 0.6, -0.8]), np.array([0.0, 0.0, 1.0]))
    np.testing.assert_array_equal(below, [0.0, 0.0, 0.0])


def test_merl_material_spec_errors(tmp_path):
    with pytest.raises(MaterialError, match="does not exist"):
        material_from_spec(f"merl:{tmp_path / 'nope.binary'}")
    with pytest.raises(MaterialError, match="needs a file path"):
        material_from_spec("merl:")
    junk = tmp_path / "junk.binary"
    junk.write_bytes(b"\0" * 100)
    with pytest.raises(MaterialError, match="header"):
        material_from_spec(f"merl:{junk}")


def test_comparisons_leave_out_bins_where_the_truth_is_unmeasured() -> None:
    from acquisition.api.truth import relative_errors
    from acquisition.tables import IsotropicTable

    edges = np.array([0.0, 30.0, 60.0])
    measured = IsotropicTable(edges, edges, np.array([0.0, 90.0, 180.0]))
    truth = IsotropicTable(edges, edges, np.array([0.0, 90.0, 180.0]))
    for ti, value, true in ((10.0, 0.11, 0.10), (40.0, 0.02, 0.0)):  # 0: the file has no data
        measured.add(np.array([ti]), np.array([10.0]), np.array([45.0]), np.full((1, 3), value))
        truth.add(np.array([ti]), np.array([10.0]), np.array([45.0]), np.full((1, 3), true))
    errors = relative_errors(measured, truth)
    assert errors.shape == (1,) and errors[0] == pytest.approx(0.1)
    assert np.isfinite(np.median(errors))
