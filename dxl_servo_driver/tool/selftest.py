"""
`dxl selftest ID`: is this servo healthy? A verdict per check, exit 1 if any failed.

Checks, each PASS, FAIL or SKIP with the reason:

- hardware error: Hardware Error Status is 0 (else the bits set, by the model's names);
- voltage: Present Input Voltage within the model's Min/Max Voltage Limit items;
- temperature: Present Temperature below the Temperature Limit item;
- move +/-: a small move each way (--degrees, default 5) with little force: current-based
  position with a low Goal Current (--current, default 0.3 A, never above the Current Limit);
  on a model without that mode, position mode with a low Goal PWM (or, Protocol 1.0, a low
  Torque Limit). The encoder must follow: Present Position reaches the goal within --tolerance
  degrees in MOVE_TIMEOUT_S, having moved the right way.

A latched hardware error keeps the torque off, so the moves are skipped then. Whatever
happens (a failure, an error, Ctrl-C), the operating mode, goals, limits and torque are restored
as they were; the servo is left where it started (within the tolerance).
"""

import argparse
from dataclasses import dataclass
import math
import time
from typing import List, Optional, Tuple

from dxl_servo_driver.tool.common import (
    add_command, EXIT_FAILED, EXIT_OK, EXIT_USAGE, ToolError)
from dxl_servo_driver.tool.session import (
    add_bus_arguments, bus_session, connect, from_si, read_present, read_retried,
    Saved, servo_ref, ServoLink, to_si, uninterrupted, write_retried)

PASS, FAIL, SKIP = 'PASS', 'FAIL', 'SKIP'
MOVE_TIMEOUT_S = 3.0
# What "little force" is when the servo has no current control: this share of full PWM.
LOW_PWM_RATIO = 0.3
LOW_TORQUE_RATIO = 0.3
SAVED = ('torque_enable', 'operating_mode', 'goal_current', 'goal_pwm', 'torque_limit',
         'goal_position', 'profile_velocity', 'profile_acceleration')


@dataclass
class Verdict:
    """One check's outcome."""

    check: str
    result: str
    reason: str

    def line(self) -> str:
        """Return the check's line."""
        return f'{self.result}  {self.check}: {self.reason}'


def check_errors(link: ServoLink) -> Verdict:
    """Return the verdict on Hardware Error Status."""
    if not link.model.has('hardware_error_status'):
        return Verdict('hardware error', SKIP, f'{link.model.name} has no Hardware Error Status')
    status = read_retried(link, 'hardware_error_status')
    if not status:
        return Verdict('hardware error', PASS, 'none latched')
    names = link.model.decode_hardware_errors(status) or [f'0x{status:02x}']
    return Verdict('hardware error', FAIL, f'latched: {", ".join(names)} (status 0x{status:02x};'
                   ' a reboot clears it once the cause is gone)')


def check_voltage(link: ServoLink) -> Verdict:
    """Return the verdict on the input voltage against the model's limits."""
    model = link.model
    names = ('present_input_voltage', 'min_voltage_limit', 'max_voltage_limit')
    if not all(model.has(name) for name in names):
        return Verdict('voltage', SKIP, f'{model.name} lacks {" or ".join(names)}')
    volts = read_retried(link, 'present_input_voltage') * model.voltage_unit_v
    low = read_retried(link, 'min_voltage_limit') * model.voltage_limit_unit_v
    high = read_retried(link, 'max_voltage_limit') * model.voltage_limit_unit_v
    if low <= volts <= high:
        return Verdict('voltage', PASS, f'{volts:.1f} V within {low:.1f}..{high:.1f} V')
    side = 'below' if volts < low else 'above'
    return Verdict('voltage', FAIL, f'{volts:.1f} V is {side} the limits {low:.1f}..{high:.1f} V '
                   '(check the supply)')


def check_temperature(link: ServoLink) -> Verdict:
    """Return the verdict on the temperature against the model's limit."""
    model = link.model
    if not (model.has('present_temperature') and model.has('temperature_limit')):
        return Verdict('temperature', SKIP, f'{model.name} has no temperature limit to check')
    degrees = read_retried(link, 'present_temperature')
    limit = read_retried(link, 'temperature_limit')
    if degrees < limit:
        return Verdict('temperature', PASS, f'{degrees} degC below the limit {limit} degC')
    return Verdict('temperature', FAIL, f'{degrees} degC at or above the limit {limit} degC '
                   '(let it cool)')


def _limit_force(link: ServoLink, current_a: float) -> Tuple[str, str]:
    """Set a mode and a low force for the moves; return (mode, how the force is limited)."""
    model = link.model
    if 'current_based_position' in model.modes and model.has('goal_current'):
        limit_raw = (read_retried(link, 'current_limit') if model.has('current_limit')
                     else link.item('goal_current').maximum)
        item = link.item('goal_current')
        raw = max(1, min(from_si(model, item, current_a), limit_raw))
        if read_retried(link, 'operating_mode') != model.modes['current_based_position']:
            write_retried(link, 'torque_enable', 0)
            write_retried(link, 'operating_mode', model.modes['current_based_position'])
        write_retried(link, 'goal_current', raw)
        amps = to_si(model, item, raw)[0]
        return 'current_based_position', f'Goal Current {amps:.3f} A'
    if 'position' in model.modes and model.mode_register == 'operating_mode':
        if read_retried(link, 'operating_mode') != model.modes['position']:
            write_retried(link, 'torque_enable', 0)
            write_retried(link, 'operating_mode', model.modes['position'])
    if model.has('goal_pwm'):
        raw = max(1, int(link.item('goal_pwm').maximum * LOW_PWM_RATIO))
        write_retried(link, 'goal_pwm', raw)
        return 'position', f'Goal PWM {raw} ({LOW_PWM_RATIO:.0%}; no current control)'
    if model.has('torque_limit'):
        raw = max(1, int(link.item('torque_limit').maximum * LOW_TORQUE_RATIO))
        write_retried(link, 'torque_limit', raw)
        return 'position', f'Torque Limit {raw} ({LOW_TORQUE_RATIO:.0%}; no current control)'
    return '', f'{model.name} has no way to limit its force here'


def _move(link: ServoLink, goal_raw: int, toward: int, tolerance_raw: int,
          start_raw: int) -> Tuple[bool, str]:
    """Move to goal_raw; return (the encoder followed, what happened)."""
    write_retried(link, 'goal_position', goal_raw)
    begun = time.monotonic()
    position = start_raw
    while time.monotonic() - begun < MOVE_TIMEOUT_S:
        position = read_present(link)
        if abs(position - goal_raw) <= tolerance_raw:
            return True, f'reached within {time.monotonic() - begun:.2f} s'
    moved = position - start_raw
    if moved * toward <= 0:
        return False, (f'the encoder did not follow: moved {moved:+d} pulses toward a goal '
                       f'{goal_raw - start_raw:+d} away (stuck, blocked or the encoder)')
    return False, (f'stopped {abs(goal_raw - position)} pulses short after {MOVE_TIMEOUT_S:.0f} s '
                   '(too little force for the load, or blocked)')


def check_moves(link: ServoLink, args: argparse.Namespace, errors: Verdict) -> List[Verdict]:
    """Return the verdicts of the small moves each way."""
    names = ('move +', 'move -')
    if errors.result == FAIL:
        return [Verdict(name, SKIP, 'a hardware error is latched: torque stays off')
                for name in names]
    model = link.model
    if not (model.has('goal_position') and model.has('present_position')
            and model.has('torque_enable')):
        return [Verdict(name, SKIP, f'{model.name} has no position control') for name in names]
    mode, force = _limit_force(link, args.current)
    if not mode:
        return [Verdict(name, SKIP, force) for name in names]
    per_rad = model.pulses_per_rev / (2.0 * math.pi)
    step_raw = max(1, int(round(math.radians(args.degrees) * per_rad)))
    tolerance_raw = max(1, int(round(math.radians(args.tolerance) * per_rad)))
    start_raw = read_present(link)
    if mode == 'position' and model.has('max_position_limit'):
        low = read_retried(link, 'min_position_limit')
        high = read_retried(link, 'max_position_limit')
        if not (low <= start_raw - step_raw and start_raw + step_raw <= high):
            return [Verdict(name, SKIP, f'the servo is within {args.degrees:g} deg of its '
                            'position limits') for name in names]
    for name in ('profile_velocity', 'profile_acceleration'):
        if model.has(name):
            write_retried(link, name, 0)
    write_retried(link, 'goal_position', start_raw)
    write_retried(link, 'torque_enable', 1)
    verdicts = []
    for name, sign in zip(names, (1, -1)):
        ok, what = _move(link, start_raw + sign * step_raw, sign, tolerance_raw, start_raw)
        verdicts.append(Verdict(name, PASS if ok else FAIL,
                                f'{sign * args.degrees:+g} deg with {force}: {what}'))
        _move(link, start_raw, -sign, tolerance_raw, start_raw + sign * step_raw)
    return verdicts


def run(args: argparse.Namespace) -> int:
    """Run every check; print a verdict line each; 1 if any failed."""
    if not 0.0 < args.degrees <= 45.0:
        raise ToolError('--degrees must be in (0, 45]', EXIT_USAGE)
    if not 0.0 < args.current <= 100.0:
        raise ToolError('--current must be in (0, 100] A', EXIT_USAGE)
    if not 0.0 < args.tolerance < args.degrees:
        raise ToolError('--tolerance must be above 0 and below --degrees', EXIT_USAGE)
    with bus_session(args) as bus:
        link = connect(bus, args.id)
        print(f'id {args.id}: {link.model.name}, firmware {link.firmware}, {bus.baud_bps} bps')
        verdicts: List[Verdict] = []
        saved: Optional[Saved] = None
        try:
            errors = check_errors(link)
            for verdict in (errors, check_voltage(link), check_temperature(link)):
                verdicts.append(verdict)
                print(verdict.line(), flush=True)
            saved = Saved(link, SAVED)
            for verdict in check_moves(link, args, errors):
                verdicts.append(verdict)
                print(verdict.line(), flush=True)
        finally:
            if saved is not None:
                with uninterrupted():
                    saved.restore()
    failed = [verdict.check for verdict in verdicts if verdict.result == FAIL]
    skipped = sum(1 for verdict in verdicts if verdict.result == SKIP)
    if failed:
        print(f'selftest: FAIL ({", ".join(failed)})')
        return EXIT_FAILED
    print(f'selftest: PASS ({len(verdicts) - skipped} passed, {skipped} skipped)')
    return EXIT_OK


def register(subparsers: 'argparse._SubParsersAction[argparse.ArgumentParser]') -> None:
    """Add `dxl selftest`."""
    parser = add_command(
        subparsers, 'selftest', 'hardware errors, voltage, temperature, a small move each way',
        __doc__.strip().splitlines()[0],
        'dxl selftest 1 --port /dev/ttyUSB0 --baud 1000000 --current 0.2',
        'dxl selftest shoulder --params my_arm.yaml')
    parser.add_argument('id', type=servo_ref, metavar='ID',
                        help="servo id (or, with --params, its joint's name)")
    parser.add_argument('--degrees', type=float, default=5.0,
                        help='how far each move goes (default 5)')
    parser.add_argument('--current', type=float, default=0.3, metavar='A',
                        help="goal current of the moves (default 0.3 A; at most the servo's "
                        'Current Limit)')
    parser.add_argument('--tolerance', type=float, default=1.0, metavar='DEG',
                        help='how close a move must come (default 1 degree)')
    add_bus_arguments(parser)
    parser.set_defaults(run=run)
