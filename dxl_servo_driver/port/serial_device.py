"""
The serial transport: one tty device, read and written through a descriptor of its own.

pyserial opens the device (exclusive lock, raw mode, speed, the kernel's low-latency flag);
the port then keeps a duplicate of its descriptor, which holds the lock, and closes pyserial's
object, so an open port owns exactly one descriptor and nothing else (no pipe, no library state
that outlives it). Every later operation is ours: os.read and os.write around poll(), ioctl and
termios on that descriptor. Whatever the OS answers (EIO once the adapter is unplugged or a
pty's far end is gone, EBADF for a descriptor closed under us) comes out as PortError, the one
exception of this layer; after close() every call raises PortError without touching a
descriptor number the process may have reused.
"""

import errno
import fcntl
import os
import select
import struct
import termios
import time
from typing import Callable, Optional, TypeVar

from dxl_servo_driver.errors import PortError
from dxl_servo_driver.models import xm430
from dxl_servo_driver.port.termios2 import set_tty_speed
import serial

WRITE_BLOCKED_S = 1.0   # a write that finds no room in the driver's buffer this long fails
# Where Linux says a USB serial adapter's latency timer (FTDI: 16 ms unless a udev rule sets it).
SYSFS_LATENCY = '/sys/bus/usb-serial/devices/{name}/latency_timer'
T = TypeVar('T')


def adapter_latency_timer_ms(device: str) -> Optional[float]:
    """Return the USB serial adapter's latency timer in ms (Linux sysfs), None if unknown."""
    name = os.path.basename(os.path.realpath(device))
    try:
        with open(SYSFS_LATENCY.format(name=name), encoding='ascii') as stream:
            return float(stream.read().strip())
    except (OSError, ValueError):
        return None


class SerialPort:
    """A serial device: one descriptor of its own, read with poll(), every OS error a PortError."""

    # Its bytes come at wire speed, never sooner: a reader may sleep until they can be there.
    paced = True
    # Whether the last read had to wait for its bytes (they were not all there when it began).
    waited = False

    def __init__(self, device: str, baud_bps: int) -> None:
        self.device = device
        try:
            opened = serial.Serial(device, baud_bps, timeout=0, write_timeout=WRITE_BLOCKED_S,
                                   exclusive=True)
        except serial.SerialException as exc:
            raise PortError(_describe_open_error(device, exc)) from None
        except (OSError, ValueError) as exc:
            raise PortError(f'cannot open {device}: {exc}') from None
        fd = -1
        try:
            try:
                # ASYNC_LOW_LATENCY: the kernel side of a 1 ms latency timer (FTDI adapters).
                opened.set_low_latency_mode(True)
            except (OSError, ValueError, AttributeError, NotImplementedError):
                pass
            # The duplicate shares the open file: its exclusive lock and non-blocking flag.
            fd = os.dup(opened.fileno())
            self._attrs = termios.tcgetattr(fd)
        except (OSError, termios.error, ValueError) as exc:
            _close_fd(fd)
            raise PortError(f'cannot open {device}: {exc}') from None
        finally:
            _close_quietly(opened)
        self._fd = fd
        self._closed = False
        self._baud_bps = baud_bps
        self._vmin = -1
        self._poll = select.poll()
        self._poll.register(fd, select.POLLIN | select.POLLERR | select.POLLHUP)
        self._write_poll = select.poll()
        self._write_poll.register(fd, select.POLLOUT | select.POLLERR | select.POLLHUP)

    @property
    def closed(self) -> bool:
        """Return True once close() was called."""
        return self._closed

    def _os(self, what: str, action: Callable[[int], T]) -> T:
        """Run one OS call on the descriptor; PortError for whatever goes wrong."""
        if self._closed:
            raise PortError(f'{self.device}: the port is closed')
        try:
            return action(self._fd)
        except BlockingIOError:
            raise
        except (OSError, termios.error, ValueError, TypeError) as exc:
            raise PortError(f'{self.device}: {what} failed ({_reason(exc)}); was the adapter '
                            'unplugged?') from None

    @property
    def baudrate(self) -> int:
        """Return the line speed in bit/s."""
        return self._baud_bps

    @baudrate.setter
    def baudrate(self, baud_bps: int) -> None:
        if not self._os(f'setting {baud_bps} bps', lambda fd: set_tty_speed(fd, baud_bps)):
            raise PortError(f'{self.device}: cannot set {baud_bps} bps')
        # The cached attributes carry the speed: take them again, or the next VMIN change
        # would put the old speed back.
        self._attrs = self._os('reading the terminal settings', termios.tcgetattr)
        self._vmin = -1
        self._baud_bps = baud_bps

    def write(self, data: bytes) -> int:
        """Send all bytes; PortError when the device is gone or stays blocked."""
        view = memoryview(data)
        sent = 0
        deadline = time.monotonic() + WRITE_BLOCKED_S
        while sent < len(view):
            try:
                sent += self._os('write', lambda fd: os.write(fd, view[sent:]))
            except BlockingIOError:
                # The port is non-blocking: wait for room, but not forever (a wedged adapter).
                if time.monotonic() > deadline:
                    raise PortError(f'{self.device}: write blocked for {WRITE_BLOCKED_S:g} s; '
                                    'is the adapter wedged?') from None
                self._write_poll.poll(100)
        return sent

    def _wake_after(self, size: int) -> None:
        # In non-canonical mode with VTIME 0 the kernel's poll() reports the tty readable only
        # once VMIN bytes are there: one wake-up per reply block instead of one per USB packet.
        vmin = max(1, min(size, 255))
        if vmin != self._vmin:
            attrs = self._attrs
            attrs[6][termios.VMIN] = vmin
            attrs[6][termios.VTIME] = 0
            self._os('setting VMIN', lambda fd: termios.tcsetattr(fd, termios.TCSANOW, attrs))
            self._vmin = vmin

    def _take(self, chunks: bytearray, size: int) -> None:
        """Read what the kernel holds, up to size bytes in all, into chunks."""
        try:
            while len(chunks) < size:
                data = self._os('read', lambda fd: os.read(fd, size - len(chunks)))
                if not data:
                    # Readable but nothing comes: the device went away.
                    raise PortError(f'{self.device}: device disconnected; was the adapter '
                                    'unplugged?')
                chunks += data
        except BlockingIOError:
            pass

    def read(self, size: int, timeout_s: float) -> bytes:
        """Block until size bytes arrived or timeout_s passed; return what arrived."""
        if self._closed:
            raise PortError(f'{self.device}: the port is closed')
        chunks = bytearray()
        deadline = time.monotonic() + timeout_s
        # What is there already is taken without a poll: a reader that slept until its bytes
        # were due mostly finds them all. Any VMIN of at least 1 makes a read of an empty tty
        # say EAGAIN (with VMIN 0 it says end of file, which _take takes for an unplugged one).
        if self._vmin < 1:
            self._wake_after(size)
        self._take(chunks, size)
        self.waited = len(chunks) < size
        if not self.waited:
            return bytes(chunks)
        while True:
            self._wake_after(size - len(chunks))
            remaining_ms = (deadline - time.monotonic()) * 1000.0
            events = self._poll.poll(max(remaining_ms, 0.0))
            for _, event in events:
                if event & select.POLLNVAL:
                    raise PortError(f'{self.device}: read failed (the descriptor is not open)')
            if events:
                # Drain what the kernel holds (a tty read returns it in pieces) before polling
                # again.
                self._take(chunks, size)
            if len(chunks) >= size:
                return bytes(chunks)
            if remaining_ms <= 0.0:
                # Fewer than VMIN bytes never wake poll(): take whatever is there now.
                self._take(chunks, size)
                return bytes(chunks)

    @property
    def in_waiting(self) -> int:
        """Return how many received bytes wait to be read."""
        data = self._os('asking for the bytes waiting',
                        lambda fd: fcntl.ioctl(fd, termios.TIOCINQ, b'\0\0\0\0'))
        return int(struct.unpack('I', data)[0])

    def reset_input_buffer(self) -> None:
        """Drop unread input."""
        self._os('flushing the input', lambda fd: termios.tcflush(fd, termios.TCIFLUSH))

    def close(self) -> None:
        """Release the descriptor (idempotent); every later call raises PortError."""
        if self._closed:
            return
        self._closed = True
        _close_fd(self._fd)


def _reason(exc: BaseException) -> str:
    strerror = getattr(exc, 'strerror', None)
    if strerror:
        return str(strerror)
    if isinstance(exc, termios.error) and len(exc.args) > 1:
        return str(exc.args[1])
    return str(exc) or type(exc).__name__


def _close_fd(fd: object) -> None:
    if isinstance(fd, int) and fd >= 0:
        try:
            os.close(fd)
        except OSError:
            pass   # closed for good even when close() reports an error (Linux)


def _close_quietly(opened: 'serial.Serial') -> None:
    """Close pyserial's object and everything it holds (its descriptor and two pipes)."""
    try:
        opened.close()
    except (OSError, serial.SerialException):
        # pyserial stops at its first error, the device's close (which released the descriptor
        # all the same, so it is not closed twice): its pipes are closed here.
        for name in ('pipe_abort_read_r', 'pipe_abort_read_w', 'pipe_abort_write_r',
                     'pipe_abort_write_w'):
            fd = getattr(opened, name, None)
            if isinstance(fd, int):
                _close_fd(fd)


def _describe_open_error(device: str, exc: Exception) -> str:
    number = getattr(exc, 'errno', None)
    if number == errno.ENOENT or not os.path.exists(device):
        return (f'port {device} does not exist: is the USB adapter plugged in? '
                '(ls /dev/ttyUSB* /dev/ttyACM* /dev/ttyDXL)')
    if number == errno.EACCES:
        return (f'permission denied on {device}: add your user to the dialout group '
                '(sudo usermod -aG dialout $USER, then log in again) or install the udev rule')
    if number == errno.EBUSY or 'exclusive' in str(exc).lower() or 'lock' in str(exc).lower():
        return f'port {device} is busy: another program holds it open'
    return f'cannot open {device}: {exc}'


def open_port(device: str, baud_bps: int) -> SerialPort:
    """Open a real serial device; PortError with a clear reason when it cannot."""
    if baud_bps not in xm430.BAUD_RATES.values():
        raise PortError(f"baud rate {baud_bps} is not one of the servo's "
                        f'{sorted(xm430.BAUD_RATES.values())}')
    return SerialPort(device, baud_bps)
