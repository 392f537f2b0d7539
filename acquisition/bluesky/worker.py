"""One thread that owns an open rig: every blocking driver call runs on it, one at a time.

``dynamixel_sdk`` is not thread-safe and an SQLite connection belongs to the thread that opened
it, so the devices never call a driver from the RunEngine's event loop: they hand a
:class:`Job` to the :class:`RigWorker` and await its future. While a sweep's session engine
runs (on this same thread, inside a job) it takes the next jobs itself, between its steps
(:meth:`RigWorker.take`), so bus access stays serial whoever asks.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import queue
import threading
from collections.abc import Callable
from typing import Any, TypeVar

T = TypeVar("T")


class Job:
    """A call to make on the rig's thread; :attr:`future` gets its result or its exception.

    ``moves``: the call may move the arms (a sweep's engine then forgets where they are).
    """

    def __init__(self, fn: Callable[..., Any], *args: Any, moves: bool = False) -> None:
        self.fn = fn
        self.args = args
        self.moves = moves
        self.future: concurrent.futures.Future[Any] = concurrent.futures.Future()

    def run(self) -> None:
        """Make the call (unless the caller gave up first) and settle the future."""
        if not self.future.set_running_or_notify_cancel():
            return
        try:
            result = self.fn(*self.args)
        except BaseException as exc:  # handed to the awaiting device, which fails its status
            self.future.set_exception(exc)
        else:
            self.future.set_result(result)


class RigWorker:
    """The rig's thread: runs :class:`Job` objects in the order they arrive.

    Parameters
    ----------
    name
        The thread's name (logs, debuggers).
    """

    def __init__(self, name: str = "gonio-rig") -> None:
        self._inbox: queue.SimpleQueue[Job | None] = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._serve, name=name, daemon=True)
        self._thread.start()

    def put(self, job: Job) -> concurrent.futures.Future[Any]:
        """Queue ``job``; returns its future."""
        self._inbox.put(job)
        return job.future

    async def call(self, fn: Callable[..., T], *args: Any, moves: bool = False) -> T:
        """Run ``fn(*args)`` on the rig's thread and return its result (or raise its error)."""
        return await asyncio.wrap_future(self.put(Job(fn, *args, moves=moves)))

    def take(self) -> Job | None:
        """The next job (None: the worker is closing). Only on the rig's thread: a job that
        runs for long (a sweep's engine) serves the others between its own steps."""
        if threading.current_thread() is not self._thread:
            raise RuntimeError("RigWorker.take() belongs to the rig's own thread")
        return self._inbox.get()

    def closing(self) -> None:
        """Tell :meth:`take`'s caller again that the worker is closing (it took the signal)."""
        self._inbox.put(None)

    def _serve(self) -> None:
        while (job := self._inbox.get()) is not None:
            job.run()

    def close(self) -> None:
        """Finish the queued jobs, then stop the thread."""
        self._inbox.put(None)
        self._thread.join()
