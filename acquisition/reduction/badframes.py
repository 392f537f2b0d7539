"""Frames a reduction cannot read: collected, so that one error lists every bad frame.

A reduction goes on past a frame whose RAW file cannot be decoded (truncated, corrupted on a
copy) or whose bytes no longer have the SHA-256 the journal recorded when it was written (a
corruption that still decodes, into wrong pixels), and, once every frame has been tried, stops
with one line naming them all and the fix: `gonio resume` sees their SHA-256 no longer match
the journal and retakes them. No table is written from a session with a bad frame.

A frame's SHA-256 is computed in a helper thread while it is decoded (hashlib releases the GIL):
a 24 MP frame's hash costs about half its decode, which it then no longer adds to. A frame whose
hash differs is dropped whatever its decode gave.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar

from acquisition.session.folder import FRAMES_DIR
from acquisition.session.journal import StepRecord
from acquisition.session.verify import frame_matches_journal
from drivers.errors import RawFormatError, SessionError

T = TypeVar("T")
SHOWN = 5
"""Bad frames named in the one-line error (the count says how many there are)."""
_HASHER: list[ThreadPoolExecutor] = []


def _hasher() -> ThreadPoolExecutor:
    """The process's thread that hashes frames while they are decoded (made on first use)."""
    if not _HASHER:
        _HASHER.append(ThreadPoolExecutor(1, thread_name_prefix="gonio-frame-hash"))
    return _HASHER[0]


class BadFramesError(SessionError):
    """Frames of a session cannot be read; the message names them and the fix."""


@dataclass
class FrameCheck:
    """Collects the frames of one reduction that fail to load."""

    session: Path
    bad: list[str] = field(default_factory=list)

    def load(self, records: StepRecord | Sequence[StepRecord], read: Callable[[], T]) -> T | None:
        """``read()`` of the frames of ``records`` (one, or an HDR bracket's), or None (and a
        frame noted) when a frame's bytes differ from the SHA-256 its journal row recorded or
        its RAW file cannot be decoded."""
        rows = [records] if isinstance(records, StepRecord) else list(records)
        frames = self.session / FRAMES_DIR
        hashed = [_hasher().submit(frame_matches_journal, frames, rec) for rec in rows]
        try:
            value, decoded = read(), True
        except RawFormatError:
            value, decoded = None, False
        for rec, same in zip(rows, hashed, strict=True):
            if not same.result():
                self.bad.append(str(rec.frame))
                return None
        if not decoded:
            self.bad.append(str(rows[0].frame))
        return value

    def raise_if_any(self) -> None:
        """:class:`BadFramesError` naming every bad frame, if there is one."""
        if not self.bad:
            return
        names = ", ".join(self.bad[:SHOWN]) + (f" and {len(self.bad) - SHOWN} more"
                                                 if len(self.bad) > SHOWN else "")
        raise BadFramesError(
            f"{self.session}: {len(self.bad)} frame(s) cannot be read (corrupt or truncated: "
            f"{names}); `gonio verify {self.session}` checks them all, `gonio resume "
            f"{self.session}` retakes them"
        )
