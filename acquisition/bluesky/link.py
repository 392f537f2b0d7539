"""What the bluesky devices of one open rig share: gonio's open devices, the one thread that
calls them, the last read-back joints, and the sweep in progress.

Event-loop side only: :meth:`RigLink.publish` sets signal values, so it runs on the RunEngine's
loop, after the awaited job that learnt the joints.
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from acquisition.bluesky.worker import RigWorker
from acquisition.config.rig import RigConfig
from acquisition.devices.rig import RigDevices
from drivers.errors import ConfigError, SafetyStop

if TYPE_CHECKING:
    from acquisition.bluesky.session import SweepSession
    from acquisition.lightstage.devices import LightStageDevices

JointsListener = Callable[[Mapping[str, float]], None]


class RigLink:
    """The shared state of one open rig's bluesky devices.

    Parameters
    ----------
    rig
        The rig file, as loaded.
    devices
        gonio's open devices (:class:`RigDevices`, or a light stage's).
    worker
        The thread that alone calls them.
    material, seed
        The simulated world's material spec and noise seed (sessions record them).
    frames_dir
        Where the camera writes frames shot outside a sweep (None: it refuses to).
    """

    def __init__(self, rig: RigConfig, devices: RigDevices | LightStageDevices, worker: RigWorker,
                 *, material: str | None, seed: int, frames_dir: Path | None) -> None:
        self.rig = rig
        self.devices = devices
        self.worker = worker
        self.material = material
        self.seed = seed
        self.frames_dir = frames_dir
        self.joints: dict[str, float] | None = None
        """The read-back joints (deg) of the last confirmed move or read; None: not known yet."""
        self.sweep: SweepSession | None = None
        """The staged sweep whose session engine journals the frames, if any."""
        self._listeners: list[JointsListener] = []
        self._moves = 0
        self._in_flight: set[object] = set()
        self._stopped_on_purpose: set[object] = set()

    @property
    def servo(self) -> RigDevices:
        """The servo rig (refused in one line on a light stage)."""
        if not isinstance(self.devices, RigDevices):
            raise ConfigError(f"{self.rig.path}: the light stage has no moving axes; set its LEDs")
        return self.devices

    def axis_source(self, axis: str) -> str:
        """``dynamixel://PORT#id=N``: the port and servo ID behind ``axis``."""
        cfg = self.rig.axes[axis]
        port = self.servo.ports.get(axis, self.rig.buses[cfg.bus].port)
        return f"dynamixel://{port}#id={cfg.servo_id}"

    # ------------------------------------------------------------------ joints
    def on_joints(self, listener: JointsListener) -> None:
        """Call ``listener(joints)`` whenever new read-back joints are known."""
        self._listeners.append(listener)

    def publish(self, joints: Mapping[str, float]) -> None:
        """New read-back joints (deg): every listening signal takes them (event loop only)."""
        self.joints = {k: float(v) for k, v in joints.items()}
        for listener in self._listeners:
            listener(self.joints)

    async def known_joints(self) -> dict[str, float]:
        """The read-back joints, read from the servos once if nothing is known yet."""
        if self.joints is None:
            self.publish(await self.worker.call(self.servo.motion.where_deg))
        assert self.joints is not None
        return dict(self.joints)

    # ------------------------------------------------------------------ moves
    async def move(self, fn: Callable[..., Mapping[str, float]], *args: Any) -> None:
        """Run the move ``fn(*args)`` (returning the read-back joints) on the rig's thread and
        publish its read-back; :meth:`stop_motion` may end it meanwhile."""
        self._moves += 1
        try:
            return await self.confirmed(self.worker.call(fn, *args, moves=True))
        finally:
            self._moves -= 1

    async def confirmed(self, move: Awaitable[Mapping[str, float]]) -> None:
        """Await a move's read-back joints and publish them. After a failed or stopped move
        the next read asks the servos again; a move ended by ``stop(success=True)`` (the
        RunEngine pausing) completes without error, as bluesky expects of such a stop."""
        token = object()
        self._in_flight.add(token)
        try:
            joints = await move
        except SafetyStop:
            self.joints = None
            if token in self._stopped_on_purpose:
                return
            raise
        except BaseException:
            self.joints = None
            raise
        finally:
            self._in_flight.discard(token)
            self._stopped_on_purpose.discard(token)
        self.publish(joints)

    async def stop_motion(self, success: bool) -> None:
        """Stop every axis if a move is under way (nothing otherwise: no bus traffic);
        ``success``: the moves' statuses complete rather than fail.

        :meth:`MotionController.stop` is made to be called from another thread than the
        moving one (the bus serialises its packets), so it runs beside the rig's thread.
        """
        if self._moves or (self.sweep is not None and self.sweep.moving):
            if success:
                self._stopped_on_purpose |= self._in_flight
            await asyncio.to_thread(self.servo.stop_motion)
