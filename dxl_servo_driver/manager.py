"""
The manager: servos by joint name over one Bus, with batching and safety ordering.

It owns what the node must never get wrong: configuration applied and verified before anything
moves, goal = present before torque on, one packed read and one sync write per register per cycle,
refusals that write nothing, what a mode change resets re-applied, servos that restart on their
own given their configuration back. No ROS here: the node calls these methods and publishes.
"""

from dataclasses import dataclass, field
import math
import struct
import threading
import time
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple

from dxl_servo_driver import control_table as ct
from dxl_servo_driver import model
from dxl_servo_driver.bus import Bus, BusError, CommTimeout, PortError, RawPort, StatusError
from dxl_servo_driver.config import DriverConfig, JointConfig

Log = Callable[[str], None]
BLOCK = model.STATE_BLOCK
_I = BLOCK.index
IDX_POSITION = _I['present_position']
IDX_VELOCITY = _I['present_velocity']
IDX_CURRENT = _I['present_current']
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
TURN_PULSES = 4096
_NO_HEALTH = (0,) * (len(BLOCK.names) - BLOCK.MOTION_FIELDS)
_ALL_ZERO_MOTION = (0,) * BLOCK.MOTION_FIELDS


class ManagerError(Exception):
    """A failure the user must act on (missing servo, wrong model, port), said in one line."""


@dataclass
class Servo:
    """What the manager knows of one configured servo."""

    joint: JointConfig
    mode: str
    model_number: int = 0
    firmware_version: int = 0
    online: bool = False            # answered at configure (or since)
    state: Optional[Tuple[int, ...]] = None   # last good state block (raw)
    state_time: float = 0.0         # monotonic time of that read
    health_time: float = 0.0        # time of the last whole-block read (0 = health unknown)
    fresh: bool = False             # state was read in the latest cycle
    comm_errors: int = 0
    consecutive_failures: int = 0
    torque_wanted: bool = False
    goal_raw: Dict[str, int] = field(default_factory=dict)   # last goal written, per register
    last_command_s: float = 0.0     # for command_timeout
    timed_out: bool = False
    limits: Dict[str, int] = field(default_factory=dict)
    restarts: int = 0
    switching: bool = False         # a mode switch is under way: commands wait for it
    recoveries: int = 0
    last_recovery_s: float = -1e9

    @property
    def name(self) -> str:
        """Return the joint name."""
        return self.joint.name

    @property
    def servo_id(self) -> int:
        """Return the servo id."""
        return self.joint.servo_id


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


def open_port(config: DriverConfig) -> Tuple[RawPort, Any]:
    """
    Open the configured port: a serial device, or `sim` for one simulated servo per joint.

    Returns the port and, for `sim`, the SimBus behind it (tests and fault injection use it).
    """
    if config.port == 'sim':
        from dxl_servo_driver.sim.bus import SimBus
        from dxl_servo_driver.sim.port import SimPortHandler
        from dxl_servo_driver.sim.virtual_bus import configure_servos
        sim = SimBus([joint.servo_id for joint in config.joints])
        configure_servos(sim, config.baud_rate, None)
        return SimPortHandler(sim, 'sim', config.baud_rate), sim
    from dxl_servo_driver.bus import open_port as open_serial
    return open_serial(config.port, config.baud_rate), None


PortFactory = Callable[[DriverConfig], Tuple[RawPort, Any]]


class Manager:
    """Servos by joint name on one bus."""

    def __init__(self, config: DriverConfig, info: Log = print, warn: Log = print,
                 error: Log = print, port_factory: PortFactory = open_port,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.config = config
        self.info = info
        self.warn = warn
        self.error = error
        self.warn_throttled = Throttle(warn, clock=clock)
        self._port_factory = port_factory
        self._clock = clock
        self.bus: Optional[Bus] = None
        self.port: Optional[RawPort] = None
        self.sim_bus: Any = None   # the SimBus behind `port: sim`
        self.servos: Dict[str, Servo] = {
            joint.name: Servo(joint, joint.operating_mode) for joint in config.joints}
        self.order: List[Servo] = [self.servos[joint.name] for joint in config.joints]
        # Serialises requests (services, topics, the cycle) over the manager's state.
        self.lock = threading.RLock()
        self._pending: Dict[str, Dict[int, int]] = {}   # register -> {servo id: raw goal}
        # Commands only queue: they take this small lock, never the bus lock above, so a
        # command arriving during a read is queued at once and goes out in this cycle's write.
        # Order when both are needed: self.lock, then _queue_lock.
        self._queue_lock = threading.Lock()
        self.cycles = 0
        self.read_failures = 0
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
        self._reading: Optional[Tuple[float, bool, int]] = None   # begin_read() in flight
        self._id_list: List[int] = []

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
            try:
                self._find_servos()
                for servo in self.order:
                    if servo.online:
                        self._apply_configuration(servo)
                self._set_return_delay()
                self._refresh_ids()
            except BusError as exc:
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

    def _open_bus(self) -> Bus:
        """Return the bus; BusError (a failure a request reports) when it is not open."""
        if self.bus is None:
            raise BusError('the bus is not open (the node is not configured)')
        return self.bus

    def active_servos(self) -> List[Servo]:
        """Return the servos that answered at configure."""
        return [servo for servo in self.order if servo.online]

    def _refresh_ids(self) -> None:
        # The hot path reads these instead of rebuilding lists every cycle.
        self._ids_cache = [(servo, servo.servo_id) for servo in self.active_servos()]
        self._id_list = [servo_id for _, servo_id in self._ids_cache]

    def _find_servos(self) -> None:
        assert self.bus is not None
        missing = []
        for servo in self.order:
            model_number = None
            last_error: Optional[BusError] = None
            for _ in range(self.config.ping_retries):
                try:
                    model_number = self.bus.ping(servo.servo_id)
                    break
                except BusError as exc:
                    last_error = exc
                    if isinstance(exc, PortError):
                        raise
            if model_number is None:
                missing.append((servo, last_error))
                continue
            if model_number != ct.MODEL_NUMBER:
                raise ManagerError(
                    f'joint {servo.name!r}: id {servo.servo_id} is model {model_number}, '
                    f'expected {ct.MODEL_NUMBER} (XM430-class control table); refusing to drive '
                    'an unknown model')
            servo.model_number = model_number
            servo.firmware_version = self.bus.read_item(servo.servo_id,
                                                        ct.BY_NAME['firmware_version'])
            servo.online = True
            errors = self.bus.read_item(servo.servo_id, ct.BY_NAME['hardware_error_status'])
            if errors:
                self.warn(f'joint {servo.name!r} (id {servo.servo_id}) has hardware errors '
                          f'latched: {", ".join(ct.decode_hardware_errors(errors))} '
                          '(a reboot clears them)')
            self.info(f'found joint {servo.name!r}: id {servo.servo_id}, model {model_number}, '
                      f'firmware {servo.firmware_version}, mode {servo.mode}')
        for servo, failure in missing:
            message = (f'joint {servo.name!r}: servo id {servo.servo_id} did not answer '
                       f'{self.config.ping_retries} pings at {self.config.baud_rate} bps '
                       f'({failure}); check the id, the baud rate, the power and the cable')
            if self.config.missing_servo == 'refuse':
                raise ManagerError(message)
            self.warn(message + '; starting without it (missing_servo: skip)')
        if not self.active_servos():
            raise ManagerError('no configured servo answered')

    def _write_verified(self, servo: Servo, name: str, value: int) -> None:
        assert self.bus is not None
        item = ct.BY_NAME[name]
        self.bus.write_item(servo.servo_id, item, value)
        read_back = self.bus.read_item(servo.servo_id, item)
        if read_back != value:
            raise BusError(f'joint {servo.name!r}: {name} reads back {read_back} after writing '
                           f'{value}', servo.servo_id)

    def _apply_configuration(self, servo: Servo) -> None:
        """Mode, EEPROM (only where it differs), RAM registers, indirect map; torque stays off."""
        assert self.bus is not None
        sid = servo.servo_id
        self.bus.write_item(sid, ct.BY_NAME['torque_enable'], 0)
        wanted = {'operating_mode': ct.OPERATING_MODES[servo.mode]}
        wanted.update(servo.joint.register_dict())
        changed = []
        for name, value in wanted.items():
            item = ct.BY_NAME[name]
            if item.area != 'eeprom':
                continue
            if self.bus.read_item(sid, item) != value:
                self._write_verified(servo, name, value)
                changed.append(f'{name}={value}')
        if changed:
            self.info(f'joint {servo.name!r}: EEPROM written: {", ".join(changed)}')
        self._apply_ram(servo)

    def _apply_ram(self, servo: Servo) -> None:
        """RAM configuration and the indirect map (lost at every reboot)."""
        assert self.bus is not None
        for name, value in servo.joint.registers:
            if ct.BY_NAME[name].area == 'ram':
                self._write_verified(servo, name, value)
        self.bus.write(servo.servo_id, BLOCK.indirect_map_address(), BLOCK.indirect_map_bytes())
        limits = ('min_position_limit', 'max_position_limit', 'velocity_limit', 'current_limit',
                  'pwm_limit')
        servo.limits = {name: self.bus.read_item(servo.servo_id, ct.BY_NAME[name])
                        for name in limits}

    def _set_return_delay(self) -> None:
        assert self.bus is not None
        delays = [self.bus.read_item(servo.servo_id, ct.BY_NAME['return_delay_time'])
                  for servo in self.active_servos()]
        self.bus.return_delay_s = max(delays, default=250) * 2e-6

    def activate(self) -> None:
        """Goal = present for every servo, then torque on (if torque_on_start)."""
        with self.lock:
            for servo in self.active_servos():
                servo.torque_wanted = self.config.torque_on_start
                try:
                    self._hold_and_enable(servo)
                except BusError as exc:
                    raise ManagerError(f'activation failed: {exc}') from None
            self._clear_pending()
            self._need_full = True

    def _hold_and_enable(self, servo: Servo) -> None:
        """Make the servo hold where it is (per mode), then set torque as wanted."""
        assert self.bus is not None
        sid = servo.servo_id
        if servo.mode in model.POSITION_MODES:
            present = self.bus.read_item(sid, ct.BY_NAME['present_position'])
            self._write_goal(servo, 'goal_position', present)
        elif servo.mode == 'velocity':
            self._write_goal(servo, 'goal_velocity', 0)
        elif servo.mode == 'current':
            # A mode change sets goal_current to the current limit: never enable with that.
            self._write_goal(servo, 'goal_current', 0)
        elif servo.mode == 'pwm':
            self._write_goal(servo, 'goal_pwm', 0)
        self.bus.write_item(sid, ct.BY_NAME['torque_enable'], int(servo.torque_wanted))
        servo.last_command_s = self._clock()
        servo.timed_out = False

    def _write_goal(self, servo: Servo, register: str, value: int) -> None:
        assert self.bus is not None
        self.bus.write_item(servo.servo_id, ct.BY_NAME[register], value)
        servo.goal_raw[register] = value

    def deactivate(self) -> None:
        """Torque off (if torque_off_on_shutdown); pending goals dropped."""
        with self.lock:
            self._clear_pending()
            if not self.config.torque_off_on_shutdown or self.bus is None:
                return
            for servo in self.active_servos():
                try:
                    self.bus.write_item(servo.servo_id, ct.BY_NAME['torque_enable'], 0)
                except BusError as exc:
                    self.warn(f'joint {servo.name!r}: torque off failed: {exc}')

    def close(self) -> None:
        """Close the port."""
        with self.lock:
            if self.bus is not None:
                self.bus.close()
            self.bus = None

    # the cycle ----------------------------------------------------------------------------
    def read_states(self, full: Optional[bool] = None,
                    retry_until: Optional[float] = None) -> float:
        """
        Read every servo's state with one sync read; return the read's monotonic time.

        The motion part of the block is read every cycle; the whole block (health too) when
        `full`, or by default every health_period_s, when a servo raised its alert bit, or when
        a servo has no health values yet. A servo whose reply was lost or corrupted is read again
        on its own (read_retries times) while the clock is before retry_until (the cycle's
        budget). A servo that still does not answer well keeps fresh False: it is left out of
        what is published, never given a stale or invented value.
        """
        self.begin_read(full)
        return self.end_read(retry_until)

    def begin_read(self, full: Optional[bool] = None) -> None:
        """
        Put the cycle's sync read on the wire and return; end_read() collects it.

        The manager's lock (and the bus's) stay held until end_read(), in the same thread: in
        between, the caller may only do work that needs neither (publishing the last cycle).
        """
        self.lock.acquire()
        try:
            assert self.bus is not None
            stamp = self._clock()
            if full is None:
                full = (stamp - self._last_full_s >= self.health_period_s
                        or self._need_full)
            length = BLOCK.size if full else BLOCK.motion_size
            self.bus.sync_read_begin(BLOCK.read_address, length, self._id_list)
        except BaseException:
            self.lock.release()
            raise
        self._reading = (stamp, full, length)

    def end_read(self, retry_until: Optional[float] = None) -> float:
        """Collect the sync read begun by begin_read(); return its monotonic time."""
        try:
            assert self.bus is not None and self._reading is not None
            stamp, full, length = self._reading
            self._reading = None
            results = self.bus.sync_read_end()
            if (retry_until is not None and self.config.read_retries
                    and not self.bus.last_read_clean):
                self._retry_failed(results, length, retry_until)
            self._need_full = False
            if full:
                self._last_full_s = stamp
            self._take_results(results, full, stamp)
            self.cycles += 1
            self.last_read_time = stamp
            return stamp
        finally:
            self.lock.release()

    def _take_results(self, results: Dict[int, Any], full: bool, stamp: float) -> None:
        alerts = self.bus.alerts if self.bus is not None else {}
        decode = BLOCK.decode if full else BLOCK.decode_motion
        for servo, servo_id in self._ids_cache:
            data = results.get(servo_id)
            if isinstance(data, bytes):
                values = decode(data)
                if not full and values == _ALL_ZERO_MOTION:
                    # What a restarted servo returns (its indirect map is gone) - or a horn at
                    # exactly -pi, at rest: ask for the whole block, canary included, to know.
                    whole = self._check_restart(servo)
                    if whole is None:
                        continue
                    servo.state = whole
                    servo.health_time = stamp
                    values = whole[:BLOCK.MOTION_FIELDS]
                elif full and values[IDX_CANARY] == 0:
                    servo.fresh = False
                    self._recover_restart(servo)
                    continue
                if full:
                    servo.state = values
                    servo.health_time = stamp
                elif servo.state is not None:
                    servo.state = values + servo.state[BLOCK.MOTION_FIELDS:]
                else:
                    # Motion is good; the health part is not known yet (health_time 0).
                    servo.state = values + _NO_HEALTH
                    self._need_full = True
                if alerts.get(servo_id) and not servo.state[IDX_HW_ERROR]:
                    self._need_full = True   # a new hardware error: decode it next cycle
                servo.state_time = stamp
                servo.fresh = True
                servo.consecutive_failures = 0
            else:
                servo.fresh = False
                servo.comm_errors += 1
                servo.consecutive_failures += 1
                self.read_failures += 1
                self.warn_throttled(f'read:{servo.name}',
                                    f'joint {servo.name!r}: state read failed: {data}')

    def _check_restart(self, servo: Servo) -> Optional[Tuple[int, ...]]:
        """
        Read the whole block of a servo whose motion read was all zeros.

        Returns the block when the servo did not restart; None when it did (it is then
        restored) or when it did not answer.
        """
        assert self.bus is not None
        try:
            values = BLOCK.decode(self.bus.read(servo.servo_id, BLOCK.read_address, BLOCK.size))
        except PortError:
            raise
        except BusError:
            servo.fresh = False
            return None
        if values[IDX_CANARY] == 0:
            servo.fresh = False
            self._recover_restart(servo)
            return None
        return values

    def _retry_failed(self, results: Dict[int, Any], length: int, until: float) -> None:
        assert self.bus is not None
        one_read_s = self.bus.reply_timeout_s(STATUS_BYTES + length, 1, READ_BYTES)
        for servo_id, data in results.items():
            if isinstance(data, bytes) or isinstance(data, StatusError):
                continue   # a status error is the servo's answer: asking again changes nothing
            for _ in range(self.config.read_retries):
                if self._clock() + one_read_s > until:
                    return
                self.retries += 1
                try:
                    results[servo_id] = self.bus.read(servo_id, BLOCK.read_address, length)
                    self.retry_successes += 1
                    break
                except PortError:
                    raise
                except BusError as exc:
                    results[servo_id] = exc

    def _recover_restart(self, servo: Servo) -> None:
        """Give a servo that restarted on its own (power cut, brown-out) its setup back."""
        servo.restarts += 1
        self._need_full = True
        self.warn(f'joint {servo.name!r} (id {servo.servo_id}) restarted on its own: '
                  'restoring its configuration, mode and torque')
        try:
            self._restore(servo, last_position=self._last_position(servo))
        except PortError:
            raise
        except BusError as exc:
            self.warn_throttled(f'restore:{servo.name}',
                                f'joint {servo.name!r}: restore after restart failed: {exc}')

    @staticmethod
    def _last_position(servo: Servo) -> Optional[int]:
        return servo.state[IDX_POSITION] if servo.state is not None else None

    def _keep_turns(self, servo: Servo, last_position: int) -> None:
        """
        Keep the multi-turn position continuous across a reboot.

        A reboot re-initialises Present Position within one turn (the seed); adding the lost
        whole turns to the Homing Offset (EEPROM, torque is off here) puts the count back where
        it was. It assumes the horn moved less than half a turn while the servo was down.
        """
        assert self.bus is not None
        sid = servo.servo_id
        present = self.bus.read_item(sid, ct.BY_NAME['present_position'])
        turns = int(round((last_position - present) / TURN_PULSES))
        if not turns:
            return
        offset = self.bus.read_item(sid, ct.BY_NAME['homing_offset'])
        wanted = offset + turns * TURN_PULSES
        if abs(wanted) > ct.HOMING_OFFSET_LIMIT:
            self.warn(f'joint {servo.name!r}: cannot keep its position across the reboot: '
                      f'{turns} turns exceed the homing offset range')
            return
        self._write_verified(servo, 'homing_offset', wanted)
        self.info(f'joint {servo.name!r}: position kept continuous across the reboot '
                  f'({turns:+d} turns via homing_offset {wanted})')

    def _restore(self, servo: Servo, hold_last_goal: bool = True,
                 last_position: Optional[int] = None) -> None:
        """Restore configuration, mode, goal and torque after a reboot."""
        assert self.bus is not None
        self._apply_configuration(servo)
        if last_position is not None and servo.mode != 'position':
            self._keep_turns(servo, last_position)
        goal = servo.goal_raw.get('goal_position')
        self._hold_and_enable(servo)
        if (hold_last_goal and servo.torque_wanted and servo.mode in model.POSITION_MODES
                and goal is not None):
            # Torque on holds where the horn is now; then back to the goal it was given (the
            # servo's profile makes that a smooth move if the horn sagged while unpowered).
            if servo.mode == 'position':
                goal = min(max(goal, servo.limits['min_position_limit']),
                           servo.limits['max_position_limit'])
            self._write_goal(servo, 'goal_position', goal)

    def recover_hardware_errors(self) -> None:
        """With hardware_error_recovery: reboot a faulty servo alone, rate-limited, restored."""
        if not self.config.hardware_error_recovery:
            return
        with self.lock:
            now = self._clock()
            for servo in self.active_servos():
                state = servo.state
                if not servo.health_time or state is None or not state[IDX_HW_ERROR]:
                    continue
                if now - servo.last_recovery_s < self.config.recovery_interval:
                    continue
                servo.last_recovery_s = now
                servo.recoveries += 1
                self.recoveries += 1
                errors = ', '.join(ct.decode_hardware_errors(state[IDX_HW_ERROR]))
                self.warn(f'joint {servo.name!r} (id {servo.servo_id}): hardware error '
                          f'{errors}: rebooting it to recover (recovery {servo.recoveries})')
                try:
                    self._reboot_and_restore(servo)
                except PortError:
                    raise
                except BusError as exc:
                    self.warn(f'joint {servo.name!r}: recovery failed: {exc}')
                    continue
                servo.health_time = 0.0
                self.info(f'joint {servo.name!r}: recovered, configuration and torque restored')

    # port loss ------------------------------------------------------------------------------
    def cycle_read(self, retry_until: Optional[float] = None) -> bool:
        """Read states unless the port is lost; False when nothing was read this cycle."""
        return self.cycle_begin() and self.cycle_end(retry_until)

    def cycle_begin(self) -> bool:
        """begin_read() unless the port is lost; False when no read is in flight."""
        if self.port_lost:
            with self.lock:
                if not self._reconnect():
                    return False
        try:
            self.begin_read()
        except PortError as exc:
            with self.lock:
                self._lose_port(exc)
            return False
        return True

    def cycle_end(self, retry_until: Optional[float] = None) -> bool:
        """end_read() of a cycle_begin(); False when the port was lost meanwhile."""
        try:
            self.end_read(retry_until)
        except PortError as exc:
            with self.lock:
                self._lose_port(exc)
            return False
        return True

    def cycle_write(self) -> None:
        """Command timeouts, pending goals, hardware-error recovery; port loss handled."""
        with self.lock:
            if self.port_lost:
                return
            try:
                self.check_command_timeout()
                self.write_pending()
                self.recover_hardware_errors()
            except PortError as exc:
                self._lose_port(exc)

    def _lose_port(self, exc: BusError) -> None:
        self.port_lost = True
        self.port_error = str(exc)
        self._clear_pending()
        for servo in self.order:
            servo.fresh = False
        self.error(f'{self.config.port}: {exc}. The node stays up and reconnects when the '
                   'device returns.')
        if self.sim_bus is None and self.bus is not None:
            self.bus.close()
        self._next_reconnect_s = self._clock() + self.reconnect_interval_s

    def _reconnect(self) -> bool:
        """Try to get the port and the servos back; True when done."""
        now = self._clock()
        if now < self._next_reconnect_s:
            return False
        self._next_reconnect_s = now + self.reconnect_interval_s
        assert self.bus is not None
        try:
            if self.sim_bus is None:
                # A real adapter comes back as a new device: open it again.
                self.port, _ = self._port_factory(self.config)
                self.bus.port = self.port
            for servo in self.active_servos():
                self.bus.ping(servo.servo_id)
            results = self.bus.sync_read(BLOCK.read_address, BLOCK.size, self._id_list)
            for servo, servo_id in self._ids_cache:
                data = results.get(servo_id)
                if isinstance(data, bytes) and BLOCK.decode(data)[IDX_CANARY] != 0:
                    continue   # kept its power and its setup: leave it as it is
                # It lost power with the adapter: setup, hold where it is, torque back.
                self._restore(servo, hold_last_goal=False,
                              last_position=self._last_position(servo))
        except (BusError, OSError):
            return False
        self.port_lost = False
        self.port_error = ''
        self._need_full = True
        self.info(f'{self.config.port}: port back, {len(self.active_servos())} servos restored')
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
                item = ct.BY_NAME[register]
                fmt = struct.Struct('<i' if item.size == 4 else '<h')
                self.bus.sync_write(item.address, item.size,
                                    [(sid, fmt.pack(value)) for sid, value in goals.items()])
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
                    register = model.COMMAND_KINDS[servo.mode].register
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
        if kind not in model.COMMAND_KINDS:
            return None, f'unknown command kind {kind!r}'
        if len(names) == 0:
            return None, 'empty command: no joint names'
        if len(names) != len(values):
            return None, (f'{len(names)} names but {len(values)} values: they must have the '
                          'same length')
        if len(set(names)) != len(names):
            return None, 'a joint is named twice'
        command = model.COMMAND_KINDS[kind]
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
            if kind not in model.MODE_COMMANDS[servo.mode]:
                return None, (f'joint {name!r} is in {servo.mode} mode: {kind} commands do not '
                              'apply to it')
            if abs(value) > 1e9:
                return None, f'joint {name!r}: {value} {command.unit} is out of any range'
            raw = command.to_raw(value)
            clamped = self._clamp(servo, command.register, raw)
            if clamped != raw:
                self.warn_throttled(
                    f'clamp:{name}:{kind}',
                    f'joint {name!r}: {kind} goal {value:g} {command.unit} clamped to '
                    f'{command.to_si(clamped):g} {command.unit} (servo limit)')
            goals.append((servo, command.register, clamped))
        return goals, ''

    def _clamp(self, servo: Servo, register: str, raw: int) -> int:
        limits = servo.limits
        if register == 'goal_position':
            if servo.mode == 'position':
                low, high = limits['min_position_limit'], limits['max_position_limit']
            else:
                low, high = -ct.EXTENDED_POSITION_LIMIT, ct.EXTENDED_POSITION_LIMIT
        else:
            bound = limits[ct.BY_NAME[register].limit or '']
            low, high = -bound, bound
        return min(max(raw, low), high)

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
            except BusError as exc:
                return Result(False, f'goals not written: {exc}')
            return Result(True, f'{len(names)} {kind} goals written')

    def _servos_named(self, names: Sequence[str]) -> Tuple[Optional[List[Servo]], str]:
        if not names:
            return self.active_servos(), ''
        servos = []
        for name in names:
            servo = self.servos.get(name)
            if servo is None:
                return None, f'unknown joint {name!r}'
            if not servo.online:
                return None, f'joint {name!r} is not on the bus'
            servos.append(servo)
        return servos, ''

    def set_torque(self, names: Sequence[str], enable: bool) -> Result:
        """Torque on (goal = present first) or off."""
        with self.lock:
            servos, reason = self._servos_named(names)
            if servos is None:
                return Result(False, reason)
            try:
                for servo in servos:
                    servo.torque_wanted = enable
                    self._pending_drop(servo)
                    if enable:
                        self._hold_and_enable(servo)
                    else:
                        self._open_bus().write_item(servo.servo_id, ct.BY_NAME['torque_enable'], 0)
            except BusError as exc:
                return Result(False, f'torque {"on" if enable else "off"} failed: {exc}')
            return Result(True, f'torque {"on" if enable else "off"} for '
                          f'{", ".join(s.name for s in servos)}')

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
            done = []
            try:
                for servo in servos:
                    with self._queue_lock:
                        servo.switching = True
                        for goals in self._pending.values():
                            goals.pop(servo.servo_id, None)
                    bus = self._open_bus()
                    bus.write_item(servo.servo_id, ct.BY_NAME['torque_enable'], 0)
                    bus.write_item(servo.servo_id, ct.BY_NAME['operating_mode'],
                                   ct.OPERATING_MODES[mode])
                    servo.mode = mode
                    servo.goal_raw.clear()
                    if mode == 'position':
                        self._single_turn_homing(servo)
                    # The seed (Operating Mode note 1): profiles, goal PWM/current and gains were
                    # reset by the mode change; give back what the configuration set.
                    for name, value in servo.joint.registers:
                        if name in model.MODE_CHANGE_RESETS:
                            self._write_verified(servo, name, value)
                    self._hold_and_enable(servo)
                    done.append(servo.name)
            except BusError as exc:
                for servo in servos:
                    self._resync_mode(servo)
                return Result(False, f'mode change failed after {done or "no joint"}: {exc}')
            finally:
                for servo in servos:
                    servo.switching = False
            return Result(True, f'{", ".join(done)} now in {mode} mode')

    def _single_turn_homing(self, servo: Servo) -> None:
        # Turns kept across reboots live in the homing offset; position mode ignores an offset
        # beyond +-1024 (the seed), so give it back the configured one (or none).
        assert self.bus is not None
        item = ct.BY_NAME['homing_offset']
        offset = self.bus.read_item(servo.servo_id, item)
        if abs(offset) > ct.HOMING_OFFSET_POSITION_MODE_LIMIT:
            self._write_verified(servo, 'homing_offset',
                                 servo.joint.register_dict().get('homing_offset', 0))

    def _resync_mode(self, servo: Servo) -> None:
        """After a failure, believe the servo about its mode."""
        assert self.bus is not None
        try:
            raw = self.bus.read_item(servo.servo_id, ct.BY_NAME['operating_mode'])
            servo.mode = model.MODE_NAMES.get(raw, servo.mode)
        except BusError:
            pass

    def reboot(self, names: Sequence[str]) -> Result:
        """Reboot, then configuration, mode and torque state restored."""
        with self.lock:
            servos, reason = self._servos_named(names)
            if servos is None:
                return Result(False, reason)
            try:
                for servo in servos:
                    self._reboot_and_restore(servo)
            except BusError as exc:
                return Result(False, f'reboot failed: {exc}')
            return Result(True, f'rebooted and restored {", ".join(s.name for s in servos)}')

    def _reboot_and_restore(self, servo: Servo) -> None:
        """REBOOT one servo, wait for it, give it its setup back holding where it is."""
        assert self.bus is not None
        self._pending_drop(servo)
        last = self._last_position(servo)
        try:
            last = self.bus.read_item(servo.servo_id, ct.BY_NAME['present_position'])
        except PortError:
            raise
        except BusError:
            pass   # a servo in trouble may not answer reads: the last good state will do
        self.bus.reboot(servo.servo_id)
        self._wait_for_boot(servo)
        self._restore(servo, hold_last_goal=False, last_position=last)
        self._need_full = True

    def _wait_for_boot(self, servo: Servo, timeout_s: float = 3.0) -> None:
        assert self.bus is not None
        deadline = self._clock() + timeout_s
        while True:
            try:
                self.bus.ping(servo.servo_id)
                return
            except CommTimeout:
                if self._clock() > deadline:
                    raise
                time.sleep(0.02)

    def read_register(self, name: str, register: str) -> Tuple[Optional[int], str]:
        """Read one register by snake_case name or decimal address: (value, message)."""
        with self.lock:
            servos, reason = self._servos_named([name]) if name else (None, 'no joint named')
            if servos is None:
                return None, reason
            item, reason = _register(register)
            if item is None:
                return None, reason
            try:
                value = self._open_bus().read_item(servos[0].servo_id, item)
            except BusError as exc:
                return None, str(exc)
            return value, f'{name}.{item.name} (address {item.address}) = {value}'

    def write_register(self, name: str, register: str, value: int) -> Result:
        """Write one register; EEPROM while torque is on is refused with the reason."""
        with self.lock:
            servos, reason = self._servos_named([name]) if name else (None, 'no joint named')
            if servos is None:
                return Result(False, reason)
            servo = servos[0]
            item, reason = _register(register)
            if item is None:
                return Result(False, reason)
            if item.access != 'RW':
                return Result(False, f'{item.name} is read-only')
            if item.name in model.DRIVER_OWNED:
                return Result(False, f'{item.name} is managed by the driver: use the '
                              'set_torque / set_operating_mode / command interfaces')
            try:
                model.check_range(item, value)
            except ValueError as exc:
                return Result(False, str(exc))
            try:
                if item.area == 'eeprom':
                    torque = self._open_bus().read_item(servo.servo_id,
                                                        ct.BY_NAME['torque_enable'])
                    if torque:
                        return Result(False, f'{item.name} is in EEPROM, which the servo locks '
                                      'while torque is on: call set_torque with enable=false '
                                      'first')
                self._open_bus().write_item(servo.servo_id, item, value)
            except StatusError as exc:
                return Result(False, str(exc))
            except BusError as exc:
                return Result(False, str(exc))
            if item.name in servo.limits:
                servo.limits[item.name] = value
            return Result(True, f'{name}.{item.name} (address {item.address}) = {value}')


def _register(key: str) -> Tuple[Optional[ct.Item], str]:
    key = key.strip()
    try:
        return ct.lookup(int(key) if key.isascii() and key.isdigit() else key), ''
    except KeyError as exc:
        return None, str(exc.args[0])
