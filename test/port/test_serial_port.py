"""
The serial transport on a pseudo-terminal: one descriptor per open port, only PortError out.

A pty stands in for the USB adapter: its slave is the device the port opens, its master the far
end (the adapter's side). Each broken state the field produces (the port closed, the far end
gone while bytes still wait, a hang-up, a descriptor closed under the port, no descriptor at
all) must give PortError from every operation, at the port and at the bus above it, and never
an exception of the serial library or the OS; close() never raises.
"""

import os
import pathlib
import time
from typing import Callable, Dict, Iterator, List, Tuple

from dxl_servo_driver.bus import Bus
from dxl_servo_driver.errors import PortError
from dxl_servo_driver.port.serial_device import open_port, SerialPort
from dxl_servo_driver.port.termios2 import set_tty_speed
import pytest

BAUD = 1_000_000
ZERO_TORQUE = (1, 64, b'\x00')   # id, address, data
NOT_A_DESCRIPTOR = 1 << 20   # above any descriptor limit: EBADF


@pytest.fixture
def pty() -> Iterator[Tuple[int, str]]:
    """Yield (master fd, slave path) of a raw pty at the servos' speed; closed afterwards."""
    master, slave = os.openpty()
    set_tty_speed(slave, BAUD)
    path = os.ttyname(slave)
    os.close(slave)   # the port opens it by its path, as a device
    state = {'master': master}
    yield master, path
    try:
        os.close(state['master'])
    except OSError:
        pass   # the test closed it (the far end gone)


def open_fds() -> List[str]:
    return sorted(os.listdir('/proc/self/fd'))


# Each break returns the descriptor it took from the port (closed by the test), or -1.
def break_closed(port: SerialPort, master: int) -> int:
    port.close()
    return -1


def break_half_open(port: SerialPort, master: int) -> int:
    # The adapter goes away while a reply is still buffered: the bytes may come, then EIO.
    os.write(master, b'\xff\xff\xfd\x00')
    os.close(master)
    return -1


def break_hangup(port: SerialPort, master: int) -> int:
    os.close(master)   # reads and writes of the slave now fail with EIO
    return -1


def break_ebadf(port: SerialPort, master: int) -> int:
    # A descriptor number that is not open (one closed under the port could be reused by
    # another thread of this process meanwhile).
    taken, port._fd = port._fd, NOT_A_DESCRIPTOR
    return taken


def break_no_fd(port: SerialPort, master: int) -> int:
    # As a closed pyserial object: no descriptor.
    taken, port._fd = port._fd, None  # type: ignore[assignment]
    return taken


BREAKS: Dict[str, Callable[[SerialPort, int], int]] = {
    'closed': break_closed, 'half-open': break_half_open, 'EIO': break_hangup,
    'EBADF': break_ebadf, 'None fd': break_no_fd,
}
OPERATIONS: Dict[str, Callable[[SerialPort], object]] = {
    'write': lambda port: port.write(b'\x01\x02'),
    'read': lambda port: port.read(8, 0.02),
    'in_waiting': lambda port: port.in_waiting,
    'reset_input_buffer': lambda port: port.reset_input_buffer(),
    'set baud': lambda port: setattr(port, 'baudrate', 57600),
}


def test_an_open_port_holds_one_descriptor_and_close_gives_it_back(
        pty: Tuple[int, str]) -> None:
    _, path = pty
    before = open_fds()
    port = open_port(path, BAUD)
    assert len(open_fds()) == len(before) + 1   # pyserial's pipes and descriptor are gone
    port.close()
    port.close()   # idempotent
    assert open_fds() == before


def test_the_port_works_both_ways(pty: Tuple[int, str]) -> None:
    master, path = pty
    port = open_port(path, BAUD)
    try:
        assert port.write(b'ping') == 4
        assert os.read(master, 16) == b'ping'
        os.write(master, b'pong')
        assert port.read(4, 1.0) == b'pong'
        os.write(master, b'xyz')
        assert port.read(8, 0.05) == b'xyz'   # the deadline: what came
        os.write(master, b'late')
        # The pty hands the bytes over when the kernel gets to it: wait for them, not a count.
        deadline = time.monotonic() + 5.0
        while port.in_waiting < 4:
            assert time.monotonic() < deadline, f'{port.in_waiting} of 4 bytes waiting'
            time.sleep(0.001)
        port.reset_input_buffer()
        assert port.in_waiting == 0
        port.baudrate = 57600
        assert port.baudrate == 57600
    finally:
        port.close()


@pytest.mark.parametrize('state', sorted(BREAKS))
@pytest.mark.parametrize('operation', sorted(OPERATIONS))
def test_a_broken_port_raises_port_error_only(pty: Tuple[int, str], state: str,
                                              operation: str) -> None:
    master, path = pty
    port = open_port(path, BAUD)
    taken = -1
    try:
        taken = BREAKS[state](port, master)
        call = OPERATIONS[operation]
        # Some calls may still succeed once (bytes buffered before a hang-up, a flush of a hung
        # up tty); none may raise anything but PortError, and reads fail for good in the end.
        try:
            call(port)
        except PortError:
            pass
        with pytest.raises(PortError):
            for _ in range(3):
                port.read(8, 0.01)
    finally:
        port.close()
        if taken >= 0:
            os.close(taken)


@pytest.mark.parametrize('state', sorted(BREAKS))
def test_the_bus_on_a_broken_port_raises_port_error_only(pty: Tuple[int, str],
                                                         state: str) -> None:
    master, path = pty
    port = open_port(path, BAUD)
    bus = Bus(port, BAUD, latency_timer_s=0.001, return_delay_s=0.0)
    taken = -1
    try:
        taken = BREAKS[state](port, master)
        for action in (lambda: bus.write(*ZERO_TORQUE), lambda: bus.ping(1),
                       lambda: bus.sync_read(224, 10, [1, 2]),
                       lambda: bus.sync_write(116, 4, [(1, b'\0\0\0\0')])):
            with pytest.raises(PortError):
                action()
                action()   # a write with no reply to wait for may pass once, before the EIO
    finally:
        bus.close()
        if taken >= 0:
            os.close(taken)


def test_failed_opens_leave_no_descriptor(tmp_path: pathlib.Path, pty: Tuple[int, str]) -> None:
    _, path = pty
    before = open_fds()
    regular = tmp_path / 'not_a_tty'
    regular.write_text('')
    for device in (str(tmp_path / 'missing'), str(regular), '/dev/null'):
        for _ in range(20):
            with pytest.raises(PortError):
                open_port(device, BAUD)
    holder = open_port(path, BAUD)
    try:
        for _ in range(20):
            with pytest.raises(PortError, match='busy'):
                open_port(path, BAUD)   # the exclusive lock is held by the first
    finally:
        holder.close()
    assert open_fds() == before
