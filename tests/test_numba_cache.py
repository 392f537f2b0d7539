"""numba's on-disk cache is invalidated by a change to a function's own file only: a cached
kernel that compiles in another file's functions would run stale machine code after an edit
there (a ``git pull``, an upgrade in place). Every module with cached kernels that uses another
module's compiled functions declares that file, and what that file declares in turn, to
:func:`drivers.numba_cache.drop_stale_cache`; and the digest it keeps drops the cache when one
changes."""

from __future__ import annotations

import importlib
import os
import sys
import time
import types
from pathlib import Path

import pytest
from numba.core.caching import NullCache
from numba.core.registry import CPUDispatcher

from drivers import numba_cache

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("acquisition", "calibration", "simulators", "drivers")


def _kernel_modules() -> list[types.ModuleType]:
    """Every module of the project whose source defines a numba kernel, imported."""
    modules = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            if "njit" not in path.read_text(encoding="utf-8"):
                continue
            name = ".".join(path.relative_to(ROOT).with_suffix("").parts)
            modules.append(importlib.import_module(name.removesuffix(".__init__")))
    return modules


def _file(obj: object) -> Path:
    return Path(obj.__file__ if isinstance(obj, types.ModuleType)  # type: ignore[union-attr]
                else importlib.import_module(obj.py_func.__module__).__file__).resolve()  # type: ignore[attr-defined]


def _compiled_uses(module: types.ModuleType) -> tuple[bool, set[Path]]:
    """(whether the module has cached kernels of its own, the other files whose kernels its
    namespace holds: imported functions, or modules with kernels imported whole)."""
    own, cached, used = Path(module.__file__).resolve(), False, set()
    for value in vars(module).values():
        if isinstance(value, CPUDispatcher):
            if _file(value) == own:
                cached |= not isinstance(value._cache, NullCache)
            else:
                used.add(_file(value))
        elif (isinstance(value, types.ModuleType) and getattr(value, "__file__", None)
              and any(isinstance(v, CPUDispatcher) and _file(v) == _file(value)
                      for v in vars(value).values())):
            used.add(_file(value))
    used.discard(own)
    return cached, used


def test_every_cached_kernel_module_declares_the_kernels_it_compiles_in() -> None:
    checked = 0
    for module in _kernel_modules():
        cached, used = _compiled_uses(module)
        if not (cached and used):
            continue
        checked += 1
        own = Path(module.__file__).resolve()
        declared = numba_cache.DECLARED.get(own, frozenset())
        missing = {p.relative_to(ROOT).as_posix() for p in used - declared}
        assert not missing, f"{module.__name__} compiles in {sorted(missing)} undeclared"
        for dep in used:  # and what those declare: the digest covers the listed files only
            indirect = numba_cache.DECLARED.get(dep, frozenset()) - declared
            assert not indirect, (module.__name__, dep.name, sorted(p.name for p in indirect))
    assert checked >= 8  # the reduction's, the binning's and the simulated exposure's kernels


def test_a_changed_dependency_drops_the_cache_and_an_unchanged_one_keeps_it(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(numba_cache, "LOADED_AT", float("inf"))  # edited before a process ran
    module, dep = tmp_path / "kern.py", tmp_path / "dep.py"
    module.write_text("x = 1\n")
    dep.write_text("y = 1\n")
    cache = tmp_path / "__pycache__"
    cache.mkdir()
    compiled = cache / "kern.f-1.py311.nbi"

    def compile_() -> None:
        numba_cache.drop_stale_cache(module, (dep,))
        compiled.touch()  # what numba writes once it has compiled

    compile_()
    numba_cache.drop_stale_cache(module, (dep,))
    assert compiled.exists()  # same sources: kept
    dep.write_text("y = 2\n")
    numba_cache.drop_stale_cache(module, (dep,))
    assert not compiled.exists()  # the dependency changed: dropped
    assert numba_cache.DECLARED[module.resolve()] == {dep.resolve()}


def test_a_dependency_edited_while_the_process_runs_leaves_an_untrusted_cache(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Its old code may be in memory already: what this process caches is dropped by the
    next one."""
    module, dep = tmp_path / "kern.py", tmp_path / "dep.py"
    module.write_text("x = 1\n")
    dep.write_text("y = 1\n")
    monkeypatch.setattr(numba_cache, "LOADED_AT", dep.stat().st_mtime - 10.0)  # edited since
    numba_cache.drop_stale_cache(module, (dep,))
    stamp = tmp_path / "__pycache__" / "kern.deps"
    assert stamp.read_text() != numba_cache.UNTRUSTED  # not imported: read from the file
    monkeypatch.setitem(sys.modules, "gonio_test_dep", types.SimpleNamespace(
        __file__=str(dep.resolve())))  # imported before the edit: its old code in memory
    numba_cache.drop_stale_cache(module, (dep,))
    assert stamp.read_text() == numba_cache.UNTRUSTED
    compiled = tmp_path / "__pycache__" / "kern.f-1.py311.nbi"
    compiled.touch()  # what this process compiles, perhaps from the old code
    monkeypatch.setattr(numba_cache, "LOADED_AT", dep.stat().st_mtime + 10.0)  # the next one
    numba_cache.drop_stale_cache(module, (dep,))
    assert not compiled.exists() and stamp.read_text() != numba_cache.UNTRUSTED
    compiled.touch()
    numba_cache.drop_stale_cache(module, (dep,))
    assert compiled.exists()  # now trusted: kept
    future = time.time() + 3600.0  # a file dated ahead of this clock: skew, not an edit
    os.utime(dep, (future, future))
    numba_cache.drop_stale_cache(module, (dep,))
    assert compiled.exists() and stamp.read_text() != numba_cache.UNTRUSTED


@pytest.mark.parametrize("name", ["acquisition.reduction.sample_kernels", "simulators.ziggurat",
                                  "simulators.exposure"])
def test_modules_that_lacked_a_declaration_have_one(name: str) -> None:
    module = importlib.import_module(name)
    assert numba_cache.DECLARED.get(Path(module.__file__).resolve())
