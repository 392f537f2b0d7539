"""Ctrl-C while the rig moves: the first press stops every axis, the second exits at once.

:func:`sigint_stops_motion` installs a SIGINT handler for the duration of a command:

- first Ctrl-C: one line on stderr, then ``KeyboardInterrupt`` is raised in the main thread, as
  Python would. The motion controller catches it and stops all axes (goal := present, torque
  stays on); the capture engine turns it into a :class:`~drivers.errors.SafetyStop` that names
  ``gonio resume``; the console into a SafetyStop of its own.
- second Ctrl-C (the stop or the clean-up hangs, or the operator insists): one line on stderr
  and the process ends with status 130 at once (``os._exit``). Frames are written atomically
  and the journal is SQLite, so the session stays resumable.

The handler writes with ``os.write`` (a signal may arrive while Python is printing to stderr, and
a buffered write from inside a handler can fail). Outside the main thread, where signals cannot
be handled, the context does nothing.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from types import FrameType

EXIT_INTERRUPTED = 130
"""Exit status after Ctrl-C (128 + SIGINT)."""

FIRST_MESSAGE = ("gonio: Ctrl-C: stopping all axes (torque stays on); "
                 "press Ctrl-C again to exit at once\n")
LIGHTS_MESSAGE = ("gonio: Ctrl-C: switching every light off; "
                  "press Ctrl-C again to exit at once\n")
"""The first notice on a light stage, which has lights to switch off and nothing to stop."""
SECOND_MESSAGE = "gonio: second Ctrl-C: exiting now; check the rig before moving it again\n"


@dataclass
class SigintState:
    """How many times Ctrl-C was pressed inside the context."""

    presses: int = 0


def _write_stderr(text: str) -> None:
    try:
        fd = sys.stderr.fileno()
    except (AttributeError, OSError, ValueError):
        fd = 2
    with suppress(OSError):
        os.write(fd, text.encode())


@contextmanager
def sigint_stops_motion(
    *,
    exit_now: Callable[[int], object] = os._exit,
    write: Callable[[str], None] = _write_stderr,
    first_message: str = FIRST_MESSAGE,
) -> Iterator[SigintState]:
    """Context in which the first SIGINT raises ``KeyboardInterrupt`` and the second exits.

    Parameters
    ----------
    exit_now:
        Called with :data:`EXIT_INTERRUPTED` on the second press (``os._exit``: no clean-up,
        no waiting for threads).
    write:
        Where the one-line notices go (stderr, unbuffered).
    first_message:
        The first press's notice (:data:`LIGHTS_MESSAGE` on a light stage).

    Yields
    ------
    SigintState
        Counts the presses (for tests and callers that want to know).
    """
    state = SigintState()
    if threading.current_thread() is not threading.main_thread():
        yield state
        return

    def handler(signum: int, frame: FrameType | None) -> None:
        state.presses += 1
        if state.presses == 1:
            write(first_message)
            raise KeyboardInterrupt
        write(SECOND_MESSAGE)
        exit_now(EXIT_INTERRUPTED)

    previous = signal.signal(signal.SIGINT, handler)
    try:
        yield state
    finally:
        signal.signal(signal.SIGINT, previous)
