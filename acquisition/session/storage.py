"""Durable files: temporary name, fsync, rename; hashes; disk-full errors that keep data safe."""

from __future__ import annotations

import errno
import hashlib
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from drivers.errors import StorageError

TMP_SUFFIX = ".partial"
"""Suffix of files being written; a file with it after a crash is discarded on resume."""


def sha256_file(path: str | Path) -> str:
    """Hex SHA-256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def fsync_path(path: str | Path) -> None:
    """Flush a file's (or a directory's) contents to disk."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextmanager
def atomic_target(final: str | Path) -> Iterator[Path]:
    """Yield a temporary path to write; on success fsync it and rename it to ``final``.

    On any error the temporary file is removed and ``final`` is untouched. A full disk
    becomes a :class:`StorageError` naming the folder.
    """
    final = Path(final)
    tmp = final.with_name(final.name + TMP_SUFFIX)
    try:
        yield tmp
        fsync_path(tmp)
        os.replace(tmp, final)
        fsync_path(final.parent)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        if exc.errno in (errno.ENOSPC, errno.EDQUOT):
            raise StorageError(
                f"disk full writing {final} : free space on {final.parent}, then `gonio resume`"
            ) from None
        raise
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
