"""
`dxl calibrate --find-stops`: a joint's servo finds its hard stops with its own motor.

In current-based position mode, at a slow profile velocity, with its goal current at the most
the user allows (never above its Current Limit), the servo drives one way until it stalls
(velocity ~0, current near the goal for a while): a stop. It backs off, then goes the other
way. Torque off after, its mode, goal current, profile and Drive Mode as they were.
"""

import math
import sys
import time
from typing import Callable, List, Optional, Tuple

from dxl_servo_driver.errors import CommError
from dxl_servo_driver.models import modes
from dxl_servo_driver.models.registers import time_based
from dxl_servo_driver.models.units import units_for
from dxl_servo_driver.tool.calibrate_servos import Joint, live, put, torque_on_holding
from dxl_servo_driver.tool.common import EXIT_USAGE, ToolError
from dxl_servo_driver.tool.session import from_si, ServoLink

__all__ = ['find_stops']

DEFAULT_BACKOFF = 0.1        # rad: how far it backs off a stop
DEFAULT_TRAVEL = 2 * math.pi   # rad: the farthest it looks for a stop each way
# A stall: velocity under this many profile-velocity units (0.229 rpm on an X) ...
STALL_VELOCITY_RAW = 2
# ... with Present Current at this share of the goal current, for this long.
STALL_CURRENT_SHARE = 0.8
STALL_TIME_S = 0.3


def find_stops(joint: Joint, current_a: float, speed: float,
               say: Callable[[str], None]) -> Tuple[float, float]:
    """Find the joint's hard stops with its own motor; return them in joint units, low first."""
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
    say(f'{joint.name}: finding its stops at {goal_current * model.current_unit_a:.3g} '
        f'A, {speed:g} rad/s (Ctrl-C stops it)')
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
        put(link, 'profile_velocity', max(1, from_si(model, velocity, speed)))
        turns = torque_on_holding(link)
        pulses = model.pulses_per_rev / (2.0 * math.pi)
        for direction in (-1, 1):
            stop, seen = _push(link, direction, goal_current, turns, pulses, speed)
            peak = max(peak, seen)
            stops.append(stop)
            back = int(round((stop - turns) - direction * DEFAULT_BACKOFF * pulses))
            put(link, 'goal_position', back)
            _settle(link, back, speed)
    finally:
        try:
            put(link, 'torque_enable', 0)
            for name, value in saved.items():
                put(link, name, value)
        except CommError as exc:
            print(f'dxl calibrate: id {link.servo_id}: could not restore its mode: {exc}',
                  file=sys.stderr)
    say(f'  {joint.name}: peak current {peak * model.current_unit_a:.3g} A (limit '
        f'{goal_current * model.current_unit_a:.3g} A)')
    if joint.config.operating_mode in modes.SINGLE_TURN:   # as the node will count
        homing = link.read('homing_offset') if model.has('homing_offset') else 0
        stops = [units_for(model).reinit_position(raw, homing) for raw in stops]
    low, high = sorted(joint.joint_value((raw - model.position_zero_raw) / pulses)
                       for raw in stops)
    say(f'  {joint.name}: stops at {low:+.4f} and {high:+.4f}')
    return low, high


def _push(link: ServoLink, direction: int, goal_current: int, turns: int,
          pulses: float, speed: float) -> Tuple[int, int]:
    """Drive one way until a stall; return the position there (raw, turns kept), peak."""
    start = live(link, 'present_position')
    target = int(round(start + direction * DEFAULT_TRAVEL * pulses))
    put(link, 'goal_position', target)
    stalled_since: Optional[float] = None
    peak = 0
    speed_s = max(speed, 0.01)
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


def _settle(link: ServoLink, goal: int, speed: float) -> None:
    """Wait (a few seconds at most) until the servo is near goal."""
    deadline = time.monotonic() + 3.0 + DEFAULT_BACKOFF / max(speed, 0.01)
    while time.monotonic() < deadline:
        if abs(live(link, 'present_position') - goal) < 10:
            return
        time.sleep(0.02)
