"""Progress bars for the CLI (tqdm), fed by the API's progress callbacks."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from contextlib import contextmanager

from tqdm import tqdm

from acquisition.journal import StepRecord


@contextmanager
def step_bar(desc: str, unit: str = "step") -> Iterator[object]:
    """A tqdm bar whose callback is ``(done, total, record)``; the bar sizes itself on first call."""
    bar = tqdm(desc=desc, unit=unit, file=sys.stderr, dynamic_ncols=True, disable=None)

    def update(done: int, total: int, _record: StepRecord | None = None) -> None:
        if bar.total != total:
            bar.total = total
            bar.n = done - 1
            bar.refresh()
        bar.update(done - bar.n)

    try:
        yield update
    finally:
        bar.close()
