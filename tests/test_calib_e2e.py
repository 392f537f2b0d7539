"""Calibration end to end on the simulated rig with a realistic sensor (PRNU, cos⁴ vignetting,
dark current): ``gonio calibrate`` builds a bundle, captures use it, the reduction applies it."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from conftest import SMALL_PLAN

from acquisition import api
from acquisition.cli import main
from acquisition.reduction.point import reduce_session
from calibration.bundle import CalibrationBundle
from calibration.white import WhiteReference

REALISTIC = """
prnu_sigma = 0.01
vignetting_focal_px = 60.0
dark_current_e_per_s = 30.0
black_noise_dn = 1.0
"""

PLAN = SMALL_PLAN

GREY = 0.18 / math.pi


@pytest.fixture(scope="module")
def calibrated(rig_sim_text: str, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("calibrated")
    rig = root / "rig.toml"
    rig.write_text(rig_sim_text.replace("seed = 7\n", "seed = 7\n" + REALISTIC, 1))
    plan = root / "plan.toml"
    plan.write_text(PLAN)
    bundle = root / "bundle"
    for kind in ("dark", "flat", "noise", "white"):
        assert main(["calibrate", kind, "--rig", str(rig), "--out", str(bundle)]) == 0
    return {"root": root, "rig": rig, "plan": plan, "bundle": bundle}


@pytest.fixture(scope="module")
def rig_sim_text() -> str:
    return (Path(__file__).resolve().parent.parent / "examples" / "rig-sim.toml").read_text()


def test_calibrate_builds_a_bundle_that_matches_the_sensor(calibrated: dict[str, Path]) -> None:
    bundle = CalibrationBundle.open(calibrated["bundle"])
    gain, read = bundle.noise_for(100).per_colour()
    np.testing.assert_allclose(gain, 2.0, rtol=0.04)  # the rig's gain_e_per_dn at ISO 100
    np.testing.assert_allclose(read, math.sqrt(1.5**2 + 1.0**2 + 1 / 12), rtol=0.08)
    flat = bundle.flat
    assert flat.shape == (64, 96) and flat.min() < 0.6 < 1.4 < flat.max()  # cos⁴ vignetting
    assert bundle.dark_for(0.01, 100) is not None
    assert bundle.bad_pixels is not None and not bundle.bad_pixels.any()
    white = WhiteReference.from_dict(bundle.white)
    assert white.theta_i_deg == 0.0 and np.all(white.signal > 0)
    assert bundle.scalars["white"]["with_flat"] is True


def test_grey_lambert_absolute_within_one_percent(calibrated: dict[str, Path]) -> None:
    out = calibrated["root"] / "grey"
    api.capture(calibrated["rig"], calibrated["plan"], out, material="lambert:albedo=0.18",
                seed=1, calibration=calibrated["bundle"])
    reduction = reduce_session(out)  # applies the session's copy of the bundle
    assert reduction.bundle is not None and reduction.bundle.is_relative_to(out)
    table = reduction.table
    measured = table.count > 0
    rel = np.abs(table.mean[measured] / GREY - 1)
    assert measured.sum() >= 8
    assert np.median(rel) <= 0.01
    predicted = reduction.predicted_variance[measured]
    assert np.all(np.isfinite(predicted)) and np.all(predicted > 0)
    assert table.provenance["calibration_bundle"] == str(reduction.bundle.resolve())


def test_rough_ggx_within_three_percent(calibrated: dict[str, Path]) -> None:
    from acquisition.api.truth import relative_errors, truth_table

    out = calibrated["root"] / "rough-ggx"
    api.capture(calibrated["rig"], calibrated["plan"], out,
                material="ggx:albedo=0.2,alpha=0.3,f0=0.04", seed=3,
                calibration=calibrated["bundle"])
    rel = relative_errors(reduce_session(out).table, truth_table(out))
    assert rel.size >= 8
    assert np.median(rel) <= 0.03


def test_predicted_bin_variance_matches_the_scatter_of_repeated_captures(
    calibrated: dict[str, Path],
) -> None:
    means, predicted = [], []
    for seed in range(8):
        out = calibrated["root"] / f"repeat-{seed}"
        api.capture(calibrated["rig"], calibrated["plan"], out, material="lambert:albedo=0.18",
                    seed=100 + seed, calibration=calibrated["bundle"])
        reduction = reduce_session(out)
        measured = reduction.table.count > 0
        means.append(reduction.table.mean[measured])
        predicted.append(reduction.predicted_variance[measured])
    scatter = np.var(means, axis=0, ddof=1)
    ratio = float(scatter.sum() / np.mean(predicted, axis=0).sum())
    assert 0.8 <= ratio <= 1.2


@pytest.mark.parametrize("shape", ["warmup", "linear"])
def test_two_percent_light_drift_is_corrected(
    calibrated: dict[str, Path], rig_sim_text: str, shape: str
) -> None:
    # The simulated lamp drifts by 2 % on the device clock, as the rig file says: a warm-up
    # (1 − exp(−t/τ), τ a quarter of the session) or linear over the session.
    plan = calibrated["root"] / "plan-refs.toml"
    plan.write_text(PLAN + "[capture]\nreference_every = 3\n")
    session_s = api.plan_sweep(plan, calibrated["rig"]).estimated_s
    span = session_s / 4 if shape == "warmup" else session_s
    rig = calibrated["root"] / f"rig-drift-{shape}.toml"
    rig.write_text(calibrated["rig"].read_text().replace(
        "[simulation]\n",
        f'[simulation]\nlight_drift_pct = 2.0\nlight_drift_s = {span}\n'
        f'light_drift_shape = "{shape}"\n', 1))
    out = calibrated["root"] / f"drift-{shape}"
    api.capture(rig, plan, out, material="lambert:albedo=0.18", seed=4,
                calibration=calibrated["bundle"])
    reduction = reduce_session(out)
    assert 1.5 <= reduction.drift_pct <= 2.5
    measured = reduction.table.count > 0
    rel = np.abs(reduction.table.mean[measured] / GREY - 1)
    assert np.median(rel) <= 0.003


def test_light_drift_keys_are_checked(rig_sim_text: str, tmp_path: Path) -> None:
    from acquisition.config.rig import load_rig
    from acquisition.simworld.scene import LightDrift
    from drivers.errors import ConfigError

    rig = tmp_path / "rig.toml"
    rig.write_text(rig_sim_text.replace("[simulation]\n", '[simulation]\nlight_drift_pct = 2\n'
                                        'light_drift_shape = "sine"\n', 1))
    with pytest.raises(ConfigError, match=r"light_drift_shape.*linear, warmup"):
        LightDrift.from_rig(load_rig(rig))
    drift = LightDrift(2.0, 100.0, "linear")
    assert drift.factor(0) == 1.0 and drift.factor(50) == pytest.approx(1.01)
    assert drift.factor(500) == pytest.approx(1.02)
    assert LightDrift(2.0, 100.0, "warmup").factor(100) == pytest.approx(1 + 0.02 * (1 - math.exp(-1)))


def test_master_dark_removes_the_dark_current_bias(
    rig_sim_text: str, calibrated: dict[str, Path]
) -> None:
    # A warm sensor: 3000 e⁻/s of dark current adds ~15 DN at 10 ms, which the stated black
    # level misses; a dark-only bundle fixes it (it has no noise model: the simulated camera's
    # sensor model predicts the variance).
    root = calibrated["root"] / "warm"
    root.mkdir()
    rig = root / "rig.toml"
    rig.write_text(rig_sim_text.replace("seed = 7\n", "seed = 7\ndark_current_e_per_s = 3000.0\n", 1))
    assert main(["calibrate", "dark", "--rig", str(rig), "--out", str(root / "bundle")]) == 0
    api.capture(rig, calibrated["plan"], root / "s", material="lambert:albedo=0.18", seed=2)
    plain = reduce_session(root / "s")
    fixed = reduce_session(root / "s", bundle=root / "bundle")
    assert plain.bundle is None and fixed.bundle is not None
    assert fixed.table.provenance["noise_model"] == "sensor model"
    measured = fixed.table.count > 0
    assert np.all(np.isfinite(fixed.predicted_variance[measured]))

    def median_error(reduction) -> float:
        return float(np.median(np.abs(reduction.table.mean[measured] / GREY - 1)))

    assert median_error(plain) > 0.01
    assert median_error(fixed) <= 0.003


def test_image_based_reduction_applies_the_bundle(tmp_path: Path) -> None:
    # A flat Lambertian coupon seen per pixel through a vignetting lens (cos⁴, PRNU): the white
    # plate calibrates the centre of the frame only, so without the bundle's flat field the
    # off-centre samples read low; with it every pixel is corrected alike.
    from test_image_capture import plan_file, small_rig

    from acquisition.reduction.image import reduce_image_session

    rig = small_rig(tmp_path, "flat")
    rig.write_text(rig.read_text().replace(
        "seed = 7\n", "seed = 7\nprnu_sigma = 0.01\nvignetting_focal_px = 300.0\n", 1))
    bundle = tmp_path / "bundle"
    for kind in ("dark", "flat"):
        assert main(["calibrate", kind, "--rig", str(rig), "--out", str(bundle)]) == 0
    out = tmp_path / "s"
    api.capture(rig, plan_file(tmp_path, [[30, 45, 180], [60, 30, 90]]), out,
                material="lambert:albedo=0.6", seed=5)

    def median_error(reduction) -> float:
        table = reduction.table
        return float(np.median(np.abs(table.mean[table.count > 0] / (0.6 / math.pi) - 1)))

    plain = reduce_image_session(out)
    fixed = reduce_session(out, bundle=bundle)  # dispatches to the image-based reducer
    assert plain.bundle is None and fixed.bundle == bundle
    assert fixed.table.provenance["calibration_bundle"] == str(bundle.resolve())
    assert median_error(plain) > 0.03
    assert median_error(fixed) <= 0.01


def test_reduce_applies_a_bundle_made_after_the_capture(
        calibrated: dict[str, Path], capsys: pytest.CaptureFixture[str]) -> None:
    """A session captured without calibration, reduced with `gonio reduce --calibration`: the
    bundle's flat field and noise model apply (the realistic sensor's vignetting no longer
    biases the grey card, and the budget's noise comes from the bundle)."""
    out = calibrated["root"] / "late"
    api.capture(calibrated["rig"], calibrated["plan"], out, material="lambert:albedo=0.18",
                seed=6)
    table = out / "late.h5"
    assert main(["reduce", str(out), "-o", str(table), "--calibration",
                 str(calibrated["bundle"]), "--json"]) == 0
    import json

    report = json.loads(capsys.readouterr().out)
    assert report["noise_model"] == "calibration bundle"
    loaded = api.open_table(table)
    assert loaded.provenance["calibration_bundle"] == str(calibrated["bundle"].resolve())
    measured = loaded.count > 0
    assert np.median(np.abs(loaded.mean[measured] / GREY - 1)) <= 0.01
    assert np.all(np.isfinite(loaded.std_error[measured]))
