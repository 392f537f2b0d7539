"""Every command that writes, on a disk that fails: injected ENOSPC/EROFS at file creation or
at the rename (runs everywhere), and a real small tmpfs filled up, nearly full, or remounted
read-only (root only; skipped with the reason otherwise).

Each run must exit non-zero with one stderr line naming a path on the failing disk and the
cause, leave no temporary, half-written or empty file there, and leave its inputs unchanged.
"""

from __future__ import annotations

import errno
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

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

RIG = EXAMPLES / "rig-sim.toml"


@dataclass(frozen=True)
class Command:
    """A gonio command writing under ``root``: its argv, its inputs, and what it needs on the
    disk before the disk fails (a session to resume)."""

    argv: Callable[[Path, dict[str, Path]], list[str]]
    inputs: Callable[[dict[str, Path]], list[Path]]
    setup: Callable[[Path, dict[str, Path]], None] | None = None
    tmpfs: str = "2m"


def _resume_setup(name: str, source: str, ignore: tuple[str, ...] = ()) -> Callable[..., None]:
    def setup(root: Path, env: dict[str, Path]) -> None:
        shutil.copytree(env[source], root / name, ignore=shutil.ignore_patterns(*ignore))
        unfinish(root / name)
    return setup


def _session_inputs(name: str) -> Callable[[dict[str, Path]], list[Path]]:
    """What a resume must not change: everything but the journal it appends to."""
    def inputs(env: dict[str, Path]) -> list[Path]:
        s = env["root_of_run"] / name
        return [s / "frames", s / "rig.toml", s / "plan.toml", s / "session.json"]
    return inputs


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
    "calibrate": Command(lambda r, e: ["calibrate", "dark", "--rig", str(RIG), "-o", str(r / "b")],
                         lambda e: [RIG]),
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
}

MULTI_FILE = ("capture", "resume", "export-exr", "calibrate", "demo", "lightstage-capture",
              "lightstage-resume")
"""Commands that write several files: a nearly full disk fails them part way."""


@pytest.fixture
def env(finished: dict[str, Path], lightstage_field: dict[str, Path]) -> dict[str, Path]:
    return {**finished, "lightstage": lightstage_field["session"],
            "field": lightstage_field["field"], "env": lightstage_field["env"]}


def _run_and_check(name: str, root: Path, env: dict[str, Path], cause: str,
                   capsys: pytest.CaptureFixture[str], before: dict[str, str]) -> None:
    code = main(COMMANDS[name].argv(root, env))
    err = capsys.readouterr().err
    assert code != 0, f"{name} succeeded on a failing disk"
    line = one_error_line(err)
    assert cause in line, line
    assert str(root) in line, f"the message names no path on the failing disk: {line}"
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
        _run_and_check(name, root, env, cause, capsys, before)


REAL = {"tmpfs-full": "disk full", "tmpfs-nearly-full": "disk full",
        "tmpfs-read-only": "read-only filesystem"}


REAL_CASES = [(n, m) for n in COMMANDS for m in REAL if m != "tmpfs-nearly-full" or n in MULTI_FILE]
"""A single small output may fit in what a nearly full disk has left: only the commands that
write several files are run on one."""


@pytest.mark.parametrize(("name", "mode"), REAL_CASES, ids=[f"{n}-{m}" for n, m in REAL_CASES])
def test_real_small_tmpfs(name: str, mode: str, env: dict[str, Path], tmp_path: Path,
                          capsys: pytest.CaptureFixture[str]) -> None:
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
        _run_and_check(name, root, env, REAL[mode], capsys, before)
