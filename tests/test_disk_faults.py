"""Every command that writes, on a disk that fails: injected ENOSPC/EROFS at file creation or
at the rename (runs everywhere), and a real small tmpfs filled up, nearly full, or remounted
read-only (root only; skipped with the reason otherwise). Commands run with -o and, where they
have one, without it (the default output beside the input, or in the working folder); tables
and MERL files are exported, point and light-stage sessions reduced.

Each run must exit non-zero with one stderr line naming a path on the failing disk and the
cause, leave no temporary, half-written or empty file there, and leave its inputs unchanged.
"""

from __future__ import annotations

import errno
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from conftest import EXAMPLES, LIGHTSTAGE_RIG, TINY_MATERIAL, unfinish
from disks import (
    bad_leftovers,
    fill,
    injected,
    one_error_line,
    remount_readonly,
    small_tmpfs,
    tree_hashes,
)

from acquisition.cli import main
from acquisition.formats.merl import write_merl
from acquisition.geometry.halfdiff import MERL_BINS

RIG = EXAMPLES / "rig-sim.toml"


@dataclass(frozen=True)
class Command:
    """A gonio command writing under ``root``: its argv, its inputs, what it needs on the disk
    before the disk fails (a session to resume, an input whose default output goes beside
    it), the default output it makes in the working folder (it runs in ``root`` then), and
    whether it also runs on a real small tmpfs (not where the injected errors cover it more
    cheaply)."""

    argv: Callable[[Path, dict[str, Path]], list[str]]
    inputs: Callable[[dict[str, Path]], list[Path]]
    setup: Callable[[Path, dict[str, Path]], None] | None = None
    tmpfs: str = "2m"
    cwd_output: str | None = None
    real: bool = True


def _copy_setup(name: str, source: str, ignore: tuple[str, ...] = ()) -> Callable[..., None]:
    """Copy the fixture ``source`` (a file or a folder) to ``root/name``: an input on the failing
    disk, for a command whose default output goes beside its input."""
    def setup(root: Path, env: dict[str, Path]) -> None:
        if env[source].is_dir():
            shutil.copytree(env[source], root / name, ignore=shutil.ignore_patterns(*ignore))
        else:
            shutil.copy(env[source], root / name)
    return setup


def _resume_setup(name: str, source: str, ignore: tuple[str, ...] = ()) -> Callable[..., None]:
    """A copy of the finished session ``source`` at ``root/name``, interrupted."""
    copy = _copy_setup(name, source, ignore)

    def setup(root: Path, env: dict[str, Path]) -> None:
        copy(root, env)
        unfinish(root / name)
    return setup


def _on_disk(name: str) -> Callable[[dict[str, Path]], list[Path]]:
    """The input copied to ``root/name`` by :func:`_copy_setup`."""
    return lambda env: [env["root_of_run"] / name]


def _session_inputs(name: str) -> Callable[[dict[str, Path]], list[Path]]:
    """What a resume must not change: everything but the journal it appends to."""
    def inputs(env: dict[str, Path]) -> list[Path]:
        s = env["root_of_run"] / name
        return [s / "frames", s / "rig.toml", s / "plan.toml", s / "session.json"]
    return inputs


MISALIGNED_RIG = EXAMPLES / "rig-misaligned-sim.toml"

COMMANDS: dict[str, Command] = {
    "capture": Command(
        lambda r, e: ["capture", "--rig", str(RIG), "--plan", str(e["plan"]), "-o", str(r / "s"),
                      "--material", TINY_MATERIAL],
        lambda e: [RIG, e["plan"]]),
    "resume": Command(lambda r, e: ["resume", str(r / "r")], _session_inputs("r"),
                      _resume_setup("r", "session")),
    "reduce": Command(lambda r, e: ["reduce", str(e["session"]), "-o", str(r / "t.h5")],
                      lambda e: [e["session"]]),
    "export-merl": Command(
        lambda r, e: ["export", str(e["table"]), "--format", "merl", "-o", str(r / "t.binary")],
        lambda e: [e["table"]]),
    "export-csv": Command(
        lambda r, e: ["export", str(e["table"]), "--format", "csv", "-o", str(r / "t.csv")],
        lambda e: [e["table"]]),
    "export-exr": Command(
        lambda r, e: ["export", str(e["table"]), "--format", "exr", "-o", str(r / "exr")],
        lambda e: [e["table"]]),
    "export-bsdf": Command(
        lambda r, e: ["export", str(e["table"]), "--format", "bsdf", "-o", str(r / "t.bsdf")],
        lambda e: [e["table"]]),
    "demo": Command(lambda r, e: ["demo", "-o", str(r / "demo")],
                    lambda e: [RIG, EXAMPLES / "plan-demo.toml"]),
    "plan": Command(
        lambda r, e: ["plan", str(e["plan"]), "--rig", str(RIG), "-o", str(r / "plan.png")],
        lambda e: [RIG, e["plan"]]),
    "lightstage-capture": Command(
        lambda r, e: ["lightstage", "capture", "--rig", str(LIGHTSTAGE_RIG), "-o", str(r / "l"),
                      "--material", "lambert:albedo=0.3"],
        lambda e: [LIGHTSTAGE_RIG]),
    "lightstage-resume": Command(lambda r, e: ["lightstage", "resume", str(r / "lr")],
                                 _session_inputs("lr"),
                                 _resume_setup("lr", "lightstage", ("field",)), tmpfs="24m"),
    "lightstage-field": Command(
        lambda r, e: ["lightstage", "field", str(e["lightstage"]), "-o", str(r / "field")],
        lambda e: [e["lightstage"]]),
    "relight": Command(
        lambda r, e: ["relight", str(e["field"]), "--env", str(e["env"]), "-o",
                      str(r / "relit.exr")],
        lambda e: [e["field"], e["env"]]),
    "reduce-lightstage": Command(
        lambda r, e: ["reduce", str(e["lightstage"]), "-o", str(r / "l.h5")],
        lambda e: [e["lightstage"]], real=False),
    "report": Command(
        lambda r, e: ["report", str(e["table"]), "--models", "lambert", "-o",
                      str(r / "report.html")],
        lambda e: [e["table"]]),
    "calibrate-geometry": Command(
        lambda r, e: ["calibrate", "geometry", "--rig", str(MISALIGNED_RIG), "-o", str(r / "g")],
        lambda e: [MISALIGNED_RIG], real=False),
    **{f"calibrate-{kind}": Command(
        lambda r, e, kind=kind: ["calibrate", kind, "--rig", str(RIG), "-o", str(r / "b")],
        lambda e: [RIG]) for kind in ("dark", "flat", "noise", "white")},
    **{f"export-{fmt}-from-merl": Command(
        lambda r, e, fmt=fmt: ["export", str(e["merl"]), "--format", fmt, "-o",
                               str(r / f"m.{fmt}")],
        lambda e: [e["merl"]]) for fmt in ("merl", "csv", "exr")},
    # Default outputs (no -o): beside the input, copied onto the failing disk first.
    "reduce-default": Command(lambda r, e: ["reduce", str(r / "s")], _on_disk("s"),
                              _copy_setup("s", "session")),
    **{f"export-{fmt}-default": Command(
        lambda r, e, fmt=fmt: ["export", str(r / "t.h5"), "--format", fmt], _on_disk("t.h5"),
        _copy_setup("t.h5", "table"), real=fmt not in ("merl", "bsdf"))
        for fmt in ("merl", "csv", "exr", "bsdf")},
    "lightstage-field-default": Command(
        lambda r, e: ["lightstage", "field", str(r / "l")], _on_disk("l"),
        _copy_setup("l", "lightstage", ("field",)), real=False),
    "demo-default": Command(lambda r, e: ["demo"], lambda e: [RIG, EXAMPLES / "plan-demo.toml"],
                            cwd_output="demo-output", real=False),
}

MULTI_FILE = ("capture", "resume", "export-exr", "calibrate-dark", "calibrate-flat", "demo",
              "lightstage-capture", "lightstage-resume", "export-exr-default")
"""Commands that write several files: a nearly full disk fails them part way."""


@pytest.fixture(scope="module")
def merl_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A MERL file measured in a few hundred bins (its CSV and EXR exports stay small)."""
    values = np.full((MERL_BINS, 3), np.nan)
    values[::5000] = 0.2
    path = tmp_path_factory.mktemp("merl") / "m.binary"
    write_merl(path, values.reshape(90, 90, 180, 3))
    return path


@pytest.fixture
def env(finished: dict[str, Path], lightstage_field: dict[str, Path],
        merl_file: Path) -> dict[str, Path]:
    return {**finished, "lightstage": lightstage_field["session"],
            "field": lightstage_field["field"], "env": lightstage_field["env"], "merl": merl_file}


def _run_and_check(name: str, root: Path, env: dict[str, Path], cause: str,
                   capsys: pytest.CaptureFixture[str], before: dict[str, str],
                   monkeypatch: pytest.MonkeyPatch) -> None:
    named = COMMANDS[name].cwd_output
    if named:
        monkeypatch.chdir(root)
    code = main(COMMANDS[name].argv(root, env))
    err = capsys.readouterr().err
    assert code != 0, f"{name} succeeded on a failing disk"
    line = one_error_line(err)
    assert cause in line, line
    assert str(root) in line or (named and f" {named}/" in line), \
        f"the message names no path on the failing disk: {line}"
    assert bad_leftovers(root) == [], line
    assert tree_hashes(*COMMANDS[name].inputs(env)) == before, "an input changed"


INJECTED = {"enospc": (errno.ENOSPC, "create", "disk full"),
            "erofs": (errno.EROFS, "create", "read-only filesystem"),
            "enospc-at-rename": (errno.ENOSPC, "commit", "disk full")}


@pytest.mark.parametrize("mode", INJECTED)
@pytest.mark.parametrize("name", COMMANDS)
def test_injected_disk_errors(name: str, mode: str, env: dict[str, Path], tmp_path: Path,
                              monkeypatch: pytest.MonkeyPatch,
                              capsys: pytest.CaptureFixture[str]) -> None:
    code, at, cause = INJECTED[mode]
    root = tmp_path / "disk"
    root.mkdir()
    env = {**env, "root_of_run": root}
    command = COMMANDS[name]
    if command.setup:
        command.setup(root, env)
    before = tree_hashes(*command.inputs(env))
    capsys.readouterr()
    with injected(monkeypatch, root, code, at):
        _run_and_check(name, root, env, cause, capsys, before, monkeypatch)


REAL = {"tmpfs-full": "disk full", "tmpfs-nearly-full": "disk full",
        "tmpfs-read-only": "read-only filesystem"}


REAL_CASES = [(n, m) for n, c in COMMANDS.items() for m in REAL
              if c.real and (m != "tmpfs-nearly-full" or n in MULTI_FILE)]
"""A single small output may fit in what a nearly full disk has left: only the commands that
write several files are run on one."""


@pytest.mark.parametrize(("name", "mode"), REAL_CASES, ids=[f"{n}-{m}" for n, m in REAL_CASES])
def test_real_small_tmpfs(name: str, mode: str, env: dict[str, Path], tmp_path: Path,
                          capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    command = COMMANDS[name]
    with small_tmpfs(tmp_path / "disk", command.tmpfs) as root:
        env = {**env, "root_of_run": root}
        if command.setup:
            command.setup(root, env)
        if mode == "tmpfs-read-only":
            remount_readonly(root)
        else:
            fill(root, leave=6000 if mode == "tmpfs-nearly-full" else 0)
        before = tree_hashes(*command.inputs(env))
        capsys.readouterr()
        _run_and_check(name, root, env, REAL[mode], capsys, before, monkeypatch)
