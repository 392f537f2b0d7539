"""``gonio demo``: the whole pipeline on the simulated rig, with a summary."""

from __future__ import annotations

import argparse

from acquisition import api
from acquisition.cli.progress import step_bar


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="capture, reduce and plot on the simulated rig")
    p.add_argument("--material", default=api.DEFAULT_MATERIAL, help="simulated material spec")
    p.add_argument("--out", default="demo-output", help="folder for the demo session")
    p.add_argument("--seed", type=int, default=1)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    with step_bar("demo capture") as bar:
        r = api.run_demo(args.out, material=args.material, seed=args.seed, progress=bar)
    rig = (f", {r.rig_minutes:.1f} min of simulated rig time "
           f"(planner's estimate {r.estimated_minutes:.1f} min)" if r.rig_minutes else "")
    print(f"material        {args.material}")
    print(f"poses captured  {r.poses}")
    print(f"measured bins   {r.measured_bins}")
    print(f"time            {r.host_minutes:.1f} min{rig}")
    print(f"error vs truth  median {100 * r.median_rel_error:.2f} % over measured bins")
    ti, tr, dp = r.peak_pose
    print(f"BRDF maximum    θi={ti:.0f}° θr={tr:.0f}° Δφ={dp:.0f}°")
    print(f"session         {r.session}")
    print(f"table           {r.table}")
    print(f"plot            {r.plot}")
    return 0
