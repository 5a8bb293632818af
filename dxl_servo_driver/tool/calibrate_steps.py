"""
The steps of `dxl calibrate` by hand, and the prompts that take its readings.

Each reading is taken when the user presses Enter (a script sends a line): zero (offsets from
the zero pose), direction (reverse from a move in each joint's positive direction), range (the
limits from the extremes seen, a gripper's ends); and the limits from the stops found by
--find-stops (calibrate_stops). What each step found is kept in `Calibration.changes`, joint by
joint, and written by the command at the end.
"""

import argparse
import math
import os
import select
import time
from typing import Dict, IO, List, Mapping, Optional, Sequence

from dxl_servo_driver.tool import yaml_edit
from dxl_servo_driver.tool.calibrate_servos import Joint
from dxl_servo_driver.tool.calibrate_stops import find_stops
from dxl_servo_driver.tool.common import ToolError

__all__ = ['Calibration', 'Prompter']

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


class Calibration:
    """The steps, run on the joints; `changes` holds what each found, joint by joint."""

    def __init__(self, joints: Sequence[Joint], prompter: Prompter, args: argparse.Namespace,
                 hints: Mapping[str, str]) -> None:
        """
        Take the joints to calibrate, the prompts, the command's arguments.

        hints: what a direction prompt says of each joint's positive direction (by name).
        """
        self.joints = list(joints)
        self.prompter = prompter
        self.args = args
        self.out = prompter.out
        self.changes: Dict[str, Dict[str, object]] = {}
        self.hints = dict(hints)

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
        low, high = find_stops(joint, current_a, self.args.speed, self.say)
        margin = self.args.margin
        if high - low <= 2 * margin:
            raise ToolError(f'joint {joint.name!r}: its stops are {high - low:.3f} apart, '
                            f'no more than twice the margin ({margin:g})')
        self._limits(joint, low + margin, high - margin, low + margin, high - margin)
