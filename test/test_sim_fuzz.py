"""
Fuzzing the simulated bus with random and mutated byte streams.

They never crash it, every status it sends is a well-formed packet, and a packet that fails its
CRC is never answered with anything but a CRC error status.
"""

import struct

from dxl_servo_driver.control_table import BY_NAME
from dxl_servo_driver.protocol import (
    BROADCAST_ID, decode_packet, encode_instruction, ErrorCode, Instruction, StreamParser)
from dxl_servo_driver.sim.bus import SimBus
from dxl_servo_driver.sim.memory import Memory, TableError
from hypothesis import given, HealthCheck, settings, strategies as st

IDS = (1, 2, 3)
BAUD = 57600
FUZZ = settings(max_examples=150, deadline=None,
                suppress_health_check=[HealthCheck.too_slow])


class Clock:
    """A hand-moved clock."""

    def __init__(self) -> None:
        self.now_s = 0.0

    def __call__(self) -> float:
        return self.now_s


def check_reply(data: bytes, ids: set[int]) -> None:
    """Assert a reply is a whole, valid status packet from a servo of the bus."""
    packet = decode_packet(data)
    assert packet.instruction == Instruction.STATUS
    assert packet.servo_id in ids


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
        item = BY_NAME[draw(st.sampled_from(sorted(BY_NAME)))]
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
    for data, dt_s, baud in chunks:
        clock.now_s += dt_s
        for reply in bus.feed(data, baud):
            check_reply(reply.data, set(range(253)))


@given(st.lists(st.tuples(instruction_packets(), st.floats(0.0, 0.05)), min_size=1,
                max_size=12))
@FUZZ
def test_valid_frames_with_random_contents_never_crash(
        packets: list[tuple[bytes, float]]) -> None:
    clock = Clock()
    bus = SimBus(IDS, clock=clock, seed=2, boot_time_s=0.01)
    for data, dt_s in packets:
        clock.now_s += dt_s
        for reply in bus.feed(data, BAUD):
            check_reply(reply.data, set(range(253)))
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
@settings(max_examples=300, deadline=None)
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
