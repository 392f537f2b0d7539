"""bluesky plans on gonio's devices: :func:`brdf_sweep`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import bluesky.plan_stubs as bps
import bluesky.preprocessors as bpp
from bluesky.utils import MsgGenerator

from acquisition.bluesky.axes import PlannedPose
from acquisition.bluesky.rig import GonioDevices
from acquisition.bluesky.session import SweepSession
from drivers.errors import ConfigError


def brdf_sweep(devices: GonioDevices, plan_path: str | Path, session_dir: str | Path, *,
               md: dict[str, Any] | None = None) -> MsgGenerator[str]:
    """Capture a gonio plan file with the RunEngine into an ordinary gonio session folder.

    The schedule is gonio's: the plan's poses as the planner accepted and ordered them, white
    references first, every ``reference_every`` poses and last, each move routed and guarded
    (the session's journal, made as ``gonio capture`` makes it). For each journal row still to
    do: a ``checkpoint``, the pose device moved to the row's pose (the planner's joints), then
    one event from the camera, the pose and every axis (``trigger_and_read``). The frames and
    the journal are those ``gonio capture`` writes, so ``gonio info``, ``verify``, ``reduce``
    and ``resume`` work on the folder.

    The RunEngine may pause at any checkpoint (and, stopping the arms, at once) and resume:
    the camera is not rewindable, so nothing is shot twice and no event is repeated. A run that
    ends early (stopped, aborted, failed) leaves the session resumable; running ``brdf_sweep``
    again on the same folder (same rig, plan, material, seed) shoots only the rows left. A run
    stopped while paused in the middle of a step keeps that step's frame in the session
    without an event for it (the journal has it).

    Parameters
    ----------
    devices
        From :func:`~acquisition.bluesky.open_rig_devices` (a servo rig).
    plan_path
        The gonio plan file (TOML).
    session_dir
        The session folder to create (or an unfinished one of the same capture to continue).
    md
        Extra metadata for the start document.

    Yields
    ------
    msg : Msg
        Messages to stage the session, open the run, then per row ``checkpoint``, ``set`` and
        ``wait`` (pose), ``trigger``, ``wait``, ``create``, ``read``, ``save``.

    Returns
    -------
    str
        The session folder.
    """
    if devices.pose is None:
        raise ConfigError(f"{devices.rig.path} is a light-stage rig: brdf_sweep moves arms; "
                          "capture it with `gonio lightstage capture`")
    pose = devices.pose
    session = SweepSession(devices.link, plan_path, session_dir)
    readers = [devices.camera, pose, *devices.axes.values()]

    def rows() -> MsgGenerator[None]:
        for rec in session.rows:
            assert rec.theta_i is not None and rec.theta_r is not None and rec.delta_phi is not None
            yield from bps.checkpoint()
            yield from bps.mv(pose, PlannedPose(rec.theta_i, rec.theta_r, rec.delta_phi,
                                                rec.joints_cmd))
            yield from bps.trigger_and_read(readers)

    def staged() -> MsgGenerator[str]:
        yield from bps.stage(session, wait=True)
        yield from bpp.run_wrapper(rows(), md={**start_metadata(devices, session), **(md or {})})
        return str(session.session_dir)

    return (yield from bpp.finalize_wrapper(staged(), bps.unstage(session, wait=True)))


def start_metadata(devices: GonioDevices, session: SweepSession) -> dict[str, Any]:
    """The start document's gonio part: rig, plan, session folder, material, seed, frames."""
    folder = session.engine.folder
    rig, plan = folder.rig(), folder.plan()
    pose = devices.pose
    assert pose is not None
    return {
        "plan_name": "brdf_sweep",
        "plan_args": {"plan_path": str(session.plan_path), "session_dir": str(folder.path)},
        "rig": {"path": str(devices.rig.path), "name": rig.name, "kinematics": rig.kinematics_name},
        "plan": {"path": str(session.plan_path), "name": plan.name},
        "session": str(folder.path),
        "material": folder.info.material,
        "seed": folder.info.seed,
        "frames": {"planned": session.planned, "to_shoot": len(session.rows)},
        "motors": [pose.name, *devices.axes],
        "detectors": [devices.camera.name],
        "hints": {"dimensions": [([pose.theta_i.name, pose.theta_r.name, pose.delta_phi.name],
                                  "primary")]},
    }

