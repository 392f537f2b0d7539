"""Protocol 2.0 framing: known vectors, CRC and stuffing against the real dynamixel_sdk."""

from __future__ import annotations

import pytest
from dynamixel_sdk import PacketHandler
from dynamixel_sdk.protocol2_packet_handler import Protocol2PacketHandler
from hypothesis import given
from hypothesis import strategies as st

from simulators.dynamixel.protocol import (
    HEADER,
    Instruction,
    PacketParser,
    build_packet,
    build_status,
    crc16,
    parse_packet,
    stuff,
    unstuff,
)

SDK = Protocol2PacketHandler()


def test_ping_to_id1_matches_the_manual_vector():
    assert build_packet(1, Instruction.PING) == bytes.fromhex("FF FF FD 00 01 03 00 01 19 4E")


def test_empty_ok_status_from_id1_matches_the_manual_vector():
    assert build_status(1, 0) == bytes.fromhex("FF FF FD 00 01 04 00 55 00 A1 0C")


@pytest.mark.parametrize(
    ("servo_id", "inst", "params", "wire"),
    [
        # e-manual examples: ping reply (model 1030, fw 38), READ 4 bytes at 132, WRITE 512 at 116
        (1, 0x55, "00 06 04 26", "FF FF FD 00 01 07 00 55 00 06 04 26 65 5D"),
        (1, 0x02, "84 00 04 00", "FF FF FD 00 01 07 00 02 84 00 04 00 1D 15"),
        (1, 0x03, "74 00 00 02 00 00", "FF FF FD 00 01 09 00 03 74 00 00 02 00 00 CA 89"),
    ],
)
def test_more_manual_vectors(servo_id, inst, params, wire):
    raw = build_packet(servo_id, inst, bytes.fromhex(params))
    assert raw == bytes.fromhex(wire)
    pkt = parse_packet(raw)
    assert (pkt.servo_id, pkt.instruction, pkt.params, pkt.crc_ok) == (
        servo_id, inst, bytes.fromhex(params), True)


@given(st.binary(max_size=300))
def test_crc_agrees_with_the_sdk(data):
    assert crc16(data) == SDK.updateCRC(0, list(data), len(data))


@given(st.lists(st.sampled_from([0xFF, 0xFD, 0x00, 0x12]), max_size=60).map(bytes))
def test_stuffing_round_trips(region):
    stuffed = stuff(region)
    assert unstuff(stuffed) == region
    # After stuffing, FF FF FD is always followed by FD: no header can appear inside.
    for i in range(len(stuffed) - 2):
        if stuffed[i : i + 3] == b"\xff\xff\xfd":
            assert stuffed[i + 3 : i + 4] == b"\xfd"


def test_stuffing_vector():
    assert stuff(bytes.fromhex("FF FF FD 01")) == bytes.fromhex("FF FF FD FD 01")
    assert stuff(bytes.fromhex("FF FF FD FD")) == bytes.fromhex("FF FF FD FD FD")
    assert unstuff(bytes.fromhex("FF FF FD FD FD")) == bytes.fromhex("FF FF FD FD")


@given(st.integers(0, 252), st.lists(st.sampled_from([0xFF, 0xFD, 0x00, 0x7F]), max_size=40))
def test_instruction_framing_matches_the_sdk(servo_id, params):
    """Our framing (stuffing, length, CRC) equals what the SDK's txPacket sends."""
    ours = build_packet(servo_id, Instruction.WRITE, bytes(params))
    # SDK framing: fill an unstuffed packet, let addStuffing + header + CRC do the rest.
    tx = [0] * (len(params) + 10) + [0] * len(params)  # room for stuffing
    tx[4], tx[5], tx[6], tx[7] = servo_id, (len(params) + 3) & 0xFF, (len(params) + 3) >> 8, 3
    tx[8 : 8 + len(params)] = params
    tx = SDK.addStuffing(tx)
    total = (tx[5] | tx[6] << 8) + 7
    tx[0:4] = list(HEADER)
    crc = SDK.updateCRC(0, tx, total - 2)
    tx[total - 2], tx[total - 1] = crc & 0xFF, crc >> 8
    assert bytes(tx[:total]) == ours


def test_sdk_unstuffs_our_status_packet():
    """The SDK recovers data containing the header pattern from our stuffed status packet.

    (The SDK's in-place removeStuffing mangles rarer patterns such as FF FF FD FF FD FD even in
    its own round trip, so this uses a plain one.)
    """
    data = bytes.fromhex("FF FF FD 01 02")
    status = build_status(5, 0, data)
    assert status.count(b"\xff\xff\xfd\xfd") == 1
    back = SDK.removeStuffing(list(status))
    n = back[5] | back[6] << 8
    assert bytes(back[9 : 9 + n - 4]) == data
    assert SDK.updateCRC(0, list(status), len(status) - 2) == status[-2] | status[-1] << 8


def test_parser_handles_split_feeds_garbage_and_bad_crc():
    good = build_packet(3, Instruction.READ, bytes.fromhex("84 00 04 00"))
    bad = bytearray(build_packet(4, Instruction.PING))
    bad[-1] ^= 0x01
    stream = b"\x00\xff\x13" + good + bytes(bad) + good[:5]
    parser = PacketParser()
    got = []
    for i in range(0, len(stream), 3):  # three bytes at a time
        got += list(parser.feed(stream[i : i + 3]))
    assert [(p.servo_id, p.crc_ok) for p in got] == [(3, True), (4, False)]
    assert parser.pending == 5
    assert [p.servo_id for p in parser.feed(good[5:])] == [3]


def test_parser_resyncs_after_an_impossible_length():
    junk = HEADER + bytes([1, 0xFF, 0xFF])  # LEN 65535
    pkt = build_packet(7, Instruction.PING)
    assert [p.servo_id for p in PacketParser().feed(junk + pkt)] == [7]


def test_parse_packet_rejects_incomplete_input():
    with pytest.raises(ValueError):
        parse_packet(build_packet(1, Instruction.PING)[:-1])


def test_sdk_packet_handler_is_protocol_2():
    assert PacketHandler(2.0).getProtocolVersion() == 2.0
