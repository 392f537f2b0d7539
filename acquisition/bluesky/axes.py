"""Motion devices: each servo axis, and the pose (θi, θr, Δφ) all of them realise together.

Every move goes through gonio's own path (:meth:`acquisition.devices.rig.RigDevices.move_to`):
servo health, the planner's motion guard on the swept path, one sync write, confirmation by
read-back, the rig's settle time. A status completes when the read-back confirms the move and
fails with gonio's one-line reason when the guard refuses it (nothing is sent then).

* :class:`GonioAxis` moves its own servo only, straight: a move the guard finds unsafe is
  refused, never routed (a route would move the other arm).
* :class:`GonioPose` moves every axis in one guarded sync write per leg, routed round the
  other arm when the straight move is not safe — not axis by axis, which would check each path
  without the others' motion. ``set((θi, θr, Δφ))`` picks the joint solution nearest to where
  the arms stand; a :class:`PlannedPose` carries the joints a planner chose.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

from bluesky.protocols import Checkable, Locatable, Location, Stoppable
from ophyd_async.core import AsyncStatus, SignalR, StandardReadable, StandardReadableFormat

from acquisition.bluesky.link import RigLink
from acquisition.bluesky.signals import RigSignalBackend
from acquisition.geometry.kinematics import Pose
from drivers.errors import LimitError

DEG = "deg"
PRECISION = 3
"""Decimal places shown for angles (the servos resolve 0.088°)."""


class PlannedPose(tuple[float, float, float]):
    """A pose (θi, θr, Δφ in degrees) with the joints (deg) a planner chose for it.

    It is a plain 3-tuple for everything else; :class:`GonioPose` moves to ``joints``.
    """

    joints: dict[str, float]

    def __new__(cls, theta_i: float, theta_r: float, delta_phi: float,
                joints: Mapping[str, float]) -> PlannedPose:
        pose = super().__new__(cls, (float(theta_i), float(theta_r), float(delta_phi)))
        pose.joints = {k: float(v) for k, v in joints.items()}
        return pose


class GonioAxis(StandardReadable, Locatable, Checkable, Stoppable):
    """One servo axis (degrees): read back, moved alone through gonio's guard.

    ``describe()`` of its reading (named after the axis) carries ``units`` (deg), control
    ``limits`` (the rig file's soft limits) and ``source`` (``dynamixel://PORT#id=N``).
    """

    def __init__(self, link: RigLink, axis: str) -> None:
        cfg = link.rig.axes[axis]
        self._link = link
        self._axis = axis
        self._limits = (cfg.min_deg, cfg.max_deg)
        self._setpoint = math.nan
        self._backend = RigSignalBackend(float, math.nan, units=DEG, precision=PRECISION,
                                         source=link.axis_source(axis), limits=self._limits,
                                         refresh=link.known_joints)
        with self.add_children_as_readables(StandardReadableFormat.HINTED_UNCACHED_SIGNAL):
            self.readback = SignalR(self._backend)
        super().__init__(name=axis)
        link.on_joints(lambda joints: self._backend.set_value(joints[axis]))

    def set_name(self, name: str, *, child_name_separator: str | None = None) -> None:
        super().set_name(name, child_name_separator=child_name_separator)
        self.readback.set_name(name)  # the reading is named after the axis, as a motor's is

    async def check_value(self, value: float) -> None:
        """Refuse a target outside the axis' soft limits (:class:`LimitError`, one line)."""
        low, high = self._limits
        if not low <= float(value) <= high:
            raise LimitError(f"{self._axis}: {float(value):g}° is outside its limits "
                             f"[{low:g}°, {high:g}°] (rig file {self._link.rig.path})")

    @AsyncStatus.wrap
    async def set(self, value: float) -> None:
        """Move this axis alone to ``value`` (deg); done when the read-back confirms it."""
        self._setpoint = float(value)
        await self._link.move(self._move, self._setpoint)

    def _move(self, target_deg: float) -> dict[str, float]:
        return self._link.servo.move_to({self._axis: target_deg}, routed=False)

    async def locate(self) -> Location[float]:
        joints = await self._link.known_joints()
        return Location(setpoint=self._setpoint, readback=joints[self._axis])

    async def stop(self, success: bool = True) -> None:
        """Stop every axis (braking, torque on) if a move is under way; ``success``: its status
        completes (a pause) rather than fails."""
        await self._link.stop_motion(success)


class GonioPose(StandardReadable, Locatable, Stoppable):
    """The pose (θi, θr, Δφ, degrees) the read-back joints realise; ``set`` moves all axes.

    In a :func:`~acquisition.bluesky.brdf_sweep` the move goes through the session engine, which
    then knows where the arms are (it moves again only to somewhere else).
    """

    def __init__(self, link: RigLink, name: str = "pose") -> None:
        self._link = link
        self._setpoint: tuple[float, float, float] = (math.nan, math.nan, math.nan)
        self._kinematics = link.servo.planner.kinematics
        source = "gonio-pose:" + ",".join(link.axis_source(a) for a in link.rig.axes)
        self._backends = {key: RigSignalBackend(float, math.nan, units=DEG, precision=PRECISION,
                                                source=f"{source}#{key}", refresh=link.known_joints)
                          for key in ("theta_i", "theta_r", "delta_phi")}
        with self.add_children_as_readables(StandardReadableFormat.HINTED_UNCACHED_SIGNAL):
            self.theta_i = SignalR(self._backends["theta_i"])
            self.theta_r = SignalR(self._backends["theta_r"])
            self.delta_phi = SignalR(self._backends["delta_phi"])
        super().__init__(name=name)
        link.on_joints(self._publish)

    def _publish(self, joints: Mapping[str, float]) -> None:
        pose = self._kinematics.forward(joints)
        for key, value in zip(self._backends, pose.as_tuple(), strict=True):
            self._backends[key].set_value(value)

    @AsyncStatus.wrap
    async def set(self, value: Sequence[float]) -> None:
        """Move to the pose ``value`` = (θi, θr, Δφ) in degrees: every axis in one guarded,
        routed move; done when the read-back confirms it."""
        theta_i, theta_r, delta_phi = (float(v) for v in value)
        pose = Pose(theta_i, theta_r, delta_phi)
        self._setpoint = pose.as_tuple()
        joints = getattr(value, "joints", None)
        sweep = self._link.sweep
        if sweep is not None:  # through the session engine, which then knows where it stands
            await self._link.confirmed(sweep.goto(pose, joints))
        else:
            await self._link.move(self._move, pose, joints)

    async def locate(self) -> Location[tuple[float, float, float]]:
        """The last target pose and the pose the read-back joints realise (θi, θr, Δφ, deg)."""
        joints = await self._link.known_joints()
        return Location(setpoint=self._setpoint,
                        readback=self._kinematics.forward(joints).as_tuple())

    def _move(self, pose: Pose, joints: Mapping[str, float] | None) -> dict[str, float]:
        servo = self._link.servo
        target = joints or servo.planner.joints_for(pose, servo.motion.where_deg())
        return servo.move_to(dict(target))

    async def stop(self, success: bool = True) -> None:
        """Stop every axis (braking, torque on) if a move is under way; ``success``: its status
        completes (a pause) rather than fails."""
        await self._link.stop_motion(success)
