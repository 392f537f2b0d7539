"""``gonio verify``: can a session folder (copied between disks or machines) be trusted?

Every frame the journal records as done is re-hashed against the SHA-256 the journal holds;
the journal passes SQLite's integrity check; frames on disk the journal does not know, or a
``-shm`` file without its ``-wal``, mean the journal's write-ahead log did not come along with
the copy (its last steps live only there).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from acquisition.session.folder import JOURNAL_FILE, SessionFolder
from acquisition.session.journal import StepRecord
from drivers.storage import is_partial, sha256_file


@dataclass
class VerifyReport:
    """What :func:`verify_session` found."""

    session: Path
    frames_checked: int = 0
    missing: list[str] = field(default_factory=list)
    """Frames the journal records as done that are not on disk."""
    mismatched: list[str] = field(default_factory=list)
    """Frames whose SHA-256 differs from the journal's (corrupt, truncated or altered)."""
    unknown: list[str] = field(default_factory=list)
    """Frames on disk the journal does not record as done."""
    journal: list[str] = field(default_factory=list)
    """Problems of the journal itself."""

    @property
    def bad_frames(self) -> int:
        return len(self.missing) + len(self.mismatched)

    @property
    def ok(self) -> bool:
        return not (self.bad_frames or self.journal)

    def lines(self) -> list[str]:
        out = [f"{self.session}: {self.frames_checked} frames checked against the journal's "
               f"SHA-256: {'all match' if not self.bad_frames else f'{self.bad_frames} bad'}"]
        out += [f"  missing   {f}" for f in self.missing]
        out += [f"  corrupt   {f} (SHA-256 differs)" for f in self.mismatched]
        out += [f"  journal   {p}" for p in self.journal]
        if self.bad_frames:
            out.append(f"  `gonio resume {self.session}` retakes the bad frames")
        return out

    def to_json(self) -> dict[str, Any]:
        return {"session": str(self.session), "ok": self.ok, "frames_checked": self.frames_checked,
                "missing": self.missing, "mismatched": self.mismatched, "unknown": self.unknown,
                "journal": self.journal}


def frame_matches_journal(frames_dir: Path, rec: StepRecord) -> bool:
    """Whether a done step's frame still has the SHA-256 its journal row recorded (True for a
    row with none, or a missing file: the frame's reader names that)."""
    if rec.sha256 is None:
        return True
    try:
        return sha256_file(frames_dir / str(rec.frame)) == rec.sha256
    except FileNotFoundError:
        return True


def verify_session(path: str | Path) -> VerifyReport:
    """Re-hash every done frame and check the journal (read only: nothing is written)."""
    folder = SessionFolder(path)
    report = VerifyReport(folder.path)
    journal_file = folder.path / JOURNAL_FILE
    wal, shm = (journal_file.with_name(journal_file.name + s) for s in ("-wal", "-shm"))
    lost_wal = shm.exists() and not wal.exists()  # looked at before SQLite opens it
    with folder.journal(readonly=True) as journal:
        report.journal += journal.integrity_problems()
        done = [r for r in journal.steps() if r.status == "done" and r.frame]
    for rec in done:
        frame = folder.frames_dir / str(rec.frame)
        report.frames_checked += 1
        if not frame.is_file():
            report.missing.append(str(rec.frame))
        elif not frame_matches_journal(folder.frames_dir, rec):
            report.mismatched.append(str(rec.frame))
    known = {str(r.frame) for r in done}
    report.unknown = sorted(p.name for p in folder.frames_dir.glob("*")
                            if p.is_file() and p.name not in known and not is_partial(p))
    if lost_wal:
        report.journal.append(
            "journal.sqlite-shm is here but journal.sqlite-wal is not: the journal's write-ahead "
            "log (its latest steps) was not copied; copy it from the source folder")
    if report.unknown:
        report.journal.append(
            f"{len(report.unknown)} frame(s) on disk are not in the journal ({report.unknown[0]}"
            f"{', ...' if len(report.unknown) > 1 else ''}): either a run stopped between writing "
            f"and journaling them (`gonio resume` retakes them) or the journal's write-ahead log "
            f"(journal.sqlite-wal) was not copied with the folder")
    return report
