"""gonio check (reciprocity, energy, coverage, SNR) and gonio compare (tables, MERL files,
material specs)."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest
from captured import MATERIALS

from acquisition import api
from acquisition.cli import main
from acquisition.formats.merl import write_merl
from acquisition.tables import IsotropicTable


def edited_copy(src: Path, dst: Path, edit) -> Path:  # noqa: ANN001 - edit(mean, terms, count)
    """A copy of a table file whose mean and uncertainty terms ``edit`` changed in place."""
    dst.write_bytes(src.read_bytes())
    with h5py.File(dst, "r+") as f:
        mean, count = f["mean"][()], f["count"][()]
        terms = {k: f["uncertainty"][k][()] for k in f["uncertainty"]}
        edit(mean, terms, count)
        f["mean"][...] = mean
        for k, v in terms.items():
            f["uncertainty"][k][...] = v
        f["std_error"][...] = np.sqrt(sum(v**2 for v in terms.values()))
    return dst


def test_check_passes_on_simulated_captures(quick_tables: dict[str, Path],
                                            capsys: pytest.CaptureFixture[str]) -> None:
    for name in MATERIALS:
        assert main(["check", str(quick_tables[name])]) == 0, name
        out = capsys.readouterr()
        assert "reciprocity:" in out.out and ": pass" in out.out and out.err == ""


def test_check_fails_on_a_planted_asymmetry(quick_tables: dict[str, Path],
                                            tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    """Bins with θi < θr raised by 5× their (independent) uncertainty: reciprocity fails."""
    def plant(mean: np.ndarray, terms: dict, count: np.ndarray) -> None:
        ii, rr = np.meshgrid(np.arange(mean.shape[0]), np.arange(mean.shape[1]), indexing="ij")
        upper = (ii < rr) & (count > 0).any(axis=-1)
        mean[upper] += 5.0 * terms["noise"][upper]

    bad = edited_copy(quick_tables["ggx"], tmp_path / "asym.h5", plant)
    assert main(["check", str(bad)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("gonio: check failed: reciprocity:")
    assert "FAIL" in err[0]


def test_check_fails_when_the_table_reflects_more_than_it_receives(
        quick_tables: dict[str, Path], tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    rho = api.check(quick_tables["ggx"]).checks[1].details["rho"].max()
    scale = 1.2 / rho

    def brighter(mean: np.ndarray, terms: dict, count: np.ndarray) -> None:
        mean *= scale
        for v in terms.values():
            v *= scale

    bad = edited_copy(quick_tables["ggx"], tmp_path / "bright.h5", brighter)
    assert main(["check", str(bad), "--json"]) == 1
    out = json.loads(capsys.readouterr().out)
    assert out["passed"] is False and out["checks"]["energy"]["passed"] is False
    assert out["checks"]["reciprocity"]["passed"] is True


def test_the_row_at_the_normal_counts_for_every_azimuth(quick_tables: dict[str, Path]) -> None:
    """At θi = 0 the planner measures one Δφ (the others are the same pose): ρ(0°) must not
    come out ~10× low for it."""
    from acquisition.analysis.checks import directional_albedo

    alb = directional_albedo(api.open_table(quick_tables["ggx"]))
    rho = alb["rho"][:, 1]
    assert rho[0] > 0.9 * rho[1] and alb["covered"][0] > 0.9


def test_compare_takes_a_session_folder_and_export_names_its_table(
        quick_tables: dict[str, Path], capsys: pytest.CaptureFixture[str]) -> None:
    folder = api.compare(quick_tables["ggx-session"], quick_tables["ggx"])
    assert folder.relative["max"]["all"] == 0.0  # the same capture, reduced again
    assert main(["export", str(quick_tables["ggx-session"]), "--format", "csv"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "is a folder: give its table" in err
    assert main(["info", str(quick_tables["ggx"])]) == 0
    assert "gonio-isotropic-brdf v2" in capsys.readouterr().out


def test_a_reader_that_leaves_early_gets_no_error(quick_tables: dict[str, Path]) -> None:
    """`gonio compare … | head -1`: the pipe closes early; gonio stops quietly (141)."""
    import subprocess
    import sys

    proc = subprocess.Popen([sys.executable, "-m", "acquisition.cli", "compare",
                             str(quick_tables["ggx"]), MATERIALS["ggx"][0]],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()  # the reader is gone before gonio writes
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 141 and b"error" not in err, err


def test_directional_albedo_of_a_lambertian_table_is_its_albedo() -> None:
    """ρ = Σ f · projected solid angle: a fully covered Lambertian table gives its albedo."""
    from acquisition.analysis.checks import directional_albedo

    edges = np.linspace(0, 90, 19)
    table = IsotropicTable(edges, edges, np.linspace(0, 180, 19))
    table.track_uncertainty({"noise": ""}, {"white_reference": ""})
    ti, tr, dp = (a.ravel() for a in np.meshgrid(*table.centers(), indexing="ij"))
    f = np.full((ti.size, 3), 0.6 / np.pi)
    table.add(ti, tr, dp, f, variances={"noise": (0.001 * f) ** 2},
              uncertainties={"white_reference": 0.002 * f})
    alb = directional_albedo(table)
    np.testing.assert_allclose(alb["rho"], 0.6, rtol=1e-12)
    np.testing.assert_allclose(alb["covered"], 1.0, rtol=1e-12)
    assert np.all(alb["u"] > 0.002 * 0.6 * 0.99)  # the common term adds linearly


def test_compare_a_capture_with_its_material_and_with_another(
        quick_tables: dict[str, Path], tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    spec = MATERIALS["ggx"][0]
    assert main(["compare", str(quick_tables["ggx"]), spec, "--json"]) == 0
    same = json.loads(capsys.readouterr().out)
    assert same["bins"] == int((IsotropicTable.load_h5(quick_tables["ggx"]).count > 0).sum())
    assert same["relative_error"]["median"]["all"] < 0.005
    assert same["z"]["median_abs"] < 1.5  # within the uncertainty, as a capture should be
    assert same["a"]["kind"] == "table" and same["b"]["kind"] == "material"
    assert main(["compare", str(quick_tables["ggx"]), str(quick_tables["beckmann"])]) == 0
    text = capsys.readouterr().out
    assert "relative error" in text and "worst:" in text
    other = api.compare(quick_tables["ggx"], quick_tables["beckmann"])
    assert other.relative["median"]["all"] > 0.1 and other.z["beyond_3"] > 0.5


def test_compare_reads_merl_files(tmp_path: Path) -> None:
    """A MERL file of a material against the spec: the same BRDF, up to MERL's binning."""
    from acquisition.formats.export import merl_bin_centres
    from acquisition.geometry.halfdiff import vectors_from_halfdiff
    from acquisition.simworld.materials import parse_material

    material = parse_material("lambert:albedo=0.4")
    th, td, pd = merl_bin_centres()
    wi, wo = vectors_from_halfdiff(th, td, pd)
    values = material.eval_vectors(wi, wo)
    values[(wi[..., 2] <= 0) | (wo[..., 2] <= 0)] = -1.0
    path = tmp_path / "lambert.binary"
    write_merl(path, values)
    result = api.compare(path, "lambert:albedo=0.4")
    assert result.a.kind == "merl" and result.relative["max"]["all"] < 1e-6
    with pytest.raises(api.ConfigError, match="neither a file nor a material spec"):
        api.compare(tmp_path / "missing.h5", "lambert:albedo=0.4")
