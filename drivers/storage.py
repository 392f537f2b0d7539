"""The disk is a device: the one way gonio writes a file, and disk errors told apart.

Every output (tables, exports, frames, bundles, plots, reports, relit images, session files)
goes through :func:`atomic_output`: a temporary name in the target folder
(``.NAME.XXXXXXXX.partial.EXT``), the caller writes it, it is verified (not empty, and the
caller's ``verify`` re-opens it), given the permissions the umask allows (``0o666 & ~umask``),
fsynced, renamed over the final name, and the folder is fsynced. On any failure the temporary
file is removed and the error becomes one :class:`StorageError` line naming the path, the cause
(disk full, read-only filesystem, permission denied, not a folder, folder missing) and the fix.
Nothing half-written or empty is ever left under a final name.

Before anything is written, :func:`check_output` refuses (:class:`OutputRefused`) a path that is
one of the command's inputs, one of a session folder's own files (:data:`SESSION_PROTECTED`), a
folder, or an existing file that ``ours`` does not recognise as a previous output of that kind.
"""

from __future__ import annotations

import errno
import hashlib
import os
import re
import secrets
import threading
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Any

from drivers.errors import GonioError, OutputRefused, StorageError

PARTIAL = ".partial"
"""Mark in the name of a file being written; one left by a crash is never a finished file."""

SESSION_MARKERS = ("session.json", "journal.sqlite")
"""A folder holding both is a gonio session folder."""

SESSION_PROTECTED = {
    "journal.sqlite": "journal", "journal.sqlite-wal": "journal (write-ahead log)",
    "journal.sqlite-shm": "journal (shared memory)", "session.json": "provenance file",
    "rig.toml": "rig copy", "plan.toml": "plan copy", "frames": "frames",
    "calibration": "calibration copy",
}
"""Entries of a session folder no command may write over (only the session engine writes them)."""

LOW_SPACE_BYTES = 1 << 20
"""Free space under which a write that failed without an errno is put down to a full disk."""

Ours = Callable[[Path], bool] | bool | None
"""May an existing file be replaced: a recogniser of previous outputs of the kind, True
(gonio owns the path), or None (never)."""

_UMASK_LOCK = threading.Lock()


class Discard(Exception):
    """Raise inside :func:`atomic_output`, or from its ``verify``, to drop the temporary file
    without an error (the caller catches it: a frame to retake, say)."""


class WriteFailed(OSError):
    """A library reported a failed write without an errno (OpenImageIO, ...): raise it inside
    :func:`atomic_output` and the folder is examined for the cause."""


# ---------------------------------------------------------------------------- primitives
def sha256_file(path: str | os.PathLike[str]) -> str:
    """Hex SHA-256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def fsync_path(path: str | os.PathLike[str]) -> None:
    """Flush a file's or a folder's contents to disk (folders that cannot be fsynced are skipped)."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    except OSError as exc:
        if exc.errno not in (errno.EINVAL, errno.ENOTSUP, errno.EBADF):
            raise
    finally:
        os.close(fd)


def current_umask() -> int:
    """The process's umask, read without changing it where the system says (Linux ``/proc``)."""
    with suppress(OSError, ValueError), open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    with _UMASK_LOCK:  # elsewhere: set and restore at once, serialised
        mask = os.umask(0o077)
        os.umask(mask)
    return mask


def file_mode() -> int:
    """Permissions of a new file: what the umask allows of ``0o666``."""
    return 0o666 & ~current_umask()


def partial_name(final: Path) -> Path:
    """A fresh temporary name beside ``final`` that keeps its extension (writers choose the
    format by it)."""
    stem, suffix = final.stem[:160], final.suffix[:16]
    return final.with_name(f".{stem}.{secrets.token_hex(4)}{PARTIAL}{suffix}")


def is_partial(path: str | os.PathLike[str]) -> bool:
    """A temporary file of :func:`atomic_output` (or of gonio before it: ``NAME.partial``)."""
    name = Path(path).name
    return (name.startswith(".") and PARTIAL + "." in name + ".") or name.endswith(PARTIAL)


# ---------------------------------------------------------------------------- causes
def write_blocker(folder: str | os.PathLike[str]) -> int | None:
    """EROFS when ``folder`` is on a read-only filesystem, EACCES when this process may not
    write in it, else None."""
    try:
        if os.statvfs(folder).f_flag & os.ST_RDONLY:
            return errno.EROFS
    except OSError as exc:
        return exc.errno
    return None if os.access(folder, os.W_OK) else errno.EACCES


def diagnose(folder: str | os.PathLike[str]) -> int | None:
    """The errno a write into ``folder`` most likely met when a library did not say."""
    try:
        st = os.statvfs(folder)
    except OSError as exc:
        return exc.errno
    if st.f_flag & os.ST_RDONLY:
        return errno.EROFS
    if st.f_bavail * st.f_frsize < LOW_SPACE_BYTES or (st.f_files and not st.f_favail):
        return errno.ENOSPC
    return None if os.access(folder, os.W_OK) else errno.EACCES


def _existing_ancestor(path: Path) -> Path:
    for p in (path, *path.parents):
        if os.path.lexists(p):
            return p
    return Path(".")


def _errno_of(exc: BaseException) -> int | None:
    for e in (exc, exc.__cause__, exc.__context__):
        if isinstance(e, OSError) and e.errno:
            return e.errno
    m = re.search(r"errno\s*=\s*(\d+)|\[Errno (\d+)\]", str(exc))
    return int(m.group(1) or m.group(2)) if m else None


def _free(folder: Path) -> str:
    """`` (12 KiB free)`` when the folder's disk is nearly full, `` (no inodes left)``, or ``""``."""
    try:
        st = os.statvfs(folder)
    except OSError:
        return ""
    free = st.f_bavail * st.f_frsize
    if st.f_files and not st.f_favail:
        return " (no inodes left)"
    if free >= LOW_SPACE_BYTES:
        return ""
    return f" ({free} B free)" if free < 1024 else f" ({free / 1024:.1f} KiB free)"


def explain(code: int | None, path: Path, retry: str | None = None,
            detail: str = "") -> tuple[str, str]:
    """(cause, fix) of a failed write of ``path`` with errno ``code``.

    ``retry`` is what to do once the cause is fixed (default: or write elsewhere with -o).
    """
    alt = retry if retry is not None else " or write elsewhere (-o PATH)"
    where = _existing_ancestor(path.parent)
    if code in (errno.ENOSPC, errno.EDQUOT):
        return f"disk full{_free(where)}", f"free space on {where}{alt}"
    if code == errno.EROFS:
        return "read-only filesystem", f"remount {where} read-write{alt}"
    if code in (errno.EACCES, errno.EPERM):
        return "permission denied", f"get write permission on {where}{alt}"
    if code in (errno.ENOTDIR, errno.EEXIST, errno.EISDIR):
        blocker = next((p for p in (path, *path.parents)
                        if os.path.lexists(p) and not os.path.isdir(p)), None)
        if blocker is None:
            return "not a file", f"{path} is a folder: give a file name"
        return "not a folder", f"{blocker} is a file, not a folder: choose another path"
    if code == errno.ENOENT:
        if where != path.parent:
            return "folder missing", f"{path.parent} does not exist: create it or choose another path"
        return "no new files allowed here", f"{where} does not take new files: choose a folder on a disk"
    text = os.strerror(code) if code else (detail or "the write failed")
    return one_line(text), f"check the disk{alt}"


def one_line(text: str, limit: int = 240) -> str:
    """``text`` on one line, cut to ``limit`` characters."""
    flat = " ".join(str(text).split())
    return flat if len(flat) <= limit else flat[: limit - 1] + "…"


def storage_error(exc: BaseException, path: str | os.PathLike[str], what: str,
                  retry: str | None = None) -> StorageError:
    """The one-line :class:`StorageError` for ``exc`` met writing ``what`` at ``path``."""
    path = Path(path)
    code = _errno_of(exc)
    if code is None:
        code = diagnose(_existing_ancestor(path.parent))
    detail = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
    cause, fix = explain(code, path, retry, detail)
    err = StorageError(f"cannot write {what} {path}: {cause}; {fix}")
    err.errno = code
    return err


def os_error_line(exc: OSError) -> str:
    """One line for an OSError nothing turned into a GonioError (the CLI's last resort)."""
    name = exc.filename if exc.filename is not None else "a file"
    cause, fix = explain(exc.errno, Path(str(name)), None, exc.strerror or str(exc))
    return f"cannot use {name}: {cause}; {fix}"


# ---------------------------------------------------------------------------- refusals
def protected_by(path: str | os.PathLike[str]) -> str | None:
    """``"session S's journal"`` etc. when ``path`` is (inside) a session folder's own files."""
    p = Path(os.path.realpath(path))
    for folder in p.parents:
        if all((folder / m).is_file() for m in SESSION_MARKERS):
            first = p.relative_to(folder).parts[0]
            if first in SESSION_PROTECTED:
                return f"session {folder}'s {SESSION_PROTECTED[first]}"
    return None


def _input_hit(path: Path, inputs: Iterable[str | os.PathLike[str]]) -> str | None:
    for inp in inputs:
        with suppress(OSError):
            if os.path.samefile(path, inp):
                return str(inp)
    return None


def check_output(path: str | os.PathLike[str], *, what: str, ours: Ours = None,
                 inputs: Iterable[str | os.PathLike[str]] = (), own_session: bool = False) -> Path:
    """Refuse (:class:`OutputRefused`) writing ``what`` at ``path`` when that would clobber
    something: an input, a session's own files (unless ``own_session``: the session engine), a
    folder, or an existing file ``ours`` does not accept. Returns ``path``."""
    path = Path(path)
    reason = None
    hit = _input_hit(path, inputs) if os.path.exists(path) else None
    if hit is not None:
        reason = f"this command's input {hit}"
    elif not own_session and (where := protected_by(path)):
        reason = where
    elif os.path.isdir(path):
        reason = "a folder"
    elif os.path.lexists(path):
        accepted = ours if isinstance(ours, bool) else (ours is not None and ours(path))
        if not accepted:
            reason = f"an existing file that is not a {what} gonio wrote"
    if reason is not None:
        raise OutputRefused(f"refusing to write {what} over {path}: it is {reason}; choose "
                            "another output path (-o PATH)")
    return path


def check_folder(path: str | os.PathLike[str], *, what: str,
                 inputs: Iterable[str | os.PathLike[str]] = (), own_session: bool = False) -> Path:
    """Refuse an output folder that is an input or a session's own folder
    (:class:`OutputRefused`), or that exists as a file (:class:`StorageError`)."""
    path = Path(path)
    hit = _input_hit(path, inputs) if os.path.exists(path) else None
    where = None if own_session else protected_by(path)
    if hit or where:
        reason = where or f"this command's input {hit}"
        raise OutputRefused(f"refusing to write {what} into {path}: it is {reason}; choose "
                            "another output path (-o PATH)")
    if os.path.lexists(path) and not os.path.isdir(path):
        raise storage_error(OSError(errno.ENOTDIR, "not a folder"), path, what)
    return path


def ensure_folder(path: str | os.PathLike[str], *, what: str,
                  inputs: Iterable[str | os.PathLike[str]] = (), own_session: bool = False,
                  retry: str | None = None) -> Path:
    """Create the output folder ``path`` (and its parents) unless it exists, after
    :func:`check_folder`; an OSError becomes a one-line :class:`StorageError`."""
    path = check_folder(path, what=what, inputs=inputs, own_session=own_session)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise storage_error(exc, path, what, retry) from None
    return path


# ---------------------------------------------------------------------------- the writer
class _Unverified(OSError):
    """The temporary file is empty or does not read back."""


def _commit(tmp: Path, final: Path, verify: Callable[[Path], object] | None,
            allow_empty: bool) -> None:
    if os.stat(tmp).st_size == 0 and not allow_empty:
        raise _Unverified("nothing was written")
    if verify is not None:
        try:
            verify(tmp)
        except Discard:
            raise
        except Exception as exc:
            raise _Unverified(f"the written file does not read back ({one_line(str(exc), 120)})") from exc
    with suppress(PermissionError, NotImplementedError):
        os.chmod(tmp, file_mode())
    fsync_path(tmp)
    os.replace(tmp, final)
    fsync_path(final.parent)


@contextmanager
def atomic_output(path: str | os.PathLike[str], *, what: str,
                  verify: Callable[[Path], object] | None = None, ours: Ours = None,
                  inputs: Iterable[str | os.PathLike[str]] = (), own_session: bool = False,
                  retry: str | None = None, allow_empty: bool = False) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` to write ``what`` into; on success verify, fsync
    and rename it to ``path`` (see the module docstring).

    ``verify(tmp)`` re-opens the written file and raises if it is not whole (or raises
    :class:`Discard` to drop it quietly). ``ours``,
    ``inputs`` and ``own_session`` are :func:`check_output`'s. ``retry`` is the fix's second
    half (default " or write elsewhere (-o PATH)"; a session: ", then `gonio resume S`").
    GonioErrors other than StorageError raised inside pass through unchanged (after cleanup).
    An empty result is a failed write unless ``allow_empty``.
    """
    final = check_output(path, what=what, ours=ours, inputs=inputs, own_session=own_session)
    tmp = partial_name(final)
    try:
        os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o666))
    except OSError as exc:
        raise storage_error(exc, final, what, retry) from None
    try:
        yield tmp
        _commit(tmp, final, verify, allow_empty)
    except BaseException as exc:
        with suppress(OSError):
            os.unlink(tmp)
        if isinstance(exc, OSError) and not (isinstance(exc, GonioError)
                                             and not isinstance(exc, StorageError)):
            raise storage_error(exc, final, what, retry) from None
        raise


def _size_is(size: int) -> Callable[[Path], None]:
    def check(tmp: Path) -> None:
        if os.path.getsize(tmp) != size:
            raise _Unverified(f"{os.path.getsize(tmp)} of {size} bytes reached the disk")
    return check


def write_bytes(path: str | os.PathLike[str], data: bytes, *, what: str,
                verify: Callable[[Path], object] | None = None, **kw: Any) -> Path:
    """Write ``data`` to ``path`` through :func:`atomic_output` (keywords as there); the size
    is checked, then ``verify``."""
    def check(tmp: Path) -> None:
        _size_is(len(data))(tmp)
        if verify is not None:
            verify(tmp)

    with atomic_output(path, what=what, verify=check, **kw) as tmp, open(tmp, "wb") as fh:
        fh.write(data)
    return Path(path)


def write_text(path: str | os.PathLike[str], text: str, *, what: str,
               verify: Callable[[Path], object] | None = None, **kw: Any) -> Path:
    """Write ``text`` (UTF-8) to ``path`` through :func:`atomic_output`."""
    return write_bytes(path, text.encode("utf-8"), what=what, verify=verify, **kw)


def copy_file(source: str | os.PathLike[str], path: str | os.PathLike[str], *, what: str,
              **kw: Any) -> Path:
    """Copy ``source`` to ``path`` through :func:`atomic_output` (size checked)."""
    size = os.path.getsize(source)
    with (atomic_output(path, what=what, verify=_size_is(size), allow_empty=size == 0, **kw)
          as tmp, open(source, "rb") as src, open(tmp, "wb") as dst):
        while chunk := src.read(1 << 20):
            dst.write(chunk)
    return Path(path)
