"""Frames as the camera device reports them, and frames shot outside a sweep.

In a sweep, gonio's session engine writes and journals each frame (``SESSION/frames/
step-NNNNNN.dng``); outside one, the camera writes ``frame-NNNNNN.dng`` into the folder given to
:func:`acquisition.bluesky.open_rig_devices`, through the same atomic writer and frame check.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from acquisition.session.engine import StepEvent
from acquisition.session.frames import check_raw_frame
from drivers.camera import CaptureInfo
from drivers.errors import ConfigError
from drivers.storage import atomic_output, ensure_folder, sha256_file

FREE_KIND = "frame"
"""The ``kind`` of a frame shot outside a sweep (a sweep's are the journal's: pose, reference)."""

FREE_SEED_OFFSET = 500_000_017
"""Added to a free frame's simulated noise seed, apart from any session step's."""


@dataclass(frozen=True)
class Shot:
    """One RAW frame written: where, its exposure, its hash and what it was.

    ``step`` is the journal step (a sweep) or the frame's number (outside one); ``joints`` the
    read-back joints (deg) the frame was taken at, when the journal knows them.
    """

    path: Path
    exposure_s: float
    iso: int
    sha256: str
    step: int
    kind: str
    joints: dict[str, float] | None = None

    @classmethod
    def from_event(cls, event: StepEvent) -> Shot:
        """The frame a session engine just journaled."""
        rec = event.record
        assert event.frame is not None and rec.sha256 is not None
        return cls(event.frame, float(rec.exposure_s or 0.0), int(rec.iso or 0), rec.sha256, rec.step,
                   rec.kind, dict(rec.joints_read) if rec.joints_read else None)


def free_frame_path(folder: Path | None) -> tuple[Path, int]:
    """The next free ``frame-NNNNNN.dng`` in ``folder`` and its number (rig's thread).

    Raises
    ------
    ConfigError
        No folder was given for frames shot outside a sweep.
    """
    if folder is None:
        raise ConfigError("the camera was triggered outside brdf_sweep, but no folder takes such "
                          "frames: pass open_rig_devices(..., frames_dir=DIR)")
    ensure_folder(folder, what="frames folder")
    taken = [int(p.stem.removeprefix("frame-")) for p in folder.glob("frame-*.dng")
             if p.stem.removeprefix("frame-").isdigit()]
    number = max(taken, default=0) + 1
    return folder / f"frame-{number:06d}.dng", number


Capture = Callable[[Path, float, int, int], CaptureInfo]
"""gonio's open devices' ``capture(path, exposure_s, iso, frame_seed)``."""


def shoot_free(capture: Capture, folder: Path | None, exposure_s: float, iso: int, seed: int) -> Shot:
    """Write one frame outside a sweep with ``capture(path, exposure_s, iso, frame_seed)`` (gonio's
    open devices' ``capture``), atomically and checked as a session's frames are."""
    final, number = free_frame_path(folder)
    with atomic_output(final, what="frame", verify=check_raw_frame) as tmp:
        info = capture(tmp, exposure_s, iso, seed * 1_000_003 + FREE_SEED_OFFSET + number)
    return Shot(final, float(info.exposure_s), int(info.iso), sha256_file(final), number, FREE_KIND)
