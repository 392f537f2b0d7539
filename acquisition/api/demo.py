"""``gonio demo``: capture on the simulated rig, reduce, plot against the truth, write the
HTML report, summarise."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from acquisition.analysis.plots import plot_slices
from acquisition.api import sessions as api
from acquisition.api.truth import relative_errors, truth_table

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


@dataclass
class DemoResult:
    session: Path
    table: Path
    plot: Path
    poses: int
    measured_bins: int
    host_minutes: float
    rig_minutes: float | None
    estimated_minutes: float
    median_rel_error: float
    peak_pose: tuple[float, float, float]
    report: Path | None = None
    """The HTML report (fits, checks, figures) of the demo's table."""


def run_demo(
    out_root: str | Path = "demo-output",
    *,
    material: str = api.DEFAULT_MATERIAL,
    rig: str | Path = EXAMPLES / "rig-sim.toml",
    plan: str | Path = EXAMPLES / "plan-demo.toml",
    seed: int = 1,
    progress: api.Progress | None = None,
    on_open: api.OnOpen | None = None,
) -> DemoResult:
    """Run the whole pipeline on the simulated rig into a new folder under ``out_root``
    (``progress``, ``on_open``: see :func:`acquisition.api.capture`)."""
    t0 = time.monotonic()
    session = Path(out_root) / time.strftime("session-%Y%m%d-%H%M%S")
    result = api.capture(rig, plan, session, material=material, seed=seed, progress=progress,
                         on_open=on_open, reduce=True)  # the table streamed beside the capture
    with result.session.journal(readonly=True) as journal:
        estimate = float(journal.meta("estimate")["estimated_s"])
    streamed = result.streamed or {}
    if not streamed.get("table"):
        from acquisition.api.streaming import StreamingError

        raise StreamingError(f"the demo's streaming reduction failed: {streamed.get('error')}")
    from acquisition.api.analysis import open_table, report  # heavy (scipy, matplotlib)

    table = open_table(Path(str(streamed["table"])))
    truth = truth_table(result.session)
    plot = plot_slices(table, truth, session / "brdf-slices.png", title=f"gonio demo — {material}")

    html = report(session, session / "report.html", table=table).path
    g = np.where(table.count > 0, table.mean[..., 1], -np.inf)
    i, j, k = np.unravel_index(int(np.argmax(g)), g.shape)
    centers = table.centers()
    return DemoResult(
        session=session,
        table=session / "brdf.h5",
        plot=plot,
        poses=result.counts.get("done", 0),
        measured_bins=int((table.count > 0).sum()),
        host_minutes=(time.monotonic() - t0) / 60,
        rig_minutes=None if result.device_seconds is None else result.device_seconds / 60,
        estimated_minutes=estimate / 60,
        median_rel_error=float(np.median(relative_errors(table, truth))),
        peak_pose=(float(centers[0][i]), float(centers[1][j]), float(centers[2][k])),
        report=html,
    )
