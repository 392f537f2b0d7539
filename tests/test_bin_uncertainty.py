"""Uncertainty in every bin: the reduction's budget (noise, white reference), each bin's mean
read-back angles, format version 2 (version 1 still reads), repeats against the prediction."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest
from conftest import EXAMPLES, SMALL_PLAN

from acquisition import api
from acquisition.session.folder import SessionFolder
from acquisition.tables import IsotropicTable

RIG = EXAMPLES / "rig-sim.toml"
MATERIAL = "ggx:albedo=0.2,alpha=0.3,f0=0.04"


@pytest.fixture(scope="module")
def two_captures(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The suite's small plan captured twice (seeds 1, 2) and reduced."""
    root = tmp_path_factory.mktemp("budget")
    plan = root / "plan.toml"
    plan.write_text(SMALL_PLAN)
    out = {"plan": plan}
    for seed in (1, 2):
        api.capture(RIG, plan, root / f"s{seed}", material=MATERIAL, seed=seed)
        out[f"s{seed}"] = root / f"s{seed}"
        out[f"t{seed}"] = root / f"t{seed}.h5"
        api.reduce(root / f"s{seed}", out[f"t{seed}"])
    return out


def test_every_measured_bin_has_a_finite_budget_single_samples_included(
        two_captures: dict[str, Path]) -> None:
    table = IsotropicTable.load_h5(two_captures["t1"])
    measured = table.count > 0
    assert (table.count[measured] == 1).all()  # single samples: the usual case
    se = table.std_error[measured]
    assert np.all(np.isfinite(se)) and np.all(se > 0)
    assert np.all(np.isnan(table.std_error[~measured]))
    terms = table.uncertainty_terms
    assert set(terms) == {"noise", "white_reference"}
    assert not terms["noise"].correlated and terms["white_reference"].correlated
    total = np.sqrt(terms["noise"].values ** 2 + terms["white_reference"].values ** 2)
    np.testing.assert_allclose(se, total[measured])
    rel = se / table.mean[measured]
    assert 1e-4 < np.median(rel) < 0.01  # the rig-sim sensor: ≈ 0.1 % per ROI mean


def test_mean_angles_are_the_read_back_poses(two_captures: dict[str, Path]) -> None:
    table = IsotropicTable.load_h5(two_captures["t1"])
    folder = SessionFolder(two_captures["s1"])
    kin = folder.rig().kinematics()
    with folder.journal(readonly=True) as journal:
        poses = [r for r in journal.steps() if r.kind == "pose" and r.status == "done"]
    angles = table.mean_angles
    for rec in poses:
        back = kin.forward(rec.joints_read)
        idx = np.unravel_index(int(table.flat_index(rec.theta_i, rec.theta_r, rec.delta_phi)[0]),
                               table.shape)
        expected = (back.theta_i, back.theta_r, float(table.normalise_delta_phi(back.delta_phi)))
        np.testing.assert_allclose(angles[idx], expected, atol=1e-9)
    measured = table.count > 0
    centres = np.stack(np.meshgrid(*table.centers(), indexing="ij"), -1)[measured]
    offsets = np.abs(angles[measured] - centres)[:, :2]
    assert offsets.max() > 0  # read-back poses sit off the bin centres …
    assert offsets.max() < 0.5  # … by less than the motion tolerance


def test_repeated_captures_scatter_as_predicted(two_captures: dict[str, Path]) -> None:
    """Two captures merged: every bin holds two samples whose spread the budget predicts."""
    a = IsotropicTable.load_h5(two_captures["t1"])
    b = IsotropicTable.load_h5(two_captures["t2"])
    both = a.merge(b)
    measured = both.count > 0
    assert (both.count[measured] == 2).all()
    ratio, bins = both.scatter
    assert bins == measured.sum()
    assert 0.6 < ratio < 1.5, ratio  # ≈ 27 bins × 3 channels: a ±15 % estimate
    ta, tb, tm = a.uncertainty_terms, b.uncertainty_terms, both.uncertainty_terms
    # independent noise: √(u_a² + u_b²) / 2; the correlated reference term adds linearly
    np.testing.assert_allclose(tm["noise"].values[measured], np.sqrt(
        ta["noise"].values ** 2 + tb["noise"].values ** 2)[measured] / 2, rtol=1e-9)
    np.testing.assert_allclose(tm["white_reference"].values[measured], (
        ta["white_reference"].values + tb["white_reference"].values)[measured] / 2, rtol=1e-9)
    path = two_captures["t1"].parent / "merged.h5"
    both.save_h5(path)
    again = IsotropicTable.load_h5(path)
    assert again.scatter == pytest.approx((ratio, bins))
    np.testing.assert_array_equal(again.std_error, both.std_error)


def test_version_1_tables_still_read(two_captures: dict[str, Path], tmp_path: Path) -> None:
    v2 = IsotropicTable.load_h5(two_captures["t1"])
    path = tmp_path / "v1.h5"
    with h5py.File(path, "w") as f:
        for name in ("theta_i_edges", "theta_r_edges", "delta_phi_edges"):
            f[name] = getattr(v2, name)
        f["mean"], f["variance"], f["count"] = v2.mean, v2.variance, v2.count
        f.attrs.update({"units": "1/sr", "quantity": "brdf", "channels": "R,G,B",
                        "format": "gonio-isotropic-brdf", "version": 1, "provenance": "{}"})
    v1 = IsotropicTable.load_h5(path)
    np.testing.assert_array_equal(v1.mean, v2.mean)
    assert not v1.tracks_uncertainty and np.all(np.isnan(v1.std_error))
    measured = v1.count > 0
    centres = np.stack(np.meshgrid(*v1.centers(), indexing="ij"), -1)
    np.testing.assert_array_equal(v1.mean_angles[measured], centres[measured])


def test_a_table_that_tracks_uncertainty_refuses_samples_without_it() -> None:
    from drivers.errors import ConfigError

    table = IsotropicTable([0, 45, 90], [0, 45, 90], [0, 180])
    table.track_uncertainty({"noise": ""}, {})
    with pytest.raises(ConfigError, match="needs variances= and uncertainties="):
        table.add(10.0, 20.0, 30.0, np.ones((1, 3)))
    table.add(10.0, 20.0, 30.0, np.ones((1, 3)), variances={"noise": np.full((1, 3), 4e-4)},
              uncertainties={})
    assert table.std_error[0, 0, 0] == pytest.approx(0.02)


def test_terms_a_bins_samples_share_are_set_per_bin_and_survive_the_file(tmp_path: Path) -> None:
    """A term known per bin (an image's frame shares its error over its pixels) is the bin
    mean's standard uncertainty as given; it adds to std_error in quadrature, is no part of the
    samples' predicted scatter, and a per-bin correction scales the bin's values."""
    table = IsotropicTable([0, 45, 90], [0, 45, 90], [0, 180])
    table.track_uncertainty({"noise": ""}, {})
    values = np.array([[1.0, 2.0, 3.0], [1.2, 2.2, 3.2]])
    table.add(10.0, 20.0, 30.0, values, variances={"noise": np.full((2, 3), 0.01)},
              uncertainties={})
    scatter = table.scatter
    shared = np.zeros(table.shape + (3,))
    shared[0, 0, 0] = [0.3, 0.4, 0.5]
    table.set_bin_term("angular", "shared", shared)
    table.set_bin_term("geometry_calibration", "common", shared / 2, correlated=True)
    terms = table.uncertainty_terms
    assert not terms["angular"].correlated and terms["geometry_calibration"].correlated
    np.testing.assert_allclose(terms["angular"].values[0, 0, 0], [0.3, 0.4, 0.5])
    noise = np.sqrt(0.02) / 2
    np.testing.assert_allclose(table.std_error[0, 0, 0],
                               np.sqrt(noise**2 + 1.25 * np.array([0.3, 0.4, 0.5]) ** 2))
    assert table.scatter == scatter  # the angular term predicts no scatter between samples
    table.scale_bins(np.full(table.shape + (3,), 0.5))
    np.testing.assert_allclose(table.mean[0, 0, 0], values.mean(axis=0) / 2)
    np.testing.assert_allclose(table.variance[0, 0, 0], values.var(axis=0, ddof=1) / 4)
    table.save_h5(tmp_path / "t.h5")
    back = IsotropicTable.load_h5(tmp_path / "t.h5")
    np.testing.assert_allclose(back.std_error[0, 0, 0], table.std_error[0, 0, 0])
    assert back.uncertainty_terms["geometry_calibration"].correlated


@pytest.mark.parametrize(("ratio", "hint"), [(1.04, False), (360.5, True)])
def test_a_scatter_far_above_noise_is_explained(ratio: float, hint: bool) -> None:
    """The reduce line's repeats ratio: near 1 it stands alone; far above, it says why (a
    dense plan's bins hold samples at different angles), lest an operator suspect the rig."""
    from types import SimpleNamespace

    from acquisition.cli.capture import SCATTER_HINT, _reduce_report

    table = SimpleNamespace(count=np.array([3, 0]), tracks_uncertainty=True,
                            std_error=np.full((2, 3), 0.01), mean=np.ones((2, 3)),
                            provenance={"noise_model": "sensor model"}, scatter=(ratio, 261))
    result = SimpleNamespace(table=table, frames=4, drift_pct=0.1, references=2)
    _, lines = _reduce_report(Path("t.h5"), result)  # type: ignore[arg-type]
    assert f"repeats scatter {ratio:.2f}× the noise prediction over 261 bins" in lines[-1]
    assert (SCATTER_HINT in lines[-1]) == hint


@pytest.mark.parametrize(("references", "said"), [(1, "drift not measured (one reference frame)"),
                                                  (3, "drift 0.10 %")])
def test_drift_is_not_claimed_from_one_reference(references: int, said: str) -> None:
    """One white-reference frame has no drift to show: the reduce line says so, not 0.00 %."""
    from types import SimpleNamespace

    from acquisition.cli.capture import _reduce_report

    table = SimpleNamespace(count=np.array([3, 0]), tracks_uncertainty=False,
                            provenance={}, scatter=(1.0, 0))
    result = SimpleNamespace(table=table, frames=4, drift_pct=0.1 if references > 1 else 0.0,
                             references=references)
    _, lines = _reduce_report(Path("t.h5"), result)  # type: ignore[arg-type]
    assert said in lines[0]
