"""gonio export --format bsdf: RGL-EPFL tensor files (Dupuy & Jakob 2018) that Mitsuba 3's
``measured`` plug-in loads and renders as gonio renders the table; ``.bsdf`` files read back
(``gonio export`` from a ``.bsdf``, ``gonio info``, the ``bsdf:PATH`` material)."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest

from acquisition.analysis.render import render_sphere, sphere_angles, table_brdf
from acquisition.cli import main
from acquisition.formats.export import export_table
from acquisition.formats.marginal2d import Marginal2D
from acquisition.formats.merl import read_merl
from acquisition.formats.rgl import RglBsdf, directions, read_bsdf
from acquisition.formats.tensorfile import read_tensor_file, write_tensor_file
from acquisition.simworld.materials import parse_material
from acquisition.tables import IsotropicTable
from drivers.errors import ConfigError, OutputRefused

MITSUBA = "3.9.1"
"""The release pinned in the test extra: its ``measured`` plug-in reads the ``rgb`` field
(RGB variants) since 3.4.0."""
LIGHTS_DEG = ((0.0, 0.0), (30.0, 0.0), (60.0, 20.0), (45.0, -120.0))
"""Light (elevation, azimuth) seen from the sphere's centre, camera at the pole."""


@pytest.fixture(scope="module")
def ggx(quick_tables: dict[str, Path], tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The simulated GGX capture's table and its ``gonio export --format bsdf``."""
    out = tmp_path_factory.mktemp("bsdf") / "ggx.bsdf"
    assert main(["export", str(quick_tables["ggx"]), "--format", "bsdf", "-o", str(out)]) == 0
    return quick_tables["ggx"], out


def test_the_file_holds_every_field_the_measured_plugin_reads(ggx: tuple[Path, Path]) -> None:
    table_path, path = ggx
    raw = path.read_bytes()
    assert raw[:12] == b"tensor_file\0" and raw[12:14] == bytes([1, 0])
    fields = read_tensor_file(path)
    assert struct.unpack_from("<I", raw, 14)[0] == len(fields)
    f32 = {"theta_i": 1, "phi_i": 1, "ndf": 2, "sigma": 2, "vndf": 4, "luminance": 4, "rgb": 5}
    for name, rank in f32.items():
        assert fields[name].dtype == np.float32 and fields[name].ndim == rank, name
        assert np.isfinite(fields[name]).all() and (fields[name] >= 0).all(), name
    assert fields["jacobian"].dtype == np.uint8 and list(fields["jacobian"]) == [1]
    n_theta = fields["theta_i"].size
    assert fields["phi_i"].shape == (1,)  # isotropic
    assert fields["rgb"].shape[:3] == (1, n_theta, 3)
    assert fields["luminance"].shape == (1, n_theta, *fields["rgb"].shape[3:])
    assert fields["vndf"].shape[:2] == (1, n_theta)
    about = json.loads(bytes(fields["description"]).decode())
    assert about["generator"] == "gonio" and about["source_format"] == "gonio-isotropic-brdf"
    assert about["provenance"]["material"] == IsotropicTable.load_h5(table_path).provenance["material"]
    assert "retro-reflection" in about["ndf"] and "shadow cone" in about["ndf"]


def test_reading_back_gives_the_table(ggx: tuple[Path, Path]) -> None:
    table_path, path = ggx
    table = IsotropicTable.load_h5(table_path)
    measured = table.count > 0
    angles = np.stack(np.meshgrid(*table.centers(), indexing="ij"), axis=-1)[measured]
    bsdf = read_bsdf(path)
    rel = np.abs(bsdf(*angles.T) / table.mean[measured] - 1.0)
    assert np.median(rel) < 0.02, np.median(rel)  # measured: 0.15 %
    spec = parse_material(f"bsdf:{path}")  # the simulated camera's view of the same file
    np.testing.assert_allclose(spec(*angles.T), bsdf(*angles.T))
    ti, tr, dp = (np.random.default_rng(0).uniform(lo, hi, 4000) for lo, hi in
                  ((0, 75), (0, 75), (0, 180)))
    rel = np.abs(bsdf(ti, tr, dp) / table_brdf(table)(ti, tr, dp) - 1.0)
    assert np.median(rel) < 0.01 and np.percentile(rel, 90) < 0.05


def test_a_bsdf_exports_to_merl_and_reexports(ggx: tuple[Path, Path], tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    _, path = ggx
    assert main(["export", str(path), "--format", "merl", "-o", str(tmp_path / "m.binary")]) == 0
    assert "MERL bin centres" in capsys.readouterr().out
    merl, bsdf = read_merl(tmp_path / "m.binary"), read_bsdf(path)
    ti, tr, dp = np.array([10.0, 40.0, 60.0]), np.array([30.0, 40.0, 20.0]), np.array([90.0, 180.0, 45.0])
    rel = np.abs(merl(ti, tr, dp) / bsdf(ti, tr, dp) - 1.0)
    assert rel.max() < 0.1  # nearest MERL bin centre
    assert main(["export", str(path), "--format", "bsdf"]) != 0  # would overwrite its input
    assert main(["export", str(path), "--format", "bsdf", "-o", str(tmp_path / "b.bsdf")]) == 0
    assert main(["info", str(tmp_path / "b.bsdf")]) == 0
    assert "RGL .bsdf" in capsys.readouterr().out


def test_a_merl_file_exports_to_bsdf(ggx: tuple[Path, Path], tmp_path: Path) -> None:
    table_path, _ = ggx
    assert main(["export", str(table_path), "--format", "merl", "-o", str(tmp_path / "t.binary")]) == 0
    assert main(["export", str(tmp_path / "t.binary"), "--format", "bsdf", "-o",
                 str(tmp_path / "t.bsdf")]) == 0
    merl, bsdf = read_merl(tmp_path / "t.binary"), read_bsdf(tmp_path / "t.bsdf")
    ti, tr, dp = (np.random.default_rng(1).uniform(lo, hi, 3000) for lo, hi in
                  ((5, 70), (5, 70), (0, 180)))
    want = merl(ti, tr, dp)
    ok = (want > 0).all(axis=1)
    assert ok.mean() > 0.5  # MERL bins the table filled (nearest measured bin)
    assert np.median(np.abs(bsdf(ti, tr, dp)[ok] / want[ok] - 1.0)) < 0.02


def test_malformed_spectral_and_foreign_files_are_refused(
        ggx: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _, path = ggx
    fields = dict(read_tensor_file(path))
    with pytest.raises(ConfigError, match="spectral"):
        RglBsdf({**fields, "wavelengths": np.array([400.0], np.float32)}, "x.bsdf")
    with pytest.raises(ConfigError, match="missing field"):
        RglBsdf({k: v for k, v in fields.items() if k != "vndf"}, "x.bsdf")
    cut = tmp_path / "cut.bsdf"
    cut.write_bytes(path.read_bytes()[:5000])
    with pytest.raises(ConfigError, match="truncated"):
        read_bsdf(cut)
    foreign = tmp_path / "theirs.bsdf"  # a tensor file gonio did not write: never replaced
    write_tensor_file(foreign, {"description": np.frombuffer(b"RGL", np.uint8)}, what="t", ours=None)
    assert main(["export", str(ggx[0]), "--format", "bsdf", "-o", str(foreign)]) != 0
    assert "not a RGL .bsdf file gonio wrote" in capsys.readouterr().err
    assert read_tensor_file(foreign)["description"].tobytes() == b"RGL"
    with pytest.raises(OutputRefused):
        export_table(ggx[0], "bsdf", foreign)


def test_the_warp_is_a_bijection_with_its_density() -> None:
    rng = np.random.default_rng(0)
    warp = Marginal2D(rng.uniform(0.1, 2.0, (3, 5, 6, 7)), [np.arange(3.0), np.linspace(0, 2, 5)])
    u = rng.uniform(0.01, 0.99, (3000, 2))
    params = rng.uniform(0, 2, (3000, 2))
    x, pdf = warp.sample(u, params)
    back, pdf_back = warp.invert(x, params)
    np.testing.assert_allclose(back, u, atol=1e-5)
    np.testing.assert_allclose(pdf_back, pdf, rtol=1e-12)
    np.testing.assert_allclose(warp.eval(x, params), pdf, rtol=1e-12)
    h = 1e-6  # the density is the inverse Jacobian determinant of the warp
    dx, _ = warp.sample(u + [h, 0.0], params)
    dy, _ = warp.sample(u + [0.0, h], params)
    det = np.abs(np.linalg.det(np.stack([(dx - x) / h, (dy - x) / h], axis=-1)))
    assert np.median(np.abs(pdf * det - 1.0)) < 1e-4


# ------------------------------------------------------------------------------ Mitsuba 3
def _mitsuba():  # type: ignore[no-untyped-def]
    mi = pytest.importorskip("mitsuba", reason="Mitsuba 3 is not installed here (it comes with "
                             f"the test extra, mitsuba=={MITSUBA}: pip install -e '.[test]')")
    mi.set_variant("scalar_rgb")
    return mi


def _mitsuba_sphere(mi, path: Path, light: np.ndarray, size: int = 64) -> np.ndarray:  # type: ignore[no-untyped-def]
    """A unit sphere of the measured material seen orthographically from +z (gonio's lit-sphere
    framing) under a point light 1000 units away towards ``light`` (irradiance 1)."""
    distance = 1000.0
    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "direct", "emitter_samples": 1, "bsdf_samples": 0},
        "sensor": {"type": "orthographic",
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 5], target=[0, 0, 0],
                                                              up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": size, "height": size,
                            "rfilter": {"type": "box"}, "pixel_format": "rgb"},
                   "sampler": {"type": "independent", "sample_count": 32}},
        "ball": {"type": "sphere", "radius": 1.0,
                 "bsdf": {"type": "measured", "filename": str(path)}},
        "light": {"type": "point", "position": (distance * light).tolist(),
                  "intensity": {"type": "rgb", "value": [distance ** 2] * 3}},
    })
    return np.asarray(mi.render(scene, seed=0), dtype=np.float64)


def _mitsuba_eval(mi, path: Path, view: np.ndarray, light: np.ndarray) -> np.ndarray:  # type: ignore[no-untyped-def]
    """Mitsuba's ``measured`` BSDF value (f · cos θ_light) for each (view, light) pair."""
    bsdf = mi.load_dict({"type": "measured", "filename": str(path)})
    out = []
    for wv, wl in zip(view, light, strict=True):
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(*wv)
        si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
        value = bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(*wl))
        out.append([value[0], value[1], value[2]])
    return np.array(out)


def _random_pairs(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(view, light) unit vectors above the horizon, both turned by a random azimuth."""
    light, view = directions(rng.uniform(0, 85, n), rng.uniform(0, 85, n), rng.uniform(0, 360, n))
    a = rng.uniform(0, 2 * np.pi, n)
    c, s = np.cos(a), np.sin(a)

    def turn(w: np.ndarray) -> np.ndarray:
        return np.stack([c * w[:, 0] - s * w[:, 1], s * w[:, 0] + c * w[:, 1], w[:, 2]], axis=-1)
    return turn(view), turn(light)


def test_mitsuba_evaluates_the_file_as_gonio_does(ggx: tuple[Path, Path]) -> None:
    mi = _mitsuba()
    view, light = _random_pairs(np.random.default_rng(3), 200)
    np.testing.assert_allclose(_mitsuba_eval(mi, ggx[1], view, light),
                               read_bsdf(ggx[1]).eval_cos(view, light), rtol=1e-4, atol=1e-7)


def write_random_bsdf(path: Path, phi_i_deg: tuple[float, ...], rng: np.random.Generator
                      ) -> dict[str, np.ndarray]:
    """A ``.bsdf`` of random fields (isotropic when ``phi_i_deg`` has one value, else with the
    symmetry reduction its range implies); returns the fields."""
    n_phi, res = len(phi_i_deg), 7
    fields = {"theta_i": np.radians([0.0, 20.0, 50.0, 90.0]), "phi_i": np.radians(phi_i_deg),
              "ndf": rng.uniform(0.5, 2, (6, 9)), "sigma": rng.uniform(0.5, 2, (5, 7)),
              "vndf": rng.uniform(0.1, 2, (n_phi, 4, 8, 11)),
              "luminance": rng.uniform(0.1, 2, (n_phi, 4, res, res)),
              "rgb": rng.uniform(0, 1, (n_phi, 4, 3, res, res))}
    if n_phi == 1:  # an isotropic material's tables are mirror-symmetric in relative azimuth
        # (Mitsuba 3.9 leaves its symmetry reduction uninitialised for isotropic files and
        # mirrors them by y: harmless only for such tables)
        fields["ndf"][:] = fields["ndf"][0]
        fields["sigma"][:] = fields["sigma"][0]
        for name in ("vndf", "luminance", "rgb"):
            fields[name] = (fields[name] + fields[name][..., ::-1, :]) / 2
    fields = {k: np.asarray(v, np.float32) for k, v in fields.items()}
    fields |= {"jacobian": np.ones(1, np.uint8), "description": np.frombuffer(b"random", np.uint8)}
    write_tensor_file(path, fields, what="test file", ours=None)
    return fields


@pytest.mark.parametrize("phi_i_deg", [(0, 45, 90), (0, 60, 120, 180), (-180, -90, 0, 90, 180)])
def test_gonio_reads_any_rgl_file_as_mitsuba_does(phi_i_deg: tuple[float, ...], tmp_path: Path) -> None:
    """Random anisotropic fields (symmetry reductions 4, 2, none): gonio's reader is the
    reference evaluator, not only for the files gonio writes."""
    mi = _mitsuba()
    rng = np.random.default_rng(len(phi_i_deg))
    path = tmp_path / "random.bsdf"
    write_random_bsdf(path, phi_i_deg, rng)
    view, light = _random_pairs(rng, 150)
    np.testing.assert_allclose(_mitsuba_eval(mi, path, view, light),
                               read_bsdf(path).eval_cos(view, light), rtol=1e-4, atol=1e-6)


def test_mitsuba_renders_the_exported_table_as_gonio_does(ggx: tuple[Path, Path]) -> None:
    mi = _mitsuba()
    assert mi.__version__ == MITSUBA, f"the test extra pins mitsuba=={MITSUBA}"
    table_path, path = ggx
    brdf = table_brdf(IsotropicTable.load_h5(table_path))
    for elevation, azimuth in LIGHTS_DEG:
        e, a = np.radians(elevation), np.radians(azimuth)
        light = np.array([np.sin(e) * np.cos(a), np.sin(e) * np.sin(a), np.cos(e)])
        ours = render_sphere(brdf, light, 64)
        theirs = _mitsuba_sphere(mi, path, light)
        ti, tr, _, _, on = sphere_angles(64, light)
        lit = on & (ti < 75.0) & (tr < 75.0)  # lit, away from grazing angles
        rel = np.abs(theirs[lit] / ours[lit] - 1.0)
        assert np.median(rel) < 0.05, (elevation, azimuth, np.median(rel))  # measured: ≤ 0.4 %
        assert np.percentile(rel, 90) < 0.05, (elevation, azimuth, np.percentile(rel, 90))
