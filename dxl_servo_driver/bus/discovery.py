"""
The search of a bus: which servos answer, at which baud rates, in which protocol.

What `scan` (and `dxl scan`) runs, and `dxl setup`'s search for the one servo connected
(find_one_servo). No printing, no arguments to parse: the search takes plain values and gives
back plain data (FoundServo, ScanResult, OneServo); what happens along the way is handed to the
caller's callbacks as it happens (a note, a step begun, a servo found).

At each baud rate the search looks for servos in each protocol asked for. A protocol with a
broadcast ping (Protocol 2.0): one broadcast PING (or, with ids, those ids one by one), its
window ended once the line has been quiet long enough for no servo to answer any more. A
protocol without one (Protocol 1.0): a sweep of every id, the pings out back to back, each once
the one before could have been answered, and the answers read at the end, the adapter's latency
waited once a sweep. Replies that collide (two servos with one id) are pinned to their ids by
sweeping halves again, and reported. Each servo found is read: its firmware version, operating
mode and hardware error status, in the protocol it answered in.

Where the time goes (plan, Step.estimate_s; nobody answering): the sweeps, each id given its
ping and answer on the wire, the longest Return Delay Time (508 us) and a millisecond of USB
transmit jitter (9600 bps alone: 3.6 s); the broadcast pings take the reply timeout each.

Which protocol does what is the framer's to say (Framer.broadcast_ping); the protocols are
named by their configuration values (2.0, 1.0), as FRAMERS keys them.
"""

from dataclasses import dataclass
from typing import (
    Callable, Collection, Dict, List, Optional, Protocol, Sequence, Tuple)

from dxl_servo_driver import models
from dxl_servo_driver.bus.transactions import broadcast_quiet_s, Sweep, sweep_spacing_s
from dxl_servo_driver.bus.wire import DEADLINE_SLACK_S
from dxl_servo_driver.errors import CommError, CorruptReply, PortError
from dxl_servo_driver.models import modes, xm430
from dxl_servo_driver.models.base import TORQUE_MODE
from dxl_servo_driver.protocol import (
    BROADCAST_ID, Framer, FRAMERS, Instruction, MAX_ID, RETURN_DELAY_UNIT_S)

# Most common first: 57600 is the factory default, 1 Mbps what most robot arms are set to; 9600
# last, as its Protocol 1.0 sweep takes longest (3.6 s: 12 bytes an id on the wire).
PREFERRED_BAUDS = (57600, 1_000_000)
# Where the firmware version of any servo is read: the same address on every X-series table.
MANUAL_TABLE = models.model_for(xm430.MODEL_NUMBER)
# The largest Return Delay Time a servo can have: 254 x 2 us.
MAX_RETURN_DELAY_S = 254 * RETURN_DELAY_UNIT_S
READ_ATTEMPTS = 3
LINUX_LATENCY_TIMER_MS = 16.0   # what an FTDI adapter's latency timer is unless set
# A Bus speaks it unless told otherwise (Bus.speak), and what a scan says leaves it unsaid.
DEFAULT_PROTOCOL = 2.0
# The order of the searches at one baud rate: the broadcast ping first, it is the quick one.
PROTOCOL_ORDER = (2.0, 1.0)
# Said when nothing answered (find_one_servo's NoServo; scan's report).
NO_SERVO_HINT = (
    'Usual causes: the servos have no power (the LED blinks once at power-up); they use a '
    'baud rate not tried (--baud), an id not tried (--ids) or a protocol not tried '
    '(--protocol); the data line or the adapter (U2D2) is miswired; or the replies come '
    'later than --protocol-timeout-ms (USB latency timer: install '
    'udev/99-dxl-servo-driver.rules to set it to 1 ms).')
# A sweep pings every id: each id it heard is pinged again alone, waiting this beyond the
# adapter's latency timer (the whole reply timeout per id would make a sweep of 253 ids last
# 13 s per baud).
SWEEP_SLACK_MS = 3.0
# What a step costs beyond its wire time and waits: switching the baud and the host's wake-ups;
# and each ping of a sweep, the host waking up late for it and writing it. Estimates only: the
# plan's time said before a scan starts.
STEP_OVERHEAD_S = 0.004
SWEEP_PING_OVERHEAD_S = 0.0002


class SearchedBus(Protocol):
    """What the search uses of a bus (dxl_servo_driver.bus.Bus)."""

    latency_timer_s: float

    @property
    def baud_bps(self) -> int:
        """Return the line speed in force."""

    def set_baud(self, baud_bps: int) -> None:
        """Change the line speed of the port and of the deadlines."""

    def speak(self, servo_id: int, framer: Framer) -> None:
        """Say that servo_id answers in this framer's protocol."""

    def ping(self, servo_id: int, probe: bool = False) -> int:
        """Return the model number of the servo; raise when it does not answer."""

    def read_item(self, servo_id: int, item: models.Item) -> int:
        """Return one control-table item's value."""

    def ping_sweep(self, ids: Sequence[int], framer: Framer) -> Sweep:
        """Ping every id in turn without waiting for each answer; return who answered."""

    def broadcast_sweep(self) -> Sweep:
        """Send one broadcast ping; return who answered, garbled and noise heard."""


def all_bauds() -> List[int]:
    """Return every baud rate some supported model takes, ascending."""
    return sorted({bps for model in models.ALL_MODELS for bps in model.bauds.values()})


def default_bauds() -> List[int]:
    """Return every baud rate some supported model takes, in the order a scan tries them."""
    rest = [b for b in all_bauds() if b not in PREFERRED_BAUDS and b != 9600]
    return list(PREFERRED_BAUDS) + rest + [9600]


def protocol_1_bauds() -> List[int]:
    """Return the baud rates of the models that speak Protocol 1.0 out of the box."""
    return sorted({bps for model in models.ALL_MODELS if model.protocol == 1.0
                   for bps in model.bauds.values()})


def sweep_wait_s(latency_timer_ms: Optional[float]) -> float:
    """Return the wait beyond its wire time of a ping alone after a sweep (None: Linux's)."""
    latency_ms = LINUX_LATENCY_TIMER_MS if latency_timer_ms is None else latency_timer_ms
    return (latency_ms + SWEEP_SLACK_MS) / 1000.0


def _protocol_said(protocol: float) -> str:
    """Return how a message names a protocol: ' (Protocol 1.0)', nothing for the default."""
    return '' if protocol == DEFAULT_PROTOCOL else f' (Protocol {protocol:.1f})'


def mode_name(mode_raw: int) -> Optional[str]:
    """Return the operating mode's name (config spelling) for a register value, None if none."""
    mode = modes.BY_NUMBER.get(mode_raw)
    return mode.name if mode is not None else None


@dataclass(frozen=True)
class FoundServo:
    """One servo that answered, and what was read from it (None: not read or no reply)."""

    servo_id: int
    baud_bps: int
    model_number: int
    firmware_version: Optional[int] = None
    operating_mode_raw: Optional[int] = None
    hardware_error_status: Optional[int] = None
    protocol: float = DEFAULT_PROTOCOL
    # The mode by name where the table says it otherwise than the XM430 manual's numbers (the
    # XL-320's Control Mode, a Protocol 1.0 table's angle limits); None: from the raw value.
    mode: Optional[str] = None

    @property
    def known_model(self) -> bool:
        """Return whether the driver knows this model's control table."""
        return self.model_number in models.SUPPORTED

    @property
    def table(self) -> models.Model:
        """Return the control table of a known model (for its firmware, when read)."""
        return models.model_for(self.model_number, self.firmware_version)

    @property
    def operating_mode(self) -> Optional[str]:
        """Return the operating mode by name, None if unread or not a valid mode."""
        if self.mode is not None:
            return self.mode or None   # '': read, and not one of its modes
        if self.operating_mode_raw is None:
            return None
        return mode_name(self.operating_mode_raw)

    @property
    def hardware_errors(self) -> Optional[List[str]]:
        """Return the decoded hardware errors, None if unread."""
        if self.hardware_error_status is None or not self.known_model:
            return None
        return self.table.decode_hardware_errors(self.hardware_error_status)


@dataclass
class ScanResult:
    """The servos found, the baud rates tried, and what went wrong along the way."""

    servos: List[FoundServo]
    bauds_tried: List[int]
    warnings: List[str]


def _read_register(bus: SearchedBus, servo_id: int, item: models.Item) -> Optional[int]:
    # A reply may come late on a busy machine or a noisy bus: a few tries before giving up.
    for _ in range(READ_ATTEMPTS):
        try:
            return bus.read_item(servo_id, item)
        except CommError:
            continue
    return None


def _describe_servo(bus: SearchedBus, servo_id: int, model_number: int, baud_bps: int,
                    protocol: float = DEFAULT_PROTOCOL) -> FoundServo:
    # The firmware version is at 6 on every X-style table; a known model says where its own
    # is (2 on the Protocol 1.0 tables); the rest is read only from a known control table.
    if model_number in models.SUPPORTED:
        where = models.model_for(model_number).item('firmware_version')
    else:
        where = MANUAL_TABLE.item('firmware_version')
    firmware = _read_register(bus, servo_id, where)
    if model_number not in models.SUPPORTED:
        return FoundServo(servo_id, baud_bps, model_number, firmware, protocol=protocol)
    table = models.model_for(model_number, firmware)
    mode_raw: Optional[int] = None
    mode: Optional[str] = None
    if table.mode_register:
        mode_raw = _read_register(bus, servo_id, table.item(table.mode_register))
        names = {number: name for name, number in table.modes.items()}
        mode = names.get(mode_raw, '') if mode_raw is not None else None
    else:   # a Protocol 1.0 table: its angle limits are its mode
        low = _read_register(bus, servo_id, table.item('min_position_limit'))
        high = _read_register(bus, servo_id, table.item('max_position_limit'))
        torque = (_read_register(bus, servo_id, table.item(TORQUE_MODE))
                  if table.has(TORQUE_MODE) else 0)
        if low is not None and high is not None and torque is not None:
            mode = table.angle_limit_mode(low, high, torque)
            mode_raw = table.modes[mode]
    errors = (_read_register(bus, servo_id, table.item('hardware_error_status'))
              if table.has('hardware_error_status') else None)
    return FoundServo(servo_id, baud_bps, model_number, firmware, mode_raw, errors, protocol,
                      mode)


def _garbled(servo_id: int, baud_bps: int, protocol: float) -> str:
    return (f'id {servo_id} at {baud_bps} bps{_protocol_said(protocol)}: garbled replies (two '
            'servos with the same id, or a noisy line?)')


def _ping_ids(bus: SearchedBus, ids: Sequence[int], warnings: List[str],
              protocol: float = DEFAULT_PROTOCOL) -> Dict[int, int]:
    """
    Ping each id alone in a protocol; return {id: model number} of those that answered.

    An id that answers in another protocol than the default is left speaking it (the caller
    describes it, then sets it back).
    """
    found: Dict[int, int] = {}
    for servo_id in ids:
        bus.speak(servo_id, FRAMERS[protocol])
        try:
            found[servo_id] = bus.ping(servo_id, probe=True)
        except CorruptReply:
            warnings.append(_garbled(servo_id, bus.baud_bps, protocol))
        except CommError:
            pass
        if servo_id not in found:
            bus.speak(servo_id, FRAMERS[DEFAULT_PROTOCOL])
    return found


def set_baud(bus: SearchedBus, baud_bps: int) -> None:
    """Switch the port and the bus's timing to another baud rate."""
    bus.set_baud(baud_bps)


def _sweep(bus: SearchedBus, ids: Sequence[int], protocol: float, sweep_s: float,
           warnings: List[str], progress: Callable[[str], None]) -> Dict[int, int]:
    """
    Find the servos among ids that answer in a protocol; return {id: model number}.

    One ping sweep (Bus.ping_sweep: the adapter's latency waited once, not once per id) names
    the candidates, each then pinged alone, which reads its model number. Where the sweep heard
    noise (answers that collided: two servos with one id; a noisy line) it is swept again in
    halves, down to the ids whose answers collide (_locate), each named in a warning.
    """
    answered, collided = _locate(bus, list(ids), FRAMERS[protocol])
    if collided:
        progress(f'  {bus.baud_bps} bps: garbled answers{_protocol_said(protocol)} from id(s) '
                 f'{" ".join(str(i) for i in collided)}')
    for servo_id in collided:
        warnings.append(_garbled(servo_id, bus.baud_bps, protocol))
    return _ping_alone(bus, answered, protocol, sweep_s, warnings)


def _locate(bus: SearchedBus, ids: List[int], framer: Framer) -> Tuple[List[int], List[int]]:
    """
    Sweep ids; return (candidates: answered or garbled, ids whose answers were only noise).

    Answers that collide carry no readable header: the sweep hears noise, not whose. Its
    halves are swept again until the noise is pinned to single ids (a sweep of n ids with one
    collision costs about two sweeps and two latency waits per halving, where pinging every
    id alone waits the latency timer 253 times).
    """
    if not ids:
        return [], []
    sweep = bus.ping_sweep(ids, framer)
    if not sweep.noise:
        return sorted(set(sweep.answered + sweep.garbled)), []
    if len(ids) == 1:
        return [], list(ids)
    half = len(ids) // 2
    first, first_noise = _locate(bus, ids[:half], framer)
    second, second_noise = _locate(bus, ids[half:], framer)
    return first + second, first_noise + second_noise


def _ping_alone(bus: SearchedBus, ids: Sequence[int], protocol: float, sweep_s: float,
                warnings: List[str]) -> Dict[int, int]:
    """Ping each id alone, waiting sweep_s beyond its wire time; return {id: model number}."""
    waited = bus.latency_timer_s
    bus.latency_timer_s = min(waited, sweep_s)
    try:
        return _ping_ids(bus, ids, warnings, protocol)
    finally:
        bus.latency_timer_s = waited


def _broadcast(bus: SearchedBus, protocol: float, sweep_s: float, warnings: List[str],
               progress: Callable[[str], None]) -> Dict[int, int]:
    """
    Find the servos of a protocol with a broadcast ping at the bus's baud rate.

    Return {id: model number}. One broadcast ping, its window ended once the line has been
    quiet long enough (Bus.broadcast_sweep). Answers that collided (two servos with one id) or
    noise spoil it: then a ping sweep of every id, and each id it heard pinged alone, says
    which ids answer and which collide (a warning names them).
    """
    heard = bus.broadcast_sweep()
    if not heard.garbled and not heard.noise:
        return heard.models
    suspects = sorted(set(heard.suspects + heard.garbled) - set(heard.models))
    progress(f'  {bus.baud_bps} bps: garbled replies to the broadcast ping (two servos with '
             f'one id?); pinging ids {_ranges(suspects)} ...')
    found = dict(heard.models)
    found.update(_sweep(bus, suspects, protocol, sweep_s, warnings, progress))
    return found


def _ranges(ids: Sequence[int]) -> str:
    """Return ids as ranges: '0..4 7 9..12'."""
    parts: List[Tuple[int, int]] = []
    for servo_id in ids:
        if parts and parts[-1][1] == servo_id - 1:
            parts[-1] = (parts[-1][0], servo_id)
        else:
            parts.append((servo_id, servo_id))
    return ' '.join(str(a) if a == b else f'{a}..{b}' for a, b in parts)


@dataclass(frozen=True)
class Step:
    """One search of a scan: a protocol at a baud rate (plan's steps, in the order run)."""

    baud_bps: int
    protocol: float
    estimate_s: float   # about how long it takes where nobody answers

    @property
    def framer(self) -> Framer:
        """Return the framer of the step's protocol."""
        return FRAMERS[self.protocol]


def _searched_at(framer: Framer, baud_bps: int, bauds_1: Optional[Collection[int]]) -> bool:
    # A protocol without a broadcast ping is swept, every id: that is long (3.6 s at 9600),
    # so it is looked for only at bauds_1 when given (where its models run out of the box).
    return framer.broadcast_ping or bauds_1 is None or baud_bps in bauds_1


def step_estimate_s(baud_bps: int, protocol: float, ids: Optional[Sequence[int]],
                    latency_s: float) -> float:
    """Return about how long one step of a scan takes where nobody answers."""
    framer = FRAMERS[protocol]
    listen_s = latency_s + DEADLINE_SLACK_S
    if ids is not None and framer.broadcast_ping:
        # Each id pinged alone, to its deadline (Wire.reply_timeout_s).
        one_s = (len(framer.encode(MAX_ID, Instruction.PING)) + framer.status_overhead
                 + framer.ping_reply_params) * 10.0 / baud_bps + MAX_RETURN_DELAY_S + listen_s
        return len(ids) * one_s + STEP_OVERHEAD_S
    if framer.broadcast_ping:
        ping_s = len(framer.encode(BROADCAST_ID, Instruction.PING)) * 10.0 / baud_bps
        return ping_s + broadcast_quiet_s(baud_bps, MAX_RETURN_DELAY_S, listen_s) + \
            STEP_OVERHEAD_S
    count = MAX_ID + 1 if ids is None else len(ids)
    return (count * (sweep_spacing_s(baud_bps, framer) + SWEEP_PING_OVERHEAD_S) + listen_s
            + STEP_OVERHEAD_S)


def plan(bauds: Sequence[int], ids: Optional[Sequence[int]], protocols: Sequence[float],
         latency_s: float, bauds_1: Optional[Collection[int]] = None) -> List[Step]:
    """Return the steps of a scan in order: at each baud 2.0, then 1.0 where it is looked for."""
    steps: List[Step] = []
    for baud_bps in bauds:
        for protocol in PROTOCOL_ORDER:
            if protocol in protocols and _searched_at(FRAMERS[protocol], baud_bps, bauds_1):
                steps.append(Step(baud_bps, protocol,
                                  step_estimate_s(baud_bps, protocol, ids, latency_s)))
    return steps


def estimate_s(bauds: Sequence[int], ids: Optional[Sequence[int]], protocols: Sequence[float],
               latency_s: float, bauds_1: Optional[Collection[int]] = None) -> float:
    """Return about how long a scan of these bauds takes on a bus where nobody answers."""
    return sum(step.estimate_s for step in plan(bauds, ids, protocols, latency_s, bauds_1))


StepStarted = Callable[[int, Step], None]


def scan_bus(bus: SearchedBus, bauds: Sequence[int], ids: Optional[Sequence[int]] = None,
             progress: Callable[[str], None] = lambda line: None,
             found_one: Callable[[FoundServo], None] = lambda servo: None,
             protocols: Sequence[float] = (DEFAULT_PROTOCOL,), sweep_s: float = 0.02,
             stop_at_first: bool = False,
             bauds_1: Optional[Collection[int]] = None,
             step_started: StepStarted = lambda index, step: None,
             result: Optional[ScanResult] = None) -> ScanResult:
    """
    Look for servos at each baud rate in turn, in each protocol; return what answered.

    A protocol with a broadcast ping: without ids one broadcast PING finds them, its window
    ended once the line has been quiet long enough (when its replies are garbled, a ping sweep
    of every id and each id heard pinged alone); with ids only those are pinged. A protocol
    without one: one sweep pings every id (or those given) and each that answered is pinged
    again alone, waiting sweep_s beyond its wire time. bauds_1: where to look for the protocol
    without a broadcast ping, Protocol 1.0 (None: every baud). progress gets the notes of what
    happened along the way, step_started(index, step) each step of plan() as it begins,
    found_one each servo as soon as it has been read. stop_at_first: no baud after the first
    where servos answered. result: filled as the scan goes (what was found before a
    KeyboardInterrupt stays in it). PortError propagates.
    """
    result = result if result is not None else ScanResult([], [], [])
    steps = plan(bauds, ids, protocols, bus.latency_timer_s, bauds_1)
    for baud_bps in bauds:
        if stop_at_first and result.servos:
            break
        mine = [(index, step) for index, step in enumerate(steps) if step.baud_bps == baud_bps]
        if not mine:
            continue
        step_started(*mine[0])
        try:
            set_baud(bus, baud_bps)
        except (PortError, ValueError) as exc:  # pyserial: SerialException, ValueError
            result.warnings.append(f'the adapter refused {baud_bps} bps ({exc}); skipped')
            continue
        result.bauds_tried.append(baud_bps)
        for number, (index, step) in enumerate(mine):
            if number:
                step_started(index, step)
            found = _search(bus, step, ids, sweep_s, result.warnings, progress)
            for servo_id in sorted(found):
                servo = _describe_servo(bus, servo_id, found[servo_id], baud_bps,
                                        step.protocol)
                bus.speak(servo_id, FRAMERS[DEFAULT_PROTOCOL])
                result.servos.append(servo)
                found_one(servo)
    return result


def _search(bus: SearchedBus, step: Step, ids: Optional[Sequence[int]], sweep_s: float,
            warnings: List[str], progress: Callable[[str], None]) -> Dict[int, int]:
    """Run one step at the bus's baud rate; return {id: model number} of those that answered."""
    if step.framer.broadcast_ping:
        if ids is None:
            return _broadcast(bus, step.protocol, sweep_s, warnings, progress)
        return _ping_ids(bus, ids, warnings, step.protocol)
    asked = list(range(MAX_ID + 1)) if ids is None else list(ids)
    return _sweep(bus, asked, step.protocol, sweep_s, warnings, progress)


@dataclass(frozen=True)
class OneServo:
    """The one servo find_one_servo found: its id, model number, protocol and baud rate."""

    servo_id: int
    model_number: int
    protocol: float
    baud_bps: int


class NoServo(CommError):
    """No servo answered at any baud rate tried, in any protocol (find_one_servo)."""


class NotOneServo(CommError):
    """
    More than one servo answered at a baud rate, or their replies collided (find_one_servo).

    answered: what answered cleanly, as (id, protocol) pairs; collided: garbled replies or
    noise were heard (two servos with one id answer at once: a new servo is id 1 at 57600).
    """

    def __init__(self, message: str, baud_bps: int, answered: Sequence[Tuple[int, float]],
                 collided: bool) -> None:
        super().__init__(message)
        self.baud_bps = baud_bps
        self.answered = list(answered)
        self.collided = collided


def _heard(bus: SearchedBus, baud_bps: int, protocols: Sequence[float],
           bauds_1: Optional[Collection[int]]) -> Tuple[Dict[Tuple[int, float], int], bool]:
    """
    Search one baud rate (the bus's) once in each protocol; return what answered, a collision.

    What answered: {(id, protocol): model number}, 0 where a sweep found it (its ping alone
    reads the model number); a collision: garbled replies or noise were heard.
    """
    answered: Dict[Tuple[int, float], int] = {}
    collided = False
    for protocol in PROTOCOL_ORDER:
        framer = FRAMERS[protocol]
        if protocol not in protocols or not _searched_at(framer, baud_bps, bauds_1):
            continue
        if framer.broadcast_ping:
            heard = bus.broadcast_sweep()
            answered.update({(servo_id, protocol): model
                             for servo_id, model in heard.models.items()})
        else:
            heard = bus.ping_sweep(range(MAX_ID + 1), framer)
            answered.update({(servo_id, protocol): 0 for servo_id in heard.answered})
        collided = collided or bool(heard.garbled or heard.noise)
    return answered, collided


def find_one_servo(bus: SearchedBus, bauds: Optional[Sequence[int]] = None,
                   protocols: Sequence[float] = PROTOCOL_ORDER,
                   bauds_1: Optional[Collection[int]] = None,
                   sweep_s: float = sweep_wait_s(None),
                   progress: Callable[[str], None] = lambda line: None) -> OneServo:
    """
    Find the one servo on the bus, at whatever baud rate and protocol; return what answered.

    For `dxl setup`, which connects new servos one at a time: each baud rate of bauds in turn
    (default_bauds(): 57600, the factory default, first) is searched in each protocol of
    protocols (2.0: one broadcast ping, its window ended once the line is quiet; 1.0: one
    sweep of every id, only at bauds_1 when given: protocol_1_bauds() is scan's default), and
    the search stops at the first baud rate where anything answered. There the one servo is
    pinged again alone in its protocol (which reads its model number) and returned as a
    OneServo (id, model number, protocol, baud rate); the bus is left at that baud rate, the
    id speaking that protocol (Bus.speak).

    Raises NotOneServo when two or more answered at that baud (two ids, or one in each
    protocol) or when the replies collided (garbled replies or noise: two servos with one id
    answering at once, as new servos all are id 1; the confirming ping alone collides too);
    its message names what answered and says to connect one servo at a time. Raises NoServo
    when nothing answered at any baud rate. PortError propagates.

    bus: opened as `scan` opens it (Bus(port, baud, latency_timer_s=the wait for each reply
    beyond its wire time, return_delay_s=MAX_RETURN_DELAY_S)). sweep_s: the wait beyond its
    wire time of each ping alone that confirms a candidate (the adapter's latency timer and a
    margin). progress gets one line per baud rate searched.
    """
    tried: List[int] = []
    for baud_bps in (default_bauds() if bauds is None else bauds):
        set_baud(bus, baud_bps)
        tried.append(baud_bps)
        progress(f'looking for a servo at {baud_bps} bps ...')
        answered, collided = _heard(bus, baud_bps, protocols, bauds_1)
        if not answered and not collided:
            continue
        names = ', '.join(f'id {servo_id}{_protocol_said(protocol)}'
                          for servo_id, protocol in sorted(answered))
        if collided:
            raise NotOneServo(
                f'replies collided at {baud_bps} bps' + (f' (and {names} answered)' if names
                                                         else '')
                + ': two or more servos share an id; connect one servo at a time',
                baud_bps, sorted(answered), True)
        if len(answered) > 1:
            raise NotOneServo(f'{len(answered)} servos answered at {baud_bps} bps ({names}); '
                              'connect one servo at a time', baud_bps, sorted(answered), False)
        (servo_id, protocol), = answered
        return _confirm(bus, servo_id, protocol, baud_bps, sweep_s)
    raise NoServo(f'no servo answered at {", ".join(str(b) for b in tried) or "no"} bps, '
                  f'Protocol {" and ".join(f"{p:.1f}" for p in protocols)}. {NO_SERVO_HINT}')


def _confirm(bus: SearchedBus, servo_id: int, protocol: float, baud_bps: int,
             sweep_s: float) -> OneServo:
    """Ping the one id heard alone in its protocol; return it (NotOneServo, NoServo: not so)."""
    warnings: List[str] = []
    for _ in range(READ_ATTEMPTS):
        model = _ping_alone(bus, [servo_id], protocol, sweep_s, warnings)
        if model or warnings:
            break
    if warnings:   # its ping alone came back garbled: two servos with that id
        raise NotOneServo(f'replies collided at {baud_bps} bps: id {servo_id} answers '
                          'garbled (two servos with one id?); connect one servo at a time',
                          baud_bps, [(servo_id, protocol)], True)
    if not model:
        raise NoServo(f'id {servo_id} answered a sweep at {baud_bps} bps (Protocol '
                      f'{protocol:.1f}) but not its ping alone: a noisy line?', servo_id)
    return OneServo(servo_id, model[servo_id], protocol, baud_bps)
