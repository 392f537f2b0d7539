"""The one exception hierarchy of gonio, rooted in :class:`GonioError`.

Every package may import this module (it imports nothing of ours). Each error's message is a
single line that names the cause (device, port, file, field) and the operator's next step; the
CLI prints it as ``gonio: error: <message>`` and exits non-zero, without a traceback.
Where a standard type fits, the error also inherits it (``LimitError`` is a ``ValueError``).
"""

from __future__ import annotations


class GonioError(Exception):
    """Root of every error gonio raises on purpose."""

    exit_code: int = 2


class ConfigError(GonioError, ValueError):
    """A rig, plan or calibration file is malformed or names something that does not exist."""


class LimitError(GonioError, ValueError):
    """A pose or joint target lies outside the rig's limits (nothing was sent)."""


class UnreachablePoseError(LimitError):
    """No joint solution reaches a requested (θi, θr, Δφ) pose."""


class CollisionError(LimitError):
    """A move would bring two arms, or an arm and the beam, too close (nothing was sent)."""


class CommunicationError(GonioError, OSError):
    """A port could not be opened, or a device stopped answering after bounded retries."""


class HardwareError(GonioError, RuntimeError):
    """A device reports a fault of its own (overload, overheating, voltage, ...)."""


class SafetyStop(GonioError, RuntimeError):
    """The operator or a guard stopped motion; the session is left resumable."""

    exit_code = 130


class RawFormatError(GonioError, ValueError):
    """A RAW file is corrupt, unreadable, or not a Bayer mosaic."""


class CalibrationError(GonioError, ValueError):
    """Calibration data are missing, inconsistent, or do not match the frame."""


class SessionError(GonioError, RuntimeError):
    """A session folder is missing, already exists, or is inconsistent with its journal."""


class MaterialError(GonioError, ValueError):
    """A material spec string is malformed or names an unknown model."""


class StorageError(GonioError, OSError):
    """Writing to disk failed (disk full, read-only, permissions, not a folder); nothing
    half-written is left under a final name and a session is left resumable."""


class OutputRefused(GonioError, ValueError):
    """An output path would overwrite an input, a session's own files, or a file that gonio did
    not write as that kind of output (nothing was written)."""
