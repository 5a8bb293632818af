"""Protocol 2.0 framing: CRC, stuffing, encoding, and the incremental parser."""

from dxl_servo_driver.protocol import (
    ALERT_BIT, BROADCAST_ID, crc16, crc16_python, CRC_IMPLEMENTATION, decode_packet,
    encode_instruction, encode_status, ErrorCode, HEADER, Instruction, Packet, StreamParser, stuff,
    unstuff)
from dynamixel_sdk.protocol2_packet_handler import Protocol2PacketHandler
from hypothesis import given, settings, strategies as st
import pytest

SDK = Protocol2PacketHandler()
# The Hypothesis profile's budget (test/conftest.py): 100 examples in make test, 2000 in fuzz.
EXAMPLES = settings.default.max_examples


def sdk_crc(data: bytes) -> int:
    """Return the CRC computed by dynamixel_sdk's own table (an independent implementation)."""
    return SDK.updateCRC(0, list(data), len(data))


def test_ping_example_from_the_e_manual() -> None:
    assert encode_instruction(1, Instruction.PING) == bytes.fromhex('FFFFFD0001030001194E')


def test_ping_status_for_model_1030_matches_sdk_crc() -> None:
    params = bytes((0x06, 0x04, 0x2D))  # model 1030 little endian, firmware 45
    status = encode_status(1, 0, params)
    body = bytes.fromhex('FFFFFD000107005500') + params
    expected_crc = sdk_crc(body)
    assert status == body + bytes((expected_crc & 0xFF, expected_crc >> 8))
    # The e-manual's worked example (firmware 38) as a fixed point of our CRC.
    assert encode_status(1, 0, bytes((0x06, 0x04, 0x26))) == bytes.fromhex(
        'FFFFFD00010700550006042665 5D'.replace(' ', ''))


def test_write_status_example() -> None:
    # e-manual: status of a successful WRITE to id 1
    assert encode_status(1, 0) == bytes.fromhex('FFFFFD0001040055 00A10C'.replace(' ', ''))


def test_read_instruction_example() -> None:
    # e-manual: READ present position (132, 4 bytes) of id 1
    assert encode_instruction(1, Instruction.READ, bytes((0x84, 0, 4, 0))) == bytes.fromhex(
        'FFFFFD0001070002840004001D15')


def test_stuffed_packet_matches_sdk_stuffing() -> None:
    params = bytes((116, 0, 0xFF, 0xFF, 0xFD, 0x00))
    packet = encode_instruction(1, Instruction.WRITE, params)
    # length: instruction 1 + params 6 + one stuffing byte + CRC 2 = 10
    assert packet[:7] == bytes.fromhex('FFFFFD00010A00')
    assert packet[7:-2] == bytes((0x03, 116, 0, 0xFF, 0xFF, 0xFD, 0xFD, 0x00))
    sdk_packet = [0xFF, 0xFF, 0xFD, 0x00, 1, 9, 0, 0x03] + list(params) + [0, 0]
    sdk_packet = SDK.addStuffing(sdk_packet)
    length = sdk_packet[5] | sdk_packet[6] << 8
    assert bytes(sdk_packet[:7 + length - 2]) == packet[:-2]
    assert decode_packet(packet) == Packet(1, Instruction.WRITE, params)


@given(st.binary(max_size=300))
@settings(max_examples=2 * EXAMPLES)
def test_crc_matches_sdk(data: bytes) -> None:
    assert crc16(data) == sdk_crc(data)


@given(st.binary(max_size=100), st.binary(max_size=100))
def test_crc_continues(first: bytes, second: bytes) -> None:
    assert crc16(second, crc16(first)) == crc16(first + second)
    assert crc16(bytearray(second), crc16(first)) == crc16(first + second)


@given(st.binary(max_size=300), st.integers(0, 0xFFFF))
@settings(max_examples=2 * EXAMPLES)
def test_the_compiled_crc_is_the_pure_one(data: bytes, start: int) -> None:
    # The hot path uses fastcrc when installed (requirements/dev.txt installs it).
    assert CRC_IMPLEMENTATION == 'fastcrc'
    assert crc16(data, start) == crc16_python(data, start)
    assert crc16_python(data) == sdk_crc(data)


@given(st.binary(max_size=200).map(lambda b: b.replace(b'\xfe', b'\xff\xff\xfd')))
@settings(max_examples=2 * EXAMPLES)
def test_stuff_round_trip(payload: bytes) -> None:
    stuffed = stuff(payload)
    assert unstuff(stuffed) == payload
    assert len(stuffed) == len(payload) + payload.count(b'\xff\xff\xfd')
    assert HEADER not in stuffed


@given(st.integers(0, 0xFE), st.sampled_from(list(Instruction)),
       st.binary(max_size=120).map(lambda b: b.replace(b'\x07', b'\xff\xff\xfd')))
@settings(max_examples=2 * EXAMPLES)
def test_encode_decode_round_trip(servo_id: int, instruction: int, params: bytes) -> None:
    packet = encode_instruction(servo_id, instruction, params)
    assert crc16(packet[:-2]) == packet[-2] | packet[-1] << 8
    if instruction == Instruction.STATUS:
        assert decode_packet(packet).servo_id == servo_id
        return
    assert decode_packet(packet) == Packet(servo_id, instruction, params)
    parser = StreamParser()
    events = parser.feed(packet, 0.0)
    assert [(e.packet, e.crc_ok) for e in events] == [(Packet(servo_id, instruction, params),
                                                      True)]


@given(st.integers(0, 252), st.integers(0, 0xFF), st.binary(max_size=60))
def test_status_round_trip(servo_id: int, error: int, params: bytes) -> None:
    decoded = decode_packet(encode_status(servo_id, error, params))
    assert decoded == Packet(servo_id, Instruction.STATUS, params, error)


def test_decode_rejects_bad_packets() -> None:
    good = encode_instruction(1, Instruction.PING)
    with pytest.raises(ValueError, match='CRC'):
        decode_packet(good[:-1] + bytes((good[-1] ^ 1,)))
    with pytest.raises(ValueError):
        decode_packet(good[:-1])
    with pytest.raises(ValueError):
        decode_packet(b'\x00' + good[1:])


def test_parser_skips_garbage_and_reassembles_bytewise() -> None:
    first = encode_instruction(3, Instruction.READ, bytes((132, 0, 4, 0)))
    second = encode_instruction(BROADCAST_ID, Instruction.PING)
    stream = b'\x00\xff\x12\xff\xff' + first + b'\xff\xfd' + second
    parser = StreamParser()
    events = []
    for index in range(len(stream)):
        events += parser.feed(stream[index:index + 1], index * 1e-4)
    assert [e.packet for e in events] == [Packet(3, Instruction.READ, bytes((132, 0, 4, 0))),
                                          Packet(BROADCAST_ID, Instruction.PING, b'')]
    assert all(e.crc_ok for e in events)
    assert parser.pending == 0


def test_parser_reports_bad_crc_with_id_and_goes_on() -> None:
    bad = bytearray(encode_instruction(5, Instruction.WRITE, bytes((65, 0, 1))))
    bad[-1] ^= 0x40
    good = encode_instruction(6, Instruction.PING)
    events = StreamParser().feed(bytes(bad) + good, 0.0)
    assert [(e.packet.servo_id, e.crc_ok) for e in events] == [(5, False), (6, True)]
    assert events[0].raw == bytes(bad)


def test_parser_drops_partial_packet_after_inter_byte_timeout() -> None:
    packet = encode_instruction(1, Instruction.PING)
    parser = StreamParser(inter_byte_timeout_s=0.01)
    assert parser.feed(packet[:6], 0.0) == []
    assert parser.pending == 6
    # The rest arrives too late: the partial packet is gone, the tail alone is no packet.
    assert parser.feed(packet[6:], 0.5) == []
    assert parser.feed(packet, 0.6)[0].packet == Packet(1, Instruction.PING, b'')
    # In time, the same split packet is whole.
    assert parser.feed(packet[:6], 1.0) == []
    assert parser.feed(packet[6:], 1.005)[0].crc_ok


def test_parser_resyncs_on_impossible_length() -> None:
    noise = HEADER + bytes((1, 0x01, 0x00))  # length 1 < 3
    packet = encode_instruction(2, Instruction.PING)
    events = StreamParser().feed(noise + packet, 0.0)
    assert [e.packet.servo_id for e in events] == [2]


def test_error_codes_and_alert_bit_values() -> None:
    assert [int(code) for code in ErrorCode] == [1, 2, 3, 4, 5, 6, 7]
    assert ALERT_BIT == 0x80
    assert int(Instruction.BULK_WRITE) == 0x93 and int(Instruction.CLEAR) == 0x10
