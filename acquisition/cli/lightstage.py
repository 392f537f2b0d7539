"""``gonio lightstage capture|resume|field`` and ``gonio relight``: light-stage sessions."""

from __future__ import annotations

import argparse
from pathlib import Path

from acquisition import api
from acquisition.cli.console import operator_output
from acquisition.cli.operator import terminal_prompt
from acquisition.cli.progress import step_bar

FIELD_DIR = "field"
"""Sub-folder of a session where the reflectance field is written."""


def _sequences(text: str) -> list[str]:
    names = [s.strip() for s in text.split(",") if s.strip()]
    bad = [n for n in names if n not in api.SEQUENCES]
    if not names or bad:
        raise argparse.ArgumentTypeError(
            f"unknown sequence '{(bad or [text])[0]}' (known: {', '.join(api.SEQUENCES)})")
    return names


def register(sub: argparse._SubParsersAction) -> None:
    stage = sub.add_parser("lightstage", help="capture on a light stage (LED dome over DMX)")
    cmds = stage.add_subparsers(dest="lightstage_command", metavar="COMMAND")
    cmds.required = True

    p = cmds.add_parser("capture", help="capture a light-stage sequence into a new session folder")
    p.add_argument("--rig", required=True, help="light-stage rig file (TOML)")
    p.add_argument("--out", required=True, help="new session folder (must not exist)")
    p.add_argument("--sequence", type=_sequences, default=["olat"], metavar="NAMES",
                   help=f"comma-separated sequences on the sample ({', '.join(api.SEQUENCES)}); "
                        "default olat")
    p.add_argument("--material", help="material the simulated camera sees, e.g. ggx:alpha=0.3")
    p.add_argument("--seed", type=int, default=0, help="noise seed of the simulated devices")
    p.add_argument("--plan", help="plan file giving table bins and exposure (default: built in)")
    p.add_argument("--calibration", metavar="PATH",
                   help="calibration file or folder used; copied into the session")
    p.set_defaults(func=run_capture)

    p = cmds.add_parser("resume", help="continue an interrupted light-stage session")
    p.add_argument("session", help="session folder")
    p.set_defaults(func=run_resume)

    p = cmds.add_parser("field", help="write a session's calibrated reflectance field (EXRs)")
    p.add_argument("session", help="session folder")
    p.add_argument("-o", "--output", help=f"folder for the EXRs (default: SESSION/{FIELD_DIR})")
    p.set_defaults(func=run_field)

    p = sub.add_parser("relight", help="relight a reflectance field with a lat-long environment map")
    p.add_argument("field", help="reflectance-field folder (light-*.exr)")
    p.add_argument("--env", required=True, help="lat-long environment map (EXR, linear)")
    p.add_argument("-o", "--output", required=True, help="relit image (EXR)")
    p.set_defaults(func=run_relight)


def _print_estimate(est: api.TimeEstimate) -> None:
    print(f"{est.frames} frames, {est.light_changes} light changes; estimated "
          f"{est.total_s:.1f} s of rig time ({est.dmx_s:.1f} s DMX and settle, "
          f"{est.exposure_s:.1f} s exposure)")


def _finish(result: api.LightStageResult) -> int:
    done = result.counts.get("done", 0)
    rig_time = f" in {result.device_seconds:.1f} s of rig time" if result.device_seconds else ""
    print(f"session {result.session.path}: {done} steps done{rig_time}")
    if done == sum(result.counts.values()) and "olat" in api.session_sequences(result.session.path):
        paths = api.write_field(result.session.path, result.session.path / FIELD_DIR)
        print(f"reflectance field: {len(paths)} EXRs in {result.session.path / FIELD_DIR}")
    return 0


def run_capture(args: argparse.Namespace) -> int:
    _print_estimate(api.plan_lightstage(args.rig, args.sequence))
    with operator_output(), api.sigint_stops_motion(), step_bar("capture") as bar:
        result = api.capture_lightstage(args.rig, args.out, sequences=args.sequence,
                                    material=args.material, seed=args.seed, plan_path=args.plan,
                                    calibration=args.calibration, progress=bar,
                                    prompt=terminal_prompt())
    return _finish(result)


def run_resume(args: argparse.Namespace) -> int:
    with operator_output(), api.sigint_stops_motion(), step_bar("resume") as bar:
        result = api.resume_lightstage(args.session, progress=bar, prompt=terminal_prompt())
    return _finish(result)


def run_field(args: argparse.Namespace) -> int:
    out = Path(args.output or Path(args.session) / FIELD_DIR)
    paths = api.write_field(args.session, out)
    print(f"{out}: {len(paths)} EXRs (one per light)")
    return 0


def run_relight(args: argparse.Namespace) -> int:
    image = api.relight_files(args.field, args.env, args.output)
    print(f"{args.output}: {image.shape[1]} × {image.shape[0]} relit image")
    return 0
