"""The operator at the terminal: notices from the devices, and the prompt that asks them to
swap targets on a real rig."""

from __future__ import annotations

import logging
import sys
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager

LOGGERS = ("acquisition.devices",)
"""Loggers whose records the CLI shows on stderr (health-guard pauses)."""


@contextmanager
def operator_output() -> Iterator[None]:
    """Show warnings (e.g. the USB latency timer) and guard notices as ``gonio: …`` lines."""

    def show(message, category, filename, lineno, file=None, line=None) -> None:  # noqa: ANN001
        print(f"gonio: warning: {message}", file=sys.stderr, flush=True)

    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("gonio: %(message)s"))
    loggers = [logging.getLogger(name) for name in LOGGERS]
    saved = [(lg, lg.level, lg.propagate) for lg in loggers]
    for lg in loggers:
        lg.addHandler(handler)
        lg.setLevel(logging.INFO)
        lg.propagate = False
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("default")
            warnings.showwarning = show
            yield
    finally:
        for lg, level, propagate in saved:
            lg.removeHandler(handler)
            lg.setLevel(level)
            lg.propagate = propagate


def terminal_prompt() -> Callable[[str], None] | None:
    """A prompt that asks on the terminal and waits for Enter; None when stdin is not a terminal
    (CI, a pipe, a service), so a rig that needs an operator is refused before anything moves."""
    stdin = sys.stdin
    if stdin is None or not stdin.isatty():
        return None

    def ask(target: str) -> None:
        input(f"Put the {target} in place and press Enter… ")

    return ask
