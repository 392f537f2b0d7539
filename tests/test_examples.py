"""The shipped example files plan cleanly, and the demo plan still fills ≥ 500 table bins."""

from __future__ import annotations

import numpy as np
from conftest import EXAMPLES

from acquisition import api
from acquisition.config.plan import load_plan
from acquisition.tables import IsotropicTable


def test_demo_plan_covers_at_least_500_bins() -> None:
    plan_path, rig_path = EXAMPLES / "plan-demo.toml", EXAMPLES / "rig-sim.toml"
    sweep = api.plan_sweep(plan_path, rig_path)
    spec = load_plan(plan_path).table
    table = IsotropicTable(spec.theta_i_edges, spec.theta_r_edges, spec.delta_phi_edges)
    poses = np.array([s.pose.as_tuple() for s in sweep.steps])
    table.add(poses[:, 0], poses[:, 1], poses[:, 2], np.ones((len(poses), 3)))
    assert int((table.count > 0).sum()) >= 500


def test_quick_plan_is_a_few_hundred_poses() -> None:
    sweep = api.plan_sweep(EXAMPLES / "plan-quick.toml", EXAMPLES / "rig-sim.toml")
    assert 100 <= len(sweep.steps) <= 400
