"""``gonio plan``: check and time a plan on a rig without moving anything."""

from __future__ import annotations

import argparse
from pathlib import Path

from acquisition import api
from acquisition.cli.capture import estimate_line
from acquisition.cli.operator import operator_output
from acquisition.cli.options import add_json, add_out, report

COMMANDS = {"plan": "check and time a plan on a rig without moving anything"}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plan", help=COMMANDS["plan"])
    p.add_argument("plan", help="plan file (TOML)")
    p.add_argument("--rig", required=True, help="rig file (TOML)")
    add_out(p, "plot (PNG, PDF or SVG) of accepted/rejected poses on (θh, θd) and the "
               "hemisphere, and a per-axis timeline", aliases=("--plot",))
    add_json(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    with operator_output():  # a plan whose angles look like radians warns
        sweep = api.plan_sweep(args.plan, args.rig)
    summary = sweep.summary()
    lines = [estimate_line(summary),
             f"motion {sweep.motion_s:.1f} s; naive order {sweep.naive_motion_s:.1f} s; "
             f"lower bound {sweep.lower_bound_motion_s:.1f} s"]
    if args.out:
        path = api.plot_sweep(sweep, args.out, title=Path(args.plan).stem)
        lines.append(f"plot written to {path}")
    report(args, summary, lines)
    return 0
