"""Fast Sync Read (0x8A): its framing, the simulated servos' answer, and the bus reading it."""

import struct
import time
from typing import Dict, Iterator, List, Tuple

from dxl_servo_driver import protocol
from dxl_servo_driver.bus import Bus
from dxl_servo_driver.config import DriverConfig, validate
from dxl_servo_driver.driver import clock
from dxl_servo_driver.driver import state_block
from dxl_servo_driver.driver.cycle import FAST_EMPTY_LIMIT
from dxl_servo_driver.driver.manager import Manager
from dxl_servo_driver.driver.transports import SimTransport
from dxl_servo_driver.errors import CommTimeout, CorruptReply
from dxl_servo_driver.models import model_for
from dxl_servo_driver.sim import servo as sim_servo
from dxl_servo_driver.sim.bus import SimBus
from dxl_servo_driver.sim.faulty_port import FaultyPort
from dxl_servo_driver.sim.port import SimPortHandler
from dxl_servo_driver.sim.virtual_bus import configure_servos
from fake_clock import FakeClock
from manager_rig import BAUD as RIG_BAUD, cycle_read, params, Rig, TapPort
import pytest

BAUD = 1_000_000
BLOCK = state_block.state_block(model_for(1030), 'present_current')
IDS = (1, 2, 3)
TICK = BLOCK.index['realtime_tick']


def fast_read_packet(address: int, length: int, ids: Tuple[int, ...]) -> bytes:
    params = struct.pack('<HH', address, length) + bytes(ids)
    return protocol.encode_instruction(protocol.BROADCAST_ID, protocol.Instruction.FAST_SYNC_READ,
                                       params)


def motion(sim: SimBus, servo_id: int) -> Tuple[int, ...]:
    regs = sim.registers(servo_id)
    return (regs['present_position'], regs['present_velocity'], regs['present_current'])


def make_bus(sim: SimBus, port: object = None) -> Bus:
    configure_servos(sim, BAUD, 0)
    raw = port if port is not None else SimPortHandler(sim, 'sim', BAUD)
    bus = Bus(raw, BAUD, latency_timer_s=0.001, return_delay_s=0.0)   # type: ignore[arg-type]
    for servo_id in sim.servo_ids():
        bus.write(servo_id, BLOCK.indirect_map_address(), BLOCK.indirect_map_bytes())
    return bus


@pytest.fixture
def rig() -> Tuple[SimBus, Bus]:
    sim = SimBus(IDS)
    return sim, make_bus(sim)


# ------------------------------------------------------------------------------ framing
def test_each_part_carries_the_crc_of_every_byte_before_it() -> None:
    parts = [(0, 1, b'\x01\x02\x03'), (0x80, 7, b'\xff\xff\xfd'), (4, 9, b'\x00\x00\x00')]
    packet = protocol.encode_fast_sync_status(parts, 3)
    assert len(packet) == protocol.fast_sync_size(3, 3)
    assert packet.startswith(protocol.fast_sync_head(3, 3))
    # Every part: error, id, data, then the CRC of the packet so far, unstuffed.
    offset = protocol.FAST_HEAD_SIZE
    for error, servo_id, data in parts:
        end = offset + 2 + len(data)
        assert packet[offset:end] == bytes((error, servo_id)) + data
        assert struct.unpack_from('<H', packet, end)[0] == protocol.crc16(packet[:end])
        offset = end + 2
    # So the whole is an ordinary packet too: its length field and last CRC check.
    assert protocol.decode_packet(packet).servo_id == protocol.BROADCAST_ID
    parsed, whole = protocol.parse_fast_sync_status(packet, 0, (1, 7, 9), 3)
    assert whole
    assert parsed == {sid: (error, data) for error, sid, data in parts}


def test_a_bad_byte_loses_its_part_and_every_part_after_it() -> None:
    parts = [(0, servo_id, bytes(range(servo_id, servo_id + 4))) for servo_id in (1, 2, 3)]
    packet = protocol.encode_fast_sync_status(parts, 3)
    part_size = 4 + protocol.FAST_PART_OVERHEAD
    for position in range(protocol.FAST_HEAD_SIZE, len(packet)):
        broken = bytearray(packet)
        broken[position] ^= 0x10
        parsed, whole = protocol.parse_fast_sync_status(broken, 0, (1, 2, 3), 4)
        kept = (position - protocol.FAST_HEAD_SIZE) // part_size
        assert not whole
        assert sorted(parsed) == [1, 2, 3][:kept], position


def test_parts_out_of_order_or_not_asked_are_not_taken() -> None:
    # Id 1 after id 2: id 1's part is missing (silent), the second part cannot be id 1's.
    packet = protocol.encode_fast_sync_status([(0, 2, b'\x00'), (0, 1, b'\x00')], 2)
    assert protocol.parse_fast_sync_status(packet, 0, (1, 2), 1) == ({2: (0, b'\x00')}, False)
    packet = protocol.encode_fast_sync_status([(0, 1, b'\x00'), (0, 5, b'\x00')], 2)
    assert protocol.parse_fast_sync_status(packet, 0, (1, 2), 1) == ({1: (0, b'\x00')}, False)


# --------------------------------------------------------------------------- simulator
@pytest.mark.parametrize('number, firmware, answers', [
    (1030, 45, True), (1030, 44, False), (1060, 45, True), (1060, 44, False),
    (1200, 46, True), (1200, 45, False), (1090, 99, False),   # 2XL430: never
])
def test_only_firmware_that_has_it_answers(number: int, firmware: int, answers: bool) -> None:
    sim = SimBus([1], models={1: model_for(number, firmware)}, firmware={1: firmware})
    packet = fast_read_packet(132, 4, (1,))
    replies = sim.feed(packet, sim.servo(1).baud_bps)
    assert bool(replies) is answers
    if answers:
        parsed, whole = protocol.parse_fast_sync_status(replies[0].data, 0, (1,), 4)
        assert whole
        assert struct.unpack('<i', parsed[1][1])[0] == sim.read_register(1, 'present_position')


def test_sent_to_one_id_it_is_an_instruction_error() -> None:
    sim = SimBus([1, 2])
    params = struct.pack('<HH', 132, 4) + bytes((1, 2))
    packet = protocol.encode_instruction(1, protocol.Instruction.FAST_SYNC_READ, params)
    replies = sim.feed(packet, sim.servo(1).baud_bps)
    assert [protocol.decode_packet(reply.data) for reply in replies] == [
        protocol.Packet(1, protocol.Instruction.STATUS, b'', protocol.ErrorCode.INSTRUCTION)]


def test_a_read_the_table_refuses_keeps_its_place_with_its_error() -> None:
    sim = SimBus([1, 2])
    packet = fast_read_packet(4096, 4, (1, 2))   # beyond every table
    parsed, whole = protocol.parse_fast_sync_status(
        sim.feed(packet, sim.servo(1).baud_bps)[0].data, 0, (1, 2), 4)
    assert whole
    assert parsed == {1: (protocol.ErrorCode.ACCESS, bytes(4)),
                      2: (protocol.ErrorCode.ACCESS, bytes(4))}


# --------------------------------------------------------------------------------- bus
def test_a_clean_fast_read_is_decoded(rig: Tuple[SimBus, Bus]) -> None:
    sim, bus = rig
    sim.inject_error(2, 'encoder')
    result = bus.sync_read(BLOCK.read_address, BLOCK.motion_size, IDS, fast=True)
    assert result.clean
    for servo_id in IDS:
        assert BLOCK.decode_motion(result.data[servo_id]) == motion(sim, servo_id)
    assert result.alerts == {1: False, 2: True, 3: False}
    assert bus.counters.timeouts == bus.counters.corrupt == bus.counters.stale == 0


def test_a_corrupted_part_loses_it_and_those_after_it(rig: Tuple[SimBus, Bus]) -> None:
    sim, bus = rig
    sim.set_corrupt(2, 1.0)
    data = bus.sync_read(BLOCK.read_address, BLOCK.motion_size, IDS, fast=True).data
    assert BLOCK.decode_motion(data[1]) == motion(sim, 1)   # type: ignore[arg-type]
    assert isinstance(data[2], CorruptReply) and isinstance(data[3], CorruptReply)
    assert bus.dirty


def test_a_silent_servo_loses_only_its_own_part(rig: Tuple[SimBus, Bus]) -> None:
    sim, bus = rig
    sim.set_drop(2, 1.0)
    data = bus.sync_read(BLOCK.read_address, BLOCK.motion_size, IDS, fast=True).data
    assert isinstance(data[2], CommTimeout)
    for servo_id in (1, 3):
        assert BLOCK.decode_motion(data[servo_id]) == motion(sim, servo_id)  # type: ignore
    sim.set_drop(1, 1.0)
    data = bus.sync_read(BLOCK.read_address, BLOCK.motion_size, IDS, fast=True).data
    assert isinstance(data[1], CommTimeout) and isinstance(data[2], CommTimeout)
    assert BLOCK.decode_motion(data[3]) == motion(sim, 3)   # type: ignore[arg-type]


@pytest.fixture
def faulty() -> Iterator[Tuple[SimBus, FaultyPort, Bus]]:
    sim = SimBus(IDS, seed=11)
    port = FaultyPort(SimPortHandler(sim, 'sim', BAUD), seed=5)
    bus = make_bus(sim, port)
    yield sim, port, bus
    port.close()


@pytest.mark.parametrize('faults', [
    {'echo': True},
    {'late_probability': 0.3, 'late_ms': (1.0, 30.0)},
    {'duplicate_probability': 0.5},
    {'noise_probability': 0.5},
    {'truncate_probability': 0.3},
    {'echo': True, 'late_probability': 0.2, 'late_ms': (1.0, 30.0),
     'duplicate_probability': 0.3, 'noise_probability': 0.3, 'truncate_probability': 0.2},
], ids=['echo', 'late', 'duplicated', 'noise', 'truncated', 'everything'])
def test_a_misbehaving_adapter_never_yields_a_stale_part(
        faulty: Tuple[SimBus, FaultyPort, Bus], faults: Dict[str, object]) -> None:
    """
    No part older than its request gets through the bus and the tick check the cycle makes.

    A late copy of an earlier fast reply that arrives alone in the answer's place is a whole,
    valid packet; the Realtime Tick (always read with fast reads) is what refuses it.
    """
    sim, port, bus = faulty
    port.set(**faults)
    clocks = {servo_id: clock.TickClock() for servo_id in IDS}
    seen: Dict[int, set] = {servo_id: set() for servo_id in IDS}
    taken = refused = 0
    for _ in range(80):
        result = bus.sync_read(BLOCK.read_address, BLOCK.tagged_size, IDS, fast=True)
        received_s = time.monotonic()
        for servo_id, data in result.data.items():
            if not isinstance(data, bytes):
                continue
            tick = BLOCK.decode_tagged(data)[TICK]
            if not clocks[servo_id].check(tick, result.sent_s, received_s):
                refused += 1
                continue
            assert tick not in seen[servo_id], (faults, servo_id, tick)
            seen[servo_id].add(tick)
            taken += 1
        # The next request goes out after the servos' millisecond tick has moved on: counted
        # from when this one was answered (it went out before that), not from before it was
        # sent (a test thread held up before the write would send the next one too soon).
        time.sleep(max(0.0, received_s + 0.0015 - time.monotonic()))
    assert taken >= 80   # most reads still serve the joints
    assert sum(port.stats.as_dict().values()) > 0   # the faults did happen
    if faults.get('echo'):
        assert bus.echo and bus.counters.echoes > 0


# ------------------------------------------------------------------- the driver's read_mode
def manager_rig(firmware: Dict[int, int],
                monkeypatch: pytest.MonkeyPatch) -> Tuple[Rig, FakeClock]:
    """
    Return the manager tests' rig on servos of these firmwares, and the clock it runs on.

    The test's own clock (fake_clock): whether a one-off retry fits in its cycle's budget
    (cycles(): 10 ms) is the code's to decide, not a busy machine's.
    """
    rig = Rig()
    clock = FakeClock().install(monkeypatch)
    rig.sim = SimBus((1, 2, 3), boot_time_s=0.02, firmware=firmware, clock=clock.monotonic)
    configure_servos(rig.sim, RIG_BAUD, None)

    def port() -> SimPortHandler:
        # Wire-timed: a read of what is not coming waits to its deadline on this clock (an
        # instant port answers it at once, and a loop waiting for the clock would spin).
        return clock.port(rig.sim, RIG_BAUD)
    rig.tap = TapPort(port())

    def open_port(_config: DriverConfig) -> SimTransport:
        def reopen() -> TapPort:
            rig.tap.port = port()   # as Rig.open_port: a new port on the same servos, same tap
            return rig.tap
        return SimTransport(rig.sim, reopen)
    rig.open_port = open_port   # type: ignore[method-assign]
    return rig, clock


def fast_reads(rig: Rig) -> int:
    return sum(p.instruction == protocol.Instruction.FAST_SYNC_READ for p in rig.tap.packets)


def cycles(manager: Manager, count: int) -> List[Dict[str, bool]]:
    fresh = []
    for _ in range(count):
        cycle_read(manager, retry_until=time.monotonic() + 0.01)
        manager.cycle_write(tasks_until=time.monotonic())
        fresh.append({servo.name: servo.fresh for servo in manager.order})
        time.sleep(0.002)
    return fresh


@pytest.mark.parametrize('read_mode, firmware, expected', [
    ('auto', {}, 'fast_sync'),                # every servo's firmware has it (45)
    ('auto', {2: 44}, 'sync'),                # one servo's does not
    ('sync', {}, 'sync'),
    ('fast_sync', {}, 'fast_sync'),
])
def test_read_mode_chooses_the_read_by_firmware(read_mode: str, firmware: Dict[int, int],
                                                expected: str,
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    rig, clock = manager_rig(firmware, monkeypatch)
    manager = rig.manager(validate(params(read_mode=read_mode)), clock=clock.monotonic)
    manager.configure()
    manager.activate()
    try:
        assert manager.read_mode_in_use == expected
        before = fast_reads(rig)
        fresh = cycles(manager, 10)
        assert all(all(cycle.values()) for cycle in fresh[1:]), fresh
        assert (fast_reads(rig) - before >= 10) is (expected == 'fast_sync')
        # Every joint's state is the servo's own.
        for servo in manager.order:
            assert servo.state is not None
            assert abs(servo.state[0] - rig.reg(servo.servo_id, 'present_position')) <= 2
        budget = manager.bus_budget()
        sync_budget = state_block.bus_budget(3, RIG_BAUD, 0, 0.001)
        assert (budget.bytes_per_cycle < sync_budget.bytes_per_cycle) is (expected == 'fast_sync')
    finally:
        manager.close()


def test_auto_gives_fast_up_when_it_brings_nothing_back_but_servos_answer(
        monkeypatch: pytest.MonkeyPatch) -> None:
    # Servos whose firmware says 45 but that ignore 0x8A (an adapter or firmware that
    # does not do it): each fast read is silent, each servo answers its one-off retry.
    monkeypatch.setitem(sim_servo._HANDLERS, protocol.Instruction.FAST_SYNC_READ,
                        lambda *args: None)
    rig, clock = manager_rig({}, monkeypatch)
    manager = rig.manager(validate(params(read_mode='auto')), clock=clock.monotonic)
    manager.configure()
    manager.activate()
    try:
        assert manager.read_mode_in_use == 'fast_sync'
        fresh = cycles(manager, 6)
        assert manager.read_mode_in_use == 'sync'
        assert fast_reads(rig) == FAST_EMPTY_LIMIT
        assert any('sync reads from now on' in line for line in rig.logs)
        # The retries served every joint meanwhile; sync reads do now, without retries.
        assert all(all(cycle.values()) for cycle in fresh[1:]), fresh
        retries = manager.stats.retries
        cycles(manager, 5)
        assert manager.stats.retries == retries
    finally:
        manager.close()


def test_forced_fast_sync_keeps_serving_a_servo_that_does_not_answer_it(
        monkeypatch: pytest.MonkeyPatch) -> None:
    # read_mode fast_sync on a servo without it: never given up (the user asked), the servo
    # is read by its one-off retry every cycle, the others by the fast read.
    rig, clock = manager_rig({2: 44}, monkeypatch)
    manager = rig.manager(validate(params(read_mode='fast_sync')), clock=clock.monotonic)
    manager.configure()
    manager.activate()
    try:
        fresh = cycles(manager, 8)
        assert manager.read_mode_in_use == 'fast_sync'
        assert all(all(cycle.values()) for cycle in fresh[1:]), fresh
        assert manager.stats.retries >= 7
    finally:
        manager.close()


def test_the_simulated_tick_is_current_while_the_physics_lags() -> None:
    # virtual_bus lets a servo's physics lag a few ms behind a busy bus; its Realtime Tick must
    # not lag with it, or a driver dating samples by it refuses them as late replies.
    now = [10.0]
    sim = SimBus([1], clock=lambda: now[0], boot_time_s=0.0)
    sim.physics_lag_s = 0.004
    now[0] += 0.0005   # mid-millisecond: no rounding at the tick's edges
    tick = model_for(1030).item('realtime_tick')
    packet = protocol.encode_instruction(1, protocol.Instruction.READ,
                                         struct.pack('<HH', tick.address, tick.size))
    ticks = []
    for _ in range(6):
        reply = protocol.decode_packet(sim.feed(packet, sim.servo(1).baud_bps)[0].data)
        ticks.append(struct.unpack('<H', reply.params)[0])
        now[0] += 0.001
    assert [value - ticks[0] for value in ticks] == [0, 1, 2, 3, 4, 5]


@pytest.mark.parametrize('fast', [True, False], ids=['fast', 'sync'])
def test_a_lingering_read_puts_request_and_answer_back_in_step(
        fast: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    """
    An answer late past its deadline is taken by the next read; lingering ends that.

    The late answer arrives after the next request flushed the input, in place of the answer
    still on its way, and the next request would then take that one: a chain of answers one
    behind. A read that lingers to its deadline takes the last one and leaves nothing behind.
    On the test's own clock (fake_clock): on the machine's, a test descheduled between the two
    requests found the first answer already there (flushed), not on its way.
    """
    clock = FakeClock().install(monkeypatch)
    sim = clock.sim(IDS)
    configure_servos(sim, BAUD, 0)
    port = clock.port(sim, BAUD)
    bus = Bus(port, BAUD, latency_timer_s=0.0, return_delay_s=0.0)
    for servo_id in IDS:
        bus.write(servo_id, BLOCK.indirect_map_address(), BLOCK.indirect_map_bytes())

    earlier = protocol.encode_instruction(
        protocol.BROADCAST_ID,
        protocol.Instruction.FAST_SYNC_READ if fast else protocol.Instruction.SYNC_READ,
        struct.pack('<HH', BLOCK.read_address, BLOCK.tagged_size) + bytes(IDS))

    def behind(linger: bool) -> int:
        """Put an earlier request's answer in flight, read again; return the bytes left behind."""
        port.write(earlier)   # a request whose answer is on its way (a stuck, late adapter)
        pending = bus.begin_sync_read(BLOCK.read_address, BLOCK.tagged_size, IDS, fast, linger)
        result = pending.collect()
        assert all(isinstance(result.data[servo_id], bytes) for servo_id in IDS)
        time.sleep(0.01)   # whatever was still on its way has come
        return port.in_waiting

    # The answer to this request is left for the next. It takes the first answer still on its
    # way when the second request flushes the input.
    assert behind(linger=False) > 0
    port.reset_input_buffer()
    assert behind(linger=True) == 0
