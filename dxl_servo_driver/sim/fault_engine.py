"""
The fault model of a misbehaving USB/RS-485 adapter between a host and the (simulated) servos.

FaultEngine mangles the servo->host byte stream a whole status packet at a time: late,
duplicated, truncated, noisy, dropped, delayed and echoed replies, and frozen adapters. Three
front ends put it in front of servos:

* virtual_bus holds one between its servos and its pty (VirtualBusServer), set from its console
  with the `adapter ...` lines (sim/control.py);
* faulty_port.FaultyPort wraps a raw port in process (the bus layer's RawPort interface,
  typically the simulator's SimPortHandler);
* adapter_proxy.AdapterProxy is a pseudo-terminal whose far end is a serial device (typically a
  virtual_bus pty), for clients that open a device path.

Every fault is off by default and can be changed at run time from any thread (set(), clear(),
freeze()); a seeded random.Random makes a run reproducible. Nothing here imports rclpy.
Replies are cut into packets by the framing of one protocol (`protocol`: 2, or 1 for Protocol
1.0's FF FF header and one-byte length), which also shapes the noise's forged headers.
"""

import collections
import dataclasses
import heapq
import os
import random
import threading
import time
from typing import Any, Callable, Optional

from dxl_servo_driver.protocol import Framer, FRAMERS, HEADER, MAX_PACKET_LENGTH

# Replies a late copy is chosen from.
LATE_HISTORY = 20
# Bytes of an incomplete packet (or a trailing header prefix) wait this long for the rest, then
# pass as they are; as the servos' own receiver, a gap this long ends a packet.
PARTIAL_FLUSH_S = 0.01


@dataclasses.dataclass(frozen=True)
class Framing:
    """How one protocol's packets are cut from a byte stream: by header and length field."""

    header: bytes
    head: int              # header, id and length field: the bytes before the length counts
    length_bytes: int      # the length field's size (little endian)
    min_length: int        # a length field below this is noise (as the servos' receiver)
    max_length: int        # and above this
    # Bytes a header found to be noise gives up: 1 in Protocol 1.0, where noise before a real
    # header makes FF FF FF (the real header starts at the second FF).
    noise_skip: int

    def length(self, buffer: bytearray) -> int:
        """Return the length field of the packet buffer starts with."""
        field = buffer[self.head - self.length_bytes:self.head]
        return int.from_bytes(field, 'little')


def _framing(framer: Framer) -> Framing:
    """Return how the adapter cuts a protocol's packets, from its framer's frame layout."""
    layout = framer.layout
    return Framing(layout.header, layout.length_at + layout.length_size, layout.length_size,
                   layout.min_length, layout.max_length,
                   1 if layout.padded_header else len(layout.header))


FRAMINGS = {framer.version: _framing(framer) for framer in FRAMERS.values()}


def _check_probability(name: str, value: float) -> None:
    if not 0.0 <= value <= 1.0:
        raise ValueError(f'{name} must be within 0..1, got {value!r}')


def _check_range(name: str, value: tuple[float, float], low: float = 0.0) -> None:
    if len(value) != 2 or not low <= value[0] <= value[1]:
        raise ValueError(f'{name} must be (lo, hi) with {low} <= lo <= hi, got {value!r}')


@dataclasses.dataclass
class Faults:
    """
    The adapter's fault settings; all off by default.

    Probabilities are per status packet from the servos (a reply); ranges are (lo, hi), drawn
    uniformly.
    """

    echo: bool = False                                 # host bytes come back to the host first
    echo_chunk: int = 0                                # echo in pieces of this size (0: whole)
    echo_gap_ms: float = 0.0                           # between two pieces of the echo
    freeze_probability: float = 0.0                    # a freeze starts at a reply
    freeze_ms: tuple[float, float] = (20.0, 100.0)     # how long a random freeze lasts
    late_probability: float = 0.0                      # a reply schedules a late earlier reply
    late_ms: tuple[float, float] = (5.0, 50.0)         # how late that copy comes
    duplicate_probability: float = 0.0                 # a reply is delivered twice in a row
    truncate_probability: float = 0.0                  # a reply loses its tail
    noise_probability: float = 0.0                     # garbage is inserted before a reply
    noise_bytes: tuple[int, int] = (1, 16)             # how much garbage
    drop_probability: float = 0.0                      # a reply vanishes
    delay_ms: tuple[float, float] = (0.0, 0.0)         # extra delay of every reply, order kept

    def active(self) -> bool:
        """Return whether any fault is on (a range without its probability is none)."""
        return (self.echo or self.delay_ms[1] > 0.0
                or any(getattr(self, field.name) for field in dataclasses.fields(self)
                       if field.name.endswith('_probability')))

    def check(self) -> None:
        """Raise ValueError when a setting is out of range."""
        for field in dataclasses.fields(self):
            if field.name.endswith('_probability'):
                _check_probability(field.name, getattr(self, field.name))
        _check_range('freeze_ms', self.freeze_ms)
        _check_range('late_ms', self.late_ms)
        _check_range('noise_bytes', self.noise_bytes, 1)
        _check_range('delay_ms', self.delay_ms)
        if self.echo_chunk < 0 or not self.echo_gap_ms >= 0.0:
            raise ValueError(f'echo_chunk and echo_gap_ms must be >= 0, got {self.echo_chunk}, '
                             f'{self.echo_gap_ms}')


@dataclasses.dataclass
class FaultStats:
    """What the engine saw and did (counts; the *_bytes fields count bytes)."""

    replies: int = 0            # whole packets from the servos
    passed_bytes: int = 0       # unparseable bytes passed through unchanged
    echoed_bytes: int = 0
    freezes: int = 0            # random and explicit
    late: int = 0
    duplicated: int = 0
    truncated: int = 0
    noise: int = 0
    noise_bytes: int = 0
    dropped: int = 0
    delayed: int = 0
    overflow_bytes: int = 0     # AdapterProxy: lost because the host left the pty buffer full

    def as_dict(self) -> dict[str, int]:
        """Return the counts by name."""
        return dataclasses.asdict(self)


def _header_prefix_len(buffer: bytearray, header: bytes = HEADER) -> int:
    """Return how many trailing bytes could be the start of a header (0..3)."""
    for keep in range(len(header) - 1, 0, -1):
        if buffer.endswith(header[:keep]):
            return keep
    return 0


class FaultEngine:
    """
    The fault model shared by FaultyPort and AdapterProxy.

    Front ends hand it host bytes (host_bytes, for the echo) and servo bytes (servo_bytes, cut
    into whole packets here so faults hit whole replies), then take what has been released to
    the host (take) at the times next_event_s says. Bytes in flight are a heap of (release time,
    seq, bytes): the in-order stream (replies, echo, noise, pass-through) has non-decreasing
    release times, late copies have their own. Released bytes move to the host's receive buffer,
    which a freeze does not touch; a freeze holds every release until it ends, so what came due
    meanwhile goes out in one burst, in order.

    Every method takes `cond`'s lock; changes notify `cond` and call the listeners, so a front
    end waiting for the next event wakes up.
    """

    def __init__(self, faults: Optional[Faults] = None, seed: Optional[int] = 0,
                 clock: Callable[[], float] = time.monotonic, protocol: int = 2) -> None:
        self.framing = FRAMINGS[protocol]
        self.cond = threading.Condition(threading.RLock())
        self.stats = FaultStats()
        self._faults = Faults()
        self._faults_on = False            # whether any fault is on (Faults.active)
        self._use(dataclasses.replace(faults) if faults is not None else Faults())
        self._random = random.Random(seed)
        self._clock = clock
        self._listeners: list[Callable[[], None]] = []
        self._queue: list[list[Any]] = []  # in flight: heap of [release_s, seq, bytearray]
        self._rx = bytearray()             # released: the host's receive buffer
        self._seq = 0
        self._stream_s = float('-inf')     # release time of the stream's last item
        self._frozen_until_s = float('-inf')
        self._history: collections.deque[bytes] = collections.deque(maxlen=LATE_HISTORY)
        self._partial = bytearray()        # servo bytes waiting for the rest of their packet
        self._partial_s = 0.0

    # ------------------------------------------------------------------ settings
    @property
    def faults(self) -> Faults:
        """Return a copy of the current settings."""
        with self.cond:
            return dataclasses.replace(self._faults)

    def set(self, **changes: Any) -> None:  # noqa: A003 - only shadows in the class body
        """Change some settings (Faults field names); TypeError/ValueError on bad ones."""
        with self.cond:
            self._use(dataclasses.replace(self._faults, **changes))
            self._changed()

    def clear(self) -> None:
        """Turn every fault off and end a freeze; bytes already scheduled keep their times."""
        with self.cond:
            self._use(Faults())
            self._frozen_until_s = float('-inf')
            self._changed()

    def engaged(self, now_s: float) -> bool:
        """
        Return whether the servos' bytes must go through the engine at now_s.

        False while every fault is off, nothing is held and no freeze runs: a front end may then
        pass them straight on, unchanged and on time, as an adapter without faults would.
        """
        with self.cond:
            return (self._faults_on or bool(self._queue) or bool(self._rx)
                    or bool(self._partial) or now_s < self._frozen_until_s)

    def counts(self) -> dict[str, int]:
        """Return the statistics by name, read at one moment."""
        with self.cond:
            return self.stats.as_dict()

    def freeze(self, duration_s: float) -> None:
        """Stop delivering from now for duration_s; what comes due meanwhile is held."""
        if not duration_s >= 0.0:
            raise ValueError(f'freeze duration must be >= 0 s, got {duration_s!r}')
        with self.cond:
            self._freeze(self._clock(), duration_s)
            self._changed()

    def add_listener(self, listener: Callable[[], None]) -> None:
        """Call listener (under the lock, so it must not block) whenever something changed."""
        with self.cond:
            self._listeners.append(listener)

    def remove_listener(self, listener: Callable[[], None]) -> None:
        """Stop calling listener (no error if it was not added)."""
        with self.cond:
            if listener in self._listeners:
                self._listeners.remove(listener)

    # ------------------------------------------------------------------ input
    def host_bytes(self, data: bytes, now_s: float) -> None:
        """Take bytes the host wrote at now_s (echoed back when echo is on)."""
        with self.cond:
            if self._faults.echo and data:
                self.stats.echoed_bytes += len(data)
                # In pieces, as an adapter hands them over while the bytes leave it; what the
                # servos answer comes after the last piece (the stream keeps its order).
                step = self._faults.echo_chunk or len(data)
                for number, start in enumerate(range(0, len(data), step)):
                    self._stream(bytes(data[start:start + step]),
                                 now_s + number * self._faults.echo_gap_ms / 1000.0,
                                 jitter=False)
                self._changed()

    def servo_bytes(self, data: bytes, now_s: float) -> None:
        """Take bytes the servos sent that reached the adapter at now_s."""
        with self.cond:
            self._flush_stale(now_s)
            if not data:
                return
            self._partial += data
            self._partial_s = now_s
            self._frame(now_s, flush=False)
            self._changed()

    def reset(self) -> None:
        """Forget everything in flight (the adapter was unplugged or closed)."""
        with self.cond:
            self._queue.clear()
            self._rx.clear()
            self._partial.clear()
            self._history.clear()
            self._stream_s = float('-inf')
            self._frozen_until_s = float('-inf')
            self._changed()

    # ------------------------------------------------------------------ output
    def take(self, now_s: float, size: int) -> bytes:
        """Remove and return up to size bytes released by now_s."""
        with self.cond:
            self._release(now_s)
            out = bytes(self._rx[:max(0, size)])
            del self._rx[:len(out)]
            return out

    def release_to(self, fd: int, now_s: float) -> None:
        """Write what is released by now to the host's end of a pty (non-blocking)."""
        data = self.take(now_s, 1 << 20)
        if not data:
            return
        try:
            written = os.write(fd, data)
        except BlockingIOError:
            written = 0
        if written < len(data):
            # The client is not reading and the pty buffer is full: like an adapter's
            # overflowing receive buffer, the rest is lost.
            with self.cond:
                self.stats.overflow_bytes += len(data) - written

    def readable(self, now_s: float) -> int:
        """Return how many bytes are released by now_s."""
        with self.cond:
            self._release(now_s)
            return len(self._rx)

    def discard_readable(self, now_s: float) -> int:
        """Drop the bytes released by now_s (the rest stays in flight); return how many."""
        with self.cond:
            self._release(now_s)
            count = len(self._rx)
            self._rx.clear()
            return count

    def next_event_s(self) -> Optional[float]:
        """Return when bytes are next released or a partial packet times out (None: never)."""
        with self.cond:
            times = []
            if self._queue:
                times.append(max(self._queue[0][0], self._frozen_until_s))
            if self._partial:
                times.append(self._partial_s + PARTIAL_FLUSH_S)
            return min(times) if times else None

    def in_flight(self) -> int:
        """Return how many bytes are in flight (not released yet, a partial packet included)."""
        with self.cond:
            return sum(len(item[2]) for item in self._queue) + len(self._partial)

    # ------------------------------------------------------------------ internals
    def _use(self, faults: Faults) -> None:
        """Check and take new settings (ValueError: the old ones stay)."""
        faults.check()
        self._faults = faults
        self._faults_on = faults.active()

    def _release(self, now_s: float) -> None:
        """Pass a stale partial packet on, then release what is due by now_s."""
        self._flush_stale(now_s)
        self._move_due(now_s)

    def _move_due(self, now_s: float) -> None:
        """Move what is due by now_s, unless frozen, to the host's receive buffer, in order."""
        if now_s < self._frozen_until_s:
            return
        queue = self._queue
        while queue and queue[0][0] <= now_s:
            self._rx += heapq.heappop(queue)[2]

    def _changed(self) -> None:
        self.cond.notify_all()
        for listener in self._listeners:
            listener()

    def _freeze(self, now_s: float, duration_s: float) -> None:
        self._move_due(now_s)  # what the host already received stays readable
        self._frozen_until_s = max(self._frozen_until_s, now_s + duration_s)
        self.stats.freezes += 1

    def _uniform(self, bounds: tuple[float, float]) -> float:
        return bounds[0] if bounds[0] == bounds[1] else self._random.uniform(*bounds)

    def _push(self, release_s: float, data: bytes) -> None:
        heapq.heappush(self._queue, [release_s, self._seq, bytearray(data)])
        self._seq += 1

    def _stream(self, data: bytes, now_s: float, jitter: bool) -> None:
        """Append to the in-order stream, after a random delay when one is set."""
        release_s = now_s
        if jitter and self._faults.delay_ms[1] > 0.0:
            release_s += self._uniform(self._faults.delay_ms) / 1000.0
            self.stats.delayed += 1
        release_s = max(release_s, self._stream_s)  # order kept: never before what came first
        self._stream_s = release_s
        self._push(release_s, data)

    def _flush_stale(self, now_s: float) -> None:
        if self._partial and now_s - self._partial_s >= PARTIAL_FLUSH_S:
            self._frame(now_s, flush=True)

    def _frame(self, now_s: float, flush: bool) -> None:
        """
        Cut the buffered servo bytes into whole packets and unparseable bytes.

        Framing is by header and length field alone (a packet with a bad CRC is still a reply).
        An incomplete packet waits unless flush: then its header is taken as garbage and the
        rest searched again, so packets inside it keep their packet treatment.
        """
        buffer = self._partial
        raw = bytearray()
        framing = self.framing
        header = framing.header
        head = framing.head
        while buffer:
            start = buffer.find(header)
            if start < 0:
                keep = 0 if flush else _header_prefix_len(buffer, header)
                raw += buffer[:len(buffer) - keep]
                del buffer[:len(buffer) - keep]
                break
            raw += buffer[:start]
            del buffer[:start]
            if len(buffer) >= head:
                length = framing.length(buffer)
                # as the servos' receiver: noise
                if length < framing.min_length or length > framing.max_length:
                    raw += buffer[:framing.noise_skip]
                    del buffer[:framing.noise_skip]
                    continue
                if len(buffer) >= head + length:
                    if raw:
                        self._pass(bytes(raw), now_s)
                        raw.clear()
                    self._reply(bytes(buffer[:head + length]), now_s)
                    del buffer[:head + length]
                    continue
            if not flush:
                break
            raw += buffer[:framing.noise_skip]
            del buffer[:framing.noise_skip]
        if raw:
            self._pass(bytes(raw), now_s)

    def _pass(self, data: bytes, now_s: float) -> None:
        self.stats.passed_bytes += len(data)
        self._stream(data, now_s, jitter=True)

    def _reply(self, packet: bytes, now_s: float) -> None:
        """Apply the faults to one whole reply and schedule what is left of it."""
        faults = self._faults
        rng = self._random
        stats = self.stats
        stats.replies += 1
        earlier = list(self._history)
        self._history.append(packet)
        if faults.late_probability and earlier and rng.random() < faults.late_probability:
            copy = rng.choice(earlier)
            self._push(now_s + self._uniform(faults.late_ms) / 1000.0, copy)
            stats.late += 1
        if faults.freeze_probability and rng.random() < faults.freeze_probability:
            # Starts before this reply is delivered, so the reply is held too.
            self._freeze(now_s, self._uniform(faults.freeze_ms) / 1000.0)
        if faults.drop_probability and rng.random() < faults.drop_probability:
            stats.dropped += 1
            return
        body = packet
        if faults.truncate_probability and rng.random() < faults.truncate_probability:
            body = packet[:rng.randint(1, len(packet) - 1)]
            stats.truncated += 1
        out = b''
        if faults.noise_probability and rng.random() < faults.noise_probability:
            count = rng.randint(*faults.noise_bytes)
            out = self._noise(count)
            stats.noise += 1
            stats.noise_bytes += count
        out += body
        if faults.duplicate_probability and rng.random() < faults.duplicate_probability:
            out += body
            stats.duplicated += 1
        self._stream(out, now_s, jitter=True)

    def _noise(self, count: int) -> bytes:
        """
        Return count random bytes, half the time with a header fragment in them.

        Header prefixes, and whole headers with a length field that is too small, too large or
        plausible (so a parser swallows the real reply after it), are the hard cases.
        """
        rng = self._random
        out = bytearray(rng.getrandbits(8) for _ in range(count))
        framing = self.framing
        header = framing.header
        if rng.random() < 0.5:
            if rng.random() < 0.5:
                fragment = header[:rng.randint(1, len(header))]
            elif framing.length_bytes == 2:
                length = rng.choice((0, 2, rng.randint(3, 40), MAX_PACKET_LENGTH + 1, 0xFFFF))
                fragment = header + bytes((rng.randrange(256),)) + length.to_bytes(2, 'little')
            else:
                length = rng.choice((0, 1, rng.randint(2, 40), framing.max_length))
                fragment = header + bytes((rng.randrange(256), length))
            fragment = fragment[:count]
            at = rng.randint(0, count - len(fragment))
            out[at:at + len(fragment)] = fragment
        return bytes(out)


class FaultControls:
    """The runtime fault controls the front ends share (delegated to self.engine)."""

    engine: FaultEngine

    @property
    def stats(self) -> FaultStats:
        """Return the live fault counters."""
        return self.engine.stats

    @property
    def faults(self) -> Faults:
        """Return a copy of the current settings."""
        return self.engine.faults

    def set(self, **faults: Any) -> None:  # noqa: A003 - only shadows in the class body
        """Change some settings (Faults field names)."""
        self.engine.set(**faults)

    def clear(self) -> None:
        """Turn every fault off and end a freeze."""
        self.engine.clear()

    def freeze(self, duration_s: float) -> None:
        """Stop delivering servo->host bytes for duration_s from now."""
        self.engine.freeze(duration_s)
