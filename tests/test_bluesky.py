"""bluesky on gonio's devices (``gonio[bluesky]``): brdf_sweep under a real RunEngine, paused and
resumed, writes the session ``gonio capture`` writes; a refused move fails its status with
gonio's own line and moves nothing; the camera and the LEDs outside a sweep."""

from __future__ import annotations

import asyncio
import sqlite3
import time
from collections import Counter
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pytest
from conftest import EXAMPLES, LIGHTSTAGE_RIG, TINY_MATERIAL

pytest.importorskip("bluesky")
pytest.importorskip("ophyd_async")

import bluesky.plan_stubs as bps  # noqa: E402
import bluesky.preprocessors as bpp  # noqa: E402
from bluesky import Msg, RunEngine  # noqa: E402
from bluesky.utils import FailedStatus, RunEngineInterrupted  # noqa: E402

from acquisition.bluesky import GonioDevices, brdf_sweep, open_rig_devices  # noqa: E402
from acquisition.bluesky.worker import Job  # noqa: E402
from acquisition.cli import main  # noqa: E402
from drivers.errors import GonioError  # noqa: E402

RIG = EXAMPLES / "rig-sim.toml"
SEED = 3
"""The ``finished`` fixture's capture: the tiny plan, TINY_MATERIAL, seed 3."""


@pytest.fixture
def RE() -> Iterator[RunEngine]:  # noqa: N802 - bluesky's own name for it
    """A RunEngine on its own event loop, which stops (and its thread ends) afterwards."""
    loop = asyncio.new_event_loop()
    engine = RunEngine({}, loop=loop)
    yield engine
    if engine.state not in ("idle", "panicked"):
        engine.halt()
    loop.call_soon_threadsafe(loop.stop)
    engine._th.join()
    loop.close()


def _collect(RE: RunEngine) -> list[tuple[str, dict[str, Any]]]:  # noqa: N803
    docs: list[tuple[str, dict[str, Any]]] = []
    RE.subscribe(lambda name, doc: docs.append((name, doc)))
    return docs


Mutator = Callable[[Msg], tuple[Any, Any]]
"""A ``bluesky.preprocessors.plan_mutator`` message processor."""


def _pause_after_trigger(n: int, *, defer: bool = False) -> Mutator:
    """A plan mutator pausing the RunEngine right after the ``n``-th camera trigger: at once,
    mid-step (the frame in flight, where only a non-rewindable camera keeps it from being shot
    again on resume), or ``defer``red to the next checkpoint (the operator's first Ctrl-C)."""
    seen: list[Msg] = []

    def mutate(msg: Msg) -> tuple[Any, Any]:
        if msg.command == "trigger" and msg.obj.name == "camera":
            seen.append(msg)
            if len(seen) == n:
                return None, bps.deferred_pause() if defer else bps.pause()
        return None, None
    return mutate


def _journal(session: Path) -> list[tuple[Any, ...]]:
    """Every step row of a finished (checkpointed) session; ``immutable``: the reader makes no
    -wal/-shm file in a session other tests share."""
    db = sqlite3.connect(f"{(session / 'journal.sqlite').as_uri()}?immutable=1", uri=True)
    try:
        return db.execute("SELECT step, kind, theta_i, theta_r, delta_phi, joints_cmd, frame, "
                          "sha256, joints_read, exposure_s, iso, device_time_s, status "
                          "FROM steps ORDER BY step").fetchall()
    finally:
        db.close()


def _datasets(path: Path) -> dict[str, bytes]:
    out: dict[str, bytes] = {}
    with h5py.File(path, "r") as f:
        f.visititems(lambda name, obj: out.__setitem__(name, np.asarray(obj[()]).tobytes())
                     if isinstance(obj, h5py.Dataset) else None)
    return out


def _check_documents(docs: list[tuple[str, dict[str, Any]]], session: Path, plan: Path,
                     frames: list[str]) -> None:
    counts = Counter(name for name, _ in docs)
    assert counts == {"start": 1, "descriptor": 1, "event": len(frames), "stop": 1}, counts
    start = next(d for n, d in docs if n == "start")
    assert start["plan_name"] == "brdf_sweep"
    assert start["rig"]["path"] == str(RIG) and start["plan"]["path"] == str(plan)
    assert start["session"] == str(session) and start["seed"] == SEED
    keys = next(d for n, d in docs if n == "descriptor")["data_keys"]
    for axis, servo_id in (("light_theta", 1), ("camera_theta", 2), ("camera_phi", 3)):
        assert keys[axis]["units"] == "deg", keys[axis]
        assert keys[axis]["source"].startswith("dynamixel:///dev/") and \
            keys[axis]["source"].endswith(f"#id={servo_id}")
        assert keys[axis]["limits"]["control"]["high"] > keys[axis]["limits"]["control"]["low"]
    assert {keys[f"pose-{k}"]["units"] for k in ("theta_i", "theta_r", "delta_phi")} == {"deg"}
    assert keys["camera-frame_exposure_s"]["units"] == "s"
    events = [d for n, d in docs if n == "event"]
    assert [e["seq_num"] for e in events] == list(range(1, len(frames) + 1))
    assert [Path(e["data"]["camera-frame"]).name for e in events] == frames  # one event per frame
    assert all(e["data"]["camera-frame_exposure_s"] > 0 and e["data"]["camera-frame_iso"] > 0
               for e in events)
    stop = next(d for n, d in docs if n == "stop")
    assert stop["exit_status"] == "success" and stop["num_events"] == {"primary": len(frames)}


def test_brdf_sweep_pauses_resumes_and_reduces_to_the_captured_table(
    RE: RunEngine, finished: dict[str, Path], tmp_path: Path,  # noqa: N803
) -> None:
    docs = _collect(RE)
    triggers = Counter[str]()
    RE.msg_hook = lambda msg: triggers.update([msg.obj.name]) if msg.command == "trigger" else None
    session = tmp_path / "bluesky-session"
    with open_rig_devices(RIG, material=TINY_MATERIAL, seed=SEED) as devices:
        plan = bpp.plan_mutator(brdf_sweep(devices, finished["plan"], session), _pause_after_trigger(3))
        with pytest.raises(RunEngineInterrupted):
            RE(plan)
        assert RE.state == "paused"
        RE.resume()
        assert devices.link.servo.collisions() == []
    journal = _journal(session)
    frames = [row[6] for row in journal]
    assert all(row[-1] == "done" for row in journal)
    assert triggers["camera"] == len(frames) == 6  # never re-shot after the pause
    _check_documents(docs, session, finished["plan"], frames)
    # the same schedule, frames (SHA-256), read-back joints and rig times as `gonio capture`'s
    assert journal == _journal(finished["session"])
    assert main(["verify", str(session)]) == 0
    assert main(["info", str(session)]) == 0
    assert main(["reduce", str(session), "-o", str(tmp_path / "bluesky.h5")]) == 0
    ours, theirs = _datasets(tmp_path / "bluesky.h5"), _datasets(finished["table"])
    assert ours.keys() == theirs.keys() and all(ours[k] == theirs[k] for k in ours)  # bit for bit


def test_a_stopped_sweep_continues_where_it_stopped(
    RE: RunEngine, finished: dict[str, Path], tmp_path: Path,  # noqa: N803
) -> None:
    docs = _collect(RE)
    session = tmp_path / "s"
    with open_rig_devices(RIG, material=TINY_MATERIAL, seed=SEED) as devices:
        with pytest.raises(RunEngineInterrupted):
            RE(bpp.plan_mutator(brdf_sweep(devices, finished["plan"], session),
                                _pause_after_trigger(2, defer=True)))
        RE.stop()  # unstaged: the session engine stops at a checkpoint, journaled
        assert [r[-1] for r in _journal(session)].count("done") == 2
        RE(brdf_sweep(devices, finished["plan"], session))  # the same folder: the rest only
    assert [d["exit_status"] for n, d in docs if n == "stop"] == ["success", "success"]
    assert [d["frames"]["to_shoot"] for n, d in docs if n == "start"] == [6, 4]
    assert sum(n == "event" for n, _ in docs) == 6
    assert _journal(session) == _journal(finished["session"])


def test_a_pause_mid_move_stops_the_arms_and_the_resumed_run_finishes(
    RE: RunEngine, finished: dict[str, Path], tmp_path: Path,  # noqa: N803
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Pausing at once during a move stops the arms (stop(success=True): the move's status
    completes); on resume the RunEngine replays the move and the session engine, stopped by it,
    starts again from the journal."""
    from simulators.clock import SteppedClock

    stepped = SteppedClock.sleep
    docs = _collect(RE)
    seen: list[Msg] = []
    polled: list[bool] = []
    session = tmp_path / "s"
    opened: list[GonioDevices] = []

    def held_sleep(clock: SteppedClock, seconds: float) -> None:
        """Hold the arms mid-move until the pause lands (however loaded the host)."""
        time.sleep(0.01)
        sweep = opened[0].link.sweep if opened else None
        if len(polled) == 1 and sweep is not None and sweep.moving:
            deadline = time.monotonic() + 60.0
            while RE.state == "running" and time.monotonic() < deadline:
                time.sleep(0.005)
        stepped(clock, seconds)

    monkeypatch.setattr(SteppedClock, "sleep", held_sleep)  # before the rig takes clock.sleep
    with open_rig_devices(RIG, material=TINY_MATERIAL, seed=SEED) as devices:
        opened.append(devices)

        async def until_moving() -> None:  # once, not again when the RunEngine replays it
            polled.append(True)
            for _ in range(3000 if len(polled) == 1 else 0):
                if devices.link.sweep is not None and devices.link.sweep.moving:
                    await asyncio.sleep(0.1)  # the goals are out, the arms on their way
                    return
                await asyncio.sleep(0.001)

        def pause_mid_move(msg: Msg) -> tuple[Any, Any]:
            if msg.command == "set" and msg.obj.name == "pose":
                seen.append(msg)
                if len(seen) == 6:  # the longest move: back to the white reference
                    return None, bpp.pchain(bps.wait_for([until_moving]), bps.pause())
            return None, None

        with pytest.raises(RunEngineInterrupted):
            RE(bpp.plan_mutator(brdf_sweep(devices, finished["plan"], session), pause_mid_move))
        RE.resume()
    assert [d["exit_status"] for n, d in docs if n == "stop"] == ["success"]
    assert sum(n == "event" for n, _ in docs) == 6
    assert [row[-1] for row in _journal(session)] == ["done"] * 6
    db = sqlite3.connect(f"{(session / 'journal.sqlite').as_uri()}?mode=ro", uri=True)
    events = [m for (m,) in db.execute("SELECT message FROM events")]
    db.close()
    assert any("was stopped" in m for m in events), events  # the pause did stop a move


def _positions(devices: GonioDevices) -> dict[str, float]:
    return devices.link.worker.put(Job(devices.link.servo.motion.positions_deg)).result()


def test_a_refused_set_fails_with_gonios_line_and_moves_nothing(
    RE: RunEngine, tmp_path: Path,  # noqa: N803
) -> None:
    with open_rig_devices(RIG, material=TINY_MATERIAL, seed=SEED, frames_dir=tmp_path) as devices:
        before = _positions(devices)
        servo = devices.link.servo
        with pytest.raises(GonioError) as refusal:  # the light arm would sweep through the camera's
            servo.planner.check_move(before, {"light_theta": 60.0})
        with pytest.raises(FailedStatus) as failed:
            RE(bps.mv(devices.axes["light_theta"], 60.0))
        assert str(failed.value.__cause__) == str(refusal.value)
        assert "\n" not in str(refusal.value)
        with pytest.raises(FailedStatus) as unreachable:  # θi = θr = 0: inside the shadow cone
            RE(bps.mv(devices.pose, (0.0, 0.0, 0.0)))
        assert isinstance(unreachable.value.__cause__, GonioError)
        assert _positions(devices) == before and servo.collisions() == []
        # a single axis moves alone; the camera outside a sweep writes into frames_dir
        RE(bps.mv(devices.axes["camera_phi"], 20.0))
        moved = _positions(devices)
        assert moved["camera_phi"] == pytest.approx(20.0, abs=0.1)
        assert {k: moved[k] for k in ("light_theta", "camera_theta")} == \
            {k: before[k] for k in ("light_theta", "camera_theta")}
        readings: dict[str, Any] = {}
        RE(bpp.run_wrapper(bps.trigger_and_read([devices.camera])),
           lambda name, doc: readings.update(doc["data"]) if name == "event" else None)
    frame = Path(readings["camera-frame"])
    assert frame == tmp_path / "frame-000001.dng" and frame.is_file()
    assert readings["camera-frame_exposure_s"] == pytest.approx(0.01)
    assert readings["camera-frame_iso"] == 100


def test_the_light_stage_leds_are_one_device(RE: RunEngine, tmp_path: Path) -> None:  # noqa: N803
    with open_rig_devices(LIGHTSTAGE_RIG, material=TINY_MATERIAL, frames_dir=tmp_path) as devices:
        assert devices.leds is not None and devices.pose is None
        levels = np.zeros(len(devices.link.devices.stage))  # type: ignore[union-attr]
        levels[[3, 10]] = [1.0, 0.5]
        RE(bps.mv(devices.leds, levels))
        data: dict[str, Any] = {}
        RE(bpp.run_wrapper(bps.trigger_and_read([devices.camera, devices.leds])),
           lambda name, doc: data.update(doc["data"]) if name == "event" else None)
        with pytest.raises(FailedStatus):
            RE(bps.mv(devices.leds, levels[:5]))
    np.testing.assert_array_equal(data["leds"], levels)
    assert Path(data["camera-frame"]).is_file()
