"""A journal reader opens `immutable` only where the medium cannot take SQLite's side files
(read-only, not writable by the user, full): on writable media it opens `mode=ro`, so it sees
what a writer commits while it reads, and it leaves the folder as it found it."""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import pytest
from disks import fill, readonly_view, small_tmpfs

from acquisition.session.journal import Journal


@pytest.fixture
def journal(tmp_path: Path) -> Path:
    """A checkpointed journal (no -wal, no -shm), as a finished run leaves it."""
    path = tmp_path / "s" / "journal.sqlite"
    path.parent.mkdir()
    with Journal(path) as j:
        j.log("info", "run ended")
    assert sorted(p.name for p in path.parent.iterdir()) == ["journal.sqlite"]
    return path


def _state(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir())}


def _messages(j: Journal) -> list[str]:
    return [e[3] for e in j.events()]


def test_a_reader_on_writable_media_sees_rows_committed_after_it_opened(journal: Path) -> None:
    before = _state(journal.parent)
    reader = Journal(journal, readonly=True)
    try:
        assert _messages(reader) == ["run ended"]
        with Journal(journal) as writer:  # `gonio resume` meanwhile
            writer.log("info", "resumed")
            assert _messages(reader) == ["run ended", "resumed"]  # immutable would not see it
    finally:
        reader.close()
    with Journal(journal, readonly=True) as again:
        assert _messages(again) == ["run ended", "resumed"]
    assert sorted(_state(journal.parent)) == sorted(before)  # no -wal/-shm left behind


def test_readers_leave_the_folder_byte_for_byte_as_they_found_it(journal: Path) -> None:
    before = _state(journal.parent)
    first = Journal(journal, readonly=True)
    with Journal(journal, readonly=True) as second:  # overlapping readers
        assert _messages(second) == ["run ended"]
    assert _messages(first) == ["run ended"]
    first.close()
    assert _state(journal.parent) == before


def test_a_reader_beside_a_live_writer_leaves_its_side_files_alone(journal: Path) -> None:
    with Journal(journal) as writer:
        writer.log("info", "step 1")
        with Journal(journal, readonly=True) as reader:
            assert _messages(reader)[-1] == "step 1"
        writer.log("info", "step 2")  # the writer's log and index are still there
        assert (journal.parent / "journal.sqlite-wal").is_file()
    with Journal(journal, readonly=True) as reader:
        assert _messages(reader)[-2:] == ["step 1", "step 2"]


def test_read_only_media_are_read_immutable_and_untouched(journal: Path, tmp_path: Path) -> None:
    before = _state(journal.parent)
    with readonly_view(journal.parent, tmp_path / "ro") as ro, \
            Journal(ro / "journal.sqlite", readonly=True) as reader:
        assert _messages(reader) == ["run ended"]
    assert _state(journal.parent) == before


def test_a_reader_on_a_full_disk_still_reads(journal: Path, tmp_path: Path) -> None:
    """SQLite cannot make its shared-memory file on a full disk: the reader falls back to
    `immutable` (nothing can be writing there either)."""
    with small_tmpfs(tmp_path / "disk", "1m") as disk:
        shutil.copy(journal, disk / "journal.sqlite")
        fill(disk)
        with Journal(disk / "journal.sqlite", readonly=True) as reader:
            assert _messages(reader) == ["run ended"]
        assert sorted(p.name for p in disk.iterdir()) == ["journal.sqlite", "zz-filler"]
