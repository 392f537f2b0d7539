"""Reduction on a Dask cluster: the frames of many sessions reduced by the workers, one table
per session, bit for bit the table a local reduction gives.

Dask is the optional extra ``gonio[distributed]``: this module is imported only when a
reduction asks for workers or a scheduler, and imports ``distributed`` only then
(:func:`dask_client`; without it, one line naming ``pip install 'gonio[distributed]'``).

How a session is reduced (:func:`reduce_on_cluster`):

* a worker opens the session (an image-based session's :class:`ImageReducer`: journal, white
  references; a point session's rig and bundle) — the client reads no frame;
* each frame (an HDR bracket is one frame) is one task; a point frame gives its ROI signal
  (the point budget's angular terms need every sample before any is binned, so the client
  bins the session's few hundred samples once every signal is in);
* an image-based frame is binned into its worker's running sums of the session (a
  :class:`~acquisition.reduction.image.PartialBuilder` per worker thread, kept in the worker
  process between tasks), so no per-frame partial is made, shipped or merged; once every
  frame is in, each worker hands its running sums over once (:func:`take_running`, through
  ``Client.run``), and the client merges them and finishes the tables. Every frame must be
  in exactly one worker's sums: a frame lost with a worker that died is recomputed by Dask
  elsewhere, and the merged frames are checked against the session's before any table.

Sums are exact, so the split, the merge order and the number of workers change no bit. The
workers' gonio, numpy and numba versions are checked against the client's before any work
(:func:`check_versions`). A frame that cannot be decoded is collected as in a local reduction
and the session fails with the same one-line error; any other failure on a worker becomes one
line naming the session (:class:`DistributedError`). Workers and client must see the
sessions (and the calibration bundle) at the same absolute paths.

``--workers N`` starts its cluster with :data:`LOCAL_CONFIG`; a cluster of one's own runs
frame-sized arrays faster with the same settings (``dask.config.set(LOCAL_CONFIG)`` where its
workers start).
"""

from __future__ import annotations

import dataclasses
import logging
import os
import threading
import uuid
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from acquisition.reduction.badframes import FrameCheck
from acquisition.reduction.image import ImageReducer, PartialBuilder
from acquisition.reduction.point import (
    FrameSignal,
    PointReducer,
    Reduction,
    SignalFrame,
    find_bundle,
    read_signal,
    signal_frames,
)
from acquisition.session.folder import SessionFolder
from acquisition.session.journal import StepRecord
from acquisition.tables import partial as partials
from acquisition.tables.partial import ReductionPartial
from calibration.bundle import CalibrationBundle
from drivers.errors import GonioError

INSTALL = "pip install 'gonio[distributed]'"
OPEN_PRIORITY, FRAME_PRIORITY = 20, 0
"""Dask task priorities: sessions open first (the bar learns every total)."""
CONNECT_TIMEOUT_S = 10.0
LOCAL_CLUSTER: dict[str, Any] = {
    "processes": True, "threads_per_worker": 1, "dashboard_address": None,
    "silence_logs": logging.ERROR,
    # the scheduler's HTTP server (health, metrics) runs even without a dashboard: on a free
    # port, not 8787, which another cluster on the host may hold
    "scheduler_kwargs": {"dashboard_address": "127.0.0.1:0"},
}
"""``distributed.LocalCluster`` options of ``--workers N``: worker processes of one thread,
no dashboard, quiet logs."""
LOCAL_CONFIG: dict[str, Any] = {
    # Dask's nanny sets MALLOC_TRIM_THRESHOLD_=65536 in its workers, which turns off glibc's
    # adaptive mmap threshold: every frame-sized array is then mapped afresh and page-faulted
    # (measured on 10 frames of 6 MP: sys time ≈ 0.75 × user time with it, ≈ 0.2 × without)
    "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
    # the profiler and monitors feed the dashboard, which is off, and the event loop was
    # checked every 20 ms: an idle worker took 3.3 % of a core with Dask's defaults, 0.8 %
    # with these (measured)
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "2s",
    "distributed.admin.system-monitor.disk": False,
}
"""Dask configuration of the local cluster's workers."""


def worker_threads(workers: int) -> dict[str, dict[str, str]]:
    """``LocalCluster`` options giving each of ``workers`` local worker processes its share of
    the cores for numba's thread pool (the linearization's): ⌊cores / workers⌋, at least 1.
    More would put several threads per core, whose switching and OpenMP spinning cost CPU
    time while the workers already use every core. (The nanny's ``env``, which its worker
    sets on start; not the ``pre-spawn-environ`` configuration, which the nanny writes into
    this process's own environment, where it then overrides later clusters' settings.)"""
    share = max(1, (os.cpu_count() or 1) // workers)
    return {"env": {"NUMBA_NUM_THREADS": str(share)}}


def use_thread_share() -> None:
    """(worker) Hold this task thread's numba kernels to the share :func:`worker_threads` gave
    the worker. The variable only sizes numba's pool if numba is imported after the worker
    sets it; a spawned worker that first re-imports a ``__main__`` importing gonio has already
    imported numba with a pool of every core (2 workers × 2 threads on 2 cores: 30 % more CPU
    per frame, measured). No variable (a remote cluster's workers): nothing changes."""
    share = os.environ.get("NUMBA_NUM_THREADS", "")
    if share.isdigit() and int(share) >= 1:
        import numba

        numba.set_num_threads(min(int(share), numba.config.NUMBA_NUM_THREADS))


class DistributedError(GonioError, RuntimeError):
    """The Dask cluster cannot be used (extra missing, scheduler unreachable, other versions
    on the workers) or a worker failed."""


def _distributed() -> Any:
    """The ``distributed`` package, or one line saying how to install it."""
    try:
        import distributed
    except ImportError:
        raise DistributedError(f"Dask is not installed: {INSTALL} (or reduce without "
                               "--workers/--scheduler)") from None
    return distributed


@contextmanager
def dask_client(workers: int | None = None, scheduler: str | None = None) -> Iterator[Any]:
    """A ``distributed.Client`` on a new ``LocalCluster`` of ``workers`` processes (one thread
    each, no dashboard) or on the cluster at ``scheduler`` (``tcp://HOST:PORT``), its workers'
    versions checked; the local cluster is shut down on exit."""
    if (workers is None) == (scheduler is None):
        raise DistributedError("give either a number of workers or a scheduler address")
    dist = _distributed()
    if scheduler is None:
        if workers < 1:  # type: ignore[operator]
            raise DistributedError(f"--workers must be ≥ 1, got {workers}")
        import dask

        with dask.config.set(LOCAL_CONFIG), \
                dist.LocalCluster(n_workers=workers, **LOCAL_CLUSTER, **worker_threads(workers)
                                  ) as cluster, \
                dist.Client(cluster) as client:
            check_versions(client)
            yield client
        return
    try:
        client = dist.Client(scheduler, timeout=CONNECT_TIMEOUT_S)
    except (OSError, TimeoutError, ValueError) as exc:
        raise DistributedError(f"cannot reach the Dask scheduler at {scheduler} ({exc}): start "
                               "it (`dask scheduler`) or check the address") from None
    with client:
        check_versions(client)
        yield client


def _versions_line(versions: dict[str, str]) -> str:
    return ", ".join(f"{k} {versions.get(k, 'missing')}" for k in partials.SOFTWARE)


def check_versions(client: Any) -> None:
    """Refuse, before any work, a cluster without workers or with a worker whose gonio, numpy
    or numba differs from the client's (partials of other versions do not merge)."""
    if not client.scheduler_info().get("workers"):
        raise DistributedError(f"the Dask cluster at {client.scheduler.address} has no worker: "
                               "start some (`dask worker ADDRESS`)")
    here = partials.software_versions()
    try:
        there = client.run(partials.software_versions)
    except Exception as exc:  # a worker without gonio cannot even unpickle the call
        raise DistributedError(f"a Dask worker cannot run gonio ({type(exc).__name__}: "
                               f"{_first_line(exc)}): install gonio[distributed] on every "
                               "worker") from None
    for address, versions in sorted(there.items()):
        if versions != here:
            raise DistributedError(f"Dask worker {address} runs {_versions_line(versions)}; this "
                                   f"client runs {_versions_line(here)}: install the same "
                                   "versions on every worker")


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


# ------------------------------------------------------------------ what the workers run
@dataclass(frozen=True)
class Piece:
    """What some frames of a session gave: their merged partial (None: no readable frame)
    and the frames that could not be decoded, in frame order."""

    partial: ReductionPartial | None
    bad: tuple[str, ...] = ()

    def merge(self, other: Piece) -> Piece:
        if self.partial is None or other.partial is None:
            part = self.partial or other.partial
        else:
            part = self.partial.merge(other.partial)
        return Piece(part, self.bad + other.bad)


@dataclass(frozen=True)
class PointSource:
    """A point session opened on a worker: what reading a frame's ROI signal needs, and the
    frames to read."""

    folder: SessionFolder
    cal: CalibrationBundle | None
    frames: list[SignalFrame]


def open_session(session: Path, bundle: str | None) -> ImageReducer | PointSource:
    """(worker) An image-based session's reducer, or a point session's :class:`PointSource`."""
    folder = SessionFolder(session)
    if folder.rig().sample.image_based:
        return ImageReducer.open(folder, bundle)
    return PointSource(folder, find_bundle(folder, bundle), signal_frames(folder))


_RUNNING: dict[tuple[str, int], PartialBuilder] = {}
"""(worker) Running sums of image frames, per (session token, worker thread)."""


def image_frame(reducer: ImageReducer, frame: list[StepRecord], token: str) -> None:
    """(worker) Bin an image frame into this worker thread's running sums of the session
    ``token`` (an undecodable frame is noted there)."""
    use_thread_share()
    slot = (token, threading.get_ident())
    builder = _RUNNING.get(slot)
    if builder is None:
        own = dataclasses.replace(reducer, check=FrameCheck(reducer.folder.path))
        builder = _RUNNING[slot] = PartialBuilder(own)
    builder.add([frame])


def take_running(token: str) -> Piece | None:
    """(worker, through ``Client.run``) This worker's running sums of the session ``token``,
    removed from it: one piece (None: it binned none of its frames)."""
    piece = None
    for slot in sorted(k for k in _RUNNING if k[0] == token):
        builder = _RUNNING.pop(slot)
        own = Piece(builder.partial(), tuple(builder.reducer.check.bad))
        piece = own if piece is None else piece.merge(own)
    return piece


def point_signal(source: PointSource, frame: SignalFrame) -> tuple[FrameSignal | None, str | None]:
    """(worker) A point frame's ROI signal, or (None, the frame's name) when undecodable."""
    use_thread_share()
    check = FrameCheck(source.folder.path)
    signal = read_signal(source.folder, source.folder.rig(), source.cal, frame, check)
    return signal, (check.bad[0] if check.bad else None)


def merge_all_pieces(pieces: list[Piece]) -> Piece:
    """One piece of several (frames disjoint: a frame in two raises)."""
    out = pieces[0]
    for p in pieces[1:]:
        out = out.merge(p)
    return out


# ------------------------------------------------------------------ what the client runs
@dataclass
class _Session:
    """The client's view of one session under reduction."""

    path: Path
    opened: Any
    """The future of :func:`open_session`."""
    token: str = field(default_factory=lambda: uuid.uuid4().hex)
    """Names the session's running sums on the workers (unique to this reduction)."""
    landed: int = 0
    """Image frames binned so far."""
    source: ImageReducer | PointSource | None = None
    """Its result, once open."""
    frames: list[Any] = field(default_factory=list)
    signals: dict[int, tuple[FrameSignal | None, str | None]] = field(default_factory=dict)
    error: BaseException | None = None
    done: bool = False


Done = Callable[[int, Reduction], None]


def reduce_on_cluster(client: Any, sessions: Sequence[str | Path],
                      bundle: str | Path | None = None,
                      progress: Callable[[int, int], None] | None = None,
                      on_done: Done | None = None) -> list[Reduction]:
    """Reduce every session on ``client``'s workers; ``on_done(i, reduction)`` as each one is
    finished (e.g. to write its table), ``progress(done, total)`` after each frame over all
    sessions (the total grows as sessions open). Returns the reductions in session order;
    raises the first failed session's error once the others are finished."""
    run = _ClusterRun(client, None if bundle is None else str(Path(bundle).resolve()),
                      progress, on_done)
    return run.reduce([Path(s).resolve() for s in sessions])


class _ClusterRun:
    """One call of :func:`reduce_on_cluster`: the futures, what each one is, the tallies."""

    def __init__(self, client: Any, bundle: str | None,
                 progress: Callable[[int, int], None] | None, on_done: Done | None) -> None:
        self.client, self.bundle = client, bundle
        self.progress, self.on_done = progress, on_done
        self.roles: dict[Any, tuple[str, int, int]] = {}
        self.pending = _distributed().as_completed()
        self.sessions: list[_Session] = []
        self.results: dict[int, Reduction] = {}
        self.frames_done = self.frames_total = 0

    def _submit(self, role: str, index: int, fn: Callable[..., Any], *args: Any,
                priority: int, at: int = 0) -> Any:
        future = self.client.submit(fn, *args, priority=priority, pure=False)
        self.roles[future] = (role, index, at)
        self.pending.add(future)
        return future

    def reduce(self, paths: list[Path]) -> list[Reduction]:
        for i, path in enumerate(paths):
            opened = self._submit("open", i, open_session, path, self.bundle,
                                  priority=OPEN_PRIORITY)
            self.sessions.append(_Session(path, opened))
        for future in self.pending:
            role, i, at = self.roles.pop(future)
            s = self.sessions[i]
            if s.error is None and not s.done:
                try:
                    getattr(self, f"_{role}")(s, i, future, at)
                except Exception as exc:
                    self._fail(s, exc)
            if role == "frame":
                self.frames_done += 1
                if self.progress:
                    self.progress(self.frames_done, self.frames_total)
        self._raise_first_error()
        return [self.results[i] for i in range(len(paths))]

    def _fail(self, s: _Session, exc: BaseException) -> None:
        s.error = exc if isinstance(exc, GonioError) else DistributedError(
            f"{s.path}: the reduction failed on a Dask worker ({type(exc).__name__}: "
            f"{_first_line(exc)})")
        self.client.cancel([f for f in (s.opened, *s.frames) if f is not None])
        with suppress(Exception):  # the workers' running sums of it are dropped
            self.client.run(take_running, s.token)

    def _open(self, s: _Session, i: int, future: Any, _at: int) -> None:
        """A session is open: its frames become tasks."""
        opened = s.source = future.result()
        self.frames_total += len(opened.frames)
        if isinstance(opened, PointSource):
            s.frames = [self._submit("frame", i, point_signal, future, f, priority=FRAME_PRIORITY,
                                     at=k) for k, f in enumerate(opened.frames)]
            if not s.frames:
                self._finish_point(s, i)
            return
        s.frames = [self._submit("frame", i, image_frame, future, f, s.token,
                                 priority=FRAME_PRIORITY) for f in opened.frames]
        if not s.frames:
            self._finish_image(s, i)

    def _frame(self, s: _Session, i: int, future: Any, at: int) -> None:
        """A frame is done: a point frame's signal is kept; once every image frame is binned,
        the workers' running sums are collected."""
        result = future.result()  # a failed task raises its error here
        if not isinstance(s.source, PointSource):
            s.landed += 1
            if s.landed == len(s.frames):
                self._finish_image(s, i)
            return
        s.signals[at] = result
        if len(s.signals) == len(s.frames):
            self._finish_point(s, i)

    def _finish_image(self, s: _Session, i: int) -> None:
        """Every frame of an image-based session is binned: the workers' running sums,
        merged here (exact sums: in any order) and checked to hold each frame once, finish
        its tables."""
        reducer = s.source
        assert isinstance(reducer, ImageReducer)
        _distributed().wait(s.frames)  # frames lost with a worker are binned again first
        pieces = [p for _, p in sorted(self.client.run(take_running, s.token).items())
                  if p is not None]
        piece = merge_all_pieces(pieces) if pieces else Piece(None)
        if piece.bad:
            FrameCheck(reducer.folder.path, list(piece.bad)).raise_if_any()
        part = piece.partial or reducer.partial([])
        expected = {recs[0].step for recs in reducer.frames}
        if part.steps != expected:
            missing = sorted(expected - part.steps)
            raise DistributedError(f"{s.path}: {len(missing)} frame(s) were lost with a Dask "
                                   f"worker (steps {missing[:5]}…): reduce the session again")
        self._done(s, i, reducer.reduction(part))

    def _finish_point(self, s: _Session, i: int) -> None:
        """Every signal of a point session is in: its samples' budget and table, here."""
        source = s.source
        assert isinstance(source, PointSource)
        bad = [name for _, (_, name) in sorted(s.signals.items()) if name is not None]
        FrameCheck(source.folder.path, bad).raise_if_any()
        known = {f.step: sig for k, f in enumerate(source.frames)
                 if (sig := s.signals[k][0]) is not None}
        reducer = PointReducer.open(source.folder.path, self.bundle, signals=known)
        self._done(s, i, reducer.reduction(reducer.partial(reducer.steps)))

    def _done(self, s: _Session, i: int, reduction: Reduction) -> None:
        s.done = True
        s.frames = []
        if self.on_done:
            self.on_done(i, reduction)
        self.results[i] = reduction

    def _raise_first_error(self) -> None:
        failed = [s for s in self.sessions if s.error is not None]
        if not failed:
            return
        first = failed[0].error
        if len(failed) > 1:
            others = ", ".join(str(s.path) for s in failed[1:])
            raise type(first)(f"{first} (also failed: {others})") from None  # type: ignore[call-arg]
        raise first  # type: ignore[misc]
