"""A scripted capture to copy: a coarse sweep, then a refinement around the specular peak.

Run on the simulated rig (about half a minute)::

    python examples/scripted_session.py runs/specular --material ggx:albedo=0.2,alpha=0.15,f0=0.04

Two session folders are written under OUT: ``coarse/`` (the plan file's sweep) and ``fine/``
(a finer grid around the peak the coarse sweep found, each pose exposed as a 2-frame bracket).
Each is an ordinary session: ``gonio info``, ``gonio reduce`` and ``gonio export`` work on it.
If the script is stopped (Ctrl-C, crash, power cut), run it again with ``--resume``: the
steps already in each session's journal are skipped, nothing is taken twice.
"""

from __future__ import annotations

import argparse
import logging
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from acquisition import api
from acquisition.api import LiveReduction, LogObserver, Pose, Rejection
from acquisition.steps import Checkpoint, Expose, Move, Reference, Step

HERE = Path(__file__).resolve().parent
RIG = HERE / "rig-sim.toml"
COARSE_PLAN = HERE / "plan-coarse-specular.toml"


def refine_plan_text(peak: Pose, half_width_deg: float = 6.0, step_deg: float = 2.0) -> str:
    """A plan file binning the refinement: θr and Δφ around ``peak``, θi fixed."""
    lo = max(peak.theta_r - half_width_deg, 0.0)
    hi = min(peak.theta_r + half_width_deg, 80.0)
    dphi_lo = max(peak.delta_phi - 6 * step_deg, 0.0)
    return f"""format_version = 1
name = "fine-specular"
[sampling]
kind = "grid"
theta_i = {{ start = {peak.theta_i:g}, stop = {peak.theta_i:g}, step = 1 }}
theta_r = {{ start = {lo:g}, stop = {hi:g}, step = {step_deg:g} }}
delta_phi = {{ start = {dphi_lo:g}, stop = 180, step = {2 * step_deg:g} }}
"""


def refinement(session: api.ScriptedSession) -> Iterator[Step]:
    """A plan as a generator: the refinement grid's safe poses, a 2-frame bracket each."""
    yield Reference()
    for pose in session.plan.poses():
        if not isinstance(session.planner.check_pose(pose), Rejection):  # unsafe: skip
            yield Move(pose)
            yield Expose(bracket=(0.5, 1.0))
            yield Checkpoint(f"θr={pose.theta_r:g} Δφ={pose.delta_phi:g}")
    yield Reference()


def run(out: str | Path, material: str, seed: int = 0, resume: bool = False) -> dict[str, Pose]:
    """Capture coarse then fine; returns the peak pose (degrees) each found."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    log = LogObserver()

    live = LiveReduction()
    with api.scripted_session(out / "coarse", RIG, COARSE_PLAN, material=material, seed=seed,
                              resume=resume) as s:
        s.run(s.sweep(), observers=[live, log])
    # A resumed run only sees the frames it took: fall back to the reduced table.
    coarse = live.peak() if live.samples else table_peak(out / "coarse")

    fine_plan = out / "plan-fine.toml"
    if not (resume and fine_plan.exists()):
        fine_plan.write_text(refine_plan_text(coarse))
    with api.scripted_session(out / "fine", RIG, fine_plan, material=material, seed=seed,
                              resume=resume) as s:
        s.run(refinement(s), observers=[log])
    return {"coarse": coarse, "fine": table_peak(out / "fine")}


def table_peak(session_dir: Path) -> Pose:
    """Reduce a session and return the bin centre (degrees) of its largest green BRDF."""
    table = api.reduce(session_dir).table
    g = np.where(table.count > 0, table.mean[..., 1], -np.inf)
    i, j, k = np.unravel_index(int(np.argmax(g)), g.shape)
    ti, tr, dp = table.centers()
    return Pose(float(ti[i]), float(tr[j]), float(dp[k]))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("out", help="folder for the two sessions")
    p.add_argument("--material", default="ggx:albedo=0.2,alpha=0.15,f0=0.04")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--resume", action="store_true", help="continue an interrupted run")
    args = p.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    peaks = run(args.out, args.material, args.seed, args.resume)
    for name, pose in peaks.items():
        print(f"{name:6} peak at θi={pose.theta_i:g}° θr={pose.theta_r:g}° Δφ={pose.delta_phi:g}°")


if __name__ == "__main__":
    main()
