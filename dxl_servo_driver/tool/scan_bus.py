"""
`scan`: find the Dynamixel servos on a serial port, at every baud rate, and describe them.

  scan --port /dev/ttyUSB0 [--baud B ...] [--ids ID ...] [--protocol 1.0|2.0|both]
       [--stop-at-first] [--output FILE] [--protocol-timeout-ms MS]

(`dxl scan` is the same command: tool/scan.py builds its parser with add_arguments and runs
run().) At each baud rate (by default every one some supported model takes, the most common
first) it looks for servos in both protocols: a Protocol 2.0 broadcast PING (or, with --ids,
those ids one by one), its window ended once the line has been quiet long enough for no servo
to answer any more, then, where a Protocol 1.0 model runs out of the box, a Protocol 1.0 sweep
of every id (1.0 has no broadcast ping: the pings go out back to back, each once the one
before could have been answered, and the answers are read at the end, the adapter's latency
waited once a sweep; --ids narrows it). Replies that collide (two servos with one id) are
pinned to their ids by sweeping halves again, and reported. It reads each servo's firmware
version, operating mode and hardware error status in the protocol it answered in.

Where the time goes (the default scan, nobody answering): the 1.0 sweeps, each id given its
ping and answer on the wire, the longest Return Delay Time (508 us) and a millisecond of USB
transmit jitter (9600 bps alone: 3.6 s); the broadcast pings take the protocol timeout each.
The estimate said first is the plan's (Step.estimate_s), which docs/hardware.md compares with
measured times.

stderr: the estimate first; then on a terminal one progress line redrawn (baud k of n, the
protocol, time elapsed, about how long is left, servos found so far), elsewhere one line a step;
notes and warnings. stdout: one line per servo found, saying its protocol. With --output it
writes a parameter file the driver node runs as it is (a joint on the other protocol than the
bus's says so: `<joint>.protocol`), its `latency_timer` the adapter's as the node measures it at
configure (driver/adapter.measure_latency_timer: Linux's word, else the found servos' answers
timed). Ctrl-C (SIGINT) stops it and keeps what was found: said,
written to --output if asked, status 130.

Exit status: 0 servos found (and the file written), 1 no servo found, 2 bad arguments, 3 the port
cannot be opened or was lost, 4 the parameter file cannot be written, 130 interrupted.

find_one_servo is `dxl setup`'s search for the one servo connected, at any baud and protocol.

Plain CLI: no ROS. It talks to the servos only through dxl_servo_driver.bus.Bus.
"""

import argparse
from dataclasses import dataclass
import datetime
import os
import shutil
import sys
import threading
import time
from typing import (
    Any, Callable, Collection, Dict, List, NoReturn, Optional, Sequence, Set, TextIO, Tuple)

from dxl_servo_driver import config
from dxl_servo_driver import models
from dxl_servo_driver import timerslack
from dxl_servo_driver.bus import (
    broadcast_quiet_s, Bus, BusTrace, DEADLINE_SLACK_S, FRAMERS, sweep_spacing_s)
from dxl_servo_driver.driver.adapter import LINUX, measure_latency_timer, Measured
from dxl_servo_driver.errors import CommError, CorruptReply, PortError
from dxl_servo_driver.models import modes, xm430
from dxl_servo_driver.models.base import TORQUE_MODE
from dxl_servo_driver.models.names import OTHER_MODELS
from dxl_servo_driver.port import adapter_latency_timer_ms, open_port
from dxl_servo_driver.protocol import (
    BROADCAST_ID, Framer, Instruction, MAX_ID, RETURN_DELAY_UNIT_S)
from dxl_servo_driver.tool.common import (
    EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK, EXIT_OUTPUT, EXIT_PORT, EXIT_USAGE)

# The exit statuses are the dxl tool's (scan is one of its commands): 1 is 'no servo found'.
EXIT_NOT_FOUND = EXIT_FAILED

# Most common first: 57600 is the factory default, 1 Mbps what most robot arms are set to; 9600
# last, as its Protocol 1.0 sweep takes longest (3.6 s: 12 bytes an id on the wire).
PREFERRED_BAUDS = (57600, 1_000_000)
UNKNOWN_MODEL = 'unknown model'
# Where scan reads the firmware version of any servo: the same address on every X-series table.
MANUAL_TABLE = models.model_for(xm430.MODEL_NUMBER)
# A scan is not time-critical: wait generously for each reply beyond its wire time (the USB
# adapter's latency timer alone is 16 ms by default on Linux).
DEFAULT_PROTOCOL_TIMEOUT_MS = 50.0
# The largest Return Delay Time a servo can have: 254 x 2 us.
MAX_RETURN_DELAY_S = 254 * RETURN_DELAY_UNIT_S
READ_ATTEMPTS = 3
LINUX_LATENCY_TIMER_MS = 16.0   # what an FTDI adapter's latency timer is unless set
HINT = ('Usual causes: the servos have no power (the LED blinks once at power-up); they use a '
        'baud rate not tried (--baud), an id not tried (--ids) or a protocol not tried '
        '(--protocol); the data line or the adapter (U2D2) is miswired; or the replies come '
        'later than --protocol-timeout-ms (USB latency timer: install '
        'udev/99-dxl-servo-driver.rules to set it to 1 ms).')
# A Protocol 1.0 sweep pings every id: each waits this beyond the adapter's latency timer (the
# whole --protocol-timeout-ms per id would make a sweep of 253 ids last 13 s per baud).
SWEEP_SLACK_MS = 3.0
PROTOCOLS = {'1.0': (1.0,), '2.0': (2.0,), 'both': (2.0, 1.0)}


def all_bauds() -> List[int]:
    """Return every baud rate some supported model takes, ascending."""
    return sorted({bps for model in models.ALL_MODELS for bps in model.bauds.values()})


def default_bauds() -> List[int]:
    """Return every baud rate some supported model takes, in the order a scan tries them."""
    rest = [b for b in all_bauds() if b not in PREFERRED_BAUDS and b != 9600]
    return list(PREFERRED_BAUDS) + rest + [9600]


def model_name(model_number: int) -> str:
    """Return a model number's name (XL430-W250; unsupported ones say so), or 'unknown model'."""
    if model_number in models.SUPPORTED:
        return models.model_for(model_number).name
    other = OTHER_MODELS.get(model_number)
    return f'{other[0]}, not supported' if other is not None else UNKNOWN_MODEL


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
    protocol: float = 2.0
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


def describe(servo: FoundServo) -> str:
    """Return the one-line description of a servo that scan prints."""
    parts = [f'id {servo.servo_id}: model {servo.model_number} ({model_name(servo.model_number)})']
    fw = servo.firmware_version
    parts.append(f'firmware {fw}' if fw is not None else 'firmware ? (no reply)')
    parts.append(f'{servo.baud_bps} bps')
    if servo.protocol != 2.0:
        parts.append(f'Protocol {servo.protocol:.1f}')
    if not servo.known_model:
        parts.append('mode not read (unknown control table)')
        parts.append('hardware errors: not read')
    else:
        raw = servo.operating_mode_raw
        if raw is None:
            parts.append('mode ? (no reply)')
        else:
            parts.append(f'mode {servo.operating_mode or f"{raw} (not a valid mode)"}')
        errors = servo.hardware_errors
        status = servo.hardware_error_status
        if not servo.table.has('hardware_error_status'):
            parts.append('hardware errors: not in its table (each reply says them)')
        elif errors is None or status is None:
            parts.append('hardware errors: ? (no reply)')
        elif status == 0:
            parts.append('hardware errors: none')
        else:
            # Bits the manual does not name are shown as the raw value only.
            parts.append(f'hardware errors: {", ".join(errors) or "unnamed bits"} '
                         f'(0x{status:02x})')
    return ', '.join(parts)


@dataclass
class ScanResult:
    """The servos found, the baud rates tried, and what went wrong along the way."""

    servos: List[FoundServo]
    bauds_tried: List[int]
    warnings: List[str]


def _read_register(bus: Bus, servo_id: int, item: models.Item) -> Optional[int]:
    # A reply may come late on a busy machine or a noisy bus: a few tries before giving up.
    for _ in range(READ_ATTEMPTS):
        try:
            return bus.read_item(servo_id, item)
        except CommError:
            continue
    return None


def _describe_servo(bus: Bus, servo_id: int, model_number: int, baud_bps: int,
                    protocol: float = 2.0) -> FoundServo:
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


def _ping_ids(bus: Bus, ids: Sequence[int], warnings: List[str],
              protocol: float = 2.0) -> Dict[int, int]:
    """
    Ping each id alone in a protocol; return {id: model number} of those that answered.

    An id that answers in 1.0 is left speaking 1.0 (the caller describes it, then sets it back).
    """
    found: Dict[int, int] = {}
    said = '' if protocol == 2.0 else f' (Protocol {protocol:.1f})'
    for servo_id in ids:
        bus.speak(servo_id, FRAMERS[protocol])
        try:
            found[servo_id] = bus.ping(servo_id, probe=True)
        except CorruptReply:
            warnings.append(f'id {servo_id} at {bus.baud_bps} bps{said}: garbled replies (two '
                            'servos with the same id, or a noisy line?)')
        except CommError:
            pass
        if servo_id not in found or protocol == 2.0:
            bus.speak(servo_id, FRAMERS[2.0])
    return found


def set_baud(bus: Bus, baud_bps: int) -> None:
    """Switch the port and the bus's timing to another baud rate."""
    bus.set_baud(baud_bps)


def _sweep(bus: Bus, ids: Sequence[int], protocol: float, sweep_s: float,
           warnings: List[str], progress: Callable[[str], None]) -> Dict[int, int]:
    """
    Find the servos among ids that answer in a protocol; return {id: model number}.

    One ping sweep (Bus.ping_sweep: the adapter's latency waited once, not once per id) names
    the candidates, each then pinged alone, which reads its model number. Where the sweep heard
    noise (answers that collided: two servos with one id; a noisy line) it is swept again in
    halves, down to the ids whose answers collide (_locate), each named in a warning.
    """
    answered, collided = _locate(bus, list(ids), FRAMERS[protocol])
    said = '' if protocol == 2.0 else f' (Protocol {protocol:.1f})'
    if collided:
        progress(f'  {bus.baud_bps} bps: garbled answers{said} from id(s) '
                 f'{" ".join(str(i) for i in collided)}')
    for servo_id in collided:
        warnings.append(f'id {servo_id} at {bus.baud_bps} bps{said}: garbled replies (two '
                        'servos with the same id, or a noisy line?)')
    return _ping_alone(bus, answered, protocol, sweep_s, warnings)


def _locate(bus: Bus, ids: List[int], framer: Framer) -> Tuple[List[int], List[int]]:
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


def _ping_alone(bus: Bus, ids: Sequence[int], protocol: float, sweep_s: float,
                warnings: List[str]) -> Dict[int, int]:
    """Ping each id alone, waiting sweep_s beyond its wire time; return {id: model number}."""
    waited = bus.latency_timer_s
    bus.latency_timer_s = min(waited, sweep_s)
    try:
        return _ping_ids(bus, ids, warnings, protocol)
    finally:
        bus.latency_timer_s = waited


def _broadcast(bus: Bus, sweep_s: float, warnings: List[str],
               progress: Callable[[str], None]) -> Dict[int, int]:
    """
    Find the Protocol 2.0 servos at the bus's baud rate; return {id: model number}.

    One broadcast ping, its window ended once the line has been quiet long enough
    (Bus.broadcast_sweep). Answers that collided (two servos with one id) or noise spoil it:
    then a ping sweep of every id, and each id it heard pinged alone, says which ids answer
    and which collide (a warning names them).
    """
    heard = bus.broadcast_sweep()
    if not heard.garbled and not heard.noise:
        return heard.models
    suspects = sorted(set(heard.suspects + heard.garbled) - set(heard.models))
    progress(f'  {bus.baud_bps} bps: garbled replies to the broadcast ping (two servos with '
             f'one id?); pinging ids {_ranges(suspects)} ...')
    found = dict(heard.models)
    found.update(_sweep(bus, suspects, 2.0, sweep_s, warnings, progress))
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


def protocol_1_bauds() -> List[int]:
    """Return the baud rates of the models that speak Protocol 1.0 out of the box."""
    return sorted({bps for model in models.ALL_MODELS if model.protocol == 1.0
                   for bps in model.bauds.values()})


@dataclass(frozen=True)
class Step:
    """One search of a scan: a protocol at a baud rate (Plan.steps, in the order run)."""

    baud_bps: int
    protocol: float
    estimate_s: float   # about how long it takes where nobody answers


# What a step costs beyond its wire time and waits: switching the baud, the host's wake-ups
# (measured on virtual_bus: a few milliseconds a baud); and each ping of a sweep, the host
# waking up late for it and writing it (0.1-0.3 ms each on an idle 2-core machine).
STEP_OVERHEAD_S = 0.004
SWEEP_PING_OVERHEAD_S = 0.0002


def step_estimate_s(baud_bps: int, protocol: float, ids: Optional[Sequence[int]],
                    latency_s: float) -> float:
    """Return about how long one step of a scan takes where nobody answers."""
    framer = FRAMERS[protocol]
    listen_s = latency_s + DEADLINE_SLACK_S
    if ids is not None and protocol == 2.0:
        # Each id pinged alone, to its deadline (Wire.reply_timeout_s).
        one_s = (len(framer.encode(MAX_ID, Instruction.PING)) + framer.status_overhead
                 + framer.ping_reply_params) * 10.0 / baud_bps + MAX_RETURN_DELAY_S + listen_s
        return len(ids) * one_s + STEP_OVERHEAD_S
    if protocol == 2.0:
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
        for protocol in (2.0, 1.0):
            if protocol not in protocols:
                continue
            if protocol == 1.0 and bauds_1 is not None and baud_bps not in bauds_1:
                continue
            steps.append(Step(baud_bps, protocol,
                              step_estimate_s(baud_bps, protocol, ids, latency_s)))
    return steps


def estimate_s(bauds: Sequence[int], ids: Optional[Sequence[int]], protocols: Sequence[float],
               latency_s: float, bauds_1: Optional[Collection[int]] = None) -> float:
    """Return about how long a scan of these bauds takes on a bus where nobody answers."""
    return sum(step.estimate_s for step in plan(bauds, ids, protocols, latency_s, bauds_1))


def _step_line(step: Step, ids: Optional[Sequence[int]]) -> str:
    """Return the progress line a step starts with (one a step where stderr is no terminal)."""
    if step.protocol == 1.0:
        count = MAX_ID + 1 if ids is None else len(ids)
        return f'scanning {step.baud_bps} bps, Protocol 1.0 (ping of {count} id(s)) ...'
    how = 'broadcast ping' if ids is None else f'ping of {len(ids)} id(s)'
    return f'scanning {step.baud_bps} bps ({how}) ...'


StepStarted = Callable[[int, Step, str], None]


def scan_bus(bus: Bus, bauds: Sequence[int], ids: Optional[Sequence[int]] = None,
             progress: Callable[[str], None] = lambda line: None,
             found_one: Callable[[FoundServo], None] = lambda servo: None,
             protocols: Sequence[float] = (2.0,), sweep_s: float = 0.02,
             stop_at_first: bool = False,
             bauds_1: Optional[Collection[int]] = None,
             step_started: Optional[StepStarted] = None,
             result: Optional[ScanResult] = None) -> ScanResult:
    """
    Look for servos at each baud rate in turn, in each protocol; return what answered.

    Protocol 2.0: without ids one broadcast PING finds them, its window ended once the line
    has been quiet long enough (when its replies are garbled, a ping sweep of every id and
    each id heard pinged alone); with ids only those are pinged. Protocol 1.0 has no broadcast
    ping: one sweep pings every id (or those given) and each that answered is pinged again
    alone, waiting sweep_s beyond its wire time. bauds_1: where to look for Protocol 1.0
    servos (None: every baud). progress gets the lines of what happened along the way,
    step_started(index, step, line) each step as it begins (by default its line goes to
    progress), found_one each servo as soon as it has been read. stop_at_first: no baud after
    the first where servos answered. result: filled as the scan goes (what was found before a
    KeyboardInterrupt stays in it). PortError propagates.
    """
    result = result if result is not None else ScanResult([], [], [])
    steps = plan(bauds, ids, protocols, bus.latency_timer_s, bauds_1)
    started: StepStarted = step_started or (lambda index, step, line: progress(line))
    for baud_bps in bauds:
        if stop_at_first and result.servos:
            break
        mine = [(index, step) for index, step in enumerate(steps) if step.baud_bps == baud_bps]
        if not mine:
            continue
        started(mine[0][0], mine[0][1], _step_line(mine[0][1], ids))
        try:
            set_baud(bus, baud_bps)
        except (PortError, ValueError) as exc:  # pyserial: SerialException, ValueError
            result.warnings.append(f'the adapter refused {baud_bps} bps ({exc}); skipped')
            continue
        result.bauds_tried.append(baud_bps)
        for number, (index, step) in enumerate(mine):
            if number:
                started(index, step, _step_line(step, ids))
            if step.protocol == 2.0:
                if ids is None:
                    found = _broadcast(bus, sweep_s, result.warnings, progress)
                else:
                    found = _ping_ids(bus, ids, result.warnings)
            else:
                asked = list(range(MAX_ID + 1)) if ids is None else list(ids)
                found = _sweep(bus, asked, 1.0, sweep_s, result.warnings, progress)
            for servo_id in sorted(found):
                servo = _describe_servo(bus, servo_id, found[servo_id], baud_bps,
                                        step.protocol)
                bus.speak(servo_id, FRAMERS[2.0])
                result.servos.append(servo)
                found_one(servo)
    return result


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


def find_one_servo(bus: Bus, bauds: Optional[Sequence[int]] = None,
                   protocols: Sequence[float] = (2.0, 1.0),
                   bauds_1: Optional[Collection[int]] = None,
                   sweep_s: float = (LINUX_LATENCY_TIMER_MS + SWEEP_SLACK_MS) / 1000.0,
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
        answered: Dict[Tuple[int, float], int] = {}
        collided = False
        if 2.0 in protocols:
            heard = bus.broadcast_sweep()
            collided = bool(heard.garbled or heard.noise)
            answered.update({(servo_id, 2.0): model for servo_id, model in heard.models.items()})
        if 1.0 in protocols and (bauds_1 is None or baud_bps in bauds_1):
            sweep = bus.ping_sweep(range(MAX_ID + 1), FRAMERS[1.0])
            collided = collided or bool(sweep.garbled or sweep.noise)
            answered.update({(servo_id, 1.0): 0 for servo_id in sweep.answered})
        if not answered and not collided:
            continue
        names = ', '.join(f'id {servo_id}' + ('' if protocol == 2.0 else ' (Protocol 1.0)')
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
    raise NoServo(f'no servo answered at {", ".join(str(b) for b in tried) or "no"} bps, '
                  f'Protocol {" and ".join(f"{p:.1f}" for p in protocols)}. {HINT}')


def _plural(count: int, word: str) -> str:
    return f'{count} {word}' + ('' if count == 1 else 's')


def choose_baud(servos: Sequence[FoundServo]) -> int:
    """Return the baud rate most servos answered at (ties: the one scanned first)."""
    counts: Dict[int, int] = {}
    for servo in servos:
        counts[servo.baud_bps] = counts.get(servo.baud_bps, 0) + 1
    return max(counts, key=lambda baud: counts[baud])  # max keeps the first of equals


def build_parameters(port: str, servos: Sequence[FoundServo],
                     latency_timer_ms: Optional[float] = None
                     ) -> Tuple[Dict[str, Any], List[str]]:
    """
    Return the node's flat parameters for the servos found, and the comment lines to go with them.

    Only servos at the chosen baud rate (the one most of them use), of a known model and in a
    valid operating mode become joints; the others are listed in the comments. ValueError when
    no servo qualifies; config.ConfigError when the result does not validate.
    """
    if not servos:
        raise ValueError('no servo found: nothing to write')
    baud_bps = choose_baud(servos)
    params: Dict[str, Any] = {'port': port, 'baud_rate': baud_bps}
    # The node's reply deadlines need it: the adapter's as measured, else the Linux default.
    params['latency_timer'] = float(latency_timer_ms if latency_timer_ms is not None
                                    else LINUX_LATENCY_TIMER_MS)
    comments = [describe(servo) for servo in servos]
    left_out: List[str] = []
    joints: List[str] = []
    ids: Set[int] = set()
    for servo in sorted(servos, key=lambda s: (s.baud_bps != baud_bps, s.servo_id, s.baud_bps)):
        if servo.baud_bps != baud_bps:
            raws = {} if not servo.known_model else {
                bps: raw for raw, bps in servo.table.bauds.items()}
            how = (f'set its baud_rate register to {raws[baud_bps]} ({baud_bps} bps)'
                   if baud_bps in raws else f'its model cannot run at {baud_bps} bps')
            left_out.append(f'id {servo.servo_id} answered at {servo.baud_bps} bps, not '
                            f'{baud_bps}: {how} or run a second node at its baud')
        elif not servo.known_model:
            left_out.append(f'id {servo.servo_id}: '
                            f'{models.unsupported_reason(servo.model_number)}')
        elif servo.operating_mode is None:
            left_out.append(f'id {servo.servo_id}: operating mode not read or not valid')
        elif servo.servo_id in ids:
            left_out.append(f'id {servo.servo_id}: listed twice')
        else:
            joint = f'joint_{servo.servo_id}'
            ids.add(servo.servo_id)
            joints.append(joint)
            params[f'{joint}.id'] = servo.servo_id
            params[f'{joint}.model'] = servo.table.name
            params[f'{joint}.operating_mode'] = servo.operating_mode
            params[f'{joint}.protocol'] = servo.protocol
            # The joint as the robot sees it: the servo's angle until the user says otherwise.
            params[f'{joint}.offset'] = 0.0
            params[f'{joint}.reverse'] = False
            params[f'{joint}.ratio'] = 1.0
    if not joints:
        raise ValueError('no servo the node could drive (' + '; '.join(left_out) + ')')
    params['joints'] = joints
    # The bus speaks 2.0 unless every joint is on 1.0; a joint on the other one says so.
    bus_protocol = 1.0 if all(params[f'{j}.protocol'] == 1.0 for j in joints) else 2.0
    params['protocol'] = bus_protocol
    for joint in joints:
        if params[f'{joint}.protocol'] == bus_protocol:
            del params[f'{joint}.protocol']
    config.validate(params)
    if left_out:
        comments.append('Not configured below:')
        comments.extend(f'  {line}' for line in left_out)
    return params, comments


def _yaml_string(text: str) -> str:
    # Single-quoted YAML scalar: only the quote itself needs escaping (doubled).
    return "'" + text.replace("'", "''") + "'"


NOT_MEASURED = 'not measured here: the Linux default (1 with our udev rule)'


def render_parameter_file(params: Dict[str, Any], comments: Sequence[str], header: str,
                          latency_source: str = 'read from the adapter') -> str:
    """
    Return the ROS 2 parameter file (`/**: ros__parameters:`) for build_parameters' output.

    latency_source: where its latency_timer came from, said in its comment (Measured.describe).
    """
    lines = [f'# {header}']
    lines.extend(f'#   {comment}' for comment in comments)
    lines.append('/**:')
    lines.append('  ros__parameters:')
    lines.append(f'    port: {_yaml_string(params["port"])}')
    lines.append(f'    baud_rate: {params["baud_rate"]}')
    if 'protocol' in params:
        lines.append(f'    protocol: {params["protocol"]}')
    if 'latency_timer' in params:
        lines.append(f'    latency_timer: {params["latency_timer"]}  # ms, {latency_source}')
    lines.append(f'    joints: [{", ".join(params["joints"])}]')
    for joint in params['joints']:
        lines.append(f'    {joint}:')
        lines.append(f'      id: {params[joint + ".id"]}')
        lines.append(f'      model: {params[joint + ".model"]}')
        lines.append(f'      operating_mode: {params[joint + ".operating_mode"]}')
        if joint + '.protocol' in params:
            lines.append(f'      protocol: {params[joint + ".protocol"]}  # not the bus\'s')
        if joint + '.offset' in params:
            lines.append(f'      offset: {params[joint + ".offset"]!r}  # rad: the URDF zero in '
                         "the servo's radians (raw 2048 = 0)")
            lines.append(f'      reverse: {str(params[joint + ".reverse"]).lower()}  # the joint '
                         'turns against the servo')
            lines.append(f'      ratio: {params[joint + ".ratio"]!r}  # joint units per servo '
                         'radian (a 1:3 gearbox: 0.333...)')
    return '\n'.join(lines) + '\n'


class _UsageError(Exception):
    """Bad command-line arguments."""


class _Parser(argparse.ArgumentParser):
    """Argument errors raise instead of exiting, so main() returns the status."""

    def error(self, message: str) -> NoReturn:
        raise _UsageError(message)


DESCRIPTION = 'Find Dynamixel servos (Protocol 2.0 and 1.0) on a port.'


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add scan's options to a parser (`scan`'s own, and `dxl scan`'s)."""
    bauds = all_bauds()
    parser.add_argument('--port', required=True, help='serial device, e.g. /dev/ttyUSB0')
    parser.add_argument('--baud', type=int, nargs='+', metavar='B',
                        help=f'baud rates to try (default: all of {bauds})')
    parser.add_argument('--ids', type=int, nargs='+', metavar='ID',
                        help=f'ping only these ids (0..{MAX_ID}) instead of a broadcast ping')
    parser.add_argument('--protocol', choices=tuple(PROTOCOLS), default='both',
                        help='the protocols to look for servos in (default both)')
    parser.add_argument('--stop-at-first', action='store_true',
                        help='stop after the first baud rate where servos answered')
    parser.add_argument('--output', metavar='FILE',
                        help='write a parameter file for the node with the servos found')
    parser.add_argument('--protocol-timeout-ms', type=float, default=DEFAULT_PROTOCOL_TIMEOUT_MS,
                        metavar='MS',
                        help='wait for each reply beyond its time on the wire (default '
                             f'{DEFAULT_PROTOCOL_TIMEOUT_MS:g}; covers the USB latency timer)')


def check_arguments(args: argparse.Namespace) -> Optional[str]:
    """Check (and de-duplicate) parsed arguments; return what is wrong, None if nothing."""
    bauds = all_bauds()
    if args.baud is not None:
        bad = [b for b in args.baud if b not in bauds]
        if bad:
            return f'--baud {bad[0]}: no supported model runs at it ({bauds})'
        args.baud = list(dict.fromkeys(args.baud))
    if args.ids is not None:
        bad = [i for i in args.ids if not 0 <= i <= MAX_ID]
        if bad:
            return f'--ids {bad[0]}: ids are 0..{MAX_ID}'
        args.ids = list(dict.fromkeys(args.ids))
    if not 0.0 < args.protocol_timeout_ms <= 10_000.0:  # also refuses nan
        return '--protocol-timeout-ms must be in (0, 10000]'
    if args.output is not None:
        folder = os.path.dirname(os.path.abspath(args.output))
        if not os.path.isdir(folder):
            return f'--output {args.output}: folder {folder} does not exist'
        if os.path.isdir(args.output):
            return f'--output {args.output} is a folder'
    return None


def _parse_args(argv: Optional[Sequence[str]]) -> argparse.Namespace:
    parser = _Parser(prog='scan', description=DESCRIPTION)
    add_arguments(parser)
    args = parser.parse_args(argv)
    problem = check_arguments(args)
    if problem is not None:
        parser.error(problem)
    return args


def _write_file(path: str, text: str) -> None:
    temporary = f'{path}.tmp{os.getpid()}'
    try:
        with open(temporary, 'w', encoding='utf-8') as stream:
            stream.write(text)
        os.replace(temporary, path)
    finally:
        if os.path.exists(temporary):
            os.unlink(temporary)


def _report_bauds(servos: Sequence[FoundServo], err: TextIO, prog: str) -> None:
    bauds = list(dict.fromkeys(servo.baud_bps for servo in servos))
    if len(bauds) > 1:
        counts = ', '.join(
            f'{_plural(sum(1 for s in servos if s.baud_bps == b), "servo")} at {b} bps'
            for b in bauds)
        print(f'{prog}: warning: the servos use different baud rates ({counts}); one bus runs '
              'at one baud rate, so the node can reach only one group', file=err)


def measure_latency(bus: Bus, port: str, servos: Sequence[FoundServo]) -> Optional[Measured]:
    """
    Return the adapter's latency timer as the node will measure it, None where it cannot be.

    The node's own measurement (driver/adapter.measure_latency_timer): Linux's word for it, else
    pings of the servos the file lists (at the baud rate it chooses, each in its protocol) timed.
    """
    baud_bps = choose_baud(servos)
    listed = [servo for servo in servos if servo.baud_bps == baud_bps and servo.known_model]
    set_baud(bus, baud_bps)
    for servo in listed:
        bus.speak(servo.servo_id, FRAMERS[servo.protocol])
    try:
        return measure_latency_timer(port, bus, [servo.servo_id for servo in listed])
    except (CommError, PortError):
        return None


def _output(args: argparse.Namespace, result: ScanResult, latency: Optional[Measured],
            err: TextIO, prog: str) -> int:
    try:
        params, comments = build_parameters(args.port, result.servos,
                                            None if latency is None else latency.timer_ms)
    except (ValueError, config.ConfigError) as exc:  # ConfigError is a ValueError too
        print(f'{prog}: error: {args.output} not written: {exc}', file=err)
        return EXIT_OUTPUT
    stamp = datetime.datetime.now().isoformat(timespec='seconds')
    # Both ways of running the node: ROS 2 from PyPI has no ros2 command line.
    header = (f'Written by `{prog} --port {args.port}` at {stamp}; run it with '
              f'`ros2 run dxl_servo_driver node --ros-args --params-file {args.output}` '
              '(without the ros2 command line: install/dxl_servo_driver/lib/dxl_servo_driver/'
              f'node --ros-args --params-file {args.output}).')
    try:
        _write_file(args.output, render_parameter_file(
            params, comments, header, NOT_MEASURED if latency is None else latency.describe()))
    except OSError as exc:
        print(f'{prog}: error: cannot write {args.output}: {exc.strerror or exc}', file=err)
        return EXIT_OUTPUT
    print(f'{prog}: wrote {args.output} ({_plural(len(params["joints"]), "joint")} at '
          f'{params["baud_rate"]} bps)', file=err)
    return EXIT_OK


# How often the progress line on a terminal is redrawn (its clock and estimate move on).
REDRAW_S = 0.25
BAR_CELLS = 10


class Progress:
    """
    What a scan says on stderr while it runs.

    Not a terminal: one line a step (`scanning 57600 bps (broadcast ping) ...`), as a log
    reads. A terminal: one line redrawn (a bar; baud k of n, the protocol, the time elapsed,
    about how long is left, the servos found so far), every REDRAW_S and at every step; other
    lines (notes, a servo found on stdout) are printed above it. The time left is the plan's
    estimate of the steps still to run (where nobody answers), the current one's part of it
    counted down.
    """

    def __init__(self, err: TextIO, out: TextIO, steps: Sequence[Step], terminal: bool,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._err = err
        self._out = out
        self._steps = list(steps)
        self._bauds = list(dict.fromkeys(step.baud_bps for step in steps))
        self.terminal = terminal
        self._clock = clock
        self._begun_s = clock()
        self._step_s = self._begun_s
        self._index = -1
        self._found = 0
        self._shown = False
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._ticker: Optional[threading.Thread] = None
        if terminal:
            self._ticker = threading.Thread(target=self._tick, name='scan_progress',
                                            daemon=True)
            self._ticker.start()

    def line(self, text: str) -> None:
        """Say one line on stderr (above the progress line on a terminal)."""
        with self._lock:
            self._clear()
            print(text, file=self._err, flush=True)
            self._draw()

    def step(self, index: int, step: Step, text: str) -> None:
        """Begin a step: its line (not a terminal), or the progress line redrawn."""
        with self._lock:
            self._index = index
            self._step_s = self._clock()
            if not self.terminal:
                print(text, file=self._err, flush=True)
            self._draw()

    def found(self, text: str) -> None:
        """Count a servo found and print its line on stdout."""
        with self._lock:
            self._found += 1
            self._clear()
            print(text, file=self._out, flush=True)
            self._draw()

    def close(self) -> None:
        """Stop redrawing and take the progress line away."""
        self._stop.set()
        if self._ticker is not None:
            self._ticker.join()
        with self._lock:
            self._clear()

    def left_s(self) -> float:
        """Return about how long the steps not yet done take (the current one counted down)."""
        if self._index < 0:
            return sum(step.estimate_s for step in self._steps)
        current = self._steps[self._index].estimate_s - (self._clock() - self._step_s)
        return max(0.0, current) + sum(step.estimate_s for step in self._steps[self._index + 1:])

    def text(self) -> str:
        """Return the progress line as it is now."""
        elapsed_s = self._clock() - self._begun_s
        left_s = self.left_s()
        done = elapsed_s / (elapsed_s + left_s) if elapsed_s + left_s > 0.0 else 1.0
        cells = min(BAR_CELLS, int(done * BAR_CELLS))
        bar = '#' * cells + '.' * (BAR_CELLS - cells)
        if self._index < 0:
            where = 'starting'
        else:
            step = self._steps[self._index]
            where = (f'baud {self._bauds.index(step.baud_bps) + 1} of {len(self._bauds)}: '
                     f'{step.baud_bps} bps, P{step.protocol:.1f}')
        # 80 columns hold it at any baud: the line is cut at the terminal's width.
        return (f'[{bar}] {where} | {elapsed_s:.0f} s, {left_s:.0f} s left | '
                f'{self._found} found')

    def _tick(self) -> None:
        while not self._stop.wait(REDRAW_S):
            with self._lock:
                self._draw()

    def _draw(self) -> None:
        if not self.terminal or self._stop.is_set():
            return
        width = shutil.get_terminal_size((80, 24)).columns
        self._err.write('\r\x1b[K' + self.text()[:max(1, width - 1)])
        self._err.flush()
        self._shown = True

    def _clear(self) -> None:
        if self._shown:
            self._err.write('\r\x1b[K')
            self._err.flush()
            self._shown = False


def run(args: argparse.Namespace, prog: str = 'scan', trace: str = '') -> int:
    """
    Run a scan of checked arguments (add_arguments, check_arguments); return the exit status.

    prog names the command in what it says (`scan`, `dxl scan`); trace, a file every byte on
    the port is written to (`dxl scan --trace FILE`, as every `dxl` command). Ctrl-C (SIGINT)
    ends it with what was found kept: said, written to --output if asked, and status 130.
    """
    out, err = sys.stdout, sys.stderr
    bauds = args.baud or default_bauds()
    latency_ms = adapter_latency_timer_ms(args.port)
    timeout_ms = args.protocol_timeout_ms
    if latency_ms is not None:
        timeout_ms = max(timeout_ms, latency_ms + 2.0)
        if latency_ms > 1.0:
            print(f'{prog}: note: the adapter latency timer is {latency_ms:g} ms; 1 ms makes '
                  'the bus much faster (install udev/99-dxl-servo-driver.rules)', file=err)
    try:
        port = open_port(args.port, bauds[0])
    except PortError as exc:
        print(f'{prog}: error: {exc}', file=err)
        return EXIT_PORT
    bus = Bus(port, bauds[0], latency_timer_s=timeout_ms / 1000.0,
              return_delay_s=MAX_RETURN_DELAY_S)
    if trace:
        try:
            bus.trace_to(BusTrace(trace, bauds[0], f'{prog} of port {args.port}'))
        except OSError as exc:
            bus.close()
            print(f'{prog}: error: cannot write the trace {trace}: {exc.strerror or exc}',
                  file=err)
            return EXIT_OUTPUT
    # A sweep's pings are spaced by sleeps of a millisecond or two: ended on time, not late.
    timerslack.fine_timer_slack()
    asked = PROTOCOLS[args.protocol]
    # Bauds asked for are searched in every protocol asked for; by default Protocol 1.0 only
    # where a 1.0 model runs out of the box (an X servo switched to 1.0 at 4 Mbps: --baud).
    bauds_1 = None if args.baud else protocol_1_bauds()
    sweep_latency_ms = latency_ms if latency_ms is not None else LINUX_LATENCY_TIMER_MS
    steps = plan(bauds, args.ids, asked, timeout_ms / 1000.0, bauds_1)
    about_s = sum(step.estimate_s for step in steps)
    print(f'{prog}: {_plural(len(bauds), "baud rate")}, Protocol '
          f'{" and ".join(f"{p:.1f}" for p in asked)}: about {_seconds(about_s)} s where '
          f'nobody answers{" (or until servos answer)" if args.stop_at_first else ""}; '
          'Ctrl-C stops it and keeps what was found', file=err, flush=True)
    progress = Progress(err, out, steps, _is_terminal(err))
    result = ScanResult([], [], [])
    interrupted = False
    latency = None if latency_ms is None else Measured(latency_ms, LINUX)
    try:
        scan_bus(bus, bauds, args.ids, progress.line, lambda servo: progress.found(
            describe(servo)), asked, (sweep_latency_ms + SWEEP_SLACK_MS) / 1000.0,
            args.stop_at_first, bauds_1, progress.step, result)
        if args.output is not None and result.servos:
            # The file's latency_timer: what the node will find at configure.
            latency = measure_latency(bus, args.port, result.servos)
    except PortError as exc:
        progress.close()
        print(f'{prog}: error: {exc}', file=err)
        return EXIT_PORT
    except KeyboardInterrupt:
        interrupted = True
    finally:
        progress.close()
        bus.close()
    for warning in result.warnings:
        print(f'{prog}: warning: {warning}', file=err)
    tried = ', '.join(str(b) for b in result.bauds_tried) or 'none'
    if interrupted:
        print(f'{prog}: interrupted: found {_plural(len(result.servos), "servo")} (tried '
              f'{tried} bps)', file=err)
        if result.servos and args.output is not None:
            status = _output(args, result, latency, err, prog)
            if status != EXIT_OK:
                return status
        return EXIT_INTERRUPTED
    if not result.servos:
        what = 'a broadcast ping' if args.ids is None else (
            'pings of id(s) ' + ' '.join(str(i) for i in args.ids))
        protocols = ' and '.join(f'{p:.1f}' for p in PROTOCOLS[args.protocol])
        print(f'{prog}: no servo answered on {args.port} ({what} at {tried} bps, Protocol '
              f'{protocols}).\n{HINT}', file=err)
        return EXIT_NOT_FOUND
    print(f'{prog}: found {_plural(len(result.servos), "servo")} (tried {tried} bps)', file=err)
    _report_bauds(result.servos, err, prog)
    if args.output is not None:
        return _output(args, result, latency, err, prog)
    return EXIT_OK


def _seconds(value_s: float) -> str:
    """Return a duration for a person: whole seconds, tenths under ten."""
    return f'{value_s:.0f}' if value_s >= 10.0 else f'{value_s:.1f}'


def _is_terminal(stream: TextIO) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):   # a replaced or closed stream
        return False


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Run the scan; return the exit status."""
    try:
        args = _parse_args(argv)
    except _UsageError as exc:
        print(f'scan: error: {exc}', file=sys.stderr)
        return EXIT_USAGE
    except SystemExit as exc:  # --help
        return exc.code if isinstance(exc.code, int) else EXIT_USAGE
    try:
        return run(args)
    except KeyboardInterrupt:   # before the scan began, or while its end was said
        print('scan: interrupted', file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == '__main__':
    sys.exit(main())
