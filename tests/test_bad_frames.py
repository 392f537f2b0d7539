"""Corrupt or truncated frames: one line naming every bad frame and the fix; `gonio info`
counts them as errors; `gonio verify` finds them and a journal that lost its write-ahead log;
`gonio resume` retakes them, giving the table an undamaged session gives."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import EXAMPLES, TINY_PLAN_ARGS, grid_plan_text

from acquisition import api
from acquisition.cli import main


@pytest.fixture
def session(tmp_path: Path) -> Path:
    plan = tmp_path / "plan.toml"
    plan.write_text(grid_plan_text(*TINY_PLAN_ARGS))
    out = tmp_path / "s"
    api.capture(EXAMPLES / "rig-sim.toml", plan, out, material="lambert:albedo=0.5", seed=2)
    return out


def _truncate(frame: Path) -> None:
    data = frame.read_bytes()
    frame.write_bytes(data[: len(data) // 3])


def _one_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, lines
    return lines[0]


def test_bad_frames_are_named_counted_verified_and_retaken(
        session: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    clean = api.reduce(session, tmp_path / "clean.h5").table
    frames = sorted((session / "frames").glob("*.dng"))
    bad = [frames[1], frames[3]]
    for f in bad:
        _truncate(f)

    assert main(["inspect", str(bad[0])]) != 0
    line = _one_line(capsys.readouterr().err)
    assert bad[0].name in line and "truncated" in line

    table = tmp_path / "t.h5"
    assert main(["reduce", str(session), "-o", str(table)]) != 0
    line = _one_line(capsys.readouterr().err)
    assert all(f.name in line for f in bad) and f"gonio resume {session}" in line
    assert not table.exists()

    assert main(["info", str(session), "--no-drift"]) == 0
    out = capsys.readouterr().out
    assert "2 error/warning(s): 2 bad frame(s)" in out

    assert main(["verify", str(session), "--json"]) == 1
    report = __import__("json").loads(capsys.readouterr().out)
    assert sorted(report["mismatched"]) == [f.name for f in bad] and not report["ok"]

    assert main(["resume", str(session)]) == 0
    capsys.readouterr()
    assert main(["verify", str(session)]) == 0
    again = api.reduce(session, table).table
    np.testing.assert_array_equal(again.mean, clean.mean)  # the retaken frames are the same


def test_a_frame_changed_but_still_decodable_is_refused_by_reduce(
        session: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Bytes changed inside a frame's pixels: it still decodes (into wrong values), so only
    its SHA-256 against the journal's tells; reduce refuses it, naming it and the fix."""
    frame = sorted((session / "frames").glob("*.dng"))[2]
    data = bytearray(frame.read_bytes())
    for i in range(len(data) - 3000, len(data) - 1000):  # pixel data, the file's tail
        data[i] ^= 0x5A
    frame.write_bytes(bytes(data))
    assert main(["inspect", str(frame)]) == 0  # LibRaw reads it without complaint
    capsys.readouterr()
    table = tmp_path / "t.h5"
    assert main(["reduce", str(session), "-o", str(table)]) != 0
    line = _one_line(capsys.readouterr().err)
    assert frame.name in line and "corrupt" in line and f"gonio resume {session}" in line
    assert not table.exists()


def test_verify_finds_a_journal_copied_without_its_write_ahead_log(
        session: Path, tmp_path: Path) -> None:
    assert api.verify_session(session).ok
    copy = tmp_path / "copy"
    shutil.copytree(session, copy)
    (copy / "journal.sqlite-shm").write_bytes(b"")  # the -shm came along, the -wal did not
    (copy / "journal.sqlite-wal").unlink(missing_ok=True)
    report = api.verify_session(copy)
    assert not report.ok and "journal.sqlite-wal" in report.journal[0]

    stray = tmp_path / "stray"
    shutil.copytree(session, stray)
    first = sorted((stray / "frames").glob("*.dng"))[0]
    shutil.copy(first, stray / "frames" / "step-000999.dng")  # a frame the journal never saw
    report = api.verify_session(stray)
    assert report.unknown == ["step-000999.dng"] and not report.ok
    assert "not in the journal" in report.journal[-1]
