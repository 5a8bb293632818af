"""virtual_bus on a pseudo-terminal, driven by the stock dynamixel_sdk and by pyserial."""

import os
import pathlib
import signal
import subprocess
import time
from typing import Callable, Iterator, TypeVar

from dxl_servo_driver import protocol
from dxl_servo_driver.models import model_for, xm430
from dxl_servo_driver.sim.timing import byte_time_s
import dynamixel_sdk as sdk
from processes import LINE_TIMEOUT_S, StartVirtualBus, VirtualBusProcess
import pytest
import serial

MANUAL = model_for(xm430.MODEL_NUMBER)   # the XM430 manual's table

ADDR_PROFILE_ACCELERATION = MANUAL.lookup('profile_acceleration').address
ADDR_ID = MANUAL.lookup('id').address
ADDR_MODEL_NUMBER = MANUAL.lookup('model_number').address
ADDR_OPERATING_MODE = MANUAL.lookup('operating_mode').address
ADDR_TORQUE_ENABLE = MANUAL.lookup('torque_enable').address
ADDR_GOAL_VELOCITY = MANUAL.lookup('goal_velocity').address


T = TypeVar('T')


def retried(call: Callable[[], T], attempts: int = 5) -> T:
    """
    Run an SDK transaction until its comm result is COMM_SUCCESS (at most `attempts` times).

    The stock SDK gives a reply about 34 ms of wall time; on a loaded CI machine the server
    process may not be scheduled that soon, so an expected success gets a few tries. Expected
    failures (RX timeouts) are asserted without retrying.
    """
    outcome = call()
    for _ in range(attempts - 1):
        result = outcome if isinstance(outcome, int) else outcome[-2]  # type: ignore[index]
        if result == sdk.COMM_SUCCESS:
            break
        outcome = call()
    return outcome


@pytest.fixture
def bus3(virtual_bus: StartVirtualBus,
         tmp_path: pathlib.Path) -> Iterator[tuple[VirtualBusProcess, str]]:
    """Servos 1, 2, 3 at 1 Mbps behind a link; yields (server, link path)."""
    link = str(tmp_path / 'ttyDXL')
    vb = virtual_bus([1, 2, 3], 1_000_000, link, ['--seed', '5'])
    device = vb.device
    assert device is not None and device.startswith('/dev/')
    assert os.readlink(link) == device
    yield vb, link


@pytest.fixture
def handler() -> sdk.Protocol2PacketHandler:
    return sdk.PacketHandler(2.0)


def open_sdk_port(path: str, baud_bps: int) -> sdk.PortHandler:
    port = sdk.PortHandler(path)
    assert port.openPort()
    assert port.setBaudRate(baud_bps)
    return port


def test_sdk_ping_read_write_over_the_pty(bus3: tuple[VirtualBusProcess, str],
                                          handler: sdk.Protocol2PacketHandler) -> None:
    _, link = bus3
    port = open_sdk_port(link, 1_000_000)
    try:
        for servo_id in (1, 2, 3):
            expected = (xm430.MODEL_NUMBER, sdk.COMM_SUCCESS, 0)
            assert retried(lambda: handler.ping(port, servo_id)) == expected
        assert handler.ping(port, 4)[1] == sdk.COMM_RX_TIMEOUT
        address = ADDR_PROFILE_ACCELERATION
        assert retried(lambda: handler.write4ByteTxRx(port, 2, address, 77)) == (
            sdk.COMM_SUCCESS, 0)
        assert retried(lambda: handler.read4ByteTxRx(port, 2, address)) == (
            77, sdk.COMM_SUCCESS, 0)
    finally:
        port.closePort()


def test_sdk_sync_write_sync_read_and_bulk_read(bus3: tuple[VirtualBusProcess, str],
                                                handler: sdk.Protocol2PacketHandler) -> None:
    _, link = bus3
    port = open_sdk_port(link, 1_000_000)
    try:
        values = {1: 5, 2: 50, 3: 500}
        writer = sdk.GroupSyncWrite(port, handler, ADDR_PROFILE_ACCELERATION, 4)
        for servo_id, value in values.items():
            assert writer.addParam(servo_id, list(value.to_bytes(4, 'little')))
        assert writer.txPacket() == sdk.COMM_SUCCESS
        reader = sdk.GroupSyncRead(port, handler, ADDR_PROFILE_ACCELERATION, 4)
        for servo_id in values:
            assert reader.addParam(servo_id)
        assert retried(reader.txRxPacket) == sdk.COMM_SUCCESS
        for servo_id, value in values.items():
            assert reader.getData(servo_id, ADDR_PROFILE_ACCELERATION, 4) == value

        bulk = sdk.GroupBulkRead(port, handler)
        assert bulk.addParam(1, ADDR_MODEL_NUMBER, 2)
        assert bulk.addParam(2, ADDR_ID, 1)
        assert bulk.addParam(3, ADDR_PROFILE_ACCELERATION, 4)
        assert retried(bulk.txRxPacket) == sdk.COMM_SUCCESS
        assert bulk.getData(1, ADDR_MODEL_NUMBER, 2) == xm430.MODEL_NUMBER
        assert bulk.getData(2, ADDR_ID, 1) == 2
        assert bulk.getData(3, ADDR_PROFILE_ACCELERATION, 4) == 500
    finally:
        port.closePort()


def test_client_at_another_baud_gets_no_answer(bus3: tuple[VirtualBusProcess, str],
                                               handler: sdk.Protocol2PacketHandler) -> None:
    _, link = bus3
    port = open_sdk_port(link, 57600)
    try:
        assert handler.ping(port, 1)[1] == sdk.COMM_RX_TIMEOUT
        assert port.setBaudRate(1_000_000)
        assert retried(lambda: handler.ping(port, 1))[1] == sdk.COMM_SUCCESS
    finally:
        port.closePort()


def test_client_reopening_the_port_is_served_again(bus3: tuple[VirtualBusProcess, str],
                                                   handler: sdk.Protocol2PacketHandler) -> None:
    _, link = bus3
    for _ in range(2):
        port = open_sdk_port(link, 1_000_000)
        try:
            assert retried(lambda: handler.ping(port, 3))[1] == sdk.COMM_SUCCESS
        finally:
            port.closePort()


def test_custom_baud_4_5_mbps_through_termios2(virtual_bus: StartVirtualBus) -> None:
    vb = virtual_bus([7], 4_500_000)
    device = vb.device
    assert device is not None
    ping = protocol.encode_instruction(7, protocol.Instruction.PING)
    # pyserial sets 4.5 Mbps through TCSETS2/BOTHER (not a standard termios speed)
    with serial.Serial(device, 4_500_000, timeout=2.0) as ser:
        ser.reset_input_buffer()
        ser.write(ping)
        reply = ser.read(14)
    packet = protocol.decode_packet(reply)
    assert packet.servo_id == 7 and packet.error == 0
    with serial.Serial(device, 4_000_000, timeout=0.2) as ser:
        ser.reset_input_buffer()
        ser.write(ping)
        assert ser.read(14) == b''


def test_control_lines(bus3: tuple[VirtualBusProcess, str],
                       handler: sdk.Protocol2PacketHandler) -> None:
    vb, link = bus3
    assert vb.control('get 2 id') == 'ok get 2 id=2'
    assert vb.control('get 1 8') == 'ok get 1 baud_rate=3'
    dump = vb.control('dump 3')
    assert dump is not None and dump.startswith('ok dump 3 ') and ' id=3 ' in dump
    assert vb.control('nonsense 1 2') == 'error: unknown command \'nonsense\' (try "help")'
    assert vb.control('drop 1 2.0') == "error: bad probability '2.0': expected 0..1"
    assert vb.control('get 9 id').startswith('error: ')
    help_line = vb.control('help')
    assert help_line is not None and help_line.startswith('ok commands:')

    port = open_sdk_port(link, 1_000_000)
    try:
        assert vb.control('drop 1 1.0') == 'ok drop 1 1'
        assert handler.ping(port, 1)[1] == sdk.COMM_RX_TIMEOUT
        assert retried(lambda: handler.ping(port, 2))[1] == sdk.COMM_SUCCESS
        assert vb.control('drop 1 0') == 'ok drop 1 0'
        assert retried(lambda: handler.ping(port, 1))[1] == sdk.COMM_SUCCESS

        assert vb.control('unplug 2') == 'ok unplug 2'
        assert handler.ping(port, 2)[1] == sdk.COMM_RX_TIMEOUT
        assert vb.control('plug 2') == 'ok plug 2'
        deadline_s = time.monotonic() + 5.0  # the servo boots before it answers again
        while handler.ping(port, 2)[1] != sdk.COMM_SUCCESS:
            assert time.monotonic() < deadline_s, 'servo 2 never came back after plug'

        assert vb.control('error 3 overload') == 'ok error 3 overload'
        _, result, error = retried(lambda: handler.ping(port, 3))
        assert result == sdk.COMM_SUCCESS and error & protocol.ALERT_BIT
    finally:
        port.closePort()
    stats = vb.control('stats')
    assert stats is not None and stats.startswith('ok stats replies=')
    fields = dict(token.split('=') for token in stats.split()[2:])
    assert set(fields) == {'replies', 'late_p50_us', 'late_p99_us', 'late_max_us'}
    assert int(fields['replies']) >= 4  # the answered pings above


def test_models_and_firmware_options(virtual_bus: StartVirtualBus,
                                     handler: sdk.Protocol2PacketHandler) -> None:
    vb = virtual_bus([1, 2], 1_000_000, extra_args=['--models', 'XL430-W250', '1200',
                                                    '--firmware', '52'])
    port = open_sdk_port(vb.device, 1_000_000)
    try:
        assert retried(lambda: handler.ping(port, 1)) == (1060, sdk.COMM_SUCCESS, 0)
        assert retried(lambda: handler.ping(port, 2)) == (1200, sdk.COMM_SUCCESS, 0)
        # Firmware 52: the X330's old table, Indirect Data 1 at 208 (pointing at itself).
        assert retried(lambda: handler.read2ByteTxRx(port, 2, 168)) == (208, sdk.COMM_SUCCESS, 0)
        # The XL430 has no Goal Current (102): access error.
        assert retried(lambda: handler.write2ByteTxRx(port, 1, 102, 0)) == (sdk.COMM_SUCCESS, 7)
    finally:
        port.closePort()
    assert vb.control('get 2 firmware_version') == 'ok get 2 firmware_version=52'
    assert vb.control('get 1 126') == 'ok get 1 present_load=0'
    # The start line names the models; it is on stderr, stdout's first line being the device.
    start = f'virtual_bus: {vb.device}: id 1 XL430-W250 (model 1060, firmware 52), ' \
            'id 2 XL330-M288 (model 1200, firmware 52)'
    deadline_s = time.monotonic() + LINE_TIMEOUT_S
    while start not in vb.stderr_text().splitlines():
        assert time.monotonic() < deadline_s, vb.stderr_text()
        time.sleep(0.01)


def test_shared_ids_and_unplugged_servos_on_the_start_line(
        virtual_bus: StartVirtualBus, handler: sdk.Protocol2PacketHandler) -> None:
    vb = virtual_bus([1, 1, 2], 1_000_000, unplugged=True)
    start = f'virtual_bus: {vb.device}: #1 id 1 XM430-W210 (model 1030, firmware 45) ' \
        'unplugged, #2 id 1 XM430-W210 (model 1030, firmware 45) unplugged, ' \
        'id 2 XM430-W210 (model 1030, firmware 45) unplugged'
    deadline_s = time.monotonic() + LINE_TIMEOUT_S
    while start not in vb.stderr_text().splitlines():
        assert time.monotonic() < deadline_s, vb.stderr_text()
        time.sleep(0.01)
    port = open_sdk_port(vb.device, 1_000_000)
    try:
        assert handler.ping(port, 2)[1] == sdk.COMM_RX_TIMEOUT   # unplugged
        assert vb.control('plug 2') == 'ok plug 2'
        assert vb.control('plug 1') == \
            'error: id 1 is ambiguous: servos #1, #2 have it; name one as #N'
        deadline_s = time.monotonic() + LINE_TIMEOUT_S   # it boots before it answers
        while handler.ping(port, 2)[1] != sdk.COMM_SUCCESS:
            assert time.monotonic() < deadline_s, 'servo 2 never answered after plug'
    finally:
        port.closePort()
    assert vb.get('#2', 'id') == 1 and vb.get(2, 'id') == 2


def test_binary_garbage_on_stdin_is_one_error_line(virtual_bus: StartVirtualBus) -> None:
    vb = virtual_bus([1])
    assert vb.device is not None
    assert vb.proc.stdin is not None
    os.write(vb.proc.stdin.fileno(), b'\xff\xfe\x00 junk\r\n')
    answer = vb.next_line()
    assert answer is not None and answer.startswith('error: unknown command')
    assert vb.control('get 1 id') == 'ok get 1 id=1'
    assert vb.proc.poll() is None


def test_wire_timing_paces_replies(virtual_bus: StartVirtualBus,
                                   handler: sdk.Protocol2PacketHandler) -> None:
    vb = virtual_bus([1], 57600, extra_args=['--timing', 'wire', '--latency-ms', '2',
                                             '--return-delay-time', '100'])
    device = vb.device
    assert device is not None
    assert vb.control('get 1 return_delay_time') == 'ok get 1 return_delay_time=100'
    port = open_sdk_port(device, 57600)
    try:
        minimum_s = 24 * byte_time_s(57600) + 100 * 2e-6 + 0.002
        for _ in range(3):
            start_s = time.monotonic()
            assert retried(lambda: handler.ping(port, 1))[1] == sdk.COMM_SUCCESS
            assert time.monotonic() - start_s >= minimum_s  # lower bound only
    finally:
        port.closePort()
    stats = vb.control('stats')
    assert stats is not None and stats.startswith('ok stats replies=')
    assert int(stats.split()[2].split('=')[1]) >= 3


def test_trace_state_logs_present_position_on_the_wall_clock(
        virtual_bus: StartVirtualBus, tmp_path: pathlib.Path,
        handler: sdk.Protocol2PacketHandler) -> None:
    trace = tmp_path / 'state.txt'
    start_s = time.time()
    vb = virtual_bus([1, 2], 1_000_000, extra_args=['--trace-state', str(trace)])
    port = open_sdk_port(vb.device, 1_000_000)
    try:
        # Servo 1 turns (velocity mode), so its position differs at every read below.
        assert retried(lambda: handler.write1ByteTxRx(port, 1, ADDR_OPERATING_MODE, 1)) == (
            sdk.COMM_SUCCESS, 0)
        assert retried(lambda: handler.write1ByteTxRx(port, 1, ADDR_TORQUE_ENABLE, 1)) == (
            sdk.COMM_SUCCESS, 0)
        assert retried(lambda: handler.write4ByteTxRx(port, 1, ADDR_GOAL_VELOCITY, 200)) == (
            sdk.COMM_SUCCESS, 0)
    finally:
        port.closePort()
    reads = []   # (wall time before the get, value)
    for _ in range(3):
        time.sleep(0.05)
        before_s = time.time()
        reads.append((before_s, vb.get(1, 'present_position')))
    time.sleep(0.05)
    assert vb.stop() == 0   # the trace file is complete once the server has exited
    end_s = time.time()
    samples: dict[int, list[tuple[float, int]]] = {1: [], 2: []}
    for line in trace.read_text().splitlines():
        stamp, servo_id, value = line.split()
        samples[int(servo_id)].append((float(stamp), int(value)))
    for servo_samples in samples.values():
        stamps = [stamp for stamp, _ in servo_samples]
        assert len(stamps) > 10
        assert stamps == sorted(set(stamps))
        assert start_s <= stamps[0] and stamps[-1] <= end_s   # time.time(), not monotonic
        # Every 2 ms, never more often. (How much later a busy machine lets the server sample is
        # the machine's, not the server's.)
        gaps = sorted(b - a for a, b in zip(stamps, stamps[1:]))
        assert 0.001 <= gaps[len(gaps) // 2]
    assert [value for _, value in reads] == sorted({value for _, value in reads})   # turning
    # Nothing advances the physics between two gets (no bus traffic, instant timing): each
    # value read shows up in the trace after its get was asked, never before.
    bounds = [before_s for before_s, _ in reads] + [end_s]
    for (before_s, value), next_s in zip(reads, bounds[1:]):
        stamps = [stamp for stamp, traced in samples[1] if traced == value]
        assert stamps and before_s <= stamps[0] < next_s, (before_s, value, stamps[:3])


def test_stdin_at_eof_does_not_stop_the_server(virtual_bus: StartVirtualBus,
                                               handler: sdk.Protocol2PacketHandler) -> None:
    vb = virtual_bus([1], 1_000_000, stdin=subprocess.DEVNULL)
    device = vb.device
    assert device is not None
    time.sleep(0.2)  # stdin EOF has been seen by now
    assert vb.proc.poll() is None
    port = open_sdk_port(device, 1_000_000)
    try:
        assert retried(lambda: handler.ping(port, 1))[1] == sdk.COMM_SUCCESS
    finally:
        port.closePort()


@pytest.mark.parametrize('sig', [signal.SIGTERM, signal.SIGINT])
def test_signal_exits_cleanly_and_removes_the_link(virtual_bus: StartVirtualBus,
                                                   tmp_path: pathlib.Path, sig: int) -> None:
    link = tmp_path / 'ttyDXL'
    vb = virtual_bus([1], link=link)
    device = vb.device
    assert device is not None and os.readlink(link) == device
    assert vb.stop(sig) == 0
    assert not vb.left_link   # virtual_bus removed it, not the helper's clean-up
    assert not os.path.lexists(link)
    assert vb.next_line() is None  # nothing else printed


def test_link_path_taken_is_refused(virtual_bus: StartVirtualBus,
                                    tmp_path: pathlib.Path) -> None:
    link = tmp_path / 'ttyDXL'
    link.write_text('mine')
    vb = virtual_bus([1], link=link, expect_device=False)
    assert vb.proc.wait(timeout=LINE_TIMEOUT_S) != 0
    assert vb.next_line() is None  # no device path on stdout
    err = vb.stderr_lines()
    assert len(err) == 1 and 'taken' in err[0] and str(link) in err[0]
    assert link.read_text() == 'mine'


def test_symlink_to_something_else_is_refused(virtual_bus: StartVirtualBus,
                                              tmp_path: pathlib.Path) -> None:
    link = tmp_path / 'ttyDXL'
    os.symlink('/dev/null', link)
    vb = virtual_bus([1], link=link, expect_device=False)
    assert vb.proc.wait(timeout=LINE_TIMEOUT_S) != 0
    assert os.readlink(link) == '/dev/null'


def test_stale_link_of_ours_is_replaced(virtual_bus: StartVirtualBus,
                                        tmp_path: pathlib.Path) -> None:
    link = tmp_path / 'ttyDXL'
    os.symlink('/dev/pts/987654', link)  # a pty that no longer exists
    vb = virtual_bus([1], link=link)
    device = vb.device
    assert device is not None and os.readlink(link) == device
    assert vb.stop() == 0
    assert not vb.left_link   # virtual_bus removed it, not the helper's clean-up
    assert not os.path.lexists(link)


@pytest.mark.parametrize('args', [
    ['--baud', '1000000'],                      # no --ids
    ['--ids', '1', '--baud', '12345'],          # not a servo baud
    ['--ids', '300'],                           # id out of range
    ['--ids', '1', '1', '--models', '1060', '1060', '1060'],   # one per id: 2 ids, 3 models
    ['--ids', 'x'],
    ['--ids', '1', '--timing', 'slow'],
    ['--ids', '1', '--latency-ms', '1'],        # latency without wire timing
    ['--ids', '1', '--return-delay-time', '255'],
    ['--ids', '1', '--trace-state', '/nonexistent/dir/state.txt'],
    ['--ids', '1', '--models', 'XL999-W1'],     # no such model
    ['--ids', '1', '2', '3', '--models', '1060', '1060'],   # neither one nor one per id
    ['--ids', '1', '--models', 'XL330-M288', '--baud', '4500000'],  # above the X330's 4 Mbps
    ['--ids', '1', '--firmware', '-1'],
])
def test_bad_arguments_one_line_and_nonzero_exit(virtual_bus: StartVirtualBus,
                                                 args: list[str]) -> None:
    vb = virtual_bus(extra_args=args, expect_device=False)
    assert vb.proc.wait(timeout=LINE_TIMEOUT_S) != 0
    assert vb.next_line() is None
    err = vb.stderr_lines()
    assert len(err) == 1 and 'error' in err[0]
