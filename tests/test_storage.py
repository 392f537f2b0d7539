"""The one file writer (drivers.storage): atomic, verified, umask permissions, causes told apart
in one line, temporary files always removed, clobbering refused."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import pytest
from disks import umask

from acquisition.session import folder as session_folder
from drivers import storage
from drivers.errors import OutputRefused, StorageError
from drivers.storage import (
    SESSION_PROTECTED,
    WriteFailed,
    atomic_output,
    check_output,
    copy_file,
    current_umask,
    ensure_folder,
    is_partial,
    write_bytes,
    write_text,
)


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if is_partial(p))


@pytest.mark.parametrize(("mask", "mode"), [(0o022, 0o644), (0o027, 0o640), (0o002, 0o664)])
def test_outputs_get_the_permissions_the_umask_allows(tmp_path: Path, mask: int, mode: int) -> None:
    with umask(mask):
        assert current_umask() == mask
        write_text(tmp_path / "a.txt", "hello", what="note")
        with atomic_output(tmp_path / "b.bin", what="blob") as tmp:
            os.chmod(tmp, 0o600)  # what mkstemp-style writers leave
            tmp.write_bytes(b"x")
        copy_file(tmp_path / "a.txt", tmp_path / "c.txt", what="copy")
    for name in ("a.txt", "b.bin", "c.txt"):
        assert (tmp_path / name).stat().st_mode & 0o777 == mode, name


def test_reading_the_umask_leaves_it_alone() -> None:
    with umask(0o037):
        assert current_umask() == 0o037
        assert os.umask(0o037) == 0o037


def test_a_failure_inside_keeps_the_previous_file_and_removes_the_temporary(tmp_path: Path) -> None:
    final = tmp_path / "t.bin"
    final.write_bytes(b"previous")
    with (pytest.raises(StorageError) as info,
          atomic_output(final, what="table", ours=True) as tmp):
        tmp.write_bytes(b"half")
        raise OSError(errno.ENOSPC, "No space left on device")
    assert final.read_bytes() == b"previous"
    assert leftovers(tmp_path) == []
    msg = str(info.value)
    assert msg.startswith(f"cannot write table {final}: disk full") and "\n" not in msg
    assert info.value.errno == errno.ENOSPC


@pytest.mark.parametrize(("code", "cause"), [
    (errno.ENOSPC, "disk full"), (errno.EDQUOT, "disk full"), (errno.EROFS, "read-only filesystem"),
    (errno.EACCES, "permission denied"), (errno.EPERM, "permission denied"),
])
def test_causes_are_told_apart_by_errno(tmp_path: Path, code: int, cause: str) -> None:
    with (pytest.raises(StorageError) as info,
          atomic_output(tmp_path / "x.csv", what="CSV export")):
        raise OSError(code, os.strerror(code))
    msg = str(info.value)
    assert f"cannot write CSV export {tmp_path / 'x.csv'}: {cause}" in msg and "\n" not in msg
    assert "-o PATH" in msg  # the fix
    assert leftovers(tmp_path) == []


def test_not_a_folder_and_missing_folder(tmp_path: Path) -> None:
    afile = tmp_path / "afile"
    afile.write_text("x")
    with pytest.raises(StorageError, match=f"not a folder; {afile} is a file"):
        write_text(afile / "sub" / "x.txt", "y", what="note")
    with pytest.raises(StorageError, match=f"not a folder; {afile} is a file"):
        ensure_folder(afile / "sub", what="session folder")
    with pytest.raises(StorageError, match=f"folder missing; {tmp_path / 'no'} does not exist"):
        write_text(tmp_path / "no" / "x.txt", "y", what="note")


def test_an_empty_or_unverifiable_result_is_a_failed_write(tmp_path: Path) -> None:
    with (pytest.raises(StorageError, match="nothing was written"),
          atomic_output(tmp_path / "e.h5", what="table")):
        pass
    assert not (tmp_path / "e.h5").exists()

    def bad(_: Path) -> None:
        raise ValueError("truncated")

    with pytest.raises(StorageError, match="does not read back .truncated"):
        write_bytes(tmp_path / "v.bin", b"data", what="blob", verify=bad)
    assert sorted(os.listdir(tmp_path)) == []


def test_a_library_failing_without_errno_is_diagnosed_from_the_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    real = os.statvfs

    class Full:
        def __init__(self, st: os.statvfs_result) -> None:
            self.f_flag, self.f_frsize, self.f_files = st.f_flag, st.f_frsize, st.f_files
            self.f_bavail, self.f_favail = 0, st.f_favail

    monkeypatch.setattr(storage.os, "statvfs", lambda p: Full(real(p)))
    with (pytest.raises(StorageError, match="disk full"),
          atomic_output(tmp_path / "a.exr", what="EXR slice")):
        raise WriteFailed("Failed OpenEXR write")
    assert os.listdir(tmp_path) == []


def test_other_gonio_errors_pass_through_after_cleanup(tmp_path: Path) -> None:
    from drivers.camera import CameraError

    with (pytest.raises(CameraError, match="flash"),
          atomic_output(tmp_path / "f.dng", what="frame") as tmp):
        tmp.write_bytes(b"II*\0")
        raise CameraError("flash failed")
    assert os.listdir(tmp_path) == []


def test_clobbering_is_refused(tmp_path: Path) -> None:
    inp = tmp_path / "in.h5"
    inp.write_bytes(b"table")
    other = tmp_path / "notes.txt"
    other.write_text("mine")
    with pytest.raises(OutputRefused, match="this command's input"):
        check_output(inp, what="CSV export", ours=True, inputs=(inp,))
    link = tmp_path / "link.h5"
    link.symlink_to(inp)
    with pytest.raises(OutputRefused, match="this command's input"):
        check_output(link, what="CSV export", ours=True, inputs=(inp,))
    with pytest.raises(OutputRefused, match="not a CSV export gonio wrote"):
        write_text(other, "new", what="CSV export", ours=lambda p: False)
    with pytest.raises(OutputRefused, match="a folder"):
        write_text(tmp_path, "new", what="CSV export", ours=True)
    assert other.read_text() == "mine" and inp.read_bytes() == b"table"
    write_text(other, "new", what="CSV export", ours=lambda p: p.read_text() == "mine")
    assert other.read_text() == "new"


def test_a_sessions_own_files_are_refused_to_everyone_but_the_session(tmp_path: Path) -> None:
    s = tmp_path / "s"
    (s / "frames").mkdir(parents=True)
    for name in ("journal.sqlite", "session.json", "rig.toml", "plan.toml"):
        (s / name).write_text(name)
    for name in (*SESSION_PROTECTED, "frames/step-000001.dng", "calibration/flat.exr"):
        with pytest.raises(OutputRefused, match=f"session {s}'s"):
            check_output(s / name, what="BRDF table", ours=True)
    with pytest.raises(OutputRefused, match=f"session {s}'s frames"):
        ensure_folder(s / "frames" / "exr", what="EXR folder")
    check_output(s / "brdf.h5", what="BRDF table")  # beside them is fine
    check_output(s / "frames" / "step-000001.dng", what="frame", ours=True, own_session=True)


def test_the_session_layout_is_protected_as_a_whole() -> None:
    names = {session_folder.RIG_FILE, session_folder.PLAN_FILE, session_folder.INFO_FILE,
             session_folder.JOURNAL_FILE, session_folder.FRAMES_DIR,
             session_folder.CALIBRATION_DIR, session_folder.JOURNAL_FILE + "-wal",
             session_folder.JOURNAL_FILE + "-shm"}
    assert names == set(SESSION_PROTECTED)
    assert set(storage.SESSION_MARKERS) <= names


def test_partial_names_keep_the_extension_and_are_recognised(tmp_path: Path) -> None:
    p = storage.partial_name(tmp_path / "brdf.h5")
    assert p.parent == tmp_path and p.suffix == ".h5" and p.name.startswith(".brdf.")
    assert is_partial(p) and is_partial("step-000001.dng.partial")
    assert not is_partial(tmp_path / "brdf.h5") and not is_partial(".hidden.dng")
