"""Motion planner benchmarks: order quality on the dense MERL plan, planning time for 10,000
poses, and the ETA's error against a simulated run.

* ``plan_dense_vs_naive`` — planned motion time / that of the same poses sorted by
  (θi, θr, Δφ) (goal ≤ 0.6), both measured here.
* ``plan_dense_vs_lower_bound`` — planned motion time / the Held–Karp (1-tree) bound on
  the same metric (goal ≤ 1.25); ``plan_dense_vs_nearest_bound`` uses the cheaper bound
  ``gonio plan`` reports for sweeps of this size.
* ``plan_10k_s`` — host seconds to plan a MERL set with about 10,000 measurable poses
  (goal < 10 s); ``plan_10k_poses`` how many it kept.
* ``eta_error_pct`` — (estimate − simulated run) / run in %, for a 24-pose sample of the
  dense plan captured on the simulated out-of-plane rig at time_scale 1;
  ``eta_error_pct_at_rig_time_scale`` the same at the rig file's time_scale, where host
  work the engine does not freeze is scaled up with the clock.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from acquisition import api, sampling
from acquisition.kinematics import Pose
from acquisition.plan import load_plan
from acquisition.planner import Planner
from acquisition.rig import load_rig

ROOT = Path(__file__).resolve().parent.parent
RIG = ROOT / "examples" / "rig-sim.toml"
DENSE = ROOT / "examples" / "plan-dense.toml"


def _eta_error_pct(poses: list[Pose], time_scale: float, workdir: Path) -> float:
    text = RIG.read_text().replace("time_scale = 25.0", f"time_scale = {time_scale}")
    rig_path = workdir / f"rig-{time_scale:g}.toml"
    rig_path.write_text(text)
    rows = ", ".join(f"[{p.theta_i!r}, {p.theta_r!r}, {p.delta_phi!r}]" for p in poses)
    plan_path = workdir / "sample.toml"
    plan_path.write_text(f'format_version = 1\nname = "sample"\n[sampling]\nkind = "list"\n'
                         f"poses = [{rows}]\n")
    rig, plan = load_rig(rig_path), load_plan(plan_path)
    planner = Planner.for_plan(rig, plan)
    sweep = planner.plan(plan.poses(), planner.reference_joints())
    result = api.capture(rig_path, plan_path, workdir / f"run-{time_scale:g}",
                         material="lambert:albedo=0.5")
    assert result.device_seconds
    return 100.0 * (sweep.estimated_s - result.device_seconds) / result.device_seconds


def bench_planner() -> dict[str, dict[str, float | str]]:
    rig, plan = load_rig(RIG), load_plan(DENSE)
    planner = Planner.for_plan(rig, plan)
    planner.bound = "held-karp"
    start = planner.reference_joints()
    dense = planner.plan(plan.poses(), start)
    nearest = Planner.for_plan(rig, plan)
    nearest.bound = "nearest"
    nearest_bound = nearest.plan(plan.poses(), start).lower_bound_motion_s

    big = [Pose(*map(float, r)) for r in sampling.merl_half_diff(32, 32, 30)]
    planner_10k = Planner(rig)
    t0 = time.monotonic()
    sweep_10k = planner_10k.plan(big, start)
    plan_10k_s = time.monotonic() - t0

    sample = [s.pose for s in dense.steps[:: max(1, len(dense.steps) // 24)]][:24]
    with tempfile.TemporaryDirectory() as tmp:
        eta_1 = _eta_error_pct(sample, 1.0, Path(tmp))
        eta_rig = _eta_error_pct(sample, rig.time_scale, Path(tmp))

    return {
        "plan_dense_poses": {"value": len(dense.steps), "unit": "poses"},
        "plan_dense_vs_naive": {"value": dense.motion_s / dense.naive_motion_s, "unit": "ratio"},
        "plan_dense_vs_lower_bound": {
            "value": dense.motion_s / dense.lower_bound_motion_s, "unit": "ratio"},
        "plan_dense_vs_nearest_bound": {"value": dense.motion_s / nearest_bound, "unit": "ratio"},
        "plan_10k_s": {"value": plan_10k_s, "unit": "s"},
        "plan_10k_poses": {"value": len(sweep_10k.steps), "unit": "poses"},
        "eta_error_pct": {"value": eta_1, "unit": "%"},
        "eta_error_pct_at_rig_time_scale": {"value": eta_rig, "unit": "%"},
        "plan_dense_motion_s": {"value": dense.motion_s, "unit": "s"},
        "plan_dense_naive_motion_s": {"value": dense.naive_motion_s, "unit": "s"},
        "plan_dense_mean_move_s": {"value": float(np.mean([s.move_s for s in dense.steps])),
                                   "unit": "s"},
    }
