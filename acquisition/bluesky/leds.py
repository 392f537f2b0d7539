"""A light stage's LEDs as one settable device: ``set(levels)`` lights LED k at ``levels[k]``
(0–1, all at once, every other LED off) and completes once the light state is on and settled
(:meth:`acquisition.lightstage.devices.LightStageDevices.set_levels`)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from bluesky.protocols import Movable
from ophyd_async.core import Array1D, AsyncStatus, SignalR, StandardReadable, StandardReadableFormat

from acquisition.bluesky.link import RigLink
from acquisition.bluesky.signals import RigSignalBackend
from acquisition.lightstage.devices import LightStageDevices
from drivers.errors import ConfigError


class LedDome(StandardReadable, Movable):
    """Every LED of the dome, read and set as one array of levels (0–1)."""

    def __init__(self, link: RigLink, name: str = "leds") -> None:
        devices = link.devices
        assert isinstance(devices, LightStageDevices)
        self._link = link
        self._count = len(devices.stage)
        ports = {u: getattr(devices.sims.get(u), "path", None) or port
                 for u, port in devices.stage.ports.items()}
        source = "dmx:" + ",".join(f"{port}#universe={u}" for u, port in sorted(ports.items()))
        self._backend = RigSignalBackend(Array1D[np.float64], np.zeros(self._count), source=source)
        with self.add_children_as_readables(StandardReadableFormat.HINTED_UNCACHED_SIGNAL):
            self.levels = SignalR(self._backend)
        super().__init__(name=name)

    def set_name(self, name: str, *, child_name_separator: str | None = None) -> None:
        super().set_name(name, child_name_separator=child_name_separator)
        self.levels.set_name(name)

    @AsyncStatus.wrap
    async def set(self, value: Sequence[float]) -> None:
        """Light LED k at ``value[k]`` (0–1) and every other one off; done once settled."""
        levels = np.asarray(value, dtype=np.float64)
        if levels.shape != (self._count,) or not np.all((levels >= 0) & (levels <= 1)):
            raise ConfigError(f"{self._link.rig.path}: LED levels must be {self._count} numbers "
                              f"within 0–1, got shape {levels.shape}")
        devices = self._link.devices
        assert isinstance(devices, LightStageDevices)
        await self._link.worker.call(devices.set_levels, levels)
        self._backend.set_value(levels)
