"""The camera as a triggerable, readable device whose reading is the RAW frame it saved.

A trigger writes one frame; the reading then names it: ``camera-frame`` (its path),
``camera-frame_exposure_s`` and ``camera-frame_iso`` (its exposure, as the journal records it
inside a sweep and as the camera reports it outside one), ``camera-frame_sha256``,
``camera-frame_step`` (the journal step, or the frame's number) and ``camera-frame_kind``
(``pose``, ``reference`` or ``frame``). Inside a :func:`~acquisition.bluesky.brdf_sweep` the
trigger shoots the session's next journal row through gonio's session engine (white reference
or sample, clipped frames retaken shorter); outside one it writes
``frame-NNNNNN.dng`` into ``frames_dir`` at the configured ``exposure_s`` and ``iso``.

A trigger cannot be taken back, so the camera is not rewindable (``rewindable.get()`` is
False, ophyd's convention that ``bluesky.plan_stubs.trigger_and_read`` asks): a RunEngine
that pauses and resumes never replays a trigger, and never duplicates a frame or an event.
"""

from __future__ import annotations

import math
from typing import Any

from bluesky.protocols import Triggerable
from ophyd_async.core import (
    AsyncStatus,
    SignalR,
    StandardReadable,
    StandardReadableFormat,
    soft_signal_rw,
)

from acquisition.bluesky.frames import Shot, shoot_free
from acquisition.bluesky.link import RigLink
from acquisition.bluesky.signals import RigSignalBackend


class NotRewindable:
    """``rewindable.get()`` → False: the device's trigger must not be replayed."""

    def get(self) -> bool:
        return False


class GonioCamera(StandardReadable, Triggerable):
    """The rig's RAW camera (simulated or gphoto2), one frame per trigger."""

    rewindable = NotRewindable()

    def __init__(self, link: RigLink, name: str = "camera") -> None:
        self._link = link
        described = link.devices.camera.describe()
        source = f"gonio-camera:{described.get('make', '?')} {described.get('model', '?')}"
        self._backends: dict[str, RigSignalBackend[Any]] = {
            "frame": RigSignalBackend(str, "", source=source),
            "frame_exposure_s": RigSignalBackend(float, math.nan, units="s", source=source),
            "frame_iso": RigSignalBackend(int, 0, source=source),
            "frame_sha256": RigSignalBackend(str, "", source=source),
            "frame_step": RigSignalBackend(int, -1, source=source),
            "frame_kind": RigSignalBackend(str, "", source=source),
        }
        with self.add_children_as_readables(StandardReadableFormat.HINTED_UNCACHED_SIGNAL):
            self.frame = SignalR(self._backends["frame"])
        with self.add_children_as_readables(StandardReadableFormat.UNCACHED_SIGNAL):
            self.frame_exposure_s = SignalR(self._backends["frame_exposure_s"])
            self.frame_iso = SignalR(self._backends["frame_iso"])
            self.frame_sha256 = SignalR(self._backends["frame_sha256"])
            self.frame_step = SignalR(self._backends["frame_step"])
            self.frame_kind = SignalR(self._backends["frame_kind"])
        with self.add_children_as_readables(StandardReadableFormat.CONFIG_SIGNAL):
            self.exposure_s = soft_signal_rw(float, link.rig.camera.exposure_s, units="s")
            self.iso = soft_signal_rw(int, link.rig.camera.iso)
        super().__init__(name=name)

    @AsyncStatus.wrap
    async def trigger(self) -> None:
        """Shoot one frame (the sweep's next journal row, inside a sweep); done once it is on
        disk, whole, hashed (and journaled)."""
        sweep = self._link.sweep
        if sweep is not None:
            shot = await sweep.shoot()
        else:
            exposure_s, iso = await self.exposure_s.get_value(), await self.iso.get_value()
            link = self._link
            shot = await link.worker.call(shoot_free, link.devices.capture, link.frames_dir,
                                          exposure_s, iso, link.seed)
        self._show(shot)

    def _show(self, shot: Shot) -> None:
        values = {"frame": str(shot.path), "frame_exposure_s": shot.exposure_s,
                  "frame_iso": shot.iso, "frame_sha256": shot.sha256, "frame_step": shot.step,
                  "frame_kind": shot.kind}
        for key, value in values.items():
            self._backends[key].set_value(value)
        if shot.joints:
            self._link.publish(shot.joints)
