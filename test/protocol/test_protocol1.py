"""Protocol 1.0 framing: checksum, encoding, the bus's scan and the servos' stream parser."""

from dxl_servo_driver.protocol import Frame, Framer, Packet
from dxl_servo_driver.protocol.protocol1 import (
    BROADCAST_ID, checksum, decode_packet, encode_instruction, encode_status, ERROR_BIT_NAMES,
    error_text, ErrorBit, Instruction1, PROTOCOL_1, scan_frames, STATUS_OVERHEAD, StreamParser1)
from hypothesis import given, strategies as st
import pytest

# The e-manual's Protocol 1.0 examples, their checksums worked by hand:
# READ of 1 byte at 0x2B (internal temperature) of id 1: ~(01+04+02+2B+01 = 33) = CC
READ_TEMPERATURE = bytes.fromhex('FFFF0104022B01CC')
# its status, temperature 0x20: ~(01+03+00+20 = 24) = DB
TEMPERATURE_STATUS = bytes.fromhex('FFFF01030020DB')
# WRITE of 1 at address 3 (the id) to every servo: ~(FE+04+03+03+01 = 109, low byte 09) = F6
WRITE_ID_BROADCAST = bytes.fromhex('FFFFFE04030301F6')


def test_the_e_manual_examples_encode_byte_for_byte() -> None:
    assert encode_instruction(1, Instruction1.READ, bytes((0x2B, 1))) == READ_TEMPERATURE
    assert encode_status(1, 0, bytes((0x20,))) == TEMPERATURE_STATUS
    assert encode_instruction(BROADCAST_ID, Instruction1.WRITE, bytes((3, 1))) == \
        WRITE_ID_BROADCAST
    assert checksum(READ_TEMPERATURE[2:-1]) == 0xCC


def test_the_e_manual_examples_decode() -> None:
    assert decode_packet(READ_TEMPERATURE) == Packet(1, Instruction1.READ, b'\x2b\x01', 2)
    status = decode_packet(TEMPERATURE_STATUS)
    assert (status.servo_id, status.error, status.params) == (1, 0, b'\x20')
    for broken in (READ_TEMPERATURE[:-1] + b'\xcd', READ_TEMPERATURE[:-1], b'\xff\xfe' * 4):
        with pytest.raises(ValueError):
            decode_packet(broken)


def test_error_bits_and_their_names() -> None:
    assert [int(bit) for bit in ErrorBit] == [1 << n for n in range(7)]
    assert set(ERROR_BIT_NAMES) == set(ErrorBit)
    assert error_text(ErrorBit.RANGE | ErrorBit.OVERLOAD) == ', '.join(
        (ERROR_BIT_NAMES[ErrorBit.RANGE], ERROR_BIT_NAMES[ErrorBit.OVERLOAD]))
    assert error_text(0) == ''


def test_the_framer_is_a_bus_framer() -> None:
    framer: Framer = PROTOCOL_1
    assert framer.status_overhead == STATUS_OVERHEAD == len(encode_status(1, 0))
    assert framer.encode(1, Instruction1.PING) == bytes.fromhex('FFFF010201FB')
    assert framer.version == 1


def test_a_status_frame_is_read_as_a_status() -> None:
    frames, rest = scan_frames(TEMPERATURE_STATUS)
    assert rest == len(TEMPERATURE_STATUS)
    (frame,) = frames
    assert isinstance(frame, Frame)
    assert (frame.start, frame.end, frame.servo_id, frame.crc_ok) == (0, 7, 1, True)
    assert frame.is_status and frame.status() == (0, b'\x20')
    # An instruction with bit 7 set cannot be a status; a short one can (the bus compares).
    sync_write = encode_instruction(BROADCAST_ID, Instruction1.SYNC_WRITE, bytes((30, 1, 1, 0)))
    assert not scan_frames(sync_write)[0][0].is_status
    assert scan_frames(READ_TEMPERATURE)[0][0].is_status


def test_scan_skips_noise_and_short_length_fields() -> None:
    noise = b'\x00\x12\xff\x34' + b'\xff\xff\x05\x01\x99' + b'\xff\xff\x05\x00'
    frames, rest = scan_frames(noise + TEMPERATURE_STATUS + b'\x55')
    assert [frame.raw for frame in frames] == [TEMPERATURE_STATUS]
    assert frames[0].start == len(noise)
    assert rest == len(noise) + len(TEMPERATURE_STATUS) + 1


def test_header_padding_before_the_id_is_skipped() -> None:
    # An id is never FF: the header is the last two FFs of a run.
    frames, _ = scan_frames(b'\xff\xff\xff' + TEMPERATURE_STATUS)
    assert [frame.start for frame in frames] == [3]
    assert frames[0].crc_ok


def test_scan_returns_where_an_incomplete_packet_begins() -> None:
    data = TEMPERATURE_STATUS + READ_TEMPERATURE
    for cut in range(len(TEMPERATURE_STATUS), len(data)):
        frames, rest = scan_frames(data[:cut])
        assert [frame.raw for frame in frames] == [TEMPERATURE_STATUS]
        # A trailing lone byte that is not FF is noise; an FF may begin a header.
        assert rest == (len(TEMPERATURE_STATUS) if cut > len(TEMPERATURE_STATUS) + 1
                        or data[cut - 1] == 0xFF else cut)
    frames, rest = scan_frames(data[:-1], final=True)
    assert [frame.raw for frame in frames] == [TEMPERATURE_STATUS]
    assert rest == len(data) - 1


def test_a_checksum_failure_is_reported_and_resync_looks_inside_it() -> None:
    # Noise forged a header whose length swallows the real status after it.
    forged = b'\xff\xff\x01\x08\x00'
    data = forged + TEMPERATURE_STATUS
    frames, rest = scan_frames(data)
    assert [(frame.crc_ok, frame.raw) for frame in frames] == [
        (False, data), (True, TEMPERATURE_STATUS)]
    assert rest == len(data)
    # A servo's receiver (no resync) skips the whole claimed length.
    frames, _ = scan_frames(data, resync=False)
    assert [frame.crc_ok for frame in frames] == [False]


def test_ff_ff_inside_the_parameters_is_data() -> None:
    # A 2-byte read answered 0xFFFF: the length field decides, the packet checks.
    status = encode_status(3, 0, b'\xff\xff')
    write = encode_instruction(4, Instruction1.WRITE, bytes((30,)) + b'\xff\xff\xff\xff')
    frames, rest = scan_frames(status + write)
    assert [(frame.raw, frame.crc_ok) for frame in frames] == [(status, True), (write, True)]
    assert frames[0].status() == (0, b'\xff\xff')
    assert rest == len(status) + len(write)


@given(st.integers(0, 253), st.integers(0, 0x7F), st.binary(max_size=40), st.binary(max_size=8))
def test_status_round_trip_after_noise(servo_id: int, error: int, params: bytes,
                                       noise: bytes) -> None:
    status = encode_status(servo_id, error, params)
    frames, rest = scan_frames(noise + status, final=True)
    matching = [frame for frame in frames if frame.raw == status]
    assert matching and matching[-1].end == len(noise) + len(status)
    assert matching[-1].status() == (error, params)
    assert rest == len(noise) + len(status)


@given(st.integers(0, 253), st.sampled_from(list(Instruction1)), st.binary(max_size=40),
       st.integers(1, 30))
def test_the_stream_parser_takes_packets_in_any_pieces(servo_id: int, instruction: int,
                                                       params: bytes, piece: int) -> None:
    packet = encode_instruction(servo_id, instruction, params)
    parser = StreamParser1()
    data = b'\x00\xff' + packet + packet
    events = []
    for start in range(0, len(data), piece):
        events += parser.feed(data[start:start + piece], 0.0)
    assert [(event.packet, event.crc_ok) for event in events] == [
        (Packet(servo_id, instruction, params), True)] * 2
    assert parser.pending == 0


def test_the_stream_parser_drops_a_partial_packet_after_the_timeout() -> None:
    parser = StreamParser1(inter_byte_timeout_s=0.01)
    assert parser.feed(READ_TEMPERATURE[:5], 0.0) == []
    assert parser.pending == 5
    # The rest comes too late: those bytes are not a packet any more.
    assert parser.feed(READ_TEMPERATURE[5:], 0.05) == []
    events = parser.feed(READ_TEMPERATURE, 0.06)
    assert [event.raw for event in events] == [READ_TEMPERATURE]


def test_the_stream_parser_reports_a_bad_checksum_with_its_id() -> None:
    parser = StreamParser1()
    bad = READ_TEMPERATURE[:-1] + b'\x00'
    (event,) = parser.feed(bad + WRITE_ID_BROADCAST, 0.0)[:1]
    assert (event.crc_ok, event.packet.servo_id, event.raw) == (False, 1, bad)


def test_a_packet_holds_at_most_253_parameters() -> None:
    assert len(encode_instruction(1, Instruction1.WRITE, bytes(253))) == 253 + 6
    with pytest.raises(ValueError):
        encode_instruction(1, Instruction1.WRITE, bytes(254))
