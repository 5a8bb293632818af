"""
A port that answers the cycle's reads at once from recorded replies: the driver's own ceiling.

On `virtual_bus --timing wire` the bus time sets the pace, and at 4 Mbps the simulator of N
servos shares the cores with the node, so a node's rate there cannot tell the node's cost from
the simulator's. This port takes the simulator out of the cycle: the first time a (fast) sync
or bulk read's request is seen it goes to the simulator and its answer is recorded; every later
identical request is answered at once from the record, with each servo's Realtime Tick moved
on by the time since (so the driver's dating passes it as a current sample) and the CRCs made
again. Sync writes are swallowed once replaying (a write has no answer; the simulator would
spend the time the bench means to leave out). Any other request (a ping, a one-off read, a
write with its status) goes to the simulator as usual, so configure, services and recovery
work unchanged.

What is measured on it is the cycle with an infinitely fast bus: cycles per second and CPU per
cycle of the driver alone. The replies do not change but for the tick: positions stand still.
"""

import threading
import time
from typing import Any, Callable, Dict, List, Tuple

from dxl_servo_driver.protocol import (
    encode_fast_status, encode_status, HEADER, Instruction, parse_fast_status, scan_frames)

_READS = (Instruction.SYNC_READ, Instruction.FAST_SYNC_READ)
_TICK_WRAP = 0x8000   # the Realtime Tick counts ms from 0 to 32767
# A sync read packet: header 4, id, length 2, instruction, address 2, length 2, ids, crc 2.
_SYNC_READ_HEAD = 12


class _Record:
    """One read's recorded answer: its parts, and the answer as last made (per millisecond)."""

    def __init__(self, fast: bool, parts: List[Tuple[int, int, bytes]], lengths: List[int],
                 recorded_ms: int) -> None:
        self.fast = fast
        self.parts = parts
        self.lengths = lengths
        self.recorded_ms = recorded_ms
        self.made_ms = -1
        self.reply = b''


class ReplayPort:
    """
    A RawPort in front of another (the simulator's, instant): cycle reads answered from records.

    tick_offset is where each servo's Realtime Tick lies in its part of a read (the state
    block's layout): a read too short to hold it is never replayed.
    """

    def __init__(self, inner: Any, tick_offset: int,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._inner = inner
        self._tick_offset = tick_offset
        self._clock = clock
        self._records: Dict[bytes, _Record] = {}
        self._rx = bytearray()
        self._lock = threading.Lock()
        self.replayed = 0      # requests answered from a record
        self.forwarded = 0     # requests that went to the simulator
        self.swallowed = 0     # sync writes dropped while replaying

    @property
    def baudrate(self) -> int:
        """Return the inner port's line speed."""
        return self._inner.baudrate

    @baudrate.setter
    def baudrate(self, baud_bps: int) -> None:
        self._inner.baudrate = baud_bps

    @property
    def in_waiting(self) -> int:
        """Return the bytes readable now."""
        return len(self._rx) + self._inner.in_waiting

    def write(self, data: bytes) -> int:
        """Answer a recorded read at once; send anything else to the simulator."""
        packet = bytes(data)
        with self._lock:
            record = self._records.get(packet)
            if record is not None:
                self._rx += self._answer(record)
                self.replayed += 1
                return len(packet)
            instruction = packet[7] if len(packet) > 7 and packet.startswith(HEADER) else -1
            if instruction == Instruction.SYNC_WRITE and self._records:
                self.swallowed += 1
                return len(packet)
            asked_ms = self._now_ms()   # the servos sample after this: their ticks are later
            written = self._inner.write(packet)
            self.forwarded += 1
            waiting = self._inner.in_waiting
            reply = self._inner.read(waiting, 0.0) if waiting else b''
            self._rx += reply
            if instruction in _READS:
                self._record(packet, instruction == Instruction.FAST_SYNC_READ, reply, asked_ms)
            return written

    def read(self, size: int, timeout_s: float) -> bytes:
        """Return what is there (replayed answers are there at once), else wait on the inner."""
        with self._lock:
            if len(self._rx) >= size or not timeout_s:
                out = bytes(self._rx[:size])
                del self._rx[:size]
                return out
            out = bytes(self._rx)
            self._rx.clear()
        return out + self._inner.read(size - len(out), timeout_s)

    def reset_input_buffer(self) -> None:
        """Drop whatever waits here and in the inner port."""
        with self._lock:
            self._rx.clear()
        self._inner.reset_input_buffer()

    def close(self) -> None:
        """Close the inner port and forget the records."""
        with self._lock:
            self._records.clear()
            self._rx.clear()
        self._inner.close()

    # recording ------------------------------------------------------------------------------
    def _record(self, packet: bytes, fast: bool, reply: bytes, asked_ms: int) -> None:
        """Keep a read's answer when it is whole (every servo asked answered, no error)."""
        if len(packet) < _SYNC_READ_HEAD + 2:
            return
        length = packet[10] | packet[11] << 8
        ids = tuple(packet[_SYNC_READ_HEAD:-2])
        if length < self._tick_offset + 2 or not ids:
            return
        parts: List[Tuple[int, int, bytes]] = []
        if fast:
            found, whole = parse_fast_status(reply, 0, ids, (length,) * len(ids))
            if not whole:
                return
            parts = [(found[servo_id][0], servo_id, found[servo_id][1]) for servo_id in ids]
        else:
            frames, _ = scan_frames(reply)
            answers = [(frame.servo_id, frame.status()) for frame in frames
                       if frame.crc_ok and frame.is_status]
            if [servo_id for servo_id, _ in answers] != list(ids):
                return
            parts = [(error, servo_id, data) for servo_id, (error, data) in answers]
            if any(len(data) != length for _, _, data in parts):
                return
        if any(error for error, _, _ in parts):
            return
        self._records[packet] = _Record(fast, parts, [length] * len(ids), asked_ms)

    def _now_ms(self) -> int:
        return int(self._clock() * 1000.0)

    def _answer(self, record: _Record) -> bytes:
        """Return the recorded answer with every tick moved on to now (made once a millisecond)."""
        now_ms = self._now_ms()
        if record.made_ms == now_ms:
            return record.reply
        elapsed = now_ms - record.recorded_ms
        at = self._tick_offset
        parts = []
        for error, servo_id, data in record.parts:
            tick = ((data[at] | data[at + 1] << 8) + elapsed) % _TICK_WRAP
            parts.append((error, servo_id, data[:at] + tick.to_bytes(2, 'little') + data[at + 2:]))
        if record.fast:
            reply = encode_fast_status(parts, record.lengths)
        else:
            reply = b''.join(encode_status(servo_id, error, data)
                             for error, servo_id, data in parts)
        record.made_ms = now_ms
        record.reply = reply
        return reply
