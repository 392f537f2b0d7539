"""Reading TOML rig and plan files with one-line errors that name the file and the field."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Any, TypeVar

from drivers.errors import ConfigError

T = TypeVar("T")

_MISSING = object()

ANGLE_UNITS = ("deg", "rad")
"""Units a file's angles may be written in (``units`` of a plan file; rig files: degrees)."""

RAD_SNAP = 5e-4
"""A radian value this close beyond a bound (π/2 written as 1.5708 or 1.571) is the bound."""

TWO_PI = 2 * math.pi


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

    def __init__(self, data: dict[str, Any], source: str, name: str = "", *,
                 units: str = "deg", units_key: bool = False,
                 angles: list[float] | None = None) -> None:
        if not isinstance(data, dict):
            raise ConfigError(f"{source}: [{name}] must be a table")
        self.data = data
        self.source = source
        self.name = name
        self.units = units
        """Units of the angles :meth:`angle` reads ("deg" or "rad"); results are degrees."""
        self.units_key = units_key
        """The file has a ``units`` key (plans): errors on radian-looking degrees name it."""
        self.angles: list[float] = [] if angles is None else angles
        """Every angle (not width) :meth:`angle` read from the file, as written; shared with
        sub-sections (for the radian-looking check)."""

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
        self, key: str, default: Any = _MISSING, *, min: float | None = None,
        max: float | None = None, unit: str = "",
    ) -> float:
        """A finite float (ints accepted) within optional bounds; ``unit`` is shown in errors."""
        value = self.get(key, float, default)
        if value is None:
            return value
        if not math.isfinite(value):
            raise self.error(key, f"must be a finite number, got {value!r}")
        u = f" {unit}" if unit else ""
        if min is not None and value < min:
            raise self.error(key, f"must be ≥ {min:g}{u}, got {value:g}{u}")
        if max is not None and value > max:
            raise self.error(key, f"must be ≤ {max:g}{u}, got {value:g}{u}")
        return value

    def angle(
        self, key: str, default: Any = _MISSING, *, min: float | None = None,
        max: float | None = None, width: bool = False,
    ) -> float:
        """An angle in degrees, written in :attr:`units` (radians are converted; a default is
        degrees), within optional bounds in degrees. A degree value out of bounds that would
        fit them as radians says so. ``width``: a step or bin size, not a direction (it is
        not recorded in :attr:`angles`)."""
        given = key in self.data
        value = self.get(key, float, default)
        if value is None or not given:
            return value
        if not math.isfinite(value):
            raise self.error(key, f"must be a finite number, got {value!r}")
        if not width:
            self.angles.append(value)
        if self.units == "rad":
            deg = math.degrees(value)
            if min is not None and min - math.degrees(RAD_SNAP) <= deg < min:
                deg = min
            if max is not None and max < deg <= max + math.degrees(RAD_SNAP):
                deg = max
            shown = f"{value:g} rad ({deg:.4g}°)"
        else:
            deg, shown = value, f"{value:g}°"
        low = min is not None and deg < min
        if low or (max is not None and deg > max):
            bound = f"≥ {min:g}°" if low else f"≤ {max:g}°"
            raise self.error(key, f"must be {bound}, got {shown}{self._radian_hint(value, min, max)}")
        return deg

    def _radian_hint(self, value: float, lo: float | None, hi: float | None) -> str:
        """``" (degrees; …)"`` when a degree ``value`` would lie within [lo, hi] as radians."""
        if self.units != "deg" or abs(value) > TWO_PI:
            return ""
        deg = math.degrees(value)
        if (lo is not None and deg < lo) or (hi is not None and deg > hi):
            return ""
        fix = ' or set units = "rad" in the plan' if self.units_key else ""
        return f" (degrees; {value:g} rad would be {deg:.3g}°: write it in degrees{fix})"

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
        return Section(value, self.source, name, units=self.units, units_key=self.units_key,
                       angles=self.angles)

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
