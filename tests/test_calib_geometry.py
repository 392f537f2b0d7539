"""Acceptance on the misaligned rig (examples/rig-misaligned-sim.toml): ``gonio calibrate
geometry`` recovers the injected errors, a capture planned and reduced with the calibration is
accurate, one reduced without it is not, and every bin's predicted uncertainty — the angular
terms included — matches its error against the truth."""

from __future__ import annotations

import contextlib
import io
import json

import numpy as np
import pytest
from conftest import EXAMPLES, grid_plan_text

from acquisition import api
from acquisition.analysis.report import budget_rows
from acquisition.api.truth import relative_errors, truth_table
from acquisition.cli import main
from acquisition.config.rig import load_rig
from acquisition.geometry.kinematics import Pose, pose_from_directions
from acquisition.planning.planner import Planner
from acquisition.reduction.point import reduce_session
from acquisition.session.alignment import alignment_of, bundle_at
from acquisition.simworld.misalignment import TrueGeometry
from acquisition.tables import IsotropicTable
from calibration.bundle import CalibrationBundle

MISALIGNED = EXAMPLES / "rig-misaligned-sim.toml"
MATERIAL = "ggx:albedo=0.1,alpha=0.06,f0=0.5"
PLAN = grid_plan_text((38, 42, 1), (33, 47, 1), (172, 180, 2), name="specular-fine")
"""Around the mirror direction at θi 38–42°: 1° in θi and θr, 2° in Δφ (the lobe is ≈ 8° wide
at half maximum): ≈ 80 peak bins, and neighbours on every side for the local slopes."""


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """``gonio calibrate geometry --json`` on the misaligned rig: its JSON and the bundle."""
    root = tmp_path_factory.mktemp("geometry")
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = main(["calibrate", "geometry", "--rig", str(MISALIGNED), "--out",
                     str(root / "cal"), "--json", "--seed", "3"])
    assert code == 0
    return {"root": root, "bundle": root / "cal", "json": json.loads(out.getvalue())}


@pytest.fixture(scope="module")
def captured(calibrated: dict) -> dict:
    """The GGX material captured with the calibration, reduced with and without it."""
    root = calibrated["root"]
    plan = root / "plan.toml"
    plan.write_text(PLAN)
    api.capture(MISALIGNED, plan, root / "s", material=MATERIAL, seed=5,
                calibration=calibrated["bundle"])
    out = {}
    for geometry in (True, False):
        table = reduce_session(root / "s", geometry=geometry).table
        out[geometry] = (table, truth_table(root / "s", geometry=geometry))
    return out


def test_calibrate_geometry_recovers_every_injected_error(calibrated: dict) -> None:
    data, errors = calibrated["json"], load_rig(MISALIGNED).sim_errors
    assert errors is not None
    found = {**{a: v for a, v in data["zero_offset_deg"].items()},
             "about_x": data["sample_tilt_deg"]["about_x"],
             "about_y": data["sample_tilt_deg"]["about_y"]}
    injected = {**errors.zero_offset_deg, "about_x": errors.sample_tilt_deg[0],
                "about_y": errors.sample_tilt_deg[1]}
    assert set(found) == set(injected)
    for name, truth in injected.items():
        value, sigma = found[name]["value"], found[name]["sigma"]
        print(f"{name}: {value:+.4f}° ± {sigma:.4f}° (injected {truth:+.4f}°, "
              f"error {value - truth:+.4f}°)")
        assert abs(value - truth) <= 0.05 and abs(value - truth) <= 2 * sigma, name
    for axis, v in data["backlash_deg"].items():  # measured from both approach directions
        assert abs(v["value"] - errors.backlash_deg[axis]) <= 3 * v["sigma"] + 0.01, axis
    assert data["rank"] == data["parameters"] and data["unobservable"] == []
    assert 0 < data["residual_deg"] < 0.05 and data["condition_number"] < 100
    assert 450 <= data["frames"] <= 530  # docs/formats.md: ≈ 490 frames
    geometry = CalibrationBundle.open(calibrated["bundle"]).geometry
    assert geometry is not None and geometry["provenance"]["rig_name"] == load_rig(MISALIGNED).name
    assert geometry["zero_offset_deg"]["camera_phi"] == data["zero_offset_deg"]["camera_phi"]["value"]


def _peak_errors(table: IsotropicTable, truth: IsotropicTable) -> tuple[np.ndarray, np.ndarray]:
    """Relative errors and error / std_error (green) over the peak bins: truth ≥ half max."""
    green = truth.mean[..., 1]
    peak = (table.count > 0) & (truth.count > 0) & (green >= 0.5 * np.nanmax(green))
    rel = np.mean(np.abs(table.mean - truth.mean) / truth.mean, axis=-1)[peak]
    z = ((table.mean - truth.mean) / table.std_error)[..., 1][peak]
    return rel, z


def test_calibrated_capture_is_accurate_and_the_uncalibrated_one_is_not(captured: dict) -> None:
    table, truth = captured[True]
    rel, _ = _peak_errors(table, truth)
    median_all = float(np.median(relative_errors(table, truth)))
    raw_table, raw_truth = captured[False]
    raw_rel, _ = _peak_errors(raw_table, raw_truth)
    print(f"with the calibration: median {median_all:.2%} over {int((table.count > 0).sum())} "
          f"bins, {np.median(rel):.2%} over {rel.size} peak bins; without: "
          f"{np.median(raw_rel):.2%} over {raw_rel.size} peak bins")
    assert median_all <= 0.015 and np.median(rel) <= 0.05 and rel.size >= 60
    assert np.median(raw_rel) >= 3 * np.median(rel)


def test_predicted_uncertainty_matches_the_error_on_the_peak(captured: dict) -> None:
    table, truth = captured[True]
    _, z = _peak_errors(table, truth)
    print(f"error / std_error over {z.size} peak bins: std {np.std(z):.3f}, mean {np.mean(z):+.3f}")
    assert 0.7 <= float(np.std(z)) <= 1.3
    terms = table.uncertainty_terms
    assert {"angular", "source_size", "geometry_calibration"} <= set(terms)
    assert terms["geometry_calibration"].correlated and not terms["angular"].correlated
    rows = {r[0]: r for r in budget_rows(table)}
    assert rows["angular"][1] == "independent" and rows["geometry_calibration"][1] == "correlated"
    assert float(rows["angular"][2].rstrip(" %")) > float(rows["noise"][2].rstrip(" %"))
    assert table.provenance["geometry_calibration"]["zero_offset_deg"]


def test_the_planner_applies_the_calibration(calibrated: dict) -> None:
    """With the measured calibration the planner's joints realise the requested pose on the
    true rig (the simulated world's own geometry) to a few hundredths of a degree; the rig
    file's model misses it by about a degree."""
    rig = load_rig(MISALIGNED)
    errors = rig.sim_errors
    assert errors is not None
    alignment = alignment_of(bundle_at(calibrated["bundle"]), rig)
    truth = TrueGeometry(rig)

    def realised(planner: Planner, pose: Pose) -> np.ndarray:
        joints = planner.joints_for(pose)  # approached from below: b/2 behind
        true = {a: v + errors.zero_offset_deg[a] - errors.backlash_deg[a] / 2
                for a, v in joints.items()}
        return np.array(pose_from_directions(*truth.directions(true)).as_tuple())

    for pose in (Pose(40, 40, 180), Pose(30, 55, 150), Pose(60, 35, 100)):
        want = np.array(pose.as_tuple())
        calibrated_miss = np.abs(realised(Planner(rig, alignment=alignment), pose) - want)
        nominal_miss = np.abs(realised(Planner(rig), pose) - want)
        assert calibrated_miss[:2].max() < 0.04 and nominal_miss[:2].max() > 0.5, pose
