"""The bus over Protocol 1.0 (protocol1.PROTOCOL_1), against simulated X servos set to 1.0."""

import random
from typing import Dict, Iterator, Tuple

from dxl_servo_driver.bus import Bus
from dxl_servo_driver.errors import (
    BadRequest, CommError, CommTimeout, CorruptReply, StatusError)
from dxl_servo_driver.models import model_for, xm430
from dxl_servo_driver.protocol.protocol1 import ErrorBit, PROTOCOL_1
from dxl_servo_driver.sim.bus import SimBus
from dxl_servo_driver.sim.faulty_port import FaultyPort
from dxl_servo_driver.sim.port import SimPortHandler
from dxl_servo_driver.sim.virtual_bus import configure_servos
import pytest

BAUD = 1_000_000
IDS = (1, 2, 3)
MANUAL = model_for(xm430.MODEL_NUMBER)
PROTOCOL_VERSION = MANUAL.lookup('protocol_version').address
LED = MANUAL.lookup('led').address
ID = MANUAL.lookup('id').address
GOAL_POSITION = MANUAL.lookup('goal_position').address
PROFILE_VELOCITY = MANUAL.lookup('profile_velocity').address
MODEL_NUMBER = MANUAL.lookup('model_number').address


def make_sim() -> SimBus:
    """Return servos at BAUD switched to Protocol 1.0 through a Protocol 2.0 bus."""
    sim = SimBus(IDS, boot_time_s=0.02)
    configure_servos(sim, BAUD, 0)
    bus2 = Bus(SimPortHandler(sim, 'sim', BAUD), BAUD, latency_timer_s=0.001,
               return_delay_s=0.0)
    for servo_id in IDS:
        bus2.write(servo_id, PROTOCOL_VERSION, b'\x01')
        assert sim.read_register(servo_id, 'protocol_version') == 1
    return sim


def bus_on(port: object, latency_timer_s: float = 0.001) -> Bus:
    return Bus(port, BAUD, latency_timer_s=latency_timer_s,   # type: ignore[arg-type]
               return_delay_s=0.0, framer=PROTOCOL_1)


@pytest.fixture
def rig() -> Tuple[SimBus, Bus]:
    sim = make_sim()
    return sim, bus_on(SimPortHandler(sim, 'sim', BAUD))


@pytest.fixture
def faulty() -> Iterator[Tuple[SimBus, FaultyPort, Bus]]:
    sim = make_sim()
    port = FaultyPort(SimPortHandler(sim, 'sim', BAUD), seed=11, protocol=1)
    yield sim, port, bus_on(port)
    port.close()


def test_ping_reads_the_model_number(rig: Tuple[SimBus, Bus]) -> None:
    sim, bus = rig
    assert [bus.ping(servo_id) for servo_id in IDS] == [xm430.MODEL_NUMBER] * 3
    with pytest.raises(CommTimeout, match='Protocol 1.0'):
        bus.ping(9, probe=True)
    assert bus.counters.timeouts == 1


def test_instructions_1_0_lacks_are_refused_by_name(rig: Tuple[SimBus, Bus]) -> None:
    _, bus = rig
    with pytest.raises(BadRequest, match='sync read does not exist in Protocol 1.0'):
        bus.sync_read(GOAL_POSITION, 4, IDS)
    with pytest.raises(BadRequest, match='fast sync read'):
        bus.begin_sync_read(GOAL_POSITION, 4, IDS, fast=True)
    with pytest.raises(BadRequest, match='broadcast ping'):
        bus.broadcast_ping()
    with pytest.raises(BadRequest, match='CLEAR'):
        bus.clear_multi_turn(1)
    assert not bus.lock._is_owned()   # noqa: SLF001 - RLock: nothing held after a refusal
    # Addresses are one byte: above 255 cannot be asked.
    with pytest.raises(BadRequest, match='0..255'):
        bus.read(1, 578, 2)
    with pytest.raises(BadRequest):
        bus.write(1, 254, b'\x00\x00\x00')


def test_read_write_and_their_errors(rig: Tuple[SimBus, Bus]) -> None:
    sim, bus = rig
    bus.write(2, LED, b'\x01')
    assert sim.read_register(2, 'led') == 1
    assert bus.read(2, LED, 1) == b'\x01'
    assert bus.read(3, ID, 1) == b'\x03'
    for _ in range(2 * 8):   # every read tag, also near the end of 1.0's reach
        assert bus.read(1, 250, 6) == bytes(6)
        assert bus.read(1, MODEL_NUMBER, 2) == xm430.MODEL_NUMBER.to_bytes(2, 'little')
    with pytest.raises(StatusError) as refused:
        bus.write(1, MODEL_NUMBER, b'\x00\x00')   # read-only
    assert refused.value.code == ErrorBit.RANGE
    assert 'range error' in str(refused.value)
    assert not refused.value.alert


def test_sync_write_and_bulk_read(rig: Tuple[SimBus, Bus]) -> None:
    sim, bus = rig
    bus.sync_write(LED, 1, [(1, b'\x01'), (3, b'\x01')])
    assert [sim.read_register(i, 'led') for i in IDS] == [1, 0, 1]
    bus.sync_write(PROFILE_VELOCITY, 4, [(i, (100 * i).to_bytes(4, 'little')) for i in IDS])
    result = bus.bulk_read([(3, PROFILE_VELOCITY, 4), (1, LED, 1), (2, MODEL_NUMBER, 2)])
    assert result.data == {3: (300).to_bytes(4, 'little'), 1: b'\x01',
                           2: xm430.MODEL_NUMBER.to_bytes(2, 'little')}
    assert result.alerts == {3: False, 1: False, 2: False}
    assert bus.counters.timeouts == bus.counters.stale == 0
    with pytest.raises(BadRequest):
        bus.bulk_read([(1, LED, 1), (1, ID, 1)])


def test_a_silent_or_corrupt_servo_fails_alone_in_a_bulk_read(
        rig: Tuple[SimBus, Bus]) -> None:
    sim, bus = rig
    sim.set_drop(2, 1.0)
    sim.set_corrupt(3, 1.0)
    data = bus.bulk_read([(1, ID, 1), (2, ID, 1), (3, ID, 1)]).data
    assert data[1] == b'\x01'
    assert isinstance(data[2], CommTimeout)
    assert isinstance(data[3], CorruptReply)
    with pytest.raises(CorruptReply):
        bus.read(3, ID, 1)


def test_alarms_are_alerts_not_refusals(rig: Tuple[SimBus, Bus]) -> None:
    sim, bus = rig
    sim.inject_error(2, 'overload')
    assert bus.read(2, ID, 1) == b'\x02'
    result = bus.bulk_read([(1, ID, 1), (2, ID, 1)])
    assert result.alerts == {1: False, 2: True}
    assert result.data[2] == b'\x02'


def test_an_echoing_adapter_is_learned_and_skipped(
        faulty: Tuple[SimBus, FaultyPort, Bus]) -> None:
    sim, port, bus = faulty
    port.set(echo=True)
    assert bus.ping(1) == xm430.MODEL_NUMBER
    assert bus.echo
    waits = bus.counters.deadline_waits
    for _ in range(3):
        assert bus.ping(2) == xm430.MODEL_NUMBER
        assert bus.read(3, ID, 1) == b'\x03'
        bus.write(1, LED, b'\x01')
        bus.sync_write(LED, 1, [(i, b'\x01') for i in IDS])
        assert bus.bulk_read([(2, ID, 1), (3, LED, 1)]).data == {2: b'\x02', 3: b'\x01'}
    counters = bus.counters
    assert (counters.timeouts, counters.stale, counters.corrupt) == (0, 0, 0)
    assert counters.deadline_waits == waits
    assert counters.echoes >= 15


def test_a_status_identical_to_the_request_follows_its_echo(
        faulty: Tuple[SimBus, FaultyPort, Bus]) -> None:
    sim, port, bus = faulty
    # An input voltage alarm makes the PING's status FF FF 01 02 01 FB: the PING itself.
    sim.inject_error(1, 'voltage')
    port.set(echo=True)
    assert bus.ping(2) == xm430.MODEL_NUMBER   # learns the echo
    assert bus.ping(1) == xm430.MODEL_NUMBER
    port.clear()
    # Without an echo it cannot be told from one: refused, never taken for the echo's servo.
    bus_plain = bus_on(SimPortHandler(sim, 'sim', BAUD))
    with pytest.raises(CommTimeout):
        bus_plain.ping(1)


def test_a_late_echo_is_never_an_answer(faulty: Tuple[SimBus, FaultyPort, Bus]) -> None:
    sim, port, bus = faulty
    # A READ of 2 bytes at 0x2B... comes back late: it has the shape of a status of id 1
    # carrying 2 bytes with the error byte 0x02. The next read of 2 bytes must not take it.
    port.set(echo=True, echo_gap_ms=0.0)
    for _ in range(3):
        assert bus.read(1, MODEL_NUMBER, 2) == xm430.MODEL_NUMBER.to_bytes(2, 'little')
    port.set(echo=False, late_probability=1.0, late_ms=(0.0, 0.5))
    truth = {(1, MODEL_NUMBER, 2): xm430.MODEL_NUMBER.to_bytes(2, 'little'),
             (1, ID, 1): b'\x01'}
    for _ in range(20):
        for (servo_id, address, length), value in truth.items():
            try:
                assert bus.read(servo_id, address, length) == value
            except CommError:
                pass


def test_late_duplicated_truncated_replies_never_answer_another_request(
        faulty: Tuple[SimBus, FaultyPort, Bus]) -> None:
    sim, port, bus = faulty
    values: Dict[Tuple[int, int, int], bytes] = {}
    for servo_id in IDS:
        bus.write(servo_id, PROFILE_VELOCITY, (200 + servo_id).to_bytes(4, 'little'))
        bus.write(servo_id, LED, bytes((servo_id & 1,)))
        values[(servo_id, PROFILE_VELOCITY, 4)] = (200 + servo_id).to_bytes(4, 'little')
        values[(servo_id, LED, 1)] = bytes((servo_id & 1,))
        values[(servo_id, ID, 1)] = bytes((servo_id,))
    port.set(late_probability=0.3, late_ms=(0.0, 3.0), duplicate_probability=0.2,
             truncate_probability=0.1, noise_probability=0.1, echo=True)
    rng = random.Random(4)
    keys = sorted(values)
    answered = 0
    for _ in range(150):
        key = rng.choice(keys)
        try:
            assert bus.read(*key) == values[key], key
            answered += 1
        except CommError:
            pass
        records = rng.sample(keys, 3)
        if len({servo_id for servo_id, _, _ in records}) == 3:
            # A bulk read has no length tag and no confirmation: a lone late reply of the same
            # id and length passes for the answer (as in a sync read, whose caller dates its
            # samples by Realtime Tick). Never one of another servo or another length.
            result = bus.bulk_read(records)
            for servo_id, _, length in records:
                data = result.data[servo_id]
                assert isinstance(data, CommError) or data in {
                    value for (owner, _, size), value in values.items()
                    if owner == servo_id and size == length}, (servo_id, data)
    stats = port.stats
    assert stats.late and stats.duplicated and stats.truncated and stats.noise
    assert answered > 75
    assert bus.counters.stale > 0


def test_switching_protocol_through_register_13(rig: Tuple[SimBus, Bus]) -> None:
    sim, bus1 = rig
    bus2 = Bus(SimPortHandler(sim, 'sim', BAUD), BAUD, latency_timer_s=0.001,
               return_delay_s=0.0)
    with pytest.raises(CommTimeout):
        bus2.ping(2, probe=True)
    # The write's status comes in 1.0; from then on only 2.0 is answered.
    bus1.write(2, PROTOCOL_VERSION, b'\x02')
    assert bus2.ping(2) == xm430.MODEL_NUMBER
    with pytest.raises(CommTimeout):
        bus1.ping(2, probe=True)
    assert bus1.ping(1) == xm430.MODEL_NUMBER
