"""Stale numba caches of kernels that call compiled functions of other files.

numba's on-disk cache (``cache=True``) is invalidated by a change to a function's own file
only; a kernel that calls (and so compiles in) a function of another file would run stale
machine code after an edit there. A module whose kernels do calls :func:`drop_stale_cache` on
import, before numba loads anything: when the sources of the files it depends on differ from
those its cached code was compiled with (a digest kept beside the cache), that cache is deleted.

A dependency edited while this process runs may already be imported, its old code in memory:
what this process compiles and caches then is not what the file on disk says. So a dependency
imported already and modified since this module was loaded (not later than now: a file dated
in the future is a clock's skew, not an edit) leaves an untrusted stamp, and the next process
compiles afresh.
"""

from __future__ import annotations

import hashlib
import sys
import time
from collections.abc import Iterable
from pathlib import Path

LOADED_AT = time.time()
"""When this process loaded this module (s since the epoch): before any kernel module."""
UNTRUSTED = "a dependency changed while the process that compiled this cache ran"

DECLARED: dict[Path, frozenset[Path]] = {}
"""The dependencies each module declared, by module file (tests/test_numba_cache.py checks that
every cached kernel module declares the files whose compiled functions it holds)."""


def drop_stale_cache(module_file: str | Path, dependencies: Iterable[str | Path]) -> None:
    """Delete ``module_file``'s cached machine code (``__pycache__/<stem>.*.nbi|nbc``) when a
    dependency's source changed since it was compiled."""
    here = Path(module_file).resolve()
    dependencies = [Path(p).resolve() for p in dependencies]
    DECLARED[here] = frozenset(dependencies)
    digest = hashlib.sha256(b"".join(p.read_bytes() for p in dependencies)).hexdigest()
    changed = _edited_in_memory(dependencies)
    cache = here.parent / "__pycache__"
    stamp = cache / f"{here.stem}.deps"
    try:
        if not changed and stamp.is_file() and stamp.read_text() == digest:
            return
        for old in cache.glob(f"{here.stem}.*.nb[ic]"):
            old.unlink(missing_ok=True)
        cache.mkdir(exist_ok=True)
        stamp.write_text(UNTRUSTED if changed else digest)
    except OSError:  # a read-only install: numba caches elsewhere (or not at all)
        pass


def _edited_in_memory(dependencies: list[Path]) -> bool:
    """Whether a dependency this process imported already was modified since :data:`LOADED_AT`."""
    now = time.time()
    imported = {getattr(m, "__file__", None) for m in list(sys.modules.values())}
    return any(str(p) in imported and LOADED_AT < p.stat().st_mtime <= now
               for p in dependencies)
