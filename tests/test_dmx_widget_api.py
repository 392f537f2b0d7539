"""The simulated DMX USB Pro against the whole widget API, driven by an independent client.

:class:`ProClient` is written here from the API 1.44 message table, like the small Enttec
clients of third-party libraries: it opens the pty with pyserial, sends Set Widget Parameters
(label 4) on open, then speaks raw frames. It shares no code with ``drivers.dmx``.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator

import numpy as np
import pytest
import serial

from drivers.dmx import DmxWidget
from simulators.dmx import ERROR_KINDS, SimDmxWidget

UNIT_S = 10.67e-6
SLOT_S = 44e-6


class ProClient:
    """Minimal Enttec DMX USB Pro client; sends label 4 with the given timing when it opens."""

    def __init__(self, path: str, *, break_units: int = 9, mab_units: int = 1, rate_hz: int = 40,
                 user_config: bytes = b"") -> None:
        self.port = serial.Serial(path, baudrate=57600, timeout=1.0)
        self.send(4, struct.pack("<HBBB", len(user_config), break_units, mab_units, rate_hz)
                  + user_config)

    def send(self, label: int, data: bytes = b"") -> None:
        self.port.write(struct.pack("<BBH", 0x7E, label, len(data)) + data + b"\xe7")

    def read_frame(self) -> tuple[int, bytes]:
        """The next frame from the widget; fails on a timeout or a malformed frame."""
        head = self.port.read(4)
        assert len(head) == 4 and head[0] == 0x7E, f"no frame from the widget (got {head!r})"
        label, n = head[1], head[2] | head[3] << 8
        body = self.port.read(n + 1)
        assert len(body) == n + 1 and body[-1] == 0xE7, f"truncated or malformed frame {body!r}"
        return label, body[:-1]

    def request(self, label: int, data: bytes = b"") -> tuple[bytes, list[tuple[int, bytes]]]:
        """Send a request; return its reply and every other frame that arrived before it."""
        self.send(label, data)
        before = []
        while (frame := self.read_frame())[0] != label:
            before.append(frame)
        return frame[1], before

    def parameters(self, user_size: int = 0) -> tuple[int, int, int, int, bytes]:
        """(firmware, break, MAB, rate, user config) from Get Widget Parameters (label 3)."""
        reply, before = self.request(3, struct.pack("<H", user_size))
        assert before == []
        fw, brk, mab, rate = struct.unpack_from("<HBBB", reply)
        return fw, brk, mab, rate, reply[5:]

    def nothing_pending(self) -> bool:
        """True if the widget sent nothing unasked: a label 3 reply comes first."""
        return self.request(3, b"\0\0")[1] == []

    def close(self) -> None:
        self.port.close()

    def __enter__(self) -> ProClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class StepClock:
    """Moves only on sleep, after every simulator parsed its input (exact timestamps)."""

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
def stepped() -> Iterator[tuple[StepClock, SimDmxWidget]]:
    clock = StepClock()
    with SimDmxWidget(clock=clock) as sim:  # type: ignore[arg-type]
        clock.sims.append(sim)
        yield clock, sim


def _frame_s(break_units: int, mab_units: int, n_channels: int) -> float:
    return (break_units + mab_units) * UNIT_S + (1 + max(24, n_channels)) * SLOT_S


def _decode_changes(frames: list[tuple[int, bytes]], array: bytearray) -> None:
    """Apply label-9 messages to a 513-byte received array (the API's algorithm)."""
    for label, data in frames:
        assert label == 9
        start, bits, changed = data[0], int.from_bytes(data[1:6], "little"), iter(data[6:])
        for i in range(40):
            if bits >> i & 1:
                array[start * 8 + i] = next(changed)
        assert next(changed, None) is None  # one byte per set bit


# -- label 4 on open, echoed by label 3 -----------------------------------------------------------


def test_set_parameters_on_open_are_echoed_by_get_parameters() -> None:
    with SimDmxWidget(firmware=0x0144) as sim, ProClient(
        sim.path, break_units=20, mab_units=5, rate_hz=25, user_config=b"gonio"  # type: ignore[arg-type]
    ) as client:
        assert client.parameters(user_size=8) == (0x0144, 20, 5, 25, b"gonio\0\0\0")
        serial_bcd, _ = client.request(10)
        assert serial_bcd == bytes([0x78, 0x56, 0x34, 0x12])  # 12345678, LSB first
    assert sim.sim_received() == {4: 1, 3: 1, 10: 1}
    assert sim.sim_errors() == dict.fromkeys(ERROR_KINDS, 0)
    # the widget keeps its configuration: the next client reads what the first one set
    with SimDmxWidget() as sim:
        with ProClient(sim.path, break_units=40, mab_units=2, rate_hz=0):  # type: ignore[arg-type]
            pass
        with DmxWidget(sim.path) as widget:  # type: ignore[arg-type]
            p = widget.parameters
            assert (p.break_units, p.mab_units, p.refresh_rate_hz) == (40, 2, 0)


@pytest.mark.parametrize(
    ("data", "kind"),
    [
        (struct.pack("<HBBB", 0, 8, 1, 40), "value"),  # break below 9
        (struct.pack("<HBBB", 0, 9, 0, 40), "value"),  # MAB below 1
        (struct.pack("<HBBB", 0, 9, 1, 41), "value"),  # rate above 40
        (struct.pack("<HBBB", 3, 9, 1, 40) + b"ab", "length"),  # user config shorter than stated
        (struct.pack("<HBB", 0, 9, 1), "length"),
    ],
)
def test_set_parameters_out_of_range_is_ignored(data: bytes, kind: str) -> None:
    with SimDmxWidget() as sim, ProClient(sim.path, break_units=30) as client:  # type: ignore[arg-type]
        client.send(4, data)
        assert client.parameters()[1:4] == (30, 1, 40)
    assert sim.sim_errors()[kind] == 1 and sum(sim.sim_errors().values()) == 1


# -- the parameters govern the output timing ---------------------------------------------------


@pytest.mark.parametrize(("brk", "mab", "rate"), [(100, 50, 10), (127, 127, 40), (9, 1, 0)])
def test_output_frames_follow_set_parameters(stepped, brk: int, mab: int, rate: int) -> None:
    clock, sim = stepped
    wire = _frame_s(brk, mab, 512)
    period = max(wire, 1 / rate) if rate else wire
    with ProClient(sim.path, break_units=brk, mab_units=mab, rate_hz=rate) as client:  # type: ignore[arg-type]
        times = [0.0, 0.3 * period, 0.6 * period, 2.5 * period]
        for i, t in enumerate(times):
            clock.t = t
            client.send(6, b"\0" + bytes([i]) * 512)
            assert sim.sim_wait_idle()
    assert sim.sim_frame_time_s(512) == pytest.approx(wire)
    h = sim.sim_history()
    # an idle port starts a frame at once; later universes wait for the next frame start
    assert [s.output_start_s for s in h] == pytest.approx([0.0, period, period, 3 * period])
    assert [s.active_s - s.output_start_s for s in h] == pytest.approx([wire] * 4)
    assert [s.dropped for s in h] == [False, True, False, False]  # #1 replaced before its frame
    assert sim.sim_state_at(period + wire) == bytes([2]) * 512


@pytest.mark.parametrize(("brk", "mab", "rate"), [(9, 1, 40), (100, 50, 10), (127, 127, 40), (9, 1, 0)])
def test_driver_confirms_by_the_timing_another_client_set(stepped, brk: int, mab: int, rate: int) -> None:
    clock, sim = stepped
    # a third-party program configured the widget, left a full universe on, and let go of it
    with ProClient(sim.path, break_units=brk, mab_units=mab, rate_hz=rate) as client:  # type: ignore[arg-type]
        client.send(6, b"\0" + bytes(512))
        assert sim.sim_wait_idle()
    clock.t = 0.004  # gonio opens mid-frame; size changes stress the frame-in-progress term
    sizes = [24, 24, 200, 512, 24, 512]
    with DmxWidget(sim.path, clock=clock) as widget:  # type: ignore[arg-type]
        assert (widget.parameters.break_units, widget.parameters.refresh_rate_hz) == (brk, rate)
        sent = [(widget.send_universe(bytes([i + 1]) * n), n) for i, n in enumerate(sizes)]
        ready = [widget.ready_at(t, n) for t, n in sent]
        assert sim.sim_wait_idle()
    history = sim.sim_history()[1:]
    assert [h.received_s for h in history] == [t for t, _ in sent]
    assert not any(h.dropped for h in history)  # every state went out on the wire
    for h, bound in zip(history, ready, strict=True):
        # the driver's bound covers the simulated output, and is not slack
        assert h.active_s <= bound < h.active_s + sim.sim_frame_period_s(512) + 3e-3


def test_light_stage_controller_after_label_4(stepped) -> None:
    from drivers.lights import LightController, pack_fixtures

    clock, sim = stepped
    with ProClient(sim.path, break_units=60, mab_units=20, rate_hz=15):  # type: ignore[arg-type]
        pass
    fixtures = pack_fixtures(np.tile([0.0, 0.0, 1.0], (16, 1)))
    with LightController.open({1: sim.path}, fixtures, clock=clock) as lights:  # type: ignore[dict-item]
        for i in range(6):
            state = lights.olat(i)
            assert sim.sim_wait_idle()
            assert clock.now() == state.ready_at_s  # set_state waited for the confirmation
            assert sim.sim_state_at(clock.now())[i] == 255  # and the light is really on
            assert lights.covers(state.ready_at_s, clock.now())


# -- direction: any request but 3 and 6 stops the output ---------------------------------------


def test_requests_other_than_3_and_6_stop_the_output(stepped) -> None:
    clock, sim = stepped
    with ProClient(sim.path) as client:  # type: ignore[arg-type]
        assert not sim.sim_is_outputting()  # an input until the first DMX packet
        client.send(6, b"\0" + bytes([9]) * 24)
        client.parameters()
        assert sim.sim_is_outputting()  # label 3 leaves the output running
        client.request(10)
        assert not sim.sim_is_outputting()  # label 10 turns the port to input
        assert sim.sim_state_at(1.0) == bytes([9]) * 24  # fixtures keep the last levels
        # a universe whose frame had not started when the output stopped never goes out
        clock.t = 1.0
        client.send(6, b"\0" + bytes([1]) * 24)  # idle port: its frame starts now
        assert sim.sim_wait_idle()
        clock.t = 1.001  # inside that frame (1.2 ms)
        client.send(6, b"\0" + bytes([2]) * 24)  # waits for the frame at 1.025
        client.send(8, b"\0")  # Receive DMX on Change: the port turns to input at 1.001
        assert client.nothing_pending()
    h = sim.sim_history()
    assert [s.dropped for s in h] == [False, False, True]
    assert sim.sim_state_at(2.0) == bytes([1]) * 24


# -- receiving DMX: labels 8, 5 and 9 ----------------------------------------------------------


def test_received_dmx_always_then_on_change() -> None:
    with SimDmxWidget() as sim, ProClient(sim.path) as client:  # type: ignore[arg-type]
        client.send(8, b"\0")  # send always (the default)
        assert client.nothing_pending()
        levels = bytes(range(1, 101))
        assert sim.sim_line_input(levels)
        assert client.read_frame() == (5, b"\0\0" + levels)  # status OK, start code 0, slots
        client.send(8, b"\1")  # changes only; the baseline restarts at zeros
        assert client.nothing_pending()
        universe = bytearray(513)
        packet = bytes(np.random.default_rng(1).integers(0, 256, 512, dtype=np.uint8))
        sim.sim_line_input(packet)
        changes = [client.read_frame() for _ in range(13)]  # 512 changed bytes in 40-byte spans
        assert client.nothing_pending()
        _decode_changes(changes, universe)
        assert universe == b"\0" + packet
        changed = bytearray(packet)
        changed[2], changed[299] = changed[2] ^ 0xFF, changed[299] ^ 0x0F
        sim.sim_line_input(bytes(changed))
        spans = [client.read_frame(), client.read_frame()]  # two far-apart changes
        assert [data[0] for _, data in spans] == [0, 300 // 8]
        _decode_changes(spans, universe)
        assert universe == b"\0" + changed
        sim.sim_line_input(bytes(changed))  # nothing changed: nothing sent
        sim.sim_line_input(b"\x01\x02", start_code=0x17)  # alternate start code: not reported
        assert client.nothing_pending()
        client.send(6, b"\0" + bytes(24))
        assert sim.sim_wait_idle()
        assert not sim.sim_line_input(levels)  # the port is an output now
        assert client.nothing_pending()
    assert sim.sim_errors() == dict.fromkeys(ERROR_KINDS, 0)


def test_a_host_that_does_not_read_loses_packets_and_is_told() -> None:
    with SimDmxWidget() as sim, ProClient(sim.path) as client:  # type: ignore[arg-type]
        played = 1000  # ~0.5 MB of label 5 frames, far more than the widget and the pty hold
        for i in range(played):
            sim.sim_line_input(struct.pack("<H", i) + bytes(510))
        got = []
        client.port.timeout = 0.3
        while head := client.port.read(4):
            body = client.port.read((head[2] | head[3] << 8) + 1)
            assert (head[:2], len(body), body[-1]) == (b"\x7e\x05", 515, 0xE7)
            status, start_code, index = struct.unpack_from("<BBH", body)
            got.append((status, index))
            assert (start_code, body[4:-1]) == (0, bytes(510))
        client.port.timeout = 1.0
        indices = [i for _, i in got]
        assert 0 < len(got) < played and indices == sorted(indices)
        # status bit 0 (queue overflowed) is set exactly on the first packet after a loss
        previous = [-1, *indices[:-1]]
        assert [s for s, _ in got] == [int(i != j + 1) for j, i in zip(previous, indices, strict=True)]
        sim.sim_line_input(b"\x05")
        lost_at_end = int(indices[-1] != played - 1)
        assert client.read_frame() == (5, bytes([lost_at_end]) + b"\x00\x05")
        sim.sim_line_input(b"\x06")
        assert client.read_frame() == (5, b"\x00\x00\x06")


# -- RDM labels 7 and 11 -----------------------------------------------------------------------

RDM_GET = bytes.fromhex("cc01180102030405064e450000000100000000100001000000")  # any RDM packet
DISCOVERY = b"\xcc" + bytes(range(37))  # 38 bytes, a DISC_UNIQUE_BRANCH request


def test_rdm_requests_are_ignored_by_dmx_firmware() -> None:
    with SimDmxWidget(firmware=0x0144) as sim, ProClient(sim.path) as client:  # type: ignore[arg-type]
        client.send(6, b"\0" + bytes([3]) * 24)
        client.send(7, RDM_GET)
        client.send(11, DISCOVERY)
        assert client.nothing_pending()  # no reply, as from a real widget
        assert sim.sim_is_outputting()  # unsupported messages change nothing
        assert sim.sim_rdm_sent() == []
    assert sim.sim_errors()["label"] == 2


def test_rdm_firmware_sends_on_the_line_and_listens() -> None:
    with SimDmxWidget(firmware=0x0244) as sim, ProClient(sim.path) as client:  # type: ignore[arg-type]
        client.send(6, b"\0" + bytes([3]) * 24)
        client.send(7, RDM_GET)
        assert client.nothing_pending()  # the simulated line has no responder
        assert not sim.sim_is_outputting()  # the port turned to input for the response
        response = bytes(range(1, 25))
        assert sim.sim_line_input(response, start_code=0xCC)  # a responder answers
        assert client.read_frame() == (5, b"\0\xcc" + response)
        client.send(11, DISCOVERY)
        client.send(11, DISCOVERY[:10])  # a discovery request is 38 bytes
        client.send(8, b"\1")  # Receive DMX on Change is not in the RDM firmware
        assert client.nothing_pending()
        assert sim.sim_rdm_sent() == [RDM_GET, DISCOVERY]
    errors = sim.sim_errors()
    assert (errors["length"], errors["label"], sum(errors.values())) == (1, 1, 2)


# -- everything else ---------------------------------------------------------------------------


def test_widget_only_and_unknown_labels_are_ignored() -> None:
    with SimDmxWidget() as sim, ProClient(sim.path) as client:  # type: ignore[arg-type]
        client.send(6, b"\0" + bytes([3]) * 24)
        for label in (0, 5, 9, 12, 77, 0x63, 255):
            client.send(label, b"\x01\x02")
        assert client.nothing_pending()
        assert sim.sim_is_outputting()
    assert sim.sim_errors()["label"] == 7 and sum(sim.sim_errors().values()) == 7


def test_firmware_bootstrap_answers_flash_pages() -> None:
    with SimDmxWidget() as sim, ProClient(sim.path) as client:  # type: ignore[arg-type]
        assert client.request(2, bytes(64))[0] == b"FALS"  # not in the bootstrap
        client.send(6, b"\0" + bytes(24))
        client.send(1)
        assert client.request(2, bytes(range(64)))[0] == b"TRUE"
        assert client.request(2, bytes(10))[0] == b"FALS"  # a page is 64 bytes
        assert sim.sim_in_bootstrap() and not sim.sim_is_outputting()
        client.send(3, b"\0\0")  # the bootstrap only programs pages
        assert client.request(2, bytes(64)) == (b"TRUE", [])
    assert sim.sim_errors()["label"] == 1
