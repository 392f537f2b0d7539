"""A cheap re-open check of a RAW frame just written (the frame writer's ``verify`` hook).

A DNG is a TIFF: the check parses its header and first IFD with tifffile and requires the
image data of that IFD and of its SubIFDs, and its EXIF IFD, to lie inside the file, which
finds a truncated or half-transferred frame in a fraction of a millisecond without decoding a
pixel. Other TIFF-based RAWs (CR2, NEF, ARW) must parse; formats that are not TIFF (CR3, RAF)
are checked for size only, by the writer.
"""

from __future__ import annotations

import os
import struct
from typing import BinaryIO

from calibration.raw import open_tiff_quietly

TIFF_MAGIC = (b"II*\0", b"MM\0*", b"II+\0", b"MM\0+")
"""First bytes of a classic TIFF, then of a BigTIFF (little-, big-endian)."""

_DNG_VERSION = 50706
_EXIF_IFD = 34665


class FrameDamaged(ValueError):
    """A written frame does not read back whole."""


def check_raw_frame(path: str | os.PathLike[str]) -> None:
    """Raise :class:`FrameDamaged` (naming the damage) when the RAW frame at ``path`` is cut
    short or its TIFF structure does not parse; see the module docstring."""
    size = os.path.getsize(path)
    with open(path, "rb") as fh:
        magic = fh.read(4)
    if magic not in TIFF_MAGIC:
        return
    try:
        with open_tiff_quietly(path) as tif:
            first = tif.pages.first
            if _DNG_VERSION not in first.tags:
                return
            ifds = [first, *(first.pages or [])]
            data_end = max((o + n for ifd in ifds
                            for o, n in zip(ifd.dataoffsets, ifd.databytecounts, strict=False)),
                           default=0)
            exif = first.tags.get(_EXIF_IFD)
            exif_at = None if exif is None else exif.offset
    except Exception as exc:
        raise FrameDamaged(f"its TIFF structure does not parse ({type(exc).__name__}: {exc})") from exc
    exif_end = 0
    if exif_at is not None:
        with open(path, "rb") as fh:
            exif_end = _exif_ifd_end(fh, exif_at, size, "<" if magic[:2] == b"II" else ">",
                                     big=magic in TIFF_MAGIC[2:])
    for what, end in (("image data", data_end), ("EXIF IFD", exif_end)):
        if end > size:
            raise FrameDamaged(f"truncated at {size:,} bytes: part of its {what} lies beyond the end")


_TYPE_BYTES = {1: 1, 2: 1, 3: 2, 4: 4, 5: 8, 6: 1, 7: 1, 8: 2, 9: 4, 10: 8, 11: 4, 12: 8, 13: 4,
               16: 8, 17: 8, 18: 8}
"""Bytes per value of each TIFF field type."""


class _Beyond(Exception):
    """A structure read past the end of the file."""


def _exif_ifd_end(fh: BinaryIO, entry_at: int, size: int, order: str, big: bool) -> int:
    """Where the EXIF IFD that IFD0's entry at ``entry_at`` points to ends, its entries' own
    values included (past ``size`` when some of it lies beyond the file)."""
    word, nfmt = ("Q", "Q") if big else ("I", "H")  # offsets and counts; number of entries
    inline = 8 if big else 4  # bytes of an entry's value field
    entry = 4 + 2 * inline  # tag, type, count, value

    def unpack(fmt: str, at: int) -> tuple[int, ...]:
        n = struct.calcsize(order + fmt)
        if at < 0 or at + n > size:
            raise _Beyond
        fh.seek(at)
        return struct.unpack(order + fmt, fh.read(n))

    try:
        (start,) = unpack(word, entry_at + 4 + inline)
        (n,) = unpack(nfmt, start)
        table = start + struct.calcsize(order + nfmt)
        end = table + n * entry + inline  # the entries and the next-IFD offset
        if end > size:
            return end
        for i in range(n):
            _, kind, count, value = unpack("HH" + 2 * word, table + i * entry)
            if (nbytes := count * _TYPE_BYTES.get(kind, 1)) > inline:
                end = max(end, value + nbytes)
    except _Beyond:
        return size + 1
    return end
