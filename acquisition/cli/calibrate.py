"""``gonio calibrate dark|flat|noise|white|geometry --rig RIG --out BUNDLE``: make a calibration
bundle (``geometry``: an out-of-plane-arcs or coaxial-arms rig's zero offsets and sample tilt,
from a mirror and the white target)."""

from __future__ import annotations

import argparse
import math

from acquisition import api
from acquisition.cli.operator import terminal_prompt
from acquisition.cli.options import add_json, add_out, add_seed, report
from acquisition.cli.progress import step_bar

COMMANDS = {"calibrate": "capture dark/flat/noise/white/geometry calibration into a bundle"}
GEOMETRY = "geometry"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("calibrate", help=COMMANDS["calibrate"])
    p.add_argument("kind", choices=(*api.KINDS, GEOMETRY), help="what to calibrate")
    p.add_argument("--rig", required=True, help="rig file (TOML)")
    add_out(p, "calibration bundle folder (created or updated)", required=True)
    p.add_argument("--frames", type=int, help="frames per measurement (dark 8, flat 16, white 4)")
    p.add_argument("--exposure", type=float, help="exposure time, s (default: the rig's)")
    p.add_argument("--iso", type=int, help="ISO (default: the rig's)")
    add_seed(p)
    add_json(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.kind == GEOMETRY:
        return run_geometry(args)
    with step_bar(f"calibrate {args.kind}", unit="frame") as bar:
        result = api.calibrate(args.kind, args.rig, args.out, frames=args.frames,
                           exposure_s=args.exposure, iso=args.iso, seed=args.seed,
                           progress=lambda d, t: bar(d, t))
    details = ", ".join(f"{k} {_fmt(v)}" for k, v in result.summary.items())
    report(args, result, [f"{result.bundle}: {result.kind} from {result.frames} frames ({details})"])
    return 0


def run_geometry(args: argparse.Namespace) -> int:
    """The geometric calibration: one line per parameter with its 1σ, then the fit's figures."""
    with step_bar("calibrate geometry", unit="frame") as bar:
        result = api.calibrate_geometry(args.rig, args.out, seed=args.seed,
                                        progress=lambda d, t: bar(d, t),
                                        prompt=terminal_prompt())
    data = result.to_json()
    lines = [f"{result.bundle}: geometry from {result.frames} frames"]
    for axis, v in data["zero_offset_deg"].items():
        lines.append(f"  zero offset {axis}: {_pm(v)}")
    for about, v in data["sample_tilt_deg"].items():
        lines.append(f"  sample tilt {about.replace('_', ' ')}: {_pm(v)}")
    for axis, v in data["backlash_deg"].items():
        lines.append(f"  backlash {axis}: {_pm(v)}")
    lines.append(f"  residual {data['residual_deg']:.4f}°, rank {data['rank']} of "
                 f"{data['parameters']}, condition number {data['condition_number']:.3g}, "
                 f"χ²/dof {data['chi2_dof']:.3g}")
    lines += [f"  unobservable: {c} (not determined: the rig file's value is kept)"
              for c in data["unobservable"]]
    lines += [f"  not measured: {c}" for c in data["not_measured"]]
    report(args, data, lines)
    return 0


def _pm(v: dict[str, float]) -> str:
    sigma = v["sigma"]
    shown = "not determined" if not math.isfinite(sigma) else f"{sigma:.4f}°"
    return f"{v['value']:+.4f}° ± {shown}"


def _fmt(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, list):
        return "/".join(f"{v:.4g}" for v in value)
    return str(value)
