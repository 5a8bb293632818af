"""
The bus's one-off transactions of one port, over its wire (wire.py).

Each transaction here is one request and its answer, or none (a sync write, a sweep's pings):
ping, read, write, reboot, CLEAR, factory reset, sync write, the adapter's reply delay, a ping
sweep and the broadcast ping. Every one with one servo goes out in that servo's protocol
(Wire.speak; the _to_servo decorator), and what differs between the protocols (one-byte
addresses and their reach, a ping's answer without the model number, the instructions 1.0 does
not have, the error byte's meaning) is the framer's to say (protocol.Framer), never a branch on
its version here. Transactions holds the port's wire (wire.Wire) and uses its public names only.

A status packet does not say which request it answers: a one-off read is tagged by its length
(Transactions.read) and, for values that do not change by themselves, confirmed by a second.
The transactions never retry on their own; the caller decides what a failure means.
"""

from dataclasses import dataclass, field
import functools
import time
from typing import (
    Any, Callable, cast, Dict, Iterable, List, Optional, Sequence, Set, Tuple, TypeVar)

from dxl_servo_driver.bus.wire import ANSWER, CORRUPT, ECHO, Request, STRAY, Wire
from dxl_servo_driver.errors import BadRequest, CommTimeout, CorruptReply, StatusError
from dxl_servo_driver.models import Item
from dxl_servo_driver.protocol import (
    BITS_PER_BYTE, BROADCAST_ID, CLEAR_MULTI_TURN, Frame, Framer, Instruction, MAX_ID,
    PROTOCOL_2, RETURN_DELAY_UNIT_S, STATUS_OVERHEAD)

# One-off reads differ in length over this many consecutive requests (see Transactions.read).
READ_TAGS = 8
# A confirmed read tries this many times more to get two equal answers in a row.
CONFIRM_ATTEMPTS = 3
PING_REPLY_PARAMS = 3          # model number (2), firmware version (1): Protocol 2.0's
# A ping sweep (Bus.ping_sweep) sends each ping once the one before could have been answered on
# the wire (request, the longest Return Delay Time, answer) and this margin more: the USB
# adapter's transmit jitter, so that a ping never goes out over the answer before it.
SWEEP_MARGIN_S = 1e-3
# How long past its wire time Bus.reply_delay listens for a ping's answer: longer than any
# adapter's latency timer in use (Linux's FTDI default is 16 ms, its maximum 255 ms).
LATENCY_LISTEN_S = 0.3
# The SDK's broadcast ping wait: every id may answer, 3 ms apart (ROBOTIS' figure).
BROADCAST_PING_PER_ID_S = 0.003


@dataclass
class Sweep:
    """What a ping sweep heard (Bus.ping_sweep)."""

    answered: List[int] = field(default_factory=list)   # ids whose answer came whole
    garbled: List[int] = field(default_factory=list)    # ids whose answer failed its checksum
    noise: int = 0          # frames or bytes that were nobody's: a collision, a noisy line
    echoed: int = 0         # pings the adapter echoed
    # A broadcast ping's answers carry the model number: {id: model number} of those answered.
    models: Dict[int, int] = field(default_factory=dict)
    # A broadcast ping's noise, placed between the clean answers around it (they come in
    # ascending id): the ids whose answers it may be (Bus.broadcast_sweep).
    suspects: List[int] = field(default_factory=list)


Method = TypeVar('Method', bound=Callable[..., Any])


def sweep_spacing_s(baud_bps: int, framer: Framer) -> float:
    """Return the time between two pings of a sweep (Bus.ping_sweep) at a baud rate."""
    ping = len(framer.encode(MAX_ID, Instruction.PING))
    answer = framer.status_overhead + framer.ping_reply_params
    return (ping + answer) * BITS_PER_BYTE / baud_bps + 254 * RETURN_DELAY_UNIT_S + SWEEP_MARGIN_S


def broadcast_ping_s(baud_bps: int) -> float:
    """
    Return the longest a broadcast ping waits beyond the latency timer (Bus.broadcast_ping).

    The SDK's wait, every id answering: the ping listens no longer than this even when the
    line never falls quiet (a noisy line), and mostly far less (broadcast_quiet_s).
    """
    answer = STATUS_OVERHEAD + PING_REPLY_PARAMS
    ping = len(PROTOCOL_2.encode(BROADCAST_ID, Instruction.PING))
    return ((ping + answer * (MAX_ID + 1)) * BITS_PER_BYTE / baud_bps
            + BROADCAST_PING_PER_ID_S * (MAX_ID + 1))


def broadcast_quiet_s(baud_bps: int, return_delay_s: float, listen_s: float) -> float:
    """
    Return how long a broadcast ping's line must stay quiet before no servo can answer any more.

    The answers come in ascending id, each its Return Delay Time after the one before ended
    (the ping's, for the first): an answer still to come ends at most the longest Return Delay
    Time and one answer's wire time after the last byte heard, and reaches the host within
    listen_s (the adapter's latency timer and the deadline slack) after that.
    """
    answer = STATUS_OVERHEAD + PING_REPLY_PARAMS
    return return_delay_s + answer * BITS_PER_BYTE / baud_bps + listen_s


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


def _outside(buffer: bytes, frames: Sequence[Frame]) -> int:
    """
    Return how many bytes of buffer no frame holds: noise, or answers that collided.

    The framer skips bytes before a header silently; two servos answering at once leave
    garbage with no header in it at all, which a sweep must not take for silence.
    """
    covered = 0
    reach = 0
    for frame in sorted(frames, key=lambda frame: frame.start):
        # A corrupt frame's span may hold the frames found by resynchronising inside it.
        start = max(frame.start, reach)
        if frame.end > start:
            covered += frame.end - start
            reach = frame.end
    return len(buffer) - covered


def _suspects(size: int, frames: Sequence[Frame], models: Dict[int, int],
              echo: bytes) -> List[int]:
    """
    Return the ids a broadcast ping's noise may come from, by where it lies among the answers.

    The answers come in ascending id: bytes that are no clean answer (garbage, a corrupt or
    stray frame) between the answers of ids a and b can only be from ids a+1..b-1. Our own
    ping coming back (an echoing adapter) is nobody's noise.
    """
    known = sorted((frame.start, frame.end, frame.servo_id if frame.raw != echo else None)
                   for frame in frames
                   if frame.raw == echo or (frame.crc_ok and frame.servo_id in models))
    suspects: Set[int] = set()
    reach, before = 0, -1
    for start, end, servo_id in known + [(size, size, MAX_ID + 1)]:
        if start > reach and servo_id is not None:   # something lies before this answer
            suspects.update(range(before + 1, servo_id))
        reach = max(reach, end)
        if servo_id is not None:
            before = servo_id
    return sorted(suspects)


def _to_servo(method: Method) -> Method:
    """Run a transaction with one servo in that servo's protocol (Wire.speak)."""
    @functools.wraps(method)
    def speaking(self: 'Transactions', servo_id: int, *args: Any, **kwargs: Any) -> Any:
        wire = self._wire
        with wire.speaking(wire.framer_for(servo_id)):
            return method(self, servo_id, *args, **kwargs)
    return cast(Method, speaking)


class Transactions:
    """
    The one-off transactions of one port, over its wire (held). Thread-safe: one at a time.

    What the layer above (the bus) may call: transact, ping, reply_delay, ping_sweep,
    broadcast_ping, broadcast_sweep, read, read_fresh, read_dated, write, read_item, write_item,
    reboot, clear_multi_turn, factory_reset and sync_write. The wire is reached through its
    public names only (wire.Wire).
    """

    def __init__(self, wire: Wire) -> None:
        self._wire = wire
        self._read_tag = 0

    def _refuse_unless(self, exists: bool, what: str, instead: str) -> None:
        """Refuse an instruction the protocol in force does not have (BadRequest)."""
        if not exists:
            raise BadRequest(f'{what} does not exist in Protocol {self._wire.framer.version}.0 '
                             f'({instead})')

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
        wire = self._wire
        request = wire.request(wire.framer.encode(servo_id, instruction, params), (servo_id,),
                               reply_params)
        with wire.lock:
            if linger is None:
                linger = wire.dirty
            sent_s, written_s = wire.send(request.packet)
            reply_size = wire.framer.status_overhead + reply_params
            deadline = written_s + wire.reply_timeout_s(reply_size, 1, len(request.packet))
            want = reply_size + (len(request.packet) if wire.echo else 0)
            buffer = bytearray(wire.read(want, deadline))
            collected = wire.collect(request, deadline, buffer, linger,
                                     lambda found: servo_id in found.answers)
            wire.note_echo(collected.echoed, servo_id in collected.answers)
            if collected.anomalies:
                wire.mark_dirty()
            answer = collected.answers.get(servo_id)
            if answer is None:
                if not probe or collected.anomalies:
                    wire.mark_dirty()
                if collected.corrupt:
                    wire.counters.corrupt += 1
                    raise CorruptReply(f'id {servo_id}: corrupted status packet for {what}',
                                       servo_id)
                wire.counters.timeouts += 1
                if collected.discarded:
                    # Replies came, none its own: the one before came after its deadline and
                    # this one's will too (a slow adapter, a starved host): the slack grows
                    # before the retry, as when late bytes wait at the next flush.
                    wire.raise_slack()
                version = wire.framer.version
                hint = (' (only replies that did not answer it came back)' if collected.discarded
                        else f' (check the id, the baud rate, Protocol {version}.0, the servo '
                        'power and the adapter latency timer)')
                raise CommTimeout(f'id {servo_id}: no status packet for {what} at '
                                  f'{wire.baud_bps} bps{hint}', servo_id)
            _, error, data = answer
            result = wire.answer(servo_id, error, data, what)
            if isinstance(result, StatusError):
                raise result
            return result, sent_s

    @_to_servo
    def ping(self, servo_id: int, probe: bool = False) -> int:
        """
        Return the model number of the servo; raise when it does not answer.

        probe: its silence is expected now and then (a booting servo, a scan), so it does not
        make the bus suspicious of the transactions that follow.
        """
        framer = self._wire.framer
        data = self._transact(servo_id, Instruction.PING, b'', framer.ping_reply_params, 'ping',
                              None, probe)[0]
        if framer.model_number_address is not None:
            # The answer carries no model number (Protocol 1.0): it is read.
            data = self.read_fresh(servo_id, framer.model_number_address, 2)[0]
        return data[0] | (data[1] << 8)

    @_to_servo
    def reply_delay(self, servo_id: int, listen_s: float = LATENCY_LISTEN_S) -> Optional[float]:
        """
        Return how long after its wire time a ping's answer came (s); None if none came.

        The deadline is listen_s, not the latency timer in force: this is how an adapter's
        real latency is measured where the OS does not say it (a pty, a non-FTDI adapter). The
        delay holds the servo's Return Delay Time and the host's wake-up too.
        """
        wire = self._wire
        framer = wire.framer
        request = wire.request(framer.encode(servo_id, Instruction.PING), (servo_id,),
                               framer.ping_reply_params)
        reply_size = framer.status_overhead + framer.ping_reply_params
        with wire.lock:
            _, written_s = wire.send(request.packet)
            due_s = written_s + wire.byte_time_s(len(request.packet) + reply_size)
            deadline = due_s + listen_s
            want = reply_size + (len(request.packet) if wire.echo else 0)
            buffer = bytearray(wire.read(want, deadline, to_deadline=True))
            collected = wire.collect(request, deadline, buffer, False,
                                     lambda found: servo_id in found.answers)
            came_s = time.monotonic()
            wire.note_echo(collected.echoed, servo_id in collected.answers)
            if servo_id not in collected.answers:
                if collected.anomalies:
                    wire.mark_dirty()
                return None
            return max(0.0, came_s - due_s)

    def ping_sweep(self, ids: Sequence[int], framer: Framer) -> Sweep:
        """
        Ping every id in turn without waiting for each answer; return who answered.

        Each ping goes out once the one before could have been answered on the wire, and the
        answers are read once, after the last: a sweep of 253 ids waits the adapter's latency
        timer once, not 253 times (Protocol 1.0 has no broadcast ping). What it finds are
        candidates: the caller pings each again alone. Noise (bytes no frame holds, frames of
        nobody asked) says answers collided or the line is noisy: the caller sweeps smaller
        groups to find whose (scan._locate).
        """
        wire = self._wire
        reply_size = framer.status_overhead + framer.ping_reply_params
        requests = {servo_id: Request(framer.encode(servo_id, Instruction.PING), (servo_id,),
                                      framer.ping_reply_params, refusal_mask=framer.refusal_mask)
                    for servo_id in ids}
        longest = max((len(request.packet) for request in requests.values()), default=0)
        spacing_s = sweep_spacing_s(wire.baud_bps, framer)
        buffer = bytearray()
        with wire.speaking(framer):
            # The pings go out back to back, not through send: one flush for all of them.
            wire.flush()
            due_s = time.monotonic()
            for request in requests.values():
                wait_s = due_s - time.monotonic()
                if wait_s > 0.0:
                    time.sleep(wait_s)
                wire.write(request.packet)
                buffer += wire.read_waiting()
                due_s = time.monotonic() + spacing_s
            deadline = due_s + wire.latency_timer_s + wire.slack_s
            buffer += wire.read(len(requests) * (longest + reply_size), deadline,
                                to_deadline=True)
            frames, _ = framer.scan(
                buffer, 0, max(2 * (framer.ping_reply_params + 4) + 8, longest), True)
        return _heard(frames, requests, _outside(buffer, frames))

    def broadcast_ping(self) -> Dict[int, int]:
        """Return {id: model number} of every servo that answers a broadcast ping (2.0 only)."""
        return self.broadcast_sweep().models

    def broadcast_sweep(self) -> Sweep:
        """
        Send one broadcast ping (2.0 only); return who answered, garbled and noise heard.

        The answers are read until the line has been quiet for broadcast_quiet_s (no servo
        can answer after such a silence: each answers its Return Delay Time after the one
        before it), or a clean answer of the last id came, and never longer than the SDK's
        wait (broadcast_ping_s): with nobody there that is one answer's window, not 253.
        Garbled answers (two servos with one id collide) and noise are counted, not dropped,
        and placed among the clean answers (Sweep.suspects): the caller sweeps those ids.
        """
        wire = self._wire
        self._refuse_unless(wire.framer.broadcast_ping, 'broadcast ping',
                            'ping the ids one by one')
        framer = wire.framer
        request = Request(framer.encode(BROADCAST_ID, Instruction.PING),
                          tuple(range(MAX_ID + 1)), PING_REPLY_PARAMS,
                          refusal_mask=framer.refusal_mask)
        max_length = max(2 * (PING_REPLY_PARAMS + 4) + 8, len(request.packet))
        buffer = bytearray()
        with wire.lock:
            _, written_s = wire.send(request.packet)
            listen_s = wire.latency_timer_s + wire.slack_s
            quiet_s = broadcast_quiet_s(wire.baud_bps, wire.return_delay_s, listen_s)
            last_s = (written_s + broadcast_ping_s(wire.baud_bps) + listen_s)
            deadline = min(last_s, written_s + wire.byte_time_s(len(request.packet)) + quiet_s)
            pos = 0
            frames: List[Frame] = []
            while True:
                piece = wire.read(1, deadline, to_deadline=True)
                if not piece:
                    break
                buffer += piece
                buffer += wire.read_waiting()
                deadline = min(last_s, time.monotonic() + quiet_s)
                found, pos = framer.scan(buffer, pos, max_length, False)
                frames += found
                if any(frame.servo_id == MAX_ID and frame.crc_ok and frame.is_status
                       and len(frame.status()[1]) == PING_REPLY_PARAMS for frame in found):
                    break   # the last id answers last: nobody comes after it
            frames += framer.scan(buffer, pos, max_length, True)[0]
            heard = Sweep(noise=_outside(buffer, frames))
            echoed = False
            for frame in frames:
                kind = request.classify(frame)
                if kind == ANSWER:
                    _, data = frame.status()
                    if len(data) == PING_REPLY_PARAMS:
                        heard.models[frame.servo_id] = data[0] | (data[1] << 8)
                    else:   # an error status without its parameters: not a ping's answer
                        heard.noise += 1
                elif kind == ECHO:
                    echoed = True
                elif kind == CORRUPT:
                    heard.garbled.append(frame.servo_id)
                else:
                    heard.noise += 1
            heard.echoed = int(echoed)
            heard.answered = sorted(heard.models)
            heard.suspects = _suspects(len(buffer), frames, heard.models, request.packet)
            heard.garbled = sorted(set(heard.garbled))
            if heard.garbled or heard.noise:
                wire.mark_dirty()
            wire.note_echo(echoed, bool(heard.models))
        return heard

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
            self._wire.counters.stale += 1
            self._wire.mark_dirty()
            data = again
        raise CorruptReply(f'id {servo_id}: read of {length} bytes at {address}: replies '
                           'disagree (late replies on the bus?)', servo_id)

    @_to_servo
    def read_fresh(self, servo_id: int, address: int, length: int) -> Tuple[bytes, float]:
        """Return (data, time the request went out) of one length-tagged read (see read())."""
        self._read_tag = (self._read_tag + 1) % READ_TAGS
        # The tag (extra bytes, before of them ahead of the register) stays inside what the
        # protocol reaches (Protocol 1.0: address 255, 253 bytes a read).
        wire = self._wire
        before, extra = wire.framer.fit_read(address, length, min(self._read_tag, address),
                                             self._read_tag)
        data, sent_s = self._transact(servo_id, Instruction.READ,
                                      wire.address_length(address - before, length + extra),
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
        return self._transact(servo_id, Instruction.READ,
                              self._wire.address_length(address, length), length,
                              f'read of {length} bytes at {address}', linger)

    @_to_servo
    def write(self, servo_id: int, address: int, data: bytes) -> None:
        """Write bytes to the servo's control table at address, and check the status."""
        params = self._wire.framer.address_param(address, len(data), 1) + bytes(data)
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
        self._refuse_unless(self._wire.framer.multi_turn_clear, 'CLEAR', 'no multi-turn clear')
        self.transact(servo_id, Instruction.CLEAR, CLEAR_MULTI_TURN, 0, 'clear multi-turn')

    @_to_servo
    def factory_reset(self, servo_id: int, option: int) -> None:
        """Send FACTORY_RESET with option 0xFF, 0x01 or 0x02 (1.0: RESET, 0xFF only)."""
        params = self._wire.framer.reset_params(option)
        if params is None:
            raise BadRequest(f'Protocol {self._wire.framer.version}.0 RESET has no option '
                             f'{option:#04x}: it resets everything (option 0xFF)', servo_id)
        # FACTORY_RESET is 1.0's RESET (0x06).
        self.transact(servo_id, Instruction.FACTORY_RESET, params, 0, 'factory reset')

    # a broadcast without a reply -----------------------------------------------------------
    def sync_write(self, address: int, length: int, data: Iterable[Tuple[int, bytes]],
                   framer: Optional[Framer] = None) -> int:
        """Write length bytes at address on several servos with one SYNC_WRITE; return bytes."""
        with self._wire.speaking(framer):
            return self._sync_write(address, length, data)

    def _sync_write(self, address: int, length: int, data: Iterable[Tuple[int, bytes]]) -> int:
        wire = self._wire
        params = bytearray(wire.address_length(address, length))
        for servo_id, value in data:
            if len(value) != length:
                raise ValueError(f'sync write of {length} bytes: id {servo_id} has {len(value)}')
            params.append(servo_id)
            params += value
        packet = wire.framer.encode(BROADCAST_ID, Instruction.SYNC_WRITE, bytes(params))
        with wire.lock:
            if wire.echo:
                # A sync write has no reply, but an echoing adapter sends it back: take it now
                # rather than let the next request flush it as an anomaly.
                wire.send(packet)
                echo = wire.read(len(packet), time.monotonic() + wire.reply_timeout_s(
                    0, 0, len(packet)))
                if echo == packet:
                    wire.echo_seen()
                else:
                    wire.echo_missing()   # what came of it, if anything, the next flush drops
            else:
                wire.write(packet)
        return len(packet)
