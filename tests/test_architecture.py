"""The house rules of ARCHITECTURE.md, enforced on the code: which room may import which, the
CLI speaks only to the API, nothing else prints or prompts, and the API's exports resolve."""

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


def room_of(module: str, rooms: dict[str, tuple[str, ...]]) -> str | None:
    matches = [r for r in rooms if module == r or module.startswith(r + ".")]
    return max(matches, key=len) if matches else None


def _under(name: str, prefix: str) -> bool:
    return name == prefix or name.startswith(prefix + ".")


def runtime_imports(tree: ast.AST, root: Path) -> list[tuple[int, str]]:
    """Gonio modules imported at run time (``if TYPE_CHECKING:`` blocks are skipped): for
    ``from A import b`` the module ``A.b`` when it is one, else ``A``."""
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
            elif isinstance(child, ast.ImportFrom) and child.level == 0 and child.module:
                for a in child.names:
                    sub = f"{child.module}.{a.name}"
                    found.append((child.lineno, sub if is_module(sub) else child.module))
            visit(child)

    visit(tree)
    return [(n, m) for n, m in found if m.split(".")[0] in PACKAGES]


def import_violations(root: Path, rules: dict[str, tuple[str, ...]]) -> list[Violation]:
    """Every run-time import of a gonio module that the room table does not allow; nothing
    but ``acquisition.cli`` may import ``acquisition.cli``."""
    out: list[Violation] = []
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            module = module_name(path, root)
            room = room_of(module, rules)
            for line, imported in runtime_imports(ast.parse(path.read_text()), root):
                own = room is not None and _under(imported, room)
                allowed = room is not None and (own or any(_under(imported, p) for p in rules[room]))
                into_cli = _under(imported, "acquisition.cli") and not _under(module, "acquisition.cli")
                if into_cli or not allowed:
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


RULES = import_rules(ROOT / "ARCHITECTURE.md")


def test_the_table_names_every_room() -> None:
    assert {"drivers", "simulators", "calibration", "acquisition.cli", "acquisition.api"} <= set(RULES)
    rooms = {p.name for p in (ROOT / "acquisition").iterdir()
             if p.is_dir() and (p / "__init__.py").is_file()}
    assert {f"acquisition.{r}" for r in rooms} <= set(RULES), "a room is missing from ARCHITECTURE.md"
    assert RULES["acquisition.cli"] == ("acquisition.api",)
    assert RULES["drivers"] == ()


def test_every_import_follows_the_table() -> None:
    bad = import_violations(ROOT, RULES)
    assert not bad, "imports ARCHITECTURE.md does not allow:\n" + "\n".join(map(str, bad))


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
])
def test_the_rule_catches_a_cli_module_that_bypasses_the_api(tmp_path: Path, line: str) -> None:
    root = _tree(tmp_path, {
        "acquisition/__init__.py": "", "acquisition/api/__init__.py": "",
        "acquisition/session/__init__.py": "", "acquisition/session/folder.py": "",
        "acquisition/devices/__init__.py": "", "acquisition/devices/rig.py": "",
        "drivers/__init__.py": "", "drivers/errors.py": "",
        "acquisition/cli/__init__.py": "", "acquisition/cli/good.py": "from acquisition import api\n",
        "acquisition/cli/bad.py": line,
    })
    bad = import_violations(root, RULES)
    assert [v.module for v in bad] == ["acquisition.cli.bad"], bad


def test_type_checking_imports_are_not_run_time_dependencies(tmp_path: Path) -> None:
    root = _tree(tmp_path, {
        "acquisition/__init__.py": "", "acquisition/api/__init__.py": "",
        "acquisition/session/__init__.py": "", "acquisition/session/folder.py": "",
        "acquisition/cli/__init__.py": "",
        "acquisition/cli/typed.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
                                    "    from acquisition.session.folder import SessionFolder\n",
    })
    assert import_violations(root, RULES) == []


def test_nothing_outside_the_cli_prints_or_prompts() -> None:
    found = terminal_io(ROOT)
    assert not found, "terminal I/O outside acquisition.cli:\n" + "\n".join(found)


def test_every_api_export_resolves() -> None:
    import acquisition.api as api

    for name in api.__all__:
        assert getattr(api, name) is not None, name
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        _ = api.nope
