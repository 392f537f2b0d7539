"""What the acceptance tests on a misaligned rig share: ``gonio calibrate geometry --json``, a
capture planned with its bundle and reduced with and without it, the peak bins' errors against
the truth, the pose the planner's joints realise on the simulated world's TRUE geometry
(its own code: :class:`~acquisition.simworld.misalignment.TrueGeometry`), and the sphere rig
at a reduced resolution."""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import numpy as np
from conftest import EXAMPLES

from acquisition import api
from acquisition.api.truth import truth_table
from acquisition.cli import main
from acquisition.config.rig import RigConfig
from acquisition.config.simerrors import SimErrors
from acquisition.geometry.alignment import Alignment
from acquisition.geometry.kinematics import Pose, pose_from_directions
from acquisition.planning.planner import Planner
from acquisition.reduction.point import reduce_session
from acquisition.simworld.misalignment import TrueGeometry
from acquisition.tables import IsotropicTable

MATERIAL = "ggx:albedo=0.1,alpha=0.06,f0=0.5"
"""The issue's GGX material: a lobe ≈ 8° wide at half maximum."""


def sphere_rig(root: Path, scale: float, errors: str, focal: float = 1.0) -> Path:
    """``root/rig.toml``: examples/rig-sphere-sim.toml at ``scale`` of its resolution (the
    region of interest alike; the focal length ``focal`` times more), with ``errors`` as its
    ``[simulation.errors]`` lines."""
    text = (EXAMPLES / "rig-sphere-sim.toml").read_text()
    size, f = int(1000 * scale), 7200.0 * scale * focal
    lo, hi = int(200 * scale), int(300 * scale)
    for old, new in (("width = 1000", f"width = {size}"), ("height = 1000", f"height = {size}"),
                     ("fx = 7200.0", f"fx = {f:g}"), ("fy = 7200.0", f"fy = {f:g}"),
                     ("roi = [200, 200, 300, 300]", f"roi = [{lo}, {lo}, {hi}, {hi}]"),
                     ("[buses.main]", f"[simulation.errors]\n{errors}\n\n[buses.main]")):
        assert old in text
        text = text.replace(old, new, 1)
    path = root / "rig.toml"
    path.write_text(text)
    return path


def calibrate_json(rig: Path, root: Path, seed: int = 3) -> dict:
    """``gonio calibrate geometry --json`` on ``rig`` into ``root/cal``: its JSON, the bundle."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = main(["calibrate", "geometry", "--rig", str(rig), "--out", str(root / "cal"),
                     "--json", "--seed", str(seed)])
    assert code == 0
    return {"root": root, "bundle": root / "cal", "json": json.loads(out.getvalue())}


def capture_both_ways(rig: Path, calibrated: dict, plan_text: str
                      ) -> dict[bool, tuple[IsotropicTable, IsotropicTable]]:
    """:data:`MATERIAL` captured with the calibration; {reduced with it: (table, truth)}."""
    root = calibrated["root"]
    plan = root / "plan.toml"
    plan.write_text(plan_text)
    api.capture(rig, plan, root / "s", material=MATERIAL, seed=5,
                calibration=calibrated["bundle"])
    out = {}
    for geometry in (True, False):
        table = reduce_session(root / "s", geometry=geometry).table
        out[geometry] = (table, truth_table(root / "s", geometry=geometry))
    return out


def peak_errors(table: IsotropicTable, truth: IsotropicTable) -> tuple[np.ndarray, np.ndarray]:
    """Relative errors and error / std_error (green) over the peak bins: truth ≥ half max."""
    green = truth.mean[..., 1]
    peak = (table.count > 0) & (truth.count > 0) & (green >= 0.5 * np.nanmax(green))
    rel = np.mean(np.abs(table.mean - truth.mean) / truth.mean, axis=-1)[peak]
    z = ((table.mean - truth.mean) / table.std_error)[..., 1][peak]
    return rel, z


def assert_planner_applies(rig: RigConfig, alignment: Alignment, poses: list[Pose]) -> None:
    """With ``alignment`` the planner's joints realise each pose on the true rig within 0.1°
    (θi, θr and the angle between light and camera, which fixes Δφ: each combines up to two
    calibrated parameters, each within 0.05°); the rig file's model misses one of them by more
    than 0.5°."""
    errors, truth = rig.sim_errors, TrueGeometry(rig)
    assert errors is not None
    for pose in poses:
        calibrated = _miss_deg(realised_pose(Planner(rig, alignment=alignment), truth, errors,
                                             pose), pose)
        nominal = _miss_deg(realised_pose(Planner(rig), truth, errors, pose), pose)
        print(f"{pose}: calibrated miss {calibrated:.4f}°, nominal {nominal:.3f}°")
        assert calibrated < 0.1 and nominal > 0.5, pose


def _miss_deg(got: np.ndarray, pose: Pose) -> float:
    """Largest error of θi, θr and the light–camera angle of ``got`` against ``pose``."""
    def spread(p: np.ndarray) -> float:
        ti, tr, dp = np.radians(p)
        return float(np.degrees(np.arccos(np.cos(ti) * np.cos(tr)
                                          + np.sin(ti) * np.sin(tr) * np.cos(dp))))

    want = np.array(pose.as_tuple())
    return float(max(*np.abs(got[:2] - want[:2]), abs(spread(got) - spread(want))))


def realised_pose(planner: Planner, truth: TrueGeometry, errors: SimErrors, pose: Pose
                  ) -> np.ndarray:
    """(θi, θr, Δφ) the planner's joints for ``pose`` realise on the true rig, every axis
    approached from below (so standing half its backlash behind)."""
    joints = planner.joints_for(pose)
    true = {a: v + errors.zero_offset_deg.get(a, 0.0) - errors.backlash_deg.get(a, 0.0) / 2
            for a, v in joints.items()}
    return np.array(pose_from_directions(*truth.directions(true)).as_tuple())


def assert_recovered(data: dict, errors: SimErrors) -> None:
    """``gonio calibrate geometry --json`` found every injected zero offset and the sample
    tilt within 0.05° and within 2σ, and each backlash it measured within 3σ + 0.01°."""
    found = {**data["zero_offset_deg"], "about_x": data["sample_tilt_deg"]["about_x"],
             "about_y": data["sample_tilt_deg"]["about_y"]}
    injected = {**errors.zero_offset_deg, "about_x": errors.sample_tilt_deg[0],
                "about_y": errors.sample_tilt_deg[1]}
    assert set(found) == set(injected)
    for name, truth in injected.items():
        value, sigma = found[name]["value"], found[name]["sigma"]
        print(f"{name}: {value:+.4f}° ± {sigma:.4f}° (injected {truth:+.4f}°, "
              f"error {value - truth:+.4f}°)")
        assert abs(value - truth) <= 0.05 and abs(value - truth) <= 2 * sigma, name
    for axis, v in data["backlash_deg"].items():  # measured from both approach directions
        assert abs(v["value"] - errors.backlash_deg[axis]) <= 3 * v["sigma"] + 0.01, axis
