"""Reading TOML rig and plan files with one-line errors that name the file and the field."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any, TypeVar

from drivers.errors import ConfigError

T = TypeVar("T")

_MISSING = object()


def load_toml(path: str | Path, what: str) -> dict[str, Any]:
    """Parse a TOML file; ``what`` ("rig file", "plan file") appears in errors."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{what} {path} does not exist: check the path") from None
    except OSError as exc:
        raise ConfigError(f"{what} {path} cannot be read ({exc.strerror})") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{what} {path} is not valid TOML: {exc}") from None


class Section:
    """A TOML table with typed, located accessors: errors read ``file: [table] key: problem``."""

    def __init__(self, data: dict[str, Any], source: str, name: str = "") -> None:
        if not isinstance(data, dict):
            raise ConfigError(f"{source}: [{name}] must be a table")
        self.data = data
        self.source = source
        self.name = name

    def where(self, key: str | None = None) -> str:
        table = f"[{self.name}]" if self.name else "top level"
        return f"{self.source}: {table}" + (f" {key}" if key else "")

    def error(self, key: str | None, problem: str) -> ConfigError:
        return ConfigError(f"{self.where(key)}: {problem}")

    def __contains__(self, key: str) -> bool:
        return key in self.data

    def names(self) -> list[str]:
        return list(self.data)

    def get(self, key: str, kind: type[T] | tuple[type, ...], default: Any = _MISSING) -> Any:
        """The value of ``key`` checked against ``kind``; missing without default is an error."""
        if key not in self.data:
            if default is _MISSING:
                raise self.error(key, "is missing")
            return default
        value = self.data[key]
        kinds = kind if isinstance(kind, tuple) else (kind,)
        if float in kinds and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if isinstance(value, bool) and bool not in kinds:
            raise self.error(key, f"must be {_kind_name(kinds)}, got {value!r}")
        if not isinstance(value, kinds):
            raise self.error(key, f"must be {_kind_name(kinds)}, got {value!r}")
        return value

    def number(
        self, key: str, default: Any = _MISSING, *, min: float | None = None, max: float | None = None
    ) -> float:
        """A float (ints accepted) within optional bounds."""
        value = self.get(key, float, default)
        if value is None:
            return value
        if min is not None and value < min:
            raise self.error(key, f"must be ≥ {min:g}, got {value:g}")
        if max is not None and value > max:
            raise self.error(key, f"must be ≤ {max:g}, got {value:g}")
        return value

    def integer(
        self, key: str, default: Any = _MISSING, *, min: int | None = None, max: int | None = None
    ) -> int:
        """An int within optional bounds."""
        value = self.get(key, int, default)
        if value is None:
            return value
        if min is not None and value < min:
            raise self.error(key, f"must be ≥ {min}, got {value}")
        if max is not None and value > max:
            raise self.error(key, f"must be ≤ {max}, got {value}")
        return value

    def section(self, key: str, default: Any = _MISSING) -> Section:
        """A sub-table as a :class:`Section`."""
        value = self.get(key, dict, {} if default is not _MISSING else _MISSING)
        name = f"{self.name}.{key}" if self.name else key
        return Section(value, self.source, name)

    def check_keys(self, allowed: set[str]) -> None:
        """Reject keys not in ``allowed`` (typos in rig files must not pass silently)."""
        unknown = sorted(set(self.data) - allowed)
        if unknown:
            raise self.error(
                unknown[0], f"unknown key (allowed: {', '.join(sorted(allowed))})"
            )


def _kind_name(kinds: tuple[type, ...]) -> str:
    names = {bool: "true/false", int: "an integer", float: "a number", str: "a string",
             list: "an array", dict: "a table"}
    return " or ".join(names.get(k, k.__name__) for k in kinds)
