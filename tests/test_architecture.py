"""The house rules of ARCHITECTURE.md, enforced on the code: which room may import which
(relative and string-literal dynamic imports included), each room's docstring repeats its row,
the CLI speaks only to the API, nothing else prints or prompts, and the API's exports resolve."""

from __future__ import annotations

import ast
import re
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("drivers", "simulators", "calibration", "acquisition")
TERMINAL_IO_ALLOWED = {"acquisition/session/interrupts.py"}
"""The Ctrl-C handler writes with a signal-safe ``os.write`` to stderr (print must not run in
a signal handler)."""


@dataclass(frozen=True)
class Violation:
    module: str
    line: int
    imported: str

    def __str__(self) -> str:
        return f"{self.module}:{self.line} imports {self.imported}"


def import_rules(architecture: Path) -> dict[str, tuple[str, ...]]:
    """``{room: allowed prefixes}`` from the table of ARCHITECTURE.md (first column: the room(s),
    last column: what they may import, ``—`` for nothing)."""
    rules: dict[str, tuple[str, ...]] = {}
    for line in architecture.read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) < 3 or not cells[0].startswith("`"):
            continue
        allowed = tuple(re.findall(r"`([\w.]+)`", cells[-1]))
        for room in re.findall(r"`([\w.]+)`", cells[0]):
            rules[room] = allowed
    return rules


def module_name(path: Path, root: Path) -> str:
    return ".".join(path.relative_to(root).with_suffix("").parts).removesuffix(".__init__")


def package_of(path: Path, root: Path) -> str:
    """The package a file's relative imports start from: itself for an ``__init__.py``."""
    module = module_name(path, root)
    return module if path.name == "__init__.py" else module.rpartition(".")[0]


def room_of(module: str, rooms: dict[str, tuple[str, ...]]) -> str | None:
    matches = [r for r in rooms if module == r or module.startswith(r + ".")]
    return max(matches, key=len) if matches else None


def _under(name: str, prefix: str) -> bool:
    return name == prefix or name.startswith(prefix + ".")


def resolve_relative(module: str | None, level: int, package: str) -> str | None:
    """The absolute name of ``from <level dots><module> import …`` in ``package`` (None when
    it climbs above the top package, which Python refuses too)."""
    if level == 0:
        return module
    parts = package.split(".") if package else []
    if level - 1 >= len(parts):
        return None
    base = ".".join(parts[: len(parts) - (level - 1)])
    return f"{base}.{module}" if module else base


DYNAMIC_IMPORTS = ("import_module", "__import__")
"""Calls that import the module their first argument names: ``importlib.import_module(…)``,
``import_module(…)``, ``__import__(…)`` (also as ``builtins.__import__``)."""


def dynamic_import(call: ast.Call, package: str) -> str | None:
    """The module a dynamic import names with a string literal (relative names resolved
    against ``package``); None for other calls or non-literal names."""
    func = call.func
    name = func.id if isinstance(func, ast.Name) else func.attr if isinstance(func, ast.Attribute) else None
    if name not in DYNAMIC_IMPORTS or not call.args:
        return None
    arg = call.args[0]
    if not (isinstance(arg, ast.Constant) and isinstance(arg.value, str)):
        return None
    dotted = arg.value.lstrip(".")
    return resolve_relative(dotted or None, len(arg.value) - len(dotted), package)


def runtime_imports(tree: ast.AST, root: Path, package: str = "",
                    tops: tuple[str, ...] | None = PACKAGES) -> list[tuple[int, str]]:
    """Modules of ``tops`` (default: gonio's; None: any) imported at run time (``if
    TYPE_CHECKING:`` blocks are skipped): for ``from A import b`` the module ``A.b`` when it
    is one, else ``A``; relative imports are resolved against ``package`` (the importing
    file's), and dynamic imports of string literals (:data:`DYNAMIC_IMPORTS`) count as
    imports."""
    found: list[tuple[int, str]] = []

    def is_module(dotted: str) -> bool:
        base = root / Path(*dotted.split("."))
        return base.with_suffix(".py").is_file() or (base / "__init__.py").is_file()

    def visit(node: ast.AST) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test):
                continue
            if isinstance(child, ast.Import):
                found.extend((child.lineno, a.name) for a in child.names)
            elif isinstance(child, ast.ImportFrom):
                base = resolve_relative(child.module, child.level, package)
                for a in child.names if base else ():
                    sub = f"{base}.{a.name}"
                    found.append((child.lineno, sub if is_module(sub) else base))
            elif isinstance(child, ast.Call) and (name := dynamic_import(child, package)):
                found.append((child.lineno, name))
            visit(child)

    visit(tree)
    return [(n, m) for n, m in found if tops is None or m.split(".")[0] in tops]


def import_violations(root: Path, rules: dict[str, tuple[str, ...]]) -> list[Violation]:
    """Every run-time import of a gonio module that the room table does not allow; nothing
    but ``acquisition.cli`` may import ``acquisition.cli``."""
    out: list[Violation] = []
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            module = module_name(path, root)
            room = room_of(module, rules)
            tree = ast.parse(path.read_text())
            for line, imported in runtime_imports(tree, root, package_of(path, root)):
                own = room is not None and _under(imported, room)
                allowed = room is not None and (own or any(_under(imported, p) for p in rules[room]))
                into_cli = _under(imported, "acquisition.cli") and not _under(module, "acquisition.cli")
                if into_cli or not allowed:
                    out.append(Violation(module, line, imported))
    return out


def extras_rules(architecture: Path) -> dict[str, tuple[str, ...]]:
    """``{third-party package: the modules that may import it}`` from the optional extras'
    table of ARCHITECTURE.md (rows ``| gonio[extra] | `package`, … | `module`, … |``)."""
    rules: dict[str, tuple[str, ...]] = {}
    for line in architecture.read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 3 and cells[0].startswith("gonio["):
            for package in re.findall(r"`([\w.]+)`", cells[1]):
                rules[package] = tuple(re.findall(r"`([\w.]+)`", cells[2]))
    return rules


def extras_violations(root: Path, rules: dict[str, tuple[str, ...]]) -> list[Violation]:
    """Every run-time import of an optional extra's package outside the modules its row
    names."""
    out: list[Violation] = []
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            module = module_name(path, root)
            tree = ast.parse(path.read_text())
            for line, imported in runtime_imports(tree, root, package_of(path, root), None):
                allowed = rules.get(imported.split(".")[0])
                if allowed is not None and not any(_under(module, m) for m in allowed):
                    out.append(Violation(module, line, imported))
    return out


def terminal_io(root: Path) -> list[str]:
    """``print``/``input`` calls and ``sys.stdout``/``sys.stderr`` uses outside the CLI."""
    out = []
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            rel = path.relative_to(root).as_posix()
            if rel.startswith("acquisition/cli/") or rel in TERMINAL_IO_ALLOWED:
                continue
            for node in ast.walk(ast.parse(path.read_text())):
                if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
                        and node.func.id in ("print", "input")):
                    out.append(f"{rel}:{node.lineno} calls {node.func.id}()")
                elif (isinstance(node, ast.Attribute) and node.attr in ("stdout", "stderr")
                        and isinstance(node.value, ast.Name) and node.value.id == "sys"):
                    out.append(f"{rel}:{node.lineno} uses sys.{node.attr}")
    return out


MAY_IMPORT = re.compile(r"^May import:(.*?)(?:\n\s*\n|\Z)", re.MULTILINE | re.DOTALL)
"""The paragraph of a room's package docstring that says what it may import."""


def declared_imports(docstring: str) -> tuple[str, ...] | None:
    """What a package docstring's ``May import:`` paragraph allows, sorted: its
    double-backticked names outside parentheses (a remark in parentheses names nothing), none
    for ``May import: nothing``; None when the docstring has no such paragraph or words it
    otherwise (an empty list)."""
    found = MAY_IMPORT.findall(docstring)
    if len(found) != 1:
        return None
    text = re.sub(r"\([^()]*\)", "", found[0])
    names = re.findall(r"``([\w.]+)``", text)
    if not names:
        return () if re.match(r"\s*nothing\b", text) else None
    return tuple(sorted(names))


RULES = import_rules(ROOT / "ARCHITECTURE.md")
ROOM_PACKAGES = sorted(r for r in RULES if (ROOT / Path(*r.split(".")) / "__init__.py").is_file())


def test_the_table_names_every_room() -> None:
    assert {"drivers", "simulators", "calibration", "acquisition.cli", "acquisition.api"} <= set(RULES)
    rooms = {p.name for p in (ROOT / "acquisition").iterdir()
             if p.is_dir() and (p / "__init__.py").is_file()}
    assert {f"acquisition.{r}" for r in rooms} <= set(RULES), "a room is missing from ARCHITECTURE.md"
    assert RULES["acquisition.cli"] == ("acquisition.api",)
    assert RULES["drivers"] == ()


@pytest.mark.parametrize("room", ROOM_PACKAGES)
def test_each_room_says_its_job_and_its_row_of_the_table(room: str) -> None:
    init = ROOT / Path(*room.split(".")) / "__init__.py"
    doc = ast.get_docstring(ast.parse(init.read_text())) or ""
    job = doc.partition("May import:")[0].strip()
    assert job, f"{init}: the docstring does not say the room's job"
    declared = declared_imports(doc)
    assert declared is not None, f"{init}: no one 'May import: ``a``, ``b``.' paragraph"
    assert doc.lower().count("may import") == 1, f"{init}: says twice what it may import"
    assert declared == tuple(sorted(RULES[room])), (
        f"{init} says it may import {declared}; ARCHITECTURE.md says {RULES[room]}")


def test_every_package_room_is_checked_for_its_docstring() -> None:
    rooms = {f"acquisition.{p.name}" for p in (ROOT / "acquisition").iterdir()
             if p.is_dir() and (p / "__init__.py").is_file()}
    assert rooms | {"drivers", "simulators", "calibration"} <= set(ROOM_PACKAGES)


@pytest.mark.parametrize(("doc", "expected"), [
    ("Job.\n\nMay import: ``b.c``, ``a`` (and its own ``x``).\n", ("a", "b.c")),
    ("Job.\n\nMay import: ``a``,\n``b``.\n\nMore prose with ``c``.", ("a", "b")),
    ("Job.\n\nMay import: nothing (the bottom layer).", ()),
    ("Job. May import `a` only.", None),
    ("Job.\n\nMay import: everything below the API.", None),
    ("Job.\n\nMay import: ``a``.\n\nMay import: ``b``.", None),
])
def test_declared_imports_reads_one_paragraph(doc: str, expected: tuple[str, ...] | None) -> None:
    assert declared_imports(doc) == expected


def test_every_import_follows_the_table() -> None:
    bad = import_violations(ROOT, RULES)
    assert not bad, "imports ARCHITECTURE.md does not allow:\n" + "\n".join(map(str, bad))


REFEREES = ("simulators", "acquisition.simworld")
"""The simulated world: it models the physics with code of its own."""
JUDGED = ("acquisition.reduction", "acquisition.planning", "acquisition.calibrate",
          "acquisition.formats", "acquisition.tables", "acquisition.geometry.halfdiff")
"""What the simulated world judges: a simulator that called it would agree with its bugs. The
file formats' readers and writers, the tables and the MERL half/difference coordinates they
bin with are judged by round trips (a capture of ``merl:x.binary`` reduced into a MERL table
and compared with x.binary), so the simulated camera reads and evaluates files with code of
its own (:mod:`simulators.measured`)."""


def referee_violations(root: Path) -> list[Violation]:
    """Every run-time import (lazy, relative and string-literal dynamic ones included) of
    judged code by a module of the simulated world."""
    out: list[Violation] = []
    for room in REFEREES:
        for path in sorted((root / Path(*room.split("."))).rglob("*.py")):
            module = module_name(path, root)
            tree = ast.parse(path.read_text())
            out.extend(Violation(module, line, imported)
                       for line, imported in runtime_imports(tree, root, package_of(path, root))
                       if any(_under(imported, judged) for judged in JUDGED))
    return out


def test_the_simulated_world_never_imports_the_code_it_judges() -> None:
    bad = referee_violations(ROOT)
    assert not bad, "a simulator imports judged code:\n" + "\n".join(map(str, bad))
    for room in REFEREES:  # nor may the table let it (a judged module inside an allowed room,
        # acquisition.geometry.halfdiff, is refused by the import check above)
        assert not [p for p in RULES[room] for j in JUDGED
                    if _under(p, j) or (_under(j, p) and j in RULES)], room


@pytest.mark.parametrize("line", [
    "from acquisition.reduction.imaging import frame_geometry\n",
    "def render():\n    from acquisition.planning.planner import Planner\n",
    "from ..reduction import imaging\n",
    "import importlib\nimportlib.import_module('acquisition.calibrate.pointing')\n",
    "from acquisition.formats.merl import read_merl\n",
    "def load():\n    from ..formats import rgl\n",
    "from acquisition.geometry.halfdiff import halfdiff_rad_from_vectors\n",
    "from acquisition.tables import MerlTable\n",
])
def test_the_referee_rule_catches_a_simulator_that_borrows_judged_code(tmp_path: Path,
                                                                       line: str) -> None:
    root = _tree(tmp_path, {
        "acquisition/__init__.py": "", "acquisition/simworld/__init__.py": "",
        "acquisition/simworld/optics.py": ("import numpy\nfrom acquisition.config import rig\n"
                                           "from acquisition.geometry import kinematics\n"),
        "acquisition/simworld/scene.py": line,
        "acquisition/config/__init__.py": "", "acquisition/config/rig.py": "",
        "acquisition/reduction/__init__.py": "", "acquisition/reduction/imaging.py": "",
        "acquisition/planning/__init__.py": "", "acquisition/planning/planner.py": "",
        "acquisition/calibrate/__init__.py": "", "acquisition/calibrate/pointing.py": "",
        "acquisition/formats/__init__.py": "", "acquisition/formats/merl.py": "",
        "acquisition/formats/rgl.py": "", "acquisition/tables/__init__.py": "",
        "acquisition/geometry/__init__.py": "", "acquisition/geometry/halfdiff.py": "",
        "acquisition/geometry/kinematics.py": "",
    })
    (root / "simulators" / "__init__.py").write_text("")
    assert [v.module for v in referee_violations(root)] == ["acquisition.simworld.scene"]


def _tree(tmp_path: Path, files: dict[str, str]) -> Path:
    for rel, text in files.items():
        path = tmp_path / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    for package in PACKAGES:
        (tmp_path / package).mkdir(exist_ok=True)
    return tmp_path


@pytest.mark.parametrize("line", [
    "from acquisition.session.folder import SessionFolder\n",
    "import acquisition.session.folder\n",
    "from acquisition.session import folder\n",
    "from drivers.errors import GonioError\n",
    "def run():\n    from acquisition.devices.rig import open_devices\n",
    # relative imports, resolved against the importing file's package
    "from ..session.folder import SessionFolder\n",
    "from ..session import folder\n",
    "from .. import devices\n",
    "def run():\n    from ..devices.rig import open_devices\n",
    # dynamic imports of string literals
    "import importlib\nimportlib.import_module('acquisition.session.folder')\n",
    "from importlib import import_module\nrig = import_module('acquisition.devices.rig')\n",
    "import importlib\nimportlib.import_module('..session', __package__)\n",
    "def run():\n    return __import__('drivers.errors')\n",
    "import builtins\nbuiltins.__import__('acquisition.devices', fromlist=['rig'])\n",
])
def test_the_rule_catches_a_cli_module_that_bypasses_the_api(tmp_path: Path, line: str) -> None:
    root = _tree(tmp_path, {**CLI_TREE, "acquisition/cli/bad.py": line})
    bad = import_violations(root, RULES)
    assert [v.module for v in bad] == ["acquisition.cli.bad"], bad


CLI_TREE = {
    "acquisition/__init__.py": "", "acquisition/api/__init__.py": "",
    "acquisition/session/__init__.py": "", "acquisition/session/folder.py": "",
    "acquisition/devices/__init__.py": "", "acquisition/devices/rig.py": "",
    "drivers/__init__.py": "", "drivers/errors.py": "",
    "acquisition/cli/__init__.py": "", "acquisition/cli/good.py": "from acquisition import api\n",
}
"""A CLI that follows the rule, beside the rooms it must not reach."""


@pytest.mark.parametrize("line", [
    "from . import good\n",
    "from .good import api\n",
    "from .. import api\n",
    "from ..api import capture\n",
    "import importlib\nimportlib.import_module('acquisition.api')\n",
    "import importlib\nimportlib.import_module('.good', __package__)\n",
    "import importlib\nimportlib.import_module(name)\n",  # not a literal: not resolvable
    "__import__('json')\n",
])
def test_relative_and_dynamic_imports_inside_the_rule_pass(tmp_path: Path, line: str) -> None:
    root = _tree(tmp_path, {**CLI_TREE, "acquisition/cli/ok.py": line})
    assert import_violations(root, RULES) == []


def test_relative_imports_resolve_to_absolute_names(tmp_path: Path) -> None:
    root = _tree(tmp_path, CLI_TREE)
    source = ("from . import good\nfrom .. import session\nfrom ..session.folder import X\n"
              "from .... import beyond\nimport importlib\nimportlib.import_module('..devices.rig', 'p')\n")
    in_module = runtime_imports(ast.parse(source), root, package_of(root / "acquisition/cli/x.py", root))
    assert in_module == [(1, "acquisition.cli.good"), (2, "acquisition.session"),
                         (3, "acquisition.session.folder"), (6, "acquisition.devices.rig")]
    init = package_of(root / "acquisition/cli/__init__.py", root)
    assert init == "acquisition.cli"  # an __init__'s relative imports start from itself
    assert runtime_imports(ast.parse("from ..devices import rig\n"), root, init) == [
        (1, "acquisition.devices.rig")]


def test_type_checking_imports_are_not_run_time_dependencies(tmp_path: Path) -> None:
    root = _tree(tmp_path, {
        "acquisition/__init__.py": "", "acquisition/api/__init__.py": "",
        "acquisition/session/__init__.py": "", "acquisition/session/folder.py": "",
        "acquisition/cli/__init__.py": "",
        "acquisition/cli/typed.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
                                    "    from acquisition.session.folder import SessionFolder\n",
    })
    assert import_violations(root, RULES) == []


def test_optional_extras_are_imported_only_where_the_table_says(tmp_path: Path) -> None:
    rules = extras_rules(ROOT / "ARCHITECTURE.md")
    assert rules["dask"] == rules["distributed"] == ("acquisition.reduction.distributed",)
    assert rules["bluesky"] == rules["ophyd_async"] == ("acquisition.bluesky",)
    bad = extras_violations(ROOT, rules)
    assert not bad, "optional extras imported where ARCHITECTURE.md does not allow:\n" + \
        "\n".join(map(str, bad))
    root = _tree(tmp_path, {"acquisition/reduction/point.py": "def f():\n    import dask\n",
                            "acquisition/reduction/distributed.py": "import distributed\n"})
    assert [(v.module, v.imported) for v in extras_violations(root, rules)] == [
        ("acquisition.reduction.point", "dask")]


def test_nothing_outside_the_cli_prints_or_prompts() -> None:
    found = terminal_io(ROOT)
    assert not found, "terminal I/O outside acquisition.cli:\n" + "\n".join(found)


def test_every_api_export_resolves() -> None:
    import acquisition.api as api

    for name in api.__all__:
        assert getattr(api, name) is not None, name
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        _ = api.nope
