"""gonio export: isotropic tables (and MERL files) to MERL binary, CSV and EXR slices."""

from __future__ import annotations

import csv
import json
import re
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


# ------------------------------------------------------------------------------ MERL counts
def _merl_centre_angles() -> tuple[np.ndarray, np.ndarray]:
    """θi, θr (degrees) of every MERL bin centre, from scratch: the half vector at θh (φh = 0),
    the difference vector (θd, φd) rotated onto it, the outgoing one its mirror about it."""
    th = np.radians(90.0 * ((np.arange(90) + 0.5) / 90) ** 2)  # θh: square-root spacing
    td = np.radians(np.arange(90) + 0.5)
    pd = np.radians(np.arange(180) + 0.5)
    th, td, pd = np.meshgrid(th, td, pd, indexing="ij")
    dx, dz = np.sin(td) * np.cos(pd), np.cos(td)
    wi_x, wi_z = dx * np.cos(th) + dz * np.sin(th), -dx * np.sin(th) + dz * np.cos(th)
    h_x, h_z = np.sin(th), np.cos(th)
    wo_z = 2 * (wi_x * h_x + wi_z * h_z) * h_z - wi_z
    return np.degrees(np.arccos(np.clip(wi_z, -1, 1))), np.degrees(np.arccos(np.clip(wo_z, -1, 1)))


def _stored_bins_with_a_value(path: Path) -> int:
    """MERL bins of a file holding a value in every channel, read from its bytes."""
    dims = np.fromfile(path, dtype="<i4", count=3)
    assert list(dims) == [90, 90, 180]
    stored = np.fromfile(path, dtype="<f8", offset=12).reshape(3, -1)
    return int((stored >= 0).all(axis=0).sum())


def _export(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    capsys.readouterr()
    assert main(argv) == 0
    return capsys.readouterr().out


def test_merl_export_counts_measured_and_nearest_bin_filled_bins(
        iso_path: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import h5py

    with h5py.File(iso_path, "r") as f:
        measured = int((f["count"][()] > 0).sum())
    assert measured == 12 * 18 * 36  # θi bins centred ≤ 60° × every θr × every Δφ
    # A MERL bin centre is filled when it is above the horizon both ways and either order of
    # (θi, θr) falls in a measured bin (θi < 60°).
    ti, tr = _merl_centre_angles()
    filled = int(((ti < 90) & (tr < 90) & (np.minimum(ti, tr) < 60)).sum())

    text = tmp_path / "text.binary"
    line = _export(["export", str(iso_path), "--format", "merl", "-o", str(text)], capsys).strip()
    numbers = re.fullmatch(rf"{re.escape(str(text))}: ([\d,]+) measured isotropic bins, copied by "
                           r"nearest bin onto ([\d,]+) of ([\d,]+) MERL bins \(.*\)", line)
    assert numbers is not None, line
    got = [int(n.replace(",", "")) for n in numbers.groups()]
    assert got == [measured, filled, 90 * 90 * 180]
    assert _stored_bins_with_a_value(text) == filled

    js = tmp_path / "json.binary"
    report = json.loads(_export(["export", str(iso_path), "--format", "merl", "-o", str(js),
                                 "--json"], capsys))
    assert report == {"path": str(js), "format": "merl", "count": filled,
                      "measured_bins": measured, "filled_bins": filled, "note": ""}
    assert js.read_bytes() == text.read_bytes()


def test_merl_input_counts_its_measured_bins_and_fills_none(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rng = np.random.default_rng(2)
    values = rng.uniform(0, 0.5, (MERL_BINS, 3))
    values[rng.random(MERL_BINS) < 0.25] = np.nan
    src = tmp_path / "src.binary"
    write_merl(src, values.reshape(90, 90, 180, 3))
    measured = _stored_bins_with_a_value(src)
    assert measured == int(np.isfinite(values).all(axis=1).sum())

    out = tmp_path / "out.binary"
    line = _export(["export", str(src), "--format", "merl", "-o", str(out)], capsys).strip()
    assert line == f"{out}: {measured} measured bins"
    report = json.loads(_export(["export", str(src), "--format", "merl", "-o", str(out), "--json"],
                                capsys))
    assert (report["measured_bins"], report["filled_bins"], report["count"]) == (measured, 0, measured)
