"""The camera role: what acquisition needs from any camera, real or simulated.

A camera takes one RAW frame per :meth:`Camera.capture` call and writes it to the path it is
given. Writing to a temporary name and renaming it into the session folder is the caller's job;
a camera only promises that the file is complete (flushed to disk) when ``capture`` returns.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

from drivers.errors import HardwareError


class CameraError(HardwareError):
    """A camera refused or failed a capture (bad exposure/ISO, no camera, transfer failed)."""


@dataclass(frozen=True)
class CaptureInfo:
    """What one capture produced.

    Attributes
    ----------
    path:
        The RAW file written.
    exposure_s:
        Exposure time actually used, s.
    iso:
        ISO speed actually used.
    timestamp:
        Start of the exposure, s on the camera's clock (the shared ``SimClock`` for simulated
        cameras, Unix time for real ones).
    """

    path: Path
    exposure_s: float
    iso: float
    timestamp: float


@runtime_checkable
class Camera(Protocol):
    """A camera that writes one RAW frame per capture."""

    def describe(self) -> dict[str, Any]:
        """Static facts: make, model, sensor size (px), bit depth, CFA pattern, source."""
        ...

    def capture(self, path: str | os.PathLike[str], exposure_s: float, iso: float) -> CaptureInfo:
        """Expose for ``exposure_s`` seconds at ``iso`` and write the RAW file to ``path``.

        Raises
        ------
        CameraError
            The camera refused the settings or the capture failed.
        drivers.errors.StorageError
            The file could not be written.
        """
        ...
