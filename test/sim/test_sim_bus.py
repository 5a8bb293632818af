"""
SimBus: several servos on one bus, driven by dynamixel_sdk's own packet code, and fault injection.

The SDK talks to the bus through a throwaway port object defined here (the real in-process port
is the TRANSPORT helper's); the clock is injected.
"""

import struct

from dxl_servo_driver.protocol import (
    BROADCAST_ID, crc16, decode_packet, encode_instruction, Instruction)
from dxl_servo_driver.sim.bus import Reply, SimBus
from dynamixel_sdk import (
    COMM_RX_CORRUPT, COMM_RX_TIMEOUT, COMM_SUCCESS, GroupBulkRead, GroupBulkWrite, GroupSyncRead,
    GroupSyncWrite, Protocol2PacketHandler)
import pytest

BAUD = 57600


class ThrowawayPort:
    """The part of dynamixel_sdk's PortHandler its packet handler uses, forwarding to SimBus."""

    def __init__(self, bus: SimBus, baud: int = BAUD) -> None:
        self.bus = bus
        self.baud = baud
        self.is_using = False
        self.rx = bytearray()

    def clearPort(self) -> None:  # noqa: N802 (SDK API)
        self.rx.clear()

    def writePort(self, packet: list[int]) -> int:  # noqa: N802
        for reply in self.bus.feed(bytes(packet), self.baud):
            self.rx += reply.data
        return len(packet)

    def readPort(self, length: int) -> list[int]:  # noqa: N802
        data = list(self.rx[:length])
        del self.rx[:length]
        return data

    def getBaudRate(self) -> int:  # noqa: N802
        return self.baud

    def setPacketTimeout(self, packet_length: int) -> None:  # noqa: N802
        pass

    def setPacketTimeoutMillis(self, msec: float) -> None:  # noqa: N802
        pass

    def isPacketTimeout(self) -> bool:  # noqa: N802
        return not self.rx  # nothing more will come: the bus answered synchronously


class Clock:
    """A hand-moved clock."""

    def __init__(self) -> None:
        self.now_s = 0.0

    def __call__(self) -> float:
        return self.now_s


@pytest.fixture
def rig() -> tuple[SimBus, ThrowawayPort, Protocol2PacketHandler, Clock]:
    clock = Clock()
    bus = SimBus([1, 2, 3, 4], clock=clock, seed=3, boot_time_s=0.05)
    return bus, ThrowawayPort(bus), Protocol2PacketHandler(), clock


def test_sdk_ping_read_write(rig: tuple) -> None:
    bus, port, sdk, _ = rig
    model, result, error = sdk.ping(port, 2)
    assert (model, result, error) == (1030, COMM_SUCCESS, 0)
    assert sdk.ping(port, 9)[1] == COMM_RX_TIMEOUT
    assert sdk.write1ByteTxRx(port, 2, 65, 1) == (COMM_SUCCESS, 0)
    assert bus.read_register(2, 'led') == 1
    assert sdk.write4ByteTxRx(port, 2, 104, (-100) & 0xFFFFFFFF) == (COMM_SUCCESS, 0)
    value, result, error = sdk.read4ByteTxRx(port, 2, 104)
    assert (struct.unpack('<i', struct.pack('<I', value))[0], result, error) == (-100, 0, 0)
    assert sdk.write4ByteTxRx(port, 2, 104, 1000) == (COMM_SUCCESS, 6)  # data limit
    assert sdk.read2ByteTxRx(port, 3, 0) == (1030, COMM_SUCCESS, 0)


def test_sdk_broadcast_ping(rig: tuple) -> None:
    bus, port, sdk, _ = rig
    found, result = sdk.broadcastPing(port)
    assert result == COMM_SUCCESS
    assert found == {i: [1030, 45] for i in (1, 2, 3, 4)}


def test_sdk_sync_read_write_across_servos(rig: tuple) -> None:
    bus, port, sdk, _ = rig
    writer = GroupSyncWrite(port, sdk, 104, 4)
    for servo_id in (1, 2, 4):
        assert writer.addParam(servo_id, list(struct.pack('<i', 10 * servo_id)))
    assert writer.txPacket() == COMM_SUCCESS
    assert [bus.read_register(i, 'goal_velocity') for i in (1, 2, 3, 4)] == [10, 20, 0, 40]
    reader = GroupSyncRead(port, sdk, 104, 4)
    for servo_id in (4, 2, 1, 3):
        assert reader.addParam(servo_id)
    assert reader.txRxPacket() == COMM_SUCCESS
    assert [reader.getData(i, 104, 4) for i in (1, 2, 3, 4)] == [10, 20, 0, 40]


def test_sdk_bulk_read_write_across_servos(rig: tuple) -> None:
    bus, port, sdk, _ = rig
    writer = GroupBulkWrite(port, sdk)
    assert writer.addParam(1, 65, 1, [1])
    assert writer.addParam(3, 112, 4, list(struct.pack('<I', 77)))
    assert writer.txPacket() == COMM_SUCCESS
    assert bus.read_register(1, 'led') == 1
    assert bus.read_register(3, 'profile_velocity') == 77
    reader = GroupBulkRead(port, sdk)
    assert reader.addParam(3, 112, 4)
    assert reader.addParam(1, 65, 1)
    assert reader.addParam(2, 0, 2)
    assert reader.txRxPacket() == COMM_SUCCESS
    assert (reader.getData(3, 112, 4), reader.getData(1, 65, 1), reader.getData(2, 0, 2)) == (
        77, 1, 1030)


def test_sync_and_bulk_read_reply_order_is_packet_order(rig: tuple) -> None:
    bus, _, _, _ = rig
    ids = bytes((3, 1, 4, 9, 2))
    replies = bus.feed(encode_instruction(BROADCAST_ID, Instruction.SYNC_READ,
                                          struct.pack('<HH', 7, 1) + ids), BAUD)
    assert [r.servo_id for r in replies] == [3, 1, 4, 2]
    assert [decode_packet(r.data).params for r in replies] == [b'\x03', b'\x01', b'\x04',
                                                               b'\x02']
    params = b''.join(struct.pack('<BHH', i, 7, 1) for i in (4, 2, 3))
    replies = bus.feed(encode_instruction(BROADCAST_ID, Instruction.BULK_READ, params), BAUD)
    assert [r.servo_id for r in replies] == [4, 2, 3]


def test_malformed_sync_and_bulk_packets_are_ignored(rig: tuple) -> None:
    bus, _, _, _ = rig
    # sync write: 4-byte data but 3 bytes per servo
    bad = struct.pack('<HH', 65, 4) + bytes((1, 1, 0, 0))
    assert bus.feed(encode_instruction(BROADCAST_ID, Instruction.SYNC_WRITE, bad), BAUD) == []
    bad = struct.pack('<BHH', 1, 65, 3) + b'\x01'
    assert bus.feed(encode_instruction(BROADCAST_ID, Instruction.BULK_WRITE, bad), BAUD) == []
    assert bus.feed(encode_instruction(BROADCAST_ID, Instruction.BULK_READ, b'\x01\x02'),
                    BAUD) == []
    assert bus.read_register(1, 'led') == 0
    # Sync/bulk sent to one id: instruction error
    replies = bus.feed(encode_instruction(1, Instruction.SYNC_READ,
                                          struct.pack('<HH', 7, 1) + b'\x01'), BAUD)
    assert [decode_packet(r.data).error for r in replies] == [2]


def test_drop_and_corrupt(rig: tuple) -> None:
    bus, port, sdk, _ = rig
    bus.set_drop(1, 1.0)
    assert sdk.ping(port, 1)[1] == COMM_RX_TIMEOUT
    assert sdk.write1ByteTxRx(port, 1, 65, 1)[0] == COMM_RX_TIMEOUT
    assert bus.read_register(1, 'led') == 1  # the write happened, its status was lost
    bus.set_drop(1, 0.0)
    bus.set_corrupt(2, 1.0)
    for _ in range(20):
        replies = bus.feed(encode_instruction(2, Instruction.PING), BAUD)
        assert len(replies) == 1
        with pytest.raises(ValueError):
            decode_packet(replies[0].data)
    assert sdk.ping(port, 2)[1] == COMM_RX_CORRUPT
    bus.set_corrupt(2, 0.0)
    assert sdk.ping(port, 2)[1] == COMM_SUCCESS


def test_drop_probability_is_seeded() -> None:
    def run() -> list[int]:
        bus = SimBus([1], clock=lambda: 0.0, seed=42)
        bus.set_drop(1, 0.5)
        return [len(bus.feed(encode_instruction(1, Instruction.PING), BAUD)) for _ in range(64)]
    first = run()
    assert first == run()
    assert 10 < sum(first) < 54


def test_unplug_plug_and_powercycle(rig: tuple) -> None:
    bus, port, sdk, clock = rig
    assert sdk.write1ByteTxRx(port, 3, 64, 1) == (COMM_SUCCESS, 0)
    assert sdk.write1ByteTxRx(port, 3, 65, 1) == (COMM_SUCCESS, 0)
    bus.unplug(3)
    assert sdk.ping(port, 3)[1] == COMM_RX_TIMEOUT
    assert 3 in bus.servo_ids()
    found, _ = sdk.broadcastPing(port)
    assert sorted(found) == [1, 2, 4]
    bus.plug(3)
    assert sdk.ping(port, 3)[1] == COMM_RX_TIMEOUT  # booting
    clock.now_s = 0.06
    assert sdk.ping(port, 3)[1] == COMM_SUCCESS
    assert (bus.read_register(3, 'torque_enable'), bus.read_register(3, 'led')) == (0, 0)
    assert sdk.write1ByteTxRx(port, 4, 65, 1) == (COMM_SUCCESS, 0)
    assert sdk.write1ByteTxRx(port, 4, 9, 7) == (COMM_SUCCESS, 0)
    bus.powercycle(4)
    clock.now_s = 0.2
    assert bus.read_register(4, 'led') == 0
    assert bus.read_register(4, 'return_delay_time') == 7  # EEPROM survives


def test_load_and_voltage_reach_the_dynamics(rig: tuple) -> None:
    bus, _, _, clock = rig
    bus.set_voltage(1, 11.1)
    bus.set_load(1, 0.5)
    assert bus.servo(1).dynamics.input_voltage_v == pytest.approx(11.1)
    assert bus.servo(1).dynamics.load_nm == pytest.approx(0.5)
    clock.now_s = 0.01
    assert bus.read_register(1, 'present_input_voltage') == 111


def test_bad_arguments_raise_value_error(rig: tuple) -> None:
    bus, _, _, _ = rig
    with pytest.raises(ValueError, match='no servo with id 8'):
        bus.set_drop(8, 0.1)
    with pytest.raises(ValueError, match='probability'):
        bus.set_corrupt(1, 1.5)
    with pytest.raises(ValueError):
        bus.set_voltage(1, -1.0)
    with pytest.raises(ValueError):
        bus.set_load(1, float('nan'))
    with pytest.raises(ValueError):
        bus.read_register(1, 'no_such_register')
    with pytest.raises(ValueError):
        SimBus([300])


def test_partial_packet_discarded_after_inter_byte_timeout(rig: tuple) -> None:
    bus, _, _, clock = rig
    packet = encode_instruction(1, Instruction.PING)
    assert bus.feed(packet[:5], BAUD) == []
    clock.now_s = 1.0
    assert bus.feed(packet[5:], BAUD) == []
    clock.now_s = 1.001
    assert bus.feed(packet[:5], BAUD) == []
    replies = bus.feed(packet[5:], BAUD)
    assert [type(r) for r in replies] == [Reply]


def test_two_packets_in_one_chunk_answer_in_order(rig: tuple) -> None:
    bus, _, _, _ = rig
    data = encode_instruction(4, Instruction.PING) + encode_instruction(2, Instruction.PING)
    assert [r.servo_id for r in bus.feed(data, BAUD)] == [4, 2]


def test_reply_crc_is_valid(rig: tuple) -> None:
    bus, _, _, _ = rig
    for reply in bus.feed(encode_instruction(BROADCAST_ID, Instruction.PING), BAUD):
        assert crc16(reply.data[:-2]) == reply.data[-2] | reply.data[-1] << 8


def test_sdk_stuffing_both_ways(rig: tuple) -> None:
    bus, port, sdk, _ = rig
    assert sdk.writeTxRx(port, 1, 224, 4, [0xFF, 0xFF, 0xFD, 0x00]) == (COMM_SUCCESS, 0)
    data, result, error = sdk.readTxRx(port, 1, 224, 4)
    assert (data, result, error) == ([0xFF, 0xFF, 0xFD, 0x00], COMM_SUCCESS, 0)
