"""
Factory-new servos, a hand on the horn and end stops: the simulator's side of `dxl setup`.

Six servos straight from the box share id 1 at 57,600 bps: plugged one at a time, the first
answers a ping and the second makes every answer collide (garbled bytes, never a clean reply);
a write of ID and then of Baud Rate moves one of them to its own id and baud. A hand turns a
horn with torque off (`turn`), end stops hold it against the hand and against the motor
(`stops`), and a motor pushing into a stop draws what its mode allows. On virtual_bus, read
through the driver's own Bus; the collision model and the servo references also in process.
"""

import contextlib
import math
import random
import time
from typing import Callable, Iterator, Optional, Tuple, TypeVar

from dxl_servo_driver.bus import Bus
from dxl_servo_driver.errors import CommError, CommTimeout
from dxl_servo_driver.models import model_for, model_named, xm430
from dxl_servo_driver.port.serial_device import open_port
from dxl_servo_driver.protocol import encode_instruction, Instruction, StreamParser
from dxl_servo_driver.protocol import protocol1
from dxl_servo_driver.sim import control, motor
from dxl_servo_driver.sim.bus import SimBus
from dxl_servo_driver.sim.collision import frame_bits, uart_read, wired_and
from processes import LINE_TIMEOUT_S, StartVirtualBus, VirtualBusProcess
import pytest
import serial

FACTORY_BAUD = 57_600
FAST_BAUD = 1_000_000
MANUAL = model_for(xm430.MODEL_NUMBER)   # the XM430 manual's table: every new servo here
ITEM = MANUAL.item
PULSES_PER_RAD = MANUAL.pulses_per_rev / (2.0 * math.pi)
T = TypeVar('T')


def raw_of(rad: float) -> int:
    """Return the Present Position a servo reads at rad servo radians (no offset, no ratio)."""
    return round(MANUAL.position_zero_raw + rad * PULSES_PER_RAD)


def wait_for(value: Callable[[], T], done: Callable[[T], bool],
             timeout_s: float = 3 * LINE_TIMEOUT_S) -> T:
    """Return value() once done says so (AssertionError with the last value after timeout_s)."""
    deadline_s = time.monotonic() + timeout_s
    while True:
        last = value()
        if done(last):
            return last
        assert time.monotonic() < deadline_s, f'still {last!r} after {timeout_s} s'


@contextlib.contextmanager
def driver_bus(device: str, baud_bps: int) -> Iterator[Bus]:
    """Open the pty through the driver's Bus (a generous latency timer: a loaded machine)."""
    port = open_port(device, baud_bps)
    try:
        yield Bus(port, baud_bps, latency_timer_s=0.2)
    finally:
        port.close()


def answer(bus: Bus, servo_id: int) -> Optional[int]:
    """Return the model number a ping of servo_id gets, None if it fails."""
    try:
        return bus.ping(servo_id)
    except CommError:
        return None


def booted(vb: VirtualBusProcess, ref: str) -> None:
    """Wait until a servo just plugged has booted: its Realtime Tick counts from power-on."""
    boot_ms = 100   # SimBus's boot time
    wait_for(lambda: vb.get(ref, 'realtime_tick'), lambda tick: tick > 2 * boot_ms)


def clean_packets(data: bytes) -> list:
    """Return the status packets in data that pass their CRC."""
    return [event.packet for event in StreamParser().feed(data, 0.0) if event.crc_ok]


# ---------------------------------------------------------------- factory-new servos
@pytest.mark.parametrize('timing', ['instant', 'wire'])
def test_six_factory_servos_plugged_one_by_one(virtual_bus: StartVirtualBus,
                                               timing: str) -> None:
    vb = virtual_bus([1] * 6, FACTORY_BAUD, unplugged=True,
                     extra_args=['--return-delay-time', '250', '--timing', timing])
    with driver_bus(vb.device, FACTORY_BAUD) as bus:
        with pytest.raises(CommTimeout):
            bus.ping(1)   # none on the bus yet
        assert vb.control('plug #1') == 'ok plug #1'
        assert wait_for(lambda: answer(bus, 1), lambda model: model is not None) == \
            xm430.MODEL_NUMBER
        for number in range(2, 7):
            assert vb.control(f'plug #{number}') == f'ok plug #{number}'
            booted(vb, f'#{number}')
            for _ in range(3):
                with pytest.raises(CommError):
                    bus.ping(1)   # two or more answer together: never a clean reply
        counters = bus.counters
        assert counters.timeouts + counters.corrupt + counters.stale > 0
    # What the host receives is not silence: garbled bytes, no packet in them.
    with serial.Serial(vb.device, FACTORY_BAUD, timeout=0.5) as port:
        port.write(encode_instruction(1, Instruction.PING))
        data = port.read(64)
    assert len(data) >= 10, data.hex()
    assert clean_packets(data) == [], data.hex()
    answer_line = vb.control('get 1 id')
    assert answer_line == 'error: id 1 is ambiguous: servos #1, #2, #3, #4, #5, #6 have it; ' \
        'name one as #N'


def test_id_then_baud_written_to_one_plugged_servo(virtual_bus: StartVirtualBus) -> None:
    vb = virtual_bus([1] * 6, FACTORY_BAUD, unplugged=True,
                     extra_args=['--return-delay-time', '250'])
    assert vb.control('plug #3') == 'ok plug #3'
    with driver_bus(vb.device, FACTORY_BAUD) as bus:
        wait_for(lambda: answer(bus, 1), lambda model: model == xm430.MODEL_NUMBER)
        bus.write_item(1, ITEM('id'), 5)   # its status still comes from id 1
        assert wait_for(lambda: answer(bus, 5), lambda model: model is not None) == \
            xm430.MODEL_NUMBER
        with pytest.raises(CommTimeout):
            bus.ping(1)
        bus.write_item(5, ITEM('baud_rate'), 3)   # 1 Mbps; its status still at 57,600 bps
        with pytest.raises(CommTimeout):
            bus.ping(5)
    with driver_bus(vb.device, FAST_BAUD) as bus:
        assert wait_for(lambda: answer(bus, 5), lambda model: model is not None) == \
            xm430.MODEL_NUMBER
        with pytest.raises(CommTimeout):
            bus.ping(1)
    # #3 is named by its new id now that no other servo has it; the others are still new.
    assert vb.get('#3', 'id') == 5 and vb.get(5, 'baud_rate') == 3
    assert [vb.get(f'#{number}', 'id') for number in (1, 2, 4, 5, 6)] == [1] * 5
    assert vb.control('plug #1') == 'ok plug #1'
    with driver_bus(vb.device, FACTORY_BAUD) as bus:
        # One servo at id 1 and 57,600 bps again (#3 is elsewhere): a clean answer.
        assert wait_for(lambda: answer(bus, 1), lambda model: model is not None) == \
            xm430.MODEL_NUMBER


# ---------------------------------------------------------------- a hand, end stops
@pytest.fixture
def one(virtual_bus: StartVirtualBus) -> Iterator[Tuple[VirtualBusProcess, Bus]]:
    """One XM430 at 1 Mbps on virtual_bus, and the driver's Bus on its pty."""
    vb = virtual_bus([1], FAST_BAUD)
    with driver_bus(vb.device, FAST_BAUD) as bus:
        yield vb, bus


def state(bus: Bus) -> Tuple[int, int, int]:
    """Return (Present Position, Present Velocity, Present Current) read in one READ."""
    current, velocity, position = (ITEM(name) for name in (
        'present_current', 'present_velocity', 'present_position'))
    assert velocity.address == current.address + 2 and position.address == velocity.address + 4
    data = bus.read_fresh(1, current.address, 10)[0]
    return (position.decode(data[6:10]), velocity.decode(data[2:6]),
            current.decode(data[0:2]))


def holds(bus: Bus, expected: Tuple[int, int, int], reads: int = 20) -> None:
    """Assert that state stays expected over reads reads (the horn is left, or held)."""
    for _ in range(reads):
        assert state(bus) == expected


def test_turn_moves_present_position_and_it_stays(
        one: Tuple[VirtualBusProcess, Bus]) -> None:
    vb, bus = one
    start = state(bus)[0]
    assert start == raw_of(0.0)
    target = raw_of(1.0)
    assert vb.control('turn 1 1 3') == 'ok turn 1 1 3'
    samples = []
    deadline_s = time.monotonic() + 3 * LINE_TIMEOUT_S
    while not samples or samples[-1][0] != target:
        samples.append(state(bus))
        assert time.monotonic() < deadline_s, samples[-3:]
    positions = [position for position, _, _ in samples]
    assert positions == sorted(positions) and positions[-1] == target
    # At constant speed: 1 rad in 3 s, in Present Velocity's unit (0.229 rpm).
    speed_raw = (1.0 / 3.0) * 60.0 / (2.0 * math.pi) / MANUAL.velocity_unit_rpm
    turning = [velocity for position, velocity, _ in samples if start < position < target]
    assert turning and all(abs(velocity - speed_raw) <= 1.0 for velocity in turning), turning
    assert all(current == 0 for _, _, current in samples)   # torque off: no current
    holds(bus, (target, 0, 0))
    # Past a full turn: Present Position counts on as the servo counts it.
    assert vb.control('turn 1 7 0') == 'ok turn 1 7 0'
    assert state(bus)[0] == raw_of(7.0) > MANUAL.pulses_per_rev
    assert vb.control('turn #1 -0.25 0') == 'ok turn #1 -0.25 0'
    holds(bus, (raw_of(-0.25), 0, 0))


def test_turn_with_torque_on_is_refused(one: Tuple[VirtualBusProcess, Bus]) -> None:
    vb, bus = one
    bus.write_item(1, ITEM('torque_enable'), 1)
    before = state(bus)
    assert vb.control('turn 1 0.5') == 'error: torque is on: the motor holds it; use load'
    holds(bus, before, reads=5)
    bus.write_item(1, ITEM('torque_enable'), 0)
    assert vb.control('turn 1 0.5 0') == 'ok turn 1 0.5 0'
    assert state(bus)[0] == raw_of(0.5)


def test_stops_hold_against_the_motor_in_position_mode(
        one: Tuple[VirtualBusProcess, Bus]) -> None:
    vb, bus = one
    assert vb.control('stops 1 -0.5 0.5') == 'ok stops 1 -0.5 0.5'
    # A PWM limit below half the stall current: the push stays short of an overload.
    pwm_limit = 400
    bus.write_item(1, ITEM('pwm_limit'), pwm_limit)
    volts = bus.read_item(1, ITEM('present_input_voltage')) * MANUAL.voltage_unit_v
    assert MANUAL.current_unit_a is not None
    stalled = motor.motor_for(MANUAL).stall_current_a(volts) * pwm_limit / MANUAL.pwm_full_raw
    limit_raw = round(stalled / MANUAL.current_unit_a)
    bus.write_item(1, ITEM('torque_enable'), 1)
    bus.write_item(1, ITEM('goal_position'), raw_of(2.0))   # beyond the stop
    pushing = (raw_of(0.5), 0, limit_raw)
    wait_for(lambda: state(bus), lambda now: now == pushing)
    holds(bus, pushing)
    assert bus.read_item(1, ITEM('present_pwm')) == pwm_limit
    assert bus.read_item(1, ITEM('hardware_error_status')) == 0


def test_stops_hold_against_the_motor_in_current_based_position(
        one: Tuple[VirtualBusProcess, Bus]) -> None:
    vb, bus = one
    assert vb.control('stops 1 -0.5 0.5') == 'ok stops 1 -0.5 0.5'
    bus.write_item(1, ITEM('operating_mode'), 5)
    bus.write_item(1, ITEM('torque_enable'), 1)
    bus.write_item(1, ITEM('goal_current'), 300)
    bus.write_item(1, ITEM('goal_position'), raw_of(-2.0))   # beyond the other stop
    pushing = (raw_of(-0.5), 0, -300)   # Present Current at Goal Current
    wait_for(lambda: state(bus), lambda now: now == pushing)
    holds(bus, pushing)
    # Back inside the stops, the motor moves the horn freely again.
    bus.write_item(1, ITEM('goal_position'), raw_of(0.25))
    wait_for(lambda: state(bus), lambda now: abs(now[0] - raw_of(0.25)) <= 2 and now[1] == 0)


def test_turn_past_a_stop_stops_at_it(one: Tuple[VirtualBusProcess, Bus]) -> None:
    vb, bus = one
    assert vb.control('stops 1 -0.5 0.5') == 'ok stops 1 -0.5 0.5'
    assert vb.control('turn 1 2 0.5') == 'ok turn 1 2 0.5'
    samples = []
    deadline_s = time.monotonic() + 3 * LINE_TIMEOUT_S
    while not samples or samples[-1][0] != raw_of(0.5):
        samples.append(state(bus))
        assert time.monotonic() < deadline_s, samples[-3:]
    assert all(position <= raw_of(0.5) for position, _, _ in samples)
    holds(bus, (raw_of(0.5), 0, 0))
    assert vb.control('turn 1 -3 0') == 'ok turn 1 -3 0'
    holds(bus, (raw_of(-0.5), 0, 0), reads=3)
    # Stops outside the horn's reach are refused; taken away, the horn turns past.
    assert vb.control('stops 1 0 1') == ('error: the horn is at -0.5000 rad, outside the stops '
                                         '0..1 rad: turn it in between first')
    assert vb.control('stops 1 off') == 'ok stops 1 off'
    assert vb.control('turn 1 -3 0') == 'ok turn 1 -3 0'
    assert state(bus)[0] == raw_of(-3.0)


# ---------------------------------------------------------------- in process
def test_a_wire_and_of_frames_reads_back_what_one_sent() -> None:
    rng = random.Random(3)
    data = bytes(rng.randrange(256) for _ in range(200))
    assert uart_read(frame_bits(data)) == data
    assert wired_and([(5, data)]) == data
    # One bit apart, the same bytes are no longer themselves.
    assert wired_and([(0, data), (1, data)]) != data
    # Apart by more than their length, they follow one another.
    assert wired_and([(0, data[:3]), (30, data[3:6])]) == data[:6]


def test_servos_sharing_an_id_collide_in_process() -> None:
    bus = SimBus([1, 1, 2], boot_time_s=0.0)
    ping = encode_instruction(1, Instruction.PING)
    collided = b''.join(reply.data for reply in bus.feed(ping, FACTORY_BAUD))
    assert collided and clean_packets(collided) == []
    bus.unplug('#2')
    clean = b''.join(reply.data for reply in bus.feed(ping, FACTORY_BAUD))
    assert [packet.servo_id for packet in clean_packets(clean)] == [1]
    bus.plug('#2')
    # A sync read of ids 1 and 2: the servos at rank 0 collide, servo 2 answers cleanly after.
    address = ITEM('present_position').address
    sync = encode_instruction(0xFE, Instruction.SYNC_READ,
                              address.to_bytes(2, 'little') + (4).to_bytes(2, 'little')
                              + bytes((1, 2)))
    replies = b''.join(reply.data for reply in bus.feed(sync, FACTORY_BAUD))
    assert [packet.servo_id for packet in clean_packets(replies)] == [2]
    # A Fast Sync Read is one packet: the collision inside it fails its CRC.
    fast = encode_instruction(0xFE, Instruction.FAST_SYNC_READ,
                              address.to_bytes(2, 'little') + (4).to_bytes(2, 'little')
                              + bytes((1, 2)))
    packet = b''.join(reply.data for reply in bus.feed(fast, FACTORY_BAUD))
    assert packet and clean_packets(packet) == []


def test_replies_far_enough_apart_do_not_collide() -> None:
    bus = SimBus([1, 1], boot_time_s=0.0)
    ping = encode_instruction(1, Instruction.PING)
    data = b''.join(reply.data for reply in bus.feed(ping, FACTORY_BAUD))
    assert data and clean_packets(data) == []   # the same Return Delay Time: they overlap
    # #1 answers at once, #2 500 us later: a ping's status lasts 2.4 ms at 57,600 bps...
    delay = ITEM('return_delay_time')
    assert bus.servo('#1').write(delay.address, delay.encode(0)) == 0
    data = b''.join(reply.data for reply in bus.feed(ping, FACTORY_BAUD))
    assert data and clean_packets(data) == []
    # ...and 70 us at 2 Mbps: #2 starts after #1 ended, and both reach the host whole.
    baud = ITEM('baud_rate')
    for ref in ('#1', '#2'):
        assert bus.servo(ref).write(baud.address, baud.encode(4)) == 0
    data = b''.join(reply.data for reply in bus.feed(ping, 2_000_000))
    assert [packet.servo_id for packet in clean_packets(data)] == [1, 1]


def test_protocol_1_servos_sharing_an_id_collide() -> None:
    ax = model_named('AX-12A')
    bus = SimBus([1, 1], boot_time_s=0.0, models=[ax, ax])
    ping = protocol1.encode_instruction(1, protocol1.Instruction1.PING)
    baud = ax.bauds[ax.item('baud_rate').initial]
    data = b''.join(reply.data for reply in bus.feed(ping, baud))
    events = protocol1.StreamParser1().feed(data, 0.0)
    assert data and not any(event.crc_ok for event in events)
    bus.unplug('#1')
    data = b''.join(reply.data for reply in bus.feed(ping, baud))
    assert [event.crc_ok for event in protocol1.StreamParser1().feed(data, 0.0)] == [True]


def test_a_servo_is_named_by_its_slot_after_its_id_changes() -> None:
    bus = SimBus([1, 1, 3], boot_time_s=0.0)
    assert control.handle_line('get 1 id', bus) == \
        'error: id 1 is ambiguous: servos #1, #2 have it; name one as #N'
    assert control.handle_line('get 3 id', bus) == 'ok get 3 id=3'
    item = ITEM('id')
    assert bus.servo('#2').write(item.address, item.encode(7)) == 0
    assert control.handle_line('get #2 id', bus) == 'ok get #2 id=7'
    assert control.handle_line('get 7 id', bus) == 'ok get 7 id=7'
    assert control.handle_line('get 1 id', bus) == 'ok get 1 id=1'   # #1 alone has it now
    assert control.handle_line('unplug #4', bus) == \
        'error: no servo #4 on the bus (it has #1..#3)'
    assert control.handle_line('drop #0 1', bus) == \
        f"error: bad servo '#0': expected an id 0..252 or #N, N 1..{control.MAX_SLOTS}"


def test_a_hand_turns_an_unplugged_horn() -> None:
    now = [0.0]
    bus = SimBus([1], clock=lambda: now[0], boot_time_s=0.0)
    bus.unplug(1)
    bus.turn(1, 1.0, 0.2)
    now[0] += 0.5
    bus.plug(1)   # Present Position is read from the horn at power-on
    assert bus.read_register(1, 'present_position') == raw_of(1.0)
