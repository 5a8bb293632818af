"""
The manager: servos by joint name over one Bus, with batching and safety ordering.

It owns what the node must never get wrong: configuration applied and verified before anything
moves, goal = present before torque on, one packed read and one sync write per register per cycle,
refusals that write nothing, what a mode change resets re-applied, samples dated so a late reply
is never published as current, servos that restart on their own given their configuration back
step by step (never stalling the others), and every torque-on matched by a torque-off at the end.
No ROS here: the node calls these methods and publishes.
"""

from dataclasses import dataclass, field
import math
import struct
import threading
import time
from typing import Any, Callable, Dict, Generator, List, Optional, Sequence, Tuple

from dxl_servo_driver import control_table as ct
from dxl_servo_driver import model
from dxl_servo_driver import models
from dxl_servo_driver.bus import Bus, RawPort, SyncRead, SyncResult
from dxl_servo_driver.config import check_joint_against, DriverConfig, JointConfig
from dxl_servo_driver.errors import (
    CommError, CommTimeout, CorruptReply, Interrupted, PortError, Refused, StatusError)
from dxl_servo_driver.model import StateBlock, TickClock
from dxl_servo_driver.models.units import Units, units_for
from dxl_servo_driver.tasks import Steps, Task, TaskRunner
from dxl_servo_driver.transports import open_transport, PortFactory

Log = Callable[[str], None]
BLOCK = model.BLOCK_SHAPE   # decodes every model's block; where it lives is Servo.block
_I = BLOCK.index
IDX_POSITION = _I['present_position']
IDX_VELOCITY = _I['present_velocity']
IDX_EFFORT = _I['effort']   # present_current, or present_load on models without current
IDX_TICK = _I['realtime_tick']
IDX_PWM = _I['present_pwm']
IDX_VOLTAGE = _I['present_input_voltage']
IDX_TEMPERATURE = _I['present_temperature']
IDX_MOVING = _I['moving']
IDX_MOVING_STATUS = _I['moving_status']
IDX_HW_ERROR = _I['hardware_error_status']
IDX_TORQUE = _I['torque_enable']
IDX_CANARY = BLOCK.canary_index
WARN_INTERVAL_S = 2.0
STATUS_BYTES = 11   # status packet overhead
READ_BYTES = 14     # a READ instruction packet
_NO_HEALTH = (0,) * (len(BLOCK.names) - BLOCK.TAGGED_FIELDS)
BOOT_TIMEOUT_S = 3.0      # a rebooted servo must answer a ping within this
BOOT_POLL_S = 0.02        # between two pings of a booting servo
RETRY_BACKOFF_S = 0.5     # a failed restore is tried again after this
REJOIN_INTERVAL_S = 1.0   # a servo missing after the adapter came back is probed this often


# A changing register this close to the Realtime Tick is read with it, to date the reply.
DATED_SPAN_BYTES = 64


def _changes_by_itself(item: ct.Item) -> bool:
    """Return True for registers the servo changes (present values, tick, flags, errors)."""
    return item.area == 'ram' and (item.access == 'R' or item.name.startswith('indirect_data'))


# A servo that missed this many sync reads in a row is not retried on its own in a cycle.
SILENT_AFTER_FAILURES = 3


class ManagerError(Refused):
    """A failure the user must act on (missing servo, wrong model, port), said in one line."""


@dataclass
class Servo:
    """What the manager knows of one configured servo."""

    joint: JointConfig
    mode: str
    # The table, units and state block of the model it answered with at configure (before:
    # the configured model, or the seed's).
    model: models.Model
    units: Units
    block: StateBlock
    model_number: int = 0
    firmware_version: int = 0
    online: bool = False            # answered at configure (or since)
    state: Optional[Tuple[int, ...]] = None   # last good state block (raw)
    state_time: float = 0.0         # monotonic time of that read
    health_time: float = 0.0        # time of the last whole-block read (0 = health unknown)
    fresh: bool = False             # state was read in the latest cycle
    comm_errors: int = 0
    consecutive_failures: int = 0
    stale_refused: int = 0          # samples refused as older than their request
    torque_wanted: bool = False
    torque_maybe_on: bool = False   # a torque-on was sent and no torque-off confirmed since
    goal_raw: Dict[str, int] = field(default_factory=dict)   # last goal written, per register
    last_command_s: float = 0.0     # for command_timeout
    timed_out: bool = False
    limits: Dict[str, int] = field(default_factory=dict)
    homing_offset: int = 0          # the servo's Homing Offset, as last read or written
    # Whole turns (pulses) the driver adds to Present Position and takes from position goals,
    # so the joint's position stays continuous when the servo re-initialises it (torque on,
    # mode change, reboot, power cut). Always 0 in position mode (single turn).
    turn_offset: int = 0
    tick: TickClock = field(default_factory=TickClock)
    restarts: int = 0
    switching: bool = False         # a mode switch is under way: commands wait for it
    recoveries: int = 0
    last_recovery_s: float = -1e9
    status: str = ''                # what is being done to it (restoring, rebooting, ...)

    @property
    def name(self) -> str:
        """Return the joint name."""
        return self.joint.name

    @property
    def servo_id(self) -> int:
        """Return the servo id."""
        return self.joint.servo_id

    def joint_pulses(self, raw: int) -> int:
        """Return a Present Position value in the joint's continuous frame (turns kept)."""
        return raw + self.turn_offset

    def last_joint_pulses(self) -> Optional[int]:
        """Return the last position read, in the joint's frame; None if never read."""
        return self.state[IDX_POSITION] + self.turn_offset if self.state is not None else None

    def set_model(self, table: models.Model) -> None:
        """Take the table, units and state block of a model."""
        self.model = table
        self.units = units_for(table, self.joint.torque_constant_nm_per_a)
        self.block = model.state_block(table, self.units.effort_register)

    @classmethod
    def of(cls, joint: JointConfig) -> 'Servo':
        """Return the servo of a joint, with the configured model's table (or the seed's)."""
        table = joint.model or models.model_for(ct.MODEL_NUMBER)
        units = units_for(table, joint.torque_constant_nm_per_a)
        return cls(joint, joint.operating_mode, table, units,
                   model.state_block(table, units.effort_register))


@dataclass
class Result:
    """The outcome of a request: success and a message meant for a person."""

    success: bool
    message: str


class Throttle:
    """At most one message per key per interval."""

    def __init__(self, log: Log, interval_s: float = WARN_INTERVAL_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._log = log
        self._interval_s = interval_s
        self._clock = clock
        self._last: Dict[str, float] = {}

    def __call__(self, key: str, message: str) -> bool:
        """Log message unless the same key was logged within the interval; True if logged."""
        now = self._clock()
        last = self._last.get(key)
        if last is not None and now - last < self._interval_s:
            return False
        self._last[key] = now
        self._log(message)
        return True


@dataclass
class _Reading:
    """The cycle's sync read in flight."""

    stamp: float
    full: bool
    length: int
    pending: SyncRead


class Manager:
    """Servos by joint name on one bus."""

    def __init__(self, config: DriverConfig, info: Log = print, warn: Log = print,
                 error: Log = print, port_factory: PortFactory = open_transport,
                 clock: Callable[[], float] = time.monotonic,
                 should_stop: Callable[[], bool] = lambda: False) -> None:
        self.config = config
        self.info = info
        self.warn = warn
        self.error = error
        self.warn_throttled = Throttle(warn, clock=clock)
        self._port_factory = port_factory
        self._clock = clock
        # Asked between transactions at configure and activate: a signal stops them promptly.
        self.should_stop = should_stop
        self.bus: Optional[Bus] = None
        self.port: Optional[RawPort] = None
        self.sim_bus: Any = None   # the SimBus behind `port: sim`
        self.servos: Dict[str, Servo] = {
            joint.name: Servo.of(joint) for joint in config.joints}
        self.order: List[Servo] = [self.servos[joint.name] for joint in config.joints]
        # Serialises requests (services, topics, the cycle) over the manager's state.
        self.lock = threading.RLock()
        self._pending: Dict[str, Dict[int, int]] = {}   # register -> {servo id: raw goal}
        # Commands only queue: they take this small lock, never the bus lock above, so a
        # command arriving during a read is queued at once and goes out in this cycle's write.
        # Order when both are needed: self.lock, then _queue_lock.
        self._queue_lock = threading.Lock()
        self.tasks = TaskRunner(self._task_done, self._task_failed, clock)
        # Transactions outside the cycle are tried this many times (lost replies happen).
        self._attempts = max(1, config.ping_retries)
        self.cycles = 0
        self.read_failures = 0
        self.stale_refused = 0
        self.retries = 0
        self.retry_successes = 0
        self.recoveries = 0
        # Port loss: the cycle stops reading, the node stays up, reconnection is tried.
        self.port_lost = False
        self.port_error = ''
        self.reconnect_interval_s = 1.0
        self._next_reconnect_s = 0.0
        self.last_read_time = 0.0
        # How often the whole state block (health part too) is read; the node sets it from
        # state_rate and the 1 Hz diagnostics.
        self.health_period_s = 0.1
        self._last_full_s = -1e9
        self._need_full = True
        self._ids_cache: List[Tuple[Servo, int]] = []
        self._reading: Optional[_Reading] = None
        # The cycle's sync reads: (address, ids) per state-block layout; one on most buses.
        self._groups: List[Tuple[model.StateBlock, List[int]]] = []
        self._by_id: Dict[int, Servo] = {}

    # transactions outside the cycle -------------------------------------------------------
    def _io(self) -> Bus:
        if self.bus is None:
            raise CommError('the bus is not open (the node is not configured)')
        return self.bus

    def _try(self, action: Callable[[], Any]) -> Any:
        """Run a transaction, again on a lost or corrupted reply (self._attempts in all)."""
        for attempt in range(self._attempts):
            if self.should_stop():
                raise Interrupted('stop requested')
            try:
                return action()
            except (CommTimeout, CorruptReply):
                if attempt + 1 >= self._attempts:
                    raise

    def _read(self, servo: Servo, name: str) -> int:
        bus = self._io()
        item = servo.model.item(name)
        if not _changes_by_itself(item):
            # Confirmed by a second read: a late reply cannot pass for the value.
            return int(self._try(lambda: bus.read_item(servo.servo_id, item)))
        return int(self._try(lambda: self._read_dated_item(servo, item)))

    def _read_dated_item(self, servo: Servo, item: ct.Item) -> int:
        """Read a value that changes by itself with the Realtime Tick, refusing a late reply."""
        bus = self._io()
        tick = servo.model.item('realtime_tick')
        start = min(tick.address, item.address)
        end = max(tick.address + tick.size, item.address + item.size)
        if end - start > DATED_SPAN_BYTES:
            # Too far from the tick to read both in one go: the length tag is the guard.
            data = bus.read(servo.servo_id, item.address, item.size, confirm=False)
            return int.from_bytes(data, 'little', signed=item.signed)
        data, sent_s = bus.read_fresh(servo.servo_id, start, end - start)
        at = tick.address - start
        if not servo.tick.check(int.from_bytes(data[at:at + tick.size], 'little'), sent_s,
                                time.monotonic()):
            self._refuse_stale(servo)
            raise CorruptReply(f'id {servo.servo_id}: a reply older than its request '
                               '(refused)', servo.servo_id)
        at = item.address - start
        return int.from_bytes(data[at:at + item.size], 'little', signed=item.signed)

    def _write(self, servo: Servo, name: str, value: int) -> None:
        bus = self._io()
        item = servo.model.item(name)
        if name == 'torque_enable' and value:
            servo.torque_maybe_on = True   # before: the write may land even if its reply is lost
        self._try(lambda: bus.write_item(servo.servo_id, item, value))
        if name == 'torque_enable' and not value:
            servo.torque_maybe_on = False
        elif name == 'homing_offset':
            servo.homing_offset = value

    def _write_verified(self, servo: Servo, name: str, value: int) -> None:
        self._write(servo, name, value)
        read_back = self._read(servo, name)
        if read_back != value:
            raise CommError(f'joint {servo.name!r}: {name} reads back {read_back} after '
                            f'writing {value}', servo.servo_id)

    # configure / activate ---------------------------------------------------------------
    def configure(self) -> None:
        """Open the port, find and verify every servo, apply the configuration."""
        with self.lock:
            try:
                self.port, self.sim_bus = self._port_factory(self.config)
            except PortError as exc:
                raise ManagerError(str(exc)) from None
            self.bus = Bus(self.port, self.config.baud_rate,
                           latency_timer_s=self.config.latency_timer / 1000.0)
            self.port_lost = False
            try:
                self._find_servos()
                for servo in self.order:
                    if servo.online:
                        _run(self._apply_configuration(servo))
                self._set_return_delay()
                self._refresh_ids()
            except (PortError, CommError) as exc:
                raise ManagerError(f'configuration failed: {exc}') from None
            budget = self.bus_budget()
            self.info(
                f'bus limit for {len(self.active_servos())} servos at {self.config.baud_rate} bps '
                f'(return delay {self.bus.return_delay_s * 1e6:.0f} us, latency timer '
                f'{self.config.latency_timer:g} ms): {budget.rate_limit_hz:.0f} Hz '
                f'({budget.bytes_per_cycle} bytes per cycle)')
            if budget.rate_limit_hz < self.config.loop_rate:
                self.warn(f'loop_rate {self.config.loop_rate:g} Hz is above what the bus can '
                          f'carry ({budget.rate_limit_hz:.0f} Hz): running as fast as the bus '
                          'allows')

    def bus_budget(self) -> model.BusBudget:
        """Return what one cycle costs on this bus."""
        rdt_raw = int(round((self.bus.return_delay_s if self.bus else 0.0005) / 2e-6))
        return model.bus_budget(max(1, len(self.active_servos())), self.config.baud_rate,
                                rdt_raw, self.config.latency_timer / 1000.0)

    def active_servos(self) -> List[Servo]:
        """Return the servos that answered at configure."""
        return [servo for servo in self.order if servo.online]

    def _refresh_ids(self) -> None:
        # The hot path reads these instead of rebuilding lists every cycle. A servo with a task
        # in progress (being restored, rebooted, probed) is left out of the cycle's read.
        self._ids_cache = [(servo, servo.servo_id) for servo in self.active_servos()
                           if servo.name not in self.tasks]
        groups: Dict[Tuple[int, int], Tuple[model.StateBlock, List[int]]] = {}
        for servo, servo_id in self._ids_cache:
            block = servo.block
            groups.setdefault((block.read_address, block.size), (block, []))[1].append(servo_id)
        self._groups = sorted(groups.values(), key=lambda group: -len(group[1]))
        self._by_id = {servo.servo_id: servo for servo in self.order}

    def _find_servos(self) -> None:
        bus = self._io()
        missing = []
        for servo in self.order:
            try:
                model_number = int(self._try(lambda: bus.ping(servo.servo_id)))
            except (CommTimeout, CorruptReply) as exc:
                missing.append((servo, exc))
                continue
            self._take_model(servo, model_number)
            servo.online = True
            errors = self._read(servo, 'hardware_error_status')
            if errors:
                self.warn(f'joint {servo.name!r} (id {servo.servo_id}) has hardware errors '
                          f'latched: {", ".join(servo.model.decode_hardware_errors(errors))} '
                          '(a reboot clears them)')
            self.info(f'found joint {servo.name!r}: id {servo.servo_id}, {servo.model.name} '
                      f'(model {model_number}), firmware {servo.firmware_version}, '
                      f'mode {servo.mode}')
        for servo, failure in missing:
            message = (f'joint {servo.name!r}: servo id {servo.servo_id} did not answer '
                       f'{self.config.ping_retries} pings at {self.config.baud_rate} bps '
                       f'({failure}); check the id, the baud rate, the power and the cable')
            if self.config.missing_servo == 'refuse':
                raise ManagerError(message)
            self.warn(message + '; starting without it (missing_servo: skip)')
        if not self.active_servos():
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
        # The firmware picks the table where it differs (X330): read it from the seed's
        # address, which every X-series table shares.
        servo.model_number = model_number
        servo.set_model(models.model_for(model_number))
        servo.firmware_version = self._read(servo, 'firmware_version')
        servo.set_model(models.model_for(model_number, servo.firmware_version))
        problem = check_joint_against(servo.joint, servo.model)
        if problem:
            raise ManagerError(f'{where} is a {servo.model.name}: {problem}')

    def _apply_configuration(self, servo: Servo) -> Steps:
        """Mode, EEPROM (only where it differs), RAM registers, indirect map; torque stays off."""
        self._write(servo, 'torque_enable', 0)
        yield
        wanted = {'operating_mode': servo.model.modes[servo.mode]}
        wanted.update(servo.joint.register_dict())
        changed = []
        for name, value in wanted.items():
            if servo.model.item(name).area != 'eeprom':
                continue
            current = self._read(servo, name)
            yield
            if current != value:
                self._write_verified(servo, name, value)
                changed.append(f'{name}={value}')
                yield
        if changed:
            self.info(f'joint {servo.name!r}: EEPROM written: {", ".join(changed)}')
        servo.homing_offset = self._read(servo, 'homing_offset')
        yield
        yield from self._apply_ram(servo)

    def _apply_ram(self, servo: Servo) -> Steps:
        """RAM configuration and the indirect map (lost at every reboot)."""
        for name, value in servo.joint.registers:
            if servo.model.item(name).area == 'ram':
                self._write_verified(servo, name, value)
                yield
        bus = self._io()
        block = servo.block
        self._try(lambda: bus.write(servo.servo_id, block.indirect_map_address(),
                                    block.indirect_map_bytes()))
        yield
        for name in LIMIT_REGISTERS:
            if servo.model.has(name):
                servo.limits[name] = self._read(servo, name)
                yield

    def _set_return_delay(self) -> None:
        delays = [self._read(servo, 'return_delay_time') for servo in self.active_servos()]
        self._io().return_delay_s = max(delays, default=250) * 2e-6

    def activate(self) -> None:
        """Goal = present for every servo, then torque on (if torque_on_start)."""
        with self.lock:
            for servo in self.active_servos():
                servo.torque_wanted = self.config.torque_on_start
                try:
                    _run(self._hold(servo))
                except (PortError, CommError) as exc:
                    raise ManagerError(f'activation failed: {exc}') from None
            self._clear_pending()
            self._need_full = True

    def _cbp_current(self, servo: Servo) -> int:
        """
        Return the goal current (the current limit) a current_based_position joint holds with.

        A mode change or a reboot sets goal_current to the servo's maximum; the joint gets
        back what it was last commanded, else what the configuration says, else current_limit.
        """
        limit = servo.limits.get('current_limit', servo.model.item('current_limit').initial)
        wanted = servo.goal_raw.get('goal_current',
                                    servo.joint.register_dict().get('goal_current', limit))
        return max(-limit, min(limit, wanted))

    def _hold(self, servo: Servo) -> Steps:
        """
        Make the servo hold where it is (per mode), then set torque as wanted.

        Torque on re-initialises Present Position within one turn (the seed), so in the position
        modes the goal written first must be in that frame: the servo is brought there before
        (CLEAR, or the seed's formula when it cannot clear), and the whole turns it loses are
        kept in the joint's turn offset. After torque on the position is read again, and a
        frame change nobody predicted is caught at once.
        """
        torque = self._read(servo, 'torque_enable')
        yield
        present = self._read(servo, 'present_position')
        yield
        goal: Optional[int] = None
        if servo.mode in model.POSITION_MODES:
            if not torque and servo.torque_wanted:
                present = yield from self._into_one_turn(servo, present)
            goal = self._clamp_position(servo, present)
            self._write(servo, 'goal_position', goal)
            servo.goal_raw['goal_position'] = goal
            yield
            if servo.mode == 'current_based_position':
                current = self._cbp_current(servo)
                self._write(servo, 'goal_current', current)
                servo.goal_raw['goal_current'] = current
                yield
        else:
            register = servo.units.kinds[_MODE_KIND[servo.mode]].register
            # A mode change sets goal_current / goal_pwm to their limits: never enable with that.
            self._write(servo, register, 0)
            servo.goal_raw[register] = 0
            yield
        if servo.torque_wanted and not torque:
            self._write(servo, 'torque_enable', 1)
            yield
            after = self._read(servo, 'present_position')
            yield
            if abs(after - present) >= servo.units.pulses_per_rev // 2:
                self._keep_turns(servo, present, after)
                if goal is not None:
                    goal = self._clamp_position(servo, after)
                    self._write(servo, 'goal_position', goal)
                    servo.goal_raw['goal_position'] = goal
                    yield
        elif not servo.torque_wanted and torque:
            self._write(servo, 'torque_enable', 0)
            yield
        servo.last_command_s = self._clock()
        servo.timed_out = False

    def _into_one_turn(self, servo: Servo, present: int) -> Generator[None, None, int]:
        """Bring Present Position within one turn before torque on; return its new value."""
        homing = servo.homing_offset
        if homing <= present < homing + servo.units.pulses_per_rev:
            return present
        bus = self._io()
        try:
            self._try(lambda: bus.clear_multi_turn(servo.servo_id))
            yield
            after = self._read(servo, 'present_position')
            yield
        except StatusError:
            # CLEAR refused (the horn is moving, or an older firmware): torque on will do the
            # same re-initialisation, by the seed's formula.
            after = servo.units.reinit_position(present, homing)
        self._keep_turns(servo, present, after)
        return after

    def _keep_turns(self, servo: Servo, before_raw: int, after_raw: int) -> None:
        """Keep the joint's position continuous after the servo re-initialised its position."""
        if servo.mode == 'position':
            servo.turn_offset = 0
            return
        servo.turn_offset += servo.units.kept_turns(before_raw, after_raw)

    def _clamp_position(self, servo: Servo, raw: int) -> int:
        if servo.mode == 'position' and servo.limits:
            return min(max(raw, servo.limits['min_position_limit']),
                       servo.limits['max_position_limit'])
        return min(max(raw, -ct.EXTENDED_POSITION_LIMIT), ct.EXTENDED_POSITION_LIMIT)

    def deactivate(self) -> List[str]:
        """
        Torque off (if torque_off_on_shutdown); pending goals and tasks dropped.

        Returns what could not be done, one line per servo (empty: every torque-off was
        acknowledged).
        """
        with self.lock:
            self._clear_pending()
            self.tasks.cancel_all('the node is stopping')
            self._refresh_ids()
            if not self.config.torque_off_on_shutdown:
                return []
            return self.torque_off_all()

    def torque_off_all(self) -> List[str]:
        """Torque off every servo that may have torque on; return the failures."""
        with self.lock:
            if self.bus is None:
                return [f'joint {s.name!r}: the port is closed' for s in self.order
                        if s.torque_maybe_on]
            failures = []
            stop, self.should_stop = self.should_stop, lambda: False   # a signal must not cut it
            try:
                for servo in self.order:
                    if not (servo.online or servo.torque_maybe_on):
                        continue
                    try:
                        self._write(servo, 'torque_enable', 0)
                    except (PortError, CommError) as exc:
                        failures.append(f'joint {servo.name!r}: {exc}')
            finally:
                self.should_stop = stop
            return failures

    def close(self) -> None:
        """Close the port."""
        with self.lock:
            if self._reading is not None and self.bus is not None:
                self.bus.abort(self._reading.pending)
                self._reading = None
            if self.bus is not None:
                self.bus.close()
            self.bus = None

    # the cycle ----------------------------------------------------------------------------
    def read_states(self, full: Optional[bool] = None,
                    retry_until: Optional[float] = None) -> float:
        """
        Read every servo's state with one sync read; return the read's monotonic time.

        The motion part of the block is read every cycle (with the Realtime Tick while the bus
        is suspicious); the whole block (health too) when `full`, or by default every
        health_period_s, when a servo raised its alert bit, or when a servo has no health values
        yet. A servo whose reply was lost or corrupted is read again on its own (read_retries
        times) while the clock is before retry_until (the cycle's budget). A servo that still
        does not answer well, or whose sample is older than its request, keeps fresh False: it
        is left out of what is published, never given a stale or invented value.
        """
        if self.begin_read(full):
            self.end_read(retry_until)
        return self.last_read_time

    def begin_read(self, full: Optional[bool] = None) -> bool:
        """
        Put the cycle's sync read on the wire and return; end_read() collects it.

        The manager's lock (and the bus's) stay held until end_read() or abort_read(), in the
        same thread: in between, the caller may only do work that needs neither (publishing the
        last cycle). False (nothing in flight, no lock held) when no servo is to be read.
        """
        self.lock.acquire()
        try:
            bus = self._io()
            if not self._groups:
                self.lock.release()
                return False
            stamp = self._clock()
            if full is None:
                full = (stamp - self._last_full_s >= self.health_period_s
                        or self._need_full)
            if full:
                length = BLOCK.size   # each group's own block size (_group_length)
            elif bus.dirty:
                length = BLOCK.tagged_size
            else:
                length = BLOCK.motion_size
            block, ids = self._groups[0]
            pending = bus.begin_sync_read(block.read_address, _group_length(block, length), ids)
        except BaseException:
            self.lock.release()
            raise
        self._reading = _Reading(stamp, full, length, pending)
        return True

    def abort_read(self) -> None:
        """Give up the sync read in flight, if any, and release the locks (idempotent)."""
        reading = self._reading
        if reading is None:
            return
        self._reading = None
        try:
            if self.bus is not None:
                self.bus.abort(reading.pending)
        finally:
            self.lock.release()

    def end_read(self, retry_until: Optional[float] = None) -> float:
        """Collect the sync read begun by begin_read(); return its monotonic time."""
        reading = self._reading
        if reading is None:
            raise RuntimeError('end_read() without a read in flight')
        self._reading = None
        try:
            bus = self._io()
            result = bus.end_sync_read(reading.pending)
            received = time.monotonic()   # the bus dates requests on this clock
            for block, ids in self._groups[1:]:
                # Models whose state block lives elsewhere (an X330 before firmware 53): one
                # more sync read each layout, dated on their own.
                more = bus.sync_read(block.read_address, _group_length(block, reading.length),
                                     ids)
                got = time.monotonic()
                result.data.update(more.data)
                result.alerts.update(more.alerts)
                result.dated.update({sid: (more.sent_s, got) for sid in ids})
                result.dated.update(more.dated)
                result.clean = result.clean and more.clean
            if (retry_until is not None and self.config.read_retries
                    and not result.clean):
                self._retry_failed(result, reading.length, retry_until)
            self._need_full = False
            if reading.full:
                self._last_full_s = reading.stamp
            self._take_results(result, reading.length, reading.stamp, received)
            self.cycles += 1
            self.last_read_time = reading.stamp
            return reading.stamp
        finally:
            self.lock.release()

    def _take_results(self, result: SyncResult, length: int, stamp: float,
                      received: float) -> None:
        for servo, servo_id in self._ids_cache:
            data = result.data.get(servo_id)
            if not isinstance(data, bytes):
                self._read_failed(servo, data)
                continue
            size = len(data)   # a retry may have read more than the sync read
            block = servo.block
            values = block.decoder(size)(data)
            full = size == block.size
            if not values[0] and not values[1] and not values[2] and not full:
                # What a restarted servo returns (its indirect map is gone) - or a horn at
                # exactly -pi, at rest: ask for the whole block, canary included, to know.
                checked = self._check_restart(servo)
                if checked is None:
                    continue
                values = checked
                full = True
            elif full and values[IDX_CANARY] == 0:
                servo.fresh = False
                self._restarted(servo)
                continue
            elif size != BLOCK.motion_size:
                sent_s, received_s = result.dated.get(servo_id, (result.sent_s, received))
                if not servo.tick.check(values[IDX_TICK], sent_s, received_s):
                    self._refuse_stale(servo)
                    continue
            if full:
                servo.state = values
                servo.health_time = stamp
            elif servo.state is not None:
                servo.state = values[:BLOCK.MOTION_FIELDS] + servo.state[BLOCK.MOTION_FIELDS:]
            else:
                # Motion is good; the health part is not known yet (health_time 0).
                servo.state = values[:BLOCK.MOTION_FIELDS] + (0,) + _NO_HEALTH
                self._need_full = True
            if result.alerts.get(servo_id) and not servo.state[IDX_HW_ERROR]:  # type: ignore
                self._need_full = True   # a new hardware error: decode it next cycle
            servo.state_time = stamp
            servo.fresh = True
            servo.consecutive_failures = 0

    def _read_failed(self, servo: Servo, error: Any) -> None:
        servo.fresh = False
        servo.comm_errors += 1
        servo.consecutive_failures += 1
        self.read_failures += 1
        self.warn_throttled(f'read:{servo.name}', f'joint {servo.name!r}: state read failed: '
                            f'{error}')

    def _refuse_stale(self, servo: Servo) -> None:
        servo.fresh = False
        servo.stale_refused += 1
        self.stale_refused += 1
        self.warn_throttled(f'stale:{servo.name}',
                            f'joint {servo.name!r}: refused a reply older than its request '
                            '(a late reply of an earlier one); nothing published for it')

    def _check_restart(self, servo: Servo) -> Optional[Tuple[int, ...]]:
        """
        Read the whole block of a servo whose motion read was all zeros.

        Returns the block when the servo did not restart; None when it did (its restore is
        then started) or when it did not answer.
        """
        bus = self._io()
        try:
            data, sent_s = bus.read_dated(servo.servo_id, servo.block.read_address,
                                          servo.block.size)
        except CommError as exc:
            self._read_failed(servo, exc)
            return None
        values = servo.block.decode(data)
        if values[IDX_CANARY] == 0:
            servo.fresh = False
            self._restarted(servo)
            return None
        if not servo.tick.check(values[IDX_TICK], sent_s, time.monotonic()):
            self._refuse_stale(servo)
            return None
        return values

    def _retry_failed(self, result: SyncResult, length: int, until: float) -> None:
        bus = self._io()
        # A retry always reads the tick: the bus is suspicious after a failure.
        length = max(length, BLOCK.tagged_size)
        one_read_s = bus.reply_timeout_s(STATUS_BYTES + length, 1, READ_BYTES)
        silent = {servo.servo_id for servo, _ in self._ids_cache
                  if servo.consecutive_failures >= SILENT_AFTER_FAILURES}
        for servo_id, data in list(result.data.items()):
            if isinstance(data, (bytes, StatusError)):
                continue   # a status error is the servo's answer: asking again changes nothing
            if servo_id in silent:
                continue   # gone for now: the sync read keeps asking; retries serve the others
            for _ in range(self.config.read_retries):
                if self._clock() + one_read_s > until:
                    break
                self.retries += 1
                try:
                    block = self._by_id[servo_id].block
                    answer, sent_s = bus.read_dated(servo_id, block.read_address,
                                                    _group_length(block, length))
                except CommError as exc:
                    result.data[servo_id] = exc
                    continue
                self.retry_successes += 1
                result.data[servo_id] = answer
                result.dated[servo_id] = (sent_s, time.monotonic())
                break

    def _restarted(self, servo: Servo) -> None:
        """Restore a servo that restarted on its own (power cut, brown-out), step by step."""
        if servo.name in self.tasks:
            return
        servo.restarts += 1
        self.warn(f'joint {servo.name!r} (id {servo.servo_id}) restarted on its own: '
                  'restoring its configuration and mode; it will hold where it is')
        self._start_task(servo, 'restore', self._restore(servo, servo.last_joint_pulses()))

    def _restore(self, servo: Servo, last_joint_pulses: Optional[int]) -> Steps:
        """
        Give a restarted servo its setup back and make it hold where it is.

        The servo's RAM is back to its defaults and its position was re-initialised within one
        turn: the configuration is written again, the lost whole turns go into the joint's turn
        offset (assuming the horn moved less than half a turn while it was down), and it holds
        where it is (goal = present; velocity, current and PWM goals 0): a goal nobody sent
        again is never replayed, a wheel does not start turning again by itself.
        """
        servo.tick.reset()
        servo.status = 'restoring'
        yield from self._apply_configuration(servo)
        present = self._read(servo, 'present_position')
        yield
        if servo.mode == 'position':
            servo.turn_offset = 0
        elif last_joint_pulses is not None:
            servo.turn_offset = servo.units.kept_turns(last_joint_pulses, present)
        for register in list(servo.goal_raw):
            if register != 'goal_current' or servo.mode != 'current_based_position':
                del servo.goal_raw[register]
        yield from self._hold(servo)
        servo.status = ''

    def _reboot(self, servo: Servo) -> Steps:
        """REBOOT one servo, wait for it to boot, give it its setup back holding where it is."""
        servo.status = 'rebooting'
        last = servo.last_joint_pulses()
        bus = self._io()
        try:
            last = servo.joint_pulses(self._read(servo, 'present_position'))
            yield
        except (CommTimeout, CorruptReply, StatusError):
            pass   # a servo in trouble may not answer reads: the last good state will do
        servo.torque_maybe_on = False   # a reboot clears torque enable
        self._try(lambda: bus.reboot(servo.servo_id))
        servo.tick.reset()   # its Realtime Tick starts again from 0
        yield
        deadline = self._clock() + BOOT_TIMEOUT_S
        next_ping = self._clock() + BOOT_POLL_S
        while True:
            while self._clock() < next_ping:
                yield   # booting: nothing to ask yet
            try:
                bus.ping(servo.servo_id)
                break
            except CommTimeout:
                if self._clock() > deadline:
                    raise CommTimeout(f'id {servo.servo_id}: did not answer within '
                                      f'{BOOT_TIMEOUT_S:g} s of its reboot', servo.servo_id)
                next_ping = self._clock() + BOOT_POLL_S
                yield
        yield from self._restore(servo, last)

    def _rejoin(self, servo: Servo) -> Steps:
        """After the adapter came back: find the servo, restore it if it lost power."""
        servo.status = 'not answering since the adapter came back'
        bus = self._io()
        bus.ping(servo.servo_id)
        yield
        block = servo.block
        values = block.decode(bus.read_fresh(servo.servo_id, block.read_address, block.size)[0])
        yield
        servo.status = ''
        if values[IDX_CANARY] != 0:
            servo.tick.reset()
            return   # it kept its power and its setup: it holds what it held
        servo.restarts += 1
        yield from self._restore(servo, servo.last_joint_pulses())

    def _start_task(self, servo: Servo, kind: str, steps: Steps,
                    not_before_s: float = 0.0) -> Task:
        servo.fresh = False
        self._pending_drop(servo)
        task = self.tasks.add(Task(servo.name, kind, steps, not_before_s))
        self._refresh_ids()
        return task

    def _task_done(self, task: Task) -> None:
        servo = self.servos[task.joint]
        servo.status = ''
        self._need_full = True
        self._refresh_ids()
        if task.kind == 'restore':
            self.info(f'joint {servo.name!r}: restored after its restart, holding where it is')
        elif task.kind == 'recover':
            servo.health_time = 0.0
            self.info(f'joint {servo.name!r}: recovered, configuration and torque restored')
        elif task.kind == 'rejoin':
            self.info(f'joint {servo.name!r}: answering again')

    def _task_failed(self, task: Task, exc: Exception) -> None:
        servo = self.servos[task.joint]
        if isinstance(exc, PortError):
            raise exc
        if task.kind == 'reboot':
            servo.status = ''
            self._refresh_ids()
            return   # the service that asked reports it
        # Restores and probes are tried again until they work: the servo is of no use before.
        retry = REJOIN_INTERVAL_S if task.kind == 'rejoin' else RETRY_BACKOFF_S
        self.warn_throttled(f'task:{servo.name}',
                            f'joint {servo.name!r}: {task.kind} failed ({exc}); trying again')
        steps = (self._rejoin(servo) if task.kind == 'rejoin'
                 else self._restore(servo, servo.last_joint_pulses()))
        self._start_task(servo, task.kind if task.kind != 'recover' else 'restore', steps,
                         self._clock() + retry)

    def recover_hardware_errors(self) -> None:
        """With hardware_error_recovery: reboot a faulty servo alone, rate-limited, restored."""
        if not self.config.hardware_error_recovery:
            return
        with self.lock:
            now = self._clock()
            for servo in self.active_servos():
                state = servo.state
                if (not servo.health_time or state is None or not state[IDX_HW_ERROR]
                        or servo.name in self.tasks):
                    continue
                if now - servo.last_recovery_s < self.config.recovery_interval:
                    continue
                servo.last_recovery_s = now
                servo.recoveries += 1
                self.recoveries += 1
                errors = ', '.join(servo.model.decode_hardware_errors(state[IDX_HW_ERROR]))
                self.warn(f'joint {servo.name!r} (id {servo.servo_id}): hardware error '
                          f'{errors}: rebooting it to recover (recovery {servo.recoveries})')
                self._start_task(servo, 'recover', self._reboot(servo))

    # port loss ------------------------------------------------------------------------------
    def cycle_begin(self) -> bool:
        """begin_read() unless the port is lost; False when no read is in flight."""
        if self.port_lost:
            with self.lock:
                if not self._reconnect():
                    return False
        try:
            return self.begin_read()
        except PortError as exc:
            with self.lock:
                self._lose_port(exc)
            return False

    def cycle_end(self, retry_until: Optional[float] = None) -> bool:
        """end_read() of a cycle_begin(); False when the port was lost meanwhile."""
        try:
            self.end_read(retry_until)
        except PortError as exc:
            with self.lock:
                self._lose_port(exc)
            return False
        return True

    def cycle_read(self, retry_until: Optional[float] = None) -> bool:
        """Read states unless the port is lost; False when nothing was read this cycle."""
        return self.cycle_begin() and self.cycle_end(retry_until)

    def cycle_write(self, tasks_until: Optional[float] = None) -> None:
        """Command timeouts, pending goals, recovery steps; port loss handled."""
        with self.lock:
            if self.port_lost or self.bus is None:
                return
            try:
                self.check_command_timeout()
                self.write_pending()
                self.recover_hardware_errors()
                if tasks_until is not None:
                    self.tasks.run(tasks_until)
            except PortError as exc:
                self._lose_port(exc)

    def _lose_port(self, exc: PortError) -> None:
        if self.port_lost:
            return
        self.port_lost = True
        self.port_error = str(exc)
        self._clear_pending()
        self.tasks.cancel_all('the port was lost')
        for servo in self.order:
            servo.fresh = False
            servo.status = ''
        self._refresh_ids()
        self.error(f'{self.config.port}: {exc}. The node stays up and reconnects when the '
                   'device returns; pending goals were dropped.')
        if self.sim_bus is None and self.bus is not None:
            self.bus.close()
        self._next_reconnect_s = self._clock() + self.reconnect_interval_s

    def _reconnect(self) -> bool:
        """
        Try to get the port back; True when it is.

        Every servo then rejoins on its own (a task each): one that kept its power goes on
        holding what it held, one that lost it is restored to hold where it is, and one that
        does not answer is probed every second without holding up the others.
        """
        now = self._clock()
        if now < self._next_reconnect_s:
            return False
        self._next_reconnect_s = now + self.reconnect_interval_s
        bus = self._io()
        try:
            if self.sim_bus is None:
                # A real adapter comes back as a new device: open it again.
                self.port, _ = self._port_factory(self.config)
                bus.port = self.port
            else:
                bus.port.in_waiting   # raises while the simulated adapter is unplugged
        except (PortError, CommError, OSError):
            return False
        self.port_lost = False
        self.port_error = ''
        self._need_full = True
        bus.mark_dirty()
        for servo in self.active_servos():
            self._start_task(servo, 'rejoin', self._rejoin(servo))
        self.info(f'{self.config.port}: port back; checking {len(self.active_servos())} servos')
        return True

    def write_pending(self) -> int:
        """Write the goals queued since the last cycle: one sync write per register."""
        with self.lock:
            if not self._pending or self.bus is None:
                return 0
            with self._queue_lock:
                pending, self._pending = self._pending, {}
            written = 0
            for register, goals in pending.items():
                # One sync write per register: its address and size are every model's alike
                # on the X series, grouped anyway so that a table that differs is honoured.
                groups: Dict[Tuple[int, int, bool], List[Tuple[int, bytes]]] = {}
                for sid, value in goals.items():
                    item = self._by_id[sid].model.item(register)
                    fmt = _PACKERS[item.size]
                    groups.setdefault((item.address, item.size, item.signed), []).append(
                        (sid, fmt.pack(value)))
                for (address, size, _), data in groups.items():
                    self.bus.sync_write(address, size, data)
                written += len(goals)
            return written

    def check_command_timeout(self) -> None:
        """Velocity, current and pwm goals fall back to zero after command_timeout."""
        timeout = self.config.command_timeout
        if timeout <= 0.0:
            return
        now = self._clock()
        with self.lock, self._queue_lock:
            for servo in self.active_servos():
                if servo.timed_out or servo.mode in model.POSITION_MODES:
                    continue
                if now - servo.last_command_s > timeout:
                    register = servo.units.kinds[_MODE_KIND[servo.mode]].register
                    if servo.goal_raw.get(register, 0) != 0:
                        self._queue(servo, register, 0)
                        self.warn(f'joint {servo.name!r}: no {servo.mode} command for '
                                  f'{timeout:g} s: goal set to zero')
                    servo.timed_out = True

    def _queue(self, servo: Servo, register: str, value: int) -> None:
        self._pending.setdefault(register, {})[servo.servo_id] = value
        servo.goal_raw[register] = value

    # commands ------------------------------------------------------------------------------
    def check_goals(self, kind: str, names: Sequence[str],
                    values: Sequence[float]) -> Tuple[Optional[List[Tuple[Servo, str, int]]], str]:
        """
        Validate goals and convert them to raw register values, clamped to the servo's limits.

        Returns (goals, '') or (None, reason); nothing is queued here.
        """
        if kind not in model.MODE_KINDS:
            return None, f'unknown command kind {kind!r}'
        if len(names) == 0:
            return None, 'empty command: no joint names'
        if len(names) != len(values):
            return None, (f'{len(names)} names but {len(values)} values: they must have the '
                          'same length')
        if len(set(names)) != len(names):
            return None, 'a joint is named twice'
        if self.port_lost:
            return None, f'the port is lost ({self.port_error}): no goal can be written'
        goals = []
        for name, value in zip(names, values):
            servo = self.servos.get(name)
            if servo is None:
                return None, f'unknown joint {name!r}'
            if not servo.online:
                return None, f'joint {name!r} is not on the bus (missing at configure)'
            if not math.isfinite(value):
                return None, f'joint {name!r}: {value} is not a finite number'
            if servo.switching:
                return None, f'joint {name!r} is changing its operating mode: try again'
            if servo.name in self.tasks:
                return None, (f'joint {name!r} is {servo.status or "busy"}: it takes goals '
                              'again once that is done')
            command = servo.units.kinds.get(kind)
            if command is None:
                return None, (f'joint {name!r} is a {servo.model.name}, which has no '
                              f'{model.GOAL_REGISTERS[kind]} register (no {kind} control); '
                              f'its commands: {", ".join(sorted(servo.units.kinds))}')
            if kind not in model.MODE_COMMANDS[servo.mode]:
                return None, (f'joint {name!r} is in {servo.mode} mode: {kind} commands do not '
                              'apply to it')
            if abs(value) > 1e9:
                return None, f'joint {name!r}: {value} {command.unit} is out of any range'
            offset = servo.turn_offset if kind == 'position' else 0
            raw = command.to_raw(value) - offset
            clamped = self._clamp(servo, command.register, raw)
            if clamped != raw:
                self.warn_throttled(
                    f'clamp:{name}:{kind}',
                    f'joint {name!r}: {kind} goal {value:g} {command.unit} clamped to '
                    f'{command.to_si(clamped + offset):g} {command.unit} (servo limit)')
            goals.append((servo, command.register, clamped))
        return goals, ''

    def _clamp(self, servo: Servo, register: str, raw: int) -> int:
        if register == 'goal_position':
            return self._clamp_position(servo, raw)
        bound = servo.limits[servo.model.item(register).limit or '']
        return min(max(raw, -bound), bound)

    def command(self, kind: str, names: Sequence[str], values: Sequence[float]) -> Result:
        """Queue goals (topic path): written by the next cycle's sync write."""
        with self._queue_lock:
            goals, reason = self.check_goals(kind, names, values)
            if goals is None:
                return Result(False, reason)
            now = self._clock()
            for servo, register, raw in goals:
                self._queue(servo, register, raw)
                servo.last_command_s = now
                servo.timed_out = False
            return Result(True, f'{len(goals)} {kind} goals queued')

    def command_now(self, kind: str, names: Sequence[str], values: Sequence[float]) -> Result:
        """Write goals at once (service path): answered after they were written."""
        with self.lock:
            result = self.command(kind, names, values)
            if not result.success:
                return result
            try:
                self.write_pending()
            except PortError as exc:
                self._lose_port(exc)
                return Result(False, f'goals not written: {exc}')
            except CommError as exc:
                return Result(False, f'goals not written: {exc}')
            return Result(True, f'{len(names)} {kind} goals written')

    def _servos_named(self, names: Sequence[str],
                      busy_ok: bool = False) -> Tuple[Optional[List[Servo]], str]:
        if self.port_lost:
            return None, f'the port is lost ({self.port_error}); try again when it is back'
        if not names:
            servos = self.active_servos()
        else:
            servos = []
            for name in names:
                servo = self.servos.get(name)
                if servo is None:
                    return None, f'unknown joint {name!r}'
                if not servo.online:
                    return None, f'joint {name!r} is not on the bus'
                servos.append(servo)
        if not busy_ok:
            for servo in servos:
                if servo.name in self.tasks:
                    return None, (f'joint {servo.name!r} is {servo.status or "busy"}: try '
                                  'again in a moment')
        return servos, ''

    def _request(self, what: str, action: Callable[[], Result]) -> Result:
        """Run a service's bus work: a lost port is handled, a bus failure is the answer."""
        try:
            return action()
        except PortError as exc:
            self._lose_port(exc)
            return Result(False, f'{what} failed: {exc}')
        except Interrupted:
            return Result(False, f'{what} interrupted: the node is stopping')

    def set_torque(self, names: Sequence[str], enable: bool) -> Result:
        """Torque on (goal = present first) or off."""
        with self.lock:
            servos, reason = self._servos_named(names)
            if servos is None:
                return Result(False, reason)
            word = 'on' if enable else 'off'

            def action() -> Result:
                try:
                    for servo in servos:
                        servo.torque_wanted = enable
                        self._pending_drop(servo)
                        if enable:
                            _run(self._hold(servo))
                        else:
                            self._write(servo, 'torque_enable', 0)
                except CommError as exc:
                    return Result(False, f'torque {word} failed: {exc}')
                return Result(True, f'torque {word} for {", ".join(s.name for s in servos)}')
            return self._request(f'torque {word}', action)

    def _clear_pending(self) -> None:
        with self._queue_lock:
            self._pending.clear()

    def _pending_drop(self, servo: Servo) -> None:
        with self._queue_lock:
            for goals in self._pending.values():
                goals.pop(servo.servo_id, None)

    def set_operating_mode(self, names: Sequence[str], mode: str) -> Result:
        """Torque off, mode, what a mode change resets re-applied, goal = present, torque back."""
        with self.lock:
            if mode not in ct.OPERATING_MODES:
                return Result(False, f'unknown operating mode {mode!r} (one of '
                              f'{", ".join(ct.OPERATING_MODES)})')
            if not names:
                return Result(False, 'no joint named')
            servos, reason = self._servos_named(names)
            if servos is None:
                return Result(False, reason)
            for servo in servos:
                if mode not in servo.model.modes:
                    return Result(False, f'joint {servo.name!r} is a {servo.model.name}, which '
                                  f'has no {mode} mode (its modes: '
                                  f'{", ".join(servo.model.modes)})')
            done: List[str] = []

            def action() -> Result:
                try:
                    for servo in servos:
                        _run(self._switch_mode(servo, mode))
                        done.append(servo.name)
                except CommError as exc:
                    for servo in servos:
                        self._resync_mode(servo)
                    return Result(False, f'mode change failed after {done or "no joint"}: {exc}')
                finally:
                    for servo in servos:
                        servo.switching = False
                return Result(True, f'{", ".join(done)} now in {mode} mode')
            return self._request('mode change', action)

    def _switch_mode(self, servo: Servo, mode: str) -> Steps:
        with self._queue_lock:
            servo.switching = True
            for goals in self._pending.values():
                goals.pop(servo.servo_id, None)
        self._write(servo, 'torque_enable', 0)
        yield
        before = self._read(servo, 'present_position')
        yield
        self._write(servo, 'operating_mode', servo.model.modes[mode])
        yield
        servo.mode = mode
        servo.goal_raw.clear()
        after = self._read(servo, 'present_position')
        yield
        # A mode change re-initialises Present Position within one turn (the seed).
        if mode == 'position':
            servo.turn_offset = 0
            yield from self._single_turn_homing(servo)
        else:
            self._keep_turns(servo, before, after)
        # The seed (Operating Mode note 1): profiles, goal PWM/current and gains were reset by
        # the mode change; give back what the configuration set.
        for name, value in servo.joint.registers:
            if name in model.MODE_CHANGE_RESETS:
                self._write_verified(servo, name, value)
                yield
        yield from self._hold(servo)

    def _single_turn_homing(self, servo: Servo) -> Steps:
        # Position mode ignores a homing offset beyond +-1024 (the seed): one left over from
        # another mode is put back to the configured one.
        offset = self._read(servo, 'homing_offset')
        yield
        if abs(offset) > ct.HOMING_OFFSET_POSITION_MODE_LIMIT:
            self._write_verified(servo, 'homing_offset',
                                 servo.joint.register_dict().get('homing_offset', 0))
            yield

    def _resync_mode(self, servo: Servo) -> None:
        """After a failure, believe the servo about its mode."""
        try:
            raw = self._read(servo, 'operating_mode')
            servo.mode = model.MODE_NAMES.get(raw, servo.mode)
        except (PortError, CommError):
            pass

    def reboot(self, names: Sequence[str], wait: Optional[Callable[[List[Task]], None]] = None
               ) -> Result:
        """
        Reboot, then configuration and mode restored, holding where it is, torque as it was.

        The reboots run as tasks the cycle steps through (the others are read and published
        meanwhile); wait(tasks) blocks until they ended. Without wait (nobody else runs the
        cycle), they run here to their end.
        """
        with self.lock:
            servos, reason = self._servos_named(names)
            if servos is None:
                return Result(False, reason)
            # A joint named twice is rebooted once.
            servos = list({servo.name: servo for servo in servos}.values())
            tasks = [self._start_task(servo, 'reboot', self._reboot(servo)) for servo in servos]
            if wait is None:
                for task in tasks:
                    if not task.done:
                        try:
                            task.run_to_end()
                        except Exception:  # noqa: B902 - reported below from task.error
                            pass
                        self.tasks.cancel_all('done', [task.joint])
                self._refresh_ids()
        if wait is not None:
            wait(tasks)
        with self.lock:
            failed = [f'{t.joint}: {t.error}' for t in tasks if t.error is not None]
            for task in tasks:
                if task.error is not None:
                    self._task_retry_after_reboot(task)
            self._need_full = True
        if failed:
            return Result(False, 'reboot failed: ' + '; '.join(failed))
        return Result(True, f'rebooted and restored {", ".join(s.name for s in servos)}')

    def _task_retry_after_reboot(self, task: Task) -> None:
        # A servo whose reboot failed part-way may be unconfigured: restore it in the background.
        servo = self.servos[task.joint]
        if isinstance(task.error, PortError):
            self._lose_port(task.error)
            return
        if servo.name not in self.tasks and not self.port_lost:
            self._start_task(servo, 'restore', self._restore(servo, servo.last_joint_pulses()),
                             self._clock() + RETRY_BACKOFF_S)

    def read_register(self, name: str, register: str) -> Tuple[Optional[int], str]:
        """Read one register by snake_case name or decimal address: (value, message)."""
        with self.lock:
            servos, reason = self._servos_named([name]) if name else (None, 'no joint named')
            if servos is None:
                return None, reason
            item, reason = _register(servos[0].model, register)
            if item is None:
                return None, reason
            try:
                value = self._read(servos[0], item.name)
            except PortError as exc:
                self._lose_port(exc)
                return None, str(exc)
            except CommError as exc:
                return None, str(exc)
            return value, f'{name}.{item.name} (address {item.address}) = {value}'

    def write_register(self, name: str, register: str, value: int) -> Result:
        """Write one register; EEPROM while torque is on is refused with the reason."""
        with self.lock:
            servos, reason = self._servos_named([name]) if name else (None, 'no joint named')
            if servos is None:
                return Result(False, reason)
            servo = servos[0]
            item, reason = _register(servo.model, register)
            if item is None:
                return Result(False, reason)
            try:
                model.writable_register(servo.model, item.name, runtime=True)
                model.check_range(item, value)
            except ValueError as exc:
                return Result(False, str(exc))

            def action() -> Result:
                try:
                    context = dict(servo.limits)
                    context['homing_offset'] = servo.homing_offset
                    for other in model.related_registers(servo.model, item.name):
                        if other not in context:
                            context[other] = self._read(servo, other)
                    model.check_register_set(context, item.name, value, servo.mode)
                    if item.area == 'eeprom' and self._read(servo, 'torque_enable'):
                        return Result(False, f'{item.name} is in EEPROM, which the servo locks '
                                      'while torque is on: call set_torque with enable=false '
                                      'first')
                    self._write(servo, item.name, value)
                except ValueError as exc:
                    return Result(False, str(exc))
                except CommError as exc:
                    return Result(False, str(exc))
                if item.name in servo.limits:
                    servo.limits[item.name] = value
                return Result(True, f'{name}.{item.name} (address {item.address}) = {value}')
            return self._request('write', action)


_MODE_KIND = {'velocity': 'velocity', 'current': 'current', 'pwm': 'pwm',
              'position': 'position', 'extended_position': 'position',
              'current_based_position': 'position'}


def _group_length(block: model.StateBlock, length: int) -> int:
    """Return the read length of a block: a whole-block read is as long as that model's."""
    return block.size if length >= BLOCK.size else length


def _run(steps: Steps) -> None:
    """Run an activity's steps to the end, at once (a synchronous caller)."""
    for _ in steps:
        pass


def _register(table: models.Model, key: str) -> Tuple[Optional[ct.Item], str]:
    key = key.strip()
    try:
        return table.lookup(int(key) if key.isascii() and key.isdigit() else key), ''
    except KeyError as exc:
        return None, str(exc.args[0])


_PACKERS = {1: struct.Struct('<b'), 2: struct.Struct('<h'), 4: struct.Struct('<i')}
# Read at configure and kept: the bounds goals are clamped to (those the model has).
LIMIT_REGISTERS = ('min_position_limit', 'max_position_limit', 'velocity_limit',
                   'current_limit', 'pwm_limit')
