"""``gonio lightstage capture|resume|field`` and ``gonio relight``: light-stage sessions."""

from __future__ import annotations

import argparse
from pathlib import Path

from acquisition import api
from acquisition.cli.capture import eta_from_time_model
from acquisition.cli.operator import operator_output, terminal_prompt
from acquisition.cli.options import add_json, add_out, add_seed, report
from acquisition.cli.progress import say, step_bar


def _sequences(text: str) -> list[str]:
    names = [s.strip() for s in text.split(",") if s.strip()]
    bad = [n for n in names if n not in api.SEQUENCES]
    if not names or bad:
        raise argparse.ArgumentTypeError(
            f"unknown sequence '{(bad or [text])[0]}' (known: {', '.join(api.SEQUENCES)})")
    return names


COMMANDS = {
    "lightstage": "capture on a light stage (LED dome over DMX)",
    "relight": "relight a reflectance field with a lat-long environment map",
}


def register(sub: argparse._SubParsersAction) -> None:
    stage = sub.add_parser("lightstage", help=COMMANDS["lightstage"])
    cmds = stage.add_subparsers(dest="lightstage_command", metavar="COMMAND")
    cmds.required = True

    p = cmds.add_parser("capture", help="capture a light-stage sequence into a new session folder")
    p.add_argument("--rig", required=True, help="light-stage rig file (TOML)")
    add_out(p, "new session folder (must not exist)", required=True)
    p.add_argument("--sequence", type=_sequences, default=["olat"], metavar="NAMES",
                   help=f"comma-separated sequences on the sample ({', '.join(api.SEQUENCES)}); "
                        "default olat")
    p.add_argument("--material", help="material the simulated camera sees, e.g. ggx:alpha=0.3")
    add_seed(p)
    p.add_argument("--plan", help="plan file giving table bins and exposure (default: built in)")
    p.add_argument("--calibration", metavar="PATH",
                   help="calibration file or folder used; copied into the session")
    add_json(p)
    p.set_defaults(func=run_capture)

    p = cmds.add_parser("resume", help="continue an interrupted light-stage session")
    p.add_argument("session", help="session folder")
    add_json(p)
    p.set_defaults(func=run_resume)

    p = cmds.add_parser("field", help="write a session's calibrated reflectance field (EXRs)")
    p.add_argument("session", help="session folder")
    add_out(p, f"folder for the EXRs (default: SESSION/{api.FIELD_DIR})", aliases=("--output",))
    add_json(p)
    p.set_defaults(func=run_field)

    p = sub.add_parser("relight", help=COMMANDS["relight"])
    p.add_argument("field", help="reflectance-field folder (light-*.exr)")
    p.add_argument("--env", required=True, help="lat-long environment map (EXR, linear)")
    add_out(p, "relit image (EXR)", required=True, aliases=("--output",))
    add_json(p)
    p.set_defaults(func=run_relight)


def _estimate_line(est: api.TimeEstimate) -> str:
    return (f"{est.frames} frames, {est.light_changes} light changes; estimated "
            f"{est.total_s:.1f} s of rig time ({est.dmx_s:.1f} s DMX and settle, "
            f"{est.exposure_s:.1f} s exposure)")


def _finish(args: argparse.Namespace, result: api.LightStageResult,
            estimate: api.TimeEstimate | None = None) -> int:
    done = result.counts.get("done", 0)
    rig_time = f" in {result.device_seconds:.1f} s of rig time" if result.device_seconds else ""
    lines = [f"session {result.session.path}: {done} steps done{rig_time}"]
    payload: dict[str, object] = {"session": result.session.path, "counts": result.counts,
                                  "device_seconds": result.device_seconds}
    if estimate is not None:
        payload["estimate"] = estimate
    if result.field is not None:
        folder = result.session.path / api.FIELD_DIR
        lines.append(f"reflectance field: {len(result.field)} EXRs in {folder}")
        payload["field"] = {"folder": folder, "images": len(result.field)}
    report(args, payload, lines)
    return 0


def run_capture(args: argparse.Namespace) -> int:
    estimate = api.plan_lightstage(args.rig, args.sequence)
    if not args.json:
        say(_estimate_line(estimate))
    with operator_output(), api.sigint_stops_motion(first_message=api.LIGHTS_MESSAGE), \
            step_bar("capture") as bar:
        result = api.capture_lightstage(args.rig, args.out, sequences=args.sequence,
                                        material=args.material, seed=args.seed,
                                        plan_path=args.plan, calibration=args.calibration,
                                        progress=bar, prompt=terminal_prompt(),
                                        on_open=eta_from_time_model(bar, args, announce=False))
    return _finish(args, result, estimate)


def run_resume(args: argparse.Namespace) -> int:
    with operator_output(), api.sigint_stops_motion(first_message=api.LIGHTS_MESSAGE), \
            step_bar("resume") as bar:
        result = api.resume_lightstage(args.session, progress=bar, prompt=terminal_prompt(),
                                       on_open=eta_from_time_model(bar, args, resumed=True))
    return _finish(args, result)


def run_field(args: argparse.Namespace) -> int:
    out = Path(args.out or Path(args.session) / api.FIELD_DIR)
    paths = api.write_field(args.session, out)
    report(args, {"folder": out, "images": len(paths)}, [f"{out}: {len(paths)} EXRs (one per light)"])
    return 0


def run_relight(args: argparse.Namespace) -> int:
    image = api.relight_files(args.field, args.env, args.out)
    report(args, {"out": args.out, "width": image.shape[1], "height": image.shape[0]},
           [f"{args.out}: {image.shape[1]} × {image.shape[0]} relit image"])
    return 0
