"""The simulated rig is a referee: a capture whose moves are not path-checked hits the camera
in the simulator, stops on the overload in one line, and the session records the collision.
And the test-wide referee (:mod:`referee`) sees every simulated bus, also one a module-scoped
fixture starts, and fails the test during whose setup, call or teardown the arms touched."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import EXAMPLES

from acquisition import api
from acquisition.cli import main
from acquisition.planning.planner import Planner
from drivers.errors import HardwareError

pytest_plugins = ["pytester"]


@pytest.mark.collides
def test_a_capture_without_path_checks_collides_in_the_simulator(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    # What the guard did before it checked swept paths: targets only, no routes.
    monkeypatch.setattr(Planner, "check_move", lambda self, cur, tgt: self.check_joints({**cur, **tgt}))
    monkeypatch.setattr(Planner, "route", lambda self, cur, tgt: [{**cur, **tgt}])
    with pytest.raises(HardwareError, match=r"overload \(bit 5\).*gonio reboot") as err:
        api.capture(EXAMPLES / "rig-sim.toml", EXAMPLES / "plan-quick.toml", tmp_path / "s",
                    material="lambert:albedo=0.5", seed=1)
    assert "\n" not in str(err.value)
    status = api.session_status(tmp_path / "s", drift=False)
    hits = [e for e in status.events if "simulated collision" in e[3]]
    assert hits and "arms touched" in hits[0][3]
    assert status.done < status.total  # stopped, resumable after `gonio reboot`
    assert main(["info", str(tmp_path / "s"), "--no-drift"]) == 0
    assert "simulated collision" in capsys.readouterr().out



SYNTHETIC_HEAD = """
import pytest
from simulators.clock import SteppedClock
from simulators.dynamixel import serve_rig

RIG = {rig!r}
THROUGH_THE_CAMERA = (2048 + round(55 * 4096 / 360)).to_bytes(4, "little")  # light_theta 55°


def crash(rig, clock):
    light = rig.servo("light_theta")  # from park, straight through the camera at θ 45°
    light.write(64, b"\\x01")
    light.write(116, THROUGH_THE_CAMERA)
    clock.advance(0.5)  # nobody asks the simulator anything: the referee must look itself
"""
SYNTHETIC = {
    "test_setup": """
@pytest.fixture(scope="module")
def crashed_in_a_module_fixture():
    clock = SteppedClock()
    with serve_rig(RIG, clock=clock) as rig:
        crash(rig, clock)
        yield rig


def test_first_user(crashed_in_a_module_fixture):
    pass


def test_second_user(crashed_in_a_module_fixture):
    pass
""",
    "test_teardown": """
@pytest.fixture(scope="module")
def crashes_at_teardown():
    clock = SteppedClock()
    with serve_rig(RIG, clock=clock) as rig:
        yield rig
        crash(rig, clock)


def test_only_user(crashes_at_teardown):
    pass
""",
    "test_other": """
@pytest.mark.collides
def test_marked_collides():
    clock = SteppedClock()
    with serve_rig(RIG, clock=clock) as rig:
        crash(rig, clock)


def test_clean():
    clock = SteppedClock()
    with serve_rig(RIG, clock=clock):
        clock.advance(1.0)
""",
}


@pytest.mark.collides  # the synthetic session runs in this process; its referee drains it all
def test_the_referee_fails_a_test_whose_module_fixture_collided(pytester: pytest.Pytester) -> None:
    pytester.makeconftest("from referee import pytest_runtest_makereport  # noqa: F401\n")
    head = SYNTHETIC_HEAD.format(rig=str(EXAMPLES / "rig-sim.toml"))
    pytester.makepyfile(**{name: head + body for name, body in SYNTHETIC.items()})
    result = pytester.runpytest_inprocess("-p", "no:cacheprovider", "-rA")
    result.assert_outcomes(passed=4, errors=2)  # test_only_user passes, then errs at teardown
    result.stdout.fnmatch_lines([
        "*ERROR at setup of test_first_user*",
        "the simulated arms collided during setup of test_setup.py::test_first_user "
        "(fixtures of every scope count; *): arms touched at t=* light_theta (servo 1) stalled*",
        "*ERROR at teardown of test_only_user*",
        "the simulated arms collided during teardown of test_teardown.py::test_only_user *",
    ])
    for test in ("test_second_user", "test_only_user", "test_marked_collides", "test_clean"):
        assert any(line.startswith("PASSED ") and line.endswith(f"::{test}")
                   for line in result.outlines), test
