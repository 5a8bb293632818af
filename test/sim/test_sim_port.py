"""SimPortHandler: under the stock dynamixel_sdk, through the raw API, wire timing, port loss."""

import errno
from typing import Iterator

from dxl_servo_driver import protocol
from dxl_servo_driver.models import model_for, xm430
from dxl_servo_driver.sim.bus import Reply, SimBus
from dxl_servo_driver.sim.port import SimPortDisconnected, SimPortHandler
from dxl_servo_driver.sim.timing import byte_time_s, hybrid_wait, LatenessStats, WireScheduler
import dynamixel_sdk as sdk
import pytest

MANUAL = model_for(xm430.MODEL_NUMBER)   # the XM430 manual's table

BAUD = 57600  # the servo's factory Baud Rate (register value 1)
RDT_S = 250 * 2e-6  # factory Return Delay Time: 250 x 2 us
ADDR_LED = MANUAL.lookup('led').address
ADDR_PROFILE_ACCELERATION = MANUAL.lookup('profile_acceleration').address
ADDR_PROFILE_VELOCITY = MANUAL.lookup('profile_velocity').address
ADDR_MODEL_NUMBER = MANUAL.lookup('model_number').address
ADDR_ID = MANUAL.lookup('id').address


class FakeClock:
    """An injected clock; sleep() advances it."""

    def __init__(self, start_s: float = 100.0) -> None:
        self.now_s = start_s
        self.slept_s = 0.0

    def __call__(self) -> float:
        return self.now_s

    def sleep(self, dt_s: float) -> None:
        assert dt_s >= 0.0
        self.now_s += dt_s
        self.slept_s += dt_s


def make_bus(ids: tuple[int, ...] = (1, 2, 3)) -> SimBus:
    return SimBus(ids, seed=7, boot_time_s=0.0)


@pytest.fixture
def port() -> Iterator[SimPortHandler]:
    p = SimPortHandler(make_bus(), baudrate=BAUD)
    assert p.openPort()
    yield p
    p.closePort()


@pytest.fixture
def handler() -> sdk.Protocol2PacketHandler:
    return sdk.PacketHandler(2.0)


# ---------------------------------------------------------------- stock SDK, instant timing
def test_sdk_ping_every_servo(port: SimPortHandler, handler: sdk.Protocol2PacketHandler) -> None:
    for servo_id in (1, 2, 3):
        model, result, error = handler.ping(port, servo_id)
        assert (model, result, error) == (xm430.MODEL_NUMBER, sdk.COMM_SUCCESS, 0)


def test_sdk_ping_absent_servo_times_out(port: SimPortHandler,
                                         handler: sdk.Protocol2PacketHandler) -> None:
    _, result, _ = handler.ping(port, 9)
    assert result == sdk.COMM_RX_TIMEOUT
    assert not port.is_using


def test_sdk_write_then_read(port: SimPortHandler, handler: sdk.Protocol2PacketHandler) -> None:
    assert handler.write1ByteTxRx(port, 2, ADDR_LED, 1) == (sdk.COMM_SUCCESS, 0)
    assert handler.read1ByteTxRx(port, 2, ADDR_LED) == (1, sdk.COMM_SUCCESS, 0)
    assert handler.write4ByteTxRx(port, 2, ADDR_PROFILE_VELOCITY, 123) == (sdk.COMM_SUCCESS, 0)
    assert handler.read4ByteTxRx(port, 2, ADDR_PROFILE_VELOCITY) == (123, sdk.COMM_SUCCESS, 0)
    assert handler.read2ByteTxRx(port, 2, ADDR_MODEL_NUMBER) == (
        xm430.MODEL_NUMBER, sdk.COMM_SUCCESS, 0)


def test_sdk_out_of_range_write_gets_data_range_error(
        port: SimPortHandler, handler: sdk.Protocol2PacketHandler) -> None:
    result, error = handler.write1ByteTxRx(port, 1, ADDR_LED, 7)
    assert result == sdk.COMM_SUCCESS
    assert error & 0x7F == protocol.ErrorCode.DATA_RANGE
    assert handler.read1ByteTxRx(port, 1, ADDR_LED) == (0, sdk.COMM_SUCCESS, 0)


def test_sdk_group_sync_write_and_sync_read(port: SimPortHandler,
                                            handler: sdk.Protocol2PacketHandler) -> None:
    writer = sdk.GroupSyncWrite(port, handler, ADDR_PROFILE_ACCELERATION, 4)
    values = {1: 10, 2: 200, 3: 3000}
    for servo_id, value in values.items():
        assert writer.addParam(servo_id, list(value.to_bytes(4, 'little')))
    assert writer.txPacket() == sdk.COMM_SUCCESS

    reader = sdk.GroupSyncRead(port, handler, ADDR_PROFILE_ACCELERATION, 4)
    for servo_id in values:
        assert reader.addParam(servo_id)
    assert reader.txRxPacket() == sdk.COMM_SUCCESS
    for servo_id, value in values.items():
        assert reader.isAvailable(servo_id, ADDR_PROFILE_ACCELERATION, 4)
        assert reader.getData(servo_id, ADDR_PROFILE_ACCELERATION, 4) == value


def test_sdk_group_bulk_read_and_bulk_write(port: SimPortHandler,
                                            handler: sdk.Protocol2PacketHandler) -> None:
    writer = sdk.GroupBulkWrite(port, handler)
    assert writer.addParam(1, ADDR_LED, 1, [1])
    assert writer.addParam(3, ADDR_PROFILE_VELOCITY, 4, list((321).to_bytes(4, 'little')))
    assert writer.txPacket() == sdk.COMM_SUCCESS

    reader = sdk.GroupBulkRead(port, handler)
    assert reader.addParam(1, ADDR_LED, 1)
    assert reader.addParam(2, ADDR_ID, 1)
    assert reader.addParam(3, ADDR_PROFILE_VELOCITY, 4)
    assert reader.txRxPacket() == sdk.COMM_SUCCESS
    assert reader.getData(1, ADDR_LED, 1) == 1
    assert reader.getData(2, ADDR_ID, 1) == 2
    assert reader.getData(3, ADDR_PROFILE_VELOCITY, 4) == 321


def test_sdk_broadcast_ping_finds_all(port: SimPortHandler,
                                      handler: sdk.Protocol2PacketHandler) -> None:
    found, result = handler.broadcastPing(port)
    assert result == sdk.COMM_SUCCESS
    assert sorted(found) == [1, 2, 3]
    for servo_id in (1, 2, 3):
        assert found[servo_id] == [xm430.MODEL_NUMBER, xm430.FIRMWARE_VERSION]


def test_sdk_at_wrong_baud_gets_no_answer(handler: sdk.Protocol2PacketHandler) -> None:
    port = SimPortHandler(make_bus(), baudrate=1_000_000)
    assert port.openPort()
    assert handler.ping(port, 1)[1] == sdk.COMM_RX_TIMEOUT
    assert port.setBaudRate(BAUD)
    assert handler.ping(port, 1)[1] == sdk.COMM_SUCCESS


def test_every_servo_baud_is_accepted() -> None:
    port = SimPortHandler(make_bus(), baudrate=BAUD)
    for baud_bps in xm430.BAUD_RATES.values():
        assert port.setBaudRate(baud_bps)
        assert port.getBaudRate() == baud_bps == port.baudrate
        assert port.tx_time_per_byte == pytest.approx(10_000.0 / baud_bps)
    assert not port.setBaudRate(0)
    assert not port.setBaudRate(-57600)
    assert port.getBaudRate() == 4_500_000


def test_sdk_port_attributes_behave_like_the_stock_handler(port: SimPortHandler) -> None:
    port.setPortName('dxl0')
    assert port.getPortName() == 'dxl0'
    assert port.is_open and not port.is_using
    port.setPacketTimeoutMillis(5.0)
    assert port.packet_timeout == 5.0
    assert not port.isPacketTimeout()
    port.setPacketTimeout(11)
    assert port.packet_timeout == pytest.approx(11 * 10_000.0 / BAUD + 34.0)
    assert port.getBytesAvailable() == 0
    port.closePort()
    assert not port.is_open


# ---------------------------------------------------------------- raw API
def ping_packet(servo_id: int) -> bytes:
    return protocol.encode_instruction(servo_id, protocol.Instruction.PING)


def test_raw_ping_round_trip() -> None:
    port = SimPortHandler(make_bus(), baudrate=BAUD)
    assert port.write(ping_packet(2)) == 10
    assert port.in_waiting == 14
    reply = port.read(14, 0.1)
    packet = protocol.decode_packet(reply)
    assert packet.servo_id == 2 and packet.error == 0
    assert int.from_bytes(packet.params[:2], 'little') == xm430.MODEL_NUMBER
    assert port.in_waiting == 0


def test_raw_read_on_silence_returns_empty() -> None:
    port = SimPortHandler(make_bus(), baudrate=BAUD)
    assert port.read(14, 0.05) == b''
    port.write(ping_packet(9))  # nobody has id 9
    assert port.read(14, 0.05) == b''


def test_raw_read_returns_partial_then_rest() -> None:
    port = SimPortHandler(make_bus(), baudrate=BAUD)
    port.write(ping_packet(1))
    head = port.read(5, 0.0)
    tail = port.read(100, 0.0)
    assert len(head) == 5 and len(tail) == 9
    assert protocol.decode_packet(head + tail).servo_id == 1


def test_raw_reset_input_buffer_discards_received_bytes() -> None:
    port = SimPortHandler(make_bus(), baudrate=BAUD)
    port.write(ping_packet(1))
    port.reset_input_buffer()
    assert port.in_waiting == 0
    assert port.read(14, 0.0) == b''


def test_raw_baudrate_property_changes_line_speed() -> None:
    port = SimPortHandler(make_bus(), baudrate=1_000_000)
    port.write(ping_packet(1))
    assert port.read(14, 0.0) == b''
    port.baudrate = BAUD
    assert port.getBaudRate() == BAUD
    port.write(ping_packet(1))
    assert len(port.read(14, 0.0)) == 14
    with pytest.raises(ValueError):
        port.baudrate = 0


def test_bad_constructor_arguments() -> None:
    with pytest.raises(ValueError):
        SimPortHandler(make_bus(), timing='fast')
    with pytest.raises(ValueError):
        SimPortHandler(make_bus(), timing='instant', latency_s=0.001)
    with pytest.raises(ValueError):
        SimPortHandler(make_bus(), timing='wire', latency_s=-1.0)


def test_closed_port_raises_oserror() -> None:
    port = SimPortHandler(make_bus(), baudrate=BAUD)
    port.close()
    with pytest.raises(OSError):
        port.write(ping_packet(1))
    assert port.openPort()
    assert port.write(ping_packet(1)) == 10


# ---------------------------------------------------------------- port loss
def test_unplug_port_raises_eio_everywhere_until_plugged() -> None:
    port = SimPortHandler(make_bus(), baudrate=BAUD)
    port.write(ping_packet(1))
    port.unplug_port()
    calls = [lambda: port.write(ping_packet(1)), lambda: port.read(14, 0.01),
             lambda: port.in_waiting, port.reset_input_buffer,
             lambda: port.readPort(14), lambda: port.writePort(list(ping_packet(1))),
             port.getBytesAvailable, port.clearPort]
    for call in calls:
        with pytest.raises(OSError) as info:
            call()
        assert info.value.errno == errno.EIO
        assert isinstance(info.value, SimPortDisconnected)
        assert 'disconnected' in str(info.value)
    port.plug_port()
    assert port.in_waiting == 0  # what was in flight when it was yanked is gone
    port.write(ping_packet(1))
    assert len(port.read(14, 0.0)) == 14


def test_unplugged_port_under_sdk_raises(handler: sdk.Protocol2PacketHandler) -> None:
    port = SimPortHandler(make_bus(), baudrate=BAUD)
    port.unplug_port()
    with pytest.raises(OSError):
        handler.ping(port, 1)


# ---------------------------------------------------------------- wire timing (injected clock)
def ping_due_s(baud_bps: int, latency_s: float = 0.0) -> float:
    return (10 + 14) * byte_time_s(baud_bps) + RDT_S + latency_s


def test_wire_reply_is_not_readable_before_its_time() -> None:
    clock = FakeClock()
    port = SimPortHandler(make_bus(), baudrate=BAUD, timing='wire', clock=clock,
                          sleep=clock.sleep)
    t0 = clock()
    port.write(ping_packet(1))
    due_s = t0 + ping_due_s(BAUD)
    clock.now_s = due_s - 1e-6
    assert port.in_waiting == 0
    assert port.read(14, 0.0) == b''
    clock.now_s = due_s
    assert port.in_waiting == 14


def test_wire_read_sleeps_until_the_reply_arrives() -> None:
    clock = FakeClock()
    port = SimPortHandler(make_bus(), baudrate=BAUD, timing='wire', latency_s=0.004,
                          clock=clock, sleep=clock.sleep)
    t0 = clock()
    port.write(ping_packet(3))
    reply = port.read(14, 1.0)
    assert protocol.decode_packet(reply).servo_id == 3
    assert clock() >= t0 + ping_due_s(BAUD, 0.004)
    assert port.stats.summary()['replies'] == 1


def test_wire_read_on_silence_waits_out_the_timeout() -> None:
    clock = FakeClock()
    port = SimPortHandler(make_bus(), baudrate=BAUD, timing='wire', clock=clock,
                          sleep=clock.sleep)
    t0 = clock()
    port.write(ping_packet(9))
    assert port.read(14, 0.25) == b''
    assert clock() >= t0 + 0.25


def test_wire_sync_read_replies_follow_each_other() -> None:
    clock = FakeClock()
    port = SimPortHandler(make_bus(), baudrate=BAUD, timing='wire', clock=clock,
                          sleep=clock.sleep)
    address = MANUAL.lookup('present_position').address
    params = address.to_bytes(2, 'little') + (4).to_bytes(2, 'little') + bytes([3, 1, 2])
    instruction = protocol.encode_instruction(protocol.BROADCAST_ID,
                                              protocol.Instruction.SYNC_READ, params)
    t0 = clock()
    port.write(instruction)
    byte_s = byte_time_s(BAUD)
    reply_len = 11 + 4
    end_s = t0 + len(instruction) * byte_s
    for k in range(3):
        end_s += RDT_S + reply_len * byte_s
        clock.now_s = end_s - 1e-7
        assert port.in_waiting == k * reply_len
        clock.now_s = end_s + 1e-9  # float rounding of the sum
        assert port.in_waiting == (k + 1) * reply_len
    data = port.read(3 * reply_len, 0.0)
    ids = [protocol.decode_packet(data[i:i + reply_len]).servo_id
           for i in range(0, len(data), reply_len)]
    assert ids == [3, 1, 2]


def test_wire_back_to_back_writes_queue_on_the_transmitter() -> None:
    clock = FakeClock()
    port = SimPortHandler(make_bus(), baudrate=BAUD, timing='wire', clock=clock,
                          sleep=clock.sleep)
    t0 = clock()
    port.write(ping_packet(9))  # unanswered, but occupies the line for 10 bytes
    port.write(ping_packet(1))
    due_s = t0 + 10 * byte_time_s(BAUD) + ping_due_s(BAUD)
    clock.now_s = due_s - 1e-6
    assert port.in_waiting == 0
    clock.now_s = due_s
    assert port.in_waiting == 14


def test_wire_reset_input_buffer_keeps_bytes_still_on_the_wire() -> None:
    clock = FakeClock()
    port = SimPortHandler(make_bus(), baudrate=BAUD, timing='wire', clock=clock,
                          sleep=clock.sleep)
    port.write(ping_packet(1))
    port.reset_input_buffer()
    clock.sleep(ping_due_s(BAUD))
    assert port.in_waiting == 14


def test_wire_timing_under_sdk_takes_at_least_the_wire_time(
        handler: sdk.Protocol2PacketHandler) -> None:
    import time
    port = SimPortHandler(make_bus(), baudrate=9600, timing='wire')
    # servo 1 to 9600 bps via a broadcast write at its factory speed, then the port follows
    port.baudrate = BAUD
    assert handler.write1ByteTxOnly(port, 1, MANUAL.lookup('baud_rate').address,
                                    0) == sdk.COMM_SUCCESS
    port.setBaudRate(9600)
    start_s = time.monotonic()
    model, result, _ = handler.ping(port, 1)
    elapsed_s = time.monotonic() - start_s
    assert (model, result) == (xm430.MODEL_NUMBER, sdk.COMM_SUCCESS)
    assert elapsed_s >= ping_due_s(9600)  # lower bound only: about 25.5 ms at 9600 bps


# ---------------------------------------------------------------- timing helpers
def test_scheduler_spaces_replies_by_return_delay_and_length() -> None:
    scheduler = WireScheduler(latency_s=0.001)
    byte_s = byte_time_s(1_000_000)
    end_s = scheduler.instruction_end_s(10.0, 20, 1_000_000)
    assert end_s == pytest.approx(10.0 + 20 * byte_s)
    # the transmitter is busy until end_s: a second write queues behind the first
    assert scheduler.instruction_end_s(10.0, 5, 1_000_000) == pytest.approx(end_s + 5 * byte_s)
    replies = [Reply(b'x' * 15, 1, 0.0005), Reply(b'y' * 11, 2, 0.0)]
    (due1, data1), (due2, data2) = scheduler.schedule(end_s, replies, 1_000_000)
    assert (data1, data2) == (b'x' * 15, b'y' * 11)
    assert due1 == pytest.approx(end_s + 0.0005 + 15 * byte_s + 0.001)
    assert due2 == pytest.approx(end_s + 0.0005 + 26 * byte_s + 0.001)


def test_hybrid_wait_reaches_the_deadline_with_an_injected_clock() -> None:
    clock = FakeClock()
    hybrid_wait(clock() + 0.5, clock, clock.sleep, spin_s=0.0)
    assert clock() >= 100.5
    before = clock.slept_s
    hybrid_wait(clock() - 1.0, clock, clock.sleep, spin_s=0.0)  # already past: no sleep
    assert clock.slept_s == before


def test_lateness_stats_percentiles() -> None:
    stats = LatenessStats()
    assert stats.summary() == {'replies': 0, 'late_p50_us': 0.0, 'late_p99_us': 0.0,
                               'late_max_us': 0.0}
    for late_us in range(100, 0, -1):
        stats.record(late_us * 1e-6)
    summary = stats.summary()
    assert summary['replies'] == 100
    assert summary['late_p50_us'] == pytest.approx(50.0)
    assert summary['late_p99_us'] == pytest.approx(99.0)
    assert summary['late_max_us'] == pytest.approx(100.0)
    assert stats.line() == ('replies=100 late_p50_us=50.0 late_p99_us=99.0 '
                            'late_max_us=100.0')
