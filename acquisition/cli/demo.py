"""``gonio demo``: the whole pipeline on the simulated rig, with a summary."""

from __future__ import annotations

import argparse

from acquisition import api
from acquisition.cli.capture import eta_from_time_model
from acquisition.cli.options import add_json, add_out, report
from acquisition.cli.progress import step_bar

COMMANDS = {"demo": "capture, reduce, plot and report on the simulated rig"}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help=COMMANDS["demo"])
    p.add_argument("--material", default=api.DEFAULT_MATERIAL, help="simulated material spec")
    add_out(p, "folder for the demo session (default demo-output)")
    p.add_argument("--seed", type=int, default=1,
                   help="noise seed of the simulated devices (default 1)")
    add_json(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    with step_bar("demo capture") as bar:
        r = api.run_demo(args.out or "demo-output", material=args.material, seed=args.seed,
                         progress=bar, on_open=eta_from_time_model(bar, args, announce=False))
    rig = (f", {r.rig_minutes:.1f} min of simulated rig time "
           f"(planner's estimate {r.estimated_minutes:.1f} min)" if r.rig_minutes else "")
    ti, tr, dp = r.peak_pose
    report(args, {"material": args.material, **r.__dict__}, [
        f"material        {args.material}",
        f"poses captured  {r.poses}",
        f"measured bins   {r.measured_bins}",
        f"time            {r.host_minutes:.1f} min{rig}",
        f"error vs truth  median {100 * r.median_rel_error:.2f} % over measured bins",
        f"BRDF maximum    θi={ti:.0f}° θr={tr:.0f}° Δφ={dp:.0f}°",
        f"session         {r.session}",
        f"table           {r.table}",
        f"plot            {r.plot}",
        f"report          {r.report}",
    ])
    return 0
