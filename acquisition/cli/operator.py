"""The operator at the terminal: the prompt that asks them to swap targets on a real rig."""

from __future__ import annotations

import sys
from collections.abc import Callable


def terminal_prompt() -> Callable[[str], None] | None:
    """A prompt that asks on the terminal and waits for Enter; None when stdin is not a terminal
    (CI, a pipe, a service), so a rig that needs an operator is refused before anything moves."""
    stdin = sys.stdin
    if stdin is None or not stdin.isatty():
        return None

    def ask(target: str) -> None:
        input(f"Put the {target} in place and press Enter… ")

    return ask
