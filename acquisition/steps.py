"""Step records: what a scripted capture plan is made of.

A plan is data: an iterable (list or generator) of frozen step records, which never touch a
device. The session engine (:class:`acquisition.session.SessionEngine`) acts on them:

=================  ==========================================================================
record             what the engine does
=================  ==========================================================================
:class:`Move`      remember the target pose; the arms move (guarded) only before the next
                   frame that is not yet in the journal, so a resumed plan skips done moves
:class:`Expose`    one RAW frame of the sample at the current pose per ``bracket`` factor
:class:`Dark`      one frame with the light off (shutter closed) at the current pose
:class:`Reference` move to the white reference's pose, present it, one frame
:class:`Checkpoint` a safe point: a stop requested by the operator happens here
:class:`Custom`    call ``fn(context)`` once (journaled, never repeated on resume)
=================  ==========================================================================

Every record that produces a journal row (Expose per bracket factor, Dark, Reference, Custom)
gets the next step number, in plan order. Replaying the same plan after a crash meets the
same numbers, so the engine skips what the journal holds as done and refuses a plan that
differs from the journal.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from .kinematics import Pose
from .planner import Planner, Sweep

POSE = "pose"
REFERENCE = "reference"
DARK = "dark"
CUSTOM = "custom"
JOURNALED_KINDS = (POSE, REFERENCE, DARK, CUSTOM)
"""The ``kind`` column values a step record can produce in the journal."""


@dataclass(frozen=True)
class Move:
    """Move the arms to ``pose`` (θi, θr, Δφ in degrees).

    ``joints`` (axis → degrees) pins the joint solution; None lets the engine's planner choose
    it (nearest to the current joints). Either way the planner's guard checks it first.
    """

    pose: Pose
    joints: Mapping[str, float] | None = None


@dataclass(frozen=True)
class Expose:
    """Expose the sample at the current pose: one frame per factor of ``bracket``.

    Parameters
    ----------
    exposure_s
        Base exposure in s (None: the plan's, else the rig's).
    bracket
        Exposure multipliers, e.g. ``(0.25, 1, 4)`` for an HDR bracket; one journal step each.
    iso
        ISO (None: the plan's, else the rig's).
    """

    exposure_s: float | None = None
    bracket: tuple[float, ...] = (1.0,)
    iso: int | None = None

    def __post_init__(self) -> None:
        if not self.bracket or any(not f > 0 for f in self.bracket):
            raise ValueError(f"bracket factors must be positive, got {self.bracket!r}")


@dataclass(frozen=True)
class Dark:
    """A dark frame (light off / shutter closed) at the current pose, exposure in s."""

    exposure_s: float | None = None
    iso: int | None = None


@dataclass(frozen=True)
class Reference:
    """Move to the white reference's pose, present the reference and expose it once.

    ``pose``/``joints`` default to the rig file's ``[white_reference]`` geometry.
    """

    pose: Pose | None = None
    joints: Mapping[str, float] | None = None
    exposure_s: float | None = None


@dataclass(frozen=True)
class Checkpoint:
    """A safe point: the engine stops here when the operator asked for a stop."""

    label: str = ""


@dataclass(frozen=True)
class Custom:
    """Call ``fn(context)`` once at this point of the plan (journaled by ``name``).

    ``context`` is the running :class:`acquisition.session.StepContext` (devices, folder,
    current pose). The call is recorded as done, so a replayed plan does not call it again.
    """

    name: str
    fn: Callable[[Any], None] = field(compare=False)


Step = Move | Expose | Dark | Reference | Checkpoint | Custom
"""Any step record."""


def journal_rows(step: Step) -> int:
    """How many journal steps (frames or calls) a record produces."""
    if isinstance(step, Expose):
        return len(step.bracket)
    return 1 if isinstance(step, Dark | Reference | Custom) else 0


def count_rows(steps: Sequence[Step]) -> int:
    """Journal steps a finite plan produces (for progress totals)."""
    return sum(journal_rows(s) for s in steps)


# -------------------------------------------------------------------------- plan builders
def sweep_steps(
    sweep: Sweep,
    *,
    reference_every: int = 0,
    reference: Reference | None = None,
    bracket: tuple[float, ...] = (1.0,),
    exposure_s: float | None = None,
) -> Iterator[Step]:
    """The standard capture of a planned sweep.

    White reference first, every ``reference_every`` poses and last; for each pose a move,
    an exposure and a checkpoint. This is what ``gonio capture`` runs.
    """
    ref = reference or Reference()
    yield ref
    yield Checkpoint()
    for i, planned in enumerate(sweep.steps):
        if reference_every and i and i % reference_every == 0:
            yield ref
            yield Checkpoint()
        yield Move(planned.pose, dict(planned.joints))
        yield Expose(exposure_s, bracket)
        yield Checkpoint()
    yield ref


def pose_steps(
    planner: Planner,
    poses: Sequence[Pose],
    start: Mapping[str, float],
    **kwargs: Any,
) -> Iterator[Step]:
    """Plan ``poses`` (reject unsafe ones, order them) and yield :func:`sweep_steps`.

    ``start`` is the joints (degrees) the arms start from, usually the reference's.
    """
    return sweep_steps(planner.plan(poses, start), **kwargs)
