"""Inputs are sacred, outputs are readable: no command writes over its inputs, a session's own
files or a file that is not an earlier output of the same kind; sessions on read-only media
are inspected, reduced and exported (only resume needs write access, and says so); readers
never write into a session; a finished or stopped run leaves a journal complete on its own;
outputs get the permissions the umask allows."""

from __future__ import annotations

import shutil
import sqlite3
from pathlib import Path

import numpy as np
import pytest
from conftest import EXAMPLES, TINY_MATERIAL
from disks import one_error_line, readonly_view, tree_hashes, umask

from acquisition import api
from acquisition.cli import main
from acquisition.tables import IsotropicTable

RIG = EXAMPLES / "rig-sim.toml"


def refused(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    capsys.readouterr()
    code = main(argv)
    err = capsys.readouterr().err
    assert code != 0, f"{argv} succeeded"
    return one_error_line(err)


def ok(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    code = main(argv)
    out, err = capsys.readouterr()
    assert code == 0, err
    return out


@pytest.fixture
def work(finished: dict[str, Path], lightstage_field: dict[str, Path],
         tmp_path: Path) -> dict[str, Path]:
    """Writable copies of the fixtures' session, table, light-stage field and environment."""
    shutil.copytree(finished["session"], tmp_path / "s")
    shutil.copy(finished["table"], tmp_path / "t.h5")
    shutil.copytree(lightstage_field["field"], tmp_path / "field")
    shutil.copy(lightstage_field["env"], tmp_path / "env.exr")
    (tmp_path / "notes.txt").write_text("my notes")
    (tmp_path / "photo.png").write_bytes(b"\x89PNG\r\n\x1a\n not a gonio plot")
    return {"s": tmp_path / "s", "t": tmp_path / "t.h5", "field": tmp_path / "field",
            "env": tmp_path / "env.exr", "plan": finished["plan"], "root": tmp_path,
            "l": lightstage_field["session"]}


# ---------------------------------------------------------------------------- clobbering
def test_reduce_refuses_to_replace_the_sessions_journal(work: dict[str, Path],
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    s = work["s"]
    before = tree_hashes(s)
    line = refused(["reduce", str(s), "-o", str(s / "journal.sqlite")], capsys)
    assert "refusing to write BRDF table" in line and "journal" in line
    assert tree_hashes(s) == before
    ok(["info", str(s), "--no-drift"], capsys)  # still a session, not "file is not a database"


def test_export_refuses_to_replace_its_input_table(work: dict[str, Path],
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    t = work["t"]
    before = tree_hashes(t)
    for fmt in ("csv", "merl"):
        line = refused(["export", str(t), "--format", fmt, "-o", str(t)], capsys)
        assert "this command's input" in line
    assert tree_hashes(t) == before
    IsotropicTable.load_h5(t)


@pytest.mark.parametrize(("case", "argv", "says"), [
    ("reduce over the rig copy", ["reduce", "{s}", "-o", "{s}/rig.toml"], "rig copy"),
    ("reduce over a frame", ["reduce", "{s}", "-o", "{s}/frames/step-000000.dng"], "frames"),
    ("reduce over a user's file", ["reduce", "{s}", "-o", "{notes}"], "not a BRDF table gonio wrote"),
    ("a table over a CSV name that is a table", ["export", "{t}", "--format", "csv", "-o",
                                                 "{s}/brdf.h5"], "not a CSV export gonio wrote"),
    ("MERL over a user's file", ["export", "{t}", "--format", "merl", "-o", "{notes}"],
     "not a MERL file gonio wrote"),
    ("EXR slices into the frames", ["export", "{t}", "--format", "exr", "-o", "{s}/frames"],
     "frames"),
    ("EXR slices into a file", ["export", "{t}", "--format", "exr", "-o", "{notes}"],
     "not a folder"),
    ("relight over its environment", ["relight", "{field}", "--env", "{env}", "-o", "{env}"],
     "this command's input"),
    ("relight over a field image", ["relight", "{field}", "--env", "{env}", "-o",
                                    "{field}/light-000.exr"], "this command's input"),
    ("plot over a photo", ["plan", "{plan}", "--rig", str(RIG), "-o", "{photo}"],
     "not a plot gonio wrote"),
    ("calibrate into a session's calibration", ["calibrate", "dark", "--rig", str(RIG), "-o",
                                                "{s}/calibration"], "calibration copy"),
    ("calibrate into a session's bundle copy", ["calibrate", "dark", "--rig", str(RIG), "-o",
                                                "{s}/calibration"], "calibration copy"),
    ("field into a session's frames", ["lightstage", "field", "{l}", "-o", "{l}/frames"], "frames"),
])
def test_other_clobbering_is_refused(case: str, argv: list[str], says: str,
                                     work: dict[str, Path],
                                     capsys: pytest.CaptureFixture[str]) -> None:
    names = {"s": work["s"], "t": work["t"], "notes": work["root"] / "notes.txt",
             "field": work["field"], "env": work["env"], "plan": work["plan"],
             "photo": work["root"] / "photo.png", "l": work["l"]}
    if case == "a table over a CSV name that is a table":
        shutil.copy(work["t"], work["s"] / "brdf.h5")
    if case == "calibrate into a session's bundle copy":
        (work["s"] / "calibration").mkdir()
        (work["s"] / "calibration" / "bundle.json").write_text(
            '{"format": "gonio-calibration-bundle", "version": 1, "darks": {}, "noise": {}}')
    before = tree_hashes(work["root"], work["l"])
    line = refused([a.format(**names) for a in argv], capsys)
    assert says in line, line
    assert tree_hashes(work["root"], work["l"]) == before


def test_capture_refuses_an_out_inside_its_calibration(tmp_path: Path,
                                                       finished: dict[str, Path],
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    cal = tmp_path / "cal"
    cal.mkdir()
    (cal / "flat.exr").write_bytes(b"flat")
    line = refused(["capture", "--rig", str(RIG), "--plan", str(finished["plan"]), "-o",
                    str(cal / "s"), "--material", TINY_MATERIAL, "--calibration", str(cal)], capsys)
    assert "inside the calibration folder" in line
    assert sorted(p.name for p in cal.iterdir()) == ["flat.exr"]


def test_earlier_outputs_of_the_same_kind_are_replaced(work: dict[str, Path],
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    r, t = work["root"], work["t"]
    runs = [["reduce", str(work["s"]), "-o", str(r / "again.h5")],
            ["reduce", str(work["s"])],
            ["export", str(t), "--format", "csv", "-o", str(r / "t.csv")],
            ["export", str(t), "--format", "merl", "-o", str(r / "t.binary")],
            ["export", str(t), "--format", "exr", "-o", str(r / "exr")],
            ["plan", str(work["plan"]), "--rig", str(RIG), "-o", str(r / "plan.svg")],
            ["relight", str(work["field"]), "--env", str(work["env"]), "-o", str(r / "relit.exr")],
            ["calibrate", "dark", "--rig", str(RIG), "-o", str(r / "bundle")]]
    for argv in runs + runs:  # every output written twice
        ok(argv, capsys)
    assert (work["s"] / "brdf.h5").is_file()


# ---------------------------------------------------------------------------- read-only media
def test_a_session_on_read_only_media_is_inspected_reduced_and_exported(
    finished: dict[str, Path], lightstage_field: dict[str, Path], tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    media = tmp_path / "media"
    media.mkdir()
    shutil.copytree(finished["session"], media / "s")
    shutil.copy(finished["table"], media / "t.h5")
    shutil.copytree(lightstage_field["session"], media / "l", ignore=shutil.ignore_patterns("field"))
    with readonly_view(media, tmp_path / "ro") as ro:
        before = tree_hashes(ro)
        ok(["info", str(ro / "s")], capsys)  # the drift reads the frames too
        ok(["reduce", str(ro / "s"), "-o", str(tmp_path / "t.h5")], capsys)
        ok(["export", str(ro / "t.h5"), "--format", "csv", "-o", str(tmp_path / "t.csv")], capsys)
        ok(["lightstage", "field", str(ro / "l"), "-o", str(tmp_path / "field")], capsys)
        line = refused(["resume", str(ro / "s")], capsys)
        assert "resuming needs write access" in line
        assert "read-only filesystem" in line or "not writable by you" in line
        line = refused(["reduce", str(ro / "s")], capsys)  # the default table goes beside it
        assert f"cannot write BRDF table {ro / 's' / 'brdf.h5'}" in line
        assert "read-only filesystem" in line or "permission denied" in line
        assert tree_hashes(ro) == before
    a = IsotropicTable.load_h5(tmp_path / "t.h5")
    b = IsotropicTable.load_h5(finished["table"])
    np.testing.assert_array_equal(a.count, b.count)
    np.testing.assert_array_equal(a.mean, b.mean)


def test_a_never_checkpointed_journal_on_read_only_media_is_named(
    finished: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    s = tmp_path / "s"
    shutil.copytree(finished["session"], s)
    writer = sqlite3.connect(s / "journal.sqlite")
    writer.execute("PRAGMA wal_autocheckpoint=0")
    writer.execute("INSERT INTO events (at, level, message) VALUES (0, 'info', 'late')")
    writer.commit()
    media = tmp_path / "media"
    shutil.copytree(s, media / "s", ignore=shutil.ignore_patterns("*-shm"))  # as a crash copy
    writer.close()
    assert (media / "s" / "journal.sqlite-wal").stat().st_size > 0
    with readonly_view(media, tmp_path / "ro") as ro:
        line = refused(["info", str(ro / "s"), "--no-drift"], capsys)
    assert "never checkpointed" in line and "copy the session to a writable disk" in line


def test_inspecting_and_reducing_write_nothing_into_the_session(
    work: dict[str, Path], lightstage_field: dict[str, Path], tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    s = work["s"]
    shutil.copytree(lightstage_field["session"], tmp_path / "l", ignore=shutil.ignore_patterns("field"))
    before = {p: tree_hashes(p) for p in (s, tmp_path / "l")}
    for argv in (["info", str(s)], ["reduce", str(s), "-o", str(tmp_path / "elsewhere.h5")],
                 ["info", str(tmp_path / "l"), "--no-drift"],
                 ["lightstage", "field", str(tmp_path / "l"), "-o", str(tmp_path / "f2")],
                 ["reduce", str(tmp_path / "l"), "-o", str(tmp_path / "l.h5")]):
        ok(argv, capsys)
        assert {p: tree_hashes(p) for p in before} == before, argv  # no -wal/-shm, no rows


# ---------------------------------------------------------------------------- the journal
@pytest.mark.parametrize("stop_after", [None, 2])
def test_a_finished_or_stopped_run_leaves_a_journal_complete_on_its_own(
    stop_after: int | None, finished: dict[str, Path], tmp_path: Path
) -> None:
    """A reader attached when the run ends (``gonio info`` in another terminal) used to keep
    the last transactions in ``journal.sqlite-wal``: a copy of the folder lost them."""
    out = tmp_path / "s"
    readers: list[sqlite3.Connection] = []

    def attach(folder: api.SessionFolder, _t: float | None) -> None:
        db = sqlite3.connect(f"{(folder.path / 'journal.sqlite').as_uri()}?mode=ro", uri=True)
        db.execute("SELECT COUNT(*) FROM steps").fetchone()
        readers.append(db)

    def progress(done: int, _total: int, _rec: object) -> None:
        if stop_after is not None and done >= stop_after:
            raise KeyboardInterrupt

    try:
        if stop_after is None:
            api.capture(RIG, finished["plan"], out, material=TINY_MATERIAL, on_open=attach)
        else:
            with pytest.raises(api.GonioError, match="interrupted"):
                api.capture(RIG, finished["plan"], out, material=TINY_MATERIAL, on_open=attach,
                            progress=progress)
        copy = tmp_path / "copy"
        copy.mkdir()
        shutil.copy(out / "journal.sqlite", copy / "journal.sqlite")  # the main file alone
    finally:
        for db in readers:
            db.close()
    db = sqlite3.connect(copy / "journal.sqlite")
    counts = dict(db.execute("SELECT status, COUNT(*) FROM steps GROUP BY status").fetchall())
    last = db.execute("SELECT message FROM events ORDER BY id DESC LIMIT 1").fetchone()[0]
    db.close()
    if stop_after is None:
        assert set(counts) == {"done"} and last.startswith("run ended")
    else:
        assert counts["done"] == stop_after and "interrupted" in last


# ---------------------------------------------------------------------------- permissions
@pytest.mark.parametrize(("mask", "mode"), [(0o022, 0o644), (0o027, 0o640)])
def test_every_output_gets_the_permissions_the_umask_allows(
    mask: int, mode: int, work: dict[str, Path], lightstage_field: dict[str, Path],
    tmp_path: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    out = tmp_path / "out"
    with umask(mask):
        ok(["capture", "--rig", str(RIG), "--plan", str(work["plan"]), "-o", str(out / "s"),
            "--material", TINY_MATERIAL], capsys)
        ok(["reduce", str(out / "s")], capsys)
        t = out / "s" / "brdf.h5"
        for fmt, name in (("merl", "t.binary"), ("csv", "t.csv"), ("exr", "exr")):
            ok(["export", str(t), "--format", fmt, "-o", str(out / name)], capsys)
        ok(["calibrate", "dark", "--rig", str(RIG), "-o", str(out / "bundle")], capsys)
        ok(["plan", str(work["plan"]), "--rig", str(RIG), "-o", str(out / "plan.png")], capsys)
        ok(["lightstage", "field", str(lightstage_field["session"]), "-o", str(out / "field")],
           capsys)
        ok(["relight", str(out / "field"), "--env", str(work["env"]), "-o", str(out / "r.exr")],
           capsys)
        api.plot_slices(IsotropicTable.load_h5(t), None, out / "slices.png")
    files = sorted(p for p in out.rglob("*") if p.is_file())
    kinds = {p.suffix for p in files}
    assert {".h5", ".binary", ".csv", ".exr", ".json", ".png", ".dng", ".toml", ".sqlite"} <= kinds
    wrong = {str(p.relative_to(out)): oct(p.stat().st_mode & 0o777) for p in files
             if p.stat().st_mode & 0o777 != mode}
    assert wrong == {}
