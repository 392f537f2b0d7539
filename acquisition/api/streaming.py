"""Reduce a session while it is captured: ``gonio reduce --follow`` and the capture's own
streaming worker.

:func:`follow_session` reduces the frames of a session as the journal marks them done
(:mod:`acquisition.reduction.stream`) for as long as a process holds the session's capture
lock (:mod:`acquisition.session.runlock`), then writes the table: the one ``gonio reduce``
gives of the same frames, bit for bit. Started before or after the capture, in the capturing
process's host or beside it, it needs nothing from the capture but its folder.

A capture with ``reduce=True`` (``gonio capture`` without ``--no-reduce``) runs
:func:`follow_session` in a worker process (:class:`StreamingWorker`): frames are
decoded on another core and never hold up a move (the capture's process does not even share
its interpreter lock with the reduction). When the run stops before its end (an error,
Ctrl-C, SIGKILL), the worker keeps its checkpoint and writes no table; the resumed capture's
worker continues from that checkpoint.

Followers of one output take turns (an exclusive ``flock`` on the output's checkpoint path's
folder), so a worker orphaned by a killed capture finishes its checkpoint before the resumed
capture's worker reads it.
"""

from __future__ import annotations

import fcntl
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from pathlib import Path

from acquisition.reduction import CHECKPOINT_EVERY
from acquisition.reduction.checkpoint import checkpoint_path, write_table
from acquisition.reduction.point import Reduction
from acquisition.reduction.stream import ImageStream, JournalView, PointStream, follow, open_stream
from acquisition.session.folder import SessionFolder
from acquisition.session.runlock import capture_running
from acquisition.session.status import DEFAULT_TABLE, live_table_path
from acquisition.tables.isotropic import WHAT as TABLE_WHAT
from acquisition.tables.isotropic import is_table_file
from drivers.errors import GonioError, SessionError
from drivers.storage import check_output, ensure_folder

POLL_S = 0.2
"""Host seconds between two reads of the journal while the capture runs."""
SNAPSHOT_S = 10.0
"""Host seconds between two partial tables written while the capture runs."""


class StreamingError(SessionError):
    """A streaming reduction could not run or failed (the capture's frames are safe)."""


@dataclass
class FollowResult:
    """How a followed capture ended for its table."""

    table: Path | None
    """The table written (None: the capture stopped early and ``incomplete=False``)."""
    reduction: Reduction | None
    pending: int
    """Journal rows the capture left not done."""
    frames: int
    """Sample frames in the table written (as ``gonio reduce`` counts them: white references
    apart); when no table was written, the frames the stream reduced so far (a resumed
    stream's checkpoint included)."""
    resumed: int = 0
    """Frames taken from the checkpoint of an earlier, interrupted stream."""


@contextmanager
def _followers_take_turns(out: Path) -> Iterator[None]:
    """One follower at a time per output folder (blocking flock on the folder)."""
    fd = os.open(out.parent, os.O_RDONLY | os.O_CLOEXEC)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


def follow_session(
    session: str | Path,
    table_path: str | Path | None = None,
    *,
    calibration: str | Path | None = None,
    checkpoint_every: int = CHECKPOINT_EVERY,
    incomplete: bool = True,
    poll_s: float = POLL_S,
    snapshot_s: float = SNAPSHOT_S,
    progress: Callable[[int, int], None] | None = None,
    parent: int | None = None,
) -> FollowResult:
    """Reduce the session's frames as they are captured; write the table once the capture ends.

    ``incomplete``: write the table also when the capture stopped before its last step (as
    ``gonio reduce`` would of those frames); otherwise only keep the checkpoint, for the
    resumed capture. ``progress(frames reduced, journal rows)`` after each read. Every
    ``snapshot_s`` host seconds while the capture runs, the table of the frames reduced so far
    is written to :func:`live_table_path` (a table like any other, its provenance's
    ``live`` says how far it got); it is deleted once the table is written.
    ``parent``: the capturing process's PID (a capture's own worker): its end ends the
    capture, even if another capture of the session has begun since.
    A light-stage session is reduced once its capture has ended.
    """
    from acquisition.lightstage.reduce import is_lightstage_session, reduce_lightstage_session

    folder = SessionFolder(session)
    out = Path(table_path) if table_path else folder.path / DEFAULT_TABLE
    check_output(out, what=TABLE_WHAT, ours=is_table_file, inputs=(folder.path,))
    if not out.parent.is_dir():
        ensure_folder(out.parent, what="the table's folder")
    def running() -> bool:
        return (parent is None or os.getppid() == parent) and capture_running(folder.path)

    with _followers_take_turns(checkpoint_path(out)):
        if is_lightstage_session(folder.path):
            stream = None
            while running():
                time.sleep(poll_s)
            view_pending, frames = pending_steps(folder), 0
        else:
            stream = open_stream(folder, calibration, checkpoint_path(out), checkpoint_every)
            snapshots = _Snapshots(stream, live_table_path(out), folder.path, snapshot_s)
            view = follow(folder, stream, running, poll_s, progress, snapshots.maybe_write)
            view_pending, frames = view.pending, stream.frames_reduced
        if stream is not None and view_pending:  # stopped early: keep what a resume keeps
            stream.save()
            if not incomplete:
                return FollowResult(None, None, view_pending, frames, _resumed(stream))
            stream.complete(view)
        result = (reduce_lightstage_session(folder.path) if stream is None else stream.finish())
        write_table(result, out, folder.path, keep_checkpoint=bool(view_pending))
        with suppress(FileNotFoundError):
            live_table_path(out).unlink()
    return FollowResult(out, result, view_pending, result.frames, _resumed(stream))


class _Snapshots:
    """Writes the stream's partial table every ``every_s`` host seconds when it has grown."""

    def __init__(self, stream: PointStream | ImageStream, path: Path, session: Path,
                 every_s: float) -> None:
        self.stream, self.path, self.session, self.every_s = stream, path, session, every_s
        self._last_t, self._last_frames = time.monotonic(), 0

    def maybe_write(self, view: JournalView) -> None:
        frames = self.stream.frames_reduced
        if time.monotonic() - self._last_t < self.every_s or frames == self._last_frames:
            return
        snap = self.stream.snapshot()
        if snap is not None:
            snap.table.provenance["live"] = {
                "frames_reduced": frames, "journal_rows": len(view.rows),
                "rows_done": len(view.rows) - view.pending, "written_at": time.time()}
            snap.table.save_h5(self.path, inputs=(self.session,),
                               merl=getattr(snap, "merl", None))
        self._last_t, self._last_frames = time.monotonic(), frames


def _resumed(stream: object) -> int:
    run = getattr(stream, "run", None)
    return 0 if run is None else int(run.resumed)


def pending_steps(folder: SessionFolder) -> int:
    """Journal rows of the session not done yet."""
    with folder.journal(readonly=True) as journal:
        return sum(n for status, n in journal.counts().items() if status != "done")


class StreamingWorker:
    """A capture's reduction in a worker process of its own (a fresh interpreter, which shares
    nothing with the capture but the session folder, and imports nothing of the capturing
    script: a researcher's script needs no ``if __name__ == "__main__"`` guard):
    :func:`follow_session` of the session into its default table, written only when the
    capture ran to its end. The report comes back as one JSON line on a pipe."""

    def __init__(self, folder: SessionFolder, calibration: str | Path | None = None) -> None:
        read_fd, write_fd = os.pipe()
        args = [str(folder.path), str(os.getpid()), str(write_fd),
                "" if calibration is None else str(calibration)]
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-c", WORKER_CODE, *args], pass_fds=(write_fd,),
                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        finally:
            os.close(write_fd)
        self._reports = os.fdopen(read_fd, "rb")

    def result(self) -> dict[str, object]:
        """Wait for the worker (it ends once the capture lock is released): its report,
        ``{"table": path or None, "frames": n, "pending": n, "resumed": n}`` or
        ``{"error": one line}``."""
        with self._reports:
            line = self._reports.readline()  # sent once the table is written (or on exit)
        code = self.proc.wait()  # quick: the worker leaves with os._exit once it reported
        if not line:
            return {"error": f"the streaming reduction ended with exit code {code} and no report"}
        return json.loads(line)


WORKER_CODE = "import os, sys; from acquisition.api.streaming import work; os._exit(work(sys.argv[1:]))"
"""What the worker's interpreter runs (``python -c``): :func:`work` with the arguments, then
an immediate exit: its table and checkpoint are closed by then, and an interpreter's teardown
(numba, LLVM, h5py) would only delay the capture that waits for it."""


def work(argv: list[str]) -> int:
    """The streaming worker: ``SESSION PARENT_PID REPORT_FD CALIBRATION`` (an empty
    calibration: the session's own). Follows the capture of the parent process and writes its
    report to the file descriptor. Ctrl-C at the terminal reaches the whole process group: the
    worker leaves it to the capture, whose end ends the worker (its checkpoint saved)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    session, parent, fd, calibration = argv
    try:
        res = follow_session(session, calibration=calibration or None, incomplete=False,
                             parent=int(parent))
        report: dict[str, object] = {"table": None if res.table is None else str(res.table),
                                     "frames": res.frames, "pending": res.pending,
                                     "resumed": res.resumed}
        code = 0
    except GonioError as exc:
        report, code = {"error": str(exc)}, 1
    with suppress(OSError):  # the capture was killed: the checkpoint is what counts
        os.write(int(fd), (json.dumps(report) + "\n").encode())
        os.close(int(fd))
    return code
