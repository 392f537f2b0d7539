"""``gonio calibrate dark|flat|noise|white --rig RIG --out BUNDLE``: make a calibration bundle."""

from __future__ import annotations

import argparse

from acquisition import api
from acquisition.cli.progress import step_bar


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("calibrate", help="capture dark/flat/noise/white calibration into a bundle")
    p.add_argument("kind", choices=api.KINDS, help="what to calibrate")
    p.add_argument("--rig", required=True, help="rig file (TOML)")
    p.add_argument("--out", required=True, help="calibration bundle folder (created or updated)")
    p.add_argument("--frames", type=int, help="frames per measurement (dark 8, flat 16, white 4)")
    p.add_argument("--exposure", type=float, help="exposure time, s (default: the rig's)")
    p.add_argument("--iso", type=int, help="ISO (default: the rig's)")
    p.add_argument("--seed", type=int, default=0, help="noise seed of the simulated devices")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    with step_bar(f"calibrate {args.kind}", unit="frame") as bar:
        result = api.calibrate(args.kind, args.rig, args.out, frames=args.frames,
                           exposure_s=args.exposure, iso=args.iso, seed=args.seed,
                           progress=lambda d, t: bar(d, t))
    details = ", ".join(f"{k} {_fmt(v)}" for k, v in result.summary.items())
    print(f"{result.bundle}: {result.kind} from {result.frames} frames ({details})")
    return 0


def _fmt(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, list):
        return "/".join(f"{v:.4g}" for v in value)
    return str(value)
