"""The planner's ETA against a simulated capture's clock, for both moving-arm kinematics.

The example rigs run on a stepped (discrete-event) clock: simulated time passes only in the
devices' own waits (motion polling, settle, exposure) and in each packet's time on the
57600-baud wire, never while the host computes, so the run's rig time is what the hardware
would take, whatever the host's load, and the estimate must match it.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from acquisition import api
from acquisition.config.plan import load_plan
from acquisition.config.rig import load_rig, move_bus_time_s
from acquisition.planning.planner import Planner

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"

TINY_PLAN = """
format_version = 1
name = "tiny"
[sampling]
kind = "list"
poses = [[10, 30, 180], [30, 50, 120], [50, 20, 60], [20, 60, 150], [60, 40, 90],
         [40, 10, 30], [15, 70, 100], [70, 25, 170], [35, 35, 180], [5, 55, 45]]
"""


@pytest.mark.parametrize("rig_name", ["rig-sim.toml", "rig-coaxial-sim.toml",
                                      "rig-misaligned-sim.toml"])  # with backlash: approach legs
def test_estimate_within_5_percent_of_simulated_run(rig_name: str, tmp_path: Path) -> None:
    rig_path = EXAMPLES / rig_name  # the rig's own settings: stepped clock, time_scale 25
    plan_path = tmp_path / "tiny.toml"
    plan_path.write_text(TINY_PLAN)
    rig, plan = load_rig(rig_path), load_plan(plan_path)
    assert rig.sim_clock == "stepped"
    planner = Planner.for_plan(rig, plan)
    sweep = planner.plan(plan.poses(), planner.reference_joints())
    assert len(sweep.steps) == 10 and sweep.motion_s > 2.0
    # The bus time per move is a real share of the run (≈ 0.1 s against ≈ 0.4 s of motion).
    assert rig.bus_cycle_s == pytest.approx(move_bus_time_s(rig.buses, rig.axes))
    assert rig.bus_cycle_s > 0.08
    result = api.capture(rig_path, plan_path, tmp_path / "run", material="lambert:albedo=0.5")
    assert result.counts == {"done": 12}  # ten poses, white reference first and last
    assert result.device_seconds is not None
    error = (sweep.estimated_s - result.device_seconds) / result.device_seconds
    assert abs(error) < 0.05, f"estimate {sweep.estimated_s:.2f} s, run {result.device_seconds:.2f} s"


def test_stepped_run_time_does_not_depend_on_the_host(tmp_path: Path) -> None:
    """The same capture twice gives the same rig time (no host time leaks into it)."""
    plan_path = tmp_path / "tiny.toml"
    plan_path.write_text(TINY_PLAN)
    times = [api.capture(EXAMPLES / "rig-sim.toml", plan_path, tmp_path / f"run{k}",
                         material="lambert:albedo=0.5").device_seconds for k in range(2)]
    assert times[0] == pytest.approx(times[1], abs=1e-9)


def test_a_slow_host_adds_no_rig_time(tmp_path: Path) -> None:
    """Replies 40 ms late in host time (a loaded host, past the SDK's 34 ms timeout) leave the
    stepped rig time unchanged: the driver waits for them instead of retrying, so no retry's
    wire time enters the timeline (a CI run once differed by 19 ms from such a retry)."""
    plan_path = tmp_path / "two.toml"
    plan_path.write_text(TINY_PLAN.split("poses")[0] + "poses = [[10, 30, 180], [30, 50, 120]]\n")
    times = [api.capture(EXAMPLES / "rig-sim.toml", plan_path, tmp_path / f"run{k}",
                         material="lambert:albedo=0.5", sim_faults=faults).device_seconds
             for k, faults in enumerate([[], ["delay=40"]])]
    assert times[1] == pytest.approx(times[0], abs=1e-9)
