"""
`scan`: find the Dynamixel servos on a serial port, at every baud rate, and describe them.

  scan --port /dev/ttyUSB0 [--baud B ...] [--ids ID ...] [--protocol 1.0|2.0|both]
       [--stop-at-first] [--output FILE] [--protocol-timeout-ms MS]

At each baud rate (by default every one some supported model takes, the most common first) it
looks for servos in both protocols: a Protocol 2.0 broadcast PING (or, with --ids, those ids one
by one), then a Protocol 1.0 sweep of every id (1.0 has no broadcast ping: the pings go out back
to back and the answers are read at the end, the adapter's latency waited once a sweep; --ids
narrows it), and
reads each servo's firmware version, operating mode and hardware error status in the protocol it
answered in. Progress goes to stderr; stdout gets one line per servo found, saying its protocol.
With --output it writes a parameter file the driver node runs as it is (a joint on the other
protocol than the bus's says so: `<joint>.protocol`).

Exit status: 0 servos found (and the file written), 1 no servo found, 2 bad arguments, 3 the port
cannot be opened or was lost, 4 the parameter file cannot be written, 130 interrupted.

Plain CLI: no ROS. It talks to the servos only through dxl_servo_driver.bus.Bus.
"""

import argparse
from dataclasses import dataclass
import datetime
import os
import sys
from typing import (
    Any, Callable, Collection, Dict, List, NoReturn, Optional, Sequence, Set, TextIO, Tuple)

from dxl_servo_driver import config
from dxl_servo_driver import models
from dxl_servo_driver import timerslack
from dxl_servo_driver.bus import (
    broadcast_ping_s, Bus, DEADLINE_SLACK_S, FRAMERS, sweep_spacing_s)
from dxl_servo_driver.errors import CommError, CorruptReply, PortError
from dxl_servo_driver.models import modes, xm430
from dxl_servo_driver.models.base import TORQUE_MODE
from dxl_servo_driver.models.names import OTHER_MODELS
from dxl_servo_driver.protocol import MAX_ID, RETURN_DELAY_UNIT_S
from dxl_servo_driver.serial_port import adapter_latency_timer_ms, open_port

EXIT_OK = 0
EXIT_NOT_FOUND = 1
EXIT_USAGE = 2
EXIT_PORT = 3
EXIT_OUTPUT = 4
EXIT_INTERRUPTED = 130

# Most common first: 57600 is the factory default, 1 Mbps what most robot arms are set to; 9600
# last, as its broadcast PING waits longest (the SDK waits for 252 replies' worth of bytes).
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
    noise (answers that collided, a noisy line) every id is pinged alone instead.
    """
    framer = FRAMERS[protocol]
    sweep = bus.ping_sweep(ids, framer)
    if sweep.noise:
        progress(f'  {bus.baud_bps} bps: {sweep.noise} unreadable frame(s) in the Protocol '
                 f'{protocol:.1f} sweep; pinging each id alone ...')
        candidates = list(ids)
    else:
        candidates = sweep.answered + sweep.garbled
    waited = bus.latency_timer_s
    bus.latency_timer_s = min(waited, sweep_s)
    try:
        return _ping_ids(bus, candidates, warnings, protocol)
    finally:
        bus.latency_timer_s = waited


def sweep_faster(baud_bps: int) -> bool:
    """Return whether a Protocol 2.0 ping sweep of every id beats a broadcast ping here."""
    return (MAX_ID + 1) * sweep_spacing_s(baud_bps, FRAMERS[2.0]) < broadcast_ping_s(baud_bps)


def protocol_1_bauds() -> List[int]:
    """Return the baud rates of the models that speak Protocol 1.0 out of the box."""
    return sorted({bps for model in models.ALL_MODELS if model.protocol == 1.0
                   for bps in model.bauds.values()})


def estimate_s(bauds: Sequence[int], ids: Optional[Sequence[int]], protocols: Sequence[float],
               latency_s: float, bauds_1: Optional[Collection[int]] = None) -> float:
    """Return about how long a scan of these bauds takes on a bus where nobody answers."""
    total = 0.0
    count = MAX_ID + 1 if ids is None else len(ids)
    for baud_bps in bauds:
        if 2.0 in protocols:
            if ids is not None:
                total += count * (21 * 10.0 / baud_bps + latency_s + DEADLINE_SLACK_S)
            elif sweep_faster(baud_bps):
                total += count * sweep_spacing_s(baud_bps, FRAMERS[2.0]) + latency_s
            else:
                total += broadcast_ping_s(baud_bps) + latency_s + DEADLINE_SLACK_S
        if 1.0 in protocols and (bauds_1 is None or baud_bps in bauds_1):
            total += count * sweep_spacing_s(baud_bps, FRAMERS[1.0]) + latency_s
    return total


def scan_bus(bus: Bus, bauds: Sequence[int], ids: Optional[Sequence[int]] = None,
             progress: Callable[[str], None] = lambda line: None,
             found_one: Callable[[FoundServo], None] = lambda servo: None,
             protocols: Sequence[float] = (2.0,), sweep_s: float = 0.02,
             stop_at_first: bool = False,
             bauds_1: Optional[Collection[int]] = None) -> ScanResult:
    """
    Look for servos at each baud rate in turn, in each protocol; return what answered.

    Protocol 2.0: without ids a broadcast PING finds them (when its replies are garbled, every id
    is pinged one by one instead); with ids only those are pinged. Protocol 1.0 has no broadcast
    ping: one sweep pings every id (or those given) and each that answered is pinged again
    alone, waiting sweep_s beyond its wire time; so does Protocol 2.0 at the bauds where such a
    sweep is faster than a broadcast ping. bauds_1: where to look for Protocol 1.0 servos (None:
    every baud). progress gets one line per step, found_one each servo as soon as it has been
    read. stop_at_first: no baud after the first where servos answered. PortError propagates.
    """
    result = ScanResult([], [], [])
    for baud_bps in bauds:
        if stop_at_first and result.servos:
            break
        if 2.0 not in protocols:
            try:
                set_baud(bus, baud_bps)
            except (PortError, ValueError) as exc:
                result.warnings.append(f'the adapter refused {baud_bps} bps ({exc}); skipped')
                continue
            result.bauds_tried.append(baud_bps)
            _scan_1(bus, baud_bps, ids, sweep_s, result, progress, found_one)
            continue
        sweep = ids is None and sweep_faster(baud_bps)
        how = ('ping sweep of every id' if sweep else 'broadcast ping' if ids is None
               else f'ping of {len(ids)} id(s)')
        progress(f'scanning {baud_bps} bps ({how}) ...')
        try:
            set_baud(bus, baud_bps)
        except (PortError, ValueError) as exc:  # pyserial: SerialException, ValueError
            result.warnings.append(f'the adapter refused {baud_bps} bps ({exc}); skipped')
            continue
        result.bauds_tried.append(baud_bps)
        if sweep:
            models = _sweep(bus, range(MAX_ID + 1), 2.0, sweep_s, result.warnings, progress)
        elif ids is None:
            try:
                models = bus.broadcast_ping()
            except CommError as exc:
                # Colliding replies (two servos with one id) spoil the whole broadcast.
                progress(f'  {baud_bps} bps: {exc}; pinging ids 0..{MAX_ID} one by one ...')
                models = _ping_ids(bus, range(MAX_ID + 1), result.warnings)
        else:
            models = _ping_ids(bus, ids, result.warnings)
        for servo_id in sorted(models):
            servo = _describe_servo(bus, servo_id, models[servo_id], baud_bps)
            result.servos.append(servo)
            found_one(servo)
        if 1.0 in protocols and (bauds_1 is None or baud_bps in bauds_1):
            _scan_1(bus, baud_bps, ids, sweep_s, result, progress, found_one)
    return result


def _scan_1(bus: Bus, baud_bps: int, ids: Optional[Sequence[int]], sweep_s: float,
            result: ScanResult, progress: Callable[[str], None],
            found_one: Callable[[FoundServo], None]) -> None:
    """Look for Protocol 1.0 servos at the bus's baud rate (scan_bus)."""
    asked = list(range(MAX_ID + 1)) if ids is None else list(ids)
    progress(f'scanning {baud_bps} bps, Protocol 1.0 (ping of {len(asked)} id(s)) ...')
    found = _sweep(bus, asked, 1.0, sweep_s, result.warnings, progress)
    for servo_id in sorted(found):
        servo = _describe_servo(bus, servo_id, found[servo_id], baud_bps, 1.0)
        bus.speak(servo_id, FRAMERS[2.0])
        result.servos.append(servo)
        found_one(servo)


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
    # The node's reply deadlines need it: what the adapter says, else the Linux default.
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


def render_parameter_file(params: Dict[str, Any], comments: Sequence[str], header: str,
                          latency_read: bool = True) -> str:
    """Return the ROS 2 parameter file (`/**: ros__parameters:`) for build_parameters' output."""
    lines = [f'# {header}']
    lines.extend(f'#   {comment}' for comment in comments)
    lines.append('/**:')
    lines.append('  ros__parameters:')
    lines.append(f'    port: {_yaml_string(params["port"])}')
    lines.append(f'    baud_rate: {params["baud_rate"]}')
    if 'protocol' in params:
        lines.append(f'    protocol: {params["protocol"]}')
    if 'latency_timer' in params:
        source = 'read from the adapter' if latency_read else \
            'not readable here: the Linux default (1 with our udev rule)'
        lines.append(f'    latency_timer: {params["latency_timer"]}  # ms, {source}')
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


def _parse_args(argv: Optional[Sequence[str]]) -> argparse.Namespace:
    bauds = all_bauds()
    parser = _Parser(prog='scan', description='Find Dynamixel servos (Protocol 2.0 and 1.0) on '
                                              'a port.')
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
    args = parser.parse_args(argv)
    if args.baud is not None:
        bad = [b for b in args.baud if b not in bauds]
        if bad:
            parser.error(f'--baud {bad[0]}: no supported model runs at it ({bauds})')
        args.baud = list(dict.fromkeys(args.baud))
    if args.ids is not None:
        bad = [i for i in args.ids if not 0 <= i <= MAX_ID]
        if bad:
            parser.error(f'--ids {bad[0]}: ids are 0..{MAX_ID}')
        args.ids = list(dict.fromkeys(args.ids))
    if not 0.0 < args.protocol_timeout_ms <= 10_000.0:  # also refuses nan
        parser.error('--protocol-timeout-ms must be in (0, 10000]')
    if args.output is not None:
        folder = os.path.dirname(os.path.abspath(args.output))
        if not os.path.isdir(folder):
            parser.error(f'--output {args.output}: folder {folder} does not exist')
        if os.path.isdir(args.output):
            parser.error(f'--output {args.output} is a folder')
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


def _report_bauds(servos: Sequence[FoundServo], err: TextIO) -> None:
    bauds = list(dict.fromkeys(servo.baud_bps for servo in servos))
    if len(bauds) > 1:
        counts = ', '.join(
            f'{_plural(sum(1 for s in servos if s.baud_bps == b), "servo")} at {b} bps'
            for b in bauds)
        print(f'scan: warning: the servos use different baud rates ({counts}); one bus runs '
              'at one baud rate, so the node can reach only one group', file=err)


def _output(args: argparse.Namespace, result: ScanResult, latency_ms: Optional[float],
            err: TextIO) -> int:
    try:
        params, comments = build_parameters(args.port, result.servos, latency_ms)
    except (ValueError, config.ConfigError) as exc:  # ConfigError is a ValueError too
        print(f'scan: error: {args.output} not written: {exc}', file=err)
        return EXIT_OUTPUT
    stamp = datetime.datetime.now().isoformat(timespec='seconds')
    header = (f'Written by `scan --port {args.port}` at {stamp}; run it with '
              f'`ros2 run dxl_servo_driver node --ros-args --params-file {args.output}`.')
    try:
        _write_file(args.output, render_parameter_file(params, comments, header,
                                                       latency_ms is not None))
    except OSError as exc:
        print(f'scan: error: cannot write {args.output}: {exc.strerror or exc}', file=err)
        return EXIT_OUTPUT
    print(f'scan: wrote {args.output} ({_plural(len(params["joints"]), "joint")} at '
          f'{params["baud_rate"]} bps)', file=err)
    return EXIT_OK


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Run the scan; return the exit status."""
    out, err = sys.stdout, sys.stderr
    try:
        args = _parse_args(argv)
    except _UsageError as exc:
        print(f'scan: error: {exc}', file=err)
        return EXIT_USAGE
    except SystemExit as exc:  # --help
        return exc.code if isinstance(exc.code, int) else EXIT_USAGE
    bauds = args.baud or default_bauds()
    latency_ms = adapter_latency_timer_ms(args.port)
    timeout_ms = args.protocol_timeout_ms
    if latency_ms is not None:
        timeout_ms = max(timeout_ms, latency_ms + 2.0)
        if latency_ms > 1.0:
            print(f'scan: note: the adapter latency timer is {latency_ms:g} ms; 1 ms makes the '
                  'bus much faster (install udev/99-dxl-servo-driver.rules)', file=err)
    try:
        port = open_port(args.port, bauds[0])
    except PortError as exc:
        print(f'scan: error: {exc}', file=err)
        return EXIT_PORT
    bus = Bus(port, bauds[0], latency_timer_s=timeout_ms / 1000.0,
              return_delay_s=MAX_RETURN_DELAY_S)

    def progress(line: str) -> None:
        print(line, file=err, flush=True)

    # A sweep's pings are spaced by sleeps of a millisecond or two: ended on time, not late.
    timerslack.fine_timer_slack()
    asked = PROTOCOLS[args.protocol]
    # Bauds asked for are searched in every protocol asked for; by default Protocol 1.0 only
    # where a 1.0 model runs out of the box (an X servo switched to 1.0 at 4 Mbps: --baud).
    bauds_1 = None if args.baud else protocol_1_bauds()
    sweep_latency_ms = latency_ms if latency_ms is not None else LINUX_LATENCY_TIMER_MS
    about_s = estimate_s(bauds, args.ids, asked, timeout_ms / 1000.0, bauds_1)
    progress(f'scan: {_plural(len(bauds), "baud rate")}, Protocol '
             f'{" and ".join(f"{p:.1f}" for p in asked)}: about {about_s:.0f} s where '
             f'nobody answers{" (or until servos answer)" if args.stop_at_first else ""}; '
             'Ctrl-C stops it')

    def found_one(servo: FoundServo) -> None:
        print(describe(servo), file=out, flush=True)

    try:
        result = scan_bus(bus, bauds, args.ids, progress, found_one, asked,
                          (sweep_latency_ms + SWEEP_SLACK_MS) / 1000.0, args.stop_at_first,
                          bauds_1)
    except PortError as exc:
        print(f'scan: error: {exc}', file=err)
        return EXIT_PORT
    except KeyboardInterrupt:
        print('scan: interrupted', file=err)
        return EXIT_INTERRUPTED
    finally:
        bus.close()
    for warning in result.warnings:
        print(f'scan: warning: {warning}', file=err)
    tried = ', '.join(str(b) for b in result.bauds_tried) or 'none'
    if not result.servos:
        what = 'a broadcast ping' if args.ids is None else (
            'pings of id(s) ' + ' '.join(str(i) for i in args.ids))
        protocols = ' and '.join(f'{p:.1f}' for p in PROTOCOLS[args.protocol])
        print(f'scan: no servo answered on {args.port} ({what} at {tried} bps, Protocol '
              f'{protocols}).\n{HINT}', file=err)
        return EXIT_NOT_FOUND
    print(f'scan: found {_plural(len(result.servos), "servo")} (tried {tried} bps)', file=err)
    _report_bauds(result.servos, err)
    if args.output is not None:
        return _output(args, result, latency_ms, err)
    return EXIT_OK


if __name__ == '__main__':
    sys.exit(main())
