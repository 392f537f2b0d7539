"""gonio export: isotropic tables (and MERL files) to MERL binary, CSV and EXR slices."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

from acquisition.cli import main
from acquisition.formats.merl import MERL_FILE_BYTES, read_merl, write_merl
from acquisition.geometry.halfdiff import MERL_BINS
from acquisition.tables import IsotropicTable
from drivers.errors import ConfigError


def _f(theta_i: np.ndarray, theta_r: np.ndarray) -> np.ndarray:
    """A smooth, reciprocal test BRDF, (…, 3) sr⁻¹."""
    base = 0.1 + 0.001 * (np.asarray(theta_i) + np.asarray(theta_r))
    return np.stack([base, 1.5 * base, 2.0 * base], axis=-1)


@pytest.fixture(scope="module")
def iso_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 5°-binned isotropic table measured for θi ≤ 60°, with two samples per bin."""
    ti_e = np.arange(0, 91, 5.0)
    tr_e = np.arange(0, 91, 5.0)
    dp_e = np.arange(0, 181, 5.0)
    t = IsotropicTable(ti_e, tr_e, dp_e, provenance={"material": "test", "seed": 3})
    ci, cr, cp = np.meshgrid(*t.centers(), indexing="ij")
    keep = ci <= 60
    for jitter in (-0.01, 0.01):
        t.add(ci[keep], cr[keep], cp[keep], _f(ci[keep], cr[keep]) * (1 + jitter))
    path = tmp_path_factory.mktemp("tables") / "brdf.h5"
    t.save_h5(path)
    return path


def test_merl_export_matches_table_at_random_directions(iso_path: Path, tmp_path: Path) -> None:
    out = tmp_path / "brdf.binary"
    assert main(["export", str(iso_path), "--format", "merl", "-o", str(out)]) == 0
    assert out.stat().st_size == MERL_FILE_BYTES
    merl = read_merl(out)
    rng = np.random.default_rng(0)
    ti = rng.uniform(2, 55, 2000)
    tr = rng.uniform(2, 55, 2000)
    dp = rng.uniform(-180, 180, 2000)
    got = merl(ti, tr, dp)
    measured = (got >= 0).all(axis=1)
    assert measured.mean() > 0.97
    # Nearest-bin resampling: the lookup's angles differ from the bin's by a bin or so.
    np.testing.assert_allclose(got[measured], _f(ti[measured], tr[measured]), rtol=0.08)
    # Where neither order was measured (θi, θr > 60°), the MERL file says unmeasured.
    far = merl(rng.uniform(70, 88, 500), rng.uniform(70, 88, 500), rng.uniform(-180, 180, 500))
    assert (far < 0).any(axis=1).mean() > 0.95


def test_merl_input_exports_byte_for_byte(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    values = rng.uniform(0, 0.5, (MERL_BINS, 3))
    values[rng.random(MERL_BINS) < 0.3] = np.nan
    src = tmp_path / "src.binary"
    write_merl(src, values.reshape(90, 90, 180, 3))
    out = tmp_path / "copy.binary"
    assert main(["export", str(src), "--format", "merl", "-o", str(out)]) == 0
    assert out.read_bytes() == src.read_bytes()


def test_csv_has_one_row_per_measured_bin(iso_path: Path, tmp_path: Path) -> None:
    out = tmp_path / "brdf.csv"
    assert main(["export", str(iso_path), "--format", "csv", "-o", str(out)]) == 0
    table = IsotropicTable.load_h5(iso_path)
    with open(out, newline="") as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["theta_i_deg", "theta_r_deg", "delta_phi_deg", "R_per_sr", "G_per_sr",
                       "B_per_sr", "var_R", "var_G", "var_B", "count"]
    data = np.array(rows[1:], float)
    assert data.shape[0] == int((table.count > 0).sum())
    assert np.all(data[:, 9] == 2)
    np.testing.assert_allclose(data[:, 3:6], _f(data[:, 0], data[:, 1]), rtol=1e-8)
    idx = table.flat_index(data[:, 0], data[:, 1], data[:, 2])
    np.testing.assert_allclose(data[:, 6:9], table.variance.reshape(-1, 3)[idx], rtol=1e-8)


def test_exr_slices_carry_values_units_and_provenance(iso_path: Path, tmp_path: Path) -> None:
    out = tmp_path / "exr"
    assert main(["export", str(iso_path), "--format", "exr", "-o", str(out)]) == 0
    table = IsotropicTable.load_h5(iso_path)
    files = sorted(out.glob("*.exr"))
    assert len(files) == table.shape[0]
    k = 7
    inp = oiio.ImageInput.open(str(files[k]))
    assert inp is not None
    spec = inp.spec()
    pixels = inp.read_image("float")
    inp.close()
    assert spec.format == oiio.TypeDesc("float") and spec.channelnames == ("R", "G", "B", "count")
    assert (spec.height, spec.width) == table.shape[1:]
    assert spec.getattribute("gonio:units") == "1/sr"
    assert spec.getattribute("gonio:theta_i_deg") == pytest.approx(table.centers()[0][k])
    assert json.loads(spec.getattribute("gonio:provenance")) == {"material": "test", "seed": 3}
    np.testing.assert_array_equal(spec.getattribute("gonio:delta_phi_edges_deg"),
                                  table.delta_phi_edges)
    np.testing.assert_array_equal(pixels[..., :3], table.mean[k].astype(np.float32))
    np.testing.assert_array_equal(pixels[..., 3], table.count[k])


def test_bad_inputs_are_one_line_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["export", str(tmp_path / "none.h5"), "--format", "csv"]) != 0
    err = capsys.readouterr().err
    assert "does not exist" in err and err.count("\n") == 1
    from acquisition.formats.export import export_table

    with pytest.raises(ConfigError, match="unknown export format"):
        export_table(tmp_path / "none.h5", "png", None)
