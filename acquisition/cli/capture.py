"""``gonio capture``, ``gonio resume``, ``gonio reduce``: sessions and tables."""

from __future__ import annotations

import argparse
import sys

from tqdm import tqdm

from acquisition import api
from acquisition.cli.console import operator_output
from acquisition.cli.operator import terminal_prompt
from acquisition.cli.progress import StepBar, step_bar


def add_sim_fault_option(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--sim-fault", action="append", default=[], metavar="SPEC",
        help="inject a fault into the simulated servo bus (e.g. drop=0.05, overload:id=2,after=20)",
    )


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("capture", help="capture a plan on a rig into a new session folder")
    p.add_argument("--rig", required=True, help="rig file (TOML)")
    p.add_argument("--plan", required=True, help="plan file (TOML)")
    p.add_argument("--out", required=True, help="new session folder (must not exist)")
    p.add_argument("--material", help="material the simulated camera sees, e.g. lambert:albedo=0.5")
    p.add_argument("--seed", type=int, default=0, help="noise seed of the simulated devices")
    p.add_argument("--calibration", metavar="PATH",
                   help="calibration file or folder used; copied into the session")
    add_sim_fault_option(p)
    p.set_defaults(func=run_capture)

    p = sub.add_parser("resume", help="continue an interrupted session")
    p.add_argument("session", help="session folder")
    add_sim_fault_option(p)
    p.set_defaults(func=run_resume)

    p = sub.add_parser("reduce", help="linearize a session's frames into a BRDF table (HDF5)")
    p.add_argument("session", help="session folder")
    p.add_argument("-o", "--output", help="table file (default: SESSION/brdf.h5)")
    p.set_defaults(func=run_reduce)


def estimate_line(summary: dict[str, object]) -> str:
    """One line from a sweep's summary: poses, rejections by reason, estimated rig time."""
    counts = summary["rejected"]
    rejected = ", ".join(f"{n} {r}" for r, n in counts.items()) or "none"  # type: ignore[union-attr]
    minutes = float(summary["estimated_s"]) / 60  # type: ignore[arg-type]
    return (f"{summary['poses']} poses planned (rejected: {rejected}); "
            f"estimated {minutes:.1f} min of rig time")


def print_estimate(sweep: api.Sweep) -> None:
    print(estimate_line(sweep.summary()))


def _finish(result: api.CaptureResult) -> int:
    counts = result.counts
    device = f" in {result.device_seconds:.1f} s of rig time" if result.device_seconds else ""
    print(f"session {result.session.path}: {counts.get('done', 0)} steps done{device}")
    return 0


def eta_from_time_model(bar: StepBar, announce: bool = False) -> api.OnOpen:
    """``on_open`` hook: the bar's ETA from the planner's per-step predictions; with
    ``announce``, first print the plan's estimate (the devices are open, nothing has moved)."""
    def start(folder: api.SessionFolder, _device_time_s: float | None) -> None:
        bar.start_eta(api.step_durations(folder))
        if announce:
            with folder.journal() as journal:
                summary = journal.meta("estimate")
            if summary:
                tqdm.write(estimate_line(summary), file=sys.stdout)
    return start


def run_capture(args: argparse.Namespace) -> int:
    with operator_output(), api.sigint_stops_motion(), step_bar("capture") as bar:
        result = api.capture(args.rig, args.plan, args.out, material=args.material,
                             seed=args.seed, sim_faults=args.sim_fault, progress=bar,
                             calibration=args.calibration,
                             on_open=eta_from_time_model(bar, announce=True),
                             prompt=terminal_prompt())
    return _finish(result)


def run_resume(args: argparse.Namespace) -> int:
    with operator_output(), api.sigint_stops_motion(), step_bar("resume") as bar:
        result = api.resume(args.session, sim_faults=args.sim_fault, progress=bar,
                            on_open=eta_from_time_model(bar), prompt=terminal_prompt())
    return _finish(result)


def run_reduce(args: argparse.Namespace) -> int:
    with step_bar("reduce", unit="frame") as bar:
        result = api.reduce(args.session, args.output, progress=lambda d, t: bar(d, t))
    out = args.output or f"{args.session}/brdf.h5"
    measured = int((result.table.count > 0).sum())
    print(f"{out}: {result.frames} frames → {measured} measured bins; "
          f"white reference drift {result.drift_pct:.2f} %")
    return 0
