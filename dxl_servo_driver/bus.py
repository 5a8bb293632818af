"""
The bus layer: one serial port of Dynamixel servos, Protocol 2.0.

This is the only layer that touches dynamixel_sdk and pyserial. One-off transactions (ping, read,
write, reboot, ...) go through the stock dynamixel_sdk Protocol2PacketHandler over an adapter whose
reads block with a deadline instead of busy-polling. The per-cycle sync read and sync write are
built once and parsed here with struct, because they run hundreds of times a second.

Every wait is a blocking read with a deadline computed from the bytes expected, the baud rate, the
servos' Return Delay Time and the USB adapter's latency timer, on the monotonic clock.
"""

import errno
import os
import select
import struct
import termios
import threading
import time
from typing import Dict, Iterable, List, Optional, Protocol, Sequence, Tuple, Union

from dxl_servo_driver import control_table as ct
from dxl_servo_driver.protocol import BROADCAST_ID, crc16, encode_instruction, ErrorCode
from dxl_servo_driver.protocol import HEADER, Instruction, unstuff
import dynamixel_sdk
import serial

# Slack added to every computed deadline: OS scheduling and USB transfer jitter.
DEADLINE_SLACK_S = 0.002
BITS_PER_BYTE = 10
STATUS_OVERHEAD = 11
ERROR_TEXT: Dict[int, str] = {
    ErrorCode.RESULT_FAIL: 'result fail (the servo could not process the instruction)',
    ErrorCode.INSTRUCTION: 'instruction error (unknown instruction, or ACTION without REG_WRITE)',
    ErrorCode.CRC: 'CRC error (the servo received a corrupted packet)',
    ErrorCode.DATA_RANGE: 'data range error (value outside the register range)',
    ErrorCode.DATA_LENGTH: 'data length error (wrong number of bytes for the register)',
    ErrorCode.DATA_LIMIT: 'data limit error (value beyond the limit register)',
    ErrorCode.ACCESS: 'access error (read-only register, or EEPROM while torque is on)',
}


class BusError(Exception):
    """A bus operation failed; servo_id names the servo when one is concerned."""

    def __init__(self, message: str, servo_id: Optional[int] = None) -> None:
        super().__init__(message)
        self.servo_id = servo_id


class PortError(BusError):
    """The serial port cannot be opened, or was lost (adapter unplugged)."""


class CommTimeout(BusError, TimeoutError):
    """No (complete) status packet arrived before the deadline."""


class CorruptReply(BusError):
    """A status packet arrived but failed its CRC or framing check."""


class StatusError(BusError):
    """The servo answered with an error code in its status packet."""

    def __init__(self, message: str, servo_id: int, code: int, alert: bool) -> None:
        super().__init__(message, servo_id)
        self.code = code
        self.alert = alert


class RawPort(Protocol):
    """The byte-level port the bus needs (a serial device or the simulator's in-process port)."""

    @property
    def baudrate(self) -> int:
        """Return the line speed in bit/s."""

    @baudrate.setter
    def baudrate(self, baud_bps: int) -> None:
        """Change the line speed."""

    @property
    def in_waiting(self) -> int:
        """Return how many received bytes wait to be read."""

    def write(self, data: bytes) -> int:
        """Send bytes."""

    def read(self, size: int, timeout_s: float) -> bytes:
        """Block until size bytes arrived or timeout_s passed; return what arrived."""

    def reset_input_buffer(self) -> None:
        """Drop whatever was received and not read."""

    def close(self) -> None:
        """Release the port."""


class SerialPort:
    """A serial device opened with pyserial and read with poll() on its file descriptor."""

    def __init__(self, device: str, baud_bps: int) -> None:
        try:
            self._serial = serial.Serial(device, baud_bps, timeout=0, write_timeout=1.0,
                                         exclusive=True)
        except serial.SerialException as exc:
            raise PortError(_describe_open_error(device, exc)) from None
        except (OSError, ValueError) as exc:
            raise PortError(f'cannot open {device}: {exc}') from None
        self.device = device
        self.low_latency = False
        try:
            # ASYNC_LOW_LATENCY: the kernel side of a 1 ms latency timer (FTDI adapters).
            self._serial.set_low_latency_mode(True)
            self.low_latency = True
        except (OSError, ValueError, AttributeError, NotImplementedError):
            pass
        self._fd = self._serial.fileno()
        self._poll = select.poll()
        self._poll.register(self._fd, select.POLLIN | select.POLLERR | select.POLLHUP)
        self._write_poll = select.poll()
        self._write_poll.register(self._fd, select.POLLOUT | select.POLLERR | select.POLLHUP)
        self._attrs = termios.tcgetattr(self._fd)
        self._vmin = -1

    @property
    def baudrate(self) -> int:
        """Return the line speed in bit/s."""
        return int(self._serial.baudrate)

    @baudrate.setter
    def baudrate(self, baud_bps: int) -> None:
        self._serial.baudrate = baud_bps
        # The cached attributes carry the speed: take them again, or the next VMIN change
        # would put the old speed back.
        self._attrs = termios.tcgetattr(self._fd)
        self._vmin = -1

    def write(self, data: bytes) -> int:
        """Send all bytes; PortError when the device is gone."""
        view = memoryview(data)
        sent = 0
        try:
            while sent < len(view):
                try:
                    sent += os.write(self._fd, view[sent:])
                except BlockingIOError:
                    # The port is non-blocking (pyserial opens it so): wait for room.
                    self._write_poll.poll(100)
        except OSError as exc:
            raise PortError(f'{self.device}: write failed ({exc.strerror}); '
                            'was the adapter unplugged?') from None
        return sent

    def _wake_after(self, size: int) -> None:
        # In non-canonical mode with VTIME 0 the kernel's poll() reports the tty readable only
        # once VMIN bytes are there: one wake-up per reply block instead of one per USB packet.
        vmin = max(1, min(size, 255))
        if vmin != self._vmin:
            self._attrs[6][termios.VMIN] = vmin
            self._attrs[6][termios.VTIME] = 0
            try:
                termios.tcsetattr(self._fd, termios.TCSANOW, self._attrs)
            except termios.error:
                return
            self._vmin = vmin

    def read(self, size: int, timeout_s: float) -> bytes:
        """Block until size bytes arrived or timeout_s passed; return what arrived."""
        chunks = bytearray()
        deadline = time.monotonic() + timeout_s
        fd = self._fd
        while True:
            self._wake_after(size - len(chunks))
            remaining_ms = (deadline - time.monotonic()) * 1000.0
            events = self._poll.poll(max(remaining_ms, 0.0))
            if events:
                # Drain what the kernel holds (a tty read returns it in pieces) before
                # polling again.
                try:
                    while len(chunks) < size:
                        data = os.read(fd, size - len(chunks))
                        if not data:
                            # poll() said readable but nothing comes: the device went away.
                            raise PortError(f'{self.device}: device disconnected')
                        chunks += data
                except BlockingIOError:
                    pass
                except OSError as exc:
                    raise PortError(f'{self.device}: read failed ({exc.strerror}); '
                                    'was the adapter unplugged?') from None
            if len(chunks) >= size:
                return bytes(chunks)
            if remaining_ms <= 0.0:
                # Fewer than VMIN bytes never wake poll(): take whatever is there now.
                try:
                    chunks += os.read(fd, size - len(chunks))
                except BlockingIOError:
                    pass
                except OSError as exc:
                    raise PortError(f'{self.device}: read failed ({exc.strerror}); '
                                    'was the adapter unplugged?') from None
                return bytes(chunks)

    @property
    def in_waiting(self) -> int:
        """Return how many received bytes wait to be read."""
        try:
            return int(self._serial.in_waiting)
        except (OSError, serial.SerialException) as exc:
            raise PortError(f'{self.device}: {exc}') from None

    def reset_input_buffer(self) -> None:
        """Drop unread input."""
        try:
            self._serial.reset_input_buffer()
        except (OSError, serial.SerialException) as exc:
            raise PortError(f'{self.device}: {exc}') from None

    def close(self) -> None:
        """Close the device."""
        try:
            self._serial.close()
        except (OSError, serial.SerialException):
            pass


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
    if baud_bps not in ct.BAUD_RATES.values():
        raise PortError(f"baud rate {baud_bps} is not one of the servo's "
                        f'{sorted(ct.BAUD_RATES.values())}')
    return SerialPort(device, baud_bps)


class _SdkPort:
    """
    dynamixel_sdk's PortHandler interface over a RawPort, without busy-waiting.

    The SDK's receive loops call readPort() until they have a packet or isPacketTimeout() says
    stop; readPort() here blocks until the bytes asked for arrive or the deadline passes, so the
    loops run a handful of times instead of spinning a core.
    """

    def __init__(self, bus: 'Bus') -> None:
        self._bus = bus
        self.is_using = False
        self._deadline = 0.0

    def getBaudRate(self) -> int:  # noqa: N802 - dynamixel_sdk's names
        return self._bus.baud_bps

    def clearPort(self) -> None:  # noqa: N802
        self._bus.port.reset_input_buffer()

    def writePort(self, packet: Sequence[int]) -> int:  # noqa: N802
        return self._bus.port.write(bytes(packet))

    def readPort(self, length: int) -> bytes:  # noqa: N802
        if length <= 0:
            return b''
        return self._bus.port.read(length, max(0.0, self._deadline - time.monotonic()))

    def setPacketTimeout(self, packet_length: int) -> None:  # noqa: N802
        self._deadline = time.monotonic() + self._bus.reply_timeout_s(packet_length)

    def setPacketTimeoutMillis(self, msec: float) -> None:  # noqa: N802
        self._deadline = time.monotonic() + msec / 1000.0

    def isPacketTimeout(self) -> bool:  # noqa: N802
        # The SDK asks this before reading the rest of a packet; bytes already waiting mean
        # the reply did arrive (this thread was just late), not that it timed out.
        return time.monotonic() > self._deadline and not self._bus.port.in_waiting


SyncResult = Dict[int, Union[bytes, BusError]]


class Bus:
    """
    One bus of Protocol 2.0 servos on one port. Thread-safe: one transaction at a time.

    The bus never retries on its own; the manager decides what a failure means.
    """

    def __init__(self, port: RawPort, baud_bps: int, latency_timer_s: float = 0.016,
                 return_delay_s: float = 0.0005) -> None:
        self.port = port
        self.baud_bps = baud_bps
        self.latency_timer_s = latency_timer_s
        # The largest Return Delay Time expected on this bus (the seed's default is 500 us).
        self.return_delay_s = return_delay_s
        self.lock = threading.RLock()
        self._sdk = dynamixel_sdk.Protocol2PacketHandler()
        self._sdk_port = _SdkPort(self)
        self._sync_read_packets: Dict[Tuple[int, int, Tuple[int, ...]], bytes] = {}
        self._in_flight: Optional[Tuple[Tuple[int, ...], int, float]] = None
        self._status_prefixes: Dict[Tuple[Tuple[int, ...], int], List[bytes]] = {}
        self.last_read_clean = False
        self.tx_packets = 0
        self.timeouts = 0
        self.corrupt = 0
        self.status_errors = 0
        self.alerts: Dict[int, bool] = {}

    # timing ------------------------------------------------------------------------------
    def byte_time_s(self, n_bytes: int) -> float:
        """Return the time n_bytes take on the wire (8N1)."""
        return n_bytes * BITS_PER_BYTE / self.baud_bps

    def reply_timeout_s(self, reply_bytes: int, n_replies: int = 1, tx_bytes: int = 0) -> float:
        """Return how long to wait for replies, from the moment the instruction was written."""
        return (self.byte_time_s(tx_bytes + reply_bytes) + n_replies * self.return_delay_s
                + self.latency_timer_s + DEADLINE_SLACK_S)

    def close(self) -> None:
        """Close the port."""
        with self.lock:
            self.port.close()

    # one-off transactions through dynamixel_sdk -----------------------------------------
    def _check(self, servo_id: int, what: str, result: int, error: int) -> None:
        if result == dynamixel_sdk.COMM_SUCCESS:
            code = error & 0x7F
            alert = bool(error & 0x80)
            self.alerts[servo_id] = alert
            if code:
                self.status_errors += 1
                text = ERROR_TEXT.get(code, f'error code {code}')
                raise StatusError(f'id {servo_id}: {what} refused: {text}', servo_id, code, alert)
            return
        if result == dynamixel_sdk.COMM_RX_TIMEOUT:
            self.timeouts += 1
            raise CommTimeout(
                f'id {servo_id}: no status packet for {what} at {self.baud_bps} bps '
                f'(check the id, the baud rate, Protocol 2.0, the servo power and the adapter '
                f'latency timer)', servo_id)
        if result == dynamixel_sdk.COMM_RX_CORRUPT:
            self.corrupt += 1
            raise CorruptReply(f'id {servo_id}: corrupted status packet for {what}', servo_id)
        raise BusError(f'id {servo_id}: {what} failed: '
                       f'{self._sdk.getTxRxResult(result)}', servo_id)

    def _sdk_call(self, func, *args):  # type: ignore[no-untyped-def]
        with self.lock:
            self.tx_packets += 1
            try:
                return func(self._sdk_port, *args)
            except (PortError, OSError) as exc:
                self._sdk_port.is_using = False
                raise _port_lost(exc) from None

    def ping(self, servo_id: int) -> int:
        """Return the model number of the servo; raise when it does not answer."""
        model, result, error = self._sdk_call(self._sdk.ping, servo_id)
        self._check(servo_id, 'ping', result, error)
        return int(model)

    def broadcast_ping(self) -> Dict[int, int]:
        """Return {id: model number} of every servo that answers a broadcast ping."""
        found, result = self._sdk_call(self._sdk.broadcastPing)
        if result not in (dynamixel_sdk.COMM_SUCCESS, dynamixel_sdk.COMM_RX_TIMEOUT):
            raise BusError(f'broadcast ping failed: {self._sdk.getTxRxResult(result)}')
        return {int(servo_id): int(info[0]) for servo_id, info in found.items()}

    def read(self, servo_id: int, address: int, length: int) -> bytes:
        """Return length bytes of the servo's control table from address."""
        data, result, error = self._sdk_call(self._sdk.readTxRx, servo_id, address, length)
        self._check(servo_id, f'read of {length} bytes at {address}', result, error)
        return bytes(data)

    def write(self, servo_id: int, address: int, data: bytes) -> None:
        """Write bytes to the servo's control table at address, and check the status."""
        result, error = self._sdk_call(self._sdk.writeTxRx, servo_id, address, len(data),
                                       list(data))
        self._check(servo_id, f'write of {len(data)} bytes at {address}', result, error)

    def read_item(self, servo_id: int, item: ct.Item) -> int:
        """Return one control-table item's value."""
        data = self.read(servo_id, item.address, item.size)
        return int.from_bytes(data, 'little', signed=item.signed)

    def write_item(self, servo_id: int, item: ct.Item, value: int) -> None:
        """Write one control-table item."""
        self.write(servo_id, item.address, value.to_bytes(item.size, 'little', signed=item.signed))

    def reboot(self, servo_id: int) -> None:
        """Send REBOOT and check the servo acknowledged it."""
        result, error = self._sdk_call(self._sdk.reboot, servo_id)
        # The status of a REBOOT may carry the alert bit of the error being cleared.
        self._check(servo_id, 'reboot', result, error)

    def clear_multi_turn(self, servo_id: int) -> None:
        """Send CLEAR: present position back within one turn."""
        result, error = self._sdk_call(self._sdk.clearMultiTurn, servo_id)
        self._check(servo_id, 'clear multi-turn', result, error)

    def factory_reset(self, servo_id: int, option: int) -> None:
        """Send FACTORY_RESET with option 0xFF, 0x01 or 0x02."""
        result, error = self._sdk_call(self._sdk.factoryReset, servo_id, option)
        self._check(servo_id, 'factory reset', result, error)

    # per-cycle transactions ----------------------------------------------------------------
    def _sync_read_packet(self, address: int, length: int, ids: Tuple[int, ...]) -> bytes:
        key = (address, length, ids)
        packet = self._sync_read_packets.get(key)
        if packet is None:
            params = struct.pack('<HH', address, length) + bytes(ids)
            packet = encode_instruction(BROADCAST_ID, Instruction.SYNC_READ, params)
            if len(self._sync_read_packets) > 64:
                self._sync_read_packets.clear()
            self._sync_read_packets[key] = packet
        return packet

    def sync_read(self, address: int, length: int, ids: Sequence[int]) -> SyncResult:
        """
        Read length bytes at address from every servo in ids with one SYNC_READ.

        Returns {id: data} for the servos that answered well and {id: BusError} for the others;
        a servo that is silent or corrupted never stops the others from being read.
        """
        self.sync_read_begin(address, length, ids)
        return self.sync_read_end()

    def sync_read_begin(self, address: int, length: int, ids: Sequence[int]) -> None:
        """
        Send a SYNC_READ and return at once; sync_read_end() collects the replies.

        The caller may do other work (publish the previous cycle) while the servos answer. The
        bus lock is held from here to sync_read_end(), which must follow in the same thread.
        """
        id_tuple = tuple(ids)
        packet = self._sync_read_packet(address, length, id_tuple)
        expected = (STATUS_OVERHEAD + length) * len(id_tuple)
        self.lock.acquire()
        try:
            port = self.port
            if port.in_waiting:
                port.reset_input_buffer()   # a late reply of an earlier transaction
            port.write(packet)
            self.tx_packets += 1
        except (PortError, OSError) as exc:
            self.lock.release()
            raise _port_lost(exc) from None
        except BaseException:
            self.lock.release()
            raise
        deadline = time.monotonic() + self.reply_timeout_s(expected, len(id_tuple), len(packet))
        self._in_flight = (id_tuple, length, deadline)

    def sync_read_end(self) -> SyncResult:
        """Collect the replies of the SYNC_READ sent by sync_read_begin()."""
        in_flight = self._in_flight
        if in_flight is None:
            raise RuntimeError('sync_read_end() without sync_read_begin()')
        self._in_flight = None
        try:
            id_tuple, length, deadline = in_flight
            reply_size = STATUS_OVERHEAD + length
            port = self.port
            try:
                buffer = port.read(reply_size * len(id_tuple),
                                   max(0.0, deadline - time.monotonic()))
                results = self._parse_sync_fast(buffer, id_tuple, length)
                # Clean: every reply there and well formed (callers skip their checks).
                self.last_read_clean = results is not None
                if results is None:
                    results = self._parse_sync(buffer, id_tuple, length)
                while len(results) < len(id_tuple):
                    # Byte stuffing or a bad packet made the replies longer, or this thread
                    # was late: read the rest (past the deadline, only what already arrived).
                    more = port.read(reply_size, max(0.0, deadline - time.monotonic()))
                    if not more:
                        break
                    buffer += more
                    results = self._parse_sync(buffer, id_tuple, length)
            except (PortError, OSError) as exc:
                raise _port_lost(exc) from None
        finally:
            self.lock.release()
        for servo_id in id_tuple:
            if servo_id not in results:
                self.timeouts += 1
                results[servo_id] = CommTimeout(
                    f'id {servo_id}: no status packet in the sync read', servo_id)
        return results

    def _parse_sync_fast(self, buffer: bytes, ids: Tuple[int, ...],
                         length: int) -> Optional[SyncResult]:
        """
        Parse the usual case at once: every reply there, in order, unstuffed, error byte 0.

        Each reply must start with exactly the bytes a clean status of that id has (header, id,
        length, 0x55, error 0) and pass its CRC; anything else returns None and the general
        parser takes the whole buffer.
        """
        reply_size = STATUS_OVERHEAD + length
        if len(buffer) != reply_size * len(ids):
            return None
        key = (ids, length)
        prefixes = self._status_prefixes.get(key)
        if prefixes is None:
            head = struct.pack('<HB', length + 4, Instruction.STATUS) + b'\x00'
            prefixes = [HEADER + bytes((servo_id,)) + head for servo_id in ids]
            if len(self._status_prefixes) > 64:
                self._status_prefixes.clear()
            self._status_prefixes[key] = prefixes
        results: SyncResult = {}
        start = 0
        for servo_id, prefix in zip(ids, prefixes):
            body_end = start + reply_size - 2
            crc = buffer[body_end] | buffer[body_end + 1] << 8
            if buffer[start:start + 9] != prefix or crc16(buffer[start:body_end]) != crc:
                return None
            results[servo_id] = buffer[start + 9:body_end]
            start += reply_size
        alerts = self.alerts
        for servo_id in ids:
            alerts[servo_id] = False
        return results

    def _parse_sync(self, buffer: bytes, ids: Tuple[int, ...], length: int) -> SyncResult:
        results: SyncResult = {}
        wanted = set(ids)
        reply_size = STATUS_OVERHEAD + length
        pos = 0
        end = len(buffer)
        while True:
            start = buffer.find(HEADER, pos)
            if start < 0 or start + 7 > end:
                break
            servo_id = buffer[start + 4]
            packet_length = buffer[start + 5] | (buffer[start + 6] << 8)
            if packet_length < 4 or packet_length > 4 * reply_size:
                pos = start + 1   # a length no status of ours has: noise, resync
                continue
            stop = start + 7 + packet_length
            if stop > end:
                break
            raw = buffer[start:stop]
            pos = stop
            if servo_id not in wanted or servo_id in results:
                continue
            if crc16(raw[:-2]) != (raw[-2] | (raw[-1] << 8)) or raw[7] != Instruction.STATUS:
                self.corrupt += 1
                results[servo_id] = CorruptReply(f'id {servo_id}: corrupted status packet',
                                                 servo_id)
                continue
            error = raw[8]
            params = raw[9:-2]
            if len(params) != length:
                params = unstuff(params)
            self.alerts[servo_id] = bool(error & 0x80)
            if error & 0x7F:
                self.status_errors += 1
                results[servo_id] = StatusError(
                    f'id {servo_id}: sync read refused (error {error & 0x7F})', servo_id,
                    error & 0x7F, bool(error & 0x80))
            elif len(params) != length:
                self.corrupt += 1
                results[servo_id] = CorruptReply(
                    f'id {servo_id}: status packet with {len(params)} bytes, expected {length}',
                    servo_id)
            else:
                results[servo_id] = bytes(params)
        return results

    def sync_write(self, address: int, length: int, data: Iterable[Tuple[int, bytes]]) -> int:
        """Write length bytes at address on several servos with one SYNC_WRITE; return bytes."""
        params = bytearray(struct.pack('<HH', address, length))
        for servo_id, value in data:
            if len(value) != length:
                raise ValueError(f'sync write of {length} bytes: id {servo_id} has {len(value)}')
            params.append(servo_id)
            params += value
        packet = encode_instruction(BROADCAST_ID, Instruction.SYNC_WRITE, bytes(params))
        with self.lock:
            try:
                self.port.write(packet)
            except (PortError, OSError) as exc:
                raise _port_lost(exc) from None
            self.tx_packets += 1
        return len(packet)


def _port_lost(exc: BaseException) -> PortError:
    # pyserial's SerialException and the simulator's disconnect are both OSError subclasses.
    if isinstance(exc, PortError):
        return exc
    return PortError(f'port lost: {exc}; was the adapter unplugged?')


def decode_values(item_list: List[ct.Item], data: bytes) -> List[int]:
    """Return the values of consecutive items read as one block."""
    values = []
    offset = 0
    for item in item_list:
        values.append(int.from_bytes(data[offset:offset + item.size], 'little',
                                     signed=item.signed))
        offset += item.size
    return values
