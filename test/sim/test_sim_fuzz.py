"""
Fuzzing the simulated bus with random and mutated byte streams.

They never crash it, every status it sends is one the protocol allows (a whole status packet from
a servo id, or a Fast Sync or Fast Bulk Read's one status packet from the broadcast id), and a
packet that
fails its CRC is never answered with anything but a CRC error status.

Budgets are multiples of the Hypothesis profile's (test/conftest.py): 100 examples in make test,
20 times that in make fuzz.
"""

import struct

from dxl_servo_driver.models import xm430
from dxl_servo_driver.protocol import (
    BROADCAST_ID, decode_packet, encode_instruction, encode_status, ErrorCode, fast_status_size,
    Instruction, MAX_ID, Packet, parse_fast_status, StreamParser)
from dxl_servo_driver.sim.bus import Reply, SimBus
from dxl_servo_driver.sim.memory import Memory, TableError
from hypothesis import example, given, settings, strategies as st
import pytest

IDS = (1, 2, 3)
BAUD = 57600
EXAMPLES = settings.default.max_examples
FUZZ = settings(max_examples=EXAMPLES * 3 // 2)


class Clock:
    """A hand-moved clock."""

    def __init__(self) -> None:
        self.now_s = 0.0

    def __call__(self) -> float:
        return self.now_s


FAST_READS = (Instruction.FAST_SYNC_READ, Instruction.FAST_BULK_READ)


def is_fast_sync_read(packet: Packet) -> bool:
    """Tell whether a packet is a fast read: instruction 0x8A or 0x9A sent to the broadcast id."""
    return packet.instruction in FAST_READS and packet.servo_id == BROADCAST_ID


def asked(request: Packet) -> dict[int, int]:
    """Return id -> data length of the servos a fast read asks, in order (a repeat once)."""
    params = request.params
    if request.instruction == Instruction.FAST_SYNC_READ:
        if len(params) < 5:
            return {}
        return dict.fromkeys(params[4:], params[2] | params[3] << 8)
    records: dict[int, int] = {}
    if params and not len(params) % 5:
        for start in range(0, len(params), 5):
            records.setdefault(params[start], params[start + 3] | params[start + 4] << 8)
    return records


def answers_fast_sync_read(data: bytes, request: Packet) -> bool:
    """
    Tell whether data is the status packet that answers the fast read request.

    One packet from the broadcast id for all the servos asked: a head whose length counts every
    id asked (a repeated id once), then one part per servo that answers, in the order asked:
    error, id, the bytes asked (in a Fast Bulk Read, its record's), a CRC over everything
    before it. A silent servo's part is left out (protocol.encode_fast_status), so the packet
    may be shorter than its length field, but every byte of it is a checked part of a servo
    asked.
    """
    lengths = asked(request)
    if not lengths:
        return False
    parts, _ = parse_fast_status(data, 0, tuple(lengths), tuple(lengths.values()))
    return bool(parts) and len(data) == fast_status_size([lengths[i] for i in parts])


def check_replies(replies: list[Reply], requests: list[Packet]) -> None:
    """
    Assert every reply to these packets (those heard whole, in order) is one the protocol allows.

    A status from the broadcast id is a fast read's, exactly: it must answer one of the fast
    reads (Fast Sync or Fast Bulk) heard, each at most once and in order. Every other status is
    a whole, valid status packet from a servo id, 0..252.
    """
    fast_reads = [request for request in requests if is_fast_sync_read(request)]
    for reply in replies:
        data = reply.data
        if data[4:5] == bytes((BROADCAST_ID,)):
            while fast_reads and not answers_fast_sync_read(data, fast_reads[0]):
                del fast_reads[0]
            assert fast_reads, f'{data.hex()}: a status from the broadcast id, no fast read'
            del fast_reads[0]
            continue
        packet = decode_packet(data)
        assert packet.instruction == Instruction.STATUS
        assert 0 <= packet.servo_id <= MAX_ID


def test_the_oracle_takes_the_broadcast_id_only_from_a_fast_sync_read() -> None:
    fast = encode_instruction(BROADCAST_ID, Instruction.FAST_SYNC_READ, bytes((0, 0, 0, 0, 1)))
    [reply] = SimBus(IDS, clock=lambda: 0.0, seed=2).feed(fast, BAUD)
    assert reply.data[4] == BROADCAST_ID
    check_replies([reply], [decode_packet(fast)])
    # The same packet after no Fast Sync Read, a Sync Read, or a Fast Sync Read of another id.
    sync = encode_instruction(BROADCAST_ID, Instruction.SYNC_READ, bytes((0, 0, 0, 0, 1)))
    other = encode_instruction(BROADCAST_ID, Instruction.FAST_SYNC_READ, bytes((0, 0, 0, 0, 2)))
    for requests in ([], [decode_packet(sync)], [decode_packet(other)]):
        with pytest.raises(AssertionError):
            check_replies([reply], requests)
    # One Fast Sync Read is answered once; an ordinary status from the broadcast id never is.
    with pytest.raises(AssertionError):
        check_replies([reply, reply], [decode_packet(fast)])
    ordinary = Reply(encode_status(BROADCAST_ID, 0), BROADCAST_ID, 0.0)
    with pytest.raises(AssertionError):
        check_replies([ordinary], [decode_packet(fast)])


instruction_codes = st.sampled_from([int(i) for i in Instruction] + [0x00, 0x07, 0x7F, 0xFF])
target_ids = st.sampled_from(list(IDS) + [BROADCAST_ID, 0, 200])


@st.composite
def instruction_packets(draw: st.DrawFn) -> bytes:
    """Draw valid frames with arbitrary (often malformed) parameters, biased to plausible ones."""
    instruction = draw(instruction_codes)
    kind = draw(st.integers(0, 3))
    if kind == 0:
        params = draw(st.binary(max_size=40))
    elif kind == 1:
        item = draw(st.sampled_from(xm430.ITEMS))
        params = struct.pack('<HH', item.address, draw(st.integers(0, 8)))
        params += draw(st.binary(max_size=8))
    elif kind == 2:
        params = struct.pack('<HH', draw(st.integers(0, 700)), draw(st.integers(0, 6)))
        params += bytes(draw(st.lists(st.sampled_from(list(IDS) + [9]), max_size=5)))
    else:
        params = b''.join(
            struct.pack('<BHH', draw(st.sampled_from(IDS)), draw(st.integers(0, 670)),
                        draw(st.integers(0, 4)))
            for _ in range(draw(st.integers(1, 3))))
    return encode_instruction(draw(target_ids), instruction, params)


@given(st.lists(st.tuples(st.binary(max_size=64), st.floats(0.0, 0.2),
                          st.sampled_from([BAUD, 1_000_000])), max_size=20))
@FUZZ
def test_random_bytes_never_crash(chunks: list[tuple[bytes, float, int]]) -> None:
    clock = Clock()
    bus = SimBus(IDS, clock=clock, seed=1, boot_time_s=0.01)
    heard = StreamParser()  # what the bus's own parser makes of the bytes, for the oracle
    for data, dt_s, baud in chunks:
        clock.now_s += dt_s
        requests = [event.packet for event in heard.feed(data, clock.now_s) if event.crc_ok]
        check_replies(bus.feed(data, baud), requests)


@given(st.lists(st.tuples(instruction_packets(), st.floats(0.0, 0.05)), min_size=1,
                max_size=12))
@FUZZ
# Found at random in make test (the oracle then refused every status from the broadcast id):
# a Fast Sync Read of id 1, whose one status packet comes from id 0xFE ...
@example(packets=[(b'\xff\xff\xfd\x00\x01\x03\x00\x01\x19N', 0.0),
                  (b'\xff\xff\xfd\x00\xfe\x08\x00\x8a\x00\x00\x00\x00\x01D2', 0.0)])
# ... and of ids 1 and 9 (not on the bus): the packet is shorter than its length field says.
@example(packets=[(b'\xff\xff\xfd\x00\x01\x03\x00\x01\x19N', 0.0),
                  (b'\xff\xff\xfd\x00\xfe\t\x00\x8a\x00\x00\x00\x00\x01\t\xfaB', 0.0)])
# ... and a Fast Sync Read of 0x8000 bytes from ids 0 and 1, whose one status packet cannot be
# framed: it is ignored, as malformed ones are.
@example(packets=[(b'\xff\xff\xfd\x00\xfe\t\x00\x8a\x00\x00\x00\x80\x00\x01\xc9\xce', 0.0)])
def test_valid_frames_with_random_contents_never_crash(
        packets: list[tuple[bytes, float]]) -> None:
    clock = Clock()
    bus = SimBus(IDS, clock=clock, seed=2, boot_time_s=0.01)
    for data, dt_s in packets:
        clock.now_s += dt_s
        request = decode_packet(data)
        replies = bus.feed(data, BAUD)
        check_replies(replies, [request])
        if is_fast_sync_read(request):
            # Its answer is the one status packet from the broadcast id, or nothing.
            assert len(replies) <= 1
            assert all(reply.data[4] == BROADCAST_ID for reply in replies)
        # The bus stays coherent: every servo still has a readable register file.
        for servo_id in bus.servo_ids():
            assert len(bus.registers(servo_id)) == len(bus.servo(servo_id).model.items)


@given(instruction_packets(), st.data())
@FUZZ
def test_bad_crc_only_ever_gets_a_crc_error(packet: bytes, data: st.DataObject) -> None:
    mutated = bytearray(packet)
    flips = data.draw(st.lists(st.tuples(st.integers(0, len(packet) - 1), st.integers(0, 7)),
                               min_size=1, max_size=4))
    for position, bit in flips:
        mutated[position] ^= 1 << bit
    stream = bytes(mutated)
    events = StreamParser().feed(stream, 0.0)
    bus = SimBus(IDS, clock=lambda: 0.0, seed=3)
    before = {servo_id: bus.registers(servo_id) for servo_id in IDS}
    replies = bus.feed(stream, BAUD)
    if any(event.crc_ok for event in events):
        return  # the flips happened to make another valid packet: any answer is legitimate
    for reply in replies:
        status = decode_packet(reply.data)
        assert status.error & 0x7F == ErrorCode.CRC
        assert status.params == b''
        assert any(event.packet.servo_id == status.servo_id for event in events)
    assert len(replies) <= len(events)
    # Nothing was acted upon.
    assert {servo_id: bus.registers(servo_id) for servo_id in IDS} == before


@given(st.integers(0, 700), st.binary(max_size=12), st.booleans())
@settings(max_examples=3 * EXAMPLES)
def test_memory_write_is_checked_and_atomic(address: int, payload: bytes, torque: bool) -> None:
    memory = Memory()
    memory.set('torque_enable', int(torque))
    before = memory.snapshot()
    try:
        names = memory.write(address, payload)
    except TableError as error:
        assert 1 <= error.code <= 7
        assert memory.snapshot() == before
        return
    for name in names:
        item = memory.item(name)
        assert item.access == 'RW'
        assert item.minimum <= memory.get(name) <= item.maximum
        if item.area == 'eeprom':
            assert not torque
