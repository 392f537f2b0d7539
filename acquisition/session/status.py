"""``gonio info``: progress, timing, errors and white-reference drift of a session folder."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from acquisition.session.folder import SessionFolder
from acquisition.session.runlock import capture_running
from acquisition.session.steps import (
    REFERENCE,
)
from acquisition.session.verify import verify_session
from calibration.signal import roi_signal

if TYPE_CHECKING:
    pass


# ---------------------------------------------------------------------------- gonio info
DEFAULT_TABLE = "brdf.h5"
"""The session's own table (``gonio reduce``'s default output, a streaming capture's table)."""
LIVE_TABLE_SUFFIX = ".live.h5"
"""A streaming reduction's table of the frames reduced so far: ``brdf.live.h5``."""


def live_table_path(table_path: str | Path) -> Path:
    """Where a followed capture's table of the frames reduced so far goes: ``NAME.live.h5``
    beside ``NAME.h5`` (rewritten while the capture runs, deleted with the final table)."""
    path = Path(table_path)
    return path.with_name(path.stem + LIVE_TABLE_SUFFIX)
PLANNED_STEPS_META = "planned_steps"
"""Journal meta of a session whose steps are journaled as they are reached (a light stage):
how many journal steps its whole sequence has."""
LINK_STATS_META = "link_stats"
"""Journal meta: per run, ``{axis: {"requests", "retries", "resends"}}`` of its servo bus."""
LIGHTSTAGE_META = "lightstage"
"""Journal meta of a light-stage session: its sequences, white and dark frames (what
:mod:`acquisition.lightstage.capture` journals; a reduction tells the session's kind by it)."""


def summed_link_stats(runs: list[dict[str, dict[str, int]]]) -> dict[str, dict[str, int]]:
    """Per axis, the requests, retries and resends of every run added up."""
    out: dict[str, dict[str, int]] = {}
    for run in runs:
        for axis, s in run.items():
            acc = out.setdefault(axis, {"requests": 0, "retries": 0, "resends": 0})
            for k in acc:
                acc[k] += int(s.get(k, 0))
    return out


@dataclass(frozen=True)
class SessionStatus:
    """What ``gonio info DIR`` prints: progress, timing, errors, white-reference drift."""

    folder: SessionFolder
    counts: dict[str, int]
    by_kind: dict[str, tuple[int, int]]
    """kind → (done, total)."""
    host_busy_s: float
    """Sum over done steps of host time from start to completion, s."""
    host_span_s: float | None
    """Host time from the first step started to the last completed, s."""
    device_s: float | None
    """Device-clock time over all runs (simulated rigs), s."""
    runs: int
    retakes: int
    """Steps taken more than once (crash, hash mismatch, interrupted)."""
    events: list[tuple[float, str, int | None, str]]
    """Warnings and errors from the journal: (host time, level, step, message)."""
    drift_pct: float | None
    """Peak-to-peak change of the white reference's ROI signal, % of its mean."""
    link: dict[str, dict[str, int]] = field(default_factory=dict)
    """Per axis over all runs: requests, retries and goal resends on its servo bus."""
    bad_frames: list[str] = field(default_factory=list)
    """Done frames missing or failing their SHA-256 (counted as errors); empty unchecked."""
    capturing: bool = False
    """A process captures the session now (:func:`~acquisition.session.runlock.capture_running`)."""
    tables: list[str] = field(default_factory=list)
    """Table files in the folder: ``brdf.h5``, and ``brdf.live.h5`` while a streaming
    reduction follows the capture (the frames reduced so far)."""

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    @property
    def done(self) -> int:
        return self.counts.get("done", 0)

    def to_json(self) -> dict[str, Any]:
        """The status as plain JSON types (``gonio info --json``)."""
        return {
            "session": str(self.folder.path), "info": self.folder.info.to_json(),
            "counts": self.counts, "total": self.total, "done": self.done,
            "by_kind": {k: {"done": d, "total": n} for k, (d, n) in self.by_kind.items()},
            "host_busy_s": self.host_busy_s, "host_span_s": self.host_span_s,
            "device_s": self.device_s, "runs": self.runs, "retakes": self.retakes,
            "events": [{"at": at, "level": lv, "step": st, "message": msg}
                       for at, lv, st, msg in self.events],
            "drift_pct": self.drift_pct,
            "link": self.link,
            "bad_frames": self.bad_frames,
            "capturing": self.capturing,
            "tables": self.tables,
        }

    def lines(self, max_events: int = 10) -> list[str]:
        info = self.folder.info
        pct = 100.0 * self.done / self.total if self.total else 0.0
        out = [
            f"session   {self.folder.path}  (rig '{info.rig_name}', plan '{info.plan_name}', "
            f"material {info.material}, seed {info.seed})",
            f"progress  {self.done}/{self.total} steps done ({pct:.0f} %)"
            + "".join(f"; {k} {d}/{t}" for k, (d, t) in self.by_kind.items()),
        ]
        if self.capturing:
            out.append("          being captured now (by another process)")
        elif self.done < self.total:
            out.append(f"          {self.total - self.done} to do: `gonio resume {self.folder.path}`")
        for name in self.tables:
            what = "the frames reduced so far" if name.endswith(LIVE_TABLE_SUFFIX) else "reduced"
            out.append(f"table     {self.folder.path / name} ({what})")
        timing = f"timing    host {self.host_busy_s:.1f} s busy"
        if self.host_span_s is not None:
            timing += f" over {self.host_span_s:.1f} s"
        if self.device_s is not None:
            timing += f"; device clock {self.device_s:.1f} s"
        if info.estimated_s:
            timing += f" (planned {info.estimated_s:.1f} s)"
        timing += f"; {self.runs} run(s), {self.retakes} step(s) retaken"
        out.append(timing)
        if self.drift_pct is not None:
            out.append(f"drift     white reference {self.drift_pct:.2f} % peak to peak")
        if info.calibration:
            out.append(f"calib     {self.folder.path / info.calibration}")
        for i, (axis, s) in enumerate(self.link.items()):
            pct = 100.0 * s["retries"] / s["requests"] if s["requests"] else 0.0
            out.append(f"{'bus' if i == 0 else '':10s}{axis}: {s['requests']} requests, "
                       f"{s['retries']} retries ({pct:.1f} %), {s['resends']} resends")
        shown = self.events[-max_events:]
        if self.bad_frames:
            out.append(f"frames    {len(self.bad_frames)} bad (missing or failing their SHA-256: "
                       f"{', '.join(self.bad_frames[:5])}): `gonio resume {self.folder.path}` "
                       "retakes them")
        out.append(f"errors    {len(self.events) + len(self.bad_frames)} error/warning(s): "
                   f"{len(self.bad_frames)} bad frame(s), {len(self.events)} event(s)"
                   + (f", last {len(shown)}:" if shown else ""))
        for at, level, step, msg in shown:
            stamp = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(at))
            where = f" step {step}" if step is not None else ""
            out.append(f"  {stamp} {level}{where}: {msg}")
        return out


def session_status(path: str | Path, *, drift: bool = True, verify: bool = True
                   ) -> SessionStatus:
    """Read a session folder (also while a capture writes it) into a :class:`SessionStatus`."""
    folder = SessionFolder(path)
    with folder.journal(readonly=True) as journal:
        records = list(journal.steps())
        counts = journal.counts()
        all_events = journal.events()
        link = summed_link_stats(journal.meta(LINK_STATS_META, []))
        planned = int(journal.meta(PLANNED_STEPS_META, 0) or 0)
    if planned > len(records):  # steps of the sequence not reached yet
        counts = {**counts, "planned": counts.get("planned", 0) + planned - len(records)}
    by_kind: dict[str, tuple[int, int]] = {}
    for r in records:
        d, t = by_kind.get(r.kind, (0, 0))
        by_kind[r.kind] = (d + (r.status == "done"), t + 1)
    done = [r for r in records if r.status == "done" and r.completed_at is not None]
    busy = sum(r.completed_at - r.started_at for r in done
               if r.completed_at is not None and r.started_at is not None)
    starts = [r.started_at for r in records if r.started_at is not None]
    ends = [r.completed_at for r in done if r.completed_at is not None]
    span = max(ends) - min(starts) if starts and ends else None
    # The device clock restarts with each run: sum the rises between completions.
    device = None
    times = [r.device_time_s for r in sorted(done, key=lambda r: r.completed_at or 0.0)
             if r.device_time_s is not None]
    if times:
        device = times[0] + sum(b - a if b >= a else b for a, b in zip(times, times[1:], strict=False))
    bad: list[str] = []
    if verify:
        report = verify_session(folder.path)
        bad = report.missing + report.mismatched
    drift_pct = None
    refs = [r for r in done if r.kind == REFERENCE and r.frame]
    # Drift compares like with like: references taken with the first one's joints (a light
    # stage's per-LED white frames are lit by different lights).
    refs = [r for r in refs if r.joints_cmd == refs[0].joints_cmd] if refs else refs
    refs = [r for r in refs if str(r.frame) not in bad]  # a damaged frame says nothing of drift
    if drift and len(refs) >= 2:
        roi = folder.rig().camera.roi
        sig = np.array([roi_signal(folder.frames_dir / str(r.frame), roi)[0] for r in refs])
        drift_pct = float(np.max(np.ptp(sig, axis=0) / np.mean(sig, axis=0)) * 100.0)
    return SessionStatus(
        folder, counts, by_kind, busy, span, device,
        sum(1 for e in all_events if e[3].startswith("run started")),
        sum(1 for r in records if r.attempts > 1),
        [e for e in all_events if e[1] in ("warning", "error")], drift_pct, link, bad,
        capture_running(folder.path),
        [n for n in (DEFAULT_TABLE, live_table_path(DEFAULT_TABLE).name)
         if (folder.path / n).is_file()],
    )
