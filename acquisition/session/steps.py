"""Step records: what a scripted capture plan is made of.

A plan is data: an iterable (list or generator) of frozen step records, which never touch a
device. The session engine (:class:`acquisition.session.engine.SessionEngine`) acts on them:

=================  ==========================================================================
record             what the engine does
=================  ==========================================================================
:class:`Move`      remember the target pose; the arms move (guarded) only before the next
                   frame that is not yet in the journal, so a resumed plan skips done moves
:class:`Expose`    one RAW frame of the sample at the current pose per ``bracket`` factor
:class:`ExposeHDR` auto-exposure bracket of the sample at the current pose: frames until the
                   ROI is unclipped in the shortest one and its darkest pixel reaches an SNR
:class:`Dark`      one frame with the light off (shutter closed) at the current pose
:class:`Reference` move to the white reference's pose, present it, one frame
:class:`Checkpoint` a safe point: a stop requested by the operator happens here
:class:`Custom`    call ``fn(context)`` once (journaled, never repeated on resume)
=================  ==========================================================================

Every record that produces a journal row (Expose per bracket factor, ExposeHDR per frame
taken, Dark, Reference, Custom) gets the next step number, in plan order. Replaying the same
plan after a crash meets the same numbers, so the engine skips what the journal holds as done
and refuses a plan that differs from the journal.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from acquisition.geometry.kinematics import Pose
from acquisition.planning.planner import Planner, Sweep

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
class ExposeHDR:
    """Auto-exposure bracket of the sample at the current pose (:func:`calibration.hdr.bracket`).

    Starting at ``exposure_s``, the exposure is divided by ``step`` while any ROI pixel clips,
    then the longest one multiplied by ``step`` until the darkest valid ROI superpixel of the
    merge reaches ``target_snr``. Each frame is one journal row whose note is
    ``hdr=<first step>:<index>``; the bracket counts as complete once the engine records it
    in the journal's meta, and an incomplete one is shot again whole on resume.

    Parameters
    ----------
    exposure_s
        First exposure in s (None: the plan's, else the rig's).
    iso
        ISO (None: the plan's, else the rig's).
    target_snr
        SNR the darkest valid ROI superpixel must reach (None: the plan's).
    step
        Exposure ratio between frames (> 1).
    max_frames
        Most frames per bracket.
    """

    exposure_s: float | None = None
    iso: int | None = None
    target_snr: float | None = None
    step: float = 4.0
    max_frames: int = 8

    def __post_init__(self) -> None:
        if not self.step > 1 or self.max_frames < 1:
            raise ValueError(f"HDR step must be > 1 and max_frames ≥ 1, got {self.step}, "
                             f"{self.max_frames}")


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

    ``context`` is the running :class:`acquisition.session.engine.StepContext` (devices, folder,
    current pose). The call is recorded as done, so a replayed plan does not call it again.
    """

    name: str
    fn: Callable[[Any], None] = field(compare=False)


Step = Move | Expose | ExposeHDR | Dark | Reference | Checkpoint | Custom
"""Any step record."""


def journal_rows(step: Step) -> int:
    """How many journal steps (frames or calls) a record produces (an :class:`ExposeHDR`
    bracket: at least 1, known only once it is taken)."""
    if isinstance(step, Expose):
        return len(step.bracket)
    return 1 if isinstance(step, ExposeHDR | Dark | Reference | Custom) else 0


def count_rows(steps: Sequence[Step]) -> int:
    """Journal steps a finite plan produces (for progress totals; a lower bound with HDR)."""
    return sum(journal_rows(s) for s in steps)


# -------------------------------------------------------------------------- plan builders
def sweep_steps(
    sweep: Sweep,
    *,
    reference_every: int = 0,
    reference: Reference | None = None,
    bracket: tuple[float, ...] = (1.0,),
    exposure_s: float | None = None,
    expose: Expose | ExposeHDR | None = None,
) -> Iterator[Step]:
    """The standard capture of a planned sweep.

    White reference first, every ``reference_every`` poses and last; for each pose a move,
    an exposure (``expose``, default ``Expose(exposure_s, bracket)``) and a checkpoint. This
    is what ``gonio capture`` runs.
    """
    return capture_steps([(p.pose, p.joints) for p in sweep.steps],
                         reference_every=reference_every, reference=reference,
                         expose=expose or Expose(exposure_s, bracket))


def capture_steps(
    poses: Sequence[tuple[Pose, Mapping[str, float]]],
    *,
    reference_every: int = 0,
    reference: Reference | None = None,
    expose: Expose | ExposeHDR | None = None,
) -> Iterator[Step]:
    """:func:`sweep_steps` for a list of (pose, joints in deg) already planned."""
    ref = reference or Reference()
    shot = expose or Expose()
    yield ref
    yield Checkpoint()
    for i, (pose, joints) in enumerate(poses):
        if reference_every and i and i % reference_every == 0:
            yield ref
            yield Checkpoint()
        yield Move(pose, dict(joints))
        yield shot
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
