"""
Fast Bulk Read (0x9A) and the pipelined bulk read: framing, the simulator's answer, the bus.

A Fast Bulk Read is answered as a Fast Sync Read is (one status packet from the broadcast id,
parts of error, id, data and the CRC of all bytes before it), each part of its own record's
length. The simulator's answer is held against the SDK's own reader (dynamixel_sdk's
GroupBulkRead.fastBulkRead) on a bus of models whose state blocks differ in place and length.
"""

import struct
import threading
import time
from typing import Callable, Dict, Iterator, List, Tuple

from dxl_servo_driver import protocol
from dxl_servo_driver.bus import Bus
from dxl_servo_driver.driver import clock
from dxl_servo_driver.driver import state_block
from dxl_servo_driver.errors import BadRequest, CommTimeout, CorruptReply
from dxl_servo_driver.models import model_for
from dxl_servo_driver.protocol.protocol1 import PROTOCOL_1
from dxl_servo_driver.sim.bus import SimBus
from dxl_servo_driver.sim.faulty_port import FaultyPort
from dxl_servo_driver.sim.port import SimPortHandler
from dxl_servo_driver.sim.virtual_bus import configure_servos
import dynamixel_sdk as sdk
import pytest

BAUD = 1_000_000
# XM430-W350, XL430-W250 (Present Load), XL330-M288 at firmware 53 (new indirect addresses) and
# at 52 (old: its block at 208, the others' at 224). Two read their tagged block, two the whole.
FIRMWARE = {1: 45, 2: 45, 3: 53, 4: 52}
MODELS = {1: model_for(1020), 2: model_for(1060), 3: model_for(1200, 53),
          4: model_for(1200, 52)}
BLOCKS = {servo_id: state_block.state_block(
    model, 'present_current' if model.has('present_current') else 'present_load')
    for servo_id, model in MODELS.items()}
IDS = tuple(MODELS)
RECORDS = [(servo_id, BLOCKS[servo_id].read_address,
            BLOCKS[servo_id].size if servo_id % 2 == 0 else BLOCKS[servo_id].tagged_size)
           for servo_id in IDS]
LENGTH = {servo_id: length for servo_id, _, length in RECORDS}
ID_ADDRESS = model_for(1020).item('id').address
TICK = {servo_id: block.index['realtime_tick'] for servo_id, block in BLOCKS.items()}


def fast_bulk_packet(records: List[Tuple[int, int, int]]) -> bytes:
    params = b''.join(struct.pack('<BHH', *record) for record in records)
    return protocol.encode_instruction(protocol.BROADCAST_ID,
                                       protocol.Instruction.FAST_BULK_READ, params)


def mixed_sim(**kwargs: object) -> SimBus:
    return SimBus(IDS, models=MODELS, firmware=FIRMWARE, **kwargs)  # type: ignore[arg-type]


def map_blocks(sim: SimBus, bus: Bus) -> None:
    for servo_id in sim.servo_ids():
        block = BLOCKS[servo_id]
        bus.write(servo_id, block.indirect_map_address(), block.indirect_map_bytes())


def make_bus(sim: SimBus, port: object = None) -> Bus:
    configure_servos(sim, BAUD, 0)
    raw = port if port is not None else SimPortHandler(sim, 'sim', BAUD)
    bus = Bus(raw, BAUD, latency_timer_s=0.001, return_delay_s=0.0)   # type: ignore[arg-type]
    map_blocks(sim, bus)
    return bus


def motion(sim: SimBus, servo_id: int) -> Tuple[int, ...]:
    regs = sim.registers(servo_id)
    return (regs['present_position'], regs['present_velocity'],
            regs[BLOCKS[servo_id].effort_register])


@pytest.fixture
def rig() -> Tuple[SimBus, Bus]:
    sim = mixed_sim()
    return sim, make_bus(sim)


# ------------------------------------------------------------------------------ framing
def parts_of(lengths: Tuple[int, ...]) -> List[Tuple[int, int, bytes]]:
    return [(index * 0x21 & 0xFF, 10 + index, bytes((0xFF, 0xFF, 0xFD, index) * 4)[:length])
            for index, length in enumerate(lengths)]


@pytest.mark.parametrize('lengths', [(4, 1, 12), (12, 10, 12, 12), (1,), (0, 3), (7, 7, 7)])
def test_parts_of_mixed_lengths_round_trip(lengths: Tuple[int, ...]) -> None:
    parts = parts_of(lengths)
    ids = tuple(servo_id for _, servo_id, _ in parts)
    packet = protocol.encode_fast_bulk_status(parts, lengths)
    assert len(packet) == protocol.fast_status_size(lengths)
    assert packet.startswith(protocol.fast_status_head(lengths))
    # Each part ends in the CRC of every byte before it, unstuffed; the last is the packet's.
    offset = protocol.FAST_HEAD_SIZE
    for error, servo_id, data in parts:
        end = offset + 2 + len(data)
        assert packet[offset:end] == bytes((error, servo_id)) + data
        assert struct.unpack_from('<H', packet, end)[0] == protocol.crc16(packet[:end])
        offset = end + 2
    assert protocol.decode_packet(packet).servo_id == protocol.BROADCAST_ID
    parsed, whole = protocol.parse_fast_status(b'noise' + packet, 5, ids, lengths)
    assert whole
    assert parsed == {servo_id: (error, data) for error, servo_id, data in parts}


def test_a_fast_sync_read_is_a_fast_bulk_read_of_equal_lengths() -> None:
    parts = parts_of((5, 5, 5))
    ids = tuple(servo_id for _, servo_id, _ in parts)
    packet = protocol.encode_fast_sync_status(parts, 3)
    assert packet == protocol.encode_fast_bulk_status(parts, (5, 5, 5))
    assert protocol.fast_sync_head(5, 3) == protocol.fast_status_head((5, 5, 5))
    assert (protocol.parse_fast_sync_status(packet, 0, ids, 5)
            == protocol.parse_fast_status(packet, 0, ids, (5, 5, 5)))


def test_a_bad_byte_loses_its_part_and_every_part_after_it() -> None:
    lengths = (3, 9, 1, 6)
    parts = parts_of(lengths)
    ids = tuple(servo_id for _, servo_id, _ in parts)
    packet = protocol.encode_fast_bulk_status(parts, lengths)
    ends = []
    offset = protocol.FAST_HEAD_SIZE
    for length in lengths:
        offset += length + protocol.FAST_PART_OVERHEAD
        ends.append(offset)
    for position in range(protocol.FAST_HEAD_SIZE, len(packet)):
        broken = bytearray(packet)
        broken[position] ^= 0x10
        parsed, whole = protocol.parse_fast_status(broken, 0, ids, lengths)
        kept = sum(end <= position for end in ends)
        assert not whole
        assert list(parsed) == list(ids[:kept]), position


def test_a_part_out_of_order_of_another_id_or_length_is_not_taken() -> None:
    lengths = (2, 4, 3)
    ids = (1, 2, 3)
    one, two, three = (0, 1, b'\x01' * 2), (0, 2, b'\x02' * 4), (0, 3, b'\x03' * 3)
    cases = [
        ([two, one, three], {2: (0, two[2])}),         # 1 after 2: no part of 1 can follow
        ([one, (0, 9, b'\x09' * 4), three], {1: (0, one[2])}),   # 9 was not asked
        ([one, (0, 2, b'\x02' * 3), three], {1: (0, one[2])}),   # 2 of another length
        ([one, three], {1: (0, one[2]), 3: (0, three[2])}),      # 2 silent: its part missing
    ]
    for parts, expected in cases:
        packet = protocol.encode_fast_status(parts, lengths)
        assert protocol.parse_fast_status(packet, 0, ids, lengths) == (expected, False)
    # The status of another request (other lengths) is refused whole, by its head.
    other = protocol.encode_fast_status([one, two, three], (2, 4, 4))
    assert protocol.parse_fast_status(other, 0, ids, lengths) == ({}, False)


# --------------------------------------------------------------------------- simulator
class FrozenClock:
    """A clock that moves only when told: the registers hold still between two reads."""

    def __init__(self) -> None:
        self.now_s = 50.0

    def __call__(self) -> float:
        return self.now_s


def frozen_rig() -> Tuple[SimBus, SimPortHandler]:
    sim = mixed_sim(clock=FrozenClock(), boot_time_s=0.0)
    port = SimPortHandler(sim, 'sim', BAUD)
    configure_servos(sim, BAUD, 0)
    bus = Bus(port, BAUD, latency_timer_s=0.001, return_delay_s=0.0)
    map_blocks(sim, bus)
    return sim, port


def expected_parts(sim: SimBus, records: List[Tuple[int, int, int]]
                   ) -> List[Tuple[int, int, bytes]]:
    return [(0, servo_id, sim.servo(servo_id).memory.read(address, length))
            for servo_id, address, length in records]


def test_the_sim_answers_byte_for_byte_what_the_sdk_reads() -> None:
    sim, port = frozen_rig()
    records = RECORDS
    lengths = tuple(length for _, _, length in records)
    # The SDK's request, as it goes out, is ours.
    written: List[bytes] = []
    write = port.writePort

    def tap(packet: object) -> int:
        written.append(bytes(packet))   # type: ignore[call-overload]
        return write(packet)   # type: ignore[arg-type]

    port.writePort = tap   # type: ignore[method-assign]
    handler = sdk.PacketHandler(2.0)
    reader = sdk.GroupBulkRead(port, handler)
    for servo_id, address, length in records:
        assert reader.addParam(servo_id, address, length)
    assert reader.fastBulkRead() == sdk.COMM_SUCCESS
    assert written == [fast_bulk_packet(records)]
    # The one status packet, byte for byte, and what the SDK made of it.
    parts = expected_parts(sim, records)
    reply = sim.feed(fast_bulk_packet(records), BAUD)
    assert [r.data for r in reply] == [protocol.encode_fast_bulk_status(parts, lengths)]
    for _, servo_id, data in parts:
        assert bytes(reader.data_dict[servo_id][0]) == data
    block = BLOCKS[3]
    position = block.index['present_position']
    assert (block.decode_tagged(parts[2][2])[position]
            == sim.read_register(3, 'present_position'))
    # Our parse agrees.
    parsed, whole = protocol.parse_fast_status(reply[0].data, 0, IDS, lengths)
    assert whole and parsed == {servo_id: (0, data) for _, servo_id, data in parts}


def test_each_servo_reads_its_own_record_in_record_order() -> None:
    sim, _ = frozen_rig()
    records = [(4, 0, 2), (2, BLOCKS[2].read_address, BLOCKS[2].tagged_size), (3, ID_ADDRESS, 1)]
    lengths = (2, BLOCKS[2].tagged_size, 1)
    [reply] = sim.feed(fast_bulk_packet(records), BAUD)
    parsed, whole = protocol.parse_fast_status(reply.data, 0, (4, 2, 3), lengths)
    assert whole
    assert parsed[4] == (0, struct.pack('<H', 1200)) and parsed[3] == (0, b'\x03')
    assert parsed[2][1] == sim.servo(2).memory.read(BLOCKS[2].read_address, lengths[1])


@pytest.mark.parametrize('number, firmware, answers', [
    (1030, 45, True), (1030, 44, False), (1200, 46, True), (1200, 45, False),
    (1090, 99, False),   # 2XL430: no Fast Sync Read, so no Fast Bulk Read
])
def test_only_firmware_with_fast_sync_read_answers(
        number: int, firmware: int, answers: bool) -> None:
    sim = SimBus([1, 2], models={1: model_for(number, firmware)}, firmware={1: firmware})
    replies = sim.feed(fast_bulk_packet([(1, 0, 2), (2, 0, 2)]), sim.servo(1).baud_bps)
    parsed, whole = protocol.parse_fast_status(replies[0].data, 0, (1, 2), (2, 2))
    # One without it is silent (an unknown broadcast instruction): its part is missing.
    assert sorted(parsed) == ([1, 2] if answers else [2])
    assert whole is answers


def test_sent_to_one_id_it_is_an_instruction_error() -> None:
    sim = SimBus([1, 2])
    params = struct.pack('<BHH', 1, 0, 2) + struct.pack('<BHH', 2, 0, 2)
    packet = protocol.encode_instruction(1, protocol.Instruction.FAST_BULK_READ, params)
    replies = sim.feed(packet, sim.servo(1).baud_bps)
    assert [protocol.decode_packet(reply.data) for reply in replies] == [
        protocol.Packet(1, protocol.Instruction.STATUS, b'', protocol.ErrorCode.INSTRUCTION)]


def test_a_refused_record_keeps_its_place_with_its_error() -> None:
    sim = SimBus([1, 2])
    [reply] = sim.feed(fast_bulk_packet([(1, 4096, 3), (2, 0, 2)]), sim.servo(1).baud_bps)
    parsed, whole = protocol.parse_fast_status(reply.data, 0, (1, 2), (3, 2))
    assert whole
    assert parsed == {1: (protocol.ErrorCode.ACCESS, bytes(3)), 2: (0, struct.pack('<H', 1030))}


# --------------------------------------------------------------------------------- bus
@pytest.mark.parametrize('fast', [True, False], ids=['fast', 'bulk'])
def test_a_clean_bulk_read_of_mixed_blocks(rig: Tuple[SimBus, Bus], fast: bool) -> None:
    sim, bus = rig
    sim.inject_error(2, 'encoder')
    result = bus.begin_bulk_read(RECORDS, fast).collect()
    assert result.clean is fast   # the alert bit takes a bulk read off the clean path
    for servo_id in IDS:
        data = result.data[servo_id]
        assert isinstance(data, bytes) and len(data) == LENGTH[servo_id]
        assert BLOCKS[servo_id].decode_motion(data[:BLOCKS[servo_id].motion_size]) == motion(
            sim, servo_id)
    assert result.alerts == {1: False, 2: True, 3: False, 4: False}
    assert bus.counters.timeouts == bus.counters.corrupt == bus.counters.stale == 0
    sim.inject_error(2, 'encoder')
    sim.powercycle(2)
    assert bus.begin_bulk_read(RECORDS, fast).collect().clean is False   # 2 is booting


def test_a_clean_plain_bulk_read_takes_the_fast_path(rig: Tuple[SimBus, Bus]) -> None:
    _, bus = rig
    result = bus.bulk_read(RECORDS)
    assert result.clean and all(isinstance(data, bytes) for data in result.data.values())


def test_a_corrupted_part_loses_it_and_those_after_it(rig: Tuple[SimBus, Bus]) -> None:
    sim, bus = rig
    sim.set_corrupt(2, 1.0)
    data = bus.begin_bulk_read(RECORDS, fast=True).collect().data
    assert isinstance(data[1], bytes)
    assert all(isinstance(data[servo_id], CorruptReply) for servo_id in (2, 3, 4))
    assert bus.dirty


def test_a_dropped_part_loses_only_its_own(rig: Tuple[SimBus, Bus]) -> None:
    sim, bus = rig
    sim.set_drop(3, 1.0)
    data = bus.begin_bulk_read(RECORDS, fast=True).collect().data
    assert isinstance(data[3], CommTimeout)
    for servo_id in (1, 2, 4):
        block = BLOCKS[servo_id]
        assert block.decode_motion(data[servo_id][:block.motion_size]) == motion(  # type: ignore
            sim, servo_id)


def test_a_pipelined_read_holds_the_bus_until_collected(rig: Tuple[SimBus, Bus]) -> None:
    sim, bus = rig
    pending = bus.begin_bulk_read(RECORDS, fast=True)
    # Meanwhile (the cycle publishes): the answer is there, and nobody else has the bus.
    size = protocol.fast_status_size(tuple(length for _, _, length in RECORDS))
    assert bus.port.in_waiting == size
    taken: List[bool] = []
    other = threading.Thread(target=lambda: taken.append(bus.lock.acquire(timeout=0.05)))
    other.start()
    other.join()
    assert taken == [False]
    result = pending.collect()
    assert result.clean and all(isinstance(data, bytes) for data in result.data.values())
    with pytest.raises(RuntimeError):
        pending.collect()

    def take_and_give() -> None:
        taken.append(bus.lock.acquire(timeout=1.0))
        bus.lock.release()

    other = threading.Thread(target=take_and_give)
    other.start()
    other.join()
    assert taken == [False, True]


def test_an_aborted_read_leaves_nothing_behind() -> None:
    sim = mixed_sim()
    bus = make_bus(sim)
    pending = bus.begin_bulk_read(RECORDS, fast=True)
    pending.abort()
    pending.abort()   # idempotent
    assert bus.port.in_waiting == 0
    assert bus.begin_bulk_read(RECORDS, fast=True).collect().clean


def test_bad_requests_are_refused(rig: Tuple[SimBus, Bus]) -> None:
    _, bus = rig
    with pytest.raises(BadRequest):
        bus.begin_bulk_read([(1, 0, 2), (1, 7, 1)])
    with pytest.raises(BadRequest):
        bus.begin_bulk_read([], fast=True)
    with pytest.raises(BadRequest):
        bus.begin_bulk_read([(1, 0, 2)], fast=True, framer=PROTOCOL_1)
    bus.speak(2, PROTOCOL_1)
    with pytest.raises(BadRequest):
        bus.begin_bulk_read([(1, 0, 2), (2, 0, 2)])
    assert bus.lock.acquire(blocking=False)   # no refusal kept the bus
    bus.lock.release()


# ------------------------------------------------------------ scripted replies on the wire
class ScriptedPort:
    """A port whose replies a test writes: answer(packet) is what comes back to a request."""

    def __init__(self, answer: Callable[[bytes], bytes]) -> None:
        self.answer = answer
        self.baudrate = BAUD
        self.rx = bytearray()
        self.sent: List[bytes] = []

    @property
    def in_waiting(self) -> int:
        return len(self.rx)

    def write(self, data: bytes) -> int:
        self.sent.append(bytes(data))
        self.rx += self.answer(bytes(data))
        return len(data)

    def read(self, size: int, timeout_s: float) -> bytes:
        data = bytes(self.rx[:size])
        del self.rx[:size]
        return data

    def reset_input_buffer(self) -> None:
        self.rx.clear()

    def close(self) -> None:
        pass


LENGTHS = (3, 5, 2)
SCRIPTED = [(1, 100, 3), (2, 200, 5), (3, 50, 2)]
FRESH = [(0, 1, b'new'), (0, 2, b'fresh'), (0, 3, b'ok')]
STALE = [(0, 1, b'old'), (0, 2, b'stale'), (0, 3, b'no')]


def scripted(reply: bytes) -> Tuple[Bus, ScriptedPort]:
    port = ScriptedPort(lambda packet: reply if packet == fast_bulk_packet(SCRIPTED) else b'')
    return Bus(port, BAUD, latency_timer_s=0.0, return_delay_s=0.0), port  # type: ignore


def status(parts: List[Tuple[int, int, bytes]], lengths: Tuple[int, ...] = LENGTHS) -> bytes:
    return protocol.encode_fast_status(parts, lengths)


def read_scripted(reply: bytes, linger: bool = False) -> Dict[int, object]:
    bus, _ = scripted(reply)
    return dict(bus.begin_bulk_read(SCRIPTED, fast=True, linger=linger).collect().data)


def test_a_late_whole_status_of_the_same_request_is_outlived_by_lingering() -> None:
    """
    A whole earlier status of this very request, first in line, looks like the answer.

    Nothing on the wire tells them apart (no sequence number): read alone it is taken (the
    Realtime Tick the cycle reads refuses it), the answer behind it makes the bus suspicious
    at the next request, and a read that lingers takes the last whole status: the answer.
    """
    bus, port = scripted(status(STALE) + status(FRESH))
    data = bus.begin_bulk_read(SCRIPTED, fast=True).collect().data
    assert data == {servo_id: payload for _, servo_id, payload in STALE}
    assert not bus.dirty and port.in_waiting == len(status(FRESH))
    data = bus.begin_bulk_read(SCRIPTED, fast=True, linger=bus.dirty).collect().data
    assert bus.dirty and bus.counters.flushed_bytes == len(status(FRESH))
    data = bus.begin_bulk_read(SCRIPTED, fast=True, linger=bus.dirty).collect().data
    assert data == {servo_id: payload for _, servo_id, payload in FRESH}
    assert port.in_waiting == 0


def test_a_status_of_another_request_is_refused() -> None:
    # Same ids, other lengths (a Fast Sync Read of 3 bytes each, say): not one part taken.
    other = status([(0, 1, b'abc'), (0, 2, b'def'), (0, 3, b'ghi')], (3, 3, 3))
    data = read_scripted(other)
    assert all(isinstance(value, CommTimeout) for value in data.values())
    # Ahead of the answer, it costs nothing.
    data = read_scripted(other + status(FRESH))
    assert data == {servo_id: payload for _, servo_id, payload in FRESH}


def test_a_truncated_status_gives_the_parts_it_holds() -> None:
    whole = status(FRESH)
    cut = protocol.FAST_HEAD_SIZE + 3 + 4 + 5 + 4 + 1
    data = read_scripted(whole[:cut])
    assert data[1] == b'new' and data[2] == b'fresh'
    assert isinstance(data[3], CommTimeout)


def test_parts_out_of_order_or_of_another_id_are_refused() -> None:
    data = read_scripted(status([FRESH[1], FRESH[0], FRESH[2]]))
    assert data[2] == b'fresh'
    assert isinstance(data[1], CorruptReply) and isinstance(data[3], CorruptReply)
    data = read_scripted(status([FRESH[0], (0, 7, b'fresh'), FRESH[2]]))
    assert data[1] == b'new'
    assert not isinstance(data[2], bytes) and not isinstance(data[3], bytes)


def test_noise_around_the_status_is_skipped() -> None:
    data = read_scripted(b'\xff\xff\xfd\x00\xfe\x30' + b'\x00\x13' + status(FRESH) + b'\xff')
    assert data == {servo_id: payload for _, servo_id, payload in FRESH}


# ------------------------------------------------------------ a misbehaving adapter
@pytest.fixture
def faulty() -> Iterator[Tuple[SimBus, FaultyPort, Bus]]:
    sim = mixed_sim(seed=11)
    port = FaultyPort(SimPortHandler(sim, 'sim', BAUD), seed=5)
    bus = make_bus(sim, port)
    yield sim, port, bus
    port.close()


OTHER = [(servo_id, ID_ADDRESS, 1) for servo_id in IDS]   # another request: each servo's id


@pytest.mark.parametrize('faults', [
    {'echo': True},
    {'late_probability': 0.3, 'late_ms': (1.0, 30.0)},
    {'duplicate_probability': 0.5},
    {'noise_probability': 0.5},
    {'truncate_probability': 0.3},
    {'drop_probability': 0.2},
    {'echo': True, 'late_probability': 0.2, 'late_ms': (1.0, 30.0),
     'duplicate_probability': 0.3, 'noise_probability': 0.3, 'truncate_probability': 0.2},
], ids=['echo', 'late', 'duplicated', 'noise', 'truncated', 'dropped', 'everything'])
def test_a_misbehaving_adapter_never_yields_a_stale_or_foreign_part(
        faulty: Tuple[SimBus, FaultyPort, Bus], faults: Dict[str, object]) -> None:
    """
    Two requests alternate: no part of the other, nor one older than its request, is taken.

    A late copy of an earlier status of the same request that arrives alone in the answer's
    place is a whole, valid packet: the Realtime Tick the cycle reads is what refuses it.
    """
    sim, port, bus = faulty
    sim.set_drop(4, 0.2)   # and a servo whose part goes missing now and then
    port.set(**faults)
    clocks = {servo_id: clock.TickClock() for servo_id in IDS}
    seen: Dict[int, set] = {servo_id: set() for servo_id in IDS}
    taken = refused = 0
    for round_ in range(100):
        if round_ % 3 == 2:
            result = bus.begin_bulk_read(OTHER, fast=True).collect()
            for servo_id, data in result.data.items():
                assert not isinstance(data, bytes) or data == bytes((servo_id,)), (faults, data)
            continue
        result = bus.begin_bulk_read(RECORDS, fast=True, linger=bus.dirty).collect()
        received_s = time.monotonic()
        for servo_id, data in result.data.items():
            if not isinstance(data, bytes):
                continue
            assert len(data) == LENGTH[servo_id]
            tick = BLOCKS[servo_id].decode_tagged(data)[TICK[servo_id]]
            if not clocks[servo_id].check(tick, result.sent_s, received_s):
                refused += 1
                continue
            assert tick not in seen[servo_id], (faults, servo_id, tick)
            seen[servo_id].add(tick)
            taken += 1
        # The next request goes out after the servos' millisecond tick has moved on: counted
        # from when this one was answered (it went out before that), not from before it was
        # sent (a test thread held up before the write would send the next one too soon).
        while time.monotonic() < received_s + 0.0015:
            time.sleep(0.0002)
    assert taken >= 100   # most reads still serve the joints
    assert sum(port.stats.as_dict().values()) > 0   # the faults did happen
    if faults.get('echo'):
        assert bus.echo and bus.counters.echoes > 0
