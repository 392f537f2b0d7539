"""Acceptance on the misaligned coaxial rig (examples/rig-coaxial-misaligned-sim.toml): ``gonio
calibrate geometry`` recovers the zero offsets of both arm azimuths and of the stage tilt and
the sample's tilt on the rotation stage, names the stage rotation's zero as not measured, and a
GGX capture planned and reduced with the calibration is accurate where the same capture reduced
without it is not; a rig whose arms do not move is refused in one line."""

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

from acquisition.cli import main
from acquisition.config.rig import load_rig
from acquisition.geometry.kinematics import Pose
from acquisition.session.alignment import alignment_of, bundle_at
from acquisition.simworld.truth import relative_errors
from calibration.bundle import CalibrationBundle

COAXIAL = EXAMPLES / "rig-coaxial-misaligned-sim.toml"
PLAN = grid_plan_text((38, 42, 1), (34, 46, 1), (174, 180, 3), name="specular-coaxial")
"""Around the mirror direction at θi 38–42°: 1° in θi and θr, 3° in Δφ: ≈ 195 poses, ≈ 55
peak bins (truth ≥ half its maximum)."""


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """``gonio calibrate geometry --json`` on the misaligned coaxial rig."""
    return calibrate_json(COAXIAL, tmp_path_factory.mktemp("coaxial"))


@pytest.fixture(scope="module")
def captured(calibrated: dict) -> dict:
    """The GGX material captured with the calibration, reduced with and without it."""
    return capture_both_ways(COAXIAL, calibrated, PLAN)


def test_calibrate_geometry_recovers_every_injected_error_on_the_coaxial_rig(
        calibrated: dict) -> None:
    data, rig = calibrated["json"], load_rig(COAXIAL)
    assert rig.sim_errors is not None
    assert set(data["zero_offset_deg"]) == {"light_azimuth", "camera_azimuth", "stage_tilt"}
    assert_recovered(data, rig.sim_errors)
    assert data["rank"] == data["parameters"] == 9 and data["unobservable"] == []
    assert len(data["not_measured"]) == 1 and "stage_rotation" in data["not_measured"][0]
    assert 0 < data["residual_deg"] < 0.05 and data["condition_number"] < 100
    assert 320 <= data["frames"] <= 400  # docs/formats.md: ≈ 350 frames
    geometry = CalibrationBundle.open(calibrated["bundle"]).geometry
    assert geometry is not None and geometry["provenance"]["rig_name"] == rig.name
    assert "stage rotations" in geometry["provenance"]["procedure"]


def test_calibrated_coaxial_capture_is_accurate_and_the_uncalibrated_one_is_not(
        captured: dict) -> None:
    table, truth = captured[True]
    rel, z = peak_errors(table, truth)
    median_all = float(np.median(relative_errors(table, truth)))
    raw_rel, _ = peak_errors(*captured[False])
    print(f"with the calibration: median {median_all:.2%} over {int((table.count > 0).sum())} "
          f"bins, {np.median(rel):.2%} over {rel.size} peak bins (error / std_error: std "
          f"{np.std(z):.2f}); without: {np.median(raw_rel):.2%} over {raw_rel.size} peak bins")
    assert median_all <= 0.015 and np.median(rel) <= 0.05 and rel.size >= 40
    assert np.median(raw_rel) >= 3 * np.median(rel)


def test_the_planner_applies_the_coaxial_calibration(calibrated: dict) -> None:
    """The measured offsets and tilt turn the arms and the stage where the true rig realises
    the pose (in and out of the arms' plane: Δφ ≠ 180° tilts the stage)."""
    rig = load_rig(COAXIAL)
    assert_planner_applies(rig, alignment_of(bundle_at(calibrated["bundle"]), rig),
                           [Pose(40, 40, 180), Pose(30, 55, 150), Pose(60, 35, 100)])


def test_a_rig_whose_arms_do_not_move_is_refused_in_one_line(
        tmp_path, capsys: pytest.CaptureFixture[str]) -> None:
    rig = EXAMPLES / "rig-lightstage-sim.toml"
    code = main(["calibrate", "geometry", "--rig", str(rig), "--out", str(tmp_path / "cal")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0 and len(err) == 1
    assert "out-of-plane-arcs and coaxial-arms" in err[0] and "light-stage" in err[0]
    assert not (tmp_path / "cal").exists()
