"""The session journal: an SQLite (WAL) record of every step's intent and completion.

A step is planned once, when the session is created, with its pose and commanded joints.
Completing it records the frame's file name and SHA-256, the read-back joints, exposure and
timestamps in one transaction, so after a crash every step is either done (with a frame whose
hash can be checked) or still to do.

A writer checkpoints the write-ahead log into ``journal.sqlite`` when it closes (a finished or
stopped run), so a copied folder is complete. A reader (``readonly=True``) never changes the
session: it opens the journal ``mode=ro``, so it sees what a writer commits meanwhile; SQLite
then makes ``-wal``/``-shm`` side files, which the reader removes when it closes if it made
them (through a closing connection, as SQLite removes them, only when no other connection is
open). ``immutable`` (no side files, no locks) is used only where the side files cannot be
made: a folder on read-only media or not writable by this user, a full disk, or a ``-shm``
without its ``-wal`` (a folder copied without its write-ahead log, which ``gonio verify``
reports).
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import sqlite3
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from drivers.errors import SessionError, StorageError
from drivers.storage import diagnose, storage_error, write_blocker

SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS steps (
    step INTEGER PRIMARY KEY,
    kind TEXT NOT NULL,               -- 'pose' | 'reference' | 'dark' | 'custom'
    theta_i REAL, theta_r REAL, delta_phi REAL,   -- degrees (NULL for 'custom')
    joints_cmd TEXT NOT NULL,         -- JSON {axis: degrees} ({} for 'custom')
    status TEXT NOT NULL DEFAULT 'planned',       -- planned | started | done
    attempts INTEGER NOT NULL DEFAULT 0,
    joints_read TEXT,                 -- JSON {axis: degrees}, read back after the move
    frame TEXT,                       -- file name under frames/
    sha256 TEXT,
    exposure_s REAL, iso INTEGER,
    started_at REAL, completed_at REAL,           -- host UNIX time, s
    device_time_s REAL,               -- device clock at completion (simulated rigs), s
    note TEXT                         -- custom step name, bracket factor, … (JSON or text)
);
CREATE TABLE IF NOT EXISTS events (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    at REAL NOT NULL, level TEXT NOT NULL, step INTEGER, message TEXT NOT NULL
);
"""


@dataclass(frozen=True)
class StepRecord:
    """One row of the journal."""

    step: int
    kind: str
    theta_i: float | None
    theta_r: float | None
    delta_phi: float | None
    joints_cmd: dict[str, float]
    status: str
    attempts: int
    joints_read: dict[str, float] | None
    frame: str | None
    sha256: str | None
    exposure_s: float | None
    iso: int | None
    started_at: float | None
    completed_at: float | None
    device_time_s: float | None
    note: str | None = None


_COLUMNS = (
    "step, kind, theta_i, theta_r, delta_phi, joints_cmd, status, attempts, joints_read, frame, "
    "sha256, exposure_s, iso, started_at, completed_at, device_time_s, note"
)


def _record(row: Sequence[Any]) -> StepRecord:
    return StepRecord(
        row[0], row[1], row[2], row[3], row[4], json.loads(row[5]), row[6], row[7],
        json.loads(row[8]) if row[8] else None, *row[9:],
    )


def _sqlite_errno(exc: sqlite3.Error, folder: Path) -> int | None:
    """The errno behind an SQLite error (SQLite reports none), from its text or the folder."""
    text = str(exc).lower()
    if "full" in text:
        return errno.ENOSPC
    if "readonly" in text or "read-only" in text:
        return write_blocker(folder) or errno.EROFS
    if "unable to open" in text or "disk i/o" in text:
        if not os.path.isdir(folder):
            return errno.ENOENT
        return diagnose(folder) or (errno.EIO if "i/o" in text else None)
    return None


class Journal:
    """Open (or create) the journal database of a session folder."""

    def __init__(self, path: str | Path, *, readonly: bool = False,
                 retry: str | None = None) -> None:
        """``retry``: the fix's second half when a write fails (default: resume the session)."""
        self.path = Path(path)
        self.readonly = readonly
        self.retry = retry if retry is not None else f", then `gonio resume {self.path.parent}`"
        fresh = [p for p in self._sidecars if not p.exists()]
        self._made_sidecars = False
        try:
            self._open(readonly)
        except (SessionError, StorageError):
            with contextlib.suppress(AttributeError, sqlite3.Error):
                self._db.close()
            if self._made_sidecars:
                self._remove_made_sidecars()
            for p in fresh:  # empty side files SQLite made before it failed
                with contextlib.suppress(OSError):
                    if p.stat().st_size == 0:
                        p.unlink()
            raise

    def _open(self, readonly: bool) -> None:
        try:
            if readonly:
                self._db = self._open_reader()
                self._db.execute("SELECT COUNT(*) FROM steps")
                return
            self._db = sqlite3.connect(self.path, isolation_level=None)
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=FULL")
            self._db.executescript(SCHEMA)
            columns = {r[1] for r in self._db.execute("PRAGMA table_info(steps)")}
            if "note" not in columns:  # journals written before the column existed
                self._db.execute("ALTER TABLE steps ADD COLUMN note TEXT")
        except sqlite3.OperationalError as exc:
            code = None if readonly else _sqlite_errno(exc, self.path.parent)
            if code is not None:
                raise self._storage_error(exc, code) from None
            raise SessionError(f"journal {self.path} is unreadable ({exc}): the session is damaged") from None
        except sqlite3.DatabaseError as exc:
            raise SessionError(f"journal {self.path} is unreadable ({exc}): the session is damaged") from None

    @property
    def _sidecars(self) -> tuple[Path, Path]:
        return (self.path.with_name(self.path.name + "-wal"),
                self.path.with_name(self.path.name + "-shm"))

    def _open_reader(self) -> sqlite3.Connection:
        """A connection that never changes the session (see the module docstring)."""
        uri = self.path.resolve().as_uri()
        wal, shm = self._sidecars
        live = wal.is_file() and wal.stat().st_size > 0
        read_only_folder = write_blocker(self.path.parent) is not None
        blocked = read_only_folder or not os.access(self.path, os.W_OK)  # could not clean up
        if live and read_only_folder and not shm.is_file():
            raise SessionError(
                f"journal {self.path} has a write-ahead log that was never checkpointed (the run "
                "did not end cleanly) and the folder is read-only: copy the session to a "
                "writable disk to read it")
        if not live and (blocked or (shm.exists() and not wal.exists())):
            return self._connect(f"{uri}?mode=ro&immutable=1")
        fresh = not wal.exists() and not shm.exists()
        db = self._connect(f"{uri}?mode=ro")
        if not fresh:
            return db
        try:
            db.execute("SELECT COUNT(*) FROM sqlite_master").fetchone()
        except sqlite3.OperationalError:
            db.close()
            if diagnose(self.path.parent) != errno.ENOSPC:
                raise
            # No room for the side files: nothing can be writing here either.
            self._unlink_fresh_sidecars()
            return self._connect(f"{uri}?mode=ro&immutable=1")
        self._made_sidecars = True
        return db

    @staticmethod
    def _connect(uri: str) -> sqlite3.Connection:
        return sqlite3.connect(uri, uri=True, isolation_level=None)

    def _unlink_fresh_sidecars(self) -> None:
        """Remove the side files a failed reader made (the WAL still empty: nothing in use)."""
        wal, shm = self._sidecars
        if wal.exists() and wal.stat().st_size > 0:
            return
        for p in (wal, shm):
            with contextlib.suppress(OSError):
                p.unlink()

    def _remove_made_sidecars(self) -> None:
        """Remove the ``-wal``/``-shm`` files this reader's open made, the way SQLite does: a
        read-write connection that closes last deletes them (none open elsewhere: it leaves
        them to the others). Nothing else changes: the log is empty, so there is nothing to
        checkpoint."""
        wal, _ = self._sidecars
        if not wal.exists() or wal.stat().st_size > 0:  # a writer came and went, or is writing
            return
        with contextlib.suppress(sqlite3.Error):
            db = self._connect(f"{self.path.resolve().as_uri()}?mode=rw")
            try:
                db.execute("SELECT COUNT(*) FROM sqlite_master").fetchone()
            finally:
                db.close()

    def _storage_error(self, exc: sqlite3.Error, code: int) -> StorageError:
        return storage_error(OSError(code, str(exc)), self.path, "the journal", self.retry)

    def checkpoint(self) -> None:
        """Move the write-ahead log into ``journal.sqlite`` and empty it (writers only)."""
        self._db.execute("PRAGMA wal_checkpoint(TRUNCATE)")

    def close(self) -> None:
        """Checkpoint (a writer; silently skipped when the disk is full) and close."""
        if not self.readonly:
            with contextlib.suppress(sqlite3.Error):
                self.checkpoint()
        self._db.close()
        if self._made_sidecars:
            self._made_sidecars = False
            self._remove_made_sidecars()

    def __enter__(self) -> Journal:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _write(self, sql: str, params: Sequence[Any] = ()) -> None:
        try:
            self._db.execute(sql, params)
        except sqlite3.OperationalError as exc:
            code = _sqlite_errno(exc, self.path.parent)
            if code is not None:
                raise self._storage_error(exc, code) from None
            raise

    # -- metadata ------------------------------------------------------------------------

    def set_meta(self, key: str, value: Any) -> None:
        self._write("INSERT OR REPLACE INTO meta VALUES (?, ?)", (key, json.dumps(value)))

    def meta(self, key: str, default: Any = None) -> Any:
        row = self._db.execute("SELECT value FROM meta WHERE key = ?", (key,)).fetchone()
        return default if row is None else json.loads(row[0])

    # -- steps ---------------------------------------------------------------------------

    def plan_steps(self, rows: Sequence[tuple[str, float, float, float, dict[str, float]]]) -> None:
        """Record the planned steps (kind, θi, θr, Δφ, joints) once, in capture order."""
        if self._db.execute("SELECT COUNT(*) FROM steps").fetchone()[0]:
            raise SessionError(f"journal {self.path} already holds a plan")
        self._db.execute("BEGIN")
        try:
            self._db.executemany(
                "INSERT INTO steps (step, kind, theta_i, theta_r, delta_phi, joints_cmd) "
                "VALUES (?, ?, ?, ?, ?, ?)",
                [(i, k, ti, tr, dp, json.dumps(j)) for i, (k, ti, tr, dp, j) in enumerate(rows)],
            )
            self._db.execute("COMMIT")
        except BaseException as exc:
            with contextlib.suppress(sqlite3.Error):
                self._db.execute("ROLLBACK")
            code = _sqlite_errno(exc, self.path.parent) if isinstance(exc, sqlite3.Error) else None
            if code is not None:
                raise self._storage_error(exc, code) from None  # type: ignore[arg-type]
            raise

    def add_step(
        self,
        step: int,
        kind: str,
        pose: tuple[float, float, float] | None,
        joints: dict[str, float],
        note: str | None = None,
    ) -> StepRecord:
        """Record one planned step met for the first time by a scripted plan."""
        ti, tr, dp = pose if pose is not None else (None, None, None)
        self._write(
            "INSERT INTO steps (step, kind, theta_i, theta_r, delta_phi, joints_cmd, note) "
            "VALUES (?, ?, ?, ?, ?, ?, ?)",
            (step, kind, ti, tr, dp, json.dumps(joints), note),
        )
        rec = self.record(step)
        assert rec is not None
        return rec

    def record(self, step: int) -> StepRecord | None:
        """The journal row of ``step``, or None."""
        row = self._db.execute(f"SELECT {_COLUMNS} FROM steps WHERE step = ?", (step,)).fetchone()
        return None if row is None else _record(row)

    def mark_started(self, step: int) -> None:
        self._write(
            "UPDATE steps SET status = 'started', attempts = attempts + 1, started_at = ? "
            "WHERE step = ?",
            (time.time(), step),
        )

    def mark_done(
        self,
        step: int,
        *,
        frame: str,
        sha256: str,
        joints_read: dict[str, float],
        exposure_s: float,
        iso: int,
        device_time_s: float | None,
    ) -> None:
        self._write(
            "UPDATE steps SET status = 'done', frame = ?, sha256 = ?, joints_read = ?, "
            "exposure_s = ?, iso = ?, completed_at = ?, device_time_s = ? WHERE step = ?",
            (frame, sha256, json.dumps(joints_read), exposure_s, iso, time.time(),
             device_time_s, step),
        )

    def mark_called(self, step: int, device_time_s: float | None) -> None:
        """Complete a step that produces no frame (a custom call)."""
        self._write(
            "UPDATE steps SET status = 'done', completed_at = ?, device_time_s = ? WHERE step = ?",
            (time.time(), device_time_s, step),
        )

    def mark_redo(self, step: int, why: str) -> None:
        """Return a step to 'planned' (its frame was missing or did not match its hash)."""
        self._write(
            "UPDATE steps SET status = 'planned', frame = NULL, sha256 = NULL WHERE step = ?",
            (step,),
        )
        self.log("warning", why, step)

    def steps(self) -> Iterator[StepRecord]:
        for row in self._db.execute(f"SELECT {_COLUMNS} FROM steps ORDER BY step"):
            yield _record(row)

    def counts(self) -> dict[str, int]:
        return dict(self._db.execute("SELECT status, COUNT(*) FROM steps GROUP BY status").fetchall())

    # -- events --------------------------------------------------------------------------

    def log(self, level: str, message: str, step: int | None = None) -> None:
        self._write(
            "INSERT INTO events (at, level, step, message) VALUES (?, ?, ?, ?)",
            (time.time(), level, step, message),
        )

    def try_log(self, level: str, message: str, step: int | None = None) -> None:
        """Like :meth:`log`, but silent when the journal cannot be written (full disk)."""
        with contextlib.suppress(StorageError, sqlite3.Error):
            self.log(level, message, step)

    def events(self) -> list[tuple[float, str, int | None, str]]:
        return self._db.execute("SELECT at, level, step, message FROM events ORDER BY id").fetchall()

    def integrity_problems(self) -> list[str]:
        """What SQLite's own integrity check finds wrong with the journal (empty: sound)."""
        try:
            rows = [r[0] for r in self._db.execute("PRAGMA integrity_check")]
        except sqlite3.DatabaseError as exc:
            return [str(exc)]
        return [] if rows == ["ok"] else rows
