"""``gonio calibrate dark|flat|noise|white --rig RIG --out BUNDLE``: make a calibration bundle."""

from __future__ import annotations

import argparse

from acquisition import api
from acquisition.cli.options import add_json, add_out, add_seed, report
from acquisition.cli.progress import step_bar

COMMANDS = {"calibrate": "capture dark/flat/noise/white calibration into a bundle"}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("calibrate", help=COMMANDS["calibrate"])
    p.add_argument("kind", choices=api.KINDS, help="what to calibrate")
    p.add_argument("--rig", required=True, help="rig file (TOML)")
    add_out(p, "calibration bundle folder (created or updated)", required=True)
    p.add_argument("--frames", type=int, help="frames per measurement (dark 8, flat 16, white 4)")
    p.add_argument("--exposure", type=float, help="exposure time, s (default: the rig's)")
    p.add_argument("--iso", type=int, help="ISO (default: the rig's)")
    add_seed(p)
    add_json(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    with step_bar(f"calibrate {args.kind}", unit="frame") as bar:
        result = api.calibrate(args.kind, args.rig, args.out, frames=args.frames,
                           exposure_s=args.exposure, iso=args.iso, seed=args.seed,
                           progress=lambda d, t: bar(d, t))
    details = ", ".join(f"{k} {_fmt(v)}" for k, v in result.summary.items())
    report(args, result, [f"{result.bundle}: {result.kind} from {result.frames} frames ({details})"])
    return 0


def _fmt(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, list):
        return "/".join(f"{v:.4g}" for v in value)
    return str(value)
