"""Who is capturing a session: an exclusive ``flock`` on its journal while a run is open.

A capture (or resume, light-stage run, scripted session) holds :func:`capture_lock` for as
long as its devices are open; the kernel drops the lock when the process ends in any way,
SIGKILL included. So a second capture of the same folder is refused in one line, and a
reduction following the session (``gonio reduce --follow``, the capture's own streaming
worker) learns that the capture ended from :func:`capture_running` without any file that a
crash could leave behind. ``flock`` locks are independent of SQLite's own (POSIX) locks on
the same file, and hold between processes on one host (not across NFS clients).
"""

from __future__ import annotations

import fcntl
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from acquisition.session.folder import JOURNAL_FILE
from drivers.errors import SessionError


def _journal(folder: str | os.PathLike[str]) -> Path:
    return Path(folder) / JOURNAL_FILE


@contextmanager
def capture_lock(folder: str | os.PathLike[str]) -> Iterator[None]:
    """Hold the session's capture lock inside the block (SessionError if another process
    captures it now)."""
    fd = os.open(_journal(folder), os.O_RDONLY | os.O_CLOEXEC)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise SessionError(f"{folder} is being captured by another gonio process: wait for it "
                               "to end (or stop it) before running this session") from None
        yield
    finally:
        os.close(fd)


def capture_running(folder: str | os.PathLike[str]) -> bool:
    """Whether a process holds the session's capture lock now."""
    try:
        fd = os.open(_journal(folder), os.O_RDONLY | os.O_CLOEXEC)
    except FileNotFoundError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    finally:
        os.close(fd)  # closing drops a shared lock we took
    return False
