"""
The requests of the node's services: goals written at once, torque, mode, reboot, registers.

Each takes the manager's lock for its bus work (the cycle waits meanwhile), refuses with the
reason and writes nothing when the request cannot be done as it stands, and answers a failed
transaction with a message rather than an exception; a lost port is handled on the way.
"""

import functools
from typing import Any, Callable, List, Optional, Sequence

from dxl_servo_driver import models
from dxl_servo_driver.driver.context import Context
from dxl_servo_driver.driver.cycle import Cycle
from dxl_servo_driver.driver.goals import Goals
from dxl_servo_driver.driver.port_watch import PortWatch
from dxl_servo_driver.driver.recovery import Recovery
from dxl_servo_driver.driver.servo import clamp_position, Result, run, Servo
from dxl_servo_driver.driver.setup import position_limit_registers, Setup
from dxl_servo_driver.driver.tasks import Task
from dxl_servo_driver.errors import BadRequest, CommError, Interrupted, PortError, Refused
from dxl_servo_driver.models import modes
from dxl_servo_driver.models import registers


def _answers(method: Callable[..., Result]) -> Callable[..., Result]:
    """Answer a request refused (BadRequest, Refused) with the reason rather than raise."""
    @functools.wraps(method)
    def answered(*args: Any, **kwargs: Any) -> Result:
        try:
            return method(*args, **kwargs)
        except Refused as exc:
            return Result(False, str(exc))
    return answered


class Services:
    """Requests on named joints, serialised with the cycle by the manager's lock."""

    def __init__(self, ctx: Context, setup: Setup, goals: Goals, cycle: Cycle,
                 recovery: Recovery, ports: PortWatch) -> None:
        self._lock = ctx.lock
        self._roster = ctx.roster
        self._link = ctx.link
        self._setup = setup
        self._goals = goals
        self._cycle = cycle
        self._recovery = recovery
        self._tasks = ctx.tasks
        self._port = ctx.port
        self._ports = ports

    @_answers
    def command_now(self, kind: str, names: Sequence[str], values: Sequence[float]) -> Result:
        """Write goals at once (service path): answered after they were written."""
        with self._lock:
            result = self._goals.command(kind, names, values)
            if not result.success:
                return result
            try:
                self._cycle.write_pending()
            except PortError as exc:
                self._ports.lose(exc)
                return Result(False, f'goals not written: {exc}')
            except CommError as exc:
                return Result(False, f'goals not written: {exc}')
            return Result(True, f'{len(names)} {kind} goals written')

    def _servos_named(self, names: Sequence[str], one: bool = False) -> List[Servo]:
        if self._port.lost:
            raise Refused(f'the port is lost ({self._port.error}); try again when it is back')
        if not names:
            servos = self._roster.active()
        else:
            servos = []
            for name in names:
                servo = self._roster.by_name.get(name)
                if servo is None:
                    raise BadRequest(f'unknown joint {name!r}')
                if servo.joint.secondary_of and not one:
                    raise BadRequest(f'{name!r} is the second servo of joint '
                                     f'{servo.joint.secondary_of!r}: name the joint')
                if not servo.online:
                    raise BadRequest(f'joint {name!r} is not on the bus')
                servos.append(servo)
            # A joint's two servos are enabled, switched, rebooted and disabled together.
            if not one:
                servos = [servo for servo in self._roster.with_secondaries(servos)
                          if servo.online]
        for servo in servos:
            if servo.name in self._tasks:
                raise Refused(f'joint {servo.name!r} is {servo.status or "busy"}: try again in a '
                              'moment')
        return servos

    def _one_named(self, name: str) -> Servo:
        if not name:
            raise BadRequest('no joint named')
        # One servo (a register service): a joint's second servo may be named on its own.
        return self._servos_named([name], one=True)[0]

    def _request(self, what: str, action: Callable[[], Result]) -> Result:
        """Run a service's bus work: a lost port is handled, a bus failure is the answer."""
        try:
            return action()
        except PortError as exc:
            self._ports.lose(exc)
            return Result(False, f'{what} failed: {exc}')
        except Interrupted:
            return Result(False, f'{what} interrupted: the node is stopping')

    @_answers
    def set_torque(self, names: Sequence[str], enable: bool) -> Result:
        """Torque on (goal = present first) or off."""
        with self._lock:
            servos = self._servos_named(names)
            word = 'on' if enable else 'off'
            if enable:
                servos = _torqued(servos, named=bool(names))

            def action() -> Result:
                try:
                    for servo in servos:
                        servo.torque_wanted = enable
                        self._goals.drop(servo)
                        if enable:
                            run(self._setup.hold(servo))
                        else:
                            self._link.write(servo, 'torque_enable', 0)
                    if enable:
                        self._join_pairs(servos)
                except CommError as exc:
                    return Result(False, f'torque {word} failed: {exc}')
                return Result(True, f'torque {word} for {", ".join(s.name for s in servos)}')
            return self._request(f'torque {word}', action)

    def _join_pairs(self, servos: Sequence[Servo]) -> None:
        """Send each second servo just enabled to where its joint's first servo is."""
        for servo in servos:
            joint = servo.joint.secondary_of
            first = self._roster.by_name.get(joint) if joint else None
            if first is None or servo.mode not in modes.POSITION_MODES:
                continue
            present = self._link.read(first, 'present_position')
            goal = clamp_position(servo, servo.units.position_from_rad(first.position_rad(present))
                                  - servo.turn_offset)
            self._link.write(servo, 'goal_position', goal)
            servo.goal_raw['goal_position'] = goal

    @_answers
    def set_operating_mode(self, names: Sequence[str], mode: str) -> Result:
        """Torque off, mode, what a mode change resets re-applied, goal = present, torque back."""
        with self._lock:
            if mode not in modes.BY_NAME:
                raise BadRequest(f'unknown operating mode {mode!r} (one of '
                                 f'{", ".join(modes.NAMES)})')
            if not names:
                raise BadRequest('no joint named')
            servos = self._servos_named(names)
            for servo in servos:
                if servo.joint.trigger and mode != 'current_based_position':
                    raise BadRequest(f'{servo.joint.refusal()}; it springs back with a limited '
                                     f'current in current_based_position, not {mode}')
                if mode not in servo.model.modes:
                    raise BadRequest(f'joint {servo.name!r} is a {servo.model.name}, which has '
                                     f'no {mode} mode (its modes: '
                                     f'{", ".join(servo.model.modes)})')
                # Limits the new mode cannot hold refuse the switch before anything changes.
                position_limit_registers(servo, mode)
            done: List[str] = []

            def action() -> Result:
                try:
                    for servo in servos:
                        # Commands wait while it switches: its goals would be in the old mode.
                        self._goals.suspend(servo)
                        run(self._setup.switch_mode(servo, mode))
                        done.append(servo.name)
                except CommError as exc:
                    for servo in servos:
                        self._setup.resync_mode(servo)
                    return Result(False, f'mode change failed after {done or "no joint"}: {exc}')
                finally:
                    for servo in servos:
                        servo.switching = False
                return Result(True, f'{", ".join(done)} now in {mode} mode')
            return self._request('mode change', action)

    @_answers
    def reboot(self, names: Sequence[str], wait: Optional[Callable[[List[Task]], None]] = None
               ) -> Result:
        """
        Reboot, then configuration and mode restored, holding where it is, torque as it was.

        The reboots run as tasks the cycle steps through (the others are read and published
        meanwhile); wait(tasks) blocks until they ended. Without wait (nobody else runs the
        cycle), they run here to their end.
        """
        with self._lock:
            servos = self._servos_named(names)
            # A joint named twice is rebooted once.
            servos = list({servo.name: servo for servo in servos}.values())
            tasks = self._recovery.start_reboots(servos)
            if wait is None:
                self._recovery.run_to_end(tasks)
        if wait is not None:
            wait(tasks)
        with self._lock:
            failed = [f'{t.joint}: {t.error}' for t in tasks if t.error is not None]
            for task in tasks:
                if task.error is None:
                    continue
                # A servo whose reboot failed part-way may be unconfigured.
                if isinstance(task.error, PortError):
                    self._ports.lose(task.error)
                else:
                    self._recovery.restore_later(self._roster.by_name[task.joint])
            self._cycle.want_full()
        if failed:
            return Result(False, 'reboot failed: ' + '; '.join(failed))
        return Result(True, f'rebooted and restored {", ".join(s.name for s in servos)}')

    @_answers
    def read_register(self, name: str, register: str) -> Result:
        """Read one register by snake_case name or decimal address (Result.value: the value)."""
        with self._lock:
            servo = self._one_named(name)
            item = _register(servo.model, register)
            try:
                value = self._link.read(servo, item.name)
            except PortError as exc:
                self._ports.lose(exc)
                return Result(False, str(exc))
            except CommError as exc:
                return Result(False, str(exc))
            return Result(True, f'{name}.{item.name} (address {item.address}) = {value}', value)

    @_answers
    def write_register(self, name: str, register: str, value: int) -> Result:
        """Write one register; EEPROM while torque is on is refused with the reason."""
        with self._lock:
            servo = self._one_named(name)
            item = _register(servo.model, register)
            try:
                registers.writable_register(servo.model, item.name, runtime=True)
                # A profile register's range is the Drive Mode's: judged below, once read.
                registers.check_range(item, value, servo.model)
            except ValueError as exc:
                return Result(False, str(exc))
            undriven = servo.joint.refusal()
            if undriven and item.name in modes.GOAL_REGISTERS.values():
                # Goal Current and Goal PWM are open to writes: not a passive joint's (it is
                # never driven) nor a trigger's (they are its spring's).
                return Result(False, f'{undriven}: {item.name} is not written to it')
            link = self._link

            def action() -> Result:
                try:
                    context = dict(servo.limits)
                    context['homing_offset'] = servo.homing_offset
                    for other in registers.related_registers(servo.model, item.name):
                        if other not in context:
                            context[other] = link.read(servo, other)
                    registers.check_register_set(servo.model, context, item.name, value,
                                                 servo.mode)
                    if item.area == 'eeprom' and link.read(servo, 'torque_enable'):
                        return Result(False, f'{item.name} is in EEPROM, which the servo locks '
                                      'while torque is on: call set_torque with enable=false '
                                      'first')
                    link.write(servo, item.name, value)
                except ValueError as exc:
                    return Result(False, str(exc))
                except CommError as exc:
                    return Result(False, str(exc))
                if item.name in servo.limits:
                    servo.limits[item.name] = value
                # A goal slot writes its registers whole: it must carry this value from now on.
                self._goals.note_written(servo, item.name, value)
                return Result(True, f'{name}.{item.name} (address {item.address}) = {value}')
            return self._request('write', action)


def _torqued(servos: List[Servo], named: bool) -> List[Servo]:
    """
    Return the servos a torque-on takes: passive joints refused by name, or left out.

    Named, a passive joint refuses the request whole (nothing is written); all joints (no
    name) are every joint but the passive ones, refused when that leaves none.
    """
    passive = [servo for servo in servos if not servo.joint.torque]
    if named and passive:
        raise BadRequest(f'{passive[0].joint.refusal()}: it is never torqued')
    left = [servo for servo in servos if servo.joint.torque]
    if not left:
        raise BadRequest('every joint is passive (torque: false): none is ever torqued')
    return left


def _register(table: models.Model, key: str) -> models.Item:
    key = key.strip()
    try:
        return table.lookup(int(key) if key.isascii() and key.isdigit() else key)
    except KeyError as exc:
        raise BadRequest(str(exc.args[0])) from None
