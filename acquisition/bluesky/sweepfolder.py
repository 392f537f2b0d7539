"""The session folder of a brdf_sweep: made as ``gonio capture`` makes it, or reopened to finish.

A new folder gets the rig and plan copies, ``session.json`` (material, seed) and every planned
step in its journal (:func:`acquisition.session.folder.create_session`), so ``gonio info``,
``verify``, ``reduce`` and ``resume`` treat it as any capture. An existing one is continued only
if it is the same capture: the same rig and plan files, material and seed.
"""

from __future__ import annotations

from pathlib import Path

from acquisition.bluesky.link import RigLink
from acquisition.config.plan import check_plan_on_rig, load_plan
from acquisition.config.rig import require_servo_rig
from acquisition.planning.planner import Planner
from acquisition.session.folder import INFO_FILE, PLAN_FILE, RIG_FILE, SessionFolder, create_session
from drivers.errors import ConfigError, SessionError

COMMAND = "brdf_sweep"


def open_sweep_folder(link: RigLink, plan_path: Path, session_dir: Path) -> SessionFolder:
    """Create the session folder ``session_dir`` for the plan, or reopen an unfinished one.

    Raises
    ------
    ConfigError
        A light-stage rig, a plan the rig's camera cannot take, an HDR plan.
    SessionError
        ``session_dir`` is another capture (rig, plan, material or seed differ), a scripted
        session, or a folder that is not a session and not empty.
    """
    rig = link.rig
    require_servo_rig(rig, COMMAND)
    if (session_dir / INFO_FILE).is_file():
        folder = SessionFolder(session_dir)
        _require_same_capture(folder, link, plan_path)
        folder.require_writable()
        return folder
    plan = load_plan(plan_path)
    check_plan_on_rig(plan, rig)
    if plan.capture.hdr:
        raise ConfigError(f"{plan.path}: [capture] hdr = true brackets each pose, which {COMMAND} "
                          "does not: capture it with `gonio capture`")
    folder, _ = create_session(session_dir, rig, plan, material=link.material, seed=link.seed,
                               planner=Planner.for_plan(rig, plan))
    return folder


def _require_same_capture(folder: SessionFolder, link: RigLink, plan_path: Path) -> None:
    info = folder.info
    if info.scripted:
        raise SessionError(f"{folder.path} is a scripted session: rerun its script to continue it")
    if (folder.path / RIG_FILE).read_bytes() != Path(link.rig.path).read_bytes():
        raise SessionError(f"{folder.path} was captured with another rig file than "
                           f"{link.rig.path}: open the devices with {folder.path / RIG_FILE}")
    if (folder.path / PLAN_FILE).read_bytes() != Path(plan_path).read_bytes():
        raise SessionError(f"{folder.path} was captured with another plan than {plan_path}: "
                           f"give {folder.path / PLAN_FILE}, or a new session folder")
    if (info.material, info.seed) != (link.material, link.seed):
        raise SessionError(f"{folder.path} was captured with material {info.material!r} and seed "
                           f"{info.seed}: open the devices with those to continue it")
