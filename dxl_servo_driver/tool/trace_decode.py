"""
The decoder of `dxl trace`: trace lines in, text lines out (tool/trace.py is the command).

A request is read as its frame's protocol says (Frame.framer): the framer states everything that
differs between Protocol 2.0 and 1.0 (its instruction names, how wide an address is in a
request, how a bulk read's records are laid out, which instructions exist and which no servo
answers, how an error byte reads, whether a ping's answer carries the model or the model number
is read, whether our own packets coming back look like statuses, what its check is called), so
the decoder holds no branch on the protocol's version. ItemTables names the items an access
covers; Decoder follows requests and their replies.
"""

from dataclasses import dataclass, field
import statistics
from typing import Dict, Iterator, List, Optional, Sequence, Tuple, Union

from dxl_servo_driver import models
from dxl_servo_driver.models.base import Model, ModelError
from dxl_servo_driver.protocol import (
    BROADCAST_ID, Frame, Framer, Instruction, MAX_PACKET_LENGTH, parse_fast_status)
from dxl_servo_driver.tool.session import to_si

# The bound of every scan here: the framers' own (Protocol 1.0's cuts it to its one-byte field).
LONGEST = MAX_PACKET_LENGTH


def _overlap(frame: Frame, others: Sequence[Frame]) -> bool:
    return any(other.start < frame.end and frame.start < other.end for other in others)


def scan_mixed(buffer: Union[bytes, bytearray], final: bool,
               framers: Sequence[Framer]) -> Tuple[List[Frame], int]:
    """
    Return the frames of two protocols in buffer, in order, and where unconsumed bytes begin.

    framers: the two, the one whose check is longer first (2.0's CRC-16, then 1.0's checksum).
    Each protocol's scan finds its own frames; their headers cannot be taken for each other (FF
    FF FD 00 would be a 1.0 packet of length 0), but FF FF inside a packet of one can look like
    a packet of the other. Where two overlap, a frame of the longer check that holds is taken
    over the other (a one-byte checksum holds by chance once in 256), a frame of the shorter
    check that holds over one of the longer that fails. A frame of the shorter check that the
    scan waits for the rest of, which would take in bytes of a checked frame of the other, is
    no frame: the scan goes on after its header. What is left for more bytes to complete starts
    at the first byte either scan still waits on.
    """
    strong, weak = framers
    frames_strong, end_strong = strong.scan(buffer, 0, LONGEST, final)
    checked_strong = [frame for frame in frames_strong if frame.crc_ok]
    frames_weak: List[Frame] = []
    pos = 0
    while True:
        more, end_weak = weak.scan(buffer, pos, LONGEST, final)
        frames_weak += more
        if end_weak >= len(buffer) or not any(end_weak < frame.end for frame in checked_strong):
            break
        pos = end_weak + 1
    checked_weak = [frame for frame in frames_weak if frame.crc_ok]
    frames = [frame for frame in frames_strong
              if frame.crc_ok or not _overlap(frame, checked_weak)]
    frames += [frame for frame in frames_weak if not _overlap(frame, checked_strong)]
    end = min(end_weak, end_strong)
    while True:   # a frame across the end is left whole for the next scan
        across = [frame.start for frame in frames if frame.start < end < frame.end]
        if not across:
            break
        end = min(across)
    return sorted((frame for frame in frames if frame.end <= end),
                  key=lambda frame: frame.start), end


@dataclass
class Line:
    """One line of a trace: its time (us), kind (tx, rx, drop, baud) and bytes or baud."""

    number: int
    t_us: int
    kind: str
    data: bytes = b''
    baud: int = 0


@dataclass
class Request:
    """A request sent, as the decoder follows its replies."""

    t_us: int
    servo_id: int
    instruction: int
    params: bytes
    packet: bytes
    framer: Framer                           # the protocol of its packet
    waiting: List[int]                       # ids whose reply has not come
    # What each id's reply holds: (address, length) read, for decoding its data.
    reads: Dict[int, Tuple[int, int]] = field(default_factory=dict)
    fast: Tuple[int, ...] = ()               # ids of a fast read's one status, in order
    echoed: bool = False                     # its copy came back (an echoing adapter)

    @property
    def name(self) -> str:
        """Return the instruction's name."""
        return self.framer.instruction_name(self.instruction)


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


class ItemTables:
    """
    What the decoder knows of each id's control table, and the items an access covers.

    The table is --model's, else the one the id's ping answer named or, where a ping's answer
    carries none (1.0), its read of the model number; indirect data items are followed to the
    items their indirect addresses point to, once the trace has written them.
    """

    def __init__(self, model: Optional[Model] = None) -> None:
        self.fixed = model
        self.learned: Dict[int, Model] = {}
        self.indirect: Dict[int, Dict[int, int]] = {}   # id -> data address -> target address

    def model(self, servo_id: int) -> Optional[Model]:
        """Return the table of servo_id: --model, else the one learnt, else none."""
        return self.fixed if self.fixed is not None else self.learned.get(servo_id)

    def learn_ping(self, servo_id: int, number: int, firmware: int) -> str:
        """Learn servo_id's model from the model number a ping's answer carried; say which."""
        try:
            model = models.model_for(number, firmware)
        except ModelError:
            return f'model {number} (unknown), firmware {firmware}'
        self.learned[servo_id] = model
        return f'model {number} {model.name}, firmware {firmware}'

    def learn_read(self, servo_id: int, model_address: int, address: int, data: bytes) -> str:
        """
        Learn servo_id's model from a read of its model number at model_address; say which.

        Where a ping's answer carries no model number the bus reads it (and the firmware
        version, which picks the table's variant, with it or later). '' when nothing new.
        """
        text = ''
        at = model_address - address
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

    def learn_write(self, servo_id: int, address: int, data: bytes) -> None:
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


class Decoder:
    """
    Turns trace lines into text lines: requests, replies, anomalies, and a summary.

    A reply is understood only through the requests still waiting for one (their ids, what each
    read, the tables learnt so far), so requests, replies and anomalies share this one state.
    """

    def __init__(self, model: Optional[Model] = None,
                 framers: Sequence[Framer] = ()) -> None:
        # The protocols read: one, or two (each frame as its own header says), the longer
        # check first.
        self.framers = sorted(framers, key=lambda framer: -framer.layout.check_size)
        self.mixed = len(self.framers) > 1
        self.tables = ItemTables(model)
        self.pending: List[Request] = []
        self.tally = Tally()
        self.start_us: Optional[int] = None
        self.baud = 0
        self._rx = bytearray()
        self._rx_t = 0
        # Whether the adapter echoes, as the first request answered showed, in a protocol whose
        # status looks like our own packet (None: not known yet): a 1.0 status may be our
        # request byte for byte (a ping's answer with the input voltage bit), so a copy of a
        # request is its echo only once, and never where the adapter does not echo (the bus's
        # own rule).
        self.adapter_echoes: Optional[bool] = None

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
        for request in list(self.pending):   # _unanswered takes each out
            yield from self._unanswered(request, 'the trace ends')
        self.pending = []

    def _scan(self, data: Union[bytes, bytearray], final: bool) -> Tuple[List[Frame], int]:
        """Return the frames in data, of the protocol read (of both on a mixed bus)."""
        if self.mixed:
            return scan_mixed(data, final, self.framers)
        return self.framers[0].scan(data, 0, LONGEST, final)

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
        framer = frame.framer
        request = Request(t_us, frame.servo_id, packet.instruction, packet.params, frame.raw,
                          framer, [])
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
            crc = f' ({framer.check_name.upper()} WRONG: the servo will {framer.bad_check_fate})'
        tag = f' [{framer.version}.0]' if self.mixed else ''
        yield f'{self._time(t_us)} >  {where} {request.name}{tag}{crc} {text}'.rstrip()
        if not request.waiting:
            self.pending.remove(request)

    def _request_text(self, request: Request) -> str:
        """Fill in what a request asks (its framer reads its fields) and return it as text."""
        p = request.params
        code = request.instruction
        sid = request.servo_id
        framer = request.framer
        size = framer.address_size
        tables = self.tables
        answered = [] if sid == BROADCAST_ID else [sid]
        if code == Instruction.PING:
            request.waiting = answered
            return ''
        if code == Instruction.READ and len(p) >= 2 * size:
            address, length = _field(p, 0, size), _field(p, size, size)
            request.waiting = answered
            request.reads[sid] = (address, length)
            return tables.names(sid, address, length)
        if code in (Instruction.WRITE, Instruction.REG_WRITE) and len(p) >= size:
            address, data = _field(p, 0, size), p[size:]
            tables.learn_write(sid, address, data)
            request.waiting = answered
            return f'{address}+{len(data)}: {tables.values(sid, address, data)}'
        if ((code == Instruction.SYNC_READ and framer.sync_read
                or code == Instruction.FAST_SYNC_READ and framer.fast_read)
                and len(p) >= 2 * size):
            address, length = _field(p, 0, size), _field(p, size, size)
            ids = list(p[2 * size:])
            request.waiting = ids
            request.reads = {i: (address, length) for i in ids}
            if code == Instruction.FAST_SYNC_READ:
                request.fast = tuple(ids)
            names = tables.names(ids[0] if ids else 0, address, length)
            return f'ids {",".join(map(str, ids))} {names}'
        records = None
        if code == Instruction.BULK_READ or (code == Instruction.FAST_BULK_READ
                                             and framer.fast_read):
            records = framer.bulk_read_records(p)
        if records is not None:
            request.waiting = [i for i, _, _ in records]
            request.reads = {i: (a, n) for i, a, n in records}
            if code == Instruction.FAST_BULK_READ:
                request.fast = tuple(request.waiting)
            return '; '.join(f'id {i} {tables.names(i, a, n)}' for i, a, n in records)
        if code == Instruction.SYNC_WRITE and len(p) >= 2 * size:
            address, length = _field(p, 0, size), _field(p, size, size)
            return self._sync_write_text(address, length, p, 2 * size)
        request.waiting = [] if code in framer.unanswered else answered
        return p.hex(' ')

    def _sync_write_text(self, address: int, length: int, p: bytes, first: int) -> str:
        """Return a sync write's data, id by id (its records from p[first:]: id, then data)."""
        parts = []
        for at in range(first, len(p) - length, length + 1):
            servo_id, data = p[at], p[at + 1:at + 1 + length]
            self.tables.learn_write(servo_id, address, data)
            parts.append(f'id {servo_id}: {self.tables.values(servo_id, address, data)}')
        return f'{address}+{length} ' + '; '.join(parts)

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
            return f'frame from id {frame.servo_id} with a wrong {frame.framer.check_name}'
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
            yield f'{time_text} !  {frame.framer.check_name.upper()} ERROR in a frame from id ' \
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
        if frame.servo_id == BROADCAST_ID and frame.framer.fast_read:
            # The one status of a fast read comes from the broadcast id.
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
        if not request.framer.echo_like_status or not frame.is_status:
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
        """Return what a status says: its error by the framer, the model, values or bytes."""
        tally = self.tally
        framer = request.framer
        tally.replies += 1
        delay = t_us - request.t_us
        tally.reply_us.append(delay)
        if remove:
            request.waiting.remove(servo_id)
            if not request.waiting:
                self.pending.remove(request)
        if framer.echo_like_status and self.adapter_echoes is None:
            self.adapter_echoes = request.echoed
        parts = [f'{request.name} reply +{delay} us']
        refusal = framer.refusal_text(error)
        if refusal:
            tally.status_errors += 1
            parts.append(f'STATUS ERROR {refusal}')
        alert = framer.alert_text(error)
        if alert:
            parts.append(f'ALERT {alert}')
        model = framer.ping_model(data) if request.instruction == Instruction.PING else None
        if model is not None:
            parts.append(self.tables.learn_ping(servo_id, *model))
        elif servo_id in request.reads and data:
            address, _ = request.reads[servo_id]
            if framer.model_number_address is not None:
                learned = self.tables.learn_read(servo_id, framer.model_number_address, address,
                                                 data)
                if learned:
                    parts.append(learned)
            parts.append(self.tables.values(servo_id, address, data))
        elif data:
            parts.append(data.hex(' '))
        return parts[0] + (': ' + ', '.join(parts[1:]) if parts[1:] else '')

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
        checks = '/'.join(framer.check_name for framer in self.framers)
        lines.append(f'anomalies: {tally.unanswered} without reply, {tally.corrupt} {checks} '
                     f'errors, {tally.garbage_bytes} garbage bytes, {tally.dropped_bytes} bytes '
                     f'dropped late, {tally.status_errors} status errors, {tally.echoes} echoes')
        return lines


def _field(params: bytes, at: int, size: int) -> int:
    """Return the little-endian number of size bytes at params[at] (an address, a length)."""
    return int.from_bytes(params[at:at + size], 'little')
