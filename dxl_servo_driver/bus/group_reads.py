"""
The bus's group reads: the reads of many servos at once, over the port's wire.

Sync read, bulk read and their fast forms (Fast Sync Read, Fast Bulk Read: one status packet for
all servos, its parts each with a CRC of all before it) are begun and collected apart (SyncRead),
so a cycle can do other work while the servos answer; the bus stays held in between. Their
replies go through the wire's collector (wire.Wire.collect) like any transaction's, except the
usual case: a whole clean block, checked and decoded at once (BlockTemplate, the clean parse),
in the protocol whose layout those know (Framer.clean_block). The cycle's state reads carry
the servos' Realtime Tick, so the caller dates every sample (driver/clock.py).

Protocol 1.0 has no sync read and no fast read (Framer.sync_read, Framer.fast_read): a bulk read
is its way to read many servos.
"""

from dataclasses import dataclass, field
import functools
import operator
import struct
import time
from typing import Any, Callable, cast, Dict, List, Optional, Sequence, Tuple, Union

from dxl_servo_driver.bus.wire import Request, Wire
from dxl_servo_driver.errors import BadRequest, CommError, CommTimeout, PortError
from dxl_servo_driver.protocol import (
    ALERT_BIT, BROADCAST_ID, crc16, FAST_HEAD_SIZE, FAST_PART_OVERHEAD, fast_status_head,
    fast_status_size, fast_sync_head, fast_sync_size, Framer, HEADER, Instruction,
    parse_fast_status, PROTOCOL_2, STATUS_OVERHEAD)


def _many(positions: Sequence[Any]) -> Callable[[Any], Tuple[Any, ...]]:
    """Return a getter of these positions that always returns a tuple (itemgetter of one not)."""
    getter = operator.itemgetter(*positions)
    if len(positions) == 1:
        return lambda sequence: (getter(sequence),)
    return cast(Callable[[Any], Tuple[Any, ...]], getter)


class BlockTemplate:
    """
    The usual reply block of one (fast) sync read, checked and decoded whole.

    For one request (ids, data length, fast or not) and the struct codes of each servo's data
    (`fields`), one struct unpacks the whole block: every servo's header, id, length and error
    byte (the fast status: its head and each part's error and id) are compared with what a clean
    block has in one comparison, the CRCs are the compiled CRC's over every reply, and the
    values of every servo come out as one flat tuple, in the order asked. What the careful path
    (`parse_clean`, `parse_fast_status`) takes as a whole clean block with every error
    byte 0 is exactly what this takes, with the same values; anything else (a missing, late,
    corrupt, stuffed reply, an alert) is left to it.
    """

    def __init__(self, ids: Tuple[int, ...], length: int, fields: str, fast: bool) -> None:
        per_servo = struct.calcsize('<' + fields)
        if per_servo != length:
            raise ValueError(f'fields {fields!r} take {per_servo} bytes, the read {length}')
        count = len(struct.unpack('<' + fields, bytes(per_servo)))   # values per servo
        self.fields_per_servo = count
        self.fast = fast
        overhead = FAST_PART_OVERHEAD if fast else STATUS_OVERHEAD
        head = FAST_HEAD_SIZE if fast else 0
        if fast:
            self.struct = struct.Struct('<8s' + ('BB' + fields + 'H') * len(ids))
            self._head = fast_sync_head(length, len(ids))
            stride = count + 3   # error, id, fields, crc
            first = 1
            self._marks = _many([first + k * stride + j for k in range(len(ids)) for j in (0, 1)])
            self._expected: Tuple[Any, ...] = tuple(
                value for servo_id in ids for value in (0, servo_id))
        else:
            self.struct = struct.Struct('<' + ('9s' + fields + 'H') * len(ids))
            stride = count + 2   # prefix, fields, crc
            first = 0
            self._marks = _many([k * stride for k in range(len(ids))])
            self._expected = tuple(
                HEADER + struct.pack('<BHBB', servo_id, length + 4, Instruction.STATUS, 0)
                for servo_id in ids)
        self.size = self.struct.size
        self._crcs = _many([first + k * stride + stride - 1 for k in range(len(ids))])
        self._values = _many([first + k * stride + (stride - count - 1) + j
                              for k in range(len(ids)) for j in range(count)])
        # What each CRC covers: a reply's bytes but its CRC; a fast part's, from the end of the
        # part before (its CRC bytes included), continuing that CRC.
        ends = [head + (k + 1) * (overhead + length) - 2 for k in range(len(ids))]
        if fast:
            starts = [0] + ends[:-1]
        else:
            starts = [end - (overhead + length - 2) for end in ends]
        self._covered = _many([slice(start, end) for start, end in zip(starts, ends)])
        self._data = [slice(end - length, end) for end in ends]

    def parse(self, buffer: bytes) -> Optional[Tuple[int, ...]]:
        """Return every servo's values, in order, when buffer is the clean block; else None."""
        if len(buffer) != self.size:
            return None
        values = self.struct.unpack(buffer)
        if self._marks(values) != self._expected:
            return None
        if self.fast:
            if values[0] != self._head:
                return None
            crc = 0
            for covered, expected in zip(self._covered(buffer), self._crcs(values)):
                crc = crc16(covered, crc)
                if crc != expected:
                    return None
        elif tuple(map(crc16, self._covered(buffer))) != self._crcs(values):
            return None
        return self._values(values)

    def data(self, buffer: bytes, index: int) -> bytes:
        """Return the data bytes of the index-th servo asked in a block parse() took."""
        return buffer[self._data[index]]


@dataclass
class SyncResult:
    """
    What a sync read brought back.

    data maps each id asked to its bytes or to the CommError saying why there are none. clean
    is True when the reply block was exactly what was expected (every reply there, in order,
    nothing else), so callers may skip their own checks. sent_s is when the request went out
    (monotonic): a sample cannot be older than that. alerts holds each reply's alert bit.

    A read given its fields (begin_sync_read) whose block was the usual clean one has instead
    `values`, every servo's decoded at once (BlockTemplate), and data empty: `block` and
    `template` give a servo's bytes when wanted.
    """

    data: Dict[int, Union[bytes, CommError]]
    clean: bool
    sent_s: float
    alerts: Dict[int, bool] = field(default_factory=dict)
    # (sent, received) of the ids whose data came from a later one-off read (a retry)
    dated: Dict[int, Tuple[float, float]] = field(default_factory=dict)
    values: Optional[Tuple[int, ...]] = None
    block: bytes = b''
    template: Optional[BlockTemplate] = None


@dataclass(eq=False)
class SyncRead:
    """
    A sync or bulk read on the wire, owning the bus while its answers come.

    Made by Bus.begin_sync_read() or Bus.begin_bulk_read() with the bus lock taken; collect()
    or abort() (exactly one of them, once, in the same thread) ends it, and they are the only
    places that lock is released.
    """

    _reads: 'GroupReads'
    request: Request
    length: int     # the data each answer carries (a bulk read: the longest)
    address: int    # a bulk read: -1 (each record has its own)
    sent_s: float
    deadline_s: float
    fast: bool      # a Fast Sync (or Bulk) Read: one status packet for all
    linger: bool    # read on to the deadline: the last whole answer wins
    done: bool = False
    bulk: bool = False            # a bulk read: each id its own length (request.lengths)
    framer: Framer = PROTOCOL_2   # the protocol it went out in (a bulk read may be 1.0's)
    fields: str = ''              # struct codes of each answer's data: decoded whole when clean

    @property
    def what(self) -> str:
        """Return what the read is called in the errors it reports."""
        return ('fast ' if self.fast else '') + ('bulk read' if self.bulk else 'sync read')

    @functools.cached_property
    def lengths(self) -> Tuple[int, ...]:
        """Return the data length of each id's answer, in the order asked."""
        lengths = self.request.lengths
        if lengths is None:
            return (self.length,) * len(self.request.ids)
        return tuple(lengths[servo_id] for servo_id in self.request.ids)

    @property
    def ids(self) -> Tuple[int, ...]:
        """Return the ids asked, in the order they answer."""
        return self.request.ids

    @property
    def packet(self) -> bytes:
        """Return the request as it went on the wire."""
        return self.request.packet

    def collect(self) -> SyncResult:
        """Collect the answers and release the bus."""
        return self._reads.collect(self)

    def abort(self) -> None:
        """
        Give the read up (idempotent) and wait its answers out, then release the bus.

        Whatever arrives until the read's deadline is its answer: it is read and dropped here,
        so no later transaction (the next activation's first read, a torque-off) can take it
        for its own. Later stragglers still find the bus suspicious (dirty).
        """
        self._reads.abort(self)


class GroupReads:
    """
    The reads of many servos at once (sync, bulk, fast), over the port's wire (held).

    What the layer above (the bus) may call: sync_read, begin_sync_read, bulk_read and
    begin_bulk_read; what a SyncRead they return calls: collect and abort (its two ends). The
    wire is reached through its public names only (wire.Wire), the answers judged by it
    (Wire.answer, Wire.missing) as the one-off transactions' are; a cycle's retries of what a
    sync read missed are one-off reads the caller makes on the bus.
    """

    def __init__(self, wire: Wire) -> None:
        self._wire = wire
        # Made once per roster and part, not per cycle (each bounded: cleared past 64).
        self._sync_read_requests: Dict[Tuple[int, int, Tuple[int, ...], bool], Request] = {}
        self._status_prefixes: Dict[Tuple[Tuple[int, ...], Tuple[int, ...]], List[bytes]] = {}
        self._templates: Dict[Tuple[bytes, str], BlockTemplate] = {}

    # sync reads ----------------------------------------------------------------------------
    def _sync_read_request(self, address: int, length: int, ids: Tuple[int, ...],
                           fast: bool) -> Request:
        """Return the Request of a sync read, made once per roster and part (not per cycle)."""
        key = (address, length, ids, fast)
        request = self._sync_read_requests.get(key)
        if request is None:
            packet = sync_read_packet(address, length, ids, fast)
            if len(self._sync_read_requests) > 64:
                self._sync_read_requests.clear()
            request = self._sync_read_requests[key] = Request(packet, ids, length)
        return request

    def sync_read(self, address: int, length: int, ids: Sequence[int],
                  fast: bool = False) -> SyncResult:
        """
        Read length bytes at address from every servo in ids with one SYNC_READ (or FAST).

        Each id maps to its data or to a CommError; a servo that is silent or corrupted never
        stops the others from being read (in a Fast Sync Read, those whose parts come before a
        corrupted one, or after a missing one).
        """
        return self.begin_sync_read(address, length, ids, fast).collect()

    def begin_sync_read(self, address: int, length: int, ids: Sequence[int],
                        fast: bool = False, linger: bool = False, fields: str = '') -> SyncRead:
        """
        Send a SYNC_READ (FAST_SYNC_READ when fast) and return at once, the bus held.

        The SyncRead returned owns the bus until its collect() or abort(), in the same thread.

        With linger the replies are read on to the deadline and the last whole answer is taken:
        the caller found the last answer stale (a late one taken in its place, the next one
        then still on its way), and this puts request and answer back in step. Meanwhile the
        caller may do other work (publish the previous cycle) while the servos answer.

        fields: the struct codes of each servo's data (the state block's). When given, the
        usual clean block is checked and decoded whole (BlockTemplate): the result has `values`
        instead of `data`; any other block is collected the careful way, as without.
        """
        wire = self._wire
        id_tuple = tuple(ids)
        # Only a bus where some id lacks sync read needs the look (not the usual one, every
        # cycle).
        if wire.mixed or not wire.default_framer.sync_read:
            for servo_id in id_tuple:
                framer = wire.framer_for(servo_id)
                if not framer.sync_read:
                    raise BadRequest(f'{"fast sync read" if fast else "sync read"} does not '
                                     f'exist in Protocol {framer.version}.0 (use bulk_read)')
        wire.lock.acquire()
        try:
            if wire.framer.sync_read:   # the usual bus: no switch on the cycle's path
                request, expected, sent_s, written_s = self._send_sync_read(
                    address, length, id_tuple, fast)
            else:
                with wire.speaking(PROTOCOL_2):
                    request, expected, sent_s, written_s = self._send_sync_read(
                        address, length, id_tuple, fast)
        except BaseException:
            wire.lock.release()
            raise
        deadline = written_s + wire.reply_timeout_s(expected, len(id_tuple), len(request.packet))
        return SyncRead(self, request, length, address, sent_s, deadline, fast, linger,
                        fields=fields)

    def _send_sync_read(self, address: int, length: int, ids: Tuple[int, ...],
                        fast: bool) -> Tuple[Request, int, float, float]:
        """Put a sync read on the wire: (request, bytes expected, sent_s, written_s)."""
        request = self._sync_read_request(address, length, ids, fast)
        expected = self._sync_reply_size(length, len(ids), fast)
        sent_s, written_s = self._wire.send(request.packet)
        return request, expected, sent_s, written_s

    def _sync_reply_size(self, length: int, count: int, fast: bool) -> int:
        """Return the bytes the answers to a sync read of length bytes from count servos take."""
        if fast:
            return fast_sync_size(length, count)
        return (self._wire.framer.status_overhead + length) * count

    def _reply_size(self, lengths: Sequence[int], fast: bool) -> int:
        """Return the bytes the answers of these data lengths take (fast: in one status)."""
        if fast:
            return fast_status_size(lengths)
        return self._wire.framer.status_overhead * len(lengths) + sum(lengths)

    # collection ----------------------------------------------------------------------------
    def collect(self, pending: SyncRead) -> SyncResult:
        """Collect a sync or bulk read's answers and release the bus (SyncRead.collect)."""
        if pending.done:
            raise RuntimeError('a sync read collected or aborted already')
        pending.done = True
        wire = self._wire
        try:
            if wire.framer is pending.framer:   # the usual case: no switch on the cycle's path
                return self._collect_sync(pending)
            with wire.speaking(pending.framer):   # the protocol it went out in
                return self._collect_sync(pending)
        finally:
            wire.lock.release()

    def abort(self, pending: SyncRead) -> None:
        """Give a read up (idempotent), wait its answers out, release the bus (SyncRead.abort)."""
        if pending.done:
            return
        pending.done = True
        wire = self._wire
        wire.mark_dirty()
        chunk = pending.framer.status_overhead * len(pending.ids) + 4096
        try:
            while time.monotonic() < pending.deadline_s:
                dropped = wire.read(chunk, pending.deadline_s, to_deadline=True)
                wire.counters.flushed_bytes += len(dropped)
        except PortError:
            pass   # a lost port holds nothing to wait for; its next user finds it lost
        finally:
            wire.lock.release()

    def _collect_sync(self, pending: SyncRead) -> SyncResult:
        """Collect a sync or bulk read's answers (its framer in force)."""
        wire = self._wire
        ids = pending.ids
        lengths = pending.lengths
        expected = self._reply_size(lengths, pending.fast)
        echo_size = len(pending.packet) if wire.echo else 0
        echoes = wire.counters.echoes
        entered = time.monotonic()
        # The earliest the whole block can be here: the line carries the request, then each
        # answer after its servo's Return Delay Time (a fast read's after the first's only).
        # An echo comes while the request goes out.
        due_s = (pending.sent_s + wire.byte_time_s(len(pending.packet) + expected)
                 + (1 if pending.fast else len(ids)) * wire.least_return_delay_s)
        buffer = wire.read(echo_size + expected, pending.deadline_s, due_s=due_s)
        if len(buffer) == echo_size + expected:
            # Whole, but in the last half of the slack while we waited for it: nearly given up
            # on. More slack before a reply comes later still (a collect begun in that half
            # cannot tell when the bytes came, and says nothing).
            near = pending.deadline_s - 0.5 * wire.slack_s
            if entered < near < time.monotonic():
                wire.raise_slack()
        if echo_size and buffer[:echo_size] == pending.packet:
            buffer = buffer[echo_size:]
            wire.echo_seen()
        clean_block = wire.framer.clean_block
        if pending.fields and not pending.linger and clean_block:
            template = self._template(pending)
            values = template.parse(buffer)
            if values is not None:
                return SyncResult({}, True, pending.sent_s, values=values, block=buffer,
                                  template=template)
        if pending.fast:
            result = self._collect_fast(pending, buffer)
        else:
            results = (None if pending.linger or not clean_block
                       else self._parse_clean(buffer, ids, lengths))
            if results is not None:
                return SyncResult(results, True, pending.sent_s, dict.fromkeys(ids, False))
            # An echo not where expected (something came first) is found among the frames.
            # No Realtime Tick need date a bulk read's answers (its caller reads what it
            # likes): an id that answered twice has a late reply among them, maybe after the
            # answer, and is refused.
            result = self._collect_sync_frames(pending, bytearray(buffer), pending.what,
                                               pending.bulk)
        if (echo_size and wire.counters.echoes == echoes
                and any(isinstance(data, bytes) for data in result.data.values())):
            wire.echo_missing()
        return result

    def _template(self, pending: SyncRead) -> BlockTemplate:
        """Return the BlockTemplate of a sync read (made once per request)."""
        key = (pending.packet, pending.fields)   # the packet says ids, length, fast
        template = self._templates.get(key)
        if template is None:
            template = BlockTemplate(pending.ids, pending.length, pending.fields, pending.fast)
            if len(self._templates) > 64:
                self._templates.clear()
            self._templates[key] = template
        return template

    def _parse_clean(self, buffer: bytes, ids: Tuple[int, ...],
                     lengths: Tuple[int, ...]) -> Optional[Dict[int, Union[bytes, CommError]]]:
        """Parse the usual case at once (parse_clean), the status prefixes made once per roster."""
        key = (ids, lengths)
        prefixes = self._status_prefixes.get(key)
        if prefixes is None:
            prefixes = status_prefixes(ids, lengths)
            if len(self._status_prefixes) > 64:
                self._status_prefixes.clear()
            self._status_prefixes[key] = prefixes
        return parse_clean(buffer, ids, lengths, prefixes)

    def _collect_sync_frames(self, pending: SyncRead, buffer: bytearray,
                             what: str = 'sync read',
                             refuse_repeated: bool = False) -> SyncResult:
        """
        Take an unusual reply block apart with the collector, reading on for missing answers.

        Each id's last answer wins. An answer that came before the answer of an id asked earlier
        cannot belong to this request unless that earlier one was late too: it is ambiguous and
        refused. When anything unusual was seen the block is read to its deadline, so an answer
        that follows a stale reply is not missed.
        """
        wire = self._wire
        ids = pending.ids
        request = pending.request
        found = wire.collect(request, pending.deadline_s, buffer, pending.linger,
                             lambda got: not got.anomalies and len(got.answers) == len(ids))
        if found.echoed:
            wire.echo_seen()   # a missing echo is judged by the caller, _collect_sync
        if found.anomalies or len(found.answers) < len(ids):
            wire.mark_dirty()   # a missing reply may still come, late
        results: Dict[int, Union[bytes, CommError]] = {}
        alerts: Dict[int, bool] = {}
        latest = 0   # frame number of the last accepted answer, in request order
        for servo_id in ids:
            answer = found.answers.get(servo_id)
            if answer is None:
                results[servo_id] = wire.missing(
                    servo_id, servo_id in found.corrupt,
                    f'corrupted status packet in the {what}', f'no status packet in the {what}')
                continue
            number, error, data = answer
            if refuse_repeated and servo_id in found.repeated:
                wire.counters.stale += 1
                results[servo_id] = CommTimeout(
                    f'id {servo_id}: more than one reply in the {what} (a late one after the '
                    'answer?)', servo_id)
                continue
            if number < latest:
                wire.counters.stale += 1
                results[servo_id] = CommTimeout(
                    f'id {servo_id}: its reply came before that of an id asked earlier '
                    '(a late reply of an earlier request?)', servo_id)
                continue
            latest = number
            alerts[servo_id] = wire.alert(error)
            results[servo_id] = wire.answer(servo_id, error, data, what)
        return SyncResult(results, False, pending.sent_s, alerts)

    def _collect_fast(self, pending: SyncRead, buffer: bytes) -> SyncResult:
        """
        Take apart the one status packet of a Fast Sync Read or Fast Bulk Read.

        The usual case is exactly one whole packet. Otherwise the packet is looked for after
        whatever came first (a late reply, noise, our own echo) and read on to the deadline
        while it is short; the last one found is the answer (a stale one comes before it).
        Parts that check are taken; a missing part (a silent servo) is a timeout, a part that
        does not check (and every part after it, whose CRCs cover it) a corrupt reply. The
        head's length field counts every length asked, and each part must have its id's: the
        status of another request (other ids, lengths or order) is refused whole or from the
        first part that differs; only an earlier status of the very same request passes, and
        the Realtime Tick the caller reads refuses it.
        """
        wire = self._wire
        ids = pending.ids
        lengths = pending.lengths
        size = fast_status_size(lengths)
        if len(buffer) == size and not pending.linger:
            parts, whole = parse_fast_status(buffer, 0, ids, lengths)
            if whole:
                return self._fast_result(pending, parts, True, False)
        data = bytearray(buffer)
        wanted = fast_status_head(lengths)
        while True:
            final = time.monotonic() >= pending.deadline_s
            start, parts, whole = _find_fast_status(data, wanted, ids, lengths)
            missing = size - (len(data) - start) if start >= 0 else size
            if final or (not pending.linger and (whole or missing <= 0)):
                break
            data += wire.read(missing if missing > 0 else size, pending.deadline_s)
        if start > 0:
            if data.startswith(pending.packet):
                wire.echo_seen()   # learned: the adapter echoes (stripped from now on)
            else:
                wire.counters.stale += 1   # something came before the answer
        wire.mark_dirty()   # a missing part may still come, late
        truncated = start < 0 or len(data) - start < size
        return self._fast_result(pending, parts, False, not truncated)

    def _fast_result(self, pending: SyncRead, parts: Dict[int, Tuple[int, bytes]],
                     clean: bool, complete: bool) -> SyncResult:
        wire = self._wire
        results: Dict[int, Union[bytes, CommError]] = {}
        alerts: Dict[int, bool] = {}
        what = pending.what
        for servo_id in pending.ids:
            part = parts.get(servo_id)
            if part is None:
                results[servo_id] = wire.missing(
                    servo_id, complete, f'its part of the {what} did not check',
                    f'no part in the {what}')
                continue
            error, data = part
            alerts[servo_id] = bool(error & ALERT_BIT)
            results[servo_id] = wire.answer(servo_id, error, data, what)
        return SyncResult(results, clean, pending.sent_s, alerts)

    # bulk reads ----------------------------------------------------------------------------
    def bulk_read(self, requests: Sequence[Tuple[int, int, int]],
                  framer: Optional[Framer] = None) -> SyncResult:
        """
        Read (id, address, length) of several servos with one BULK_READ; hold the bus meanwhile.

        In the framer's protocol (None: the bus's default). The status packets come back one
        per servo, in the order asked, and are collected as a sync read's are (an id's answer is
        refused when it came before that of an id asked earlier, or is of another length, or
        corrupt, or came twice); each id maps to its data or to the CommError saying why there
        is none. When the bus is suspicious the replies are read to the deadline and each id's
        last answer wins.
        """
        wire = self._wire
        with wire.speaking(framer):
            return self.begin_bulk_read(requests, linger=wire.dirty,
                                        framer=wire.framer).collect()

    def begin_bulk_read(self, requests: Sequence[Tuple[int, int, int]], fast: bool = False,
                        linger: bool = False, framer: Optional[Framer] = None) -> SyncRead:
        """
        Send a BULK_READ (FAST_BULK_READ when fast) of (id, address, length) records, the bus held.

        Returns at once a SyncRead that owns the bus until its collect() or abort(), in the
        same thread, as begin_sync_read() does (linger likewise). The answers come in the order
        of the records, each of its record's length: separate status packets, or with fast one
        status packet of parts (a Fast Sync Read's, of per-id lengths). framer: the protocol
        (None: 2.0, as sync reads; 1.0 has a bulk read but no fast one); every id must speak
        it. BadRequest for an id asked twice, none, or one of the other protocol.
        """
        wire = self._wire
        framer = PROTOCOL_2 if framer is None else framer
        records = [(int(servo_id), int(address), int(length))
                   for servo_id, address, length in requests]
        ids = tuple(servo_id for servo_id, _, _ in records)
        if not ids or len(set(ids)) != len(ids):
            raise BadRequest(f'a bulk read asks each id once, at least one: got {list(ids)}')
        version = framer.version
        if fast and not framer.fast_read:
            raise BadRequest(f'fast bulk read does not exist in Protocol {version}.0 '
                             '(use bulk_read)')
        # The framers are one object per protocol (FRAMERS): the same one, the same protocol.
        others = [servo_id for servo_id in ids if wire.framer_for(servo_id) is not framer]
        if others:
            raise BadRequest(f'ids {others} do not speak Protocol {version}.0: a bulk read '
                             'reaches the servos of one protocol')
        lengths = {servo_id: length for servo_id, _, length in records}
        wire.lock.acquire()
        try:
            with wire.speaking(framer):
                packet = self._bulk_read_packet(records, fast)
                request = wire.request(packet, ids, max(lengths.values()), lengths)
                expected = self._reply_size([length for _, _, length in records], fast)
                sent_s, written_s = wire.send(packet)
        except BaseException:
            wire.lock.release()
            raise
        deadline = written_s + wire.reply_timeout_s(expected, len(ids), len(packet))
        return SyncRead(self, request, max(lengths.values()), -1, sent_s, deadline, fast, linger,
                        bulk=True, framer=framer)

    def _bulk_read_packet(self, records: List[Tuple[int, int, int]], fast: bool) -> bytes:
        """Return a bulk read's packet in the framer in force (fast: 2.0's only)."""
        wire = self._wire
        # BULK_READ is the same instruction byte in both protocols; the records' layout is not.
        return wire.framer.encode(
            BROADCAST_ID, Instruction.FAST_BULK_READ if fast else Instruction.BULK_READ,
            wire.framer.bulk_read_params(records))


def sync_read_packet(address: int, length: int, ids: Sequence[int], fast: bool) -> bytes:
    """Return a (fast) sync read's packet: Protocol 2.0's, the only one with sync reads."""
    params = struct.pack('<HH', address, length) + bytes(ids)
    return PROTOCOL_2.encode(
        BROADCAST_ID, Instruction.FAST_SYNC_READ if fast else Instruction.SYNC_READ, params)


def status_prefixes(ids: Sequence[int], lengths: Sequence[int]) -> List[bytes]:
    """Return the bytes each clean Protocol 2.0 status of ids starts with (to its error 0)."""
    return [HEADER + struct.pack('<BHBB', servo_id, length + 4, Instruction.STATUS, 0)
            for servo_id, length in zip(ids, lengths)]


def parse_clean(buffer: bytes, ids: Tuple[int, ...], lengths: Tuple[int, ...],
                prefixes: Optional[List[bytes]] = None
                ) -> Optional[Dict[int, Union[bytes, CommError]]]:
    """
    Parse the usual reply block at once: every reply there, in order, unstuffed, error byte 0.

    Each reply (of its id's length: a bulk read's differ) must start with exactly the bytes a
    clean Protocol 2.0 status of that id has (header, id, length, 0x55, error 0: prefixes, made
    here when not given) and pass its CRC; anything else returns None and the collector takes
    the whole buffer (the careful path).
    """
    if len(buffer) != STATUS_OVERHEAD * len(ids) + sum(lengths):
        return None
    if prefixes is None:
        prefixes = status_prefixes(ids, lengths)
    results: Dict[int, Union[bytes, CommError]] = {}
    start = 0
    for servo_id, prefix, length in zip(ids, prefixes, lengths):
        body_end = start + STATUS_OVERHEAD + length - 2
        crc = buffer[body_end] | buffer[body_end + 1] << 8
        if buffer[start:start + 9] != prefix or crc16(buffer[start:body_end]) != crc:
            return None
        results[servo_id] = buffer[start + 9:body_end]
        start = body_end + 2
    return results


def _find_fast_status(data: bytearray, head: bytes, ids: Tuple[int, ...],
                      lengths: Tuple[int, ...]) -> Tuple[int, Dict[int, Tuple[int, bytes]], bool]:
    """
    Return where the fast read's status in data starts, its parts, and whether it is whole.

    The last whole packet wins (a stale one comes first); with none whole, the one with the
    most parts (the head's bytes could also occur inside data). Start -1: no head at all.
    """
    best: Tuple[int, Dict[int, Tuple[int, bytes]], bool] = (-1, {}, False)
    start = data.find(head)
    while start >= 0:
        parts, whole = parse_fast_status(data, start, ids, lengths)
        if whole or best[0] < 0 or (not best[2] and len(parts) >= len(best[1])):
            best = (start, parts, whole)
        start = data.find(head, start + 1)
    return best
