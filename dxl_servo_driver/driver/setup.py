"""
Bringing servos to a known state: discovery, configuration, hold, mode switch, turns kept.

Configuration is applied and verified before anything moves: the model checked against the
file, EEPROM written only where it differs and read back, the RAM registers and the indirect
map written (the servo loses them at every reboot). A servo is enabled only once it holds
where it is (goal = present), and the whole turns the servo forgets when it re-initialises
Present Position are kept in the joint's turn offset. The long activities are steps
(generators, one transaction between two yields) that tasks.py or a synchronous caller runs.
"""

from typing import Any, Dict, Generator, List, Optional, Tuple

from dxl_servo_driver import models
from dxl_servo_driver.config import check_joint_against
from dxl_servo_driver.driver import state_block
from dxl_servo_driver.driver.adapter import settle_latency_timer
from dxl_servo_driver.driver.context import Context
from dxl_servo_driver.driver.servo import clamp_position, ManagerError, run, Servo
from dxl_servo_driver.driver.tasks import Steps
from dxl_servo_driver.errors import (
    CommError, CommTimeout, ConfigurationError, CorruptReply, PortError, StatusError)
from dxl_servo_driver.models import modes
from dxl_servo_driver.models.base import TORQUE_MODE
from dxl_servo_driver.protocol import RETURN_DELAY_UNIT_S

# Read at configure and kept: the bounds goals are clamped to (those the model has).
LIMIT_REGISTERS = ('min_position_limit', 'max_position_limit', 'velocity_limit',
                   'current_limit', 'pwm_limit')


class Setup:
    """Configuration, activation and mode switches of the servos, over the link."""

    def __init__(self, ctx: Context) -> None:
        self._ctx = ctx
        self._roster = ctx.roster
        self._link = ctx.link
        self._clock = ctx.clock
        self._log = ctx.log

    # configure ------------------------------------------------------------------------------
    def configure(self) -> None:
        """Find and verify every servo, apply its configuration, learn the return delay."""
        settle_latency_timer(self._ctx, self._roster.order)
        self._find_servos()
        for servo in self._roster.order:
            if servo.online:
                run(self.apply_configuration(servo))
                if servo.joint.trigger:
                    check_trigger(servo)
        self._set_return_delay()

    def _find_servos(self) -> None:
        missing = []
        for servo in self._roster.order:
            try:
                model_number = self._link.ping(servo)
            except (CommTimeout, CorruptReply) as exc:
                missing.append((servo, exc))
                continue
            self._take_model(servo, model_number)
            servo.online = True
            # The Protocol 1.0 tables have no such register: their status packets say it.
            errors = (self._link.read(servo, 'hardware_error_status')
                      if servo.model.has('hardware_error_status') else 0)
            if errors:
                self._log.warn(f'joint {servo.name!r} (id {servo.servo_id}) has hardware errors '
                               f'latched: {", ".join(servo.model.decode_hardware_errors(errors))} '
                               '(a reboot clears them)')
            self._log.info(f'found joint {servo.name!r}: id {servo.servo_id}, {servo.model.name} '
                           f'(model {model_number}), firmware {servo.firmware_version}, '
                           f'mode {servo.mode}')
        config = self._ctx.config
        for servo, failure in missing:
            message = (f'joint {servo.name!r}: servo id {servo.servo_id} did not answer '
                       f'{config.ping_retries} pings at {config.baud_rate} bps '
                       f'({failure}); check the id, the baud rate, the power and the cable')
            if config.missing_servo == 'refuse':
                raise ManagerError(message)
            self._log.warn(message + '; starting without it (missing_servo: skip)')
        if not self._roster.active():
            raise ManagerError('no configured servo answered')

    def _take_model(self, servo: Servo, model_number: int) -> None:
        """Choose the servo's table by the model and firmware it answered with, or refuse."""
        where = f'joint {servo.name!r}: id {servo.servo_id}'
        reason = models.unsupported_reason(model_number)
        if reason:
            raise ManagerError(f'{where}: {reason}')
        wanted = servo.joint.model
        if wanted is not None and wanted.number != model_number:
            other = models.model_for(model_number)
            raise ManagerError(f'{where} is a {other.name} (model {model_number}), but the '
                               f'configuration says {servo.joint.name}.model {wanted.name}; '
                               'refusing to drive it with another control table')
        # The firmware picks the table where it differs (X330): read it from the XM430 manual's
        # address, which every X-series table shares.
        servo.model_number = model_number
        servo.set_model(models.model_for(model_number))
        servo.firmware_version = self._link.read(servo, 'firmware_version')
        servo.set_model(models.model_for(model_number, servo.firmware_version))
        try:
            check_joint_against(servo.joint, servo.model)
        except ConfigurationError as exc:
            raise ManagerError(f'{where} is a {servo.model.name}: {exc}') from None

    def apply_configuration(self, servo: Servo) -> Steps:
        """Mode, EEPROM (only where it differs), RAM registers, indirect map; torque stays off."""
        link = self._link
        link.write(servo, 'torque_enable', 0)
        yield
        wanted = mode_registers(servo, servo.mode)
        wanted.update(servo.joint.register_dict())
        wanted.update(position_limit_registers(servo))
        for note in position_limit_notes(servo):
            self._log.info(note)
        changed = []
        for name, value in wanted.items():
            if servo.model.item(name).area != 'eeprom':
                continue
            current = link.read(servo, name)
            yield
            if current != value:
                link.write_verified(servo, name, value)
                changed.append(f'{name}={value}')
                yield
        if changed:
            self._log.info(f'joint {servo.name!r}: EEPROM written: {", ".join(changed)}')
        if servo.model.has('homing_offset'):
            servo.homing_offset = link.read(servo, 'homing_offset')
            yield
        yield from self._apply_ram(servo)

    def _apply_ram(self, servo: Servo) -> Steps:
        """RAM configuration, a mode kept in RAM, the indirect map (lost at every reboot)."""
        link = self._link
        ram_mode = [(name, value) for name, value in mode_registers(servo, servo.mode).items()
                    if servo.model.item(name).area == 'ram']   # the MX(1.0)'s torque control
        for name, value in [*servo.joint.registers, *ram_mode]:
            if servo.model.item(name).area == 'ram':
                link.write_verified(servo, name, value)
                yield
        slot = self._slot_for(servo, servo.mode)
        link.write_indirect_map(servo, slot)
        servo.goal_slot = slot   # checked by the first goals written through it (hold)
        yield
        for name in LIMIT_REGISTERS:
            if servo.model.has(name):
                servo.limits[name] = link.read(servo, name)
                yield

    def _slot_for(self, servo: Servo, mode: str) -> Optional[state_block.GoalSlot]:
        """Return the goal slot the servo's goals go through in a mode (None: per register)."""
        if self._ctx.config.write_mode != 'indirect' or servo.slot_refused:
            return None
        return state_block.goal_slot(servo.model, servo.block, mode)

    def _set_return_delay(self) -> None:
        delays = [self._link.read(servo, 'return_delay_time') for servo in self._roster.active()]
        bus = self._link.io()
        bus.return_delay_s = max(delays, default=250) * RETURN_DELAY_UNIT_S
        bus.least_return_delay_s = min(delays, default=0) * RETURN_DELAY_UNIT_S

    # hold and torque ------------------------------------------------------------------------
    def activate(self, servos: List[Servo]) -> None:
        """Goal = present for every servo, then torque on as torque_at_start says."""
        for servo in servos:
            servo.torque_wanted = torque_at_start(servo, self._ctx.config.torque_on_start)
            try:
                run(self.hold(servo))
            except (PortError, CommError) as exc:
                raise ManagerError(f'activation failed: {exc}') from None

    def hold(self, servo: Servo) -> Steps:
        """
        Make the servo hold where it is (per mode), then set torque as wanted.

        Torque on re-initialises Present Position within one turn (the XM430 manual), so in the
        position modes the goal written first must be in that frame: the servo is brought there
        first (CLEAR, or the manual's formula when it cannot clear), and the whole turns it
        loses are kept in the joint's turn offset. After torque on the position is read again,
        and a frame change nobody predicted is caught at once.

        A passive joint (torque: false) gets no goal and never torque, whoever asked; a trigger
        holds its rest position with its spring's current, not where it is.
        """
        link = self._link
        passive = not servo.joint.torque
        if passive:
            servo.torque_wanted = False
        torque = link.read(servo, 'torque_enable')
        yield
        present = link.read(servo, 'present_position')
        yield
        goal: Optional[int] = None
        if passive:
            pass   # it holds nothing: a goal would only wait for a torque it never gets
        elif servo.mode in modes.POSITION_MODES:
            if not torque and servo.torque_wanted:
                present = yield from self._into_one_turn(servo, present)
            goals = _holding_goals(servo, present)
            goal = goals['goal_position']
            yield from self._set_goals(servo, goals)
        else:
            register = modes.BY_NAME[servo.mode].holding_register
            # A mode change sets goal_current / goal_pwm to their limits: never enable with that.
            yield from self._set_goals(servo, {register: 0})
        if servo.torque_wanted and not torque:
            link.write(servo, 'torque_enable', 1)
            yield
            after = link.read(servo, 'present_position')
            yield
            if abs(after - present) >= servo.units.pulses_per_rev // 2:
                keep_turns(servo, present, after)
                if goal is not None:
                    goal = _holding_goals(servo, after)['goal_position']
                    yield from self._set_goals(servo, {'goal_position': goal})
            elif servo.joint.trigger:
                # A servo may take its present position as its goal at torque on (the
                # simulator does): the spring's rest is written again, with torque on.
                yield from self._set_goals(servo, _holding_goals(servo, after))
            elif goal is not None and servo.goal_slot is not None:
                # A servo may take its present position as its goal at torque on (the
                # simulator does): a goal slot repeats goal_position with other goals, so the
                # driver's record must be what the servo holds, not what was written before.
                servo.goal_raw['goal_position'] = link.read(servo, 'goal_position')
                yield
        elif not servo.torque_wanted and torque:
            link.write(servo, 'torque_enable', 0)
            yield
        servo.last_command_s = self._clock()
        servo.timed_out = False

    def _set_goals(self, servo: Servo, goals: Dict[str, int]) -> Steps:
        """
        Write goals at once: through the goal slot, read back, or register by register.

        Every hold is where the driver checks that the servo applies goals written through its
        slot: the slot's indirect entries are read back, and each goal register from its own
        address after the write. Any difference gives the slot up for that servo (a warning;
        its goals go register by register from then on). A goal equal to what the register
        held already cannot show a slot that does not work; the next hold checks again.
        """
        link = self._link
        servo.goal_raw.update(goals)
        slot = servo.goal_slot
        if slot is not None:
            wrong = []
            if not link.slot_mapped(servo, slot):
                wrong.append('its indirect entries do not read back as mapped')
            else:
                yield
                try:
                    link.write_slot(servo, slot)
                except StatusError as exc:
                    wrong.append(str(exc))
                yield
            for name in slot.registers if not wrong else ():
                back = link.read(servo, name)
                yield
                if back != servo.goal_raw[name]:
                    wrong.append(f'{name} reads {back} after {servo.goal_raw[name]} was written')
            if not wrong:
                return
            servo.goal_slot = None
            servo.slot_refused = True
            self._log.warn(f'joint {servo.name!r}: goals written through its indirect goal slot '
                           f'did not arrive ({"; ".join(wrong)}); its goals are written register '
                           'by register from now on')
        for name, value in goals.items():
            link.write(servo, name, value)
            yield

    def _into_one_turn(self, servo: Servo, present: int) -> Generator[Any, None, int]:
        """Bring Present Position within one turn before torque on; return its new value."""
        homing = servo.homing_offset
        if homing <= present < homing + servo.units.pulses_per_rev:
            return present
        try:
            self._link.clear_multi_turn(servo)
            yield
            after = self._link.read(servo, 'present_position')
            yield
        except StatusError:
            # CLEAR refused (the horn is moving, or an older firmware): torque on will do the
            # same re-initialisation, by the manual's formula.
            after = servo.units.reinit_position(present, homing)
        keep_turns(servo, present, after)
        return after

    # mode switch ----------------------------------------------------------------------------
    def switch_mode(self, servo: Servo, mode: str) -> Steps:
        """Torque off, the mode, what a mode change resets re-applied, hold (goals set aside)."""
        link = self._link
        link.write(servo, 'torque_enable', 0)
        yield
        before = link.read(servo, 'present_position')
        yield
        for name, value in mode_registers(servo, mode).items():
            link.write(servo, name, value)
            if name in LIMIT_REGISTERS:   # a Protocol 1.0 table's mode is its angle limits
                servo.limits[name] = value
            yield
        servo.mode = mode
        servo.goal_raw.clear()
        slot = self._slot_for(servo, mode)
        if slot is not None:
            link.write_slot_map(servo, slot)
            yield
        servo.goal_slot = slot
        after = link.read(servo, 'present_position')
        yield
        # A mode change re-initialises Present Position within one turn (the XM430 manual).
        if mode in modes.SINGLE_TURN:
            servo.turn_offset = 0
            yield from self._single_turn_homing(servo)
        else:
            keep_turns(servo, before, after)
        # The XM430 manual (Operating Mode, note 1): profiles, goal PWM/current and gains were
        # reset by the mode change; give back what the configuration set.
        for name, value in servo.joint.registers:
            if name in modes.RESET_BY_MODE_CHANGE:
                link.write_verified(servo, name, value)
                yield
        # The joint's own limits, now that the mode uses them (EEPROM: torque is off here).
        for name, value in position_limit_registers(servo, mode).items():
            if link.read(servo, name) != value:
                link.write_verified(servo, name, value)
            servo.limits[name] = value
            yield
        yield from self.hold(servo)

    def _single_turn_homing(self, servo: Servo) -> Steps:
        # Position mode ignores a homing offset beyond +-1024 (the XM430 manual): one left over
        # from another mode is put back to the configured one.
        ignored = servo.model.homing_position_mode_limit
        if ignored is None or not servo.model.has('homing_offset'):
            return
        offset = self._link.read(servo, 'homing_offset')
        yield
        if abs(offset) > ignored:
            self._link.write_verified(servo, 'homing_offset',
                                      servo.joint.register_dict().get('homing_offset', 0))
            yield

    def resync_mode(self, servo: Servo) -> None:
        """After a failure, believe the servo about its mode."""
        try:
            model = servo.model
            if model.mode_register:
                raw = self._link.read(servo, model.mode_register)
                numbers = {number: name for name, number in model.modes.items()}
                servo.mode = numbers.get(raw, servo.mode)
            else:
                servo.mode = model.angle_limit_mode(
                    self._link.read(servo, 'min_position_limit'),
                    self._link.read(servo, 'max_position_limit'),
                    self._link.read(servo, TORQUE_MODE) if model.has(TORQUE_MODE) else 0)
        except (PortError, CommError):
            pass


def keep_turns(servo: Servo, before_raw: int, after_raw: int) -> None:
    """Keep the joint's position continuous after the servo re-initialised its position."""
    if servo.mode in modes.SINGLE_TURN:
        servo.turn_offset = 0
        return
    servo.turn_offset += servo.units.kept_turns(before_raw, after_raw)


def torque_at_start(servo: Servo, torque_on_start: bool) -> bool:
    """Return whether a servo gets torque at activate: never passive, always a trigger."""
    if not servo.joint.torque:
        return False
    return True if servo.joint.trigger else torque_on_start


def _holding_goals(servo: Servo, present: int) -> Dict[str, int]:
    """Return the goals a position-mode servo holds with: where it is, or a trigger's rest."""
    if servo.joint.trigger:
        return {'goal_position': trigger_rest(servo), 'goal_current': trigger_current(servo)}
    goals = {'goal_position': clamp_position(servo, present)}
    if servo.mode == 'current_based_position':
        goals['goal_current'] = _cbp_current(servo)
    return goals


def trigger_rest(servo: Servo) -> int:
    """Return a trigger's Goal Position: its trigger_position in the servo's frame now."""
    raw = servo.units.position_from_rad(servo.joint.trigger_position) - servo.turn_offset
    return clamp_position(servo, raw)


def trigger_current(servo: Servo) -> int:
    """Return a trigger's Goal Current (raw): its trigger_current, within Current Limit."""
    limit = servo.limits.get('current_limit', servo.model.item('current_limit').initial)
    return max(0, min(limit, servo.units.current_from_a(servo.joint.trigger_current)))


def check_trigger(servo: Servo) -> None:
    """Refuse (ManagerError) a trigger its servo cannot be: no current, or above its limit."""
    joint = servo.joint
    if servo.units.a_per_current_raw is None or 'current' not in servo.units.kinds:
        raise ManagerError(f'joint {joint.name!r}: a trigger needs current control, which the '
                           f'{servo.model.name} has not')
    raw = servo.limits.get('current_limit', servo.model.item('current_limit').initial)
    limit_a = servo.units.current_to_a(raw)
    # Half a unit of slack: a limit given in A lands on the nearest raw value.
    if joint.trigger_current > limit_a + servo.units.a_per_current_raw / 2:
        raise ManagerError(f'joint {joint.name!r}: trigger_current {joint.trigger_current:g} A '
                           f"is above the {servo.model.name}'s Current Limit {limit_a:.4g} A "
                           f'(current_limit {raw}): lower it, or raise '
                           f'{joint.name}.registers.current_limit')


def _cbp_current(servo: Servo) -> int:
    """
    Return the goal current (the current limit) a current_based_position joint holds with.

    A mode change or a reboot sets goal_current to the servo's maximum; the joint gets back
    what it was last commanded, else what the configuration says, else current_limit.
    """
    limit = servo.limits.get('current_limit', servo.model.item('current_limit').initial)
    wanted = servo.goal_raw.get('goal_current',
                                servo.joint.register_dict().get('goal_current', limit))
    return max(-limit, min(limit, wanted))


def mode_registers(servo: Servo, mode: str) -> Dict[str, int]:
    """
    Return the registers (and values) that put a servo in a mode.

    Its mode register (Operating Mode; the XL-320's Control Mode), or on the Protocol 1.0
    tables, which have none, the CW/CCW Angle Limits (min/max_position_limit): both 0 is wheel
    (velocity) mode, both at the top of their range multi-turn (extended_position, the MX),
    anything else joint (position) mode within them (Model.angle_limit_mode reads them back).
    """
    model = servo.model
    if model.mode_register:
        return {model.mode_register: model.modes[mode]}
    torque = {TORQUE_MODE: 0} if model.has(TORQUE_MODE) else {}
    if mode == 'current':   # the MX-64/106 (1.0): its angle limits stay as they are
        return {TORQUE_MODE: 1}
    low, high = model.item('min_position_limit'), model.item('max_position_limit')
    if mode == 'velocity':
        return {**torque, 'min_position_limit': 0, 'max_position_limit': 0}
    if mode == 'extended_position':
        return {**torque, 'min_position_limit': low.maximum, 'max_position_limit': high.maximum}
    limits = {**torque, 'min_position_limit': low.initial, 'max_position_limit': high.initial}
    limits.update(position_limit_registers(servo, mode))
    return limits


def position_limit_registers(servo: Servo, mode: str = '') -> Dict[str, int]:
    """
    Return the Min/Max Position Limit a joint's min_position/max_position give its servo.

    Only in a single-turn position mode (the one that uses them; elsewhere the driver alone
    refuses goals beyond them), and only the ends the configuration gives. ManagerError when an
    end is beyond what the mode can reach.
    """
    return {register: raw for register, raw, _ in _position_limits(servo, mode)}


def position_limit_notes(servo: Servo) -> List[str]:
    """Return what the log says of a joint limit taken as the servo's end (one tick beyond)."""
    return [note for _, _, note in _position_limits(servo) if note]


def _position_limits(servo: Servo, mode: str = '') -> List[Tuple[str, int, str]]:
    """
    Return (register, raw, note) for position_limit_registers; ManagerError beyond reach.

    A joint limit within one tick beyond the register's range is that end of the range (the
    note says so): a full-turn joint's URDF limit of +-pi is raw 0 and 4096 through the frame,
    and 4096 is the same place as 4095 within the tick the servo can tell apart, which is how
    the official stacks take it. Farther is refused.
    """
    joint = servo.joint
    if (mode or servo.mode) not in modes.SINGLE_TURN:
        return []
    if joint.min_position is None and joint.max_position is None:
        return []
    ends = []
    # A reversed joint's lowest position is the servo's highest.
    for key, value in (('min_position', joint.min_position), ('max_position', joint.max_position)):
        if value is None:
            continue
        raw = servo.units.position_from_rad(value)
        register = ('min_position_limit' if (key == 'min_position') != joint.reverse
                    else 'max_position_limit')
        item = servo.model.item(register)
        note = ''
        end = min(max(raw, item.minimum), item.maximum)
        if abs(raw - end) == 1:
            note = (f'joint {joint.name!r}: {key} {value:g} is servo position {raw}, one tick '
                    f'beyond the {item.minimum}..{item.maximum} of {register}: taken as its '
                    f'end, {end}')
        elif raw != end:
            raise ManagerError(
                f'joint {joint.name!r}: {key} {value:g} is servo position {raw}, beyond the '
                f'{item.minimum}..{item.maximum} of {register} ({mode or servo.mode} mode turns '
                'once)')
        ends.append((register, end, note))
    return ends
