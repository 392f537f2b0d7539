"""The geometric calibration's mathematics: peak location, least squares that names what it
cannot determine, and the mirror model's blind spot (a light offset of 2ε with a tilt of ε)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from acquisition.calibrate import mirror_model as mm
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


def test_mirror_peaks_alone_cannot_tell_a_light_offset_from_a_tilt() -> None:
    """On the out-of-plane rig, a light-arm offset of 2ε with a tilt of ε about y moves no
    mirror peak: without the white fall-off the fit says so."""
    zero = dict.fromkeys(mm.NAMES, 0.0)
    eps = 0.3
    moved = {**zero, "light_theta": 2 * eps, "tilt_about_y": eps}
    joints = {"light_theta": -30.0, "camera_theta": 30.0, "camera_phi": 0.0}
    for axis in ("camera_theta", "camera_phi"):
        obs = mm.PeakObservation(joints, axis, {}, 0.01)
        assert mm.predict_peak(moved, obs) == pytest.approx(mm.predict_peak(zero, obs), abs=2e-4)
    peaks = [mm.PeakObservation({"light_theta": lt, "camera_theta": abs(lt),
                                 "camera_phi": 0.0 if lt < 0 else 178.0}, axis,
                                {a: s for a in mm.AXES}, 0.01)
             for lt in (-30.0, -60.0, 30.0) for axis in ("camera_theta", "camera_phi")
             for s in (1, -1) if not (lt > 0 and axis == "camera_phi")]
    peaks = [mm.PeakObservation({**o.joints, o.axis: mm.predict_peak(moved, o)}, o.axis,
                                o.approach, o.sigma_deg) for o in peaks]
    fit = solve(lambda x: mm.residuals(x, peaks, []), np.zeros(len(mm.NAMES)), mm.NAMES,
                mm.SCALES)
    named = " ".join(fit.unobservable)
    assert "light_theta" in named and "tilt_about_y" in named
    assert math.isinf(fit.sigma("light_theta")) and math.isinf(fit.sigma("tilt_about_y"))
