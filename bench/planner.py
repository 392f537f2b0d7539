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
  dense plan captured on the simulated out-of-plane rig with the rig file's own settings
  (stepped clock: rig time = motion + polling + wire time + settle + exposure);
  ``eta_error_pct_coaxial`` the same on the coaxial rig (the dense plan's poses it accepts);
  ``eta_error_pct_scaled_clock`` the out-of-plane sample on the old scaled clock
  (``clock = "scaled"``, time_scale 25) as the baseline, where host work the engine does not
  freeze is scaled up with the clock.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from acquisition import api
from acquisition.config.plan import load_plan
from acquisition.config.rig import load_rig
from acquisition.geometry import sampling
from acquisition.geometry.kinematics import Pose
from acquisition.planning.planner import Planner

ROOT = Path(__file__).resolve().parent.parent
RIG = ROOT / "examples" / "rig-sim.toml"
COAXIAL = ROOT / "examples" / "rig-coaxial-sim.toml"
DENSE = ROOT / "examples" / "plan-dense.toml"


def _eta_error_pct(poses: list[Pose], rig_file: Path, workdir: Path, tag: str,
                   simulation: str | None = None) -> float:
    """Capture ``poses`` on ``rig_file`` (its ``time_scale`` line replaced by ``simulation``
    if given); the planner's estimate against the run's rig time, in %."""
    text = rig_file.read_text()
    if simulation is not None:
        text = text.replace("time_scale = 25.0", simulation)
    rig_path = workdir / f"rig-{tag}.toml"
    rig_path.write_text(text)
    rows = ", ".join(f"[{p.theta_i!r}, {p.theta_r!r}, {p.delta_phi!r}]" for p in poses)
    plan_path = workdir / f"sample-{tag}.toml"
    plan_path.write_text(f'format_version = 1\nname = "sample"\n[sampling]\nkind = "list"\n'
                         f"poses = [{rows}]\n")
    rig, plan = load_rig(rig_path), load_plan(plan_path)
    planner = Planner.for_plan(rig, plan)
    sweep = planner.plan(plan.poses(), planner.reference_joints())
    result = api.capture(rig_path, plan_path, workdir / f"run-{tag}",
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
    coax_rig = load_rig(COAXIAL)
    coax_planner = Planner.for_plan(coax_rig, plan)
    coax = coax_planner.plan(plan.poses(), coax_planner.reference_joints())
    coax_sample = [s.pose for s in coax.steps[:: max(1, len(coax.steps) // 24)]][:24]
    with tempfile.TemporaryDirectory() as tmp:
        eta_rig = _eta_error_pct(sample, RIG, Path(tmp), "oop")
        eta_coax = _eta_error_pct(coax_sample, COAXIAL, Path(tmp), "coax")
        eta_scaled = _eta_error_pct(sample, RIG, Path(tmp), "scaled",
                                    'time_scale = 25.0\nclock = "scaled"')

    return {
        "plan_dense_poses": {"value": len(dense.steps), "unit": "poses"},
        "plan_dense_vs_naive": {"value": dense.motion_s / dense.naive_motion_s, "unit": "ratio"},
        "plan_dense_vs_lower_bound": {
            "value": dense.motion_s / dense.lower_bound_motion_s, "unit": "ratio"},
        "plan_dense_vs_nearest_bound": {"value": dense.motion_s / nearest_bound, "unit": "ratio"},
        "plan_10k_s": {"value": plan_10k_s, "unit": "s"},
        "plan_10k_poses": {"value": len(sweep_10k.steps), "unit": "poses"},
        "eta_error_pct": {"value": eta_rig, "unit": "%"},
        "eta_error_pct_coaxial": {"value": eta_coax, "unit": "%"},
        "eta_error_pct_scaled_clock": {"value": eta_scaled, "unit": "%"},
        "plan_dense_motion_s": {"value": dense.motion_s, "unit": "s"},
        "plan_dense_naive_motion_s": {"value": dense.naive_motion_s, "unit": "s"},
        "plan_dense_mean_move_s": {"value": float(np.mean([s.move_s for s in dense.steps])),
                                   "unit": "s"},
    }
