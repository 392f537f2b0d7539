"""DMX widget driver, simulated widget and light controller, over real pseudo-terminals."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest
import serial
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.dmx import (
    DmxWidget,
    FrameReader,
    WidgetParameters,
    decode_frame,
    decode_serial_number,
    encode_dmx_packet,
    encode_frame,
    frame_time_s,
)
from drivers.errors import CommunicationError, ConfigError, LimitError
from drivers.lights import (
    DutyCycleLimit,
    DutyPolicy,
    Fixture,
    LightController,
    fixture_from_config,
    pack_fixtures,
)
from simulators.dmx import ERROR_KINDS, SimDmxWidget, serve_dmx_forever


class StepClock:
    """A clock that only moves when someone sleeps, after every simulator has parsed its input.

    Shared by driver and simulators, it makes timestamps exact: the simulator stamps a frame
    with the time the driver wrote it, whatever the host's scheduling does.
    """

    def __init__(self) -> None:
        self.t = 0.0
        self.sims: list[SimDmxWidget] = []

    def now(self) -> float:
        return self.t

    def sleep(self, seconds: float) -> None:
        for sim in self.sims:
            assert sim.sim_wait_idle(), "simulator did not parse its input within 2 s"
        self.t += max(seconds, 0.0)


@pytest.fixture
def sim() -> Iterator[SimDmxWidget]:
    with SimDmxWidget() as s:
        yield s


@pytest.fixture
def stepped() -> Iterator[tuple[StepClock, SimDmxWidget]]:
    clock = StepClock()
    with SimDmxWidget(clock=clock) as s:  # type: ignore[arg-type]
        clock.sims.append(s)
        yield clock, s


def _sync(sim: SimDmxWidget) -> None:
    assert sim.sim_wait_idle(), "simulator did not parse its input within 2 s"


# -- frame codec --------------------------------------------------------------------------------


def test_encode_frame_vectors() -> None:
    assert encode_frame(3, b"\x00\x00") == bytes.fromhex("7e03020000" "00e7")
    assert encode_frame(10) == bytes.fromhex("7e0a0000e7")
    packet = encode_dmx_packet([255, 0, 128])  # padded to the widget's 24-channel minimum
    assert packet[:4] == bytes.fromhex("7e061900")  # label 6, length 25 = start code + 24
    assert packet[4:8] == bytes.fromhex("00ff0080") and packet[8:-1] == bytes(21)
    assert packet[-1] == 0xE7
    full = encode_dmx_packet(bytes(range(256)) * 2)
    assert full[2:4] == bytes.fromhex("0102") and len(full) == 513 + 5  # 513 = 0x0201, LSB first


def test_encode_rejects_bad_levels() -> None:
    with pytest.raises(ValueError, match="512"):
        encode_dmx_packet(bytes(513))
    with pytest.raises(ValueError, match="0–255"):
        encode_dmx_packet([0, 256])
    with pytest.raises(ValueError, match="integers"):
        encode_dmx_packet(np.array([0.5, 1.0]))
    with pytest.raises(ValueError, match="600"):
        encode_frame(6, bytes(601))


def test_decode_frame_is_strict() -> None:
    assert decode_frame(bytes.fromhex("7e0305004401090128e7")) == (3, bytes.fromhex("4401090128"))
    with pytest.raises(ValueError, match="0xE7"):
        decode_frame(bytes.fromhex("7e0a0000e6"))
    with pytest.raises(ValueError, match="length"):
        decode_frame(bytes.fromhex("7e0a0100e7"))
    with pytest.raises(ValueError, match="0x7E"):
        decode_frame(bytes.fromhex("7f0a0000e7"))


@settings(max_examples=60, deadline=None)
@given(
    frames=st.lists(
        st.tuples(st.integers(0, 255), st.binary(max_size=600)), min_size=1, max_size=4
    ),
    junk=st.binary(max_size=8).filter(lambda b: 0x7E not in b),
    chunk=st.integers(1, 64),
)
def test_frame_reader_round_trip(frames: list[tuple[int, bytes]], junk: bytes, chunk: int) -> None:
    stream = junk + b"".join(encode_frame(label, data) for label, data in frames)
    reader = FrameReader()
    got = []
    for i in range(0, len(stream), chunk):
        got += reader.feed(stream[i : i + chunk])
    assert got == frames
    assert all(decode_frame(encode_frame(label, data)) == (label, data) for label, data in frames)


def test_parameters_and_serial_number_vectors() -> None:
    p = WidgetParameters.from_reply(bytes([0x44, 0x01, 9, 1, 40, 0xAA]))
    assert (p.firmware_version, p.break_units, p.mab_units, p.refresh_rate_hz) == (0x0144, 9, 1, 40)
    assert p.user_config == b"\xaa"
    assert p.break_s == pytest.approx(96.03e-6) and p.mab_s == pytest.approx(10.67e-6)
    assert WidgetParameters.from_reply(p.to_reply()) == p
    with pytest.raises(ValueError, match="≥ 5"):
        WidgetParameters.from_reply(b"\x01\x02")
    assert decode_serial_number(bytes([0x78, 0x56, 0x34, 0x12])) == "12345678"
    with pytest.raises(ValueError, match="BCD"):
        decode_serial_number(bytes([0x7A, 0, 0, 0]))


def test_dmx_frame_time_arithmetic() -> None:
    # 250 kbaud, 11 bits/slot = 44 µs; full universe: break 96 µs + MAB 10.7 µs + 513 slots
    assert frame_time_s(512) == pytest.approx(22.68e-3, abs=0.01e-3)
    assert frame_time_s(10) == frame_time_s(24)  # the widget pads to 24 channels
    assert frame_time_s(512, break_units=20) - frame_time_s(512) == pytest.approx(11 * 10.67e-6)


# -- simulator strictness -----------------------------------------------------------------------

GOOD = encode_dmx_packet(bytes([10, 20, 30]) + bytes(21))
MALFORMED = {
    "end_byte": GOOD[:-1] + b"\x00",
    "length": encode_frame(6, bytes(11)),  # a DMX packet needs 25–513 bytes
    "length_over_600": bytes.fromhex("7e06ffff") + b"\x01\x02\x03",
    "label": encode_frame(0x63, b"\x01"),
    "start_byte": b"\x00\x01\x02",
    "start_code": encode_frame(6, b"\xcc" + bytes(range(1, 25))),
}


@pytest.mark.parametrize("case", sorted(MALFORMED))
def test_simulator_counts_and_ignores_malformed_frames(sim: SimDmxWidget, case: str) -> None:
    kind = case.removesuffix("_over_600")
    assert kind in ERROR_KINDS
    with serial.Serial(sim.path, timeout=0.5) as port:
        port.write(GOOD)
        _sync(sim)
        held = sim.sim_universe()
        assert held == bytes([10, 20, 30]) + bytes(21)
        port.write(MALFORMED[case])
        _sync(sim)
        assert sim.sim_universe() == held  # ignored, like a real widget
        errors = sim.sim_errors()
        assert errors[kind] == 1 and sum(errors.values()) == 1, errors
        # the parser resynchronises: the next good frame is taken
        port.write(encode_dmx_packet(bytes([7] * 24)))
        _sync(sim)
        assert sim.sim_universe() == bytes([7] * 24)
        assert sum(sim.sim_errors().values()) == 1


def test_simulator_reassembles_frames_split_across_writes(sim: SimDmxWidget) -> None:
    frame = encode_dmx_packet(bytes(range(200)))
    with serial.Serial(sim.path) as port:
        for i in range(0, len(frame), 37):
            port.write(frame[i : i + 37])
            port.flush()
        _sync(sim)
    assert sim.sim_universe() == bytes(range(200))
    assert sim.sim_errors() == dict.fromkeys(ERROR_KINDS, 0)


# -- driver ↔ simulator -------------------------------------------------------------------------


def test_driver_reads_parameters_and_serial_from_simulator() -> None:
    with (
        SimDmxWidget(serial_number=87654321, firmware=0x0150, break_units=20, refresh_rate_hz=30)
        as sim,
        DmxWidget(sim.path) as widget,  # type: ignore[arg-type]
    ):
        p = widget.parameters  # read on open
        assert (p.firmware_version, p.break_units, p.mab_units, p.refresh_rate_hz) == (
            0x0150,
            20,
            1,
            30,
        )
        assert widget.get_parameters(user_config_size=3).user_config == bytes(3)
        assert widget.get_serial_number() == "87654321"
        assert widget.frame_period_s() == pytest.approx(1 / 30)  # rate-limited, not wire-limited
        assert sim.sim_received() == {3: 2, 10: 1}


def test_simulator_holds_exactly_the_bytes_sent(sim: SimDmxWidget) -> None:
    rng = np.random.default_rng(7)
    levels = rng.integers(0, 256, 512, dtype=np.uint8)
    with DmxWidget(sim.path) as widget:
        widget.send_universe(levels)
        _sync(sim)
        assert sim.sim_universe() == levels.tobytes()
        widget.send_universe([1, 2, 3])
        _sync(sim)
        assert sim.sim_universe() == bytes([1, 2, 3]) + bytes(21)
    assert sim.sim_errors() == dict.fromkeys(ERROR_KINDS, 0)


def test_driver_works_through_a_spy_url(sim: SimDmxWidget, tmp_path) -> None:
    log = tmp_path / "traffic.txt"
    with DmxWidget(f"spy://{sim.path}?file={log}") as widget:
        widget.send_universe(bytes([5] * 30))
        _sync(sim)
    assert sim.sim_universe() == bytes([5] * 30)
    assert "7E 06 1F 00 00 05" in log.read_text()


def test_refresh_limit_spaces_sends_by_one_output_period(stepped) -> None:
    clock, sim = stepped
    with DmxWidget(sim.path, clock=clock) as widget:
        period = widget.frame_period_s(512)
        assert period == pytest.approx(1 / 40)  # the widget outputs 40 frames/s
        sent = [widget.send_universe(bytes([i]) * 512) for i in range(6)]
        _sync(sim)
    history = sim.sim_history()
    received = np.array([h.received_s for h in history])
    assert received.tolist() == sent
    assert np.all(np.diff(received) >= period - 1e-12)
    assert not any(h.dropped for h in history)  # every state went out on the wire
    # an exposure inside one state's settled span sees one state; one straddling sees two
    h1, h2 = history[1], history[2]
    assert sim.sim_states_during(h1.active_s, h2.active_s - 1e-6) == [h1.levels]
    assert sim.sim_states_during(h1.active_s, h2.active_s) == [h1.levels, h2.levels]
    # the driver's readiness bound covers the simulated output latency, and is not slack
    for h in history:
        ready = widget.ready_at(h.received_s, 512)
        assert h.active_s <= ready < h.active_s + period + 3e-3
    # control: the same frames written without the driver's pacing arrive together, and all
    # but the last are overwritten before the widget outputs them
    with serial.Serial(sim.path) as port:
        port.write(b"".join(encode_dmx_packet(bytes([i]) * 512) for i in range(6)))
        _sync(sim)
    raw = sim.sim_history()[6:]
    assert len(raw) == 6 and np.ptp([h.received_s for h in raw]) == 0.0
    assert [h.dropped for h in raw] == [True] * 5 + [False]


def test_refresh_limit_measured_on_host_time(sim: SimDmxWidget) -> None:
    # same property on the wall clock, with generous bounds (pacing is ≥ 25 ms per frame)
    with DmxWidget(sim.path) as widget:
        period = widget.frame_period_s(512)
        for i in range(6):
            widget.send_universe(bytes([i]) * 512)
        _sync(sim)
    received = np.array([h.received_s for h in sim.sim_history()])
    assert received[-1] - received[0] >= 0.6 * 5 * period


# -- failures -----------------------------------------------------------------------------------


def test_missing_port_is_a_one_line_communication_error(tmp_path) -> None:
    with pytest.raises(CommunicationError, match="cannot open DMX widget port") as err:
        DmxWidget(str(tmp_path / "ttyUSB9"))
    assert "\n" not in str(err.value) and "ttyUSB9" in str(err.value)


def test_second_client_cannot_take_an_open_widget(sim: SimDmxWidget) -> None:
    with DmxWidget(sim.path), pytest.raises(CommunicationError, match="no other program"):
        DmxWidget(sim.path)


def test_silent_device_is_reported_and_port_released() -> None:
    master, slave = os.openpty()  # a pty nobody answers on
    try:
        path = os.ttyname(slave)
        with pytest.raises(CommunicationError, match="no reply to Get Widget Parameters"):
            DmxWidget(path, timeout_s=0.05)
        with serial.Serial(path, exclusive=True):  # nothing left holding the port
            pass
    finally:
        os.close(master)
        os.close(slave)


def test_unplug_mid_sequence_raises_communication_error(sim: SimDmxWidget) -> None:
    path = sim.path
    fixtures = pack_fixtures(np.tile([0.0, 0.0, 1.0], (8, 1)))
    with (
        pytest.raises(CommunicationError) as err,
        LightController.open({1: path}, fixtures) as lights,  # type: ignore[dict-item]
    ):
        for i in range(8):
            if i == 3:
                sim.sim_unplug()
            lights.olat(i)
    message = str(err.value)
    assert path in message and "USB cable" in message and "\n" not in message
    assert sim.sim_history()[-1].levels[:3] == bytes([0, 0, 255])  # olat(2) was the last
    assert not os.path.exists(path)


def test_serve_dmx_forever_prints_path_first_and_stops_on_sigterm() -> None:
    code = ("import sys; from simulators.dmx import serve_dmx_forever as s; "
            "raise SystemExit(s(out=sys.stdout, err=sys.stderr))")
    proc = subprocess.Popen(
        [sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        path = proc.stdout.readline().strip()  # type: ignore[union-attr]
        assert path.startswith("/dev/")
        with DmxWidget(path) as widget:
            assert widget.get_serial_number() == "12345678"
            widget.send_universe(bytes([1, 2]))
            widget.get_parameters()  # the reply proves the universe before it was parsed
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=10)
    finally:
        proc.kill()
    assert proc.returncode == 0
    assert "4 frames received" in err and "malformed/ignored: none" in err


def test_serve_dmx_forever_in_process(capsys) -> None:
    main = threading.main_thread().ident
    assert main is not None

    def fire() -> None:
        time.sleep(0.05)
        signal.pthread_kill(main, signal.SIGINT)  # to the main thread, which sigwaits for it

    threading.Thread(target=fire).start()
    assert serve_dmx_forever(out=sys.stdout, err=sys.stderr) == 0
    out = capsys.readouterr()
    assert out.out.splitlines()[0].startswith("/dev/")


# -- fixtures and the light controller ----------------------------------------------------------


def test_fixture_channel_maps_to_dmx_values() -> None:
    rgbi = Fixture(
        "A", 1, 10, {"intensity": 0, "r": 1, "g": 2, "b": 3, "mode": 4}, (0, 0, 2), {"mode": 200}
    )
    assert rgbi.direction == (0.0, 0.0, 1.0)
    assert rgbi.dmx_values(0.5) == {10: 128, 11: 255, 12: 255, 13: 255, 14: 200}
    assert rgbi.dmx_values((1.0, 0.5, 0.0)) == {10: 255, 11: 255, 12: 128, 13: 0, 14: 200}
    assert rgbi.dmx_values(0.0) == {10: 0, 11: 0, 12: 0, 13: 0, 14: 200}
    mono = Fixture("B", 1, 1, {"intensity": 0}, (1, 0, 1))
    assert mono.dmx_values(1.0) == {1: 255}
    with pytest.raises(ValueError, match="scalar"):
        mono.dmx_values((1.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="outside 0–1"):
        mono.dmx_values(1.5)


def test_fixture_config_errors_name_the_field() -> None:
    good = {
        "name": "L0",
        "universe": 1,
        "start_channel": 1,
        "channels": {"intensity": 0},
        "direction": [0, 0, 1],
    }
    assert fixture_from_config(good).addresses == {"intensity": 1}
    with pytest.raises(ConfigError, match=r"lights\[2\] lacks direction"):
        fixture_from_config({k: v for k, v in good.items() if k != "direction"}, "lights[2]")
    with pytest.raises(ConfigError, match="outside DMX 1–512"):
        fixture_from_config({**good, "start_channel": 511, "channels": {"r": 0, "g": 1, "b": 2}})
    with pytest.raises(ConfigError, match="non-zero 3-vector"):
        fixture_from_config({**good, "direction": [0, 0, 0]})
    a, b = Fixture("a", 1, 1, {"r": 0, "g": 1}, (0, 0, 1)), Fixture("b", 1, 2, {"i": 0}, (0, 0, 1))
    with pytest.raises(ConfigError, match="both use channel 2"):
        LightController({1: None}, [a, b])  # type: ignore[dict-item]
    with pytest.raises(ConfigError, match="universe 2, which has no widget"):
        LightController({1: None}, [Fixture("c", 2, 1, {"i": 0}, (0, 0, 1))])  # type: ignore[dict-item]


def test_pack_fixtures_fills_universes_without_straddling() -> None:
    dirs = np.tile([0.0, 0.0, 1.0], (156, 1))
    fixtures = pack_fixtures(dirs, channels={"intensity": 0, "r": 1, "g": 2, "b": 3, "x": 4})
    per_universe = 512 // 5
    assert [f.universe for f in fixtures].count(1) == per_universe
    assert {f.universe for f in fixtures} == {1, 2}
    assert all(max(f.addresses.values()) <= 512 for f in fixtures)
    assert fixtures[per_universe].start_channel == 1 and fixtures[-1].name == "L155"


def test_controller_over_two_universes(stepped) -> None:
    clock, sim1 = stepped
    with SimDmxWidget(clock=clock) as sim2:  # type: ignore[arg-type]
        clock.sims.append(sim2)
        fixtures = pack_fixtures(
            np.tile([0.0, 0.0, 1.0], (156, 1)), channels={"intensity": 0, "r": 1, "g": 2, "b": 3}
        )
        with LightController.open({1: sim1.path, 2: sim2.path}, fixtures, clock=clock) as lights:
            state = lights.olat(150, (1.0, 0.5, 0.0))
            _sync(sim2)
            assert state.lit == ("L150",)
            u2 = sim2.sim_universe()
            offset = (150 - 128) * 4  # 128 four-channel fixtures fill universe 1
            assert u2[offset : offset + 4] == bytes([255, 255, 128, 0])
            assert sum(u2) == 255 + 255 + 128 and not any(sim1.sim_universe())
            assert lights.universes() == {1: sim1.sim_universe(), 2: u2}
            # confirmation by timing: when set_state returns, the widget is outputting it
            assert clock.now() == state.ready_at_s
            assert sim2.sim_state_at(clock.now()) == u2
            assert sim2.sim_state_at(state.sent_at_s) != u2  # not on the instant it was sent
            assert lights.covers(state.ready_at_s, clock.now())
            assert not lights.covers(state.sent_at_s, clock.now())
            # only universes that change are sent
            lights.olat(151)
            assert sim1.sim_received().get(6) == 1 and sim2.sim_received().get(6) == 2
            lights.all_on(0.2)
            _sync(sim1)
            assert sim1.sim_universe()[:4] == bytes([51, 255, 255, 255])
        _sync(sim1)
        _sync(sim2)
        assert not any(sim1.sim_universe()) and not any(sim2.sim_universe())  # off on close


def test_controller_refuses_bad_commands(stepped) -> None:
    clock, sim = stepped
    fixtures = pack_fixtures(np.tile([0.0, 0.0, 1.0], (4, 1)))
    with LightController.open({1: sim.path}, fixtures, clock=clock) as lights:
        with pytest.raises(LimitError, match="index 4"):
            lights.olat(4)
        with pytest.raises(LimitError, match="outside 0–1"):
            lights.set_state({"L000": 2.0})
        with pytest.raises(ConfigError, match="no fixture named 'X'"):
            lights.set_state({"X": 1.0})
        _sync(sim)
        assert sim.sim_received().get(6) is None  # nothing was sent


def test_duty_cycle_limit_raises_then_waits(stepped) -> None:
    clock, sim = stepped
    fixtures = pack_fixtures(np.tile([0.0, 0.0, 1.0], (2, 1)))
    limit = DutyCycleLimit(max_on_fraction=0.5, window_s=2.0)
    with LightController.open({1: sim.path}, fixtures, clock=clock, duty_limit=limit) as lights:
        lights.olat(0, hold_s=0.6)
        clock.sleep(0.6)  # the exposure
        with pytest.raises(LimitError, match=r"light 'L000' was on .* wait \d+\.\d s"):
            lights.olat(0, hold_s=0.6)
        lights.olat(1, hold_s=0.6)  # another LED has its own budget
        with pytest.raises(LimitError, match="exceeds its duty budget"):
            lights.olat(1, hold_s=1.5)
    with LightController.open(
        {1: sim.path},
        fixtures,
        clock=clock,
        duty_limit=DutyCycleLimit(0.5, 2.0, DutyPolicy.WAIT),
    ) as lights:
        lights.olat(0, hold_s=0.6)
        clock.sleep(0.6)
        before = clock.now()
        state = lights.olat(0, hold_s=0.6)
        assert state.sent_at_s > before + 0.1  # it paused with the light off
        # at the end of the 0.6 s hold, the LED has been on ≤ 50 % of the last 2 s
        assert lights.duty_fraction("L000", state.sent_at_s + 0.6) <= 0.5 + 1e-6
        _sync(sim)
        history = sim.sim_history()
        assert history[-2].levels[0] == 0 and history[-1].levels[0] == 255
