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

This module is the command: its arguments, the file, the diff and the write. The servos are
calibrate_servos', the steps by hand and their prompts calibrate_steps', the stops found with
the motor calibrate_stops'.
"""

import argparse
import os
import sys
import tempfile
from typing import Dict, Optional, Sequence
import xml.etree.ElementTree as ElementTree

from dxl_servo_driver import config as driver_config
from dxl_servo_driver.errors import CommError, ConfigurationError
from dxl_servo_driver.tool import yaml_edit
from dxl_servo_driver.tool.calibrate_servos import Arm, connect_joints
from dxl_servo_driver.tool.calibrate_steps import Calibration, Prompter
from dxl_servo_driver.tool.common import (
    EXIT_FAILED, EXIT_OK, EXIT_OUTPUT, EXIT_USAGE, ToolError)
from dxl_servo_driver.tool.session import open_bus, read_params

STEPS = ('zero', 'direction', 'range')
DEFAULT_MARGIN = 0.05        # rad (joint units): about 3 degrees
DEFAULT_MIN_MOVE = 0.2       # rad of the servo: a deliberate move, not a nudge or noise
DEFAULT_SPEED = 0.3          # rad/s: how fast --find-stops approaches a stop


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


def prompt_hints(args: argparse.Namespace) -> Dict[str, str]:
    """Return what the direction prompts say of each joint: --urdf's axes, then --hint's."""
    hints: Dict[str, str] = urdf_hints(args.urdf) if args.urdf else {}
    for hint in args.hint:
        joint, sep, text = hint.partition('=')
        if not sep or not text:
            raise ToolError(f'--hint {hint!r}: expected JOINT=TEXT', EXIT_USAGE)
        hints[joint] = text
    return hints


# ---- the command ----------------------------------------------------------------------------
def _confirm(prompter: Prompter, path: str) -> bool:
    answer = prompter.ask(f'Write these changes to {path}? [y/N] ').lower()
    return answer in ('y', 'yes')


def run(args: argparse.Namespace) -> int:
    """Calibrate; write the file; return the exit status."""
    text, config = read_params(args.params, label='')
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
            hints = prompt_hints(args)
            calibration = Calibration([j for j in joints if j.name in (args.joints or names)],
                                      prompter, args, hints)
            for step in STEPS:
                if step in steps:
                    print(f'-- {step}')
                    getattr(calibration, f'step_{step}')()
            if args.find_stops is not None:
                print('-- find stops')
                joint = next(j for j in joints if j.name == args.find_stops)
                stops = Calibration([joint], prompter, args, hints)
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
