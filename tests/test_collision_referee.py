"""The simulated rig is a referee: a capture whose moves are not path-checked hits the camera
in the simulator, stops on the overload in one line, and the session records the collision."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import EXAMPLES

from acquisition import api
from acquisition.cli import main
from acquisition.planning.planner import Planner
from drivers.errors import HardwareError


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
