"""
In-process serial port in front of a SimBus.

Two faces on one object:

* the duck-typed `dynamixel_sdk.PortHandler` interface (openPort, readPort, writePort,
  setPacketTimeout, ...), so the stock Protocol2PacketHandler and the Group* helpers run unchanged;
* a small pyserial-like raw API (write, read(size, timeout_s), reset_input_buffer, close,
  baudrate, in_waiting) used by the driver's own bus layer.

Timing 'instant' makes replies readable as soon as the write returns; 'wire' makes each reply
readable when the real bus would have delivered it (see sim/timing.py for the model).
"""

import collections
import errno
import threading
import time
from typing import Callable, Iterable

from dxl_servo_driver.sim.bus import SimBus
from dxl_servo_driver.sim.timing import byte_time_s, hybrid_wait, LatenessStats, WireScheduler

TIMINGS = ('instant', 'wire')
# The stock PortHandler's packet timeout adds twice the FTDI default latency timer (16 ms) and
# 2 ms; the same formula keeps a client's timeouts identical on the simulated port.
SDK_LATENCY_TIMER_MS = 16.0
POLL_IDLE_S = 200e-6  # readPort with nothing due: brief sleep so a polling client does not spin


class SimPortDisconnected(OSError):
    """
    The simulated adapter was unplugged.

    pyserial reports a yanked USB adapter as serial.SerialException, a subclass of OSError
    (IOError), from read/write, and as a bare OSError(EIO) from in_waiting; catching OSError
    handles both the real and the simulated port.
    """

    def __init__(self) -> None:
        super().__init__(errno.EIO, 'device disconnected')


class SimPortHandler:
    """A serial port whose far end is a SimBus."""

    def __init__(self, bus: SimBus, port_name: str = 'sim', baudrate: int = 57600,
                 timing: str = 'instant', latency_s: float = 0.0,
                 clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] | None = None) -> None:
        """
        Open the port (like serial.Serial(port), it is usable at once).

        `sleep` is only for tests with an injected clock: when given, waits call it instead of
        the real hybrid sleep/spin, so a fake clock can advance.
        """
        if timing not in TIMINGS:
            raise ValueError(f'timing must be one of {TIMINGS}, got {timing!r}')
        if timing == 'instant' and latency_s != 0.0:
            raise ValueError('latency only applies to timing="wire"')
        self._bus = bus
        self._timing = timing
        self._clock = clock
        self._sleep = sleep
        self._scheduler = WireScheduler(latency_s)
        self._lock = threading.RLock()
        # (due time on self._clock, bytes not yet read); due times are non-decreasing
        self._rx: collections.deque[tuple[float, bytearray]] = collections.deque()
        self._unplugged = False
        self._baudrate = 0
        self.stats = LatenessStats()
        self.port_name = port_name
        self.is_open = True
        self.is_using = False
        self.packet_start_time = 0.0
        self.packet_timeout = 0.0
        self.tx_time_per_byte = 0.0
        self.baudrate = baudrate

    # ------------------------------------------------------------------ raw (pyserial-like) API
    @property
    def baudrate(self) -> int:
        """Line speed in bps; setting it changes the speed, as pyserial does."""
        return self._baudrate

    @baudrate.setter
    def baudrate(self, baud_bps: int) -> None:
        if isinstance(baud_bps, bool) or not isinstance(baud_bps, int) or baud_bps <= 0:
            raise ValueError(f'baud rate must be a positive integer, got {baud_bps!r}')
        with self._lock:
            if baud_bps != self._baudrate:
                # Bytes still on the wire were sent at the old speed: the UART would only see
                # framing errors, modelled as lost.
                now_s = self._clock()
                self._rx = collections.deque(c for c in self._rx if c[0] <= now_s)
            self._baudrate = baud_bps
            self.tx_time_per_byte = byte_time_s(baud_bps) * 1000.0  # SDK keeps it in ms

    @property
    def timing(self) -> str:
        """Return 'instant' or 'wire'."""
        return self._timing

    @property
    def in_waiting(self) -> int:
        """Bytes readable now."""
        with self._lock:
            self._check_usable()
            now_s = self._clock()
            return sum(len(chunk) for due_s, chunk in self._rx if due_s <= now_s)

    def write(self, data: bytes | bytearray | Iterable[int]) -> int:
        """Put bytes on the bus; return how many were written."""
        payload = bytes(data)
        with self._lock:
            self._check_usable()
            if not payload:
                return 0
            baud_bps = self._baudrate
            now_s = self._clock()
            replies = self._bus.feed(payload, baud_bps)
            if self._timing == 'instant':
                for reply in replies:
                    self._rx.append((now_s, bytearray(reply.data)))
            else:
                end_s = self._scheduler.instruction_end_s(now_s, len(payload), baud_bps)
                for due_s, chunk in self._scheduler.schedule(end_s, replies, baud_bps):
                    self._rx.append((due_s, bytearray(chunk)))
            return len(payload)

    def read(self, size: int, timeout_s: float) -> bytes:
        """
        Block until size bytes arrived or timeout_s passed; return what arrived.

        With timing 'instant' nothing can arrive later than the write that caused it, so a short
        read returns at once instead of sleeping out the timeout: the result is the same.
        """
        out = bytearray()
        deadline_s = self._clock() + max(0.0, timeout_s)
        while True:
            with self._lock:
                self._check_usable()
                out += self._take_due(size - len(out))
                next_due_s = self._rx[0][0] if self._rx else None
            now_s = self._clock()
            if len(out) >= size or now_s >= deadline_s:
                break
            if next_due_s is None:
                if self._timing == 'instant':
                    break
                self._wait(deadline_s)
            elif next_due_s <= deadline_s:
                self._wait(next_due_s)
                self.stats.record(self._clock() - next_due_s)
            else:
                self._wait(deadline_s)
        return bytes(out)

    def reset_input_buffer(self) -> None:
        """Discard bytes already received; bytes still on the wire arrive later, as on a UART."""
        with self._lock:
            self._check_usable()
            now_s = self._clock()
            while self._rx and self._rx[0][0] <= now_s:
                self._rx.popleft()

    def close(self) -> None:
        """Close the port; pending bytes are lost."""
        with self._lock:
            self.is_open = False
            self._rx.clear()

    # ------------------------------------------------------------------ fault injection
    def unplug_port(self) -> None:
        """Yank the adapter: every read/write raises SimPortDisconnected until plug_port()."""
        with self._lock:
            self._unplugged = True
            self._rx.clear()

    def plug_port(self) -> None:
        """Plug the adapter back in (the port is usable again without reopening)."""
        with self._lock:
            self._unplugged = False

    # ------------------------------------------------------------------ dynamixel_sdk PortHandler
    def openPort(self) -> bool:  # noqa: N802 - dynamixel_sdk's method names
        """Open the port at the current baud rate."""
        return self.setBaudRate(self._baudrate)

    def closePort(self) -> None:  # noqa: N802
        """Close the port."""
        self.close()

    def clearPort(self) -> None:  # noqa: N802
        """Discard received bytes."""
        self.reset_input_buffer()

    def setPortName(self, port_name: str) -> None:  # noqa: N802
        """Set the name reported by getPortName."""
        self.port_name = port_name

    def getPortName(self) -> str:  # noqa: N802
        """Return the port name."""
        return self.port_name

    def setBaudRate(self, baudrate: int) -> bool:  # noqa: N802
        """Set the line speed and (re)open; any positive baud is accepted, incl. 4.5 Mbps."""
        if self.getCFlagBaud(baudrate) <= 0:
            return False
        return self.setupPort(baudrate)

    def getBaudRate(self) -> int:  # noqa: N802
        """Return the line speed in bps."""
        return self._baudrate

    def getBytesAvailable(self) -> int:  # noqa: N802
        """Return the number of readable bytes."""
        return self.in_waiting

    def readPort(self, length: int) -> bytes:  # noqa: N802
        """
        Non-blocking read (the SDK opens pyserial with timeout=0).

        When nothing is readable it waits a little (until a reply due within POLL_IDLE_S, or
        POLL_IDLE_S) so the SDK's polling loop does not burn a CPU core.
        """
        with self._lock:
            self._check_usable()
            data = bytes(self._take_due(length))
            next_due_s = self._rx[0][0] if self._rx else None
        if data or length <= 0:
            return data
        now_s = self._clock()
        if next_due_s is not None and next_due_s <= now_s + POLL_IDLE_S:
            self._wait(next_due_s)
            self.stats.record(self._clock() - next_due_s)
        else:
            self._wait(now_s + POLL_IDLE_S)
        with self._lock:
            self._check_usable()
            return bytes(self._take_due(length))

    def writePort(self, packet: bytes | bytearray | Iterable[int]) -> int:  # noqa: N802
        """Write a packet (the SDK passes a list of ints)."""
        return self.write(packet)

    def setPacketTimeout(self, packet_length: int) -> None:  # noqa: N802
        """Arm the reply timeout for a packet of packet_length bytes (SDK formula, in ms)."""
        self.packet_start_time = self.getCurrentTime()
        self.packet_timeout = (self.tx_time_per_byte * packet_length
                               + 2.0 * SDK_LATENCY_TIMER_MS + 2.0)

    def setPacketTimeoutMillis(self, msec: float) -> None:  # noqa: N802
        """Arm the reply timeout to msec milliseconds."""
        self.packet_start_time = self.getCurrentTime()
        self.packet_timeout = msec

    def isPacketTimeout(self) -> bool:  # noqa: N802
        """Return True (once) when the armed timeout has expired."""
        if self.getTimeSinceStart() > self.packet_timeout:
            self.packet_timeout = 0
            return True
        return False

    def getCurrentTime(self) -> float:  # noqa: N802
        """Return the port clock in milliseconds (the same clock the replies are scheduled on)."""
        return self._clock() * 1000.0

    def getTimeSinceStart(self) -> float:  # noqa: N802
        """Return milliseconds since the timeout was armed."""
        elapsed_ms = self.getCurrentTime() - self.packet_start_time
        if elapsed_ms < 0.0:
            self.packet_start_time = self.getCurrentTime()
        return elapsed_ms

    def setupPort(self, cflag_baud: int) -> bool:  # noqa: N802
        """(Re)open the port at cflag_baud bps; received bytes are discarded."""
        with self._lock:
            self.baudrate = cflag_baud
            self.is_open = True
            now_s = self._clock()
            while self._rx and self._rx[0][0] <= now_s:
                self._rx.popleft()
        return True

    def getCFlagBaud(self, baudrate: int) -> int:  # noqa: N802
        """Return baudrate when it is usable, else -1 (the stock handler's convention)."""
        if isinstance(baudrate, bool) or not isinstance(baudrate, int) or baudrate <= 0:
            return -1
        return baudrate

    # ------------------------------------------------------------------ internals
    def _check_usable(self) -> None:
        if self._unplugged:
            raise SimPortDisconnected()
        if not self.is_open:
            # pyserial raises PortNotOpenError (a SerialException, hence an OSError)
            raise OSError(errno.EBADF, 'port not open')

    def _take_due(self, size: int) -> bytearray:
        """Pop up to size bytes whose due time has passed (caller holds the lock)."""
        out = bytearray()
        if size <= 0:
            return out
        now_s = self._clock()
        while self._rx and len(out) < size and self._rx[0][0] <= now_s:
            chunk = self._rx[0][1]
            take = size - len(out)
            out += chunk[:take]
            del chunk[:take]
            if not chunk:
                self._rx.popleft()
        return out

    def _wait(self, until_s: float) -> None:
        if self._sleep is not None:
            hybrid_wait(until_s, self._clock, self._sleep, spin_s=0.0)
        else:
            hybrid_wait(until_s, self._clock)
