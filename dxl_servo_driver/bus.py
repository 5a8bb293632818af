"""
The bus layer: the transactions of one port of Dynamixel servos (Protocol 2.0 or 1.0).

Every transaction follows one rule: a reply is accepted only when it answers the request just
sent. Before a request goes out, whatever is waiting on the port (a late reply of an earlier
request) is dropped; then the replies are framed (the framer: protocol.PROTOCOL_2 by default,
protocol1.PROTOCOL_1 for Protocol 1.0) and every frame goes through one classifier: our own
request coming back (the local echo of a half-duplex adapter: learned, then expected and skipped
cheaply), a status packet from an id asked with the parameter length the request implies (an
answer), a corrupted frame from an id asked, or anything else (a reply to another id or of
another length, an earlier reply again, line noise), counted and discarded. One collector reads
and classifies for every transaction: one-off, broadcast ping, sync read, bulk read. The one
status packet for all servos of a Fast Sync Read or Fast Bulk Read has its own parse (its
parts, each with a CRC of all before it) inside the same collector. The reads of many servos
(sync, bulk, and their fast forms) are begun and collected apart (SyncRead), so a cycle can do
other work while the servos answer.

Protocol 1.0 has no instruction byte in its status packets, so our echo is told from an answer
by comparing the frame with the packet sent, before anything else; a frame equal to one of the
last few packets sent is a late echo, never an answer. A status identical to the request (a PING
answered with the error byte 0x01) is taken for the echo the first time it comes and for the
answer the second time (echo, then answer). Its instructions differ where the bus knows them:
one-byte addresses, no sync read (bulk_read instead), no broadcast ping, a ping reply without
the model number (read from address 0), and an error byte of bits (protocol1.ErrorBit).

No status packet carries a sequence number, so a late reply of an identical earlier request
looks like the answer to this one. The bus therefore keeps a "dirty" flag for a while after any
anomaly (a timeout, a discarded or corrupted reply, bytes waiting before a request): while it
is set, one-off transactions read on to their deadline and take the last matching reply (replies
leave the bus in order). The cycle's state reads carry the servos' Realtime Tick, so the caller
dates every sample (driver/clock.py).

Every wait is a blocking read with an absolute deadline on the monotonic clock, computed from
the bytes expected, the baud rate, the servos' Return Delay Time and the USB adapter's latency
timer: a device that never stops sending cannot hold a transaction past it. The serial device
itself is serial_port.py's (or the simulator's port): the bus sees a RawPort.

The module is long (~800 lines) on purpose: the rules above (the lock, the flush, the dirty
flag, the echo, the deadlines, the counters) are one state shared by every transaction, and
splitting the sync reads from the one-off ones would spread that state over two modules that
reach into each other.
"""

import collections
import contextlib
from dataclasses import dataclass, field
import functools
import operator
import struct
import threading
import time
from typing import (
    Any, Callable, cast, Deque, Dict, Iterable, Iterator, List, Optional, Sequence, Set, Tuple,
    TypeVar, Union)

from dxl_servo_driver.errors import (
    BadRequest, CommError, CommTimeout, CorruptReply, PortError, StatusError)
from dxl_servo_driver.models import Item
from dxl_servo_driver.protocol import (
    ALERT_BIT, BITS_PER_BYTE, BROADCAST_ID, CLEAR_MULTI_TURN, crc16, ERROR_CODE_MASK, ErrorCode,
    FAST_HEAD_SIZE, FAST_PART_OVERHEAD, fast_status_head, fast_status_size, fast_sync_head,
    fast_sync_size, Frame, Framer, HEADER, Instruction, MAX_ID, parse_fast_status, PROTOCOL_2,
    RETURN_DELAY_UNIT_S, STATUS_OVERHEAD)
from dxl_servo_driver.protocol1 import (
    error_text as error_text_1, Instruction1, MAX_ADDRESS as MAX_ADDRESS_1,
    MAX_PARAMS as MAX_PARAMS_1, PROTOCOL_1)
from dxl_servo_driver.serial_port import RawPort

# The framer of each protocol version, as configurations name them.
FRAMERS: Dict[float, Framer] = {1.0: PROTOCOL_1, 2.0: PROTOCOL_2}
# Slack added to every computed deadline: OS scheduling and USB transfer jitter. It starts at
# DEADLINE_SLACK_S and doubles, up to MAX_DEADLINE_SLACK_S, whenever a reply shows it came after
# its deadline, late rather than lost (a busy machine, an adapter's jitter): the bytes a read gave
# up on wait before the next request, or the caller finds a reply dated before its request
# (Bus.raise_slack); or a sync read's whole block came only in the last half of the slack. So it
# follows the jitter seen, before a reply is lost to it. SLACK_DECAY_REQUESTS requests in a row
# with no read given up on halve it again, down to DEADLINE_SLACK_S. A servo that does not answer
# never raises it (nothing comes late), so a silent servo costs each cycle the small slack, not
# the large one.
DEADLINE_SLACK_S = 0.002
MAX_DEADLINE_SLACK_S = 0.016
SLACK_DECAY_REQUESTS = 5000
# A read sleeps until its bytes can be there only when that is further off than this: a sleep
# is a wake-up too, and a shorter one saves none.
MIN_SLEEP_S = 100e-6
# The turnaround a sync read's whole block comes after its wire time (Bus.turnaround_s) is
# learned so that this share of reads finds every byte there when its sleep ends; the rest wait
# on in poll(). The median: a later one makes every cycle sleep past its block by more (behind
# a 1 ms adapter on the benchmark's machine, 0.8 ran at 0.92 of the rate the wire and latency
# allow, 0.5 at 0.93). A step moves it by TURNAROUND_STEP_S and a twentieth of itself.
TURNAROUND_ON_TIME = 0.5
TURNAROUND_STEP_S = 10e-6
# One-off reads differ in length over this many consecutive requests (see Bus.read).
READ_TAGS = 8
# A confirmed read tries this many times more to get two equal answers in a row.
CONFIRM_ATTEMPTS = 3
PING_REPLY_PARAMS = 3          # model number (2), firmware version (1)
# A ping sweep (Bus.ping_sweep) sends each ping once the one before could have been answered on
# the wire (request, the longest Return Delay Time, answer) and this margin more: the USB
# adapter's transmit jitter, so that a ping never goes out over the answer before it.
SWEEP_MARGIN_S = 1e-3
# How long past its wire time Bus.reply_delay listens for a ping's answer: longer than any
# adapter's latency timer in use (Linux's FTDI default is 16 ms, its maximum 255 ms).
LATENCY_LISTEN_S = 0.3
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
# What the classifier makes of a frame.
ECHO, ANSWER, CORRUPT, STRAY = 'echo', 'answer', 'corrupt', 'stray'
# Protocol 1.0: packets sent lately whose echo, coming late, could pass for a status packet.
RECENT_PACKETS = 16
# Protocol 1.0: where the model number (2 bytes) is, its ping reply not carrying it.
MODEL_NUMBER_ADDRESS_1 = 0


@dataclass
class Counters:
    """What the bus saw, for diagnostics: every anomaly is counted, none is silent."""

    timeouts: int = 0          # a servo's reply missing at the deadline
    corrupt: int = 0           # replies from a servo we asked that failed their CRC
    status_errors: int = 0     # replies carrying an error code
    stale: int = 0             # replies discarded: wrong id, length, order, or a repeat
    echoes: int = 0            # our own requests seen coming back (local echo)
    flushed_bytes: int = 0     # bytes waiting before a request (late replies, noise)
    deadline_waits: int = 0    # reads that ended at their deadline short of what they asked
    slack_raised: int = 0      # times the deadline slack was doubled (replies came late)


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
    (`Bus._parse_clean`, `parse_fast_status`) takes as a whole clean block with every error
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


@dataclass
class Request:
    """A request on the wire, as the classifier matches replies against it."""

    packet: bytes
    ids: Tuple[int, ...]        # the ids that answer it, in the order they answer
    reply_params: int           # the parameters each answer carries (the most, with lengths)
    # Each id's own parameter count where they differ (a bulk read); None: reply_params.
    lengths: Optional[Dict[int, int]] = None
    # Packets sent before this one (Protocol 1.0): a late echo of one is not an answer.
    earlier: Tuple[bytes, ...] = ()
    refusal_mask: int = ERROR_CODE_MASK
    order: Dict[int, int] = field(init=False)

    def __post_init__(self) -> None:
        self.order = {servo_id: index for index, servo_id in enumerate(self.ids)}

    def classify(self, frame: Frame) -> str:
        """Return what a frame is to this request: ECHO, ANSWER, CORRUPT or STRAY."""
        if not frame.crc_ok:
            return CORRUPT if frame.servo_id in self.order else STRAY
        # First: a Protocol 1.0 echo has the shape of a status packet.
        if frame.raw == self.packet:
            return ECHO
        if not frame.is_status or frame.raw in self.earlier:
            return STRAY
        return self.classify_status(frame)

    def classify_status(self, frame: Frame) -> str:
        """Return ANSWER for a status frame that answers this request, else STRAY."""
        if frame.servo_id not in self.order:
            return STRAY
        error, data = frame.status()
        expected = self.reply_params if self.lengths is None else self.lengths[frame.servo_id]
        # An error status may come without the parameters.
        if len(data) == expected or (error & self.refusal_mask and not data):
            return ANSWER
        return STRAY

    def reply_bytes(self, overhead: int, answered: Dict[int, Tuple[int, int, bytes]]) -> int:
        """Return the bytes the answers not in answered take (each with overhead bytes)."""
        if self.lengths is None:
            return max(1, len(self.ids) - len(answered)) * (overhead + self.reply_params)
        missing = [servo_id for servo_id in self.ids if servo_id not in answered]
        return sum(overhead + self.lengths[servo_id] for servo_id in missing or self.ids[-1:])


@dataclass
class Collected:
    """What one collection found: the answers by id (the last wins), and what else came."""

    answers: Dict[int, Tuple[int, int, bytes]] = field(default_factory=dict)  # order, error, data
    corrupt: Set[int] = field(default_factory=set)   # ids asked whose frame failed its CRC
    repeated: Set[int] = field(default_factory=set)  # ids that answered more than once
    echoed: bool = False
    discarded: int = 0     # well-formed frames that answered nothing of this request (stale)
    noise: int = 0         # frames that failed their CRC, from ids not asked
    frames: int = 0
    leftover: bool = False   # bytes after the last whole frame

    @property
    def anomalies(self) -> bool:
        """Return True when anything but the answers (and our echo) came."""
        return bool(self.discarded or self.noise or self.corrupt or self.leftover)


@dataclass
class Sweep:
    """What a ping sweep heard (Bus.ping_sweep)."""

    answered: List[int] = field(default_factory=list)   # ids whose answer came whole
    garbled: List[int] = field(default_factory=list)    # ids whose answer failed its checksum
    noise: int = 0          # frames or bytes that were nobody's: a collision, a noisy line
    echoed: int = 0         # pings the adapter echoed


@dataclass(eq=False)
class SyncRead:
    """
    A sync or bulk read on the wire, owning the bus while its answers come.

    Made by Bus.begin_sync_read() or Bus.begin_bulk_read() with the bus lock taken; collect()
    or abort() (exactly one of them, once, in the same thread) ends it, and they are the only
    places that lock is released.
    """

    _bus: 'Bus'
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
        if self.done:
            raise RuntimeError('a sync read collected or aborted already')
        self.done = True
        bus = self._bus
        try:
            if bus.framer is self.framer:   # the usual case: no switch on the cycle's path
                return bus._collect_sync(self)
            with bus.speaking(self.framer):   # the protocol it went out in
                return bus._collect_sync(self)
        finally:
            bus.lock.release()

    def abort(self) -> None:
        """
        Give the read up (idempotent) and wait its answers out, then release the bus.

        Whatever arrives until the read's deadline is its answer: it is read and dropped here,
        so no later transaction (the next activation's first read, a torque-off) can take it
        for its own. Later stragglers still find the bus suspicious (dirty).
        """
        if self.done:
            return
        self.done = True
        bus = self._bus
        bus.mark_dirty()
        chunk = self.framer.status_overhead * len(self.ids) + 4096
        try:
            while time.monotonic() < self.deadline_s:
                dropped = bus._read(chunk, self.deadline_s, to_deadline=True)
                bus.counters.flushed_bytes += len(dropped)
        except PortError:
            pass   # a lost port holds nothing to wait for; its next user finds it lost
        finally:
            bus.lock.release()


Method = TypeVar('Method', bound=Callable[..., Any])


def sweep_spacing_s(baud_bps: int, framer: Framer) -> float:
    """Return the time between two pings of a sweep (Bus.ping_sweep) at a baud rate."""
    ping = len(framer.encode(MAX_ID, Instruction.PING))
    answer = framer.status_overhead + framer.ping_reply_params
    return (ping + answer) * BITS_PER_BYTE / baud_bps + 254 * RETURN_DELAY_UNIT_S + SWEEP_MARGIN_S


def broadcast_ping_s(baud_bps: int) -> float:
    """Return how long a broadcast ping waits beyond the latency timer (Bus.broadcast_ping)."""
    answer = STATUS_OVERHEAD + PING_REPLY_PARAMS
    ping = len(PROTOCOL_2.encode(BROADCAST_ID, Instruction.PING))
    return ((ping + answer * (MAX_ID + 1)) * BITS_PER_BYTE / baud_bps
            + BROADCAST_PING_PER_ID_S * (MAX_ID + 1))


def _heard(frames: Sequence[Frame], requests: Dict[int, Request], leftover: int) -> Sweep:
    """Sort a ping sweep's frames into answers, garbled answers and noise."""
    sweep = Sweep(noise=leftover)
    echoes: Dict[int, int] = {}
    for frame in frames:
        request = requests.get(frame.servo_id)
        kind = request.classify(frame) if request is not None else STRAY
        if kind == ECHO and echoes.get(frame.servo_id) and frame.is_status:
            # Protocol 1.0: an answer may be our ping byte for byte; the echo comes first.
            kind = request.classify_status(frame) if request is not None else STRAY
        if kind == ANSWER:
            sweep.answered.append(frame.servo_id)
        elif kind == ECHO:
            echoes[frame.servo_id] = echoes.get(frame.servo_id, 0) + 1
        elif kind == CORRUPT:
            sweep.garbled.append(frame.servo_id)
        else:
            sweep.noise += 1
    sweep.echoed = len(echoes)
    if sweep.echoed <= len(requests) // 2:
        # The adapter does not echo: a lone copy of a ping is its servo's answer.
        sweep.answered += [servo_id for servo_id in echoes if servo_id not in sweep.answered]
    sweep.answered = sorted(set(sweep.answered))
    sweep.garbled = sorted(set(sweep.garbled) - set(sweep.answered))
    return sweep


def _to_servo(method: Method) -> Method:
    """Run a transaction with one servo in that servo's protocol (Bus.speak)."""
    @functools.wraps(method)
    def speaking(bus: 'Bus', servo_id: int, *args: Any, **kwargs: Any) -> Any:
        with bus.speaking(bus.framer_for(servo_id)):
            return method(bus, servo_id, *args, **kwargs)
    return cast(Method, speaking)


class Bus:
    """
    One bus of servos on one port. Thread-safe: one transaction at a time.

    A bus may carry both protocols: the one given is its default (broadcasts, and every id not
    told otherwise); speak() says an id answers in the other. The framer in force (`framer`)
    is switched only under the bus lock, for one transaction.

    The bus never retries on its own; the caller decides what a failure means.
    """

    def __init__(self, port: RawPort, baud_bps: int, latency_timer_s: float = 0.016,
                 return_delay_s: float = 0.0005, framer: Framer = PROTOCOL_2) -> None:
        self.port = port
        # A real device: its bytes come no faster than the wire carries them (Bus._read).
        self._paced = bool(getattr(port, 'paced', False))
        self.baud_bps = baud_bps
        self.latency_timer_s = latency_timer_s
        # The largest Return Delay Time expected on this bus (the factory default is 500 us),
        # and the smallest: no answer comes sooner than that after its request.
        self.return_delay_s = return_delay_s
        self.least_return_delay_s = 0.0
        # How long after its wire time a sync read's block is whole on this port: the device's
        # or simulator's turnaround, an adapter's latency timer (learned by Bus._read).
        self.turnaround_s = 0.0
        self.framer = framer
        self.default_framer = framer
        self._framers: Dict[int, Framer] = {}   # ids that speak another protocol
        self.lock = threading.RLock()
        self.counters = Counters()
        self.echo = False             # learned: the adapter echoes what we send
        self._echo_misses = 0
        self._dirty_until = 0.0
        self.slack_s = DEADLINE_SLACK_S   # the deadline slack in force (see DEADLINE_SLACK_S)
        self._gave_up = False             # a read since the last request ended short
        self._easy_requests = 0
        self._sync_read_requests: Dict[Tuple[int, int, Tuple[int, ...], bool], Request] = {}
        self._status_prefixes: Dict[Tuple[Tuple[int, ...], Tuple[int, ...]], List[bytes]] = {}
        self._templates: Dict[Tuple[bytes, str], BlockTemplate] = {}
        self._read_tag = 0
        self._recent: Deque[bytes] = collections.deque(maxlen=RECENT_PACKETS)

    # protocols ----------------------------------------------------------------------------
    def speak(self, servo_id: int, framer: Framer) -> None:
        """Say that servo_id answers in this framer's protocol (its transactions use it)."""
        with self.lock:
            if framer is self.default_framer:
                self._framers.pop(servo_id, None)
            else:
                self._framers[servo_id] = framer

    def framer_for(self, servo_id: int) -> Framer:
        """Return the framer of the protocol servo_id speaks."""
        return self._framers.get(servo_id, self.default_framer)

    @contextlib.contextmanager
    def speaking(self, framer: Optional[Framer]) -> Iterator[None]:
        """Hold the bus with this framer in force (None: the default), restored after."""
        with self.lock:
            before = self.framer
            self.framer = self.default_framer if framer is None else framer
            try:
                yield
            finally:
                self.framer = before

    # timing and state --------------------------------------------------------------------
    def byte_time_s(self, n_bytes: int) -> float:
        """Return the time n_bytes take on the wire (8N1)."""
        return n_bytes * BITS_PER_BYTE / self.baud_bps

    def reply_timeout_s(self, reply_bytes: int, n_replies: int = 1, tx_bytes: int = 0) -> float:
        """Return how long to wait for replies, from the moment the instruction was written."""
        return (self.byte_time_s(tx_bytes + reply_bytes) + n_replies * self.return_delay_s
                + self.latency_timer_s + self.slack_s)

    def raise_slack(self) -> None:
        """
        Double the deadline slack (to its cap): a reply came after its deadline.

        The bus sees it when the bytes a read gave up on wait before the next request; the
        caller when a reply it took is dated before its request (a late one taken in the place
        of its own: the cycle's tick dating).
        """
        self.slack_s = min(MAX_DEADLINE_SLACK_S, 2.0 * self.slack_s)
        self.counters.slack_raised += 1
        self._easy_requests = 0

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

    def mark_dirty(self) -> None:
        """Be suspicious of replies for a while (an anomaly happened)."""
        self._dirty_until = time.monotonic() + DIRTY_HOLD_S

    def close(self) -> None:
        """Close the port."""
        with self.lock:
            self.port.close()

    # the port ------------------------------------------------------------------------------
    def _flush(self) -> None:
        # Bytes waiting before a request are late replies or noise: never an answer to it.
        port = self.port
        waiting = port.in_waiting
        if waiting:
            port.reset_input_buffer()
            self.counters.flushed_bytes += waiting
            self.mark_dirty()
            if self._gave_up:
                # What the last read gave up on came after all: the deadline was too tight.
                self.raise_slack()
        elif not self._gave_up and self.slack_s > DEADLINE_SLACK_S:
            self._easy_requests += 1
            if self._easy_requests >= SLACK_DECAY_REQUESTS:
                self.slack_s = max(DEADLINE_SLACK_S, 0.5 * self.slack_s)
                self._easy_requests = 0
        self._gave_up = False

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
        if self.framer.version == 1:
            self._recent.append(packet)
        return before, time.monotonic()

    def _request(self, packet: bytes, ids: Tuple[int, ...], reply_params: int,
                 lengths: Optional[Dict[int, int]] = None) -> Request:
        """Return the Request a packet about to be sent is matched by."""
        if self.framer.version == 1:
            return Request(packet, ids, reply_params, lengths, tuple(self._recent),
                           self.framer.refusal_mask)
        return Request(packet, ids, reply_params, lengths)

    def _address_length(self, address: int, length: int) -> bytes:
        """Return an instruction's address and length parameters in this bus's protocol."""
        if self.framer.version == 1:
            _check_reach_1(address, length)
            return bytes((address, length))
        return struct.pack('<HH', address, length)

    def _read(self, size: int, deadline_s: float, to_deadline: bool = False,
              due_s: float = 0.0) -> bytes:
        """
        Read up to size bytes by deadline_s; to_deadline: waiting it out is the point.

        due_s: the earliest they can all be there. On a port whose bytes come at wire speed
        (`paced`) the read sleeps until then plus the learned turnaround (_learn_turnaround): a
        tty wakes a poller at every piece that comes (each servo's status packet, each USB
        transfer), and each wake-up costs more CPU than the read itself (40-70 us of a core on
        the benchmark's machine).
        """
        size = max(1, size)
        learn = self._paced and due_s > 0.0
        if learn:
            wait_s = min(due_s + self.turnaround_s, deadline_s) - time.monotonic()
            if wait_s > MIN_SLEEP_S:
                time.sleep(wait_s)
        try:
            data = self.port.read(size, max(0.0, deadline_s - time.monotonic()))
        except OSError as exc:
            raise _port_lost(exc) from None
        if learn and len(data) >= size:
            self._learn_turnaround(bool(getattr(self.port, 'waited', False)))
        if len(data) < size and not to_deadline:
            # What makes a cycle slow: a wait to the deadline (a missing reply, or asking for
            # more than is coming).
            self.counters.deadline_waits += 1
            self._gave_up = True
        return data

    def _learn_turnaround(self, waited: bool) -> None:
        """
        Move the learned turnaround after a whole block: later if it had to be waited for.

        Sleeping until the bytes are all there saves the wake-ups of a poll() that each piece
        ends (each servo's answer, each USB transfer); sleeping longer than that delays the
        cycle. A stochastic quantile: up by TURNAROUND_ON_TIME of a step when the block had to
        be waited for, down by the rest of one when it was there, so that share of reads finds
        it there. Held below the latency timer and a quarter of the deadline's least slack:
        a sleep never ends where a block taken is judged nearly given up on (the last half of
        the slack, Bus._collect_sync). A read that did not get its block (a silent servo) says
        nothing.
        """
        step = TURNAROUND_STEP_S + 0.05 * self.turnaround_s
        if waited:
            self.turnaround_s = min(self.turnaround_s + TURNAROUND_ON_TIME * step,
                                    self.latency_timer_s + 0.25 * DEADLINE_SLACK_S)
        else:
            self.turnaround_s = max(0.0, self.turnaround_s - (1.0 - TURNAROUND_ON_TIME) * step)

    # the echo ------------------------------------------------------------------------------
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

    def _note_echo(self, echoed: bool, answered: bool) -> None:
        if echoed:
            self._echo_seen()
        elif answered:
            self._echo_missing()

    # the collector -------------------------------------------------------------------------
    def _collect(self, request: Request, deadline_s: float, buffer: bytearray,
                 linger: bool, done: Callable[[Collected], bool]) -> Collected:
        """
        Read and classify the replies of a request until done() or its deadline.

        buffer holds what was read already. Each id's last answer wins (replies leave the bus
        in order: a late or repeated one comes before the answer to this request). With linger
        the replies are read to the deadline; otherwise no more is asked of the port than the
        answers still missing need (asking more would wait for the deadline).
        """
        collected = Collected()
        reply_size = self.framer.status_overhead + request.reply_params
        max_length = max(2 * (request.reply_params + 4) + 8, len(request.packet))
        pos = 0
        while True:
            final = time.monotonic() >= deadline_s
            frames, pos = self.framer.scan(buffer, pos, max_length, final)
            for frame in frames:
                collected.frames += 1
                kind = request.classify(frame)
                if kind == ECHO and collected.echoed and frame.is_status:
                    # Protocol 1.0: a status may be our request byte for byte; the echo
                    # comes first, so the second copy is the servo's.
                    kind = request.classify_status(frame)
                if kind == ANSWER:
                    servo_id = frame.servo_id
                    if servo_id in collected.answers:
                        collected.discarded += 1   # an earlier one was late: the last wins
                        collected.repeated.add(servo_id)
                    error, data = frame.status()
                    collected.answers[servo_id] = (collected.frames, error, data)
                elif kind == ECHO:
                    collected.echoed = True
                elif kind == CORRUPT:
                    collected.corrupt.add(frame.servo_id)
                elif frame.crc_ok:
                    collected.discarded += 1
                else:
                    collected.noise += 1
            if final or (not linger and done(collected)):
                break
            if linger:
                buffer += self._read(reply_size, deadline_s, to_deadline=True)
            else:
                # What the missing answers still lack (the bytes from pos on start one).
                missing = request.reply_bytes(self.framer.status_overhead, collected.answers)
                buffer += self._read(max(1, missing - (len(buffer) - pos)), deadline_s)
        collected.leftover = pos < len(buffer)
        self.counters.stale += collected.discarded
        return collected

    def _missing(self, servo_id: int, corrupt: bool, corrupt_text: str,
                 silent_text: str) -> CommError:
        """Count and return why a servo has no answer: corrupt or silent."""
        if corrupt:
            self.counters.corrupt += 1
            return CorruptReply(f'id {servo_id}: {corrupt_text}', servo_id)
        self.counters.timeouts += 1
        return CommTimeout(f'id {servo_id}: {silent_text}', servo_id)

    def _answer(self, servo_id: int, error: int, data: bytes,
                what: str) -> Union[bytes, StatusError]:
        """Return an answer's data, or the StatusError its error byte says (counted)."""
        framer = self.framer
        code = error & framer.refusal_mask
        if not code:
            return data
        self.counters.status_errors += 1
        text = error_text_1(code) if framer.version == 1 else ERROR_TEXT.get(code, str(code))
        return StatusError(f'id {servo_id}: {what} refused: {text}', servo_id, code,
                           bool(error & framer.alert_mask))

    def alert(self, error: int) -> bool:
        """Return whether a status error byte reports a hardware error (the alert)."""
        return bool(error & self.framer.alert_mask)

    # one-off transactions ------------------------------------------------------------------
    @_to_servo
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
        request = self._request(self.framer.encode(servo_id, instruction, params), (servo_id,),
                                reply_params)
        with self.lock:
            if linger is None:
                linger = self.dirty
            sent_s, written_s = self._send(request.packet)
            reply_size = self.framer.status_overhead + reply_params
            deadline = written_s + self.reply_timeout_s(reply_size, 1, len(request.packet))
            want = reply_size + (len(request.packet) if self.echo else 0)
            buffer = bytearray(self._read(want, deadline))
            collected = self._collect(request, deadline, buffer, linger,
                                      lambda found: servo_id in found.answers)
            self._note_echo(collected.echoed, servo_id in collected.answers)
            if collected.anomalies:
                self.mark_dirty()
            answer = collected.answers.get(servo_id)
            if answer is None:
                if not probe or collected.anomalies:
                    self.mark_dirty()
                if collected.corrupt:
                    self.counters.corrupt += 1
                    raise CorruptReply(f'id {servo_id}: corrupted status packet for {what}',
                                       servo_id)
                self.counters.timeouts += 1
                version = self.framer.version
                hint = (' (only replies that did not answer it came back)' if collected.discarded
                        else f' (check the id, the baud rate, Protocol {version}.0, the servo '
                        'power and the adapter latency timer)')
                raise CommTimeout(f'id {servo_id}: no status packet for {what} at '
                                  f'{self.baud_bps} bps{hint}', servo_id)
            _, error, data = answer
            result = self._answer(servo_id, error, data, what)
            if isinstance(result, StatusError):
                raise result
            return result, sent_s

    def _refuse_on_1(self, what: str, instead: str) -> None:
        """Refuse an instruction Protocol 1.0 does not have (BadRequest)."""
        if self.framer.version == 1:
            raise BadRequest(f'{what} does not exist in Protocol 1.0 ({instead})')

    @_to_servo
    def ping(self, servo_id: int, probe: bool = False) -> int:
        """
        Return the model number of the servo; raise when it does not answer.

        probe: its silence is expected now and then (a booting servo, a scan), so it does not
        make the bus suspicious of the transactions that follow.
        """
        if self.framer.version == 1:
            # A Protocol 1.0 ping reply carries no parameters: the model number is read.
            self._transact(servo_id, Instruction1.PING, b'', 0, 'ping', None, probe)
            data = self.read_fresh(servo_id, MODEL_NUMBER_ADDRESS_1, 2)[0]
            return data[0] | (data[1] << 8)
        data = self._transact(servo_id, Instruction.PING, b'', PING_REPLY_PARAMS, 'ping', None,
                              probe)[0]
        return data[0] | (data[1] << 8)

    @_to_servo
    def reply_delay(self, servo_id: int, listen_s: float = LATENCY_LISTEN_S) -> Optional[float]:
        """
        Return how long after its wire time a ping's answer came (s); None if none came.

        The deadline is listen_s, not the latency timer in force: this is how an adapter's
        real latency is measured where the OS does not say it (a pty, a non-FTDI adapter). The
        delay holds the servo's Return Delay Time and the host's wake-up too.
        """
        framer = self.framer
        request = self._request(framer.encode(servo_id, Instruction.PING), (servo_id,),
                                framer.ping_reply_params)
        reply_size = framer.status_overhead + framer.ping_reply_params
        with self.lock:
            _, written_s = self._send(request.packet)
            due_s = written_s + self.byte_time_s(len(request.packet) + reply_size)
            deadline = due_s + listen_s
            want = reply_size + (len(request.packet) if self.echo else 0)
            buffer = bytearray(self._read(want, deadline, to_deadline=True))
            collected = self._collect(request, deadline, buffer, False,
                                      lambda found: servo_id in found.answers)
            came_s = time.monotonic()
            self._note_echo(collected.echoed, servo_id in collected.answers)
            if servo_id not in collected.answers:
                if collected.anomalies:
                    self.mark_dirty()
                return None
            return max(0.0, came_s - due_s)

    def ping_sweep(self, ids: Sequence[int], framer: Framer) -> Sweep:
        """
        Ping every id in turn without waiting for each answer; return who answered.

        Each ping goes out once the one before could have been answered on the wire, and the
        answers are read once, after the last: a sweep of 253 ids waits the adapter's latency
        timer once, not 253 times (Protocol 1.0 has no broadcast ping). What it finds are
        candidates: the caller pings each again alone. Noise says the sweep cannot be trusted
        (answers collided), and the caller then pings every id alone.
        """
        reply_size = framer.status_overhead + framer.ping_reply_params
        requests = {servo_id: Request(framer.encode(servo_id, Instruction.PING), (servo_id,),
                                      framer.ping_reply_params, refusal_mask=framer.refusal_mask)
                    for servo_id in ids}
        longest = max((len(request.packet) for request in requests.values()), default=0)
        spacing_s = sweep_spacing_s(self.baud_bps, framer)
        buffer = bytearray()
        with self.speaking(framer):
            self._flush()
            due_s = time.monotonic()
            for request in requests.values():
                wait_s = due_s - time.monotonic()
                if wait_s > 0.0:
                    time.sleep(wait_s)
                try:
                    self.port.write(request.packet)
                    waiting = self.port.in_waiting
                    if waiting:
                        buffer += self.port.read(waiting, 0.0)
                except OSError as exc:
                    raise _port_lost(exc) from None
                due_s = time.monotonic() + spacing_s
            deadline = due_s + self.latency_timer_s + self.slack_s
            buffer += self._read(len(requests) * (longest + reply_size), deadline,
                                 to_deadline=True)
            frames, end = framer.scan(
                buffer, 0, max(2 * (framer.ping_reply_params + 4) + 8, longest), True)
        return _heard(frames, requests, len(buffer) - end)

    def broadcast_ping(self) -> Dict[int, int]:
        """Return {id: model number} of every servo that answers a broadcast ping (2.0 only)."""
        self._refuse_on_1('broadcast ping', 'ping the ids one by one')
        request = Request(self.framer.encode(BROADCAST_ID, Instruction.PING),
                          tuple(range(MAX_ID + 1)), PING_REPLY_PARAMS)
        with self.lock:
            _, written_s = self._send(request.packet)
            # Every id may answer: the replies are read to the deadline.
            deadline = (written_s + broadcast_ping_s(self.baud_bps) + self.latency_timer_s
                        + self.slack_s)
            collected = self._collect(request, deadline, bytearray(), True, lambda found: False)
            self._note_echo(collected.echoed, bool(collected.answers))
        return {servo_id: data[0] | (data[1] << 8)
                for servo_id, (_, error, data) in collected.answers.items()
                if len(data) == PING_REPLY_PARAMS}

    @_to_servo
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

    @_to_servo
    def read_fresh(self, servo_id: int, address: int, length: int) -> Tuple[bytes, float]:
        """Return (data, time the request went out) of one length-tagged read (see read())."""
        self._read_tag = (self._read_tag + 1) % READ_TAGS
        before = min(self._read_tag, address)
        extra = self._read_tag
        if self.framer.version == 1:
            _check_reach_1(address, length)
            # Protocol 1.0 reaches address 255 at most, 253 bytes a read: the tag (extra
            # bytes, before of them ahead of the register) stays inside that.
            extra = min(extra, MAX_PARAMS_1 - length)
            room = MAX_ADDRESS_1 + 1 - address - length
            before = min(address, extra, max(before, extra - room))
            extra = min(extra, before + room)
        data, sent_s = self._transact(servo_id, Instruction.READ,
                                      self._address_length(address - before, length + extra),
                                      length + extra, f'read of {length} bytes at {address}',
                                      None)
        return data[before:before + length], sent_s

    @_to_servo
    def read_dated(self, servo_id: int, address: int, length: int,
                   linger: Optional[bool] = False) -> Tuple[bytes, float]:
        """
        Return (data, time the request went out) of a read whose data the caller dates itself.

        For the state block's tagged reads (the Realtime Tick tells a late reply): no reading
        on to the deadline when the bus is suspicious (linger None: then it does, for a sample
        that carries no tick).
        """
        return self._transact(servo_id, Instruction.READ, self._address_length(address, length),
                              length, f'read of {length} bytes at {address}', linger)

    @_to_servo
    def write(self, servo_id: int, address: int, data: bytes) -> None:
        """Write bytes to the servo's control table at address, and check the status."""
        if self.framer.version == 1:
            _check_reach_1(address, len(data), 1)
            params = bytes((address,)) + bytes(data)
        else:
            params = struct.pack('<H', address) + bytes(data)
        self.transact(servo_id, Instruction.WRITE, params, 0,
                      f'write of {len(data)} bytes at {address}')

    def read_item(self, servo_id: int, item: Item) -> int:
        """Return one control-table item's value."""
        data = self.read(servo_id, item.address, item.size)
        return item.decode(data)

    def write_item(self, servo_id: int, item: Item, value: int) -> None:
        """Write one control-table item."""
        self.write(servo_id, item.address, item.encode(value))

    @_to_servo
    def reboot(self, servo_id: int) -> None:
        """Send REBOOT and check the servo acknowledged it."""
        # The status of a REBOOT may carry the alert bit of the error being cleared.
        self.transact(servo_id, Instruction.REBOOT, b'', 0, 'reboot')

    @_to_servo
    def clear_multi_turn(self, servo_id: int) -> None:
        """Send CLEAR: present position back within one turn (the servo must be still)."""
        self._refuse_on_1('CLEAR', 'no multi-turn clear')
        self.transact(servo_id, Instruction.CLEAR, CLEAR_MULTI_TURN, 0, 'clear multi-turn')

    @_to_servo
    def factory_reset(self, servo_id: int, option: int) -> None:
        """Send FACTORY_RESET with option 0xFF, 0x01 or 0x02 (1.0: RESET, 0xFF only)."""
        if self.framer.version == 1:
            if option != 0xFF:
                raise BadRequest(f'Protocol 1.0 RESET has no option {option:#04x}: it resets '
                                 'everything (option 0xFF)', servo_id)
            self.transact(servo_id, Instruction1.RESET, b'', 0, 'factory reset')
            return
        self.transact(servo_id, Instruction.FACTORY_RESET, bytes((option,)), 0, 'factory reset')

    # per-cycle transactions ----------------------------------------------------------------
    def _sync_read_request(self, address: int, length: int, ids: Tuple[int, ...],
                           fast: bool) -> Request:
        """Return the Request of a sync read, made once per roster and part (not per cycle)."""
        key = (address, length, ids, fast)
        request = self._sync_read_requests.get(key)
        if request is None:
            params = struct.pack('<HH', address, length) + bytes(ids)
            packet = self.framer.encode(
                BROADCAST_ID, Instruction.FAST_SYNC_READ if fast else Instruction.SYNC_READ,
                params)
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
        id_tuple = tuple(ids)
        # Only a bus where some id speaks 1.0 needs the look (not the usual one, every cycle).
        if (self._framers or self.default_framer.version == 1) and any(
                self.framer_for(servo_id).version == 1 for servo_id in id_tuple):
            raise BadRequest(f'{"fast sync read" if fast else "sync read"} does not exist in '
                             'Protocol 1.0 (use bulk_read)')
        self.lock.acquire()
        try:
            if self.framer is PROTOCOL_2:   # the usual bus: no switch on the cycle's path
                request, expected, sent_s, written_s = self._send_sync_read(
                    address, length, id_tuple, fast)
            else:
                with self.speaking(PROTOCOL_2):
                    request, expected, sent_s, written_s = self._send_sync_read(
                        address, length, id_tuple, fast)
        except BaseException:
            self.lock.release()
            raise
        deadline = written_s + self.reply_timeout_s(expected, len(id_tuple), len(request.packet))
        return SyncRead(self, request, length, address, sent_s, deadline, fast, linger,
                        fields=fields)

    def _send_sync_read(self, address: int, length: int, ids: Tuple[int, ...],
                        fast: bool) -> Tuple[Request, int, float, float]:
        """Put a sync read on the wire: (request, bytes expected, sent_s, written_s)."""
        request = self._sync_read_request(address, length, ids, fast)
        expected = self._sync_reply_size(length, len(ids), fast)
        sent_s, written_s = self._send(request.packet)
        return request, expected, sent_s, written_s

    def _sync_reply_size(self, length: int, count: int, fast: bool) -> int:
        """Return the bytes the answers to a sync read of length bytes from count servos take."""
        if fast:
            return fast_sync_size(length, count)
        return (self.framer.status_overhead + length) * count

    def _reply_size(self, lengths: Sequence[int], fast: bool) -> int:
        """Return the bytes the answers of these data lengths take (fast: in one status)."""
        if fast:
            return fast_status_size(lengths)
        return self.framer.status_overhead * len(lengths) + sum(lengths)

    def _collect_sync(self, pending: SyncRead) -> SyncResult:
        """Collect a sync or bulk read's answers (SyncRead.collect, its framer in force)."""
        ids = pending.ids
        lengths = pending.lengths
        expected = self._reply_size(lengths, pending.fast)
        echo_size = len(pending.packet) if self.echo else 0
        echoes = self.counters.echoes
        entered = time.monotonic()
        # The earliest the whole block can be here: the line carries the request, then each
        # answer after its servo's Return Delay Time (a fast read's after the first's only).
        # An echo comes while the request goes out.
        due_s = (pending.sent_s + self.byte_time_s(len(pending.packet) + expected)
                 + (1 if pending.fast else len(ids)) * self.least_return_delay_s)
        buffer = self._read(echo_size + expected, pending.deadline_s, due_s=due_s)
        if len(buffer) == echo_size + expected:
            # Whole, but in the last half of the slack while we waited for it: nearly given up
            # on. More slack before a reply comes later still (a collect begun in that half
            # cannot tell when the bytes came, and says nothing).
            near = pending.deadline_s - 0.5 * self.slack_s
            if entered < near < time.monotonic():
                self.raise_slack()
        if echo_size and buffer[:echo_size] == pending.packet:
            buffer = buffer[echo_size:]
            self._echo_seen()
        if pending.fields and not pending.linger and self.framer.version == 2:
            template = self._template(pending)
            values = template.parse(buffer)
            if values is not None:
                return SyncResult({}, True, pending.sent_s, values=values, block=buffer,
                                  template=template)
        if pending.fast:
            result = self._collect_fast(pending, buffer)
        else:
            results = (None if pending.linger or self.framer.version != 2
                       else self._parse_clean(buffer, ids, lengths))
            if results is not None:
                return SyncResult(results, True, pending.sent_s, dict.fromkeys(ids, False))
            # An echo not where expected (something came first) is found among the frames.
            # No Realtime Tick need date a bulk read's answers (its caller reads what it
            # likes): an id that answered twice has a late reply among them, maybe after the
            # answer, and is refused.
            result = self._collect_sync_frames(pending, bytearray(buffer), pending.what,
                                               pending.bulk)
        if (echo_size and self.counters.echoes == echoes
                and any(isinstance(data, bytes) for data in result.data.values())):
            self._echo_missing()
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
        """
        Parse the usual case at once: every reply there, in order, unstuffed, error byte 0.

        Each reply (of its id's length: a bulk read's differ) must start with exactly the bytes
        a clean Protocol 2.0 status of that id has (header, id, length, 0x55, error 0) and pass
        its CRC; anything else returns None and the collector takes the whole buffer.
        """
        overhead = self.framer.status_overhead
        if len(buffer) != overhead * len(ids) + sum(lengths):
            return None
        key = (ids, lengths)
        prefixes = self._status_prefixes.get(key)
        if prefixes is None:
            prefixes = [HEADER + struct.pack('<BHBB', servo_id, length + 4, Instruction.STATUS, 0)
                        for servo_id, length in zip(ids, lengths)]
            if len(self._status_prefixes) > 64:
                self._status_prefixes.clear()
            self._status_prefixes[key] = prefixes
        results: Dict[int, Union[bytes, CommError]] = {}
        start = 0
        for servo_id, prefix, length in zip(ids, prefixes, lengths):
            body_end = start + overhead + length - 2
            crc = buffer[body_end] | buffer[body_end + 1] << 8
            if buffer[start:start + 9] != prefix or crc16(buffer[start:body_end]) != crc:
                return None
            results[servo_id] = buffer[start + 9:body_end]
            start = body_end + 2
        return results

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
        ids = pending.ids
        request = pending.request
        found = self._collect(request, pending.deadline_s, buffer, pending.linger,
                              lambda got: not got.anomalies and len(got.answers) == len(ids))
        if found.echoed:
            self._echo_seen()   # a missing echo is judged by the caller, _collect_sync
        if found.anomalies or len(found.answers) < len(ids):
            self.mark_dirty()   # a missing reply may still come, late
        results: Dict[int, Union[bytes, CommError]] = {}
        alerts: Dict[int, bool] = {}
        latest = 0   # frame number of the last accepted answer, in request order
        for servo_id in ids:
            answer = found.answers.get(servo_id)
            if answer is None:
                results[servo_id] = self._missing(
                    servo_id, servo_id in found.corrupt,
                    f'corrupted status packet in the {what}', f'no status packet in the {what}')
                continue
            number, error, data = answer
            if refuse_repeated and servo_id in found.repeated:
                self.counters.stale += 1
                results[servo_id] = CommTimeout(
                    f'id {servo_id}: more than one reply in the {what} (a late one after the '
                    'answer?)', servo_id)
                continue
            if number < latest:
                self.counters.stale += 1
                results[servo_id] = CommTimeout(
                    f'id {servo_id}: its reply came before that of an id asked earlier '
                    '(a late reply of an earlier request?)', servo_id)
                continue
            latest = number
            alerts[servo_id] = self.alert(error)
            results[servo_id] = self._answer(servo_id, error, data, what)
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
            data += self._read(missing if missing > 0 else size, pending.deadline_s)
        if start > 0:
            if data.startswith(pending.packet):
                self._echo_seen()   # learned: the adapter echoes (stripped from now on)
            else:
                self.counters.stale += 1   # something came before the answer
        self.mark_dirty()   # a missing part may still come, late
        truncated = start < 0 or len(data) - start < size
        return self._fast_result(pending, parts, False, not truncated)

    def _fast_result(self, pending: SyncRead, parts: Dict[int, Tuple[int, bytes]],
                     clean: bool, complete: bool) -> SyncResult:
        results: Dict[int, Union[bytes, CommError]] = {}
        alerts: Dict[int, bool] = {}
        what = pending.what
        for servo_id in pending.ids:
            part = parts.get(servo_id)
            if part is None:
                results[servo_id] = self._missing(
                    servo_id, complete, f'its part of the {what} did not check',
                    f'no part in the {what}')
                continue
            error, data = part
            alerts[servo_id] = bool(error & ALERT_BIT)
            results[servo_id] = self._answer(servo_id, error, data, what)
        return SyncResult(results, clean, pending.sent_s, alerts)

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
        with self.speaking(framer):
            return self.begin_bulk_read(requests, linger=self.dirty,
                                        framer=self.framer).collect()

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
        framer = PROTOCOL_2 if framer is None else framer
        records = [(int(servo_id), int(address), int(length))
                   for servo_id, address, length in requests]
        ids = tuple(servo_id for servo_id, _, _ in records)
        if not ids or len(set(ids)) != len(ids):
            raise BadRequest(f'a bulk read asks each id once, at least one: got {list(ids)}')
        version = framer.version
        if fast and version == 1:
            raise BadRequest('fast bulk read does not exist in Protocol 1.0 (use bulk_read)')
        others = [servo_id for servo_id in ids if self.framer_for(servo_id).version != version]
        if others:
            raise BadRequest(f'ids {others} do not speak Protocol {version}.0: a bulk read '
                             'reaches the servos of one protocol')
        lengths = {servo_id: length for servo_id, _, length in records}
        self.lock.acquire()
        try:
            with self.speaking(framer):
                packet = self._bulk_read_packet(records, fast)
                request = self._request(packet, ids, max(lengths.values()), lengths)
                expected = self._reply_size([length for _, _, length in records], fast)
                sent_s, written_s = self._send(packet)
        except BaseException:
            self.lock.release()
            raise
        deadline = written_s + self.reply_timeout_s(expected, len(ids), len(packet))
        return SyncRead(self, request, max(lengths.values()), -1, sent_s, deadline, fast, linger,
                        bulk=True, framer=framer)

    def _bulk_read_packet(self, records: List[Tuple[int, int, int]], fast: bool) -> bytes:
        """Return a bulk read's packet in the framer in force (1.0: never fast)."""
        if self.framer.version == 1:
            params = bytearray((0x00,))   # the e-manual's Protocol 1.0 bulk read starts so
            for servo_id, address, length in records:
                _check_reach_1(address, length)
                params += bytes((length, servo_id, address))
            return self.framer.encode(BROADCAST_ID, Instruction1.BULK_READ, bytes(params))
        params = bytearray()
        for servo_id, address, length in records:
            params += struct.pack('<BHH', servo_id, address, length)
        return self.framer.encode(
            BROADCAST_ID, Instruction.FAST_BULK_READ if fast else Instruction.BULK_READ,
            bytes(params))

    def sync_write(self, address: int, length: int, data: Iterable[Tuple[int, bytes]],
                   framer: Optional[Framer] = None) -> int:
        """Write length bytes at address on several servos with one SYNC_WRITE; return bytes."""
        with self.speaking(framer):
            return self._sync_write(address, length, data)

    def _sync_write(self, address: int, length: int, data: Iterable[Tuple[int, bytes]]) -> int:
        params = bytearray(self._address_length(address, length))
        for servo_id, value in data:
            if len(value) != length:
                raise ValueError(f'sync write of {length} bytes: id {servo_id} has {len(value)}')
            params.append(servo_id)
            params += value
        packet = self.framer.encode(BROADCAST_ID, Instruction.SYNC_WRITE, bytes(params))
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
        return len(packet)


def _check_reach_1(address: int, length: int, other_params: int = 0) -> None:
    """Refuse an access Protocol 1.0 cannot express: one-byte addresses, 253 parameters."""
    if (address < 0 or length < 1 or address + length > MAX_ADDRESS_1 + 1
            or length + other_params > MAX_PARAMS_1):
        raise BadRequest(f'{length} bytes at address {address}: Protocol 1.0 reaches addresses '
                         f'0..{MAX_ADDRESS_1} only, {MAX_PARAMS_1} parameters a packet')


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


def _port_lost(exc: BaseException) -> PortError:
    # pyserial's SerialException and the simulator's disconnect are both OSError subclasses.
    if isinstance(exc, PortError):
        return exc
    return PortError(f'port lost: {exc}; was the adapter unplugged?')
