"""Reading the tensor file container of the RGL-EPFL material database (Mitsuba 3's
``TensorFile``), the simulator's own reader.

All little-endian: the 12 bytes ``tensor_file\\0``; the version, two uint8 (1, 0); the field
count, uint32; then per field its name length (uint16), name (UTF-8), rank (uint16), type code
(uint8: Mitsuba's ``Struct::Type``, UInt8 = 1 … Float64 = 11), the byte offset of its data from
the start of the file (uint64) and its shape (rank × uint64). Each field's data are C-ordered
at its offset.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from drivers.errors import MaterialError
from simulators.measured.files import read_material_bytes

MAGIC = b"tensor_file\0"
TYPE_CODES = {1: "u1", 2: "i1", 3: "u2", 4: "i2", 5: "u4", 6: "i4", 7: "u8", 8: "i8",
              9: "f2", 10: "f4", 11: "f8"}
"""Mitsuba ``Struct::Type`` code → numpy type (little-endian)."""


class _Cursor:
    """Reads little-endian scalars one after the other from a byte string."""

    def __init__(self, raw: bytes, at: int) -> None:
        self.raw, self.at = raw, at

    def take(self, kind: str, count: int = 1) -> np.ndarray:
        dtype = np.dtype("<" + kind)
        end = self.at + dtype.itemsize * count
        if end > len(self.raw):
            raise ValueError("the header runs past the end of the file")
        out = np.frombuffer(self.raw[self.at:end], dtype=dtype)
        self.at = end
        return out

    def one(self, kind: str) -> int:
        return int(self.take(kind)[0])


def _fields(raw: bytes) -> dict[str, np.ndarray]:
    cursor = _Cursor(raw, len(MAGIC))
    version = tuple(int(v) for v in cursor.take("u1", 2))
    if version != (1, 0):
        raise ValueError(f"version {version[0]}.{version[1]}, not 1.0")
    out: dict[str, np.ndarray] = {}
    for _ in range(cursor.one("u4")):
        name = cursor.take("u1", cursor.one("u2")).tobytes().decode("utf-8")
        rank, code, offset = cursor.one("u2"), cursor.one("u1"), cursor.one("u8")
        shape = tuple(int(s) for s in cursor.take("u8", rank))
        if code not in TYPE_CODES:
            raise ValueError(f"field {name!r} has unknown type code {code}")
        dtype = np.dtype("<" + TYPE_CODES[code])
        count = int(np.prod(shape, dtype=np.int64))
        if offset + count * dtype.itemsize > len(raw):
            raise ValueError(f"field {name!r} runs past the end of the file")
        out[name] = np.frombuffer(raw, dtype=dtype, count=count, offset=offset).reshape(shape)
    return out


def read_tensor_fields(path: str | Path) -> dict[str, np.ndarray]:
    """Every field of a tensor file, name → array; :class:`MaterialError` naming what is wrong."""
    path = Path(path)
    raw = read_material_bytes(path, "tensor file")
    if not raw.startswith(MAGIC):
        raise MaterialError(f"{path} is not a tensor file (no 'tensor_file' magic): give an "
                            "RGL .bsdf file")
    try:
        return _fields(raw)
    except (ValueError, UnicodeDecodeError) as exc:
        raise MaterialError(f"tensor file {path} is truncated or malformed ({exc}); download or "
                            "export it again") from None
