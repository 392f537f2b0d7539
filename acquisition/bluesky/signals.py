"""The signals of gonio's bluesky devices: soft signals that say where their value comes from.

A :class:`RigSignalBackend` is an ophyd-async soft signal backend whose data key names its
source (``dynamixel:///dev/ttyUSB0#id=1``, ``gonio-camera:…``) instead of ``soft://…``, carries
the control limits of an axis, and may refresh its value (an awaited call) before a read. The
devices set its value after every action they confirm (a move read back, a frame written), so a
read costs no bus traffic unless nothing is known yet.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable

from bluesky.protocols import Reading
from ophyd_async.core import SignalDatatypeT, SoftSignalBackend

Refresh = Callable[[], Awaitable[object]]
"""Awaited before a read (it sets the signal's value when it learns something new)."""


class RigSignalBackend(SoftSignalBackend[SignalDatatypeT]):
    """A soft signal backend with a real source, optional limits and an optional refresh.

    Parameters
    ----------
    datatype, initial_value, units, precision
        As :class:`ophyd_async.core.SoftSignalBackend`.
    source
        What the value comes from (port and servo ID, camera, DMX widgets).
    limits
        ``(low, high)`` control limits (an axis' soft limits, degrees).
    refresh
        Awaited before each read (e.g. read the servos once when no position is known yet).
    """

    def __init__(self, datatype: type[SignalDatatypeT], initial_value: SignalDatatypeT | None = None,
                 *, source: str, units: str | None = None, precision: int | None = None,
                 limits: tuple[float, float] | None = None, refresh: Refresh | None = None) -> None:
        super().__init__(datatype, initial_value, units, precision)
        self._source = source
        self._refresh = refresh
        if limits is not None:
            low, high = limits
            self.metadata["limits"] = {"control": {"low": low, "high": high},
                                       "display": {"low": low, "high": high}}

    def source(self, name: str, read: bool) -> str:
        return self._source

    async def get_reading(self) -> Reading[SignalDatatypeT]:
        if self._refresh is not None:
            await self._refresh()
        return await super().get_reading()

    async def get_value(self) -> SignalDatatypeT:
        if self._refresh is not None:
            await self._refresh()
        return await super().get_value()
