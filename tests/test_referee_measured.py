"""The simulated camera's measured materials (``merl:``, ``bsdf:``) are the simulator's own code
(:mod:`simulators.measured`): they agree with gonio's readers (two implementations of one
format), with Mitsuba 3's ``measured`` plug-in, and with files built byte by byte, and a bug in
gonio's half/difference coordinates now shows in the capture-and-reduce round trip instead of
cancelling out."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from test_image_capture import merl_round_trip
from test_rgl_bsdf import _mitsuba, _mitsuba_eval, _random_pairs, write_random_bsdf

import acquisition.formats.merl as gonio_merl
import acquisition.geometry.halfdiff as gonio_halfdiff
import acquisition.tables.merl_table as gonio_merl_table
from acquisition.formats.merl import read_merl
from acquisition.formats.rgl import RglBsdf
from acquisition.formats.tensorfile import write_tensor_file
from acquisition.geometry.halfdiff import halfdiff_rad_from_vectors, merl_flat_index_rad
from acquisition.simworld.materials import MerlMaterial, RglMaterial
from drivers.errors import MaterialError
from simulators.materials import MATERIAL_PARSERS, Material, directions_from_angles, material_from_spec
from simulators.measured.merl import N_BINS, bin_index, half_difference_rad, read_merl_file
from simulators.measured.rgl import RglFile, read_rgl_file

SCALES = (1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0)
EDGE_BAND = 1e-8
"""Distance (in bins) from a bin edge within which two correct implementations may pick either
neighbour: their angles differ by float rounding (measured ≤ 4e-10 bins at integer poses)."""


def _flat(ih: int, id_: int, ip: int) -> int:
    return (ih * 90 + id_) * 180 + ip


UNMEASURED_G, NAN_B, MEASURED_ZERO_R = _flat(40, 20, 30), _flat(40, 20, 31), _flat(40, 20, 32)
"""Bins of :func:`numbered_file` with one odd channel."""
MARKED = (UNMEASURED_G, NAN_B, MEASURED_ZERO_R)


def _merl_bytes(planes: np.ndarray, dims: tuple[int, int, int] = (90, 90, 180)) -> bytes:
    """A MERL file's bytes built with struct and numpy alone: (3, 1,458,000) stored values."""
    return struct.pack("<3i", *dims) + np.ascontiguousarray(planes, "<f8").tobytes()


@pytest.fixture(scope="module")
def numbered_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Each bin stores its own flat index (R), twice it (G), three times (B): a lookup names
    the bin it read; a few bins are unmeasured in one channel or not a number."""
    k = np.arange(N_BINS, dtype=np.float64)
    planes = np.stack([k, 2 * k, 3 * k])
    planes[1, UNMEASURED_G] = -1.0
    planes[2, NAN_B] = np.nan
    planes[0, MEASURED_ZERO_R] = -0.0
    path = tmp_path_factory.mktemp("referee") / "numbered.binary"
    path.write_bytes(_merl_bytes(planes))
    return path


def _unit_directions(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2])
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _bin_coordinates(theta_h: np.ndarray, theta_d: np.ndarray, phi_d: np.ndarray) -> np.ndarray:
    """Continuous MERL bin coordinates (3, n): integers are bin edges."""
    folded = np.where(phi_d < 0, phi_d + np.pi, phi_d)
    return np.stack([90 * np.sqrt(theta_h / (np.pi / 2)), theta_d / (np.pi / 2) * 90,
                     folded / np.pi * 180])


# ---------------------------------------------------------------------------- MERL
def _directions_in_bins(ih: np.ndarray, id_: np.ndarray, ip: np.ndarray,
                        rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Light and view vectors (n, 3) at the centres of the bins (θh, θd, φd indices), built
    the other way round: wi = Rz(φh)·Ry(θh)·d for a random φh (and φd on either side of the
    reciprocity fold), wo its mirror about h."""
    n = len(ih)
    theta_h = ((ih + 0.5) / 90) ** 2 * (np.pi / 2)
    theta_d = (id_ + 0.5) / 90 * (np.pi / 2)
    phi_d = (ip + 0.5) / 180 * np.pi - np.where(rng.random(n) < 0.5, np.pi, 0.0)
    phi_h = rng.uniform(-np.pi, np.pi, n)
    d = np.stack([np.sin(theta_d) * np.cos(phi_d), np.sin(theta_d) * np.sin(phi_d),
                  np.cos(theta_d)], axis=-1)
    ch, sh, cp, sp = np.cos(theta_h), np.sin(theta_h), np.cos(phi_h), np.sin(phi_h)
    x, z = ch * d[:, 0] + sh * d[:, 2], -sh * d[:, 0] + ch * d[:, 2]
    wi = np.stack([cp * x - sp * d[:, 1], sp * x + cp * d[:, 1], z], axis=-1)
    h = np.stack([sh * cp, sh * sp, ch], axis=-1)
    return wi, 2 * np.sum(wi * h, axis=-1, keepdims=True) * h - wi


def test_the_referee_reads_the_bin_the_format_names(numbered_file: Path) -> None:
    """Directions built from bin-centre angles come back to that bin; the values are stored ×
    the channel's scale."""
    merl = read_merl_file(numbered_file)
    rng = np.random.default_rng(1)
    ih, id_, ip = rng.integers(0, 90, 4000), rng.integers(0, 90, 4000), rng.integers(0, 180, 4000)
    flat = (ih * 90 + id_) * 180 + ip
    keep = ~np.isin(flat, MARKED)
    wi, wo = _directions_in_bins(ih[keep], id_[keep], ip[keep], rng)
    np.testing.assert_array_equal(merl.lookup(wi, wo),
                                  (flat[keep, None] * np.array([1, 2, 3])) * SCALES)


def test_the_referee_lookup_agrees_with_the_gonio_reader(numbered_file: Path) -> None:
    """Two implementations of one format: on random directions the angles agree to 1e-12 rad
    and every lookup is the same; at integer-degree poses (many exactly on a bin edge) a bin
    differs only within :data:`EDGE_BAND` of an edge, and then by one step on that axis."""
    merl, gonio = read_merl_file(numbered_file), read_merl(numbered_file)
    rng = np.random.default_rng(7)
    wi, wo = _unit_directions(rng, 200_000), _unit_directions(rng, 200_000)
    ours, theirs = half_difference_rad(wi, wo), halfdiff_rad_from_vectors(wi, wo)
    for a, b in zip(ours[:2], theirs[:2], strict=True):
        assert np.abs(a - b).max() < 1e-12
    turn = np.abs(ours[2] - theirs[2])
    assert np.minimum(turn, 2 * np.pi - turn).max() < 1e-12
    np.testing.assert_array_equal(merl.lookup(wi, wo), gonio.eval_vectors(wi, wo))

    ti, tr, dp = (a.ravel() for a in np.meshgrid(np.arange(90.0), np.arange(90.0),
                                                 np.arange(-180.0, 181.0, 5.0), indexing="ij"))
    wi, wo = directions_from_angles(ti, tr, dp)
    ours = half_difference_rad(wi, wo)
    mine, gonio_bins = bin_index(*ours), merl_flat_index_rad(*halfdiff_rad_from_vectors(wi, wo))
    differ = mine != gonio_bins
    coords = _bin_coordinates(*ours)
    on_edge = np.abs(coords - np.rint(coords)) < EDGE_BAND
    assert 0 < differ.sum() < on_edge.any(axis=0).sum()  # measured: 9,908 of 43,060 on an edge
    assert on_edge.any(axis=0)[differ].all()
    steps = np.abs(np.array(np.unravel_index(mine[differ], (90, 90, 180)))
                   - np.array(np.unravel_index(gonio_bins[differ], (90, 90, 180))))
    steps[2] = np.minimum(steps[2], 180 - steps[2])  # φd: bins 0 and 179 meet at the fold
    assert steps.max() == 1 and (steps <= on_edge[:, differ]).all()
    same = ~differ
    np.testing.assert_array_equal(merl.lookup(wi[same], wo[same]),
                                  gonio.eval_vectors(wi[same], wo[same]))


def test_unmeasured_bins_render_black_in_every_channel(numbered_file: Path) -> None:
    """The reference reports a lookup "Below horizon." when any channel is negative; the
    material renders such a bin, and a NaN one, black (−0.0 is a measured zero)."""
    material = material_from_spec(f"merl:{numbered_file}")
    assert isinstance(material, MerlMaterial) and isinstance(material, Material)
    rng = np.random.default_rng(3)
    ip = np.repeat([29, 30, 31, 32, 33], 50)
    wi, wo = _directions_in_bins(np.full(ip.size, 40), np.full(ip.size, 20), ip, rng)
    up = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    assert up.all()
    raw, shown = material.merl.lookup(wi, wo), material.eval_vectors(wi, wo)
    assert (raw[ip == 30, 1] < 0).all() and np.isnan(raw[ip == 31, 2]).all()
    np.testing.assert_array_equal(shown[(ip == 30) | (ip == 31)], 0.0)
    keep = (ip != 30) & (ip != 31)  # incl. the −0.0 bin, shown as stored
    np.testing.assert_array_equal(shown[keep], raw[keep])
    assert (shown[ip == 29] > 0).all()
    below = material.eval_vectors(np.array([0.0, 0.6, -0.8]), np.array([0.0, 0.0, 1.0]))
    np.testing.assert_array_equal(below, [0.0, 0.0, 0.0])


def test_malformed_merl_files_are_refused_in_one_line(numbered_file: Path, tmp_path: Path) -> None:
    raw = numbered_file.read_bytes()
    odd = tmp_path / "odd.binary"  # the reference checks only the product of the dimensions
    odd.write_bytes(struct.pack("<3i", 180, 90, 90) + raw[12:])
    np.testing.assert_array_equal(read_merl_file(odd).brdf, read_merl_file(numbered_file).brdf)
    short = tmp_path / "short.binary"
    short.write_bytes(raw[:-8])
    with pytest.raises(MaterialError, match="expected 34992012"):
        material_from_spec(f"merl:{short}")
    bad = tmp_path / "bad.binary"
    bad.write_bytes(struct.pack("<3i", 90, 90, 360) + raw[12:])
    with pytest.raises(MaterialError, match="header"):
        read_merl_file(bad)


# ---------------------------------------------------------------------------- round trip
def _swapped_theta_h_and_theta_d(wi: np.ndarray, wo: np.ndarray) -> tuple[np.ndarray, ...]:
    theta_h, theta_d, phi_d = ORIGINAL(wi, wo)
    return theta_d, theta_h, phi_d


def _unnormalised_half_vector(wi: np.ndarray, wo: np.ndarray) -> tuple[np.ndarray, ...]:
    """θh = acos((wi + wo)_z / 2): the division by |wi + wo| / 2 = cos θd left out."""
    theta_h, theta_d, phi_d = ORIGINAL(wi, wo)
    return np.arccos(np.cos(theta_h) * np.cos(theta_d)), theta_d, phi_d


def _atan2_arguments_swapped(wi: np.ndarray, wo: np.ndarray) -> tuple[np.ndarray, ...]:
    """φd = atan2(d_x, d_y) = 90° − φd (wrapped into (−180°, 180°])."""
    theta_h, theta_d, phi_d = ORIGINAL(wi, wo)
    return theta_h, theta_d, np.angle(np.exp(1j * (np.pi / 2 - phi_d)))


ORIGINAL = halfdiff_rad_from_vectors
BUGS = {"swapped θh and θd": _swapped_theta_h_and_theta_d,
        "unnormalised half vector": _unnormalised_half_vector,
        "atan2 arguments swapped": _atan2_arguments_swapped}


class GonioMerlMaterial(Material):
    """The simulated material as it was before the referee had a reader: gonio's own lookup."""

    def __init__(self, path: str) -> None:
        self.brdf, self.spec = read_merl(path), f"gonio-merl:{path}"

    def eval_vectors(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        up = (wi[..., 2] > 0) & (wo[..., 2] > 0)
        return np.where(up[..., None], np.maximum(self.brdf.eval_vectors(wi, wo), 0.0), 0.0)


@pytest.mark.parametrize("bug", list(BUGS))
def test_a_wrong_half_difference_conversion_fails_the_merl_round_trip(
        bug: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """gonio's vector → (θh, θd, φd) conversion replaced by a wrong one wherever it is used (the
    numpy binning path: the numba kernels hold their own compiled copy of the formula). The
    capture of ``merl:x.binary`` reduced into a MERL table no longer gives x.binary back; it
    did when the simulated camera evaluated the file through gonio's reader (the same wrong
    bins cancelled). With the correct code both give it back (tests/test_image_capture.py)."""
    monkeypatch.setenv("GONIO_BINNING_BACKEND", "numpy")
    for module in (gonio_halfdiff, gonio_merl_table, gonio_merl):
        monkeypatch.setattr(module, "halfdiff_rad_from_vectors", BUGS[bug])
    monkeypatch.setitem(MATERIAL_PARSERS, "gonio-merl", GonioMerlMaterial)
    (tmp_path / "before").mkdir()
    (tmp_path / "referee").mkdir()
    before = merl_round_trip(tmp_path / "before", prefix="gonio-merl")
    assert before.passes, before  # measured: ≤ 2.2 % of the bins off by 10 %
    caught = merl_round_trip(tmp_path / "referee")
    assert not caught.passes, caught
    assert caught.table_off > 0.03  # measured: 93 %, 29 %, 4.2 % of the bins off by 10 %


# ---------------------------------------------------------------------------- RGL .bsdf
@pytest.mark.parametrize("phi_i_deg", [(0,), (0, 45, 90), (0, 60, 120, 180),
                                       (-180, -90, 0, 90, 180)])
def test_the_referee_evaluates_bsdf_files_as_gonio_and_mitsuba_do(
        phi_i_deg: tuple[float, ...], tmp_path: Path) -> None:
    """Random files (isotropic; anisotropic with symmetry reductions 4, 2 and none): the
    referee's value agrees with gonio's reader to float64 rounding (measured ≤ 2e-13 relative)
    and with Mitsuba 3's plug-in to its float32 arithmetic (an isotropic file's tables are
    symmetric in relative azimuth: see :func:`write_random_bsdf`)."""
    rng = np.random.default_rng(len(phi_i_deg))
    path = tmp_path / "random.bsdf"
    fields = write_random_bsdf(path, phi_i_deg, rng)
    ours = read_rgl_file(path)
    view, light = _random_pairs(rng, 20_000)
    mine = ours.eval_cos(view, light)
    np.testing.assert_allclose(mine, RglBsdf(fields).eval_cos(view, light), rtol=1e-11, atol=0)
    material = material_from_spec(f"bsdf:{path}")
    assert isinstance(material, RglMaterial)
    np.testing.assert_allclose(material.eval_vectors(light, view), mine / light[:, 2:3],
                               rtol=1e-15)
    mi = _mitsuba()
    np.testing.assert_allclose(_mitsuba_eval(mi, path, view[:150], light[:150]), mine[:150],
                               rtol=1e-4, atol=1e-6)


def test_bsdf_directions_below_the_horizon_give_zero(tmp_path: Path) -> None:
    path = tmp_path / "iso.bsdf"
    write_random_bsdf(path, (0,), np.random.default_rng(0))
    material = material_from_spec(f"bsdf:{path}")
    up, down = np.array([[0.3, 0.0, 0.954]]), np.array([[0.3, 0.0, -0.954]])
    assert (material.eval_vectors(up, up) > 0).all()
    for wi, wo in ((up, down), (down, up), (np.array([[1.0, 0, 0]]), up)):
        np.testing.assert_array_equal(material.eval_vectors(wi, wo), 0.0)


def test_malformed_bsdf_files_are_refused_in_one_line(tmp_path: Path) -> None:
    path = tmp_path / "ok.bsdf"
    fields = write_random_bsdf(path, (0,), np.random.default_rng(0))
    cut = tmp_path / "cut.bsdf"
    cut.write_bytes(path.read_bytes()[:400])
    with pytest.raises(MaterialError, match="truncated or malformed"):
        material_from_spec(f"bsdf:{cut}")
    spectral = tmp_path / "spectral.bsdf"
    write_tensor_file(spectral, {**fields, "wavelengths": np.array([500.0], np.float32)},
                      what="test file", ours=None)
    with pytest.raises(MaterialError, match="spectral"):
        material_from_spec(f"bsdf:{spectral}")
    with pytest.raises(MaterialError, match="no field vndf"):
        RglFile({k: v for k, v in fields.items() if k != "vndf"}, "x.bsdf")
    foreign = tmp_path / "foreign.bsdf"
    foreign.write_bytes(b"not a tensor file")
    with pytest.raises(MaterialError, match="not a tensor file"):
        material_from_spec(f"bsdf:{foreign}")
