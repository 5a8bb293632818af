"""
The goal queue: commands checked, converted, clamped and queued, never written here.

A command is refused whole (nothing queued) when any of its goals is wrong, converted with the
servo's units into the joint's frame (turns kept), clamped to the servo's limits with a
warning, and queued per register; the latest goal per joint wins. Whoever writes the goals
takes them all at once (take). Streamed velocity, current and PWM goals fall back to zero when
no command came for command_timeout (the deadman).

Commands take only the queue's own small lock, never the manager's, so a command arriving
during the cycle's read is queued at once and goes out in that cycle's write. Order when both
are needed: the manager's lock, then this one.
"""

import math
import threading
from typing import Callable, Dict, List, Optional, Sequence, Tuple, TypeVar

from dxl_servo_driver.driver.context import Context
from dxl_servo_driver.driver.servo import (
    clamp_position, IDX_POSITION, IDX_VELOCITY, Result, Servo, Throttle)
from dxl_servo_driver.errors import BadRequest, Refused
from dxl_servo_driver.models import modes

Goal = Tuple[Servo, str, int]   # the servo, its goal register, the raw value
# How far ahead, in cycles at its present velocity, check_ranges looks for a joint's end.
LOOKAHEAD_CYCLES = 2.0
# ... and for a joint driven by current or PWM, which must be braked, not merely given zero.
TORQUE_LOOKAHEAD_CYCLES = 4.0
# Slower than this (joint units per second), a joint braked at its end is at rest.
REST_RAD_S = 0.05
Pending = Dict[str, Dict[int, int]]   # register -> {servo id: raw goal}
T = TypeVar('T')


class Goals:
    """The goals queued since the last write."""

    def __init__(self, ctx: Context) -> None:
        self._ctx = ctx
        self.lock = threading.Lock()
        self._pending: Pending = {}
        self._roster = ctx.roster
        self._tasks = ctx.tasks   # joints with a task in progress take no goals
        self._port = ctx.port
        self._clock = ctx.clock
        self._warn = ctx.log.warn
        self._warn_throttled = Throttle(ctx.log.warn, clock=ctx.clock)
        # The servos a configured range bounds (check_ranges), whatever mode they are in now;
        # a joint's second servo judges the joint by its own reading.
        self._ranged = tuple(servo for servo in ctx.roster.order
                             if servo.joint.position_limits() != (None, None)
                             and not servo.joint.refusal())   # never driven: never stopped
        # One commander at a time: joints a commander holds (a follower's, while it follows)
        # take only its goals; anyone else's are refused with why (joint -> (owner, why)).
        self.held: Dict[str, Tuple[str, str]] = {}

    def check(self, kind: str, names: Sequence[str], values: Sequence[float],
              owner: str = '') -> List[Goal]:
        """
        Validate goals and convert them to raw register values, clamped to the servo's limits.

        Nothing is queued here: BadRequest for what the command says, Refused for what the
        joint or the port is doing now (or a joint held by a commander other than owner).
        """
        if kind not in modes.COMMAND_KINDS:
            raise BadRequest(f'unknown command kind {kind!r}')
        if len(names) == 0:
            raise BadRequest('empty command: no joint names')
        if len(names) != len(values):
            raise BadRequest(f'{len(names)} names but {len(values)} values: they must have '
                             'the same length')
        if len(set(names)) != len(names):
            raise BadRequest('a joint is named twice')
        if self._port.lost:
            raise Refused(f'the port is lost ({self._port.error}): no goal can be written')
        goals = []
        for name, value in zip(names, values):
            servo = self._roster.by_name.get(name)
            if servo is None:
                raise BadRequest(f'unknown joint {name!r}')
            held = self.held.get(name)
            if held is not None and held[0] != owner:
                raise Refused(f'joint {name!r} {held[1]}')
            if servo.joint.secondary_of:
                raise BadRequest(f'{name!r} is the second servo of joint '
                                 f'{servo.joint.secondary_of!r}: command the joint')
            if servo.joint.refusal():   # passive or a trigger: nobody commands it
                raise BadRequest(servo.joint.refusal())
            goals.extend(self._goal(servo, kind, value))
        return goals

    def _goal(self, servo: Servo, kind: str, value: float) -> List[Tuple[Servo, str, int]]:
        """Return one joint's goal as (servo, register, raw): its second servo's too."""
        name = servo.name
        if not math.isfinite(value):
            raise BadRequest(f'joint {name!r}: {value} is not a finite number')
        if abs(value) > 1e9:
            raise BadRequest(f'joint {name!r}: {value} is out of any range')
        if kind == 'position':
            low, high = servo.joint.position_limits()
            if (low is not None and value < low) or (high is not None and value > high):
                where = ('min_position, max_position and the travel gripper_open..'
                         'gripper_closed' if servo.joint.gripper else
                         'min_position, max_position')
                raise BadRequest(
                    f'joint {name!r}: position {value:g} is beyond its limits '
                    f'{low if low is not None else "-inf"}..'
                    f'{high if high is not None else "inf"} ({where})')
        second = self._roster.secondary.get(name)
        goals = []
        for target in (servo, second) if second is not None else (servo,):
            # The second servo is said as such: 'joint 'lift (secondary)' is rebooting'.
            which = target.name
            if not target.online:
                raise BadRequest(f'joint {which!r} is not on the bus (missing at configure)')
            if target.switching:
                raise Refused(f'joint {which!r} is changing its operating mode: try again')
            if target.name in self._tasks:
                raise Refused(f'joint {which!r} is {target.status or "busy"}: it takes goals '
                              'again once that is done')
            command = target.units.kinds.get(kind)
            if command is None:
                raise BadRequest(f'joint {which!r} is a {target.model.name}, which has no '
                                 f'{modes.GOAL_REGISTERS[kind]} register (no {kind} control); '
                                 f'its commands: {", ".join(sorted(target.units.kinds))}')
            if kind not in modes.BY_NAME[target.mode].commands:
                raise BadRequest(f'joint {which!r} is in {target.mode} mode: {kind} commands '
                                 'do not apply to it')
            offset = target.turn_offset if kind == 'position' else 0
            raw = command.to_raw(value) - offset
            clamped = _clamp(target, command.register, raw)
            end = self._end_ahead(target, clamped) if kind != 'position' else None
            if end is not None:
                self._warn_throttled(
                    f'end:{which}', f'joint {which!r} is at its {end}: a {kind} goal toward it '
                    'is held at zero until it is back within its range')
                clamped = 0
            elif clamped != raw:
                self._warn_throttled(
                    f'clamp:{which}:{kind}',
                    f'joint {which!r}: {kind} goal {value:g} {command.unit} clamped to '
                    f'{command.to_si(clamped + offset):g} {command.unit} (servo limit)')
            goals.append((target, command.register, clamped))
        return goals

    def command(self, kind: str, names: Sequence[str], values: Sequence[float],
                owner: str = '') -> Result:
        """Queue goals (all or none): written by the next write."""
        with self.lock:
            try:
                goals = self.check(kind, names, values, owner)
            except Refused as exc:
                return Result(False, str(exc))
            now = self._clock()
            for servo, register, raw in goals:
                self._queue(servo, register, raw)
                servo.last_command_s = now
                servo.timed_out = False
            return Result(True, f'{len(goals)} {kind} goals queued')

    def check_timeout(self) -> None:
        """Velocity, current and pwm goals fall back to zero after command_timeout."""
        timeout = self._ctx.config.command_timeout
        if timeout <= 0.0:
            return
        now = self._clock()
        with self.lock:
            for servo in self._roster.active():
                if servo.timed_out or servo.mode in modes.POSITION_MODES:
                    continue
                if now - servo.last_command_s > timeout:
                    register = modes.BY_NAME[servo.mode].holding_register
                    queued = self._pending.get(register, {})
                    if queued.get(servo.servo_id, servo.goal_raw.get(register, 0)) != 0:
                        self._queue(servo, register, 0)
                        self._warn(f'joint {servo.name!r}: no {servo.mode} command for '
                                   f'{timeout:g} s: goal set to zero')
                    servo.timed_out = True

    def check_ranges(self) -> None:
        """
        Stop a joint driven by velocity, current or PWM at the ends of its range.

        The servo keeps no position limit in those modes, so a joint with min_position or
        max_position would turn past them on a goal that never ends: at an end, or about to
        pass one before two more cycles at its present velocity, its goal toward that end is
        set to zero (a current or PWM goal reversed first, as a brake, until the joint is at
        rest); a new goal toward it is held at zero (check) until one away from it is taken.
        """
        if not self._ranged:
            return
        with self.lock:
            for servo in self._ranged:
                if (servo.mode in modes.POSITION_MODES or not servo.fresh or not servo.online
                        or servo.state is None):
                    continue
                register = modes.BY_NAME[servo.mode].holding_register
                goal = self._pending.get(register, {}).get(servo.servo_id,
                                                           servo.goal_raw.get(register, 0))
                if servo.at_end and servo.mode != 'velocity':
                    # A zero current or PWM lets the joint coast on: it is braked with the
                    # goal it was stopped with, reversed, until it is at rest.
                    outward_rad_s = (servo.units.velocity_to_rad_s(servo.state[IDX_VELOCITY])
                                     * servo.at_end)
                    brake = -servo.end_goal_raw if outward_rad_s > REST_RAD_S else 0
                    if goal != brake:
                        self._queue(servo, register, brake)
                    continue
                end = self._end_ahead(servo, goal)
                if end is not None:
                    servo.end_goal_raw = goal
                    self._queue(servo, register, 0 if servo.mode == 'velocity' else -goal)
                    self._warn_throttled(
                        f'end:{servo.name}', f'joint {servo.name!r} reached its {end} in '
                        f'{servo.mode} mode: stopped there until a goal away from it')

    def _end_ahead(self, servo: Servo, raw: int) -> Optional[str]:
        """
        Return the end (said) a goal drives the joint to, at or past it; None if none.

        A joint stopped at an end stays there (Servo.at_end) until a goal away from it is
        taken: it stopped a little short, and a goal toward the end must not creep it on.
        """
        low, high = servo.joint.position_limits()
        if (low is None and high is None) or servo.state is None or raw == 0:
            return None
        # The goal's direction in the joint's frame: a reversed joint turns against the servo.
        outward = 1 if raw * servo.units.frame.scale > 0 else -1
        if servo.at_end and outward != servo.at_end:
            servo.at_end = 0
            return None
        position = servo.position_rad(servo.state[IDX_POSITION])
        cycles = LOOKAHEAD_CYCLES if servo.mode == 'velocity' else TORQUE_LOOKAHEAD_CYCLES
        ahead = position + (servo.units.velocity_to_rad_s(servo.state[IDX_VELOCITY])
                            * cycles / self._ctx.config.loop_rate)
        if high is not None and outward > 0 and (servo.at_end > 0 or max(position, ahead) >= high):
            servo.at_end = 1
            return f'max_position {high:g}'
        if low is not None and outward < 0 and (servo.at_end < 0 or min(position, ahead) <= low):
            servo.at_end = -1
            return f'min_position {low:g}'
        return None

    def _queue(self, servo: Servo, register: str, value: int) -> None:
        # goal_raw is what was written: it changes when the writer takes the goal (a goal
        # dropped before, by torque off or a mode switch, never reaches it).
        self._pending.setdefault(register, {})[servo.servo_id] = value

    def waiting(self) -> bool:
        """Return True when goals (or what is left of them) wait to be written."""
        return bool(self._pending)

    def take(self, pack: Callable[[Pending], T]) -> T:
        """
        Hand the queued goals to pack() under the queue's lock and return what it makes of them.

        The queue starts empty; the servos' goal_raw take the values now (the writer sends
        them in this cycle), so pack sees every goal a slot repeats at its latest value.
        """
        with self.lock:
            pending, self._pending = self._pending, {}
            by_id = self._roster.by_id
            for register, goals in pending.items():
                for servo_id, value in goals.items():
                    by_id[servo_id].goal_raw[register] = value
            return pack(pending)

    def note_written(self, servo: Servo, register: str, value: int) -> None:
        """Record a goal register written outside the queue (write_register): slots repeat it."""
        with self.lock:
            if register in servo.goal_raw or (servo.goal_slot is not None
                                              and register in servo.goal_slot.needs):
                servo.goal_raw[register] = value

    def clear(self) -> None:
        """Drop every queued goal."""
        with self.lock:
            self._pending.clear()

    def drop(self, servo: Servo) -> None:
        """Drop the servo's queued goals."""
        with self.lock:
            for goals in self._pending.values():
                goals.pop(servo.servo_id, None)

    def suspend(self, servo: Servo) -> None:
        """Drop the servo's queued goals and refuse new ones until switching is cleared."""
        with self.lock:
            servo.switching = True
            for goals in self._pending.values():
                goals.pop(servo.servo_id, None)


def _clamp(servo: Servo, register: str, raw: int) -> int:
    if register == 'goal_position':
        return clamp_position(servo, raw)
    item = servo.model.item(register)
    if item.limit is None or item.limit not in servo.limits:
        # No register bounds it at run time (the AX's Moving Speed): its own range does.
        return min(max(raw, item.minimum), item.maximum)
    bound = servo.limits[item.limit]
    return min(max(raw, -bound), bound)
