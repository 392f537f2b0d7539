"""The tensor file container of the RGL-EPFL material database and Mitsuba 3 (``TensorFile``).

Layout, all little-endian:

* magic: the 12 bytes ``tensor_file\\0``;
* version: two uint8, 1 and 0;
* the number of fields, uint32;
* one record per field: name length (uint16), the name (UTF-8), rank (uint16), dtype (uint8,
  :data:`DTYPES`), the data's byte offset from the start of the file (uint64), then the
  shape (rank × uint64);
* each field's data, C order, at its offset (gonio aligns offsets to 8 bytes).
"""

from __future__ import annotations

import os
import struct
from collections.abc import Iterable, Mapping
from pathlib import Path

import numpy as np

from drivers.errors import ConfigError
from drivers.storage import Ours, atomic_output

MAGIC = b"tensor_file\0"
VERSION = (1, 0)
ALIGN_BYTES = 8
DTYPES: dict[int, np.dtype] = {
    1: np.dtype("<u1"), 2: np.dtype("<i1"), 3: np.dtype("<u2"), 4: np.dtype("<i2"),
    5: np.dtype("<u4"), 6: np.dtype("<i4"), 7: np.dtype("<u8"), 8: np.dtype("<i8"),
    9: np.dtype("<f2"), 10: np.dtype("<f4"), 11: np.dtype("<f8"),
}
"""Type code → numpy dtype (Mitsuba's ``Struct::Type``: UInt8 = 1 … Float64 = 11)."""
_CODES = {dt: code for code, dt in DTYPES.items()}


def is_tensor_file(path: str | os.PathLike[str]) -> bool:
    """True when ``path`` starts with the tensor-file magic."""
    try:
        with open(path, "rb") as fh:
            return fh.read(len(MAGIC)) == MAGIC
    except OSError:
        return False


def _records(fields: Mapping[str, np.ndarray]) -> tuple[bytes, list[tuple[int, np.ndarray]]]:
    """The header bytes and (offset, array) of each field's data."""
    arrays = {}
    for name, value in fields.items():
        arr = np.ascontiguousarray(value)
        dt = arr.dtype.newbyteorder("<")
        if dt not in _CODES:
            raise ValueError(f"tensor field {name!r}: dtype {arr.dtype} has no tensor-file code")
        arrays[name] = arr.astype(dt, copy=False)
    size = len(MAGIC) + 2 + 4 + sum(2 + len(n.encode()) + 2 + 1 + 8 + 8 * a.ndim
                                    for n, a in arrays.items())
    header = bytearray(MAGIC + struct.pack("<BBI", *VERSION, len(arrays)))
    placed = []
    offset = size
    for name, arr in arrays.items():
        offset = -(-offset // ALIGN_BYTES) * ALIGN_BYTES
        label = name.encode()
        header += struct.pack("<H", len(label)) + label
        header += struct.pack("<HBQ", arr.ndim, _CODES[arr.dtype], offset)
        header += struct.pack(f"<{arr.ndim}Q", *arr.shape)
        placed.append((offset, arr))
        offset += arr.nbytes
    return bytes(header), placed


def write_tensor_file(path: str | os.PathLike[str], fields: Mapping[str, np.ndarray], *, what: str,
                      ours: Ours = None, inputs: Iterable[str | os.PathLike[str]] = ()) -> None:
    """Write ``fields`` (name → array, written in this order) through
    :func:`drivers.storage.atomic_output`; the copy is read back and compared before the rename."""
    header, placed = _records(fields)

    def verify(tmp: Path) -> None:
        back = read_tensor_file(tmp)
        for name, value in fields.items():
            if name not in back or not np.array_equal(back[name], np.asarray(value), equal_nan=True):
                raise ValueError(f"field {name!r} does not read back as written")

    with atomic_output(path, what=what, verify=verify, ours=ours,
                       inputs=inputs) as tmp, open(tmp, "wb") as fh:
        fh.write(header)
        for offset, arr in placed:
            fh.write(b"\0" * (offset - fh.tell()))
            fh.write(arr.tobytes())


def read_tensor_file(path: str | os.PathLike[str]) -> dict[str, np.ndarray]:
    """Every field of a tensor file, name → array; :class:`ConfigError` naming what is wrong."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise ConfigError(f"tensor file {path} does not exist: check the path") from None
    except OSError as exc:
        raise ConfigError(f"tensor file {path} cannot be read: {exc.strerror or exc}") from None
    if raw[:len(MAGIC)] != MAGIC:
        raise ConfigError(f"{path} is not a tensor file (no 'tensor_file' magic): give an RGL "
                          ".bsdf file")
    try:
        return _parse(raw)
    except (struct.error, ValueError, KeyError) as exc:
        raise ConfigError(f"tensor file {path} is truncated or malformed ({exc}); "
                          "export or download it again") from None


def _parse(raw: bytes) -> dict[str, np.ndarray]:
    at = len(MAGIC)
    version = struct.unpack_from("<BB", raw, at)
    if version != VERSION:
        raise ValueError(f"version {version[0]}.{version[1]}, this gonio reads 1.0")
    (count,) = struct.unpack_from("<I", raw, at + 2)
    at += 6
    out = {}
    for _ in range(count):
        (n,) = struct.unpack_from("<H", raw, at)
        name = raw[at + 2:at + 2 + n].decode("utf-8")
        at += 2 + n
        ndim, code, offset = struct.unpack_from("<HBQ", raw, at)
        at += 11
        shape = struct.unpack_from(f"<{ndim}Q", raw, at)
        at += 8 * ndim
        dtype = DTYPES[code]
        nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
        if offset + nbytes > len(raw):
            raise ValueError(f"field {name!r} runs past the end of the file")
        out[name] = np.frombuffer(raw, dtype=dtype, count=nbytes // dtype.itemsize,
                                  offset=offset).reshape(shape)
    return out
