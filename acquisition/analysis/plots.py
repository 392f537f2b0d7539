"""Plots of plans and BRDF tables (matplotlib with the Agg backend: no display needed).

matplotlib is imported on first use, so importing this module is cheap. Plots are PNG, PDF
or SVG files written through :func:`drivers.storage.atomic_output`; each carries the marker
:data:`PLOT_MARK` in its metadata, so a later plot may replace it and nothing else is
overwritten.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from acquisition.geometry.halfdiff import halfdiff_from_angles
from acquisition.planning.planner import Reason, Sweep
from acquisition.tables import IsotropicTable
from drivers.errors import ConfigError
from drivers.storage import atomic_output, ensure_folder

PLOT_MARK = "gonio:plot"
"""Written into every plot's metadata (PNG Software, PDF/SVG Creator)."""
PLOT_FORMATS = {".png": "png", ".pdf": "pdf", ".svg": "svg"}
WHAT = "plot"
_SIGNATURES = {"png": (b"\x89PNG", b"IEND"), "pdf": (b"%PDF", b"%%EOF"), "svg": (b"<?xml", b"</svg>")}


def is_plot(path: str | Path) -> bool:
    """True for a plot gonio wrote (it may be replaced)."""
    try:
        with open(path, "rb") as fh:
            return PLOT_MARK.encode() in fh.read(8 << 20)
    except OSError:
        return False


def plot_format(path: str | Path) -> str:
    """``png``, ``pdf`` or ``svg`` from the path's extension; :class:`ConfigError` otherwise."""
    fmt = PLOT_FORMATS.get(Path(path).suffix.lower())
    if fmt is None:
        raise ConfigError(f"plot {path}: unknown extension {Path(path).suffix or '(none)'!r}; "
                          "end the name in .png, .pdf or .svg")
    return fmt


def save_figure(fig: Any, path: str | Path, *, make_parents: bool = False) -> Path:
    """Save a matplotlib figure through the writer (format from the extension, verified)."""
    path = Path(path)
    fmt = plot_format(path)
    if make_parents:
        ensure_folder(path.parent, what="plot folder")
    head, tail = _SIGNATURES[fmt]

    def verify(tmp: Path) -> None:
        data = tmp.read_bytes()
        if not data.startswith(head) or tail not in data[-64:] or PLOT_MARK.encode() not in data:
            raise ValueError(f"not a whole {fmt.upper()} file")

    meta = {"Software" if fmt == "png" else "Creator": f"{PLOT_MARK} (matplotlib)"}
    with atomic_output(path, what=WHAT, verify=verify, ours=is_plot) as tmp:
        fig.savefig(tmp, dpi=110, format=fmt, metadata=meta)
    return path


def _pyplot() -> Any:
    """matplotlib.pyplot on the Agg backend (imported on first use: it takes ~0.5 s)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _in_plane(table: IsotropicTable, i: int) -> tuple[np.ndarray, np.ndarray]:
    """Signed θr (negative = same side as the light, Δφ≈0; positive = mirror side, Δφ≈180)
    and the green-channel value, for θi bin ``i``."""
    _, tr, dp = table.centers()
    j_back, j_fwd = int(np.argmin(np.abs(dp))), int(np.argmin(np.abs(dp - 180)))
    x = np.concatenate([-tr[::-1], tr])
    y = np.concatenate([table.mean[i, ::-1, j_back, 1], table.mean[i, :, j_fwd, 1]])
    return x, y


def plot_slices(
    measured: IsotropicTable, truth: IsotropicTable | None, path: str | Path, title: str = ""
) -> Path:
    """In-plane BRDF slices (measured points, truth lines) and measured-vs-truth scatter."""
    plot_format(path)
    plt = _pyplot()
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(12, 5))
    ti = measured.centers()[0]
    picks = np.unique(np.linspace(0, len(ti) - 1, min(5, len(ti))).round().astype(int))
    for n, i in enumerate(picks):
        colour = f"C{n}"
        x, y = _in_plane(measured, i)
        ax.plot(x, y, "o", color=colour, label=f"measured θi≈{ti[i]:.0f}°")
        if truth is not None:
            xt, yt = _in_plane(truth, i)
            ax.plot(xt, yt, "-", color=colour, alpha=0.7)
    ax.set_yscale("log")
    ax.set_xlabel("signed θr (°): − towards the light (Δφ=0), + mirror side (Δφ=180)")
    ax.set_ylabel("BRDF, green channel (sr⁻¹)")
    ax.set_title("In-plane slices (lines: simulated truth)")
    ax.legend(fontsize=8)
    if truth is not None:
        mask = (measured.count > 0) & (truth.count > 0)
        t, m = truth.mean[mask][:, 1], measured.mean[mask][:, 1]
        ax2.loglog(t, m, ".", ms=3)
        lo, hi = float(np.nanmin(t)), float(np.nanmax(t))
        ax2.plot([lo, hi], [lo, hi], "k-", lw=0.8)
        ax2.set_xlabel("truth (sr⁻¹)")
        ax2.set_ylabel("measured (sr⁻¹)")
        ax2.set_title(f"All {int(mask.sum())} measured bins")
    else:
        ax2.axis("off")
    fig.suptitle(title)
    fig.tight_layout()
    try:
        return save_figure(fig, path)
    finally:
        plt.close(fig)


REASON_COLOURS = {
    Reason.MAX_ELEVATION: "#bbbbbb",
    Reason.DUPLICATE: "#8c564b",
    Reason.UNREACHABLE: "#7f7f7f",
    Reason.JOINT_LIMITS: "#9467bd",
    Reason.ARM_COLLISION: "#d62728",
    Reason.UNROUTABLE: "#bcbd22",
    Reason.SHADOW: "#ff7f0e",
    Reason.FOOTPRINT: "#e377c2",
    Reason.RECIPROCAL: "#17becf",
}


def plot_sweep(sweep: Sweep, path: str | Path, title: str = "") -> Path:
    """Accepted and rejected poses on (θh, θd) and on the hemisphere (camera direction
    relative to the light: radius θr, angle Δφ), and every axis against the estimated time."""
    plot_format(path)
    plt = _pyplot()
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
    try:
        return save_figure(fig, path, make_parents=True)
    finally:
        plt.close(fig)
