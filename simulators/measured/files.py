"""Reading a material file whole, with a one-line :class:`MaterialError` when it cannot be."""

from __future__ import annotations

from pathlib import Path

from drivers.errors import MaterialError


def read_material_bytes(path: Path, what: str) -> bytes:
    """The bytes of ``path`` (``what`` names the kind of file in the message)."""
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise MaterialError(f"{what} {path} does not exist: check the path") from None
    except OSError as exc:
        raise MaterialError(f"{what} {path} cannot be read: {exc.strerror or exc}") from None
