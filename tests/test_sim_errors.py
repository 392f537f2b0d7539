"""A misaligned simulated rig: ``[simulation.errors]`` is parsed strictly, and the simulator moves
the arms and renders the camera from the TRUE geometry while the driver reads only ticks."""

from __future__ import annotations

import math
import random
from pathlib import Path

import numpy as np
import pytest
from conftest import EXAMPLES, assert_no_sim_collision

from acquisition import api
from acquisition.config.rig import load_rig
from acquisition.devices.servos import open_servos
from acquisition.planning.planner import Planner
from acquisition.simworld.misalignment import TrueGeometry, disc_offsets
from drivers.errors import ConfigError
from simulators.dynamixel.drivetrain import Drivetrain

MISALIGNED = EXAMPLES / "rig-misaligned-sim.toml"


def edited(src: Path, tmp_path: Path, old: str, new: str) -> Path:
    text = src.read_text()
    assert old in text
    out = tmp_path / src.name
    out.write_text(text.replace(old, new, 1))
    return out


@pytest.mark.parametrize(("old", "new", "match"), [
    ("seed = 1", "seed = 1\nbacklash = 0.2",
     r"\[simulation.errors\] backlash: unknown key \(allowed: backlash_deg"),
    ("camera_phi = 1.0 }", "camera_phi = 1.0, sample_phi = 0.1 }",
     r"\[simulation.errors.zero_offset_deg\] sample_phi: names no axis of this rig"),
    ("[0.4, -0.3]", "[0.4]", r"\[simulation.errors\] sample_tilt_deg: must be \[about_x, about_y\]"),
    ("source_diameter_m = 0.005", "source_diameter_m = 5",
     r"\[simulation.errors\] source_diameter_m: must be ≤ 0.2 m, got 5 m"),
    ("seed = 1", "seed = 1\ncamera_pointing_deg = [0.1, 0.0]",
     r"\[simulation.errors\] camera_pointing_deg: only an image-based rig"),
])
def test_simulation_errors_refused_in_one_line(tmp_path: Path, old: str, new: str,
                                               match: str) -> None:
    with pytest.raises(ConfigError, match=match) as info:
        load_rig(edited(MISALIGNED, tmp_path, old, new))
    assert "\n" not in str(info.value) and str(tmp_path) in str(info.value)


def test_errors_on_a_real_rig_are_refused_naming_the_field(tmp_path: Path) -> None:
    path = edited(MISALIGNED, tmp_path, 'port = "sim"', 'port = "/dev/ttyUSB0"')
    path.write_text(path.read_text().replace("simulated = true", "simulated = false"))
    with pytest.raises(ConfigError, match=r"\[simulation.errors\] zero_offset_deg: a real "
                                          r"\(non-simulated\) rig has no simulated errors") as info:
        load_rig(path)
    assert "\n" not in str(info.value)


def test_the_example_states_its_errors_and_the_instrument_specs_follow() -> None:
    rig = load_rig(MISALIGNED)
    errors = rig.sim_errors
    assert errors is not None and errors.any
    assert max(abs(v) for v in errors.zero_offset_deg.values()) <= 1.0
    assert math.hypot(*errors.sample_tilt_deg) == pytest.approx(0.5)
    assert errors.source_diameter_m == 0.005 and rig.light_source_diameter_m == 0.005
    assert all(a.backlash_deg == 0.2 for a in rig.axes.values())
    assert load_rig(EXAMPLES / "rig-sim.toml").sim_errors is None


def test_backlash_is_a_dead_band_the_shaft_drags_the_arm_through() -> None:
    train = Drivetrain(lambda ticks: ticks, offset_deg=0.5, backlash_deg=0.2)
    train.on_goal(0.0, 10.0)            # moving up: the arm trails by half the play
    assert train.arm_deg(10.0) == pytest.approx(10.0 - 0.1 + 0.5)
    train.on_goal(10.0, 9.95)           # a reversal smaller than the play leaves the arm
    assert train.arm_deg(9.95) == pytest.approx(9.9 + 0.5)
    train.on_goal(9.95, 5.0)            # down: now it trails from above
    assert train.arm_deg(5.0) == pytest.approx(5.1 + 0.5)


def test_position_noise_is_drawn_per_move_and_seeded() -> None:
    def arms(seed: int) -> list[float]:
        train = Drivetrain(lambda t: t, noise_deg=0.02, rng=random.Random(seed))
        out = []
        for goal in (10.0, 20.0, 20.0, 30.0):
            train.on_goal(out[-1] if out else 0.0, goal)
            out.append(train.arm_deg(goal) - goal)
        return out

    a = arms(1)
    assert a == arms(1) and a != arms(2)
    assert a[1] == a[2]  # no move, no new draw
    assert 0 < max(abs(v) for v in a) < 0.1


def test_the_simulated_arms_stand_where_the_errors_put_them() -> None:
    rig = load_rig(MISALIGNED)
    errors = rig.sim_errors
    assert errors is not None
    with open_servos(rig, Planner(rig), seed=2) as servos:
        read = servos.move_to({"light_theta": -30.0, "camera_theta": 40.0, "camera_phi": 10.0})
        true = servos.true_joints()
    for axis, value in read.items():
        offset = errors.zero_offset_deg[axis] - 0.1  # approached from below: b/2 behind
        assert true[axis] - value == pytest.approx(offset, abs=0.08), axis
        assert abs(true[axis] - value - offset) > 1e-6  # position noise: not exactly there


def test_the_true_geometry_tilts_the_sample_and_spreads_the_lamp() -> None:
    rig = load_rig(MISALIGNED)
    truth = TrueGeometry(rig)
    light, camera = truth.directions({"light_theta": 0.0, "camera_theta": 0.0, "camera_phi": 0.0})
    theta = np.degrees(np.arccos(light[2]))
    assert theta == pytest.approx(0.5, abs=1e-4)  # the normal is 0.5° from the arms' zenith
    disc = disc_offsets(0.005, 37)
    assert np.max(np.hypot(*disc.T)) <= 0.0025 and abs(disc.mean(axis=0)).max() < 2e-4


def test_uncalibrated_captures_keep_the_misaligned_arms_apart(tmp_path: Path) -> None:
    """Up to ≈ 1.2° from where the guard believes them, the arms still never touch: the rig
    file's 25 mm clearance covers the uncalibrated errors (the test-wide referee sees every
    contact of the simulated arms), and every move ends approaching from below."""
    result = api.capture(MISALIGNED, EXAMPLES / "plan-quick.toml", tmp_path / "s",
                         material="lambert:albedo=0.5", seed=4)
    assert result.counts["done"] > 100
    assert_no_sim_collision(tmp_path / "s")
