"""``gonio plan``: check and time a plan on a rig without moving anything."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from acquisition import api
from acquisition.cli.capture import print_estimate
from acquisition.geometry.halfdiff import halfdiff_from_angles
from acquisition.planning.planner import Reason, Sweep


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
        path = plot_sweep(sweep, args.plot, title=Path(args.plan).stem)
        if not args.json:
            print(f"plot written to {path}")
    return 0


REASON_COLOURS = {
    Reason.MAX_ELEVATION: "#bbbbbb",
    Reason.DUPLICATE: "#8c564b",
    Reason.UNREACHABLE: "#7f7f7f",
    Reason.JOINT_LIMITS: "#9467bd",
    Reason.ARM_COLLISION: "#d62728",
    Reason.SHADOW: "#ff7f0e",
    Reason.FOOTPRINT: "#e377c2",
    Reason.RECIPROCAL: "#17becf",
}


def plot_sweep(sweep: Sweep, path: str | Path, title: str = "") -> Path:
    """Accepted and rejected poses on (θh, θd) and on the hemisphere (camera direction
    relative to the light: radius θr, angle Δφ), and every axis against the estimated time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    fig = plt.figure(figsize=(13, 9))
    ax_hd = fig.add_subplot(2, 2, 1)
    ax_hemi = fig.add_subplot(2, 2, 2, projection="polar")
    ax_t = fig.add_subplot(2, 1, 2)

    def draw(rows: np.ndarray, colour: str, label: str, size: float) -> None:
        if not len(rows):
            return
        th, td, _ = halfdiff_from_angles(rows[:, 0], rows[:, 1], rows[:, 2])
        ax_hd.scatter(th, td, s=size, c=colour, label=label, linewidths=0)
        ax_hemi.scatter(np.radians(rows[:, 2]), rows[:, 1], s=size, c=colour, linewidths=0)

    by_reason: dict[Reason, list[tuple[float, float, float]]] = {}
    for r in sweep.rejected:
        by_reason.setdefault(r.reason, []).append(r.pose.as_tuple())
    for reason, rows in by_reason.items():
        draw(np.array(rows), REASON_COLOURS.get(reason, "#444444"), f"{reason.value} ({len(rows)})", 4)
    accepted = np.array([s.pose.as_tuple() for s in sweep.steps]).reshape(-1, 3)
    draw(accepted, "#1f77b4", f"planned ({len(accepted)})", 6)
    ax_hd.set_xlabel("θh (deg)")
    ax_hd.set_ylabel("θd (deg)")
    ax_hd.set_xlim(0, 90)
    ax_hd.set_ylim(0, 90)
    ax_hd.set_title("half/difference angles")
    ax_hd.legend(fontsize=7, markerscale=2, loc="upper right")
    ax_hemi.set_rmax(90)
    ax_hemi.set_title("camera relative to the light (r = θr, angle = Δφ)", fontsize=9)

    # Timeline: each axis's target, held from the end of its move to the end of the step.
    overhead = sweep.overhead_s / max(len(sweep.steps), 1)
    t, times = 0.0, []
    for step in sweep.steps:
        t += step.move_s
        times.append(t)
        t += overhead
    names = list(sweep.start_joints)
    for name in names:
        values = [sweep.start_joints[name]] + [s.joints[name] for s in sweep.steps]
        ax_t.step([0.0, *times], values, where="post", lw=0.8, label=name)
    ax_t.set_xlabel("estimated time (s)")
    ax_t.set_ylabel("joint (deg)")
    ax_t.legend(fontsize=8, loc="upper right")
    ax_t.set_title(
        f"motion {sweep.motion_s:.0f} s (naive {sweep.naive_motion_s:.0f} s, lower bound "
        f"{sweep.lower_bound_motion_s:.0f} s); total estimate {sweep.estimated_s:.0f} s"
    )
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
