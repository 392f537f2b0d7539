"""``gonio capture``, ``gonio resume``, ``gonio reduce``: sessions and tables."""

from __future__ import annotations

import argparse
from pathlib import Path

from acquisition import api
from acquisition.cli.operator import operator_output, terminal_prompt
from acquisition.cli.options import add_json, add_out, add_seed, add_sim_fault, report
from acquisition.cli.progress import StepBar, say, step_bar

COMMANDS = {
    "capture": "capture a plan on a rig into a new session folder",
    "resume": "continue an interrupted session",
    "reduce": "linearize sessions' frames into BRDF tables (HDF5), here or on a Dask cluster",
}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("capture", help=COMMANDS["capture"])
    p.add_argument("--rig", required=True, help="rig file (TOML)")
    p.add_argument("--plan", required=True, help="plan file (TOML)")
    add_out(p, "new session folder (must not exist)", required=True)
    p.add_argument("--material", help="material the simulated camera sees, e.g. lambert:albedo=0.5")
    add_seed(p)
    p.add_argument("--calibration", metavar="PATH",
                   help="calibration file or folder used; copied into the session")
    add_sim_fault(p)
    _add_no_reduce(p)
    add_json(p)
    p.set_defaults(func=run_capture)

    p = sub.add_parser("resume", help=COMMANDS["resume"])
    p.add_argument("session", help="session folder")
    add_sim_fault(p)
    _add_no_reduce(p)
    add_json(p)
    p.set_defaults(func=run_resume)

    p = sub.add_parser("reduce", help=COMMANDS["reduce"])
    p.add_argument("session", nargs="+", help="session folder(s)")
    add_out(p, "table file (default: SESSION/brdf.h5); with several sessions a folder, each "
               "table FOLDER/SESSION_NAME.h5 (default: each SESSION/brdf.h5)",
            aliases=("--output",))
    where = p.add_mutually_exclusive_group()
    where.add_argument("--workers", type=_workers, metavar="N",
                       help="reduce on a local Dask cluster of N worker processes "
                            "(pip install 'gonio[distributed]')")
    where.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                       help="reduce on a running Dask cluster whose workers see the sessions at "
                            "the same paths")
    p.add_argument("--calibration", metavar="BUNDLE",
                   help="calibration bundle to apply (default: the session's own copy)")
    p.add_argument("--follow", action="store_true",
                   help="reduce the frames of a capture running in another process as they "
                        "land; write the table when it ends (one session, here)")
    p.add_argument("--checkpoint-every", type=_frames, default=api.CHECKPOINT_EVERY, metavar="N",
                   help="image-based sessions reduced here (not on a cluster): save the "
                        "partial tables beside the table every N frames, to resume after an "
                        f"interruption (0: only at the end; default {api.CHECKPOINT_EVERY})")
    add_json(p)
    p.set_defaults(func=run_reduce)


def _add_no_reduce(p: argparse.ArgumentParser) -> None:
    p.add_argument("--no-reduce", dest="reduce", action="store_false",
                   help="do not reduce the frames as they land (by default a worker process "
                        "beside the capture does, into SESSION/brdf.h5)")


def _workers(text: str) -> int:
    """A number of worker processes ≥ 1 (argparse type)."""
    return _count(text, 1, "workers")


def _frames(text: str) -> int:
    """A number of frames ≥ 0 (argparse type)."""
    return _count(text, 0, "frames")


def _count(text: str, least: int, what: str) -> int:
    """A whole number of ``what`` ≥ ``least`` (argparse type)."""
    try:
        n = int(text)
    except ValueError:
        n = least - 1
    if n < least:
        raise argparse.ArgumentTypeError(f"expected a number of {what} ≥ {least}, got {text!r}")
    return n


def estimate_line(summary: dict[str, object]) -> str:
    """One line from a sweep's summary: poses, rejections by reason, estimated rig time."""
    counts = summary["rejected"]
    rejected = ", ".join(f"{n} {r}" for r, n in counts.items()) or "none"  # type: ignore[union-attr]
    minutes = float(summary["estimated_s"]) / 60  # type: ignore[arg-type]
    return (f"{summary['poses']} poses planned (rejected: {rejected}); "
            f"estimated {minutes:.1f} min of rig time")


def remaining_line(predicted: dict[int, float]) -> str:
    """What a resumed run has left: steps and their predicted rig time."""
    return (f"{len(predicted)} steps left; estimated {sum(predicted.values()) / 60:.1f} min "
            "of rig time")


def _report(args: argparse.Namespace, result: api.CaptureResult) -> int:
    counts = result.counts
    device = (f"; this run took {result.device_seconds:.1f} s of rig time"
              if result.device_seconds else "")  # a resumed run's own time, not the session's
    payload = {"session": result.session.path, "counts": counts,
               "device_seconds": result.device_seconds}
    lines = [f"session {result.session.path}: {counts.get('done', 0)} steps done{device}"]
    streamed = getattr(result, "streamed", None)
    if streamed is not None:
        payload["streamed"] = streamed
        if streamed.get("error"):
            raise api.StreamingError(f"{streamed['error']} (the frames are safe: reduce them "
                                     f"with `gonio reduce {result.session.path}`)")
        if streamed.get("table"):
            lines.append(f"table {streamed['table']}: {streamed['frames']} frames reduced "
                         "while capturing")
    field = getattr(result, "field", None)  # a light-stage session's reflectance field
    if field is not None:
        payload["field"] = {"folder": result.session.path / api.FIELD_DIR, "images": len(field)}
        lines.append(f"reflectance field: {len(field)} EXRs in {result.session.path / api.FIELD_DIR}")
    report(args, payload, lines)
    return 0


def eta_from_time_model(bar: StepBar, args: argparse.Namespace, *,
                        resumed: bool = False, announce: bool = True) -> api.OnOpen:
    """``on_open`` hook: the bar's ETA from the per-step predictions of
    :func:`acquisition.api.step_durations` (the planner's time model; a light stage's
    sequence estimate), and (the devices are open, nothing has moved yet) the plan's
    estimate, or for a resumed run what is left of it, unless ``--json`` or not
    ``announce``."""
    def start(folder: api.SessionFolder, _device_time_s: float | None) -> None:
        predicted = api.step_durations(folder)
        bar.start_eta(predicted)
        if getattr(args, "json", False) or not announce:
            return
        if resumed:
            say(remaining_line(predicted))
            return
        with folder.journal(readonly=True) as journal:
            summary = journal.meta("estimate")
        if summary:
            say(estimate_line(summary))
    return start


def run_capture(args: argparse.Namespace) -> int:
    with operator_output(), api.sigint_stops_motion(), step_bar("capture") as bar:
        result = api.capture(args.rig, args.plan, args.out, material=args.material,
                             seed=args.seed, sim_faults=args.sim_fault, progress=bar,
                             calibration=args.calibration,
                             on_open=eta_from_time_model(bar, args), prompt=terminal_prompt(),
                             reduce=args.reduce)
    return _report(args, result)


def run_resume(args: argparse.Namespace) -> int:
    lights = api.is_lightstage_session(args.session)
    notice = api.LIGHTS_MESSAGE if lights else api.FIRST_MESSAGE
    with operator_output(), api.sigint_stops_motion(first_message=notice), \
            step_bar("resume") as bar:
        result = api.resume(args.session, sim_faults=args.sim_fault, progress=bar,
                            on_open=eta_from_time_model(bar, args, resumed=True),
                            prompt=terminal_prompt(), reduce=args.reduce and not lights)
    return _report(args, result)


def run_reduce(args: argparse.Namespace) -> int:
    if args.follow:
        return _follow(args)
    with step_bar("reduce", unit="frame") as bar:
        results = api.reduce_many(args.session, args.out, progress=lambda d, t: bar(d, t),
                                  calibration=args.calibration,
                                  checkpoint_every=args.checkpoint_every, workers=args.workers,
                                  scheduler=args.scheduler)
    outs = api.table_paths(args.session, args.out)
    reports = [_reduce_report(out, result) for out, result in zip(outs, results, strict=True)]
    payload = reports[0][0] if len(reports) == 1 else {"tables": [r[0] for r in reports]}
    report(args, payload, [line for _, lines in reports for line in lines])
    return 0


def _follow(args: argparse.Namespace) -> int:
    """``gonio reduce --follow SESSION``: one session, on this host."""
    if len(args.session) != 1 or args.workers or args.scheduler:
        raise api.StreamingError("--follow reduces one session on this host: give one session "
                                 "folder and no --workers/--scheduler")
    with step_bar("reduce", unit="frame") as bar:
        res = api.follow_session(args.session[0], args.out, calibration=args.calibration,
                                 checkpoint_every=args.checkpoint_every,
                                 progress=lambda d, t: bar(d, t))
    out = res.table if res.table is not None else Path(args.session[0])
    payload, lines = _reduce_report(out, res.reduction)  # type: ignore[arg-type]
    if res.pending:
        lines.append(f"the capture stopped with {res.pending} steps left: `gonio resume "
                     f"{args.session[0]}` continues it")
    report(args, {**payload, "pending": res.pending}, lines)
    return 0


SCATTER_HINT_ABOVE = 3.0
SCATTER_HINT = (" (more than noise: the BRDF changes across those bins, whose samples lie at "
                "different angles; narrower bins show less)")
"""Said after a repeats' scatter ratio above :data:`SCATTER_HINT_ABOVE`: a dense plan puts
several poses in a bin, and near a specular peak their values differ by far more than noise."""


def _reduce_report(out: Path, result: api.Reduction) -> tuple[dict[str, object], list[str]]:
    """One reduced table's JSON object and text lines."""
    table = result.table
    measured = int((table.count > 0).sum())
    rel = api.median_relative_uncertainty(table)
    ratio, repeats = table.scatter
    drift = (f"white reference drift {result.drift_pct:.2f} %" if result.references != 1
             else "white reference drift not measured (one reference frame)")
    lines = [f"{out}: {result.frames} frames → {measured} measured bins; {drift}"]
    resumed = getattr(result, "resumed_frames", 0)
    if resumed:
        lines.insert(0, f"resumed: {resumed} frames from the checkpoint of an interrupted run")
    if table.tracks_uncertainty:
        lines.append(f"uncertainty: median {rel:.3g} % per bin (noise model: "
                     f"{table.provenance.get('noise_model', 'unknown')})"
                     + (f"; repeats scatter {ratio:.2f}× the noise prediction over {repeats} "
                        f"bins{SCATTER_HINT if ratio > SCATTER_HINT_ABOVE else ''}"
                        if repeats else ""))
    return ({"table": out, "frames": result.frames, "measured_bins": measured,
             "references": result.references, "drift_pct": result.drift_pct,
             "median_rel_uncertainty_pct": rel,
             "noise_model": table.provenance.get("noise_model"),
             "scatter_ratio": ratio, "scatter_bins": repeats,
             "resumed_frames": resumed}, lines)
