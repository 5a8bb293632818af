"""
`dxl calibrate`: measure an arm's joints by hand and write them into its parameter file.

The joints (ids, models, offset, reverse, ratio, limits) are the driver's parameter file's
(config.validate checks it first, with its own messages). Every servo's torque goes off (and
back to what it was if the command does not finish: Ctrl-C, an error, the write declined), then
the steps run, each taking its readings when the user presses Enter (a script sends a line):

- zero: the arm in its zero pose; each joint's `offset` = its Present Position in servo
  radians, so that the node publishes 0 there (models/units.JointFrame: joint = (-1 if reverse
  else 1) * ratio * (servo - offset)); a second servo's `secondary_offset` likewise.
- direction: each joint (or all, --together) moved in its positive direction (the URDF's: the
  prompt says which way); a servo that counted down gets `reverse: true` (a second servo
  `secondary_reverse`); a move under --min-move is asked again.
- range: every joint moved through its whole range while the positions show live;
  `min_position`/`max_position` = the extremes seen widened by --margin (joint units); a
  gripper's `gripper_open`/`gripper_closed` = its two ends (it asks which is open).
- --find-stops JOINT --current A: the joint's servo finds its hard stops itself, in
  current-based position mode at a slow profile velocity with its goal current at A (refused
  above the servo's Current Limit): a stall (velocity ~0, current near A for a while) is a stop;
  it backs off, then goes the other way. Limits = the stops narrowed by --margin. Torque off
  after, its mode and goals as they were.

The changes are shown as a unified diff and written (yaml_edit: comments and layout kept) after
a confirmation (--yes: without one; --dry-run: the diff only). Nothing is written before the end.
"""

import argparse
import math
import os
import select
import sys
import tempfile
import time
from typing import Dict, IO, List, Optional, Sequence, Tuple
import xml.etree.ElementTree as ElementTree

from dxl_servo_driver import config as driver_config
from dxl_servo_driver.bus import Bus, FRAMERS
from dxl_servo_driver.errors import CommError, ConfigurationError
from dxl_servo_driver.models import modes
from dxl_servo_driver.models.registers import time_based
from dxl_servo_driver.models.units import JointFrame, units_for
from dxl_servo_driver.tool import yaml_edit
from dxl_servo_driver.tool.common import (
    EXIT_FAILED, EXIT_OK, EXIT_OUTPUT, EXIT_USAGE, ToolError)
from dxl_servo_driver.tool.session import connect, from_si, open_bus, ServoLink

STEPS = ('zero', 'direction', 'range')
DEFAULT_MARGIN = 0.05        # rad (joint units): about 3 degrees
DEFAULT_MIN_MOVE = 0.2       # rad of the servo: a deliberate move, not a nudge or noise
DEFAULT_SPEED = 0.3          # rad/s: how fast --find-stops approaches a stop
DEFAULT_BACKOFF = 0.1        # rad: how far it backs off a stop
DEFAULT_TRAVEL = 2 * math.pi   # rad: the farthest it looks for a stop each way
# A stall: velocity under this many profile-velocity units (0.229 rpm on an X) ...
STALL_VELOCITY_RAW = 2
# ... with Present Current at this share of the goal current, for this long.
STALL_CURRENT_SHARE = 0.8
STALL_TIME_S = 0.3
ATTEMPTS = 3                 # tries of one transaction before the bus is said to fail
LIVE_RETRY_S = 1.0           # ... and how long a live reading is tried at least
REFRESH_S = 0.1              # the live display's refresh while the range is moved


class Prompter:
    """
    Lines from stdin, read by the tool itself (select + os.read), never through Python's buffer.

    The range step shows positions until a line comes: select() must see every byte that has
    not been taken yet, which a buffered sys.stdin would hide.
    """

    def __init__(self, stream: IO[str], out: IO[str]) -> None:
        self.fd = stream.fileno()
        self.out = out
        self._buffer = b''

    def poll(self, timeout_s: float) -> Optional[str]:
        """Return a line if one comes within timeout_s (without its break), else None."""
        deadline = time.monotonic() + timeout_s
        while b'\n' not in self._buffer:
            left = deadline - time.monotonic()
            if left < 0 or not select.select([self.fd], [], [], max(left, 0.0))[0]:
                return None
            chunk = os.read(self.fd, 1024)
            if not chunk:
                raise ToolError('stdin ended at a prompt: nothing written')
            self._buffer += chunk
        line, _, self._buffer = self._buffer.partition(b'\n')
        return line.decode(errors='replace').strip()

    def ask(self, text: str) -> str:
        """Print text and return the next line."""
        self.out.write(text)
        self.out.flush()
        while True:
            line = self.poll(3600.0)
            if line is not None:
                return line


def live(link: ServoLink, name: str) -> int:
    """
    Return an item that changes by itself (a position, a current): read once, unconfirmed.

    A reply lost now and then (noise, a busy adapter, a host too loaded to read in time) is
    read again, ATTEMPTS times and for LIVE_RETRY_S at least: the readings go on for minutes,
    and a few lost replies must not end a calibration the user has half done.
    """
    item = link.item(name)
    give_up = time.monotonic() + LIVE_RETRY_S
    attempt = 0
    while True:
        try:
            return item.decode(link.bus.read(link.servo_id, item.address, item.size,
                                             confirm=False))
        except CommError:
            attempt += 1
            if attempt >= ATTEMPTS and time.monotonic() >= give_up:
                raise


def put(link: ServoLink, name: str, value: int) -> None:
    """Write an item, again if its status was lost (writing a value twice is harmless)."""
    for attempt in range(ATTEMPTS):
        try:
            link.write(name, value)
            return
        except CommError:
            if attempt == ATTEMPTS - 1:
                raise


class Joint:
    """One joint of the file being calibrated: its servos and the frame found so far."""

    def __init__(self, joint: driver_config.JointConfig, links: Sequence[ServoLink]) -> None:
        self.config = joint
        self.links = list(links)            # the joint's servo, then its second one if any
        self.offsets = [joint.offset, joint.offset if joint.secondary_offset is None
                        else joint.secondary_offset]
        self.reverse = [joint.reverse, joint.secondary_reverse]

    @property
    def name(self) -> str:
        """Return the joint's name."""
        return self.config.name

    def servo_rad(self, index: int = 0, absolute: bool = True) -> float:
        """
        Return a servo's Present Position in servo radians (raw 'zero' = 0 rad).

        absolute: as the node will read it. In a single-turn mode the node keeps no turns:
        Present Position is then re-initialised within one turn at torque on (the XM430
        manual), and so is this reading. Not absolute: as the servo counts now (for moves).
        """
        link = self.links[index]
        model = link.model
        raw = live(link, 'present_position')
        if absolute and self.config.operating_mode in modes.SINGLE_TURN:
            homing = link.read('homing_offset') if model.has('homing_offset') else 0
            raw = units_for(model).reinit_position(raw, homing)
        return (raw - model.position_zero_raw) * 2.0 * math.pi / model.pulses_per_rev

    def frame(self) -> JointFrame:
        """Return the joint's frame as calibrated so far."""
        return JointFrame(self.offsets[0], self.reverse[0], self.config.ratio)

    def joint_value(self, servo_rad: float) -> float:
        """Return a servo angle as the joint's position, in the frame found so far."""
        frame = self.frame()
        return frame.scale * (servo_rad - frame.offset_rad)


def register(subparsers: 'argparse._SubParsersAction[argparse.ArgumentParser]') -> None:
    """Add the calibrate command."""
    parser = subparsers.add_parser(
        'calibrate', help='calibrate an arm into its parameter file (offsets, directions, '
        'limits)', description="Measure an arm by hand (its zero pose, each joint's "
        "positive direction and range), or find a joint's hard stops with its motor, and write "
        "offset, reverse, min/max_position and a gripper's ends into the driver's parameter "
        'file, its comments and layout kept. Torque goes off on every servo (back as it was if '
        'the command does not finish).',
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog='examples:\n'
        '  dxl calibrate --params config/arm.yaml --port /dev/ttyUSB0\n'
        '  dxl calibrate --params config/arm.yaml --step zero --yes   # the arm is at zero now\n'
        '  dxl calibrate --params config/arm.yaml --find-stops gripper --current 0.3 '
        '--gripper-open low\n'
        'Each reading is taken when Enter is pressed (a script sends a line on stdin). '
        'Ctrl-C at any prompt: nothing written, torque as it was, exit 130.')
    parser.add_argument('--params', required=True, metavar='FILE',
                        help="the driver's parameter file: read, then changed in place")
    parser.add_argument('--port', help="serial device or virtual_bus pty (default: the file's "
                        'port)')
    parser.add_argument('--baud', type=int, metavar='BPS',
                        help="baud rate (default: the file's baud_rate)")
    parser.add_argument('--joints', nargs='+', metavar='JOINT',
                        help='calibrate only these joints (default: every joint of the file)')
    parser.add_argument('--step', action='append', choices=STEPS, dest='steps',
                        help='run this step (repeat for several; default: zero, direction, '
                        'range, or none when --find-stops is given)')
    parser.add_argument('--margin', type=float, default=DEFAULT_MARGIN, metavar='UNITS',
                        help='widen the range seen by hand (narrow the stops found) by this '
                        f'much, in joint units (default {DEFAULT_MARGIN} rad, about 3 deg)')
    parser.add_argument('--min-move', type=float, default=DEFAULT_MIN_MOVE, metavar='RAD',
                        help='the least a direction move counts as one, in servo radians '
                        f'(default {DEFAULT_MIN_MOVE})')
    parser.add_argument('--together', action='store_true',
                        help='direction step: move every joint at once, one Enter')
    parser.add_argument('--gripper-open', choices=('low', 'high'),
                        help="which end of a gripper's travel is open (else it asks)")
    parser.add_argument('--urdf', metavar='FILE',
                        help="the robot's URDF: the direction prompts say each joint's axis")
    parser.add_argument('--hint', action='append', default=[], metavar='JOINT=TEXT',
                        help='the words a direction prompt uses for a joint, e.g. '
                        '"shoulder_lift=raise the shoulder"')
    parser.add_argument('--find-stops', metavar='JOINT',
                        help="find this joint's hard stops with its own motor (needs --current)")
    parser.add_argument('--current', type=float, metavar='A',
                        help='the most current --find-stops may use (at most the Current Limit)')
    parser.add_argument('--speed', type=float, default=DEFAULT_SPEED, metavar='RAD/S',
                        help=f'--find-stops approach speed (default {DEFAULT_SPEED})')
    parser.add_argument('--yes', action='store_true',
                        help='no prompt for the zero pose (the arm is there now) and no '
                        'confirmation before writing')
    parser.add_argument('--dry-run', action='store_true',
                        help='print the diff, write nothing')
    parser.add_argument('--trace', default='', metavar='FILE',
                        help='write every frame sent and received to FILE')
    parser.set_defaults(run=run)


# ---- the file -------------------------------------------------------------------------------
def load(path: str) -> Tuple[str, driver_config.DriverConfig]:
    """Return a parameter file's text and configuration; ToolError (exit 2) naming what is bad."""
    try:
        driver_config.check_parameter_file(path)
        with open(path, encoding='utf-8') as stream:
            text = stream.read()
        return text, driver_config.validate(yaml_edit.parameters_of(text))
    except (ConfigurationError, yaml_edit.EditError) as exc:
        raise ToolError(f'{path}: {exc}' if path not in str(exc) else str(exc),
                        EXIT_USAGE) from None


def write_file(path: str, text: str) -> None:
    """Replace a file's content at once (a temporary file renamed), keeping its mode."""
    folder = os.path.dirname(os.path.abspath(path))
    try:
        mode = os.stat(path).st_mode & 0o7777
        handle, temporary = tempfile.mkstemp(prefix='.calibrate-', dir=folder)
        try:
            with os.fdopen(handle, 'w', encoding='utf-8', newline='') as stream:
                stream.write(text)
            os.chmod(temporary, mode)
            os.replace(temporary, path)
        except BaseException:
            os.unlink(temporary)
            raise
    except OSError as exc:
        raise ToolError(f'cannot write {path}: {exc}', EXIT_OUTPUT) from None


def urdf_hints(path: str) -> Dict[str, str]:
    """Return what a direction prompt says of each joint of a URDF (its axis)."""
    try:
        root = ElementTree.parse(path).getroot()
    except (OSError, ElementTree.ParseError) as exc:
        raise ToolError(f'cannot read the URDF {path}: {exc}', EXIT_USAGE) from None
    hints = {}
    for element in root.iter('joint'):
        axis = element.find('axis')
        xyz = axis.get('xyz', '1 0 0') if axis is not None else '1 0 0'
        kind = element.get('type', '')
        if kind == 'prismatic':
            hints[element.get('name', '')] = f'along its axis ({xyz})'
        elif kind in ('revolute', 'continuous'):
            hints[element.get('name', '')] = (f'counter-clockwise about its axis ({xyz}) seen '
                                              'from the axis tip: the right-hand rule')
    return hints


# ---- the servos -----------------------------------------------------------------------------
class Arm:
    """Every servo of the joints calibrated, their torque off, put back as it was on abort."""

    def __init__(self, bus: Bus, joints: Sequence[Joint]) -> None:
        self.bus = bus
        self.joints = list(joints)
        self.torque_was: List[Tuple[ServoLink, int]] = []

    def links(self) -> List[ServoLink]:
        """Return every servo, joints' order."""
        return [link for joint in self.joints for link in joint.links]

    def torque_off(self) -> None:
        """Turn every servo's torque off, keeping what it was."""
        for link in self.links():
            enabled = link.read('torque_enable')
            self.torque_was.append((link, enabled))
            if enabled:
                link.write('torque_enable', 0)

    def restore(self) -> None:
        """Torque back on where it was on, each holding where it is now (best effort)."""
        for link, enabled in self.torque_was:
            if not enabled:
                continue
            try:
                mode = modes.BY_NAME.get(_mode_name(link))
                if mode is None or mode.position:
                    torque_on_holding(link)
                else:
                    put(link, 'torque_enable', 1)
            except (CommError, ToolError) as exc:
                print(f'dxl calibrate: could not turn torque back on at id {link.servo_id}: '
                      f'{exc}', file=sys.stderr)


def torque_on_holding(link: ServoLink) -> int:
    """
    Turn torque on with the goal where the horn is; return the whole turns torque-on took.

    Torque on re-initialises Present Position within one turn (the XM430 manual) and a horn
    turned by hand may be turns away from where it was: the goal is written where the count
    will be, then again where it is once torque is on, so that the motor never chases a goal
    turns away.
    """
    model = link.model
    before = live(link, 'present_position')
    if not model.has('goal_position'):
        put(link, 'torque_enable', 1)
        return 0
    homing = link.read('homing_offset') if model.has('homing_offset') else 0
    units = units_for(model)
    put(link, 'goal_position', units.reinit_position(before, homing))
    put(link, 'torque_enable', 1)
    after = live(link, 'present_position')
    put(link, 'goal_position', after)
    return units.kept_turns(before, after)


def _mode_name(link: ServoLink) -> str:
    """Return the servo's mode's name ('' when its table has no mode register or it is odd)."""
    if not link.model.mode_register:
        return ''
    number = link.read(link.model.mode_register)
    for name, value in link.model.modes.items():
        if value == number:
            return name
    return ''


def connect_joints(bus: Bus, config: driver_config.DriverConfig,
                   names: Sequence[str]) -> List[Joint]:
    """Connect every servo of the joints named; ToolError naming a joint that does not answer."""
    joints = []
    for name in names:
        joint = config.joint(name)
        links = []
        for servo_id in (joint.servo_id, joint.secondary_id):
            if servo_id is None:
                continue
            bus.speak(servo_id, FRAMERS[joint.protocol])
            try:
                link = connect(bus, servo_id)
            except ToolError as exc:
                raise ToolError(f'joint {name!r}: {exc}', exc.status) from None
            if joint.model is not None and link.model.number != joint.model.number:
                raise ToolError(f'joint {name!r}: the file says {joint.model.name}, id '
                                f'{servo_id} is a {link.model.name}')
            links.append(link)
        joints.append(Joint(joint, links))
    return joints


# ---- the steps ------------------------------------------------------------------------------
class Calibration:
    """The steps, run on the joints; `changes` holds what each found, joint by joint."""

    def __init__(self, joints: Sequence[Joint], prompter: Prompter,
                 args: argparse.Namespace) -> None:
        self.joints = list(joints)
        self.prompter = prompter
        self.args = args
        self.out = prompter.out
        self.changes: Dict[str, Dict[str, object]] = {}
        self.hints: Dict[str, str] = urdf_hints(args.urdf) if args.urdf else {}
        for hint in args.hint:
            joint, sep, text = hint.partition('=')
            if not sep or not text:
                raise ToolError(f'--hint {hint!r}: expected JOINT=TEXT', EXIT_USAGE)
            self.hints[joint] = text

    def say(self, text: str) -> None:
        """Print one line."""
        self.out.write(text + '\n')
        self.out.flush()

    def record(self, joint: Joint, key: str, value: object) -> None:
        """Record a change of one joint key."""
        self.changes.setdefault(joint.name, {})[key] = value

    def step_zero(self) -> None:
        """Offsets from the zero pose."""
        if not self.args.yes:
            self.prompter.ask('Put the arm in its zero pose (every joint at the 0 of its URDF) '
                              'and press Enter: ')
        for joint in self.joints:
            for index, key in enumerate(('offset', 'secondary_offset')[:len(joint.links)]):
                offset = round(joint.servo_rad(index), yaml_edit.DECIMALS)
                joint.offsets[index] = offset
                self.record(joint, key, offset)
                self.say(f'  {joint.name}: {key} {offset:+.4f} rad (id '
                         f'{joint.links[index].servo_id})')

    def step_direction(self) -> None:
        """Reverse from a move in each joint's positive direction."""
        pending = list(self.joints)
        if self.args.together:
            starts = {joint.name: self._positions(joint) for joint in pending}
            self.prompter.ask('Move every joint in its positive direction (at least '
                              f'{math.degrees(self.args.min_move):.0f} deg each) and press '
                              'Enter: ')
            pending = [joint for joint in pending if not self._judge(joint, starts[joint.name])]
        for joint in pending:
            start = self._positions(joint)
            hint = self.hints.get(joint.name, "its URDF's positive direction")
            while True:
                self.prompter.ask(f'Move {joint.name} in its positive direction ({hint}), at '
                                  f'least {math.degrees(self.args.min_move):.0f} deg, and press '
                                  'Enter: ')
                if self._judge(joint, start):
                    break

    def _positions(self, joint: Joint) -> List[float]:
        return [joint.servo_rad(index, absolute=False) for index in range(len(joint.links))]

    def _judge(self, joint: Joint, start: Sequence[float]) -> bool:
        """Set the joint's reverse from its move since start; False (said) if it is too small."""
        moves = [now - then for now, then in zip(self._positions(joint), start)]
        small = [move for move in moves if abs(move) < self.args.min_move]
        if small:
            self.say(f'  {joint.name}: moved {math.degrees(small[0]):+.1f} deg only: too small '
                     f'a move (at least {math.degrees(self.args.min_move):.0f} deg); move it '
                     'farther the same way')
            return False
        for index, key in enumerate(('reverse', 'secondary_reverse')[:len(moves)]):
            joint.reverse[index] = moves[index] < 0
            self.record(joint, key, moves[index] < 0)
            self.say(f'  {joint.name}: servo id {joint.links[index].servo_id} counted '
                     f'{"down" if moves[index] < 0 else "up"} ({math.degrees(moves[index]):+.1f} '
                     f'deg): {key} {"true" if moves[index] < 0 else "false"}')
        return True

    def step_range(self) -> None:
        """Limits from the extremes seen while the joints are moved through their ranges."""
        seen: Dict[str, List[float]] = {}
        self.say('Move every joint through its whole range, to both ends; press Enter when '
                 'done.')
        tty = self.out.isatty()
        last_line = 0.0
        while True:
            parts = []
            for joint in self.joints:
                value = joint.joint_value(joint.servo_rad())
                low, high = seen.setdefault(joint.name, [value, value])
                seen[joint.name] = [min(low, value), max(high, value)]
                parts.append(f'{joint.name} {value:+.3f} [{seen[joint.name][0]:+.3f} '
                             f'{seen[joint.name][1]:+.3f}]')
            if tty:
                self.out.write('\r' + '  '.join(parts) + '\x1b[K')
                self.out.flush()
            elif time.monotonic() - last_line > 1.0:
                self.say('  '.join(parts))
                last_line = time.monotonic()
            if self.prompter.poll(REFRESH_S) is None:
                continue
            if tty:
                self.out.write('\n')
            still = [joint.name for joint in self.joints
                     if seen[joint.name][1] - seen[joint.name][0] < self.args.min_move]
            if not still:
                break
            self.say(f'  not moved yet (under {math.degrees(self.args.min_move):.0f} deg): '
                     f'{", ".join(still)}; move them through their range and press Enter')
        for joint in self.joints:
            low, high = seen[joint.name]
            self._limits(joint, low - self.args.margin, high + self.args.margin, low, high)

    def _limits(self, joint: Joint, low: float, high: float, end_low: float,
                end_high: float) -> None:
        """Record a joint's limits (and a gripper's ends), asking which end is open."""
        digits = yaml_edit.DECIMALS
        self.record(joint, 'min_position', round(low, digits))
        self.record(joint, 'max_position', round(high, digits))
        self.say(f'  {joint.name}: min_position {low:+.4f}, max_position {high:+.4f}')
        if not joint.config.gripper:
            return
        which = self.args.gripper_open
        while which is None:
            answer = self.prompter.ask(
                f'{joint.name}: its ends are {end_low:+.4f} and {end_high:+.4f}. Open the '
                'gripper fully and press Enter (or type low or high): ').lower()
            if answer in ('low', 'high'):
                which = answer
            elif not answer:
                value = joint.joint_value(joint.servo_rad())
                which = 'low' if abs(value - end_low) < abs(value - end_high) else 'high'
        opened, closed = (end_low, end_high) if which == 'low' else (end_high, end_low)
        self.record(joint, 'gripper_open', round(opened, digits))
        self.record(joint, 'gripper_closed', round(closed, digits))
        self.say(f'  {joint.name}: gripper_open {opened:+.4f}, gripper_closed {closed:+.4f}')

    def find_stops(self, joint: Joint, current_a: float) -> None:
        """Find the joint's hard stops with its own motor; limits (a gripper's ends) from them."""
        if len(joint.links) > 1:
            raise ToolError(f'joint {joint.name!r} is driven by two servos: find its range by '
                            'hand (--step range)', EXIT_USAGE)
        link = joint.links[0]
        model = link.model
        if model.current_unit_a is None or not model.has('goal_current') or \
                'current_based_position' not in model.modes:
            raise ToolError(f'{model.name} (joint {joint.name!r}) has no current-based '
                            'position mode: find its range by hand (--step range)', EXIT_USAGE)
        limit_raw = link.read('current_limit')
        limit_a = limit_raw * model.current_unit_a
        if not 0.0 < current_a <= limit_a + 1e-9:
            raise ToolError(f'--current {current_a:g} A: must be above 0 and at most the '
                            f'Current Limit of id {link.servo_id} ({limit_a:.4g} A)', EXIT_USAGE)
        goal_current = min(limit_raw, int(current_a / model.current_unit_a + 1e-9))
        # Drive Mode first: restored before the profile that its time-based bit gives a meaning.
        saved = {name: link.read(name) for name in
                 ('drive_mode', model.mode_register, 'goal_current', 'profile_velocity')
                 if model.has(name)}
        self.say(f'{joint.name}: finding its stops at {goal_current * model.current_unit_a:.3g} '
                 f'A, {self.args.speed:g} rad/s (Ctrl-C stops it)')
        stops: List[int] = []
        peak = 0
        try:
            put(link, 'torque_enable', 0)
            put(link, model.mode_register, model.modes['current_based_position'])
            put(link, 'goal_current', goal_current)
            if time_based(model, saved.get('drive_mode')):
                # A time-based profile would take the speed below for a move's time in ms:
                # velocity-based while the stops are found, the servo's own mode restored after.
                assert model.time_profile_bit is not None
                put(link, 'drive_mode', saved['drive_mode'] & ~(1 << model.time_profile_bit))
            velocity = link.item('profile_velocity')
            put(link, 'profile_velocity', max(1, from_si(model, velocity, self.args.speed)))
            turns = torque_on_holding(link)
            pulses = model.pulses_per_rev / (2.0 * math.pi)
            for direction in (-1, 1):
                stop, seen = self._push(link, direction, goal_current, turns, pulses)
                peak = max(peak, seen)
                stops.append(stop)
                back = int(round((stop - turns) - direction * DEFAULT_BACKOFF * pulses))
                put(link, 'goal_position', back)
                self._settle(link, back)
        finally:
            try:
                put(link, 'torque_enable', 0)
                for name, value in saved.items():
                    put(link, name, value)
            except CommError as exc:
                print(f'dxl calibrate: id {link.servo_id}: could not restore its mode: {exc}',
                      file=sys.stderr)
        self.say(f'  {joint.name}: peak current {peak * model.current_unit_a:.3g} A (limit '
                 f'{goal_current * model.current_unit_a:.3g} A)')
        if joint.config.operating_mode in modes.SINGLE_TURN:   # as the node will count
            homing = link.read('homing_offset') if model.has('homing_offset') else 0
            stops = [units_for(model).reinit_position(raw, homing) for raw in stops]
        ends = sorted(joint.joint_value((raw - model.position_zero_raw) / pulses)
                      for raw in stops)
        self.say(f'  {joint.name}: stops at {ends[0]:+.4f} and {ends[1]:+.4f}')
        if ends[1] - ends[0] <= 2 * self.args.margin:
            raise ToolError(f'joint {joint.name!r}: its stops are {ends[1] - ends[0]:.3f} apart, '
                            f'no more than twice the margin ({self.args.margin:g})')
        self._limits(joint, ends[0] + self.args.margin, ends[1] - self.args.margin,
                     ends[0] + self.args.margin, ends[1] - self.args.margin)

    def _push(self, link: ServoLink, direction: int, goal_current: int, turns: int,
              pulses: float) -> Tuple[int, int]:
        """Drive one way until a stall; return the position there (raw, turns kept), peak."""
        start = live(link, 'present_position')
        target = int(round(start + direction * DEFAULT_TRAVEL * pulses))
        put(link, 'goal_position', target)
        stalled_since: Optional[float] = None
        peak = 0
        speed_s = max(self.args.speed, 0.01)
        deadline = time.monotonic() + DEFAULT_TRAVEL / speed_s * 1.5 + 5.0
        while time.monotonic() < deadline:
            current = live(link, 'present_current')
            velocity = live(link, 'present_velocity')
            peak = max(peak, abs(current))
            if abs(velocity) <= STALL_VELOCITY_RAW and \
                    abs(current) >= STALL_CURRENT_SHARE * goal_current:
                now = time.monotonic()
                stalled_since = now if stalled_since is None else stalled_since
                if now - stalled_since >= STALL_TIME_S:
                    return live(link, 'present_position') + turns, peak
            else:
                stalled_since = None
            if abs(live(link, 'present_position') - target) < 2:
                break
            time.sleep(0.02)
        raise ToolError(f'id {link.servo_id}: no stop found within '
                        f'{math.degrees(DEFAULT_TRAVEL):.0f} deg '
                        f'{"down" if direction < 0 else "up"}')

    def _settle(self, link: ServoLink, goal: int) -> None:
        """Wait (a few seconds at most) until the servo is near goal."""
        deadline = time.monotonic() + 3.0 + DEFAULT_BACKOFF / max(self.args.speed, 0.01)
        while time.monotonic() < deadline:
            if abs(live(link, 'present_position') - goal) < 10:
                return
            time.sleep(0.02)


# ---- the command ----------------------------------------------------------------------------
def _confirm(prompter: Prompter, path: str) -> bool:
    answer = prompter.ask(f'Write these changes to {path}? [y/N] ').lower()
    return answer in ('y', 'yes')


def run(args: argparse.Namespace) -> int:
    """Calibrate; write the file; return the exit status."""
    text, config = load(args.params)
    names = list(args.joints or [joint.name for joint in config.joints])
    unknown = [name for name in names if name not in [joint.name for joint in config.joints]]
    if unknown:
        raise ToolError(f'--joints: {", ".join(unknown)} not in {args.params} (its joints: '
                        f'{", ".join(joint.name for joint in config.joints)})', EXIT_USAGE)
    steps = list(args.steps or ([] if args.find_stops else STEPS))
    if args.find_stops is not None:
        if args.find_stops not in [joint.name for joint in config.joints]:
            raise ToolError(f'--find-stops {args.find_stops}: no such joint in {args.params}',
                            EXIT_USAGE)
        if args.current is None:
            raise ToolError('--find-stops needs --current A (the most current it may use)',
                            EXIT_USAGE)
        if args.find_stops not in names:
            names.append(args.find_stops)
    if args.margin < 0 or args.min_move <= 0 or args.speed <= 0:
        raise ToolError('--margin must be >= 0, --min-move and --speed > 0', EXIT_USAGE)
    check_editable(args.params, text, config, args.joints or names, steps, args.find_stops)
    bus = open_bus(args.port or config.port, args.baud or config.baud_rate, config.protocol,
                   trace=args.trace)
    prompter = Prompter(sys.stdin, sys.stdout)
    try:
        joints = connect_joints(bus, config, names)
        arm = Arm(bus, joints)
        written = False
        try:
            arm.torque_off()
            print(f'torque off on {len(arm.links())} servos')
            calibration = Calibration([j for j in joints if j.name in (args.joints or names)],
                                      prompter, args)
            for step in STEPS:
                if step in steps:
                    print(f'-- {step}')
                    getattr(calibration, f'step_{step}')()
            if args.find_stops is not None:
                print('-- find stops')
                joint = next(j for j in joints if j.name == args.find_stops)
                stops = Calibration([joint], prompter, args)
                stops.find_stops(joint, args.current)
                for key, value in stops.changes.get(joint.name, {}).items():
                    calibration.changes.setdefault(joint.name, {})[key] = value
            status = _finish(args, text, calibration.changes, prompter)
            written = status == WRITTEN
        except CommError as exc:
            raise ToolError(f'the bus failed: {exc}') from None
        finally:
            if not written:
                arm.restore()
    finally:
        bus.close()
    return EXIT_FAILED if status == DECLINED else EXIT_OK


def planned_keys(joint: driver_config.JointConfig, steps: Sequence[str],
                 find_stops: bool) -> Dict[str, object]:
    """Return the keys the steps will write into a joint, each with a stand-in value."""
    second = joint.secondary_id is not None
    keys: Dict[str, object] = {}
    if 'zero' in steps:
        keys.update({'offset': 0.0, **({'secondary_offset': 0.0} if second else {})})
    if 'direction' in steps:
        keys.update({'reverse': False, **({'secondary_reverse': False} if second else {})})
    if 'range' in steps or find_stops:
        keys.update({'min_position': -1.0, 'max_position': 1.0})
        if joint.gripper:
            keys.update({'gripper_open': 0.0, 'gripper_closed': 1.0})
    return keys


def check_editable(path: str, text: str, config: driver_config.DriverConfig,
                   names: Sequence[str], steps: Sequence[str],
                   find_stops: Optional[str]) -> None:
    """
    Refuse (ToolError) a file the calibration could not be written into, before it starts.

    The keys each step will write are placed, with stand-in values, by the same editor that
    writes them at the end: a joint it cannot change is named now, before torque goes off and
    the user moves the arm, not after.
    """
    planned = {name: planned_keys(config.joint(name), steps, False) for name in names}
    if find_stops is not None:
        planned.setdefault(find_stops, {}).update(
            planned_keys(config.joint(find_stops), (), True))
    try:
        yaml_edit.apply(text, {name: keys for name, keys in planned.items() if keys})
    except yaml_edit.EditError as exc:
        raise ToolError(f'{path}: {exc}; the calibration could not be written there, so '
                        'nothing was started (torque untouched)', EXIT_USAGE) from None


WRITTEN, UNCHANGED, DRY_RUN, DECLINED = 'written', 'unchanged', 'dry run', 'declined'


def _finish(args: argparse.Namespace, text: str, changes: Dict[str, Dict[str, object]],
            prompter: Prompter) -> str:
    """Show the diff, check and write the file; return what became of it."""
    try:
        new = yaml_edit.apply(text, changes)
    except yaml_edit.EditError as exc:
        raise ToolError(f'{args.params}: {exc}; nothing written') from None
    diff = yaml_edit.unified_diff(text, new, args.params)
    print(diff or 'no change to the file', end='' if diff else '\n')
    try:
        driver_config.validate(yaml_edit.parameters_of(new))
    except ConfigurationError as exc:
        raise ToolError(f'the calibrated file would be refused by the driver: {exc}; nothing '
                        'written') from None
    if not diff:
        return UNCHANGED
    if args.dry_run:
        print('dry run: nothing written')
        return DRY_RUN
    if not args.yes and not _confirm(prompter, args.params):
        print('nothing written')
        return DECLINED
    write_file(args.params, new)
    print(f'wrote {args.params}; torque is off on every servo')
    return WRITTEN
