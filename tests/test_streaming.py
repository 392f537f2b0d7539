"""Streaming reduction: frames reduced while the capture runs give `gonio reduce`'s table,
bit for bit — in the capture's worker, in `gonio reduce --follow` beside a capture in another
process, and after a SIGKILL and `gonio resume`."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import threading
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
from conftest import grid_plan_text

from acquisition import api
from acquisition.reduction.checkpoint import checkpoint_path
from acquisition.session.runlock import capture_lock, capture_running
from acquisition.tables.partial import load_partial
from drivers.errors import SessionError

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
GONIO = Path(sys.executable).with_name("gonio")
POINT_PLAN = grid_plan_text((0, 60, 30), (30, 60, 30), (90, 180, 90), reference_every=4)
POINT_MATERIAL = "ggx:albedo=0.3,alpha=0.25,f0=0.04"
SPHERE_RIG = EXAMPLES / "rig-sphere-sim.toml"
SPHERE_PLAN = """format_version = 1
name = "sphere-stream"
[sampling]
kind = "list"
reciprocal = "both"
bin_deg = 5
poses = [[15, 45, 180], [30, 45, 180], [45, 45, 180], [60, 45, 180], [75, 45, 180],
         [30, 45, 0], [60, 45, 0]]
[capture]
reference_every = 2
"""
SPHERE_MATERIAL = "ggx:albedo=0.3,alpha=0.2,f0=0.04"


def table_arrays(path: Path) -> dict[str, np.ndarray]:
    """Every dataset of a table file (the provenance, with its times, left aside)."""
    out: dict[str, np.ndarray] = {}
    with h5py.File(path, "r") as f:
        f.visititems(lambda name, obj: out.__setitem__(name, obj[()])
                     if isinstance(obj, h5py.Dataset) else None)
    return out


def assert_same_tables(a: Path, b: Path) -> None:
    ta, tb = table_arrays(a), table_arrays(b)
    assert ta.keys() == tb.keys() and len(ta) >= 4
    for name in ta:
        assert np.array_equal(ta[name], tb[name], equal_nan=True), name


def _plan(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "plan.toml"
    path.write_text(text)
    return path


def _done(session: Path) -> int:
    try:
        db = sqlite3.connect(f"{(session / 'journal.sqlite').as_uri()}?mode=ro", uri=True,
                             timeout=0.5)
        try:
            return int(db.execute("SELECT COUNT(*) FROM steps WHERE status = 'done'").fetchone()[0])
        finally:
            db.close()
    except sqlite3.Error:
        return -1


def test_a_streamed_point_capture_ends_with_the_reduced_table(tmp_path: Path) -> None:
    plan = _plan(tmp_path, POINT_PLAN)
    streamed = api.capture(EXAMPLES / "rig-sim.toml", plan, tmp_path / "s",
                           material=POINT_MATERIAL, seed=5, reduce=True)
    plain = api.capture(EXAMPLES / "rig-sim.toml", plan, tmp_path / "p",
                        material=POINT_MATERIAL, seed=5)
    assert streamed.streamed is not None and streamed.streamed["pending"] == 0
    assert streamed.streamed["table"] == str(tmp_path / "s" / "brdf.h5")
    again = api.reduce(tmp_path / "s", tmp_path / "again.h5")
    assert streamed.streamed["frames"] == again.frames  # sample frames, as reduce counts them
    assert streamed.device_seconds == plain.device_seconds  # the worker delays no move
    assert not (tmp_path / "p" / "brdf.h5").exists()
    assert_same_tables(tmp_path / "s" / "brdf.h5", tmp_path / "again.h5")
    status = api.session_status(tmp_path / "s", drift=False, verify=False)
    assert status.tables == ["brdf.h5"] and not status.capturing
    assert f"table     {tmp_path / 's' / 'brdf.h5'} (reduced)" in status.lines()
    # resuming a complete session keeps its table (it may have been reduced with a
    # calibration since); one without a table gets it
    table = (tmp_path / "s" / "brdf.h5").read_bytes()
    assert api.resume(tmp_path / "s", reduce=True).streamed is None
    assert (tmp_path / "s" / "brdf.h5").read_bytes() == table
    assert api.resume(tmp_path / "p", reduce=True).streamed["pending"] == 0  # type: ignore[index]
    assert_same_tables(tmp_path / "p" / "brdf.h5", tmp_path / "again.h5")


def test_image_frames_are_binned_during_the_capture_into_the_reduced_table(tmp_path: Path) -> None:
    """A follower beside the capture bins frames once the references around them are in;
    the table equals `gonio reduce`'s."""
    plan = _plan(tmp_path, SPHERE_PLAN)
    session = tmp_path / "s"
    seen: list[tuple[int, bool]] = []
    live: list[tuple[dict, dict]] = []  # (the live table's "live" provenance, gonio info's json)
    result: dict[str, api.FollowResult] = {}
    live_path = tmp_path / "streamed.live.h5"

    class HoldForTheLiveTable(api.Observer):
        """Mid-capture (host time only: the rig's clock stands still), wait for the live
        table, read it and `gonio info`."""

        def step(self, event: object) -> None:
            if live or _done(session) < 8:
                return
            deadline = time.monotonic() + 60
            while not live_path.exists() and time.monotonic() < deadline:
                time.sleep(0.01)
            live.append((api.open_table(live_path).provenance["live"],
                         api.session_status(session, drift=False, verify=False).to_json()))

    def progress(done: int, rows: int) -> None:
        seen.append((done, capture_running(session)))

    def follower() -> None:
        while _done(session) < 1:
            time.sleep(0.01)
        result["r"] = api.follow_session(session, tmp_path / "streamed.h5", checkpoint_every=1,
                                         poll_s=0.05, snapshot_s=0.0, progress=progress)

    thread = threading.Thread(target=follower)
    thread.start()
    api.capture(SPHERE_RIG, plan, session, material=SPHERE_MATERIAL, seed=2,
                observers=[HoldForTheLiveTable()])
    thread.join(timeout=300)
    res = result["r"]
    assert res.pending == 0 and res.table == tmp_path / "streamed.h5" and res.frames == 7
    assert any(done > 0 and running for done, running in seen), seen  # binned mid-capture
    assert not checkpoint_path(res.table).exists() and not live_path.exists()
    # The table of the frames so far could be read mid-capture, and gonio info said so.
    assert live and all(0 < p["frames_reduced"] < 7 for p, _ in live), live
    assert live[0][1]["capturing"] and live[0][1]["counts"].get("done") < 12, live
    api.reduce(session, tmp_path / "batch.h5")
    assert_same_tables(tmp_path / "streamed.h5", tmp_path / "batch.h5")


def test_reduce_follow_follows_a_capture_in_another_process(tmp_path: Path) -> None:
    plan = _plan(tmp_path, POINT_PLAN)
    session = tmp_path / "s"
    capture = subprocess.Popen(
        [str(GONIO), "capture", "--rig", str(EXAMPLES / "rig-sim.toml"), "--plan", str(plan),
         "--out", str(session), "--material", POINT_MATERIAL, "--seed", "3", "--no-reduce"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    while _done(session) < 2 and time.monotonic() < deadline:
        time.sleep(0.01)
    follow = subprocess.run([str(GONIO), "reduce", "--follow", str(session), "--json"],
                            capture_output=True, text=True, timeout=300)
    assert capture.wait(timeout=300) == 0, capture.stderr.read().decode()  # type: ignore[union-attr]
    assert follow.returncode == 0, follow.stderr
    assert '"pending": 0' in follow.stdout
    subprocess.run([str(GONIO), "reduce", str(session), "-o", str(tmp_path / "batch.h5")],
                   check=True, capture_output=True, timeout=300)
    assert_same_tables(session / "brdf.h5", tmp_path / "batch.h5")


@pytest.fixture(scope="module")
def whole_sphere(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An uninterrupted streaming capture of the sphere plan: its table."""
    folder = tmp_path_factory.mktemp("whole")
    plan = _plan(folder, SPHERE_PLAN)
    api.capture(SPHERE_RIG, plan, folder / "s", material=SPHERE_MATERIAL, seed=4, reduce=True)
    return folder / "s" / "brdf.h5"


@pytest.mark.parametrize("how", ["SIGKILL", "Ctrl-C"])
def test_a_streaming_capture_stopped_then_resumed_gives_the_uninterrupted_table(
        how: str, whole_sphere: Path, tmp_path: Path) -> None:
    """SIGKILL of the capture alone (its worker, orphaned, keeps its frames), or Ctrl-C at the
    terminal (SIGINT to the whole process group: the worker leaves it to the capture)."""
    plan = _plan(tmp_path, SPHERE_PLAN)
    session = tmp_path / "s"
    proc = subprocess.Popen(
        [str(GONIO), "capture", "--rig", str(SPHERE_RIG), "--plan", str(plan), "--out",
         str(session), "--material", SPHERE_MATERIAL, "--seed", "4"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)
    deadline = time.monotonic() + 120
    while _done(session) < 6 and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.005)
    if how == "SIGKILL":
        proc.send_signal(signal.SIGKILL)
        assert proc.wait(timeout=30) == -signal.SIGKILL, "the capture ended before the kill"
    else:
        os.killpg(proc.pid, signal.SIGINT)
        err = proc.communicate(timeout=60)[1].decode()
        assert proc.returncode != 0 and _done(session) < 12, err  # stopped mid-run
    checkpoint = checkpoint_path(session / "brdf.h5")  # the worker keeps its frames
    while not checkpoint.exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    kept = load_partial(checkpoint).steps
    assert kept and not (session / "brdf.h5").exists()
    result = api.resume(session, reduce=True)  # its worker waits for an orphaned one
    assert result.streamed is not None and result.streamed["pending"] == 0, result.streamed
    assert result.streamed["resumed"] == len(kept) and result.streamed["frames"] == 7
    assert not checkpoint.exists()
    assert_same_tables(session / "brdf.h5", whole_sphere)


def test_a_second_capture_of_a_running_session_is_refused(tmp_path: Path) -> None:
    plan = _plan(tmp_path, POINT_PLAN)
    session = tmp_path / "s"
    api.capture(EXAMPLES / "rig-sim.toml", plan, session, material=POINT_MATERIAL, seed=1)
    assert not capture_running(session)
    with capture_lock(session):
        assert capture_running(session)
        with pytest.raises(SessionError, match="being captured by another gonio process"):
            api.resume(session)
    assert not capture_running(session)


def test_follow_takes_one_session_here(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from acquisition.cli import main

    assert main(["reduce", "--follow", str(tmp_path / "a"), str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err
    assert "--follow reduces one session on this host" in err and err.count("\n") == 1


def test_a_script_without_a_main_guard_streams(tmp_path: Path) -> None:
    """The worker is a fresh interpreter that imports nothing of the capturing script (a
    spawned multiprocessing child would run the script's top level again), and it has ended
    when the capture returns."""
    script = tmp_path / "capture.py"
    script.write_text(
        "from acquisition import api\n"
        f"r = api.capture({str(EXAMPLES / 'rig-sim.toml')!r}, {str(_plan(tmp_path, POINT_PLAN))!r},"
        f" {str(tmp_path / 's')!r}, material={POINT_MATERIAL!r}, reduce=True)\n"
        "print('STREAMED', r.streamed['pending'], r.streamed['table'])\n")
    done = subprocess.run([sys.executable, "-W", "always::ResourceWarning", str(script)],
                          capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert done.stderr == ""  # e.g. no "subprocess … is still running": the worker was reaped
    assert done.stdout.count("STREAMED") == 1 and "STREAMED 0 " in done.stdout
    assert (tmp_path / "s" / "brdf.h5").is_file()


def test_the_streaming_worker_loads_no_capture_stack() -> None:
    """The worker process beside a capture (WORKER_CODE, then follow_session's imports) loads
    the reduction only: not the capture, rig devices, servo simulators or scipy.optimize,
    whose import is CPU (~1 s here) taken from the capture it runs beside."""
    code = ("import sys; from acquisition.api.streaming import follow_session\n"
            "try:\n    follow_session('/nonexistent/session')\nexcept Exception:\n    pass\n"
            "import acquisition.lightstage.reduce\n"
            "stack = {'acquisition.api.sessions', 'acquisition.devices.rig', "
            "'acquisition.lightstage.capture', 'simulators.dynamixel', 'scipy.optimize'}\n"
            "print(sorted(stack & set(sys.modules)))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip().splitlines()[-1] == "[]"
