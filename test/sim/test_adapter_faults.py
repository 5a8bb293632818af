"""The faulty-adapter fixture itself: FaultyPort over SimPortHandler, AdapterProxy over a pty."""

import os
import threading
import time
from typing import Callable, Iterator, TypeVar

from dxl_servo_driver import protocol
from dxl_servo_driver.models import model_for, xm430
from dxl_servo_driver.protocol import encode_instruction, HEADER, Instruction
from dxl_servo_driver.sim.adapter_proxy import AdapterProxy
from dxl_servo_driver.sim.bus import SimBus
from dxl_servo_driver.sim.fault_engine import FaultEngine, Faults, PARTIAL_FLUSH_S
from dxl_servo_driver.sim.faulty_port import FaultyPort
from dxl_servo_driver.sim.port import SimPortDisconnected, SimPortHandler
from dxl_servo_driver.sim.virtual_bus import configure_servos, tty_speed_bps
import dynamixel_sdk as sdk
from processes import StartVirtualBus
import pytest
import serial

MANUAL = model_for(xm430.MODEL_NUMBER)   # the XM430 manual's table

BAUD = 1_000_000
ADDR_ID = MANUAL.lookup('id').address
ADDR_MODEL_NUMBER = MANUAL.lookup('model_number').address
T = TypeVar('T')


def read_request(servo_id: int, name: str) -> bytes:
    """Return a READ instruction packet for one register."""
    item = MANUAL.lookup(name)
    params = item.address.to_bytes(2, 'little') + item.size.to_bytes(2, 'little')
    return encode_instruction(servo_id, Instruction.READ, params)


PING_1 = encode_instruction(1, Instruction.PING)
PING_2 = encode_instruction(2, Instruction.PING)
READ_MODEL_1 = read_request(1, 'model_number')
READ_ID_2 = read_request(2, 'id')
REQUESTS = (PING_1, PING_2, READ_MODEL_1, READ_ID_2)
# A blocking read that must end when its bytes come: given this long, it is told from one that
# waits its own timeout out by half of it, whatever a busy machine adds to the wait.
READ_TIMEOUT_S = 30.0


@pytest.fixture
def sim() -> SimBus:
    bus = SimBus([1, 2], seed=1, boot_time_s=0.0)
    configure_servos(bus, BAUD, None)
    return bus


@pytest.fixture
def port(sim: SimBus) -> Iterator[FaultyPort]:
    faulty = FaultyPort(SimPortHandler(sim, 'sim', BAUD), seed=3)
    yield faulty
    faulty.close()


def plain_reply(sim: SimBus, request: bytes) -> bytes:
    """Return the servos' reply to request through a port without faults."""
    plain = SimPortHandler(sim, 'sim', BAUD)
    plain.write(request)
    reply = plain.read(1024, 0.0)
    assert protocol.decode_packet(reply).error == 0, reply.hex()
    return reply


# ---------------------------------------------------------------- FaultyPort over SimPortHandler
def test_without_faults_replies_pass_unchanged(sim: SimBus, port: FaultyPort) -> None:
    for request in REQUESTS:
        expected = plain_reply(sim, request)
        assert port.write(request) == len(request)
        assert port.in_waiting == len(expected)
        assert port.read(len(expected), 0.5) == expected
    assert port.in_waiting == 0
    counts = port.stats.as_dict()
    assert counts.pop('replies') == len(REQUESTS)
    assert set(counts.values()) == {0}, counts
    assert port.baudrate == BAUD


def test_echo_returns_the_request_before_the_reply(sim: SimBus, port: FaultyPort) -> None:
    port.set(echo=True)
    for request in (PING_1, READ_ID_2):
        reply = plain_reply(sim, request)
        port.write(request)
        assert port.read(len(request) + len(reply), 0.5) == request + reply
    assert port.stats.echoed_bytes == len(PING_1) + len(READ_ID_2)
    port.set(echo=False)
    port.write(PING_1)
    assert port.read(64, 0.05) == plain_reply(sim, PING_1)


def test_freeze_holds_replies_then_delivers_them_in_order(sim: SimBus,
                                                          port: FaultyPort) -> None:
    first, second = plain_reply(sim, PING_1), plain_reply(sim, READ_ID_2)
    port.write(PING_2)  # received before the freeze: stays readable
    early = plain_reply(sim, PING_2)
    start_s = time.monotonic()
    port.freeze(0.15)
    port.write(PING_1)
    port.write(READ_ID_2)
    waiting = port.in_waiting
    if time.monotonic() - start_s < 0.15:
        assert waiting == len(early)
    assert port.read(len(early), 0.5) == early
    data = port.read(len(first) + len(second), READ_TIMEOUT_S)
    elapsed_s = time.monotonic() - start_s
    assert data == first + second
    # Woken when the freeze ended, not at the read's own timeout.
    assert 0.15 <= elapsed_s < 0.5 * READ_TIMEOUT_S
    assert port.stats.freezes == 1


def test_random_freeze_starts_at_a_reply(sim: SimBus, port: FaultyPort) -> None:
    reply = plain_reply(sim, PING_1)
    port.set(freeze_probability=1.0, freeze_ms=(60.0, 60.0))
    start_s = time.monotonic()
    port.write(PING_1)
    waiting = port.in_waiting
    if time.monotonic() - start_s < 0.06:
        assert waiting == 0
    assert port.read(len(reply), 1.0) == reply
    assert time.monotonic() - start_s >= 0.06
    assert port.stats.freezes == 1
    port.set(freeze_probability=0.0)
    port.write(PING_1)
    assert port.in_waiting == len(reply)


def test_late_copy_of_an_earlier_reply_arrives_in_a_later_transaction(
        sim: SimBus, port: FaultyPort) -> None:
    first, second, third = (plain_reply(sim, r) for r in (PING_1, PING_2, READ_ID_2))
    port.write(PING_1)
    assert port.read(len(first), 0.5) == first
    port.set(late_probability=1.0, late_ms=(80.0, 80.0))
    written_s = time.monotonic()
    port.write(PING_2)  # the only earlier reply is the first: its copy is due in 80 ms
    assert port.read(len(second), 0.5) == second
    port.set(late_probability=0.0)
    assert port.stats.late == 1
    time.sleep(0.1)
    port.write(READ_ID_2)
    assert port.read(len(first) + len(third), 0.5) == first + third
    assert time.monotonic() - written_s >= 0.08
    assert port.in_waiting == 0


def test_late_copy_blocks_a_read_until_it_is_due(sim: SimBus, port: FaultyPort) -> None:
    first = plain_reply(sim, PING_1)
    port.write(PING_1)
    port.read(len(first), 0.5)
    port.set(late_probability=1.0, late_ms=(80.0, 80.0))
    written_s = time.monotonic()
    port.write(PING_2)
    data = port.read(len(first) + 14, 1.0)
    assert data[-len(first):] == first
    assert time.monotonic() - written_s >= 0.08


def test_duplicate_delivers_a_reply_twice(sim: SimBus, port: FaultyPort) -> None:
    reply = plain_reply(sim, PING_1)
    port.set(duplicate_probability=1.0)
    port.write(PING_1)
    assert port.read(2 * len(reply), 0.5) == reply + reply
    assert port.in_waiting == 0
    assert port.stats.duplicated == 1


def test_truncate_cuts_the_tail_keeping_at_least_one_byte(sim: SimBus,
                                                          port: FaultyPort) -> None:
    full = plain_reply(sim, READ_MODEL_1)
    port.set(truncate_probability=1.0)
    lengths = set()
    for _ in range(20):
        port.write(READ_MODEL_1)
        data = port.read(port.in_waiting, 0.1)
        assert 1 <= len(data) < len(full) and full.startswith(data), data.hex()
        lengths.add(len(data))
    assert len(lengths) > 3, lengths
    assert port.stats.truncated == 20


def test_noise_is_inserted_before_replies(sim: SimBus, port: FaultyPort) -> None:
    reply = plain_reply(sim, PING_1)
    port.set(noise_probability=1.0, noise_bytes=(4, 12))
    noises = []
    for _ in range(40):
        port.write(PING_1)
        data = port.read(port.in_waiting, 0.1)
        assert data.endswith(reply)
        noises.append(data[:-len(reply)])
    assert all(4 <= len(noise) <= 12 for noise in noises), noises
    assert len(set(noises)) == len(noises)
    # Biased towards header fragments and whole headers with bogus length fields.
    assert sum(HEADER[:2] in noise for noise in noises) >= 8
    assert any(HEADER in noise[:-3] for noise in noises)
    assert port.stats.noise == 40 and port.stats.noise_bytes == sum(map(len, noises))


def test_drop_loses_the_reply(sim: SimBus, port: FaultyPort) -> None:
    reply = plain_reply(sim, PING_1)
    port.set(drop_probability=1.0)
    port.write(PING_1)
    assert port.read(1, 0.05) == b''
    assert port.stats.dropped == 1
    port.clear()
    assert port.faults == Faults()
    port.write(PING_1)
    assert port.read(len(reply), 0.5) == reply


def test_delay_jitter_keeps_the_order(sim: SimBus, port: FaultyPort) -> None:
    replies = [plain_reply(sim, request) for request in REQUESTS]
    port.set(delay_ms=(100.0, 150.0))
    start_s = time.monotonic()
    for request in REQUESTS:
        port.write(request)
    waiting = port.in_waiting
    if time.monotonic() - start_s < 0.1:
        assert waiting == 0
    assert port.read(sum(map(len, replies)), 2.0) == b''.join(replies)
    assert time.monotonic() - start_s >= 0.1
    assert port.stats.delayed == len(REQUESTS)


def test_reset_input_buffer_keeps_bytes_in_flight(sim: SimBus, port: FaultyPort) -> None:
    second = plain_reply(sim, PING_2)
    port.write(PING_1)
    port.freeze(5.0)   # ended by clear() below, not by the clock
    port.write(PING_2)
    port.reset_input_buffer()
    assert port.in_waiting == 0
    port.clear()
    assert port.in_waiting == len(second)
    assert port.read(len(second), 0.5) == second


def test_read_blocks_until_due_and_sleeps(sim: SimBus, port: FaultyPort) -> None:
    reply = plain_reply(sim, PING_1)
    port.set(delay_ms=(200.0, 200.0))
    start_s = time.monotonic()
    port.write(PING_1)
    written_s = time.monotonic()
    cpu_s = time.process_time()
    data = port.read(len(reply), READ_TIMEOUT_S)
    cpu_s = time.process_time() - cpu_s
    done_s = time.monotonic()
    assert data == reply
    assert done_s - start_s >= 0.2
    assert done_s - written_s < 0.5 * READ_TIMEOUT_S   # when due, not at its own timeout
    assert cpu_s < 0.05, f'{cpu_s:.3f} s of CPU in a 0.2 s blocking read'
    # Nothing in flight: the read sleeps out its timeout (a real UART), as cheaply.
    cpu_s = time.process_time()
    start_s = time.monotonic()
    assert port.read(1, 0.2) == b''
    assert time.monotonic() - start_s >= 0.2
    assert time.process_time() - cpu_s < 0.05


def test_a_blocked_read_sees_writes_and_faults_from_another_thread(
        sim: SimBus, port: FaultyPort) -> None:
    reply = plain_reply(sim, PING_1)
    got: list[tuple[bytes, float]] = []

    def reader() -> None:
        data = port.read(len(reply), READ_TIMEOUT_S)
        got.append((data, time.monotonic()))

    thread = threading.Thread(target=reader)
    thread.start()
    time.sleep(0.05)   # (blocked by now, most likely: the reply comes the same either way)
    start_s = time.monotonic()
    port.freeze(0.1)
    port.write(PING_1)
    thread.join(2.0 * READ_TIMEOUT_S)
    assert not thread.is_alive()
    assert got and got[0][0] == reply
    # Woken by the write and the freeze's end, not at the read's own timeout.
    assert 0.1 <= got[0][1] - start_s < 0.5 * READ_TIMEOUT_S


def test_unplug_and_plug_propagate(sim: SimBus, port: FaultyPort) -> None:
    reply = plain_reply(sim, PING_1)
    port.freeze(5.0)
    port.write(PING_1)
    port.unplug_port()
    with pytest.raises(SimPortDisconnected):
        port.write(PING_1)
    with pytest.raises(OSError):
        port.read(1, 0.05)
    with pytest.raises(OSError):
        port.in_waiting
    with pytest.raises(OSError):
        port.reset_input_buffer()
    port.plug_port()
    port.clear()
    assert port.in_waiting == 0   # what the adapter held was lost with it
    port.write(PING_1)
    assert port.read(len(reply), 0.5) == reply


def test_settings_are_checked() -> None:
    engine = FaultEngine()
    with pytest.raises(ValueError):
        engine.set(drop_probability=1.5)
    with pytest.raises(ValueError):
        engine.set(late_ms=(5.0, 1.0))
    with pytest.raises(ValueError):
        engine.set(noise_bytes=(0, 3))
    with pytest.raises(TypeError):
        engine.set(nonsense=1.0)
    with pytest.raises(ValueError):
        Faults(freeze_probability=-0.1).check()
    assert engine.faults == Faults()


# ---------------------------------------------------------------- the engine's framing
STATUS = protocol.encode_status(1, 0, bytes((0x06, 0x04, 0x26)))


def test_garbage_passes_unchanged_around_a_dropped_reply() -> None:
    engine = FaultEngine(Faults(drop_probability=1.0))
    engine.servo_bytes(b'\x01\x02' + STATUS + b'\x03\xff', 10.0)
    # The trailing FF could start a header: it waits for the rest, then passes alone.
    assert engine.take(10.0, 100) == b'\x01\x02\x03'
    assert engine.take(10.0 + 2 * PARTIAL_FLUSH_S, 100) == b'\xff'
    assert (engine.stats.dropped, engine.stats.passed_bytes) == (1, 4)


def test_a_reply_split_across_chunks_is_one_packet() -> None:
    engine = FaultEngine(Faults(duplicate_probability=1.0))
    engine.servo_bytes(STATUS[:5], 10.0)
    engine.servo_bytes(STATUS[5:], 10.001)
    assert engine.take(10.001, 100) == STATUS + STATUS


def test_bogus_headers_pass_and_the_reply_behind_them_is_found() -> None:
    engine = FaultEngine(Faults(duplicate_probability=1.0))
    bad_length = HEADER + b'\x01\x01\x00'          # length below 3: noise at once
    engine.servo_bytes(bad_length + STATUS, 10.0)
    assert engine.take(10.0, 100) == bad_length + STATUS + STATUS
    swallowing = HEADER + b'\x01\x20\x00'          # claims 32 more bytes: swallows the reply
    engine.servo_bytes(swallowing + STATUS, 11.0)
    assert engine.take(11.0, 100) == b''
    assert engine.take(11.0 + 2 * PARTIAL_FLUSH_S, 100) == swallowing + STATUS + STATUS
    assert engine.stats.replies == 2


# ---------------------------------------------------------------- AdapterProxy over virtual_bus
def retried(call: Callable[[], T], attempts: int = 5) -> T:
    """Run an SDK transaction until COMM_SUCCESS (a loaded machine may miss the SDK's timeout)."""
    outcome = call()
    for _ in range(attempts - 1):
        result = outcome if isinstance(outcome, int) else outcome[-2]  # type: ignore[index]
        if result == sdk.COMM_SUCCESS:
            break
        outcome = call()
    return outcome


def open_fds() -> set[str]:
    return set(os.listdir('/proc/self/fd'))


def test_proxy_serves_the_stock_sdk_at_1_mbps(virtual_bus: StartVirtualBus) -> None:
    vb = virtual_bus([1, 2], BAUD)
    handler = sdk.PacketHandler(2.0)
    with AdapterProxy(vb.device) as proxy:
        client = sdk.PortHandler(proxy.path)
        assert client.openPort() and client.setBaudRate(BAUD)
        try:
            for servo_id in (1, 2):
                assert retried(lambda: handler.ping(client, servo_id)) == (
                    xm430.MODEL_NUMBER, sdk.COMM_SUCCESS, 0)
            assert retried(lambda: handler.read1ByteTxRx(client, 2, ADDR_ID)) == (
                2, sdk.COMM_SUCCESS, 0)
            assert retried(lambda: handler.read2ByteTxRx(client, 1, ADDR_MODEL_NUMBER)) == (
                xm430.MODEL_NUMBER, sdk.COMM_SUCCESS, 0)
        finally:
            client.closePort()
        assert proxy.upstream_baud == BAUD
        assert proxy.stats.replies >= 4
        assert proxy.error is None and not proxy.upstream_lost


def test_proxy_echo_and_faults_through_the_pty(virtual_bus: StartVirtualBus) -> None:
    vb = virtual_bus([1], BAUD)
    with AdapterProxy(vb.device, Faults(echo=True)) as proxy:
        with serial.Serial(proxy.path, BAUD, timeout=2.0) as ser:
            ser.write(PING_1)
            assert ser.read(len(PING_1)) == PING_1
            reply = ser.read(14)
            assert protocol.decode_packet(reply).servo_id == 1
            proxy.set(echo=False, duplicate_probability=1.0)
            ser.write(PING_1)
            assert ser.read(2 * len(reply)) == reply + reply
            proxy.clear()
            proxy.freeze(0.15)
            start_s = time.monotonic()
            ser.write(PING_1)
            assert ser.read(len(reply)) == reply
            assert time.monotonic() - start_s >= 0.15
        assert proxy.stats.echoed_bytes == len(PING_1)
        assert proxy.error is None


def test_proxy_propagates_the_client_baud_incl_4_5_mbps(virtual_bus: StartVirtualBus) -> None:
    vb = virtual_bus([7], 4_500_000)
    ping = encode_instruction(7, Instruction.PING)
    upstream = os.open(vb.device, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        with AdapterProxy(vb.device) as proxy:
            assert proxy.upstream_baud == 4_500_000
            with serial.Serial(proxy.path, BAUD, timeout=0.2) as ser:
                ser.write(ping)
                assert ser.read(14) == b''   # the servo listens at 4.5 Mbps only
                assert tty_speed_bps(upstream) == BAUD
                # pyserial sets 4.5 Mbps through termios2 (BOTHER); the stock SDK refuses it
                ser.baudrate = 4_500_000
                ser.timeout = 2.0
                ser.write(ping)
                reply = ser.read(14)
            assert protocol.decode_packet(reply).servo_id == 7
            assert tty_speed_bps(upstream) == 4_500_000
    finally:
        os.close(upstream)


def test_proxy_stop_closes_every_fd_and_ends_its_thread(virtual_bus: StartVirtualBus) -> None:
    vb = virtual_bus([1], BAUD)
    fds, threads = open_fds(), set(threading.enumerate())
    with pytest.raises(OSError):
        AdapterProxy('/nonexistent/tty').start()
    assert open_fds() == fds
    # Late copies due in a minute: a stop that waited for them would take it.
    proxy = AdapterProxy(vb.device, Faults(late_probability=1.0, late_ms=(60000.0, 60000.0)))
    path = proxy.start()
    assert path == proxy.path and path.startswith('/dev/')
    assert len(open_fds() - fds) == 5   # pty master and slave, upstream, wake pipe
    assert len(set(threading.enumerate()) - threads) == 1
    with serial.Serial(path, BAUD, timeout=2.0) as ser:
        for _ in range(2):
            ser.write(PING_1)
            assert len(ser.read(14)) == 14
    assert proxy.engine.in_flight() > 0   # a late copy is still scheduled
    start_s = time.monotonic()
    proxy.stop()
    proxy.stop()
    assert time.monotonic() - start_s < 30.0   # (half the minute: nothing of a wait)
    assert open_fds() == fds
    assert set(threading.enumerate()) == threads
    assert proxy.error is None
