"""Every refusal of the motion guard is one line naming the axes, where the arms would meet and
what to do; and a move that cannot be made safe stops ``gonio plan``/``capture``/``resume`` in
one line before anything moves."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from conftest import EXAMPLES, grid_plan_text

from acquisition.cli import main
from acquisition.config.plan import load_plan
from acquisition.config.rig import load_rig
from acquisition.planning.planner import Planner
from drivers.errors import CollisionError, LimitError

RIG = EXAMPLES / "rig-sim.toml"
COAXIAL = EXAMPLES / "rig-coaxial-sim.toml"
PARK = {"light_theta": 0.0, "camera_theta": 45.0, "camera_phi": 0.0}
MEET = r"\(the light arm 0\.\d\d m and the camera arm 0\.\d\d m from the sample centre\)"
"""Where on the arms they would meet."""


@pytest.fixture(scope="module")
def planner() -> Planner:
    return Planner(load_rig(RIG))


def refusal(planner: Planner, current: dict[str, float], target: dict[str, float],
            error: type[Exception] = CollisionError) -> str:
    with pytest.raises(error) as info:
        planner.check_move(current, target)
    line = str(info.value)
    assert "\n" not in line and line.startswith("refused move of ")
    return line


def test_a_target_outside_the_limits(planner: Planner) -> None:
    assert refusal(planner, PARK, {"camera_phi": 200.0}, LimitError) == (
        "refused move of camera_phi: camera_phi=200.000° outside [-179, 179]°; give camera_phi "
        "a target inside the soft limits (min_deg/max_deg of [axes.camera_phi] in the rig file)")


def test_a_target_above_the_maximum_elevation(planner: Planner) -> None:
    assert refusal(planner, PARK, {"camera_theta": 86.0}, LimitError) == (
        "refused move of camera_theta: at the target θr 86.0° is above the rig's 85° maximum "
        "elevation; choose a target with θi and θr at most 85° (the rig's maximum elevation)")
    assert refusal(planner, PARK, {"camera_theta": 100.0}, LimitError) == (
        "refused move of camera_theta: at the target θr 100.0° is below the horizon; choose a "
        "target with θi and θr at most 85° (the rig's maximum elevation)")


def test_a_target_where_the_arms_overlap(planner: Planner) -> None:
    line = refusal(planner, PARK, {"light_theta": 30.0, "camera_theta": 32.0})
    assert re.fullmatch(
        r"refused move of light_theta and camera_theta: at light_theta 30\.0°, camera_theta "
        r"32\.0°, camera_phi 0\.0° the arms' swept volumes would overlap by \d+\.\d mm "
        r"\(clearance 5 mm\), meeting at the light arm 0\.\d\d m and the camera arm 0\.\d\d m "
        r"from the sample centre; choose a target that keeps the arms further apart", line), line


def test_a_target_in_the_shadow_cone(planner: Planner) -> None:
    assert refusal(planner, PARK, {"light_theta": 30.0, "camera_theta": 37.0}) == (
        "refused move of light_theta and camera_theta: at light_theta 30.0°, camera_theta 37.0°, "
        "camera_phi 0.0° the camera is 7.00° from the light, inside the 8° shadow cone; choose "
        "a target with the camera at least 8° from the light")


def test_a_swept_path_through_the_other_arm(planner: Planner) -> None:
    start = {"light_theta": 40.0, "camera_theta": 40.0, "camera_phi": 30.0}
    line = refusal(planner, start, {"camera_phi": -30.0})
    assert re.fullmatch(
        r"refused move of camera_phi: moving camera_phi brings the arms \d+\.\d mm inside the "
        r"5 mm clearance at light_theta 40\.0°, camera_theta 40\.0°, camera_phi -?\d+\.\d° "
        + MEET + r"; let gonio route it \(gonio jog, move, home and park do\), or move the "
        r"other arm out of the way first", line), line


def test_the_subset_rule(planner: Planner) -> None:
    start = {"light_theta": 0.0, "camera_theta": 70.0, "camera_phi": 0.0}
    line = refusal(planner, start, {"light_theta": 80.0, "camera_phi": 40.0})
    assert re.fullmatch(
        r"refused move of light_theta and camera_phi: moving light_theta alone \(if camera_phi "
        r"misses the sync write\) brings the arms \d+\.\d mm inside the 5 mm clearance at "
        r"light_theta \d+\.\d°, camera_theta 70\.0°, camera_phi 0\.0° " + MEET
        + r"; let gonio route it \(each leg of a route stays clear even if a servo misses its "
        r"sync write\), or move the axes one at a time", line), line


STUCK = {"light_azimuth": 30.0, "camera_azimuth": -70.0, "stage_tilt": 0.0, "stage_rotation": 0.0}
"""On the coaxial rig (arms on one circle), the camera on the far side of the light: it cannot
get back to the white reference (camera at 45°) without passing through the light."""


def test_no_route() -> None:
    planner = Planner(load_rig(COAXIAL))
    with pytest.raises(CollisionError) as info:
        planner.route(STUCK, planner.reference_joints())
    line = str(info.value)
    assert "\n" not in line
    assert re.fullmatch(
        r"refused move of light_azimuth and camera_azimuth: moving light_azimuth and "
        r"camera_azimuth brings the arms \d+\.\d mm inside the 5 mm clearance at light_azimuth "
        r"-?\d+\.\d°, camera_azimuth -?\d+\.\d°, stage_tilt 0\.0°, stage_rotation 0\.0° "
        + MEET + r", and no route round it exists inside the joint limits; park the rig "
        r"\(`gonio park`\) and approach from there, or choose a target the arms can reach "
        r"without passing each other", line), line


# ---------------------------------------------------------------------- stop before moving
def test_a_plan_whose_reference_cannot_be_reached_stops_in_one_line() -> None:
    rig = load_rig(COAXIAL)
    planner = Planner.for_plan(rig, load_plan(EXAMPLES / "plan-quick.toml"))
    with pytest.raises(CollisionError) as info:
        planner.plan(load_plan(EXAMPLES / "plan-quick.toml").poses(), STUCK)
    line = str(info.value)
    assert "\n" not in line
    assert line.startswith("the white reference cannot be reached safely from the start: "
                           "refused move of light_azimuth and camera_azimuth: ")


def test_capture_and_resume_stop_before_moving_when_the_first_move_has_no_route(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, sims: list,
        capsys: pytest.CaptureFixture[str]) -> None:
    """The rig stands where no route reaches the white reference (the simulator starts there):
    the session's first move is refused in one line and no goal reaches a servo."""
    from acquisition.devices import servos as servos_mod

    rig = load_rig(COAXIAL)
    stuck = {name: servos_mod.make_axis(cfg).deg_to_ticks(STUCK[name])
             for name, cfg in rig.axes.items()}
    plan = tmp_path / "plan.toml"
    plan.write_text(grid_plan_text((20, 40, 20), (30, 30, 10), (90, 180, 90), name="tiny"))
    out = tmp_path / "s"
    for argv in (["capture", "--rig", str(COAXIAL), "--plan", str(plan), "-o", str(out),
                  "--material", "lambert:albedo=0.4"], ["resume", str(out)]):
        with monkeypatch.context() as patch:
            patch.setattr(servos_mod, "park_ticks", lambda rig, planner: stuck)
            assert main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "Traceback" not in err[0], err
        assert err[0].startswith("gonio: error: refused move of light_azimuth and camera_azimuth: ")
        assert "no route round it exists inside the joint limits" in err[0]
        (sim,) = sims[-1:]
        for name, cfg in rig.axes.items():  # every goal as the rig stood: nothing was sent
            servo = sim.servos[cfg.servo_id]
            goal = int.from_bytes(servo.read(116, 4)[1], "little", signed=True)
            assert goal == stuck[name]
            assert servo.sim_true_position_ticks() == pytest.approx(stuck[name])
    assert main(["resume", str(out)]) == 0  # from the park pose, the session completes
