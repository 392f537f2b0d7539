"""The planner's ETA against a simulated capture's clock, for both moving-arm kinematics.

The simulated clock runs ``time_scale`` times faster than the host, so host work that the
engine does not freeze (bus transactions, polling) is scaled up with it; at time_scale 1 the
clock measures what the rig would take, which is what the estimate predicts.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from acquisition import api
from acquisition.plan import load_plan
from acquisition.planner import Planner
from acquisition.rig import load_rig

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"

TINY_PLAN = """
format_version = 1
name = "tiny"
[sampling]
kind = "list"
poses = [[10, 30, 180], [30, 50, 120], [50, 20, 60], [20, 60, 150], [60, 40, 90],
         [40, 10, 30], [15, 70, 100], [70, 25, 170], [35, 35, 180], [5, 55, 45]]
"""


@pytest.mark.slow
@pytest.mark.parametrize("rig_name", ["rig-sim.toml", "rig-coaxial-sim.toml"])
def test_estimate_within_5_percent_of_simulated_run(rig_name: str, tmp_path: Path) -> None:
    text = (EXAMPLES / rig_name).read_text()
    assert "time_scale = 25.0" in text
    rig_path = tmp_path / rig_name
    rig_path.write_text(text.replace("time_scale = 25.0", "time_scale = 1.0"))
    plan_path = tmp_path / "tiny.toml"
    plan_path.write_text(TINY_PLAN)
    rig, plan = load_rig(rig_path), load_plan(plan_path)
    planner = Planner.for_plan(rig, plan)
    sweep = planner.plan(plan.poses(), planner.reference_joints())
    assert len(sweep.steps) == 10 and sweep.motion_s > 2.0
    result = api.capture(rig_path, plan_path, tmp_path / "run", material="lambert:albedo=0.5")
    assert result.counts == {"done": 12}  # ten poses, white reference first and last
    assert result.device_seconds is not None
    error = (sweep.estimated_s - result.device_seconds) / result.device_seconds
    assert abs(error) < 0.05, f"estimate {sweep.estimated_s:.2f} s, run {result.device_seconds:.2f} s"
