"""
The bus layer: one serial port of Dynamixel servos, Protocol 2.0 transactions.

This is the only layer that touches the serial device. Every transaction follows one rule:
a reply is accepted only when it answers the request just sent. Before a request goes out,
whatever is waiting on the port (a late reply of an earlier request) is dropped; then the
replies are framed by protocol.scan_frames and each is checked: a status packet, from the id
asked, with exactly the parameter length the request implies (and, in a sync read, in the
order of the ids asked). Anything else is counted and discarded: the local echo of our own
request (half-duplex adapters without echo suppression, learned and then skipped cheaply),
replies to other ids, replies of the wrong length, line noise, truncated packets.

No status packet carries a sequence number, so a late reply of an identical earlier request
looks like the answer to this one. The bus therefore keeps a "dirty" flag for a while after any
anomaly (a timeout, a discarded or corrupted reply, bytes waiting before a request): while it
is set, one-off transactions read on to their deadline and take the last matching reply (replies
leave the bus in order), and the cycle's state reads carry the servos' Realtime Tick so the
caller can date every sample (see driver/clock.py).

Every wait is a blocking read with an absolute deadline on the monotonic clock, computed from
the bytes expected, the baud rate, the servos' Return Delay Time and the USB adapter's latency
timer: a device that never stops sending cannot hold a transaction past it.
"""

from dataclasses import dataclass, field
import struct
import threading
import time
from typing import Dict, Iterable, List, Optional, Sequence, Tuple, Union

from dxl_servo_driver.errors import CommError, CommTimeout, CorruptReply, PortError, StatusError
from dxl_servo_driver.models import Item
from dxl_servo_driver.protocol import (
    BITS_PER_BYTE, BROADCAST_ID, crc16, encode_instruction, ErrorCode, fast_sync_head,
    fast_sync_size, Frame, HEADER, Instruction, MAX_ID, parse_fast_sync_status, scan_frames,
    STATUS_OVERHEAD, unstuff)
from dxl_servo_driver.serial_port import RawPort

# Slack added to every computed deadline: OS scheduling and USB transfer jitter.
DEADLINE_SLACK_S = 0.002
# One-off reads differ in length over this many consecutive requests (see Bus.read).
READ_TAGS = 8
# A confirmed read tries this many times more to get two equal answers in a row.
CONFIRM_ATTEMPTS = 3
PING_REPLY_PARAMS = 3          # model number (2), firmware version (1)
# How long the bus stays suspicious after an anomaly: late replies of a frozen adapter arrive
# within this window of the timeouts they caused.
DIRTY_HOLD_S = 1.0
ERROR_TEXT: Dict[int, str] = {
    ErrorCode.RESULT_FAIL: 'result fail (the servo could not process the instruction)',
    ErrorCode.INSTRUCTION: 'instruction error (unknown instruction, or ACTION without REG_WRITE)',
    ErrorCode.CRC: 'CRC error (the servo received a corrupted packet)',
    ErrorCode.DATA_RANGE: 'data range error (value outside the register range)',
    ErrorCode.DATA_LENGTH: 'data length error (wrong number of bytes for the register)',
    ErrorCode.DATA_LIMIT: 'data limit error (value beyond the limit register)',
    ErrorCode.ACCESS: 'access error (read-only register, or EEPROM while torque is on)',
}
# An echo once learned is expected until this many answered transactions in a row came without
# it: one odd request (an adapter that swallowed its echo) does not make the next ones wait.
ECHO_MISSES_TO_FORGET = 3
# The SDK's broadcast ping wait: every id may answer, 3 ms apart (ROBOTIS' figure).
BROADCAST_PING_PER_ID_S = 0.003


@dataclass
class Counters:
    """What the bus saw, for diagnostics: every anomaly is counted, none is silent."""

    tx_packets: int = 0
    timeouts: int = 0          # a servo's reply missing at the deadline
    corrupt: int = 0           # replies from a servo we asked that failed their CRC
    status_errors: int = 0     # replies carrying an error code
    stale: int = 0             # replies discarded: wrong id, length, order, or a duplicate
    echoes: int = 0            # our own requests seen coming back (local echo)
    flushed_bytes: int = 0     # bytes waiting before a request (late replies, noise)
    deadline_waits: int = 0    # reads that ended at their deadline short of what they asked


@dataclass
class SyncRead:
    """A sync read on the wire: begin_sync_read() made it, end_sync_read() collects it."""

    address: int
    length: int
    ids: Tuple[int, ...]
    packet: bytes
    sent_s: float
    deadline_s: float
    done: bool = False
    fast: bool = False   # a Fast Sync Read: one status packet for all
    linger: bool = False   # read on to the deadline: the last whole answer wins


@dataclass
class SyncResult:
    """
    What a sync read brought back.

    data maps each id asked to its bytes or to the CommError saying why there are none. clean
    is True when the reply block was exactly what was expected (every reply there, in order,
    nothing else), so callers may skip their own checks. sent_s is when the request went out
    (monotonic): a sample cannot be older than that. alerts holds each reply's alert bit.
    """

    data: Dict[int, Union[bytes, CommError]]
    clean: bool
    sent_s: float
    alerts: Dict[int, bool] = field(default_factory=dict)
    # (sent, received) of the ids whose data came from a later one-off read (a retry)
    dated: Dict[int, Tuple[float, float]] = field(default_factory=dict)


class Bus:
    """
    One bus of Protocol 2.0 servos on one port. Thread-safe: one transaction at a time.

    The bus never retries on its own; the caller decides what a failure means.
    """

    def __init__(self, port: RawPort, baud_bps: int, latency_timer_s: float = 0.016,
                 return_delay_s: float = 0.0005) -> None:
        self.port = port
        self.baud_bps = baud_bps
        self.latency_timer_s = latency_timer_s
        # The largest Return Delay Time expected on this bus (the seed's default is 500 us).
        self.return_delay_s = return_delay_s
        self.lock = threading.RLock()
        self.counters = Counters()
        self.echo = False             # learned: the adapter echoes what we send
        self._echo_misses = 0
        self._dirty_until = 0.0
        self._sync_read_packets: Dict[Tuple[int, int, Tuple[int, ...], bool], bytes] = {}
        self._status_prefixes: Dict[Tuple[Tuple[int, ...], int], List[bytes]] = {}
        self._pending: Optional[SyncRead] = None
        self._read_tag = 0

    # timing ------------------------------------------------------------------------------
    def byte_time_s(self, n_bytes: int) -> float:
        """Return the time n_bytes take on the wire (8N1)."""
        return n_bytes * BITS_PER_BYTE / self.baud_bps

    def reply_timeout_s(self, reply_bytes: int, n_replies: int = 1, tx_bytes: int = 0) -> float:
        """Return how long to wait for replies, from the moment the instruction was written."""
        return (self.byte_time_s(tx_bytes + reply_bytes) + n_replies * self.return_delay_s
                + self.latency_timer_s + DEADLINE_SLACK_S)

    def set_baud(self, baud_bps: int) -> None:
        """Change the line speed of the port and of the deadlines."""
        with self.lock:
            try:
                self.port.baudrate = baud_bps
            except OSError as exc:
                raise _port_lost(exc) from None
            self.baud_bps = baud_bps

    @property
    def dirty(self) -> bool:
        """Return True while the bus is suspicious (an anomaly happened lately)."""
        return time.monotonic() < self._dirty_until

    def _echo_seen(self) -> None:
        """Our own request came back: the adapter echoes (expected in front of every answer)."""
        self.echo = True
        self._echo_misses = 0
        self.counters.echoes += 1

    def _echo_missing(self) -> None:
        """Note an answered transaction that came without the echo it was expected to carry."""
        if self.echo:
            self._echo_misses += 1
            if self._echo_misses >= ECHO_MISSES_TO_FORGET:
                self.echo = False
                self._echo_misses = 0

    def mark_dirty(self) -> None:
        """Be suspicious of replies for a while (an anomaly happened)."""
        self._dirty_until = time.monotonic() + DIRTY_HOLD_S

    def close(self) -> None:
        """Close the port."""
        with self.lock:
            self.port.close()

    # one-off transactions ------------------------------------------------------------------
    def _flush(self) -> None:
        # Bytes waiting before a request are late replies or noise: never an answer to it.
        port = self.port
        waiting = port.in_waiting
        if waiting:
            port.reset_input_buffer()
            self.counters.flushed_bytes += waiting
            self.mark_dirty()

    def _send(self, packet: bytes) -> Tuple[float, float]:
        """Flush, write; return (time before the write, time after it)."""
        try:
            self._flush()
            # A servo may sample its state as soon as the request reaches it, which can be
            # before write() returns (the in-process simulator answers inside it): a reply
            # cannot be older than this.
            before = time.monotonic()
            self.port.write(packet)
        except OSError as exc:   # PortError is not an OSError; SimPortDisconnected is
            raise _port_lost(exc) from None
        self.counters.tx_packets += 1
        return before, time.monotonic()

    def _read(self, size: int, deadline_s: float, to_deadline: bool = False) -> bytes:
        """Read up to size bytes by deadline_s; to_deadline: waiting it out is the point."""
        size = max(1, size)
        try:
            data = self.port.read(size, max(0.0, deadline_s - time.monotonic()))
        except OSError as exc:
            raise _port_lost(exc) from None
        if len(data) < size and not to_deadline:
            # What makes a cycle slow: a wait to the deadline (a missing reply, or asking for
            # more than is coming).
            self.counters.deadline_waits += 1
        return data

    def transact(self, servo_id: int, instruction: int, params: bytes, reply_params: int,
                 what: str) -> bytes:
        """
        Send one instruction to one servo and return the parameters of its status packet.

        Only a status packet from servo_id whose parameter count is reply_params answers (an
        error status may carry none); StatusError when it carries an error code, CommTimeout
        when none came by the deadline, CorruptReply when the only one failed its CRC.
        """
        return self._transact(servo_id, instruction, params, reply_params, what, None)[0]

    def _transact(self, servo_id: int, instruction: int, params: bytes, reply_params: int,
                  what: str, linger: Optional[bool], probe: bool = False) -> Tuple[bytes, float]:
        """
        Return (reply parameters, time the request went out); linger None: if dirty.

        With probe, silence is an answer too (a servo booting, or not there): a missing reply
        alone does not make the bus suspicious. A late one is still refused by its length.
        """
        packet = encode_instruction(servo_id, instruction, params)
        reply_size = STATUS_OVERHEAD + reply_params
        with self.lock:
            if linger is None:
                linger = self.dirty
            sent_s, written_s = self._send(packet)
            deadline = written_s + self.reply_timeout_s(reply_size, 1, len(packet))
            buffer = bytearray()
            pos = 0
            want = reply_size + (len(packet) if self.echo else 0)
            found: Optional[Tuple[int, bytes]] = None
            corrupt = stale = echoed = False
            max_length = 2 * (reply_params + 4) + 8
            while True:
                chunk = self._read(want - len(buffer), deadline)
                buffer += chunk
                final = time.monotonic() >= deadline
                frames, pos = scan_frames(buffer, pos, max_length=max(max_length, len(packet)),
                                          final=final)
                for frame in frames:
                    kind = self._classify(frame, packet, servo_id)
                    if kind == 'echo':
                        echoed = True
                    elif kind == 'corrupt':
                        corrupt = True
                    elif kind == 'status':
                        error, data = _status_of(frame)
                        if len(data) == reply_params or (error & 0x7F and not data):
                            if found is not None:
                                stale = True   # an earlier one was a late reply: last wins
                            found = (error, data)
                        else:
                            stale = True
                    else:
                        stale = True
                if final or (found is not None and not linger):
                    break
                if linger:
                    # Dirty bus: read on to the deadline, a later matching reply replaces this.
                    want = len(buffer) + reply_size
                else:
                    # No more than the reply still lacks (the bytes from pos on are its start):
                    # asking for more would wait for the deadline.
                    want = len(buffer) + max(1, reply_size - (len(buffer) - pos))
            if echoed:
                self._echo_seen()
            elif found is not None:
                self._echo_missing()
            if stale or corrupt or pos < len(buffer):
                self.counters.stale += int(stale)
                self.mark_dirty()
            if found is None:
                if not probe or stale or corrupt:
                    self.mark_dirty()
                if corrupt:
                    self.counters.corrupt += 1
                    raise CorruptReply(f'id {servo_id}: corrupted status packet for {what}',
                                       servo_id)
                self.counters.timeouts += 1
                hint = (' (only replies that did not answer it came back)' if stale else
                        ' (check the id, the baud rate, Protocol 2.0, the servo power and the '
                        'adapter latency timer)')
                raise CommTimeout(f'id {servo_id}: no status packet for {what} at '
                                  f'{self.baud_bps} bps{hint}', servo_id)
            error, data = found
            code = error & 0x7F
            if code:
                self.counters.status_errors += 1
                text = ERROR_TEXT.get(code, f'error code {code}')
                raise StatusError(f'id {servo_id}: {what} refused: {text}', servo_id, code,
                                  bool(error & 0x80))
            return data, sent_s

    @staticmethod
    def _classify(frame: Frame, packet: bytes, servo_id: int) -> str:
        if not frame.crc_ok:
            return 'corrupt' if frame.servo_id == servo_id else 'noise'
        if frame.instruction != Instruction.STATUS:
            return 'echo' if frame.raw == packet else 'noise'
        return 'status' if frame.servo_id == servo_id else 'other'

    def ping(self, servo_id: int, probe: bool = False) -> int:
        """
        Return the model number of the servo; raise when it does not answer.

        probe: its silence is expected now and then (a booting servo, a scan), so it does not
        make the bus suspicious of the transactions that follow.
        """
        data = self._transact(servo_id, Instruction.PING, b'', PING_REPLY_PARAMS, 'ping', None,
                              probe)[0]
        return data[0] | (data[1] << 8)

    def broadcast_ping(self) -> Dict[int, int]:
        """Return {id: model number} of every servo that answers a broadcast ping."""
        packet = encode_instruction(BROADCAST_ID, Instruction.PING)
        reply_size = STATUS_OVERHEAD + PING_REPLY_PARAMS
        found: Dict[int, int] = {}
        with self.lock:
            _, written_s = self._send(packet)
            deadline = (written_s + self.reply_timeout_s(reply_size * (MAX_ID + 1), 0, len(packet))
                        + BROADCAST_PING_PER_ID_S * (MAX_ID + 1))
            buffer = bytearray()
            pos = 0
            while True:
                buffer += self._read(reply_size, deadline, to_deadline=True)
                final = time.monotonic() >= deadline
                frames, pos = scan_frames(buffer, pos, max_length=32, final=final)
                for frame in frames:
                    if frame.crc_ok and frame.instruction == Instruction.STATUS:
                        error, data = _status_of(frame)
                        if len(data) == PING_REPLY_PARAMS:
                            found[frame.servo_id] = data[0] | (data[1] << 8)
                    elif frame.raw == packet:
                        self._echo_seen()
                if final:
                    break
        return found

    def read(self, servo_id: int, address: int, length: int, confirm: bool = True) -> bytes:
        """
        Return length bytes of the servo's control table from address.

        A status packet does not say which request it answers, and a reply that comes late
        (a frozen adapter) has the id and often the length the next read of that servo
        expects. So consecutive one-off reads ask for a few bytes more each (before the
        register where the table has room, after it otherwise; reserved addresses read as
        zero): the reply's length tells most late replies from the answer. With confirm (for
        values that do not change by themselves) a second read must agree, which catches the
        rest; changing values are read with read_fresh() and dated by the caller.
        """
        data = self.read_fresh(servo_id, address, length)[0]
        if not confirm:
            return data
        for _ in range(CONFIRM_ATTEMPTS):
            again = self.read_fresh(servo_id, address, length)[0]
            if again == data:
                return data
            self.counters.stale += 1
            self.mark_dirty()
            data = again
        raise CorruptReply(f'id {servo_id}: read of {length} bytes at {address}: replies '
                           'disagree (late replies on the bus?)', servo_id)

    def read_fresh(self, servo_id: int, address: int, length: int) -> Tuple[bytes, float]:
        """Return (data, time the request went out) of one length-tagged read (see read())."""
        self._read_tag = (self._read_tag + 1) % READ_TAGS
        before = min(self._read_tag, address)
        extra = self._read_tag
        data, sent_s = self._transact(servo_id, Instruction.READ,
                                      struct.pack('<HH', address - before, length + extra),
                                      length + extra, f'read of {length} bytes at {address}',
                                      None)
        return data[before:before + length], sent_s

    def read_dated(self, servo_id: int, address: int, length: int) -> Tuple[bytes, float]:
        """
        Return (data, time the request went out) of a read whose data the caller dates itself.

        For the state block's tagged reads (the Realtime Tick tells a late reply): no reading
        on to the deadline when the bus is suspicious.
        """
        return self._transact(servo_id, Instruction.READ, struct.pack('<HH', address, length),
                              length, f'read of {length} bytes at {address}', False)

    def write(self, servo_id: int, address: int, data: bytes) -> None:
        """Write bytes to the servo's control table at address, and check the status."""
        self.transact(servo_id, Instruction.WRITE, struct.pack('<H', address) + bytes(data), 0,
                      f'write of {len(data)} bytes at {address}')

    def read_item(self, servo_id: int, item: Item) -> int:
        """Return one control-table item's value."""
        data = self.read(servo_id, item.address, item.size)
        return int.from_bytes(data, 'little', signed=item.signed)

    def write_item(self, servo_id: int, item: Item, value: int) -> None:
        """Write one control-table item."""
        self.write(servo_id, item.address, value.to_bytes(item.size, 'little', signed=item.signed))

    def reboot(self, servo_id: int) -> None:
        """Send REBOOT and check the servo acknowledged it."""
        # The status of a REBOOT may carry the alert bit of the error being cleared.
        self.transact(servo_id, Instruction.REBOOT, b'', 0, 'reboot')

    def clear_multi_turn(self, servo_id: int) -> None:
        """Send CLEAR: present position back within one turn (the servo must be still)."""
        self.transact(servo_id, Instruction.CLEAR, b'\x01\x44\x58\x4c\x22', 0,
                      'clear multi-turn')

    def factory_reset(self, servo_id: int, option: int) -> None:
        """Send FACTORY_RESET with option 0xFF, 0x01 or 0x02."""
        self.transact(servo_id, Instruction.FACTORY_RESET, bytes((option,)), 0, 'factory reset')

    # per-cycle transactions ----------------------------------------------------------------
    def _sync_read_packet(self, address: int, length: int, ids: Tuple[int, ...],
                          fast: bool = False) -> bytes:
        key = (address, length, ids, fast)
        packet = self._sync_read_packets.get(key)
        if packet is None:
            params = struct.pack('<HH', address, length) + bytes(ids)
            packet = encode_instruction(
                BROADCAST_ID, Instruction.FAST_SYNC_READ if fast else Instruction.SYNC_READ,
                params)
            if len(self._sync_read_packets) > 64:
                self._sync_read_packets.clear()
            self._sync_read_packets[key] = packet
        return packet

    def sync_read(self, address: int, length: int, ids: Sequence[int],
                  fast: bool = False) -> SyncResult:
        """
        Read length bytes at address from every servo in ids with one SYNC_READ (or FAST).

        Each id maps to its data or to a CommError; a servo that is silent or corrupted never
        stops the others from being read (in a Fast Sync Read, those whose parts come before a
        corrupted one, or after a missing one).
        """
        return self.end_sync_read(self.begin_sync_read(address, length, ids, fast))

    def begin_sync_read(self, address: int, length: int, ids: Sequence[int],
                        fast: bool = False, linger: bool = False) -> SyncRead:
        """
        Send a SYNC_READ (FAST_SYNC_READ when fast) and return at once; end_sync_read() collects.

        With linger the replies are read on to the deadline and the last whole answer is taken:
        the caller found the last answer stale (a late one taken in its place, the next one
        then still on its way), and this puts request and answer back in step.

        The caller may do other work (publish the previous cycle) while the servos answer. The
        bus lock is held from here to end_sync_read() or abort(), which must follow in the same
        thread.
        """
        id_tuple = tuple(ids)
        packet = self._sync_read_packet(address, length, id_tuple, fast)
        expected = (fast_sync_size(length, len(id_tuple)) if fast
                    else (STATUS_OVERHEAD + length) * len(id_tuple))
        self.lock.acquire()
        try:
            if self._pending is not None and not self._pending.done:
                raise RuntimeError('a sync read is already in flight')
            sent_s, written_s = self._send(packet)
        except BaseException:
            self.lock.release()
            raise
        deadline = written_s + self.reply_timeout_s(expected, len(id_tuple), len(packet))
        pending = SyncRead(address, length, id_tuple, packet, sent_s, deadline, fast=fast,
                           linger=linger)
        self._pending = pending
        return pending

    def abort(self, pending: Optional[SyncRead]) -> None:
        """
        Give up a sync read begun and not ended (idempotent), and wait its replies out.

        Whatever arrives until the read's deadline is its answer: it is read and dropped here,
        so no later transaction (the next activation's first read, a torque-off) can take it
        for its own. Later stragglers still find the bus suspicious (dirty).
        """
        if pending is None or pending.done:
            return
        pending.done = True
        self.mark_dirty()
        try:
            while time.monotonic() < pending.deadline_s:
                dropped = self._read(STATUS_OVERHEAD * len(pending.ids) + 4096,
                                     pending.deadline_s, to_deadline=True)
                self.counters.flushed_bytes += len(dropped)
        except PortError:
            pass   # a lost port holds nothing to wait for; its next user finds it lost
        finally:
            self.lock.release()

    def end_sync_read(self, pending: SyncRead) -> SyncResult:
        """Collect the replies of a sync read begun by begin_sync_read()."""
        if pending.done:
            raise RuntimeError('end_sync_read() of a sync read already ended')
        pending.done = True
        try:
            return self._collect(pending)
        finally:
            self.lock.release()

    def _collect(self, pending: SyncRead) -> SyncResult:
        ids = pending.ids
        length = pending.length
        reply_size = STATUS_OVERHEAD + length
        expected = fast_sync_size(length, len(ids)) if pending.fast else reply_size * len(ids)
        echo_size = len(pending.packet) if self.echo else 0
        echoes = self.counters.echoes
        buffer = self._read(echo_size + expected, pending.deadline_s)
        if echo_size and buffer[:echo_size] == pending.packet:
            buffer = buffer[echo_size:]
            self._echo_seen()
        if pending.fast:
            result = self._collect_fast(pending, buffer)
        else:
            results = None if pending.linger else self._parse_sync_fast(buffer, ids, length)
            if results is not None:
                return SyncResult(results, True, pending.sent_s, dict.fromkeys(ids, False))
            # An echo not where expected (something came first) is found among the frames.
            result = self._collect_slow(pending, bytearray(buffer))
        if (echo_size and self.counters.echoes == echoes
                and any(isinstance(data, bytes) for data in result.data.values())):
            self._echo_missing()
        return result

    def _parse_sync_fast(self, buffer: bytes, ids: Tuple[int, ...],
                         length: int) -> Optional[Dict[int, Union[bytes, CommError]]]:
        """
        Parse the usual case at once: every reply there, in order, unstuffed, error byte 0.

        Each reply must start with exactly the bytes a clean status of that id has (header, id,
        length, 0x55, error 0) and pass its CRC; anything else returns None and the careful
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
        results: Dict[int, Union[bytes, CommError]] = {}
        start = 0
        for servo_id, prefix in zip(ids, prefixes):
            body_end = start + reply_size - 2
            crc = buffer[body_end] | buffer[body_end + 1] << 8
            if buffer[start:start + 9] != prefix or crc16(buffer[start:body_end]) != crc:
                return None
            results[servo_id] = buffer[start + 9:body_end]
            start += reply_size
        return results

    def _collect_fast(self, pending: SyncRead, buffer: bytes) -> SyncResult:
        """
        Take apart the one status packet of a Fast Sync Read.

        The usual case is exactly one whole packet. Otherwise the packet is looked for after
        whatever came first (a late reply, noise, our own echo) and read on to the deadline
        while it is short; the last one found is the answer (a stale one comes before it).
        Parts that check are taken; a missing part (a silent servo) is a timeout, a part that
        does not check (and every part after it, whose CRCs cover it) a corrupt reply.
        """
        ids = pending.ids
        length = pending.length
        size = fast_sync_size(length, len(ids))
        counters = self.counters
        if len(buffer) == size and not pending.linger:
            parts, whole = parse_fast_sync_status(buffer, 0, ids, length)
            if whole:
                return self._fast_result(pending, parts, True, False)
        data = bytearray(buffer)
        wanted = fast_sync_head(length, len(ids))
        while True:
            final = time.monotonic() >= pending.deadline_s
            start, parts, whole = _find_fast_status(data, wanted, ids, length)
            missing = size - (len(data) - start) if start >= 0 else size
            if final or (not pending.linger and (whole or missing <= 0)):
                break
            data += self._read(missing if missing > 0 else size, pending.deadline_s)
        if start > 0:
            if data.startswith(pending.packet):
                self._echo_seen()   # learned: the adapter echoes (stripped from now on)
            else:
                counters.stale += 1   # something came before the answer
        self.mark_dirty()   # a missing part may still come, late
        truncated = start < 0 or len(data) - start < size
        return self._fast_result(pending, parts, False, not truncated)

    def _fast_result(self, pending: SyncRead, parts: Dict[int, Tuple[int, bytes]],
                     clean: bool, complete: bool) -> SyncResult:
        results: Dict[int, Union[bytes, CommError]] = {}
        alerts: Dict[int, bool] = {}
        for servo_id in pending.ids:
            part = parts.get(servo_id)
            if part is None:
                results[servo_id] = self._missing(
                    servo_id, complete, 'its part of the fast sync read did not check',
                    'no part in the fast sync read')
                continue
            error, data = part
            alerts[servo_id] = bool(error & 0x80)
            results[servo_id] = self._answer(servo_id, error, data, 'fast sync read')
        return SyncResult(results, clean, pending.sent_s, alerts)

    def _missing(self, servo_id: int, corrupt: bool, corrupt_text: str,
                 silent_text: str) -> CommError:
        """Count and return why a servo has no reply in a sync read: corrupt or silent."""
        if corrupt:
            self.counters.corrupt += 1
            return CorruptReply(f'id {servo_id}: {corrupt_text}', servo_id)
        self.counters.timeouts += 1
        return CommTimeout(f'id {servo_id}: {silent_text}', servo_id)

    def _answer(self, servo_id: int, error: int, data: bytes,
                what: str) -> Union[bytes, CommError]:
        """Return a sync-read reply's data, or the StatusError its error byte says (counted)."""
        code = error & 0x7F
        if not code:
            return data
        self.counters.status_errors += 1
        return StatusError(f'id {servo_id}: {what} refused: {ERROR_TEXT.get(code, code)}',
                           servo_id, code, bool(error & 0x80))

    def _collect_slow(self, pending: SyncRead, buffer: bytearray) -> SyncResult:
        """
        Take an unusual reply block apart, reading on when replies are missing.

        Each id's last well-formed reply of the right length wins (replies leave the bus in
        order, so a late or duplicated one comes before the answer to this request). A reply
        that comes before the reply of an id asked earlier cannot belong to this request
        unless that earlier one was late too: it is ambiguous and refused. When anything
        unusual was seen the block is read to its deadline, so an answer that follows a stale
        reply is not missed.
        """
        ids = pending.ids
        length = pending.length
        order = {servo_id: index for index, servo_id in enumerate(ids)}
        reply_size = STATUS_OVERHEAD + length
        max_length = 2 * (length + 4) + 8
        entries: Dict[int, Tuple[int, int, bytes]] = {}   # id -> (frame index, error, data)
        corrupt: Dict[int, int] = {}
        anomalies = 0
        pos = 0
        index = 0
        counters = self.counters
        while True:
            final = time.monotonic() >= pending.deadline_s
            frames, pos = scan_frames(buffer, pos, max_length=max(max_length, len(pending.packet)),
                                      final=final)
            for frame in frames:
                index += 1
                servo_id = frame.servo_id
                if not frame.crc_ok:
                    anomalies += 1
                    if servo_id in order:
                        corrupt[servo_id] = corrupt.get(servo_id, 0) + 1
                    continue
                if frame.instruction != Instruction.STATUS:
                    if frame.raw == pending.packet:
                        self._echo_seen()
                    else:
                        anomalies += 1
                    continue
                if servo_id not in order:
                    anomalies += 1
                    counters.stale += 1
                    continue
                error, data = _status_of(frame)
                if len(data) != length and not (error & 0x7F and not data):
                    anomalies += 1
                    counters.stale += 1
                    continue
                if servo_id in entries:
                    anomalies += 1
                    counters.stale += 1
                entries[servo_id] = (index, error, data)
            if final or (not anomalies and len(entries) == len(ids) and not pending.linger):
                break
            missing = len(ids) - len(entries)
            # What the missing replies still lack (the bytes from pos on start one of them).
            buffer += self._read(max(missing * reply_size - (len(buffer) - pos), 1),
                                 pending.deadline_s)
        if anomalies or pos < len(buffer) or len(entries) < len(ids):
            self.mark_dirty()   # a missing reply may still come, late
        results: Dict[int, Union[bytes, CommError]] = {}
        alerts: Dict[int, bool] = {}
        latest = 0   # frame index of the last accepted reply, in request order
        for servo_id in ids:
            entry = entries.get(servo_id)
            if entry is None:
                results[servo_id] = self._missing(
                    servo_id, bool(corrupt.get(servo_id)),
                    'corrupted status packet in the sync read',
                    'no status packet in the sync read')
                continue
            frame_index, error, data = entry
            if frame_index < latest:
                counters.stale += 1
                results[servo_id] = CommTimeout(
                    f'id {servo_id}: its reply came before that of an id asked earlier '
                    '(a late reply of an earlier request?)', servo_id)
                continue
            latest = frame_index
            alerts[servo_id] = bool(error & 0x80)
            results[servo_id] = self._answer(servo_id, error, data, 'sync read')
        return SyncResult(results, False, pending.sent_s, alerts)

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
            if self.echo:
                # A sync write has no reply, but an echoing adapter sends it back: take it now
                # rather than let the next request flush it as an anomaly.
                self._send(packet)
                echo = self._read(len(packet), time.monotonic() + self.reply_timeout_s(
                    0, 0, len(packet)))
                if echo == packet:
                    self._echo_seen()
                else:
                    self._echo_missing()   # what came of it, if anything, the next flush drops
            else:
                try:
                    self.port.write(packet)
                except OSError as exc:
                    raise _port_lost(exc) from None
                self.counters.tx_packets += 1
        return len(packet)


def _find_fast_status(data: bytearray, head: bytes, ids: Tuple[int, ...], length: int
                      ) -> Tuple[int, Dict[int, Tuple[int, bytes]], bool]:
    """
    Return where the Fast Sync Read status in data starts, its parts, and whether it is whole.

    The last whole packet wins (a stale one comes first); with none whole, the one with the
    most parts (the head's bytes could also occur inside data). Start -1: no head at all.
    """
    best: Tuple[int, Dict[int, Tuple[int, bytes]], bool] = (-1, {}, False)
    start = data.find(head)
    while start >= 0:
        parts, whole = parse_fast_sync_status(data, start, ids, length)
        if whole or best[0] < 0 or (not best[2] and len(parts) >= len(best[1])):
            best = (start, parts, whole)
        start = data.find(head, start + 1)
    return best


def _status_of(frame: Frame) -> Tuple[int, bytes]:
    """Return (error byte, parameters) of a status frame (parameters unstuffed)."""
    raw = frame.raw
    if len(raw) < STATUS_OVERHEAD:
        return 0, b''
    data = raw[9:-2]
    if b'\xff\xff\xfd\xfd' in data:
        data = unstuff(data)
    return raw[8], data


def _port_lost(exc: BaseException) -> PortError:
    # pyserial's SerialException and the simulator's disconnect are both OSError subclasses.
    if isinstance(exc, PortError):
        return exc
    return PortError(f'port lost: {exc}; was the adapter unplugged?')
