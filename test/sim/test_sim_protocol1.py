"""Simulated X servos set to Protocol 1.0 (Protocol Version, address 13), byte for byte."""

from dxl_servo_driver import protocol
from dxl_servo_driver.models import model_for, xm430
from dxl_servo_driver.protocol import Instruction
from dxl_servo_driver.protocol.protocol1 import (
    BROADCAST_ID, encode_instruction, encode_status, ErrorBit, Instruction1)
from dxl_servo_driver.sim.bus import SimBus
import pytest

BAUD = 57600   # the X's factory baud rate
MANUAL = model_for(xm430.MODEL_NUMBER)
PROTOCOL_VERSION = MANUAL.lookup('protocol_version').address
LED = MANUAL.lookup('led').address
GOAL_POSITION = MANUAL.lookup('goal_position').address
STATUS_RETURN_LEVEL = MANUAL.lookup('status_return_level').address
MODEL = xm430.MODEL_NUMBER.to_bytes(2, 'little')


class Clock:
    """A hand-moved clock."""

    def __init__(self) -> None:
        self.now_s = 0.0

    def __call__(self) -> float:
        return self.now_s


def send(sim: SimBus, packet: bytes) -> list[bytes]:
    """Put a packet on the bus; return the status packets, in wire order."""
    return [reply.data for reply in sim.feed(packet, BAUD)]


def ping1(servo_id: int) -> bytes:
    return encode_instruction(servo_id, Instruction1.PING)


def ping2(servo_id: int) -> bytes:
    return protocol.encode_instruction(servo_id, Instruction.PING)


def write1(servo_id: int, address: int, data: bytes) -> bytes:
    return encode_instruction(servo_id, Instruction1.WRITE, bytes((address,)) + data)


def read1(servo_id: int, address: int, length: int) -> bytes:
    return encode_instruction(servo_id, Instruction1.READ, bytes((address, length)))


def to_protocol_1(sim: SimBus, servo_id: int) -> None:
    """Set a servo to Protocol 1.0 the way a user does: a Protocol 2.0 WRITE of register 13."""
    reply = send(sim, protocol.encode_instruction(
        servo_id, Instruction.WRITE, PROTOCOL_VERSION.to_bytes(2, 'little') + b'\x01'))
    assert reply == [protocol.encode_status(servo_id, 0)]


@pytest.fixture
def sim() -> SimBus:
    bus = SimBus([1, 2, 3], clock=Clock(), seed=5, boot_time_s=0.05)
    for servo_id in (1, 2, 3):
        to_protocol_1(bus, servo_id)
    return bus


def test_a_servo_answers_only_the_protocol_its_register_names() -> None:
    sim = SimBus([1, 2], clock=Clock(), boot_time_s=0.05)
    assert send(sim, ping1(1)) == []
    assert send(sim, ping2(1)) == [protocol.encode_status(1, 0, MODEL + b'\x2d')]
    # The write's status goes out in the protocol it came in; then only 1.0 is heard.
    to_protocol_1(sim, 1)
    assert sim.read_register(1, 'protocol_version') == 1
    assert send(sim, ping2(1)) == []
    assert send(sim, ping1(1)) == [encode_status(1, 0)]
    # The other servo still speaks 2.0 only.
    assert send(sim, ping1(2)) == []
    assert send(sim, ping2(2)) == [protocol.encode_status(2, 0, MODEL + b'\x2d')]
    # Back to 2.0 by a 1.0 WRITE: its status in 1.0, then only 2.0 answers.
    assert send(sim, write1(1, PROTOCOL_VERSION, b'\x02')) == [encode_status(1, 0)]
    assert send(sim, ping1(1)) == []
    assert send(sim, ping2(1)) == [protocol.encode_status(1, 0, MODEL + b'\x2d')]


def test_read_and_write_reach_the_same_control_table(sim: SimBus) -> None:
    assert send(sim, read1(2, 0, 2)) == [encode_status(2, 0, MODEL)]
    assert send(sim, read1(2, 6, 1)) == [encode_status(2, 0, b'\x2d')]   # the X's firmware
    assert send(sim, write1(2, LED, b'\x01')) == [encode_status(2, 0)]
    assert sim.read_register(2, 'led') == 1
    assert sim.read_register(1, 'led') == 0
    goal = (1234).to_bytes(4, 'little')
    assert send(sim, write1(3, GOAL_POSITION, goal)) == [encode_status(3, 0)]
    assert sim.read_register(3, 'goal_position') == 1234


def test_table_refusals_become_error_bits(sim: SimBus) -> None:
    assert send(sim, write1(1, 0, MODEL)) == [encode_status(1, ErrorBit.RANGE)]   # read-only
    assert send(sim, write1(1, 11, b'\x09')) == [encode_status(1, ErrorBit.RANGE)]  # no mode 9
    assert send(sim, write1(1, 64, b'\x01')) == [encode_status(1, 0)]
    beyond = (5000).to_bytes(4, 'little')   # past the Max Position Limit (4095)
    assert send(sim, write1(1, GOAL_POSITION, beyond)) == [
        encode_status(1, ErrorBit.ANGLE_LIMIT)]
    # Above address 255 is out of 1.0's reach; a length that crosses it too.
    assert send(sim, read1(1, 250, 10)) == [encode_status(1, ErrorBit.RANGE)]
    assert send(sim, read1(1, 255, 1)) == [encode_status(1, 0, b'\x00')]
    assert send(sim, encode_instruction(1, Instruction1.READ, b'\x00')) == [
        encode_status(1, ErrorBit.RANGE)]


def test_unknown_instruction_and_bad_checksum(sim: SimBus) -> None:
    assert send(sim, encode_instruction(1, 0x10, b'\x01')) == [
        encode_status(1, ErrorBit.INSTRUCTION)]
    assert send(sim, encode_instruction(BROADCAST_ID, 0x10)) == []
    bad = bytearray(read1(2, 0, 2))
    bad[-1] ^= 0xFF
    assert send(sim, bytes(bad)) == [encode_status(2, ErrorBit.CHECKSUM)]
    broadcast = bytearray(write1(BROADCAST_ID, LED, b'\x01'))
    broadcast[-1] ^= 0xFF
    assert send(sim, bytes(broadcast)) == []
    assert sim.read_register(1, 'led') == 0


def test_status_return_level(sim: SimBus) -> None:
    for level, answered in ((0, {'ping'}), (1, {'ping', 'read', 'bulk'}),
                            (2, {'ping', 'read', 'bulk', 'write'})):
        send(sim, write1(1, STATUS_RETURN_LEVEL, bytes((level,))))
        assert sim.read_register(1, 'status_return_level') == level
        got = {
            'ping': send(sim, ping1(1)) == [encode_status(1, 0)],
            'read': send(sim, read1(1, 7, 1)) == [encode_status(1, 0, b'\x01')],
            'bulk': send(sim, encode_instruction(
                BROADCAST_ID, Instruction1.BULK_READ, bytes((0, 1, 1, 7)))) == [
                    encode_status(1, 0, b'\x01')],
            'write': send(sim, write1(1, LED, b'\x00')) == [encode_status(1, 0)],
        }
        assert {name for name, ok in got.items() if ok} == answered, level


def test_reg_write_waits_for_action(sim: SimBus) -> None:
    reg = encode_instruction(2, Instruction1.REG_WRITE, bytes((LED, 1)))
    assert send(sim, reg) == [encode_status(2, 0)]
    assert sim.read_register(2, 'led') == 0
    assert sim.read_register(2, 'registered_instruction') == 1
    assert send(sim, encode_instruction(BROADCAST_ID, Instruction1.ACTION)) == []
    assert sim.read_register(2, 'led') == 1
    assert send(sim, encode_instruction(2, Instruction1.ACTION)) == [
        encode_status(2, ErrorBit.INSTRUCTION)]


def test_sync_write_and_bulk_read(sim: SimBus) -> None:
    params = bytes((LED, 1, 1, 1, 3, 1))
    assert send(sim, encode_instruction(BROADCAST_ID, Instruction1.SYNC_WRITE, params)) == []
    assert [sim.read_register(i, 'led') for i in (1, 2, 3)] == [1, 0, 1]
    # Replies in the order of the records, each its own address and length.
    bulk = bytes((0, 1, 3, LED, 2, 1, 0, 1, 2, 7))
    assert send(sim, encode_instruction(BROADCAST_ID, Instruction1.BULK_READ, bulk)) == [
        encode_status(3, 0, b'\x01'), encode_status(1, 0, MODEL), encode_status(2, 0, b'\x02')]
    # Sent to one id they are Instruction errors; malformed ones nobody answers.
    assert send(sim, encode_instruction(2, Instruction1.BULK_READ, bulk)) == [
        encode_status(2, ErrorBit.INSTRUCTION)]
    assert send(sim, encode_instruction(BROADCAST_ID, Instruction1.BULK_READ, bulk[:-1])) == []


def test_hardware_errors_set_their_bits_in_every_status(sim: SimBus) -> None:
    sim.inject_error(1, 'overload')
    sim.inject_error(2, 'encoder')   # no 1.0 bit: the register holds it
    assert send(sim, ping1(1)) == [encode_status(1, ErrorBit.OVERLOAD)]
    assert send(sim, read1(1, 7, 1)) == [encode_status(1, ErrorBit.OVERLOAD, b'\x01')]
    assert send(sim, ping1(2)) == [encode_status(2, 0)]
    assert send(sim, read1(2, 70, 1)) == [encode_status(2, 0, b'\x08')]


def test_reboot_answers_then_restarts() -> None:
    clock = Clock()
    sim = SimBus([3], clock=clock, boot_time_s=0.05)
    to_protocol_1(sim, 3)
    send(sim, write1(3, LED, b'\x01'))
    assert send(sim, encode_instruction(3, Instruction1.REBOOT)) == [encode_status(3, 0)]
    assert send(sim, ping1(3)) == []   # booting
    clock.now_s = 0.06
    assert send(sim, ping1(3)) == [encode_status(3, 0)]
    assert sim.read_register(3, 'led') == 0   # RAM back to its defaults
    assert sim.read_register(3, 'protocol_version') == 1   # EEPROM kept


def test_corrupted_replies_fail_their_checksum(sim: SimBus) -> None:
    sim.set_corrupt(1, 1.0)
    for _ in range(20):
        (reply,) = send(sim, read1(1, 0, 2))
        assert reply[:4] == b'\xff\xff\x01\x04'
        assert reply != encode_status(1, 0, MODEL)
        assert protocol1_checksum_fails(reply)


def protocol1_checksum_fails(packet: bytes) -> bool:
    return (~sum(packet[2:-1]) & 0xFF) != packet[-1]
