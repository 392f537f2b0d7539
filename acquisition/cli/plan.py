"""``gonio plan``: check and time a plan on a rig without moving anything."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from acquisition import api
from acquisition.cli.capture import print_estimate


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plan", help="check and time a plan on a rig without moving anything")
    p.add_argument("plan", help="plan file (TOML)")
    p.add_argument("--rig", required=True, help="rig file (TOML)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--plot", metavar="FILE.png",
                   help="draw accepted/rejected poses on (θh, θd) and the hemisphere, and a "
                        "per-axis timeline")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    sweep = api.plan_sweep(args.plan, args.rig)
    if args.json:
        print(json.dumps(sweep.summary()))
    else:
        print_estimate(sweep)
        print(f"motion {sweep.motion_s:.1f} s; naive order {sweep.naive_motion_s:.1f} s; "
              f"lower bound {sweep.lower_bound_motion_s:.1f} s")
    if args.plot:
        path = api.plot_sweep(sweep, args.plot, title=Path(args.plan).stem)
        if not args.json:
            print(f"plot written to {path}")
    return 0
