"""Many sessions in one call (a material library): reduced one after the other here, or by the
workers of a Dask cluster (the optional extra ``gonio[distributed]``), each into the table
:func:`acquisition.api.reduce` writes for it, bit for bit."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

from acquisition.api.sessions import DEFAULT_TABLE, reduce, write_table
from acquisition.reduction import CHECKPOINT_EVERY
from acquisition.reduction.point import Reduction
from acquisition.session.folder import SessionFolder
from acquisition.tables.isotropic import WHAT as TABLE_WHAT
from acquisition.tables.isotropic import is_table_file
from drivers.errors import ConfigError
from drivers.storage import check_output, ensure_folder

Sessions = Sequence[str | Path | SessionFolder]


def _path(session: str | Path | SessionFolder) -> Path:
    return session.path if isinstance(session, SessionFolder) else Path(session)


def table_paths(sessions: Sessions, out: str | Path | None = None) -> list[Path]:
    """Where each session's table goes: one session, ``out`` (default SESSION/brdf.h5) as
    :func:`~acquisition.api.reduce` names it; several, ``out`` is a folder and each table
    ``out/SESSION_NAME.h5`` (default: each SESSION/brdf.h5). Two sessions writing the same
    file are refused in one line (:class:`ConfigError`)."""
    paths = [_path(s) for s in sessions]
    if not paths:
        raise ConfigError("no session to reduce: name at least one session folder")
    if len(paths) == 1:
        return [Path(out) if out else paths[0] / DEFAULT_TABLE]
    if out is not None and Path(out).suffix == ".h5":
        raise ConfigError(f"-o {out} names one table but {len(paths)} sessions are reduced: give "
                          "a folder (each table is FOLDER/SESSION_NAME.h5)")
    outs = [Path(out) / f"{p.resolve().name}.h5" if out else p / DEFAULT_TABLE for p in paths]
    seen: dict[Path, Path] = {}
    for session, table in zip(paths, outs, strict=True):
        first = seen.setdefault(table.resolve(), session)
        if first is not session:
            raise ConfigError(f"sessions {first} and {session} would both write {table}: reduce "
                              "them in separate calls, or give -o a folder for sessions of "
                              "different names")
    return outs


def reduce_many(
    sessions: Sessions,
    out: str | Path | None = None,
    progress: Callable[[int, int], None] | None = None,
    *,
    calibration: str | Path | None = None,
    checkpoint_every: int = CHECKPOINT_EVERY,
    workers: int | None = None,
    scheduler: str | None = None,
) -> list[Reduction]:
    """Reduce every session into its table (:func:`table_paths`), in session order.

    Without ``workers`` or ``scheduler``: one session after the other, as
    :func:`~acquisition.api.reduce` does (checkpoints included). With ``workers=N`` (a new
    local cluster of N worker processes) or ``scheduler="tcp://HOST:PORT"`` (a running Dask
    cluster whose workers see the sessions at the same paths): every frame of every session is
    a task on the workers (:mod:`acquisition.reduction.distributed`; needs
    ``pip install 'gonio[distributed]'``), and each table is written as its session finishes.
    ``progress(done, total)``: frames over all sessions. ``calibration`` applies to every
    session. Every output is checked before anything is reduced; a session that fails
    writes nothing, and its error (one line) is raised once the others are written.
    """
    paths = [_path(s) for s in sessions]
    outs = table_paths(paths, out)
    if len(paths) > 1 and out is not None:
        ensure_folder(out, what="tables folder", inputs=paths)
    for session, table in zip(paths, outs, strict=True):
        check_output(table, what=TABLE_WHAT, ours=is_table_file, inputs=(session,))
    if workers is None and scheduler is None:
        return _one_by_one(sessions, outs, progress, calibration, checkpoint_every)
    from acquisition.lightstage.reduce import is_lightstage_session

    for session in paths:
        if is_lightstage_session(session):
            raise ConfigError(f"{session} is a light-stage session: reduce it without "
                              "--workers/--scheduler")
    from acquisition.reduction.distributed import dask_client, reduce_on_cluster

    with dask_client(workers, scheduler) as client:
        return reduce_on_cluster(client, paths, calibration, progress,
                                 on_done=lambda i, r: write_table(r, outs[i], paths[i]))


def _one_by_one(sessions: Sessions, outs: list[Path], progress: Callable[[int, int], None] | None,
                calibration: str | Path | None, checkpoint_every: int) -> list[Reduction]:
    """Each session reduced in turn; ``progress`` counts frames over the sessions so far."""
    results, before = [], 0
    last = [0]

    def step(done: int, total: int) -> None:
        last[0] = total
        if progress:
            progress(before + done, before + total)

    for session, table in zip(sessions, outs, strict=True):
        results.append(reduce(session, table, step, calibration=calibration,
                              checkpoint_every=checkpoint_every))
        before, last[0] = before + last[0], 0
    return results
