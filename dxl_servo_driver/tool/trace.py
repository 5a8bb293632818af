# noqa: A005 (the brief names it tool/trace.py; it is imported by its full name only)
"""
`dxl trace FILE`: a bus trace decoded, frame by frame, for a person.

A trace is what `--trace FILE` (any `dxl` command) or the node's `trace` parameter wrote: a line
per write or read of the port (wire.BusTrace: `<monotonic us> tx|rx|drop <hex>`, `baud <bps>`,
`#` comments). Each request is printed with its instruction, id and the items it names (the
model's table: --model, else the one each id's ping answer named, else addresses only), each
reply with its status error, values (raw, and SI where the item has a unit) and how long after
its request it came; and the anomalies: a request left without a reply, a corrupted frame (CRC),
bytes that are no frame (garbage), replies the bus dropped unread before a request (late ones),
our own packet coming back (the adapter's echo). Indirect data items are shown as the items
their indirect addresses point to, when the trace holds the writes that set them.

Protocol 2.0 and 1.0, read with the framers' own scans (protocol.scan_frames,
protocol1.scan_frames). Which one: --protocol, else the one the trace's header names (the tool
writes `Protocol 1.0` there), else the one its requests are packets of (a tx line starts with
FF FF FD 00 in 2.0, FF FF <id> <length> in 1.0). A trace holding requests of both (a mixed bus,
a scan of both protocols) has each frame read as its own header says: both scans run and a frame
whose check holds claims its bytes. In 1.0 a status carries the error bits (input voltage, angle
limit, overheating, range, checksum, overload, instruction: the refusals as STATUS ERROR, the
hardware state as ALERT), no model number in a ping's answer: the model is learnt from a read of
the model number at address 0. A wrong checksum is reported as a CRC is in 2.0.
"""

import argparse
from dataclasses import dataclass, field
import itertools
import os
import re
import statistics
import struct
import sys
from typing import (
    AbstractSet, Callable, Dict, FrozenSet, Iterable, Iterator, List, Optional, Sequence, Tuple,
    Union)

from dxl_servo_driver import models

from dxl_servo_driver.models.base import Model, ModelError
from dxl_servo_driver.protocol import (
    ALERT_BIT, BROADCAST_ID, ERROR_CODE_MASK, ERROR_TEXT, Frame, Instruction,
    parse_fast_status, scan_frames)
from dxl_servo_driver.protocol import protocol1
from dxl_servo_driver.protocol.protocol1 import Frame1, Instruction1
from dxl_servo_driver.tool.common import (
    add_command, EXIT_FAILED, EXIT_OK, EXIT_USAGE, ToolError)
from dxl_servo_driver.tool.session import to_si

DIRECTIONS = ('tx', 'rx', 'drop')
# Instructions no servo answers (broadcast or no status) beside those sent to the broadcast id.
_SILENT = {Instruction.SYNC_WRITE, Instruction.BULK_WRITE, Instruction.ACTION}
_SILENT_1 = {Instruction1.SYNC_WRITE}
# What a frame's check is called in each protocol.
_CHECK = {1: 'checksum', 2: 'CRC'}
# The note the tool writes in the header line (tool/session.open_bus: `Protocol 1.0`).
_HEADER_PROTOCOL = re.compile(r'^# dxl bus trace:.*\bProtocol ([12])(?:\.0)?\s*$')

Scan = Callable[[Union[bytes, bytearray], int, bool], Tuple[List[Frame], int]]


def _scan_1(buffer: Union[bytes, bytearray], pos: int, final: bool) -> Tuple[List[Frame], int]:
    return protocol1.scan_frames(buffer, pos, final=final)


def _scan_2(buffer: Union[bytes, bytearray], pos: int, final: bool) -> Tuple[List[Frame], int]:
    return scan_frames(buffer, pos, final=final)


# Each protocol's own scan (with resync, as the bus reads): the decoder frames nothing itself.
SCANS: Dict[int, Scan] = {1: _scan_1, 2: _scan_2}


def version_of(frame: Frame) -> int:
    """Return the protocol of a frame the scans found: 1 or 2."""
    return 1 if isinstance(frame, Frame1) else 2


def _overlap(frame: Frame, others: Iterable[Frame]) -> bool:
    return any(other.start < frame.end and frame.start < other.end for other in others)


def scan_both(buffer: Union[bytes, bytearray], final: bool) -> Tuple[List[Frame], int]:
    """
    Return the frames of both protocols in buffer, in order, and where unconsumed bytes begin.

    Each protocol's scan finds its own frames; their headers cannot be taken for each other (FF
    FF FD 00 would be a 1.0 packet of length 0), but FF FF inside a packet of one can look like
    a packet of the other. Where two overlap, a 2.0 frame whose CRC-16 holds is taken over the
    1.0 one (a one-byte checksum holds by chance once in 256), a 1.0 frame whose checksum holds
    over a 2.0 one whose CRC fails. A 1.0 frame the scan waits for the rest of that would take
    in bytes of a checked 2.0 frame is no frame: the scan goes on after its header. What is
    left for more bytes to complete starts at the first byte either scan still waits on.
    """
    frames_2, end_2 = _scan_2(buffer, 0, final)
    checked_2 = [frame for frame in frames_2 if frame.crc_ok]
    frames_1: List[Frame] = []
    pos = 0
    while True:
        more, end_1 = _scan_1(buffer, pos, final)
        frames_1 += more
        if end_1 >= len(buffer) or not any(end_1 < frame.end for frame in checked_2):
            break
        pos = end_1 + 1
    checked_1 = [frame for frame in frames_1 if frame.crc_ok]
    frames = [frame for frame in frames_2 if frame.crc_ok or not _overlap(frame, checked_1)]
    frames += [frame for frame in frames_1 if not _overlap(frame, checked_2)]
    end = min(end_1, end_2)
    while True:   # a frame across the end is left whole for the next scan
        across = [frame.start for frame in frames if frame.start < end < frame.end]
        if not across:
            break
        end = min(across)
    return sorted((frame for frame in frames if frame.end <= end),
                  key=lambda frame: frame.start), end


def header_protocol(line: str) -> Optional[int]:
    """Return the protocol a trace's header line names (1 or 2), or None when it names none."""
    match = _HEADER_PROTOCOL.match(line.strip())
    return int(match.group(1)) if match else None


@dataclass
class Line:
    """One line of a trace: its time (us), kind (tx, rx, drop, baud) and bytes or baud."""

    number: int
    t_us: int
    kind: str
    data: bytes = b''
    baud: int = 0


def read_trace(stream: Iterable[str], name: str) -> List[Line]:
    """Return the lines of a trace; ToolError naming the first malformed line."""
    lines: List[Line] = []
    for number, text in enumerate(stream, 1):
        text = text.strip()
        if not text or text.startswith('#'):
            continue
        parts = text.split(None, 2)
        try:
            t_us = int(parts[0])
            kind = parts[1]
            if kind == 'baud':
                lines.append(Line(number, t_us, kind, baud=int(parts[2])))
            elif kind in DIRECTIONS:
                lines.append(Line(number, t_us, kind, bytes.fromhex(parts[2])))
            else:
                raise ValueError(f'unknown direction {kind!r}')
        except (IndexError, ValueError) as exc:
            raise ToolError(f'{name} line {number} is not a trace line ({exc}): {text[:60]!r}',
                            EXIT_USAGE) from None
    return lines


def frame_protocols(lines: Iterable[Line]) -> FrozenSet[int]:
    """Return the protocols the trace's requests are packets of: a tx line begins with one."""
    found = set()
    for line in lines:
        if line.kind != 'tx':
            continue
        for version, scan in SCANS.items():
            frames, _ = scan(line.data, 0, True)
            if frames and frames[0].start == 0 and frames[0].crc_ok:
                found.add(version)
        if len(found) == len(SCANS):
            break
    return frozenset(found)


@dataclass
class Request:
    """A request sent, as the decoder follows its replies."""

    t_us: int
    servo_id: int
    instruction: int
    params: bytes
    packet: bytes
    waiting: List[int]                        # ids whose reply has not come
    # What each id's reply holds: (address, length) read, for decoding its data.
    reads: Dict[int, Tuple[int, int]] = field(default_factory=dict)
    fast: Tuple[int, ...] = ()               # ids of a fast read's one status, in order
    version: int = 2                         # the protocol of its packet
    echoed: bool = False                     # its copy came back (an echoing adapter)

    @property
    def name(self) -> str:
        """Return the instruction's name."""
        try:
            if self.version == 1:
                return Instruction1(self.instruction).name
            return Instruction(self.instruction).name
        except ValueError:
            return f'instruction 0x{self.instruction:02x}'


@dataclass
class Tally:
    """What the decoder counted over the whole trace."""

    requests: Dict[str, int] = field(default_factory=dict)
    replies: int = 0
    unanswered: int = 0
    corrupt: int = 0
    garbage_bytes: int = 0
    dropped_bytes: int = 0
    echoes: int = 0
    status_errors: int = 0
    reply_us: List[int] = field(default_factory=list)

    @property
    def anomalies(self) -> int:
        """Return how many anomalies were seen."""
        return self.unanswered + self.corrupt + (1 if self.garbage_bytes else 0) + (
            1 if self.dropped_bytes else 0)


class Decoder:
    """
    Turns trace lines into text lines: requests, replies, anomalies, and a summary.

    About 460 lines, on purpose: a reply is understood only through the requests still waiting
    for one (their ids, what each read, the models and indirect maps learnt so far), so the
    request texts of both protocols, the replies and the anomalies share that one state.
    """

    def __init__(self, model: Optional[Model] = None,
                 versions: AbstractSet[int] = frozenset({2})) -> None:
        self.fixed = model
        # The protocols read: one, or both (each frame as its own header says).
        self.versions = frozenset(versions)
        self.mixed = len(self.versions) > 1
        self.learned: Dict[int, Model] = {}
        self.indirect: Dict[int, Dict[int, int]] = {}   # id -> data address -> target address
        self.pending: List[Request] = []
        self.tally = Tally()
        self.start_us: Optional[int] = None
        self.baud = 0
        self._rx = bytearray()
        self._rx_t = 0
        # Whether the adapter echoes, as the first Protocol 1.0 request answered showed (None:
        # not known yet): a 1.0 status may be our request byte for byte (a ping's answer with
        # the input voltage bit), so a copy of a request is its echo only once, and never where
        # the adapter does not echo (the bus's own rule).
        self.adapter_echoes: Optional[bool] = None

    # models and items ----------------------------------------------------------------------
    def model(self, servo_id: int) -> Optional[Model]:
        """Return the table of servo_id: --model, else its ping's (1.0: its read's), else none."""
        return self.fixed if self.fixed is not None else self.learned.get(servo_id)

    def _learn_read(self, servo_id: int, address: int, data: bytes) -> str:
        """
        Learn servo_id's model from a Protocol 1.0 read of its model number; return what it is.

        A 1.0 ping's answer carries no model number: the bus reads it at address 0 (and the
        firmware version, which picks the table's variant, with it or later).
        """
        text = ''
        at = protocol1.MODEL_NUMBER_ADDRESS - address
        if 0 <= at and at + 2 <= len(data):
            number = data[at] | (data[at + 1] << 8)
            known = self.learned.get(servo_id)
            if known is None or known.number != number:
                try:
                    self.learned[servo_id] = models.model_for(number)
                    text = f'model {number} {self.learned[servo_id].name}'
                except ModelError:
                    self.learned.pop(servo_id, None)
                    text = f'model {number} (unknown)'
        model = self.learned.get(servo_id)
        if model is not None and model.has('firmware_version'):
            item = model.item('firmware_version')
            at = item.address - address
            if 0 <= at and at + item.size <= len(data):
                self.learned[servo_id] = models.model_for(model.number, data[at])
        return text

    def _segments(self, servo_id: int, address: int, length: int) -> List[Tuple[int, int, int]]:
        """Return (target address, offset in data, length) runs, indirect data followed."""
        table = self.indirect.get(servo_id, {})
        runs: List[Tuple[int, int, int]] = []
        for offset in range(length):
            target = table.get(address + offset, address + offset)
            if runs and runs[-1][0] + runs[-1][2] == target:
                first, where, size = runs[-1]
                runs[-1] = (first, where, size + 1)
            else:
                runs.append((target, offset, 1))
        return runs

    def names(self, servo_id: int, address: int, length: int) -> str:
        """Return the items a read or write of length bytes at address covers."""
        model = self.model(servo_id)
        where = f'{address}+{length}'
        if model is None:
            return where
        names: List[str] = []
        for target, _, size in self._segments(servo_id, address, length):
            names += [item.name for item in model.items
                      if target <= item.address and item.address + item.size <= target + size]
        return f'{where} {",".join(names)}' if names else where

    def values(self, servo_id: int, address: int, data: bytes) -> str:
        """Return the items in data read or written at address, name=raw (SI)."""
        model = self.model(servo_id)
        if model is None:
            return data.hex(' ')
        shown: List[str] = []
        for target, offset, size in self._segments(servo_id, address, len(data)):
            for item in model.items:
                if target <= item.address and item.address + item.size <= target + size:
                    start = offset + item.address - target
                    raw = item.decode(data[start:start + item.size])
                    si, unit = to_si(model, item, raw)
                    text = f'{item.name}={raw}'
                    if unit and item.unit and (si != raw or unit != item.unit):
                        text += f' ({si:.4g} {unit})'
                    elif item.unit and not item.unit.startswith('1/'):   # not a gain's scale
                        text += f' {item.unit}'
                    shown.append(text)
        return ', '.join(shown) if shown else data.hex(' ')

    def _learn_write(self, servo_id: int, address: int, data: bytes) -> None:
        """Follow writes of indirect addresses (what their data items then mean)."""
        model = self.model(servo_id)
        if model is None:
            return
        table = self.indirect.setdefault(servo_id, {})
        for item in model.items:
            if (item.name.startswith('indirect_address_') and address <= item.address
                    and item.address + item.size <= address + len(data)):
                number = item.name.rsplit('_', 1)[1]
                target = item.decode(data[item.address - address:item.address - address + 2])
                try:
                    table[model.item(f'indirect_data_{number}').address] = target
                except KeyError:
                    pass

    # lines ---------------------------------------------------------------------------------
    def _time(self, t_us: int) -> str:
        assert self.start_us is not None
        return f'{(t_us - self.start_us) / 1000.0:12.3f} ms'

    def feed(self, line: Line) -> Iterator[str]:
        """Return the text lines one trace line brings."""
        if self.start_us is None:
            self.start_us = line.t_us
        if line.kind == 'baud':
            self.baud = line.baud
            yield f'{self._time(line.t_us)}    baud {line.baud}'
        elif line.kind == 'tx':
            yield from self._sent(line)
        elif line.kind == 'rx':
            self._rx += line.data
            self._rx_t = line.t_us
            yield from self._received(line.t_us, final=False)
        else:
            yield from self._dropped(line)

    def finish(self) -> Iterator[str]:
        """Return the lines of what is left at the end: bytes, requests never answered."""
        yield from self._received(self._rx_t, final=True)
        for request in self.pending:
            yield from self._unanswered(request, 'the trace ends')
        self.pending = []

    def _scan(self, data: Union[bytes, bytearray], final: bool) -> Tuple[List[Frame], int]:
        """Return the frames in data, of the protocol read (of both on a mixed bus)."""
        if self.mixed:
            return scan_both(data, final)
        return SCANS[next(iter(self.versions))](data, 0, final)

    def _sent(self, line: Line) -> Iterator[str]:
        frames, end = self._scan(line.data, True)
        if not frames:
            yield f'{self._time(line.t_us)} >  {len(line.data)} bytes that are no packet: ' \
                  f'{line.data.hex(" ")}'
            return
        for frame in frames:
            yield from self._request(line.t_us, frame)

    def _request(self, t_us: int, frame: Frame) -> Iterator[str]:
        packet = frame.packet()
        params = packet.params
        version = version_of(frame)
        request = Request(t_us, frame.servo_id, packet.instruction, params, frame.raw, [],
                          version=version)
        tally = self.tally
        tally.requests[request.name] = tally.requests.get(request.name, 0) + 1
        text = self._request_text(request)
        # A new request to an id still awaited: the old one will not be answered now.
        for old in list(self.pending):
            overlap = [i for i in old.waiting if i in request.waiting]
            if overlap:
                yield from self._unanswered(old, 'asked again', overlap)
        self.pending.append(request)
        where = 'broadcast' if frame.servo_id == BROADCAST_ID else f'id {frame.servo_id}'
        crc = ''
        if not frame.crc_ok:
            crc = (' (CRC WRONG: the servo will ignore it)' if version == 2 else
                   ' (CHECKSUM WRONG: the servo will refuse it)')
        tag = f' [{version}.0]' if self.mixed else ''
        yield f'{self._time(t_us)} >  {where} {request.name}{tag}{crc} {text}'.rstrip()
        if not request.waiting:
            self.pending.remove(request)

    def _request_text(self, request: Request) -> str:
        """Fill in what a request asks and return it as text."""
        if request.version == 1:
            return self._request_text_1(request)
        p = request.params
        code = request.instruction
        sid = request.servo_id
        if code == Instruction.PING:
            request.waiting = [] if sid == BROADCAST_ID else [sid]
            return ''
        if code == Instruction.READ and len(p) >= 4:
            address, length = struct.unpack_from('<HH', p)
            request.waiting = [sid]
            request.reads[sid] = (address, length)
            return self.names(sid, address, length)
        if code in (Instruction.WRITE, Instruction.REG_WRITE) and len(p) >= 2:
            address = struct.unpack_from('<H', p)[0]
            data = p[2:]
            self._learn_write(sid, address, data)
            request.waiting = [] if sid == BROADCAST_ID else [sid]
            return f'{address}+{len(data)}: {self.values(sid, address, data)}'
        if code in (Instruction.SYNC_READ, Instruction.FAST_SYNC_READ) and len(p) >= 4:
            address, length = struct.unpack_from('<HH', p)
            ids = list(p[4:])
            request.waiting = ids
            request.reads = {i: (address, length) for i in ids}
            if code == Instruction.FAST_SYNC_READ:
                request.fast = tuple(ids)
            names = self.names(ids[0] if ids else 0, address, length)
            return f'ids {",".join(map(str, ids))} {names}'
        if code in (Instruction.BULK_READ, Instruction.FAST_BULK_READ):
            records = [struct.unpack_from('<BHH', p, at) for at in range(0, len(p) - 4, 5)]
            request.waiting = [i for i, _, _ in records]
            request.reads = {i: (a, n) for i, a, n in records}
            if code == Instruction.FAST_BULK_READ:
                request.fast = tuple(request.waiting)
            return '; '.join(f'id {i} {self.names(i, a, n)}' for i, a, n in records)
        if code == Instruction.SYNC_WRITE and len(p) >= 4:
            address, length = struct.unpack_from('<HH', p)
            return self._sync_write_text(address, length, p, 4)
        request.waiting = [] if sid == BROADCAST_ID or code in _SILENT else [sid]
        return p.hex(' ')

    def _sync_write_text(self, address: int, length: int, p: bytes, first: int) -> str:
        """Return a sync write's data, id by id (its records from p[first:]: id, then data)."""
        parts = []
        for at in range(first, len(p) - length, length + 1):
            servo_id, data = p[at], p[at + 1:at + 1 + length]
            self._learn_write(servo_id, address, data)
            parts.append(f'id {servo_id}: {self.values(servo_id, address, data)}')
        return f'{address}+{length} ' + '; '.join(parts)

    def _request_text_1(self, request: Request) -> str:
        """Fill in what a Protocol 1.0 request asks and return it as text (one-byte fields)."""
        p = request.params
        code = request.instruction
        sid = request.servo_id
        answered = [] if sid == BROADCAST_ID else [sid]
        if code == Instruction1.PING:
            request.waiting = answered
            return ''
        if code == Instruction1.READ and len(p) >= 2:
            address, length = p[0], p[1]
            request.waiting = answered
            request.reads[sid] = (address, length)
            return self.names(sid, address, length)
        if code in (Instruction1.WRITE, Instruction1.REG_WRITE) and p:
            address, data = p[0], p[1:]
            self._learn_write(sid, address, data)
            request.waiting = answered
            return f'{address}+{len(data)}: {self.values(sid, address, data)}'
        if code == Instruction1.SYNC_WRITE and len(p) >= 2:
            return self._sync_write_text(p[0], p[1], p, 2)
        if code == Instruction1.BULK_READ and p:
            # 0x00, then length, id, address a record; the answers come in the records' order.
            records = [(p[at + 1], p[at + 2], p[at]) for at in range(1, len(p) - 2, 3)]
            request.waiting = [i for i, _, _ in records]
            request.reads = {i: (a, n) for i, a, n in records}
            return '; '.join(f'id {i} {self.names(i, a, n)}' for i, a, n in records)
        request.waiting = [] if code in _SILENT_1 else answered
        return p.hex(' ')

    def _received(self, t_us: int, final: bool) -> Iterator[str]:
        buffer = self._rx
        frames, end = self._scan(buffer, final)
        pos = 0
        for frame in frames:
            if frame.start > pos:
                yield from self._garbage(t_us, bytes(buffer[pos:frame.start]))
            pos = max(pos, frame.end)
            yield from self._reply(t_us, frame)
        if end > pos:
            yield from self._garbage(t_us, bytes(buffer[pos:end]))
        del buffer[:end]

    def _garbage(self, t_us: int, data: bytes) -> Iterator[str]:
        self.tally.garbage_bytes += len(data)
        yield f'{self._time(t_us)} !  GARBAGE {len(data)} bytes (no frame): {data.hex(" ")}'

    def _dropped(self, line: Line) -> Iterator[str]:
        self.tally.dropped_bytes += len(line.data)
        yield (f'{self._time(line.t_us)} !  DROPPED {len(line.data)} bytes waiting before a '
               'request (late replies or noise):')
        frames, _ = self._scan(line.data, True)
        for frame in frames:
            yield f'{"":15}      late {self._frame_text(frame)}'

    def _frame_text(self, frame: Frame) -> str:
        if not frame.crc_ok:
            return f'frame from id {frame.servo_id} with a wrong {_CHECK[version_of(frame)]}'
        if frame.is_status:
            error, data = frame.status()
            return f'status of id {frame.servo_id}, error 0x{error:02x}, {len(data)} bytes'
        return f'request to id {frame.servo_id}'

    def _reply(self, t_us: int, frame: Frame) -> Iterator[str]:
        time_text = self._time(t_us)
        if not frame.crc_ok:
            self.tally.corrupt += 1
            # Taken for the reply it was meant to be: that request is not also unanswered.
            request = self._awaiting(frame.servo_id)
            what = ''
            if request is not None:
                what = f' (the reply to {request.name})'
                request.waiting.remove(frame.servo_id)
                if not request.waiting:
                    self.pending.remove(request)
            yield f'{time_text} !  {_CHECK[version_of(frame)].upper()} ERROR in a frame from id ' \
                  f'{frame.servo_id}{what}: {frame.raw.hex(" ")}'
            return
        for request in self.pending:
            if frame.raw == request.packet and self._echo(request, frame):
                self.tally.echoes += 1
                yield f'{time_text} <  echo of our {request.name} (the adapter echoes)'
                return
        if not frame.is_status:
            yield (f'{time_text} !  a request to id {frame.servo_id} came back '
                   f'({frame.raw.hex(" ")})')
            return
        if frame.servo_id == BROADCAST_ID and version_of(frame) == 2:
            yield from self._fast_reply(t_us, frame)
            return
        request = self._awaiting(frame.servo_id)
        error, data = frame.status()
        if request is None:
            yield f'{time_text} !  STRAY status from id {frame.servo_id} (no request awaits ' \
                  f'it): error 0x{error:02x}, {data.hex(" ")}'
            return
        answer = self._answer(t_us, request, frame.servo_id, error, data)
        yield f'{time_text} <  id {frame.servo_id} {answer}'

    def _echo(self, request: Request, frame: Frame) -> bool:
        """Return whether a copy of request's packet is its echo (and note it: 1.0 once)."""
        if request.version == 2 or not frame.is_status:
            return True
        if request.echoed or self.adapter_echoes is False:
            return False
        request.echoed = True
        return True

    def _fast_reply(self, t_us: int, frame: Frame) -> Iterator[str]:
        request = next((r for r in reversed(self.pending) if r.fast), None)
        if request is None:
            yield f'{self._time(t_us)} !  STRAY fast read status: {frame.raw.hex(" ")}'
            return
        lengths = [request.reads[i][1] for i in request.fast]
        parts, whole = parse_fast_status(frame.raw, 0, request.fast, lengths)
        for servo_id in request.fast:
            if servo_id in parts:
                error, data = parts[servo_id]
                if servo_id in request.waiting:
                    request.waiting.remove(servo_id)
                yield f'{self._time(t_us)} <  id {servo_id} (fast) ' \
                      f'{self._answer(t_us, request, servo_id, error, data, remove=False)}'
        if not whole:
            self.tally.corrupt += 1
            yield f'{self._time(t_us)} !  fast read status not whole (a part missing or corrupt)'
        yield from self._done(request)

    def _awaiting(self, servo_id: int) -> Optional[Request]:
        """Return the newest request awaiting servo_id's reply; older ones before it are done."""
        for request in reversed(self.pending):
            if servo_id in request.waiting:
                return request
        return None

    def _answer(self, t_us: int, request: Request, servo_id: int, error: int, data: bytes,
                remove: bool = True) -> str:
        tally = self.tally
        tally.replies += 1
        delay = t_us - request.t_us
        tally.reply_us.append(delay)
        if remove:
            request.waiting.remove(servo_id)
            if not request.waiting:
                self.pending.remove(request)
        parts = [f'{request.name} reply +{delay} us']
        if request.version == 1:
            parts += self._answer_1(request, servo_id, error, data)
            return parts[0] + (': ' + ', '.join(parts[1:]) if parts[1:] else '')
        code = error & ERROR_CODE_MASK
        if code:
            tally.status_errors += 1
            parts.append(f'STATUS ERROR {code}: {ERROR_TEXT.get(code, "unknown")}')
        if error & ALERT_BIT:
            parts.append('ALERT (hardware error: read hardware_error_status)')
        if request.instruction == Instruction.PING and len(data) >= 3:
            number, firmware = data[0] | (data[1] << 8), data[2]
            try:
                model = models.model_for(number, firmware)
                self.learned[servo_id] = model
                parts.append(f'model {number} {model.name}, firmware {firmware}')
            except ModelError:
                parts.append(f'model {number} (unknown), firmware {firmware}')
        elif servo_id in request.reads and data:
            address, _ = request.reads[servo_id]
            parts.append(self.values(servo_id, address, data))
        elif data:
            parts.append(data.hex(' '))
        return parts[0] + (': ' + ', '.join(parts[1:]) if parts[1:] else '')

    def _answer_1(self, request: Request, servo_id: int, error: int, data: bytes) -> List[str]:
        """Return what a Protocol 1.0 status says: its error bits by name, the model, values."""
        if self.adapter_echoes is None:
            self.adapter_echoes = request.echoed
        parts = []
        refused = error & protocol1.REFUSAL_MASK
        if refused:
            self.tally.status_errors += 1
            parts.append(f'STATUS ERROR 0x{refused:02x}: {protocol1.error_text(refused)}')
        alert = error & protocol1.ALERT_MASK
        if alert:
            parts.append(f'ALERT 0x{alert:02x}: {protocol1.error_text(alert)}')
        if servo_id in request.reads and data:
            address, _ = request.reads[servo_id]
            learned = self._learn_read(servo_id, address, data)
            if learned:
                parts.append(learned)
            parts.append(self.values(servo_id, address, data))
        elif data:
            parts.append(data.hex(' '))
        return parts

    def _done(self, request: Request) -> Iterator[str]:
        if request in self.pending:
            self.pending.remove(request)
            if request.waiting:
                yield from self._unanswered(request, 'its status came without them')

    def _unanswered(self, request: Request, why: str,
                    ids: Optional[Sequence[int]] = None) -> Iterator[str]:
        missing = list(request.waiting if ids is None else ids)
        for servo_id in missing:
            request.waiting.remove(servo_id)
        if not request.waiting and request in self.pending:
            self.pending.remove(request)
        if not missing:
            return
        self.tally.unanswered += len(missing)
        who = ', '.join(map(str, missing))
        yield (f'{self._time(request.t_us)} !  NO REPLY from id{"s" if len(missing) > 1 else ""} '
               f'{who} to the {request.name} sent here ({why})')

    def summary(self) -> List[str]:
        """Return the closing lines: what was sent, answered, and went wrong."""
        tally = self.tally
        sent = ', '.join(f'{count} {name}' for name, count in sorted(tally.requests.items()))
        lines = [f'requests: {sum(tally.requests.values())} ({sent or "none"}); replies: '
                 f'{tally.replies}']
        if tally.reply_us:
            lines.append(f'reply after its request: median {statistics.median(tally.reply_us):.0f}'
                         f' us, max {max(tally.reply_us)} us')
        checks = '/'.join(_CHECK[version] for version in sorted(self.versions, reverse=True))
        lines.append(f'anomalies: {tally.unanswered} without reply, {tally.corrupt} {checks} '
                     f'errors, {tally.garbage_bytes} garbage bytes, {tally.dropped_bytes} bytes '
                     f'dropped late, {tally.status_errors} status errors, {tally.echoes} echoes')
        return lines


def decode(lines: Sequence[Line], model: Optional[Model] = None, protocol: Optional[int] = None,
           source: str = '--protocol') -> Tuple[List[str], Decoder]:
    """
    Return the decoded text of trace lines, and the decoder (its tally).

    protocol: 1 or 2, every frame read in it (source says who says so, for the first line);
    None: the protocols the requests are packets of (frame_protocols; none found: 2.0). A trace
    read in another protocol than 2.0 starts with a line that says which and why.
    """
    if protocol is None:
        versions = frame_protocols(lines) or frozenset({2})
        source = 'its requests are Protocol 1.0 packets'
    else:
        versions = frozenset({protocol})
    decoder = Decoder(model, versions)
    out: List[str] = []
    if versions == {1}:
        out.append(f'Protocol 1.0 ({source})')
    elif decoder.mixed:
        out.append('Protocol 2.0 and 1.0 (its requests are packets of both): each frame read as '
                   'its header says, a request marked [2.0] or [1.0]')
    for line in lines:
        out.extend(decoder.feed(line))
    out.extend(decoder.finish())
    return out, decoder


def _protocol(text: str) -> int:
    """Return the major version --protocol names: 1 or 2 (1.0 and 2.0 taken too)."""
    try:
        value = float(text)
    except ValueError:
        value = 0.0
    if value not in (1.0, 2.0):
        raise argparse.ArgumentTypeError(f'{text!r} is not a protocol: 1 or 2')
    return int(value)


def run(args: argparse.Namespace) -> int:
    """Print a trace decoded; exit 1 when it shows anomalies and --strict was given."""
    model: Optional[Model] = None
    if args.model:
        try:
            model = (models.model_for(int(args.model)) if args.model.isdigit()
                     else models.model_named(args.model))
        except ModelError as exc:
            raise ToolError(f'--model: {exc}', EXIT_USAGE) from None
    try:
        with open(args.file, encoding='ascii', errors='replace') as stream:
            first = stream.readline()
            lines = read_trace(itertools.chain([first], stream), args.file)
    except OSError as exc:
        raise ToolError(f'cannot read {args.file}: {exc.strerror or exc}', EXIT_USAGE) from None
    protocol, source = args.protocol, f'--protocol {args.protocol}'
    if protocol is None:
        protocol, source = header_protocol(first), "the trace's header says so"
    text, decoder = decode(lines, model, protocol, source)
    try:
        for line in text + decoder.summary():
            print(line)
        sys.stdout.flush()
    except BrokenPipeError:
        # Read by a pager or `head` that stopped reading: not an error of the trace.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_OK
    return EXIT_FAILED if args.strict and decoder.tally.anomalies else EXIT_OK


def register(subparsers: 'argparse._SubParsersAction[argparse.ArgumentParser]') -> None:
    """Add `dxl trace`."""
    parser = add_command(
        subparsers, 'trace', 'decode a bus trace (--trace FILE, or the trace parameter of the '
        'node)', __doc__.strip().splitlines()[0],
        'dxl scan --port /dev/ttyUSB0 --trace bus.trace',
        'dxl trace bus.trace --model XM430-W350',
        'dxl get 1 present_position --port /dev/ttyUSB0 --protocol 1.0 --trace ax.trace',
        'dxl trace ax.trace                    # Protocol 1.0: its header says so',
        'dxl trace old.trace --protocol 1      # a trace whose header names none')
    parser.add_argument('file', metavar='FILE', help='the trace file')
    parser.add_argument('--model', metavar='NAME|NUMBER',
                        help='the control table of every id (default: the one the ping '
                        'answer of each id in the trace names, in Protocol 1.0 its read of '
                        'the model number; none: addresses only)')
    parser.add_argument('--protocol', type=_protocol, metavar='{1,2}',
                        help="read every frame in this protocol (default: the one the trace's "
                        'header names, else the one its requests are packets of; both, each '
                        'frame by its header, when it holds requests of both)')
    parser.add_argument('--strict', action='store_true',
                        help='exit 1 when the trace shows anomalies')
    parser.set_defaults(run=run)
