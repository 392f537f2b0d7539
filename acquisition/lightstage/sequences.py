"""Light-stage sequences as data: frames under light states, and their time estimate.

A :class:`LightFrame` is a step record (see :mod:`acquisition.session.steps`): expose the sample or
the white reference under one light state (a 0–1 level per LED). The capture engine
(:mod:`acquisition.lightstage.capture`) journals each as one step: kind ``pose`` (sample),
``reference`` (white target) or ``dark``, joints ``{"light": k}`` for one-light-at-a-time
frames (so the ``light-stage`` kinematics gives their geometry) and ``{}`` for patterns, and
the pattern's name as the step note.

Sequences (:data:`SEQUENCES`):

* ``olat``: one light at a time, every LED in dome order;
* ``all-on``: every LED at full level;
* ``dark``: every LED off;
* ``gradient``: spherical gradient illumination (Ma et al. 2007): all-on and the three
  gradients (1 + ω_x)/2, (1 + ω_y)/2, (1 + ω_z)/2 of each LED's direction ω;
* ``sh``: real spherical harmonics of order ≤ 2 (9 patterns), each mapped to 0–1 as
  (1 + Y/max|Y|)/2 over the dome's LEDs.

:func:`capture_steps` puts a white-reference OLAT pass (the per-LED calibration) and a dark
frame before the sample's sequences. :func:`estimate_s` times a sequence with the DMX model of
:mod:`drivers.dmx` (refresh-limited send + one frame on the wire + USB margin + settle) plus
the exposures, like the planner's time model does for moves.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field

import numpy as np

from acquisition.config.stage import StageConfig
from acquisition.session.steps import DARK, POSE, REFERENCE, Checkpoint, Step
from drivers.dmx import (
    DEFAULT_BREAK_UNITS,
    DEFAULT_MAB_UNITS,
    USB_MARGIN_S,
    frame_time_s,
)
from drivers.errors import ConfigError

SEQUENCES = ("olat", "all-on", "dark", "gradient", "sh")
"""Sequence names accepted by :func:`sequence_frames`."""


@dataclass(frozen=True)
class LightFrame:
    """One frame under a light state.

    Attributes
    ----------
    kind:
        Journal kind: ``"pose"`` (sample), ``"reference"`` (white target) or ``"dark"``.
    target:
        ``"sample"`` or ``"white"``: what sits under the dome.
    pattern:
        Name of the light state (``"olat"``, ``"all-on"``, ``"sh-1-0"``…), the journal note.
    levels:
        Level (0–1) of every LED.
    light:
        The one LED lit (OLAT frames), else None.
    exposure_s:
        Exposure (s); None: the plan's, else the rig's.
    """

    kind: str
    target: str
    pattern: str
    levels: tuple[float, ...] = field(repr=False)
    light: int | None = None
    exposure_s: float | None = None

    @property
    def joints(self) -> dict[str, float]:
        """Journal joints: ``{"light": k}`` for an OLAT frame, else empty."""
        return {} if self.light is None else {"light": float(self.light)}


def _sh_basis(d: np.ndarray) -> list[tuple[str, np.ndarray]]:
    """Real spherical harmonics Y_lm (l ≤ 2) at unit directions d (N, 3)."""
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    return [
        ("sh-0-0", np.full(len(d), 0.282095)),
        ("sh-1--1", 0.488603 * y), ("sh-1-0", 0.488603 * z), ("sh-1-1", 0.488603 * x),
        ("sh-2--2", 1.092548 * x * y), ("sh-2--1", 1.092548 * y * z),
        ("sh-2-0", 0.315392 * (3 * z * z - 1)), ("sh-2-1", 1.092548 * x * z),
        ("sh-2-2", 0.546274 * (x * x - y * y)),
    ]


def _unit(values: np.ndarray) -> np.ndarray:
    peak = float(np.max(np.abs(values)))
    return np.ones_like(values) if peak == 0 else 0.5 * (1.0 + values / peak)


def sequence_frames(stage: StageConfig, name: str, *, target: str = "sample",
                    kind: str = POSE) -> list[LightFrame]:
    """The frames of sequence ``name`` (one of :data:`SEQUENCES`)."""
    n = len(stage)
    d = stage.directions
    if name == "olat":
        frames = []
        for k in range(n):
            levels = np.zeros(n)
            levels[k] = 1.0
            frames.append(LightFrame(kind, target, "olat", tuple(levels), k))
        return frames
    if name == "all-on":
        return [LightFrame(kind, target, "all-on", (1.0,) * n)]
    if name == "dark":
        return [LightFrame(DARK, target, "dark", (0.0,) * n)]
    if name == "gradient":
        pats = [("all-on", np.ones(n))] + [(f"gradient-{a}", 0.5 * (1 + d[:, i]))
                                           for i, a in enumerate("xyz")]
    elif name == "sh":
        pats = [(p, _unit(v)) for p, v in _sh_basis(d)]
    else:
        raise ConfigError(f"unknown light-stage sequence '{name}' (known: {', '.join(SEQUENCES)})")
    return [LightFrame(kind, target, p, tuple(float(x) for x in v)) for p, v in pats]


def capture_steps(stage: StageConfig, sequences: Sequence[str] = ("olat",), *,
                  white: bool = True, dark: bool = True) -> list[Step]:
    """The light-stage capture: white-reference OLAT pass, a dark frame, then ``sequences``
    on the sample; a checkpoint after every frame."""
    frames: list[LightFrame] = []
    if white:
        frames += sequence_frames(stage, "olat", target="white", kind=REFERENCE)
    if dark:
        frames += sequence_frames(stage, "dark")
    for name in sequences:
        frames += sequence_frames(stage, name)
    return list(_with_checkpoints(frames))


def _with_checkpoints(frames: Iterable[LightFrame]) -> Iterator[Step]:
    for f in frames:
        yield f  # type: ignore[misc]
        yield Checkpoint()


@dataclass(frozen=True)
class TimeEstimate:
    """Predicted rig time of a light-stage sequence (s)."""

    frames: int
    light_changes: int
    dmx_s: float
    """Refresh-limited sends, frames on the wire, USB margin and settle, summed (s)."""
    exposure_s: float

    @property
    def total_s(self) -> float:
        return self.dmx_s + self.exposure_s


def estimate_s(stage: StageConfig, steps: Iterable[Step], exposure_s: float) -> TimeEstimate:
    """Rig time of ``steps``: each light change costs one output period (the frame in
    progress) + one frame + USB margin + settle before the exposure may start
    (:meth:`drivers.dmx.DmxWidget.ready_at`); duty-cycle cool-downs are not included."""
    frames = changes = 0
    exposure = 0.0
    for changed, t in _frame_costs(steps, exposure_s):
        frames += 1
        changes += changed
        exposure += t
    return TimeEstimate(frames, changes, changes * light_change_s(stage), exposure)


def frame_times_s(stage: StageConfig, steps: Iterable[Step], exposure_s: float) -> list[float]:
    """Predicted rig time (s) of each :class:`LightFrame` of ``steps``, in order: its light
    change, if it has one, and its exposure (they add up to :func:`estimate_s`)."""
    change_s = light_change_s(stage)
    return [change_s * changed + t for changed, t in _frame_costs(steps, exposure_s)]


def light_change_s(stage: StageConfig) -> float:
    """Rig time of one light change before an exposure may start (see :func:`estimate_s`)."""
    n_channels = max(max(f.addresses.values()) for f in stage.fixtures)
    wire = frame_time_s(max(n_channels, 24), break_units=DEFAULT_BREAK_UNITS,
                        mab_units=DEFAULT_MAB_UNITS)
    period = max(wire, 1.0 / stage.refresh_rate_hz)
    return period + wire + USB_MARGIN_S + stage.settle_s


def _frame_costs(steps: Iterable[Step], exposure_s: float) -> Iterator[tuple[bool, float]]:
    """``(lights change, exposure s)`` of each :class:`LightFrame` of ``steps``."""
    last: tuple[float, ...] | None = None
    for s in steps:
        if not isinstance(s, LightFrame):
            continue
        yield s.levels != last, s.exposure_s or exposure_s
        last = s.levels
