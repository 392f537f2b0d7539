"""Acceptance on the misaligned rig (examples/rig-misaligned-sim.toml): ``gonio calibrate
geometry`` recovers the injected errors, a capture planned and reduced with the calibration is
accurate, one reduced without it is not, and every bin's predicted uncertainty — the angular
terms included — matches its error against the truth."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import EXAMPLES, grid_plan_text
from misaligned import (
    assert_planner_applies,
    assert_recovered,
    calibrate_json,
    capture_both_ways,
    peak_errors,
)

from acquisition.analysis.report import budget_rows
from acquisition.config.rig import load_rig
from acquisition.geometry.kinematics import Pose
from acquisition.session.alignment import alignment_of, bundle_at
from acquisition.simworld.truth import relative_errors
from calibration.bundle import CalibrationBundle

MISALIGNED = EXAMPLES / "rig-misaligned-sim.toml"
PLAN = grid_plan_text((38, 42, 1), (33, 47, 1), (172, 180, 2), name="specular-fine")
"""Around the mirror direction at θi 38–42°: 1° in θi and θr, 2° in Δφ (the lobe is ≈ 8° wide
at half maximum): ≈ 80 peak bins, and neighbours on every side for the local slopes."""


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """``gonio calibrate geometry --json`` on the misaligned rig: its JSON and the bundle."""
    return calibrate_json(MISALIGNED, tmp_path_factory.mktemp("geometry"))


@pytest.fixture(scope="module")
def captured(calibrated: dict) -> dict:
    """The GGX material captured with the calibration, reduced with and without it."""
    return capture_both_ways(MISALIGNED, calibrated, PLAN)


def test_calibrate_geometry_recovers_every_injected_error(calibrated: dict) -> None:
    data, errors = calibrated["json"], load_rig(MISALIGNED).sim_errors
    assert errors is not None
    assert_recovered(data, errors)
    assert data["rank"] == data["parameters"] and data["unobservable"] == []
    assert 0 < data["residual_deg"] < 0.05 and data["condition_number"] < 100
    assert 450 <= data["frames"] <= 530  # docs/formats.md: ≈ 490 frames
    geometry = CalibrationBundle.open(calibrated["bundle"]).geometry
    assert geometry is not None and geometry["provenance"]["rig_name"] == load_rig(MISALIGNED).name
    assert geometry["zero_offset_deg"]["camera_phi"] == data["zero_offset_deg"]["camera_phi"]["value"]


def test_calibrated_capture_is_accurate_and_the_uncalibrated_one_is_not(captured: dict) -> None:
    table, truth = captured[True]
    rel, _ = peak_errors(table, truth)
    median_all = float(np.median(relative_errors(table, truth)))
    raw_table, raw_truth = captured[False]
    raw_rel, _ = peak_errors(raw_table, raw_truth)
    print(f"with the calibration: median {median_all:.2%} over {int((table.count > 0).sum())} "
          f"bins, {np.median(rel):.2%} over {rel.size} peak bins; without: "
          f"{np.median(raw_rel):.2%} over {raw_rel.size} peak bins")
    assert median_all <= 0.015 and np.median(rel) <= 0.05 and rel.size >= 60
    assert np.median(raw_rel) >= 3 * np.median(rel)


def test_predicted_uncertainty_matches_the_error_on_the_peak(captured: dict) -> None:
    table, truth = captured[True]
    _, z = peak_errors(table, truth)
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
    assert_planner_applies(rig, alignment_of(bundle_at(calibrated["bundle"]), rig),
                           [Pose(40, 40, 180), Pose(30, 55, 150), Pose(60, 35, 100)])
