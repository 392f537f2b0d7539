"""One CLI grammar over every command's parser: ``-o/--out`` for outputs, ``--json`` wherever a
command reports, ``--sim-fault`` and ``--seed`` spelled and meant alike, ``--version``, and
``gonio`` alone printing the help."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys

import pytest

from acquisition import api
from acquisition.cli import COMMAND_MODULES, build_parser, main

SERVERS = {"sim servos", "sim dmx"}
"""Commands that serve a device in the foreground instead of reporting."""


def _leaves(parser: argparse.ArgumentParser, prefix: str = "") -> dict[str, argparse.ArgumentParser]:
    """``{"lightstage capture": parser, ...}`` for every command that runs something."""
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        return {prefix.strip(): parser}
    out: dict[str, argparse.ArgumentParser] = {}
    for action in subs:
        for name, child in action.choices.items():
            out.update(_leaves(child, f"{prefix} {name}"))
    return out


LEAVES = _leaves(build_parser())


def _options(parser: argparse.ArgumentParser) -> dict[str, argparse.Action]:
    return {opt: a for a in parser._actions for opt in a.option_strings}


def test_every_command_is_found() -> None:
    assert {"capture", "resume", "reduce", "plan", "demo", "info", "export", "status", "scan",
            "jog", "move", "home", "park", "torque", "reboot", "inspect", "calibrate",
            "lightstage capture", "lightstage resume", "lightstage field", "relight",
            "sim servos", "sim dmx"} <= set(LEAVES)


@pytest.mark.parametrize("name", sorted(LEAVES))
def test_outputs_are_dash_o_dash_dash_out(name: str) -> None:
    opts = _options(LEAVES[name])
    outs = [a for a in LEAVES[name]._actions if a.dest == "out"]
    for action in outs:
        assert {"-o", "--out"} <= set(action.option_strings), (name, action.option_strings)
    for legacy in ("--output", "--plot"):  # older spellings survive only as aliases of --out
        if legacy in opts:
            assert opts[legacy].dest == "out", (name, legacy)


@pytest.mark.parametrize("name", sorted(set(LEAVES) - SERVERS))
def test_every_reporting_command_takes_json(name: str) -> None:
    action = _options(LEAVES[name]).get("--json")
    assert action is not None and action.nargs == 0, f"gonio {name} has no --json"


@pytest.mark.parametrize("name", sorted(LEAVES))
def test_fault_and_seed_mean_the_same_everywhere(name: str) -> None:
    opts = _options(LEAVES[name])
    if "--seed" in opts:
        assert "simulated devices" in (opts["--seed"].help or ""), name
    if "--sim-fault" in opts:
        assert opts["--sim-fault"].dest == "sim_fault", name
    if "--fault" in opts:  # the deprecated spelling, on `gonio sim servos` only
        assert name == "sim servos" and "deprecated" in (opts["--fault"].help or "")


def test_every_command_module_declares_its_commands() -> None:
    import importlib

    declared = {c for m in COMMAND_MODULES for c in importlib.import_module(m).COMMANDS}
    assert declared == {name.split()[0] for name in LEAVES}


def test_version_and_bare_gonio(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as stop:
        main(["--version"])
    assert stop.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("gonio ") and out.split()[1][0].isdigit()
    assert main([]) == 0
    assert "COMMAND" in capsys.readouterr().out


def test_a_command_parses_with_only_its_own_module_registered(
        capsys: pytest.CaptureFixture[str]) -> None:
    partial = build_parser("plan", full=False)
    args = partial.parse_args(["plan", "p.toml", "--rig", "r.toml", "-o", "x.png", "--json"])
    assert (args.out, args.json) == ("x.png", True)
    with pytest.raises(SystemExit):
        main(["capture", "--help"])
    assert "--sim-fault" in capsys.readouterr().out


def test_legacy_spellings_still_parse() -> None:
    parser = build_parser()
    assert parser.parse_args(["reduce", "s", "--output", "t.h5"]).out == "t.h5"
    assert parser.parse_args(["reduce", "s", "-o", "t.h5"]).out == "t.h5"
    assert parser.parse_args(["plan", "p", "--rig", "r", "--plot", "a.png"]).out == "a.png"
    assert parser.parse_args(["export", "t.h5", "--format", "csv", "--output", "t.csv"]).out == "t.csv"
    assert parser.parse_args(["lightstage", "field", "s", "--output", "f"]).out == "f"


def test_deprecated_fault_option_says_so(monkeypatch: pytest.MonkeyPatch,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    seen: list[object] = []
    monkeypatch.setattr(api, "serve_servos", lambda *a, **k: seen.append(a) or 0, raising=False)
    assert main(["sim", "servos", "--ids", "1,2", "--fault", "drop=0.1"]) == 0
    assert "--fault is deprecated: use --sim-fault" in capsys.readouterr().err
    assert seen and seen[0][3] == ["drop=0.1"]


def test_json_output_is_one_object(tmp_path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["plan", "examples/plan-quick.toml", "--rig", "examples/rig-sim.toml",
                 "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["poses"] > 0
    assert main(["status", "--rig", "examples/rig-sim.toml", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)["axes"]
    assert {r["axis"] for r in rows} == {"light_theta", "camera_theta", "camera_phi"}


def test_help_needs_no_heavy_import() -> None:
    code = ("import sys; from acquisition.cli import main\n"
            "try:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
            "heavy = {'numba', 'h5py', 'scipy', 'matplotlib', 'OpenImageIO', 'rawpy'}\n"
            "print(sorted(heavy & set(sys.modules)))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip().splitlines()[-1] == "[]"
