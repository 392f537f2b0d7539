"""Progress bars for the CLI (tqdm), fed by the API's progress callbacks.

A capture's bar shows an ETA from the planner's time model (:class:`RunEta`) instead of
tqdm's rate-based one: each remaining journal step's predicted rig time, scaled by how long
the steps done so far really took against their prediction.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from typing import Any

from acquisition import api

DISABLE: bool | None = None
"""tqdm's ``disable``: None hides the bars when stderr is not a terminal (tests may force)."""

ETA_FORMAT = "{l_bar}{bar}| {n_fmt}/{total_fmt} [{elapsed}{postfix}]"
"""Bar layout with the time-model ETA in the postfix (no rate-based remaining time)."""


class RunEta:
    """Remaining time of a run from per-step predictions, corrected as the run goes.

    Parameters
    ----------
    predicted:
        ``{journal step: predicted rig time (s)}`` of the steps still to do
        (:func:`acquisition.api.step_durations`).
    clock:
        The clock the run is watched on (host monotonic s).

    The ETA is Σ predicted(remaining) × scale, where scale = elapsed time ÷ Σ predicted(done
    in this run): 1 until a step is done (on hardware the host's clock is the rig's), then
    whatever ratio the run shows (a simulated rig runs much faster than its rig time; a
    real one may be slower than the model).
    """

    def __init__(self, predicted: Mapping[int, float],
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._remaining = dict(predicted)
        self._left_s = math.fsum(self._remaining.values())
        self._done_s = 0.0
        self._clock = clock
        self._t0 = clock()

    def step_done(self, step: int) -> None:
        """Count journal step ``step`` as done (unknown or repeated steps are ignored)."""
        t = self._remaining.pop(step, None)
        if t is not None:
            self._done_s += t
            self._left_s = max(0.0, self._left_s - t)

    @property
    def predicted_left_s(self) -> float:
        """Σ predicted rig time (s) of the steps not done."""
        return self._left_s if self._remaining else 0.0

    @property
    def scale(self) -> float:
        """Elapsed time per predicted second of the steps done (1 before the first)."""
        if self._done_s <= 0.0:
            return 1.0
        return (self._clock() - self._t0) / self._done_s

    def eta_s(self) -> float:
        """Estimated time (s, on ``clock``) until every step is done."""
        return self.predicted_left_s * self.scale


def format_eta(seconds: float) -> str:
    """``"ETA 1:02:03"`` / ``"ETA 4:05"`` (h:mm:ss or m:ss)."""
    s = max(0, int(round(seconds)))
    h, rest = divmod(s, 3600)
    m, sec = divmod(rest, 60)
    return f"ETA {h}:{m:02d}:{sec:02d}" if h else f"ETA {m}:{sec:02d}"


class StepBar:
    """A tqdm bar whose callback is ``(done, total, record)``; sizes itself on first call.

    :meth:`start_eta` (e.g. from the API's ``on_open``) switches the bar to the time-model
    ETA of :class:`RunEta`.
    """

    def __init__(self, bar: Any) -> None:
        self.bar = bar
        self.eta: RunEta | None = None

    def start_eta(self, predicted: Mapping[int, float]) -> None:
        self.eta = RunEta(predicted)
        self.bar.bar_format = ETA_FORMAT
        self.bar.set_postfix_str(format_eta(self.eta.eta_s()), refresh=False)

    def __call__(self, done: int, total: int, record: api.StepRecord | None = None) -> None:
        bar = self.bar
        if self.eta is not None and record is not None:
            self.eta.step_done(record.step)
            bar.set_postfix_str(format_eta(self.eta.eta_s()), refresh=False)
        if bar.total != total:
            bar.total = total
            bar.n = done - 1
            bar.refresh()
        bar.update(done - bar.n)


def say(line: str) -> None:
    """Print a line on stdout without breaking a progress bar on the terminal."""
    from tqdm import tqdm

    tqdm.write(line, file=sys.stdout)


def status(line: str) -> None:
    """Tell the operator what a long step is doing, on stderr when it is a terminal only.

    Pipes and logs keep stderr for warnings and the one error line."""
    if sys.stderr.isatty():
        print(line, file=sys.stderr)


@contextmanager
def step_bar(desc: str, unit: str = "step") -> Iterator[StepBar]:
    """A :class:`StepBar` on stderr (hidden when stderr is not a terminal)."""
    from tqdm import tqdm

    bar = tqdm(desc=desc, unit=unit, file=sys.stderr, dynamic_ncols=True, disable=DISABLE)
    try:
        yield StepBar(bar)
    finally:
        bar.close()

