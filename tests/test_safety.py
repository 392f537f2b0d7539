"""Safety on the simulated rig: faults on the wire, overload, Ctrl-C, temperature/voltage guards.

Everything runs the real stack: the CLI entry point or the Python API, the driver on
dynamixel_sdk, the servo simulator behind a pty, real DNG frames, the real journal.
"""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from acquisition import api
from acquisition.cli import main
from acquisition.config.rig import load_rig
from acquisition.devices.console import open_console
from acquisition.devices.health import HealthLimits, ServoHealthError
from acquisition.devices.rig import open_devices
from acquisition.planning.planner import Planner
from acquisition.session.folder import JOURNAL_FILE
from acquisition.session.interrupts import EXIT_INTERRUPTED, sigint_stops_motion
from acquisition.session.journal import Journal
from acquisition.tables import IsotropicTable
from drivers.errors import SafetyStop
from simulators.dynamixel import SimServoBus

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"

ROOT = Path(__file__).resolve().parent.parent
MATERIAL = "lambert:albedo=0.3"
SEED = 5

# 17 steps. With 1 s of settling per move the capture lasts > 25 s of rig time even on a fast
# host, so an overload due 20 s after the bus starts always trips in the middle of it.
PLAN = """
format_version = 1
name = "safety"
[sampling]
kind = "grid"
theta_i = { start = 0, stop = 60, step = 30 }
theta_r = { start = 0, stop = 60, step = 30 }
delta_phi = { start = 0, stop = 180, step = 45 }
"""


def rig_copy(folder: Path, **replace: str) -> Path:
    """The example simulated rig with some lines replaced (``settle_s``, ``time_scale``)."""
    text = (EXAMPLES / "rig-sim.toml").read_text()
    for old, new in replace.items():
        assert old in text
        text = text.replace(old, new)
    path = folder / "rig.toml"
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    folder = tmp_path_factory.mktemp("safety")
    rig = rig_copy(folder, **{"settle_s = 0.05": "settle_s = 1.0"})
    plan = folder / "plan.toml"
    plan.write_text(PLAN)
    return rig, plan


@pytest.fixture(scope="module")
def baseline(files: tuple[Path, Path], tmp_path_factory: pytest.TempPathFactory
             ) -> IsotropicTable:
    rig, plan = files
    out = tmp_path_factory.mktemp("baseline") / "s"
    api.capture(rig, plan, out, material=MATERIAL, seed=SEED)
    return api.reduce(out).table


def assert_same_table(session: Path, expected: IsotropicTable) -> None:
    table = api.reduce(session).table
    assert table.count.sum() > 0
    np.testing.assert_array_equal(table.count, expected.count)
    np.testing.assert_array_equal(table.mean, expected.mean)


def journal_counts(session: Path) -> dict[str, int]:
    with Journal(session / JOURNAL_FILE) as j:
        return j.counts()


def capture_args(files: tuple[Path, Path], out: Path, *faults: str) -> list[str]:
    rig, plan = files
    args = ["capture", "--rig", str(rig), "--plan", str(plan), "--out", str(out),
            "--material", MATERIAL, "--seed", str(SEED)]
    for f in faults:
        args += ["--sim-fault", f]
    return args


# ---------------------------------------------------------------------- faults on the wire
def test_lossy_bus_capture_gives_the_same_table(
    files: tuple[Path, Path], baseline: IsotropicTable, sims: list[SimServoBus], tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    out = tmp_path / "lossy"
    assert main(capture_args(files, out, "drop=0.05", "corrupt=0.05")) == 0
    assert "error" not in capsys.readouterr().err
    (bus,) = sims
    assert bus.stats["dropped"] > 5 and bus.stats["corrupted"] > 5  # the faults were real
    assert journal_counts(out) == {"done": 17}
    assert_same_table(out, baseline)


# ---------------------------------------------------------------------- overload
def test_overload_stops_names_axis_and_resume_completes(
    files: tuple[Path, Path], baseline: IsotropicTable, sims: list[SimServoBus], tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    out = tmp_path / "overload"
    code = main(capture_args(files, out, "overload:id=2,after=20"))
    err = capsys.readouterr().err
    assert code != 0
    errors = [line for line in err.splitlines() if line.startswith("gonio: error:")]
    assert len(errors) == 1 and err.strip().endswith(errors[0])
    assert "axis 'camera_theta'" in errors[0] and "overload" in errors[0]
    assert "gonio reboot camera_theta" in errors[0]
    # Every axis stands still: goal = present, nothing moving; only servo 2 lost torque.
    (bus,) = sims
    bus.clock.sleep(1.0)  # a stepped clock stands still after the run: let the brakes finish
    for sid, servo in bus.servos.items():
        _, raw = servo.read(64, 84)
        goal = int.from_bytes(raw[116 - 64:120 - 64], "little", signed=True)
        present = int.from_bytes(raw[132 - 64:136 - 64], "little", signed=True)
        assert abs(goal - present) <= 3 and raw[122 - 64] == 0, sid
        assert raw[0] == (0 if sid == 2 else 1)
    counts = journal_counts(out)
    assert 0 < counts.get("done", 0) < 17  # tripped in the middle, resumable

    assert main(["resume", str(out)]) == 0  # a fresh simulator, without the fault
    assert journal_counts(out) == {"done": 17}
    assert_same_table(out, baseline)


# ---------------------------------------------------------------------- Ctrl-C
def _frames(session: Path) -> int:
    return len(list((session / "frames").glob("step-*.dng")))


def test_ctrl_c_during_capture_leaves_it_resumable(
    files: tuple[Path, Path], baseline: IsotropicTable, tmp_path: Path,
    capfd: pytest.CaptureFixture[str],
) -> None:
    out = tmp_path / "sigint"
    pid = os.getpid()
    before = signal.getsignal(signal.SIGINT)  # SIG_IGN when run as a background job

    def press_ctrl_c() -> None:
        deadline = time.monotonic() + 30
        while _frames(out) < 4 if out.exists() else True:
            if time.monotonic() > deadline:
                return
            time.sleep(0.002)
        os.kill(pid, signal.SIGINT)

    presser = threading.Thread(target=press_ctrl_c)
    presser.start()
    code = main(capture_args(files, out))
    presser.join()
    err = capfd.readouterr().err  # the handler writes to file descriptor 2
    assert code == EXIT_INTERRUPTED
    assert "stopping all axes" in err and f"gonio resume {out}" in err
    assert 3 <= journal_counts(out).get("done", 0) < 17
    assert signal.getsignal(signal.SIGINT) is before  # restored

    assert main(["resume", str(out)]) == 0
    assert_same_table(out, baseline)


def test_ctrl_c_stops_a_console_move_midway(tmp_path: Path, sims: list[SimServoBus]) -> None:
    # Real time (a scaled clock), so that the presser thread can catch the move midway.
    rig = rig_copy(tmp_path, **{"time_scale = 25.0": 'time_scale = 1.0\nclock = "scaled"'})
    with open_console(rig) as con:
        (bus,) = sims
        servo = bus.servos[3]  # camera_phi
        pid = os.getpid()

        def press_when_moving() -> None:
            deadline = time.monotonic() + 10
            while time.monotonic() < deadline:
                if servo.read(122, 1)[1][0]:
                    time.sleep(0.2)
                    os.kill(pid, signal.SIGINT)
                    return
                time.sleep(0.001)

        presser = threading.Thread(target=press_when_moving)
        presser.start()
        with sigint_stops_motion() as state, pytest.raises(SafetyStop, match="all axes stopped"):
            con.move_joints({"camera_phi": 170.0})  # ≈ 1.1 s at 150 units
        presser.join()
        assert state.presses == 1
        # goal := present at speed: the servo brakes (overshooting by v²/2a) and returns to
        # where it was told to stop, torque on.
        deadline = time.monotonic() + 5
        while (phi := next(r for r in con.status() if r.axis == "camera_phi")).moving:
            assert time.monotonic() < deadline
            time.sleep(0.02)
        assert phi.torque_on and not phi.errors
        assert 5.0 < phi.goal_deg < 150.0  # stopped well short of 170°
        assert phi.position_deg == pytest.approx(phi.goal_deg, abs=0.3)


SECOND_PRESS = textwrap.dedent("""
    import sys, time
    from acquisition.session.interrupts import sigint_stops_motion
    with sigint_stops_motion():
        try:
            print("ready", flush=True)
            time.sleep(30)
        except KeyboardInterrupt:
            print("stopping", flush=True)
            time.sleep(30)  # a stop that hangs: the second Ctrl-C must not wait for it
    print("not reached", flush=True)
""")


def test_second_ctrl_c_exits_at_once() -> None:
    proc = subprocess.Popen([sys.executable, "-c", SECOND_PRESS], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "ready"
        proc.send_signal(signal.SIGINT)
        assert proc.stdout.readline().strip() == "stopping"
        t0 = time.monotonic()
        proc.send_signal(signal.SIGINT)
        code = proc.wait(timeout=10)
        assert time.monotonic() - t0 < 5
    finally:
        proc.kill()
        proc.wait()
    assert code == EXIT_INTERRUPTED
    err = proc.stderr.read()
    assert "press Ctrl-C again" in err and "second Ctrl-C: exiting now" in err
    assert "not reached" not in proc.stdout.read()


def test_sigint_handler_counts_and_restores() -> None:
    exits: list[int] = []
    lines: list[str] = []
    before = signal.getsignal(signal.SIGINT)
    with sigint_stops_motion(exit_now=exits.append, write=lines.append) as state:
        with pytest.raises(KeyboardInterrupt):
            signal.raise_signal(signal.SIGINT)
        signal.raise_signal(signal.SIGINT)
    assert state.presses == 2 and exits == [EXIT_INTERRUPTED] and len(lines) == 2
    assert signal.getsignal(signal.SIGINT) is before


# ---------------------------------------------------------------------- health guards
TARGET = {"light_theta": -30.0, "camera_theta": 45.0, "camera_phi": 0.0}


def open_sim(rig_path: Path, faults: list[str], limits: HealthLimits):
    rig = load_rig(rig_path)
    return open_devices(rig, Planner(rig), material=None, sim_faults=faults,
                        health_limits=limits)


def test_voltage_dip_pauses_until_back_in_range_with_hysteresis(
    caplog: pytest.LogCaptureFixture,
) -> None:
    # 9.8 V pauses (< 10.0); 10.1 V is not enough to resume (< 10.3); 12 V is.
    faults = ["voltage:id=1,volts=9.8", "voltage:id=1,volts=10.1,after=8",
              "voltage:id=1,volts=12,after=16"]
    with caplog.at_level(logging.WARNING, logger="acquisition.devices"), \
            open_sim(EXAMPLES / "rig-sim.toml", faults, HealthLimits(poll_s=1.0)) as dev:
        readback = dev.move_to(TARGET)
    (pause,) = dev.health.pauses
    assert pause.reasons == ("axis 'light_theta' (servo 1) supply 9.8 V (outside 10–14.8 V)",)
    assert 16.0 <= pause.end_s <= 19.0
    assert readback["light_theta"] == pytest.approx(-30.0, abs=0.1)
    text = caplog.text
    assert "pausing before the next move: axis 'light_theta'" in text
    assert "resuming after" in text


def test_voltage_inside_the_range_does_not_pause() -> None:
    with open_sim(EXAMPLES / "rig-sim.toml", ["voltage:id=1,volts=10.1"],
                  HealthLimits(poll_s=1.0)) as dev:
        dev.move_to(TARGET)
    assert dev.health.pauses == []


def test_hot_servo_pauses_until_it_cooled_below_the_resume_limit(tmp_path: Path) -> None:
    rig = rig_copy(tmp_path, **{"time_scale = 25.0": "time_scale = 200.0"})
    # Servo 2 heats towards 94 °C until t = 30 s, then cools towards 34 °C (tau 120 s).
    faults = ["overheat:id=2,heat=60", "overheat:id=2,after=30,heat=-60"]
    limits = HealthLimits(pause_at_c=40.0, resume_below_c=38.0, poll_s=2.0)
    with open_sim(rig, faults, limits) as dev:
        dev.clock.sleep(25.0 - dev.clock.now())
        readback = dev.move_to(TARGET)
        status = dev.health.read()
    (pause,) = dev.health.pauses
    assert "axis 'camera_theta' (servo 2) at 4" in pause.reasons[0]
    assert pause.end_s - pause.start_s > 100  # cooling takes ~150 s of rig time
    assert status["camera_theta"].temperature_c < 38
    assert all(s.hardware_error == 0 and s.torque_on for s in status.values())
    assert readback["light_theta"] == pytest.approx(-30.0, abs=0.1)


def test_guard_gives_up_with_a_typed_error_and_nothing_moves() -> None:
    limits = HealthLimits(poll_s=1.0, give_up_s=5.0)
    with open_sim(EXAMPLES / "rig-sim.toml", ["voltage:id=1,volts=9.8"], limits) as dev:
        before = dev.motion.positions_deg()
        with pytest.raises(ServoHealthError, match=r"paused \d+ s and still axis 'light_theta' "
                           r"\(servo 1\) supply 9.8 V.*gonio resume"):
            dev.move_to(TARGET)
        assert dev.motion.positions_deg() == before


def test_capture_paused_by_a_voltage_dip_gives_the_same_table(
    files: tuple[Path, Path], baseline: IsotropicTable, tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    out = tmp_path / "dip"
    code = main(capture_args(files, out, "voltage:id=1,volts=9.8",
                             "voltage:id=1,volts=12,after=6"))
    err = capsys.readouterr().err
    assert code == 0
    assert ("gonio: pausing before the next move: axis 'light_theta' (servo 1) supply 9.8 V"
            in err)
    assert "gonio: resuming after" in err
    assert_same_table(out, baseline)


def test_opening_a_rig_sets_return_delay_zero(rig_sim_path) -> None:
    """The low-latency setting: every servo answers with Return Delay Time 0 once opened."""
    from acquisition.config.rig import load_rig
    from acquisition.devices.servos import open_servos
    from acquisition.planning.planner import Planner
    from drivers.dynamixel.bus import Addr

    rig = load_rig(rig_sim_path)
    with open_servos(rig, Planner(rig)) as servos:
        bus = servos.buses["main"]
        delays = [bus.read(a.servo_id, Addr.RETURN_DELAY_TIME, 1, signed=False)
                  for a in rig.axes.values()]
    assert delays == [0, 0, 0]
