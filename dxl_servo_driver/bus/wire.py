"""
The bus's bottom layer: one port's wire, the state every transaction on it shares.

It owns the state every transaction of the port shares: the lock (one transaction at a time),
the framer in force, the flush, the deadlines and their adaptive slack, the local echo, the
learned turnaround, the dirty flag, the counters, the one frame classifier (Request) and
collector (Wire.collect) every transaction reads its replies with, and the judgement of an answer
(Wire.answer, Wire.missing). The layers above (transactions.Transactions, group_reads.GroupReads)
each hold the wire and reach it through its public names only (the Wire docstring lists them).

Every transaction follows one rule: a reply is accepted only when it answers the request just
sent. Before a request goes out, whatever is waiting on the port (a late reply of an earlier
request) is dropped; then the replies are framed (the framer: protocol.PROTOCOL_2 by default,
protocol1.PROTOCOL_1 for Protocol 1.0) and every frame goes through one classifier: our own
request coming back (the local echo of a half-duplex adapter: learned, then expected and skipped
cheaply), a status packet from an id asked with the parameter length the request implies (an
answer), a corrupted frame from an id asked, or anything else (a reply to another id or of
another length, an earlier reply again, line noise), counted and discarded.

Where our own packets look like status packets (Protocol 1.0: Framer.echo_like_status), our echo
is told from an answer by comparing the frame with the packet sent, before anything else; a
frame equal to one of the last few packets sent is a late echo, never an answer. A status
identical to the request (a PING answered with the error byte 0x01) is taken for the echo the
first time it comes and for the answer the second time (echo, then answer).

No status packet carries a sequence number, so a late reply of an identical earlier request
looks like the answer to this one. The wire therefore keeps a "dirty" flag for a while after any
anomaly (a timeout, a discarded or corrupted reply, bytes waiting before a request): while it
is set, one-off transactions read on to their deadline and take the last matching reply (replies
leave the bus in order).

Every wait is a blocking read with an absolute deadline on the monotonic clock, computed from
the bytes expected, the baud rate, the servos' Return Delay Time and the USB adapter's latency
timer: a device that never stops sending cannot hold a transaction past it. The serial device
itself is port/serial_device.py's (or the simulator's port): the wire sees a RawPort.
"""

import collections
import contextlib
from dataclasses import dataclass, field
import threading
import time
from typing import Callable, Deque, Dict, Iterator, Optional, Set, Tuple, Union

from dxl_servo_driver.errors import CommError, CommTimeout, CorruptReply, PortError, StatusError
from dxl_servo_driver.port import port_paced, port_waited, RawPort
from dxl_servo_driver.protocol import (
    BITS_PER_BYTE, ERROR_CODE_MASK, Frame, Framer, PROTOCOL_2)

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
# on in poll(). The median: a later quantile makes every cycle sleep past its block by more,
# which costs rate behind a slow adapter. A step moves it by TURNAROUND_STEP_S and a twentieth
# of itself.
TURNAROUND_ON_TIME = 0.5
TURNAROUND_STEP_S = 10e-6
# How long the bus stays suspicious after an anomaly: late replies of a frozen adapter arrive
# within this window of the timeouts they caused.
DIRTY_HOLD_S = 1.0
# An echo once learned is expected until this many answered transactions in a row came without
# it: one odd request (an adapter that swallowed its echo) does not make the next ones wait.
ECHO_MISSES_TO_FORGET = 3
# What the classifier makes of a frame.
ECHO, ANSWER, CORRUPT, STRAY = 'echo', 'answer', 'corrupt', 'stray'
# Packets sent lately whose echo, coming late, could pass for a status packet (Protocol 1.0).
RECENT_PACKETS = 16


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


class Wire:
    """
    One port's wire: the state every transaction on it shares, and the reads and writes.

    A bus may carry both protocols: the framer given is its default (broadcasts, and every id
    not told otherwise); speak() says an id answers in the other. The framer in force
    (`framer`) is switched only under the lock, for one transaction.

    The layers above (transactions.Transactions, group_reads.GroupReads) each hold the one wire
    of their port, so every transaction takes the same lock and counters. What they may use:

    - state: `port` (read), `lock` (held for a transaction), `framer` (the one in force) and
      `default_framer`, `counters`, `echo`, `dirty`, `baud_bps`, `latency_timer_s`,
      `return_delay_s`, `least_return_delay_s`, `slack_s`, `turnaround_s`; `mixed`.
    - protocols: speak, framer_for, speaking.
    - timing: byte_time_s, reply_timeout_s, raise_slack, mark_dirty.
    - a request: request (its Request), address_length, flush, send (flush and write), write
      (no flush: a packet that follows one sent), read, read_waiting, collect (the replies read
      and classified).
    - the echo: echo_seen, echo_missing, note_echo.
    - an answer: answer (its data or the StatusError), missing (why there is none), alert.
    - the port: set_baud, trace_to, attach, close.

    Everything else (the slack's decay, the turnaround's learning, the echo's misses, the dirty
    deadline, the packets sent lately) is the wire's own.
    """

    def __init__(self, port: RawPort, baud_bps: int, latency_timer_s: float = 0.016,
                 return_delay_s: float = 0.0005, framer: Framer = PROTOCOL_2) -> None:
        self.port = port
        # The trace hook (trace_to): with a trace, the port is a TracedPort around the device;
        # without, the device itself, so an untraced bus pays nothing for it.
        self.trace: Optional[BusTrace] = None
        # A real device: its bytes come no faster than the wire carries them (Wire.read).
        self._paced = port_paced(port)
        self.baud_bps = baud_bps
        self.latency_timer_s = latency_timer_s
        # The largest Return Delay Time expected on this bus (the factory default is 500 us),
        # and the smallest: no answer comes sooner than that after its request.
        self.return_delay_s = return_delay_s
        self.least_return_delay_s = 0.0
        # How long after its wire time a sync read's block is whole on this port: the device's
        # or simulator's turnaround, an adapter's latency timer (learned by Wire.read).
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
        self._recent: Deque[bytes] = collections.deque(maxlen=RECENT_PACKETS)

    # protocols ----------------------------------------------------------------------------
    def speak(self, servo_id: int, framer: Framer) -> None:
        """Say that servo_id answers in this framer's protocol (its transactions use it)."""
        with self.lock:
            if framer is self.default_framer:
                self._framers.pop(servo_id, None)
            else:
                self._framers[servo_id] = framer

    @property
    def mixed(self) -> bool:
        """Return True when some id speaks a protocol other than the default (speak)."""
        return bool(self._framers)

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
                raise port_lost(exc) from None
            self.baud_bps = baud_bps

    @property
    def dirty(self) -> bool:
        """Return True while the bus is suspicious (an anomaly happened lately)."""
        return time.monotonic() < self._dirty_until

    def mark_dirty(self) -> None:
        """Be suspicious of replies for a while (an anomaly happened)."""
        self._dirty_until = time.monotonic() + DIRTY_HOLD_S

    def trace_to(self, trace: Optional['BusTrace']) -> None:
        """Write every byte of the port to trace from now on (None: stop tracing)."""
        with self.lock:
            port = self.port.inner if isinstance(self.port, TracedPort) else self.port
            self.trace = trace
            self.attach(port)

    def attach(self, port: RawPort) -> None:
        """Put the bus on a port (the same device back after a loss), traced if the bus is."""
        with self.lock:
            self.port = port if self.trace is None else TracedPort(port, self.trace)

    def close(self) -> None:
        """Close the port (and the trace)."""
        with self.lock:
            try:
                self.port.close()
            finally:
                if self.trace is not None:
                    self.trace.close()

    # the port ------------------------------------------------------------------------------
    def flush(self) -> None:
        """Drop what waits on the port: before a request, late replies or noise (counted)."""
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

    def send(self, packet: bytes) -> Tuple[float, float]:
        """Flush, write; return (time before the write, time after it)."""
        try:
            self.flush()
            # A servo may sample its state as soon as the request reaches it, which can be
            # before write() returns (the in-process simulator answers inside it): a reply
            # cannot be older than this.
            before = time.monotonic()
            self.port.write(packet)
        except OSError as exc:   # PortError is not an OSError; SimPortDisconnected is
            raise port_lost(exc) from None
        if self.framer.echo_like_status:
            self._recent.append(packet)
        return before, time.monotonic()

    def write(self, packet: bytes) -> None:
        """Write a packet with no flush (one of several back to back, or one with no reply)."""
        try:
            self.port.write(packet)
        except OSError as exc:
            raise port_lost(exc) from None

    def read_waiting(self) -> bytes:
        """Return what waits on the port now, without waiting for more."""
        try:
            waiting = self.port.in_waiting
            return self.port.read(waiting, 0.0) if waiting else b''
        except OSError as exc:
            raise port_lost(exc) from None

    def request(self, packet: bytes, ids: Tuple[int, ...], reply_params: int,
                lengths: Optional[Dict[int, int]] = None) -> Request:
        """Return the Request a packet about to be sent is matched by."""
        framer = self.framer
        if framer.echo_like_status:
            return Request(packet, ids, reply_params, lengths, tuple(self._recent),
                           framer.refusal_mask)
        return Request(packet, ids, reply_params, lengths, refusal_mask=framer.refusal_mask)

    def address_length(self, address: int, length: int) -> bytes:
        """Return an instruction's address and length parameters in the protocol in force."""
        return self.framer.address_length(address, length)

    def read(self, size: int, deadline_s: float, to_deadline: bool = False,
             due_s: float = 0.0) -> bytes:
        """
        Read up to size bytes by deadline_s; to_deadline: waiting it out is the point.

        due_s: the earliest they can all be there. On a port whose bytes come at wire speed
        (`paced`) the read sleeps until then plus the learned turnaround (_learn_turnaround): a
        tty wakes a poller at every piece that comes (each servo's status packet, each USB
        transfer), and each wake-up costs more CPU than the read itself.
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
            raise port_lost(exc) from None
        if learn and len(data) >= size:
            self._learn_turnaround(port_waited(self.port))
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
        the slack, GroupReads.collect). A read that did not get its block (a silent
        servo) says nothing.
        """
        step = TURNAROUND_STEP_S + 0.05 * self.turnaround_s
        if waited:
            self.turnaround_s = min(self.turnaround_s + TURNAROUND_ON_TIME * step,
                                    self.latency_timer_s + 0.25 * DEADLINE_SLACK_S)
        else:
            self.turnaround_s = max(0.0, self.turnaround_s - (1.0 - TURNAROUND_ON_TIME) * step)

    # the echo ------------------------------------------------------------------------------
    def echo_seen(self) -> None:
        """Our own request came back: the adapter echoes (expected in front of every answer)."""
        self.echo = True
        self._echo_misses = 0
        self.counters.echoes += 1

    def echo_missing(self) -> None:
        """Note an answered transaction that came without the echo it was expected to carry."""
        if self.echo:
            self._echo_misses += 1
            if self._echo_misses >= ECHO_MISSES_TO_FORGET:
                self.echo = False
                self._echo_misses = 0

    def note_echo(self, echoed: bool, answered: bool) -> None:
        """Note a transaction's echo: seen, or missing from one that was answered."""
        if echoed:
            self.echo_seen()
        elif answered:
            self.echo_missing()

    # the collector -------------------------------------------------------------------------
    def collect(self, request: Request, deadline_s: float, buffer: bytearray,
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
                buffer += self.read(reply_size, deadline_s, to_deadline=True)
            else:
                # What the missing answers still lack (the bytes from pos on start one).
                missing = request.reply_bytes(self.framer.status_overhead, collected.answers)
                buffer += self.read(max(1, missing - (len(buffer) - pos)), deadline_s)
        collected.leftover = pos < len(buffer)
        self.counters.stale += collected.discarded
        return collected

    # answers -------------------------------------------------------------------------------
    def answer(self, servo_id: int, error: int, data: bytes,
               what: str) -> Union[bytes, StatusError]:
        """Return an answer's data, or the StatusError its error byte says (counted)."""
        framer = self.framer
        code = error & framer.refusal_mask
        if not code:
            return data
        self.counters.status_errors += 1
        return StatusError(f'id {servo_id}: {what} refused: {framer.error_text(code)}',
                           servo_id, code, bool(error & framer.alert_mask))

    def missing(self, servo_id: int, corrupt: bool, corrupt_text: str,
                silent_text: str) -> CommError:
        """Count and return why a servo has no answer: corrupt or silent."""
        if corrupt:
            self.counters.corrupt += 1
            return CorruptReply(f'id {servo_id}: {corrupt_text}', servo_id)
        self.counters.timeouts += 1
        return CommTimeout(f'id {servo_id}: {silent_text}', servo_id)

    def alert(self, error: int) -> bool:
        """Return whether a status error byte reports a hardware error (the alert)."""
        return bool(error & self.framer.alert_mask)


def port_lost(exc: BaseException) -> PortError:
    """Return the PortError a port's failure is reported as (a PortError as it is)."""
    # pyserial's SerialException and the simulator's disconnect are both OSError subclasses.
    if isinstance(exc, PortError):
        return exc
    return PortError(f'port lost: {exc}; was the adapter unplugged?')


class BusTrace:
    """
    A bus trace: every byte sent and received on a port, a line per write or read.

    Each line is `<monotonic time in us> <direction> <bytes in hex>`: `tx` what went out, `rx`
    what came in (as the reads returned it: a status packet may span lines, several may share
    one), `drop` bytes waiting before a request that the bus threw away unread (late replies,
    noise). `baud <bps>` marks a change of speed; lines starting with `#` are comments.
    `dxl trace FILE` decodes it (tool/trace.py). Line-buffered: what a crash leaves is whole.
    """

    def __init__(self, path: str, baud_bps: int = 0, note: str = '') -> None:
        """Open path for writing (OSError when it cannot be) and write the header."""
        self.path = path
        self._file = open(path, 'w', buffering=1, encoding='ascii')
        self._lock = threading.Lock()
        self.error = ''   # why the trace stopped early, if it did
        try:
            self._file.write('# dxl bus trace: <monotonic us> tx|rx|drop <hex bytes> | '
                             f'baud <bps>{"; " + note if note else ""}\n')
        except OSError:
            self.close()
            raise
        if baud_bps:
            self.baud(baud_bps)

    def record(self, direction: str, data: bytes) -> None:
        """Write one line: data went out (tx), came in (rx) or was dropped unread (drop)."""
        self._write(f'{time.monotonic_ns() // 1000} {direction} {data.hex(" ")}\n')

    def baud(self, baud_bps: int) -> None:
        """Write that the line speed is now baud_bps."""
        self._write(f'{time.monotonic_ns() // 1000} baud {baud_bps}\n')

    def _write(self, line: str) -> None:
        # A trace that cannot be written (a full disk) ends; the bus goes on: an OSError here
        # would pass for the port's own and the port would be taken for lost.
        with self._lock:
            if self.error or self._file.closed:
                return
            try:
                self._file.write(line)
            except OSError as exc:
                self.error = f'the trace {self.path} stopped: {exc}'
                try:
                    self._file.close()
                except OSError:
                    pass

    def close(self) -> None:
        """Close the file (idempotent)."""
        with self._lock:
            try:
                self._file.close()
            except OSError as exc:   # the last lines could not be flushed
                self.error = self.error or f'the trace {self.path} stopped: {exc}'


class TracedPort:
    """A port that writes every byte through it to a BusTrace (the wire's trace hook)."""

    def __init__(self, port: RawPort, trace: BusTrace) -> None:
        self.inner = port
        self._trace = trace

    @property
    def paced(self) -> bool:
        """Return what the port says of its pacing (raw_port.port_paced)."""
        return port_paced(self.inner)

    @property
    def waited(self) -> bool:
        """Say whether the last read of the port had to wait for its bytes."""
        return port_waited(self.inner)

    @property
    def baudrate(self) -> int:
        """Return the line speed in bit/s."""
        return self.inner.baudrate

    @baudrate.setter
    def baudrate(self, baud_bps: int) -> None:
        self.inner.baudrate = baud_bps
        self._trace.baud(baud_bps)

    @property
    def in_waiting(self) -> int:
        """Return how many received bytes wait to be read."""
        return self.inner.in_waiting

    def write(self, data: bytes) -> int:
        """Trace bytes and send them (traced first: a simulator answers inside its write)."""
        self._trace.record('tx', bytes(data))
        return self.inner.write(data)

    def read(self, size: int, timeout_s: float) -> bytes:
        """Read as the port does; trace what came."""
        data = self.inner.read(size, timeout_s)
        if data:
            self._trace.record('rx', bytes(data))
        return data

    def reset_input_buffer(self) -> None:
        """Drop what waits, traced as dropped: read out first, so the trace shows it."""
        waiting = self.inner.in_waiting
        if waiting:
            data = self.inner.read(waiting, 0.0)
            if data:
                self._trace.record('drop', bytes(data))
        self.inner.reset_input_buffer()

    def close(self) -> None:
        """Release the port."""
        self.inner.close()
