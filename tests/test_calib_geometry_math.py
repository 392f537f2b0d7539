"""The geometric calibration's mathematics: peak location, least squares that names what it
cannot determine, and the mirror model's blind spots (out-of-plane: a light offset of 2ε with a
tilt of ε; coaxial: the arms' offsets with the tilt at one stage rotation, and the difference of
the arms' offsets at any), which the stage rotation and the white fall-off remove."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from conftest import EXAMPLES

from acquisition.calibrate import mirror_model as mm
from acquisition.config.rig import load_rig
from acquisition.geometry.alignment import TILT_PARAMS
from calibration.lsq import solve
from calibration.peaks import fit_peak
from drivers.errors import CalibrationError


def test_fit_peak_finds_the_vertex_and_its_width() -> None:
    x = np.linspace(9.0, 11.0, 21)
    s = 100.0 * np.exp(-((x - 10.123) ** 2) / (2 * 0.4**2))
    peak = fit_peak(x, s, 1e-4)
    assert peak.centre_deg == pytest.approx(10.123, abs=1e-3)
    assert peak.width_deg == pytest.approx(0.4, rel=0.02)
    with pytest.raises(CalibrationError, match="largest at the scan's end"):
        fit_peak(x, np.exp(x), what="scan")


def test_least_squares_names_the_combination_it_cannot_see() -> None:
    def residual(p: np.ndarray) -> np.ndarray:  # only a − 2b is measured
        return np.array([(p[0] - 2 * p[1]) - 1.0, (p[0] - 2 * p[1]) - 1.004, p[2] - 3.0]) / 0.01

    fit = solve(residual, [0.0, 0.0, 0.0], ("a", "b", "c"), (1.0, 1.0, 1.0))
    assert fit.rank == 2 and fit.unobservable == ("a + 0.5·b",)
    assert math.isinf(fit.sigma("a")) and math.isinf(fit.sigma("b"))
    assert fit.values[2] == pytest.approx(3.0) and fit.sigma("c") == pytest.approx(0.01)
    assert fit.values[0] - 2 * fit.values[1] == pytest.approx(1.002)
    few = solve(lambda p: np.array([(p[0] + p[1] - 1.0) / 0.01]), [0.0, 0.0, 0.0],
                ("a", "b", "c"), (1.0, 1.0, 1.0))  # fewer data than parameters
    assert few.rank == 1 and len(few.unobservable) == 2
    assert all(math.isinf(few.sigma(n)) for n in ("a", "b", "c"))


def test_mirror_peaks_alone_cannot_tell_a_light_offset_from_a_tilt() -> None:
    """On the out-of-plane rig, a light-arm offset of 2ε with a tilt of ε about y moves no
    mirror peak: without the white fall-off the fit says so."""
    model = mm.MirrorModel(load_rig(EXAMPLES / "rig-misaligned-sim.toml").kinematics())
    zero = dict.fromkeys(model.names, 0.0)
    eps = 0.3
    moved = {**zero, "light_theta": 2 * eps, "tilt_about_y": eps}
    joints = {"light_theta": -30.0, "camera_theta": 30.0, "camera_phi": 0.0}
    for axis in ("camera_theta", "camera_phi"):
        obs = mm.PeakObservation(joints, axis, {}, 0.01)
        assert model.predict_peak(moved, obs) == pytest.approx(model.predict_peak(zero, obs),
                                                               abs=2e-4)
    peaks = [mm.PeakObservation({"light_theta": lt, "camera_theta": abs(lt),
                                 "camera_phi": 0.0 if lt < 0 else 178.0}, axis,
                                dict.fromkeys(model.axes, s), 0.01)
             for lt in (-30.0, -60.0, 30.0) for axis in ("camera_theta", "camera_phi")
             for s in (1, -1) if not (lt > 0 and axis == "camera_phi")]
    peaks = [mm.PeakObservation({**o.joints, o.axis: model.predict_peak(moved, o)}, o.axis,
                                o.approach, o.sigma_deg) for o in peaks]
    fit = solve(lambda x: model.residuals(x, peaks, []), np.zeros(len(model.names)),
                model.names, model.scales)
    named = " ".join(fit.unobservable)
    assert "light_theta" in named and "tilt_about_y" in named
    assert math.isinf(fit.sigma("light_theta")) and math.isinf(fit.sigma("tilt_about_y"))


COAXIAL_TRUTH = {"light_azimuth": 0.7, "camera_azimuth": -0.9, "stage_tilt": 0.6,
                 "tilt_about_x": 0.3, "tilt_about_y": -0.4, "backlash:light_azimuth": 0.2,
                 "backlash:camera_azimuth": 0.2, "backlash:stage_tilt": 0.2,
                 mm.AMPLITUDE: 5.0}


def _coaxial_observations(model: mm.MirrorModel, rotations: tuple[float, ...],
                          white: bool) -> tuple[list, list]:
    """The coaxial procedure's observations (acquisition.calibrate.coaxial), exact under
    :data:`COAXIAL_TRUTH`."""
    peaks, whites = [], []
    for psi in rotations:
        for s in (1, -1):
            approach = {**dict.fromkeys(model.axes, s), "stage_rotation": 1}
            joints = {"light_azimuth": -30.0, "camera_azimuth": 31.0, "stage_tilt": -0.4,
                      "stage_rotation": psi}
            for axis in ("stage_tilt", "camera_azimuth"):
                obs = mm.PeakObservation(joints, axis, approach, 0.01)
                peaks.append(mm.PeakObservation(
                    {**joints, axis: model.predict_peak(COAXIAL_TRUTH, obs)}, axis, approach,
                    0.01))
    for s in (1, -1) if white else ():
        approach = {**dict.fromkeys(model.axes, s), "stage_rotation": 1}
        for light in (-50.0, 50.0, -74.0, 74.0):
            w = mm.WhiteObservation({"light_azimuth": light, "camera_azimuth": 0.0,
                                     "stage_tilt": 0.0, "stage_rotation": 0.0}, approach, 0.0,
                                    0.001)
            whites.append(replace(w, log_signal=float(
                model.predict_log_whites(COAXIAL_TRUTH, [w])[0])))
    return peaks, whites


def test_coaxial_mirror_peaks_see_only_the_sum_of_the_arms_and_the_tilt_with_the_stage() -> None:
    """On the coaxial rig, a common offset ε of both arm azimuths with a tilt of ε about the
    stage's x, or a stage-tilt offset ε with a tilt of −ε about its y, moves no mirror peak at
    stage rotation 0, and the light turned by +ε with the camera by −ε moves none at any."""
    model = mm.MirrorModel(load_rig(EXAMPLES / "rig-coaxial-misaligned-sim.toml").kinematics())
    eps = 0.3
    zero = dict.fromkeys(model.names, 0.0)
    blind = (({"light_azimuth": eps, "camera_azimuth": eps, "tilt_about_x": eps}, 0.0),
             ({"stage_tilt": eps, "tilt_about_y": -eps}, 0.0),
             ({"light_azimuth": eps, "camera_azimuth": -eps}, 0.0),
             ({"light_azimuth": eps, "camera_azimuth": -eps}, 85.0))
    for moved, psi in blind:
        joints = {"light_azimuth": -30.0, "camera_azimuth": 30.0, "stage_tilt": 0.0,
                  "stage_rotation": psi}
        for axis in ("stage_tilt", "camera_azimuth"):
            obs = mm.PeakObservation(joints, axis, {}, 0.01)
            assert model.predict_peak({**zero, **moved}, obs) == pytest.approx(
                model.predict_peak(zero, obs), abs=2e-4), (moved, axis)
    one, _ = _coaxial_observations(model, (0.0,), white=False)
    fit = solve(lambda x: model.residuals(x, one, []), model.start([]), model.names,
                model.scales)
    assert fit.rank == 4  # stage_tilt + tilt_about_y, the arms' sum − 2·tilt_about_x, 2 backlashes
    assert all(math.isinf(fit.sigma(n)) for n in model.axes + TILT_PARAMS)
    three, _ = _coaxial_observations(model, (0.0, 85.0, -85.0), white=False)
    fit = solve(lambda x: model.residuals(x, three, []), model.start([]), model.names,
                model.scales)
    assert fit.rank == len(model.names) - 3  # the arms' difference, their backlashes', amplitude
    named = " ".join(fit.unobservable)
    assert "light_azimuth" in named and "camera_azimuth" in named
    assert math.isinf(fit.sigma("light_azimuth")) and math.isinf(fit.sigma("camera_azimuth"))
    assert all(fit.sigma(n) < 0.01 for n in ("stage_tilt", *TILT_PARAMS))


def test_coaxial_peaks_at_three_rotations_and_the_white_fall_off_determine_everything() -> None:
    model = mm.MirrorModel(load_rig(EXAMPLES / "rig-coaxial-misaligned-sim.toml").kinematics())
    peaks, whites = _coaxial_observations(model, (0.0, 85.0, -85.0), white=True)
    fit = solve(lambda x: model.residuals(x, peaks, whites), model.start(whites), model.names,
                model.scales)
    assert fit.rank == len(model.names) and fit.unobservable == ()
    assert fit.values == pytest.approx([COAXIAL_TRUTH[n] for n in model.names], abs=1e-5)
    assert fit.condition < 100
