"""Disks that fail for tests: injected errno at file creation or rename under a folder (runs
everywhere), real small tmpfs mounts filled up, and read-only mounts or views (root, or chmod
for other users), plus the checks every output test makes."""

from __future__ import annotations

import errno
import hashlib
import io
import os
import shutil
import subprocess
import uuid
from collections.abc import Iterable, Iterator
from contextlib import contextmanager, suppress
from pathlib import Path

import pytest

from drivers.storage import is_partial

FILLER = "zz-filler"
"""Name of the file that fills a tmpfs (not an output)."""


def tree_hashes(*paths: Path) -> dict[str, str]:
    """SHA-256 of every file under ``paths`` (a file or a folder), by path."""
    out: dict[str, str] = {}
    for root in paths:
        files = [root] if root.is_file() else sorted(p for p in root.rglob("*") if p.is_file())
        for f in files:
            out[str(f)] = hashlib.sha256(f.read_bytes()).hexdigest()
    return out


def bad_leftovers(root: Path) -> list[str]:
    """Temporary, half-written or empty files under ``root`` (there must be none)."""
    bad = []
    for p in root.rglob("*"):
        if p.name == FILLER or p.is_dir():
            continue
        if is_partial(p) or p.stat().st_size == 0:
            bad.append(str(p.relative_to(root)))
    return sorted(bad)


def _under(path: object, root: str) -> bool:
    if isinstance(path, int):
        return False
    p = os.path.realpath(os.fspath(path))  # type: ignore[arg-type]
    return p == root or p.startswith(root + os.sep)


@contextmanager
def injected(monkeypatch: pytest.MonkeyPatch, root: Path, code: int, at: str) -> Iterator[None]:
    """Under ``root``: with ``at="create"`` every new file or folder fails with ``code``; with
    ``at="commit"`` every rename into it does (the data were written, the rename fails)."""
    where = os.path.realpath(root)
    real_open, real_mkdir, real_replace, real_io_open = os.open, os.mkdir, os.replace, io.open

    def fail(path: object) -> OSError:
        return OSError(code, os.strerror(code), os.fspath(path))  # type: ignore[arg-type]

    def fake_open(path, flags, mode=0o777, *, dir_fd=None):  # noqa: ANN001, ANN202
        if at == "create" and flags & os.O_CREAT and _under(path, where):
            raise fail(path)
        return real_open(path, flags, mode, dir_fd=dir_fd)

    def fake_mkdir(path, mode=0o777, *, dir_fd=None):  # noqa: ANN001, ANN202
        if at == "create" and _under(path, where):
            raise fail(path)
        return real_mkdir(path, mode, dir_fd=dir_fd)

    def fake_io_open(file, mode="r", *args, **kwargs):  # noqa: ANN001, ANN202
        if at == "create" and any(c in mode for c in "wax") and _under(file, where) \
                and not os.path.exists(file):
            raise fail(file)
        return real_io_open(file, mode, *args, **kwargs)

    def fake_replace(src, dst, *args, **kwargs):  # noqa: ANN001, ANN202
        if at == "commit" and _under(dst, where):
            raise fail(dst)
        return real_replace(src, dst, *args, **kwargs)

    with monkeypatch.context() as m:
        m.setattr(os, "open", fake_open)
        m.setattr(os, "mkdir", fake_mkdir)
        m.setattr(os, "replace", fake_replace)
        m.setattr(io, "open", fake_io_open)
        m.setattr("builtins.open", fake_io_open)
        yield


def _mount(*args: str) -> None:
    subprocess.run(["mount", *args], check=True, capture_output=True, text=True)


def _umount(path: Path) -> None:
    subprocess.run(["umount", "-l", str(path)], capture_output=True)


@contextmanager
def small_tmpfs(path: Path, size: str = "2m") -> Iterator[Path]:
    """A tmpfs of ``size`` mounted at ``path`` (skips the test when mounting is not allowed)."""
    path.mkdir(parents=True, exist_ok=True)
    if os.geteuid() != 0:
        pytest.skip("mounting a small tmpfs needs root; the injected-error cases cover this")
    try:
        _mount("-t", "tmpfs", "-o", f"size={size},mode=0755", f"gonio-test-{uuid.uuid4().hex[:6]}",
               str(path))
    except (OSError, subprocess.CalledProcessError) as exc:
        pytest.skip(f"cannot mount a tmpfs here ({getattr(exc, 'stderr', exc)!s}".strip() + ")")
    try:
        yield path
    finally:
        _umount(path)


def fill(root: Path, leave: int = 0) -> None:
    """Fill the filesystem of ``root`` with one file until it is full, then free ``leave`` bytes."""
    block = b"\0" * 4096
    with open(root / FILLER, "wb", buffering=0) as fh, suppress(OSError):
        while True:
            fh.write(block)
    with suppress(OSError):
        os.truncate(root / FILLER, max(0, os.path.getsize(root / FILLER) - leave))
    st = os.statvfs(root)
    assert st.f_bavail * st.f_frsize <= leave + 8192, "the tmpfs did not fill up"


def remount_readonly(root: Path) -> None:
    _mount("-o", "remount,ro", str(root))


@contextmanager
def readonly_view(source: Path, where: Path) -> Iterator[Path]:
    """``source`` seen read-only at ``where``: a read-only bind mount as root, else a copy
    made unwritable with chmod (both are real: writes fail with EROFS or EACCES)."""
    if os.geteuid() == 0:
        where.mkdir(parents=True)
        try:
            _mount("--bind", str(source), str(where))
            _mount("-o", "remount,bind,ro", str(where))
        except (OSError, subprocess.CalledProcessError) as exc:
            _umount(where)
            pytest.skip(f"cannot bind-mount read-only here ({getattr(exc, 'stderr', exc)!s})")
        try:
            yield where
        finally:
            _umount(where)
        return
    shutil.copytree(source, where)
    for p in [where, *where.rglob("*")]:
        p.chmod(p.stat().st_mode & ~0o222)
    try:
        yield where
    finally:
        for p in [where, *where.rglob("*")]:
            p.chmod(p.stat().st_mode | 0o200)


@contextmanager
def umask(mask: int) -> Iterator[None]:
    """Run the block under ``mask``."""
    old = os.umask(mask)
    try:
        yield
    finally:
        os.umask(old)


def one_error_line(err: str) -> str:
    """The single stderr line of a failed command (fails the test otherwise)."""
    lines = [line for line in err.strip().splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in err, f"expected one error line, got:\n{err}"
    assert lines[0].startswith("gonio: error: "), lines[0]
    return lines[0]


def files_under(paths: Iterable[Path]) -> list[Path]:
    return sorted(f for p in paths for f in ([p] if p.is_file() else p.rglob("*")) if f.is_file())


ERRNO_CAUSE = {errno.ENOSPC: "disk full", errno.EROFS: "read-only filesystem",
               errno.EACCES: "permission denied"}
