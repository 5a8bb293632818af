"""
The ROS 2 node: parameters, topics, services, lifecycle and diagnostics over the manager.

This is the only module that imports rclpy. The bus cycle runs in its own thread at loop_rate, so
it never waits on the executor; topic and service callbacks only queue goals or call the manager,
whose lock keeps one transaction on the bus at a time.
"""

import math
import signal
import sys
import threading
import time
from typing import Any, Dict, List, Optional

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from dxl_servo_driver import config as cfg
from dxl_servo_driver import control_table as ct
from dxl_servo_driver import model
from dxl_servo_driver.manager import (
    IDX_CURRENT, IDX_HW_ERROR, IDX_MOVING, IDX_MOVING_STATUS, IDX_POSITION, IDX_PWM,
    IDX_TEMPERATURE, IDX_TORQUE, IDX_VELOCITY, IDX_VOLTAGE, Manager, ManagerError, Servo)
from dxl_servo_driver_msgs.msg import JointCommand, ServoState, ServoStateArray
from dxl_servo_driver_msgs.srv import (
    ReadRegister, Reboot, SetGoals, SetOperatingMode, SetTorque, WriteRegister)
from rcl_interfaces.msg import (
    FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType, SetParametersResult)
import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import JointState

NODE_NAME = 'dxl_servo_driver'
COMMAND_KINDS = ('position', 'velocity', 'current', 'pwm')
# Parameters that may change while the node runs; the others need a restart.
RUNTIME_PARAMS = ('loop_rate', 'state_rate', 'command_timeout', 'temperature_warn',
                  'temperature_error', 'voltage_low', 'voltage_high')
_PARAM_TYPES = {bool: ParameterType.PARAMETER_BOOL, int: ParameterType.PARAMETER_INTEGER,
                float: ParameterType.PARAMETER_DOUBLE, str: ParameterType.PARAMETER_STRING,
                list: ParameterType.PARAMETER_STRING_ARRAY}


class StartupFailure(Exception):
    """The node cannot start; the message says why, in one line (or it was logged already)."""

    def __init__(self, message: str, logged: bool = False) -> None:
        super().__init__(message)
        self.logged = logged


class RateMeter:
    """Measured cycles per second over a sliding window."""

    def __init__(self, window_s: float = 1.0) -> None:
        self._window_s = window_s
        self._count = 0
        self._start = time.monotonic()
        self.rate_hz = 0.0

    def tick(self) -> None:
        """Count one cycle."""
        self._count += 1
        now = time.monotonic()
        if now - self._start >= self._window_s:
            self.rate_hz = self._count / (now - self._start)
            self._count = 0
            self._start = now


def _descriptor(spec: cfg.ParamSpec, read_only: bool) -> ParameterDescriptor:
    text = spec.description + (f' [{spec.unit}]' if spec.unit else '')
    if spec.choices:
        text += f' One of: {", ".join(str(c) for c in spec.choices)}.'
    descriptor = ParameterDescriptor(description=text, type=_PARAM_TYPES[spec.kind],
                                     read_only=read_only)
    if spec.choices:
        descriptor.additional_constraints = f'one of {list(spec.choices)}'
    if spec.minimum is not None and spec.maximum is not None:
        if spec.kind is float:
            descriptor.floating_point_range = [FloatingPointRange(
                from_value=float(spec.minimum), to_value=float(spec.maximum))]
        elif spec.kind is int:
            descriptor.integer_range = [IntegerRange(
                from_value=int(spec.minimum), to_value=int(spec.maximum))]
    return descriptor


class DriverNode(LifecycleNode):
    """One bus of Dynamixel servos as a lifecycle node."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, automatically_declare_parameters_from_overrides=True,
                         **kwargs)
        params = {name: p.value for name, p in self.get_parameters_by_prefix('').items()}
        try:
            self.config = cfg.validate(params)
        except cfg.ConfigError as exc:
            raise StartupFailure(f'invalid configuration: {exc}') from None
        self._declare_with_descriptors()
        log = self.get_logger()
        self.manager = Manager(self.config, info=log.info, warn=log.warning, error=log.error)
        self._active = False
        self._stop = threading.Event()
        self._thread: Optional[threading.Thread] = None
        self._timer: Any = None
        self._rate = RateMeter()
        self._loop_period_s = 1.0 / self.config.loop_rate
        self._state_period_s = (1.0 / self.config.state_rate) if self.config.state_rate else 0.0
        self._set_health_period()
        self._thresholds = {name: getattr(self.config, name) for name in RUNTIME_PARAMS[3:]}
        self._command_timeout = self.config.command_timeout
        self._last_state_s = 0.0
        self._last_diag_s = 0.0
        self._joint_state = JointState()
        self._bus_cycle_s = 0.0
        self._read_stamp: Any = None
        self._read_began_s = 0.0
        self._next_rate_log_s = 0.0
        assert (IDX_POSITION, IDX_VELOCITY, IDX_CURRENT) == (0, 1, 2)
        # (servo, joint name, N*m per current unit) per joint, in joint_states order.
        self._joint_table = [
            (servo, servo.name, model.A_PER_CURRENT_RAW * servo.joint.torque_constant_nm_per_a)
            for servo in self.manager.order]
        self._all_names = [servo.name for servo in self.manager.order]
        self.joint_states_pub = self.create_publisher(JointState, 'joint_states', 10)
        self.servo_states_pub = self.create_publisher(ServoStateArray, '~/servo_states', 10)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self._command_subs = [
            self.create_subscription(JointCommand, f'~/commands/{kind}',
                                     self._command_callback(kind), 10)
            for kind in COMMAND_KINDS]
        # Not `_services`: rclpy's Node keeps its own list under that name (parameter and
        # lifecycle services); replacing it left those services unserved or destroyed.
        self._driver_services = [
            self.create_service(SetGoals, f'~/set_{kind}', self._set_goals_callback(kind))
            for kind in COMMAND_KINDS]
        self._driver_services += [
            self.create_service(SetOperatingMode, '~/set_operating_mode', self._on_set_mode),
            self.create_service(SetTorque, '~/set_torque', self._on_set_torque),
            self.create_service(Reboot, '~/reboot', self._on_reboot),
            self.create_service(ReadRegister, '~/read_register', self._on_read_register),
            self.create_service(WriteRegister, '~/write_register', self._on_write_register),
        ]
        self.add_on_set_parameters_callback(self._on_set_parameters)

    # parameters ----------------------------------------------------------------------------
    def _declare_with_descriptors(self) -> None:
        """Re-declare every parameter with its description and range (ros2 param describe)."""
        for spec in cfg.PARAMS:
            value = getattr(self.config, spec.name) if spec.name != 'joints' else [
                joint.name for joint in self.config.joints]
            if self.has_parameter(spec.name):
                self.undeclare_parameter(spec.name)
            read_only = spec.name not in RUNTIME_PARAMS
            self.declare_parameter(spec.name, value, _descriptor(spec, read_only),
                                   ignore_override=True)
        for joint in self.config.joints:
            entries = [
                ('id', joint.servo_id, "Dynamixel id of the joint's servo (0..252).",
                 ParameterType.PARAMETER_INTEGER),
                ('operating_mode', joint.operating_mode,
                 f'Operating mode at start: one of {", ".join(ct.OPERATING_MODES)}.',
                 ParameterType.PARAMETER_STRING),
                ('torque_constant', joint.torque_constant_nm_per_a,
                 'Effort = current x this [N*m/A] (seed: 4.1 N*m at 2.3 A).',
                 ParameterType.PARAMETER_DOUBLE),
            ]
            for register, value in joint.registers:
                item = ct.BY_NAME[register]
                entries.append((f'registers.{register}', value,
                                f'{item.description} at address {item.address}, raw '
                                f'[{item.unit or "count"}], {item.minimum}..{item.maximum}, '
                                f'{item.area.upper()}; applied at configure.',
                                ParameterType.PARAMETER_INTEGER))
            for key, value, text, kind in entries:
                name = f'{joint.name}.{key}'
                if self.has_parameter(name):
                    self.undeclare_parameter(name)
                self.declare_parameter(name, value, ParameterDescriptor(
                    description=text, type=kind, read_only=True), ignore_override=True)

    def _set_health_period(self) -> None:
        # servo_states and the 1 Hz diagnostics need the health part of the state block.
        self.manager.health_period_s = min(1.0, self._state_period_s or 1.0)

    def _on_set_parameters(self, params: List[Parameter]) -> SetParametersResult:
        changes: Dict[str, float] = {}
        for param in params:
            if param.name not in RUNTIME_PARAMS:
                return SetParametersResult(
                    successful=False,
                    reason=f'{param.name} cannot be changed while the node runs (restart it)')
            spec = cfg.PARAMS_BY_NAME[param.name]
            try:
                changes[param.name] = cfg._check_spec(spec, param.value)
            except cfg.ConfigError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        if changes.get('state_rate', 1.0) < 0.0:
            return SetParametersResult(successful=False, reason='state_rate must be >= 0')
        for name, value in changes.items():
            if name == 'loop_rate':
                self._loop_period_s = 1.0 / value
                if self._timer is not None:
                    self.destroy_timer(self._timer)
                    self._timer = self.create_timer(self._loop_period_s, self._timer_cycle)
            elif name == 'state_rate':
                self._state_period_s = (1.0 / value) if value else 0.0
                self._set_health_period()
            elif name == 'command_timeout':
                self._command_timeout = value
                self.manager.config = _replace(self.manager.config, command_timeout=value)
            else:
                self._thresholds[name] = value
        return SetParametersResult(successful=True)

    # lifecycle -----------------------------------------------------------------------------
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Open the port, find and verify every servo, apply the configuration."""
        try:
            self.manager.configure()
        except ManagerError as exc:
            self.get_logger().error(str(exc))
            self.manager.close()
            return TransitionCallbackReturn.FAILURE
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Goal = present, torque on, start the cycle."""
        try:
            self.manager.activate()
            self._bus_cycle_s = self.manager.bus_budget().cycle_time_s
        except ManagerError as exc:
            self.get_logger().error(str(exc))
            return TransitionCallbackReturn.FAILURE
        self._stop.clear()
        self._active = True
        if self.config.cycle_driver == 'timer':
            self._timer = self.create_timer(self._loop_period_s, self._timer_cycle)
        else:
            self._thread = threading.Thread(target=self._run, name='dxl_bus_cycle',
                                            daemon=True)
            self._thread.start()
        self.get_logger().info(
            f'active: {len(self.manager.active_servos())} servos on {self.config.port} at '
            f'{self.config.baud_rate} bps, loop_rate {self.config.loop_rate:g} Hz')
        return super().on_activate(state)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Stop the cycle; torque off if torque_off_on_shutdown."""
        self._stop_cycle()
        self.manager.deactivate()
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Close the port."""
        self.manager.close()
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Stop, torque off (if configured), close the port."""
        self.shutdown()
        return TransitionCallbackReturn.SUCCESS

    def _stop_cycle(self) -> None:
        self._active = False
        self._stop.set()
        if self._timer is not None:
            self.destroy_timer(self._timer)
            self._timer = None
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None

    def shutdown(self) -> None:
        """Stop the cycle, apply torque_off_on_shutdown, close the port. Idempotent."""
        was_active = self._active or self._thread is not None or self._timer is not None
        self._stop_cycle()
        if was_active:
            self.manager.deactivate()
            torque = 'torque off' if self.config.torque_off_on_shutdown else 'torque left on'
            self.get_logger().info(f'stopped: {torque}, port {self.config.port} closed')
        self.manager.close()

    def start(self) -> None:
        """With autostart, configure and activate; StartupFailure when that fails."""
        if not self.config.autostart:
            self.get_logger().info('autostart is false: waiting for lifecycle transitions')
            return
        # on_configure / on_activate logged the reason: one clear line, not two.
        if self.trigger_configure() != TransitionCallbackReturn.SUCCESS:
            raise StartupFailure('configure failed', logged=True)
        if self.trigger_activate() != TransitionCallbackReturn.SUCCESS:
            raise StartupFailure('activate failed', logged=True)

    # the cycle -----------------------------------------------------------------------------
    def _run(self) -> None:
        """
        Run the bus cycle in its own thread: read, write goals, publish, pace.

        When the next cycle is due at once (the loop runs as fast as the bus allows), the next
        read goes on the wire before this cycle is published, so publishing overlaps the bus
        transaction instead of adding to it.
        """
        next_s = time.monotonic()
        behind_reported = False
        reading = self._begin()
        while not self._stop.is_set():
            try:
                stamp, began_s = self._read_stamp, self._read_began_s
                ok = reading is not None and self._end(began_s)
                reading = None
                self.manager.cycle_write()
                next_s += self._loop_period_s
                delay = next_s - time.monotonic()
                if delay < -self._loop_period_s:
                    if not behind_reported:
                        behind_reported = True
                        self.get_logger().warning(
                            f'the bus cannot keep loop_rate {1.0 / self._loop_period_s:g} Hz: '
                            'running as fast as it allows (the measured rate is in '
                            '/diagnostics)')
                    next_s = time.monotonic()
                pipelined = delay <= self._bus_cycle_s
                if pipelined:
                    reading = self._begin()
                self._publish(stamp, ok)
            except Exception as exc:  # noqa: B902 - the cycle must survive anything
                self.get_logger().error(f'cycle failed: {exc}', throttle_duration_sec=2.0)
                if reading is not None:
                    self._end(time.monotonic())
                    reading = None
                self._stop.wait(0.1)
                pipelined = False
            self._rate.tick()
            if time.monotonic() >= self._next_rate_log_s:
                self._log_rate()
            if not pipelined:
                delay = next_s - time.monotonic()
                if delay > 0:
                    self._stop.wait(delay)
                reading = self._begin()
        if reading is not None:
            self._end(time.monotonic())   # never leave the bus held

    def _begin(self) -> Optional[bool]:
        """Stamp and start a read; None when the port is lost (nothing in flight)."""
        self._read_stamp = self.get_clock().now().to_msg()
        self._read_began_s = time.monotonic()
        return True if self.manager.cycle_begin() else None

    def _end(self, began_s: float) -> bool:
        # Lost or corrupted replies are read again while the cycle has time (or twice the bus
        # time when the loop runs as fast as the bus allows).
        retry_until = began_s + max(0.9 * self._loop_period_s, 2.0 * self._bus_cycle_s)
        return self.manager.cycle_end(retry_until)

    def _timer_cycle(self) -> None:
        try:
            began = self._begin()
            ok = began is not None and self._end(self._read_began_s)
            self.manager.cycle_write()
            self._publish(self._read_stamp, ok)
        except Exception as exc:  # noqa: B902 - the cycle must survive anything
            self.get_logger().error(f'cycle failed: {exc}', throttle_duration_sec=2.0)
        self._rate.tick()
        if time.monotonic() >= self._next_rate_log_s:
            self._log_rate()

    def _log_rate(self) -> None:
        # A first report once the rate has settled, then one a minute.
        first = self._next_rate_log_s == 0.0
        self._next_rate_log_s = time.monotonic() + (3.0 if first else 60.0)
        if first:
            return
        budget = self.manager.bus_budget()
        self.get_logger().info(
            f'measured loop rate {self._rate.rate_hz:.1f} Hz (requested '
            f'{1.0 / self._loop_period_s:g} Hz, bus limit {budget.rate_limit_hz:.0f} Hz); '
            f'{self.manager.read_failures} read failures, {self.manager.retries} retries')

    def _publish(self, stamp: Any, read_ok: bool) -> None:
        if read_ok:
            self._publish_joint_states(stamp)
        now = time.monotonic()
        if self._state_period_s and now - self._last_state_s >= self._state_period_s:
            self._last_state_s = now
            self.servo_states_pub.publish(self._servo_states(stamp))
        if now - self._last_diag_s >= 1.0:
            self._last_diag_s = now
            self.diagnostics_pub.publish(self._diagnostics(stamp))

    def _publish_joint_states(self, stamp: Any) -> None:
        msg = self._joint_state
        msg.header.stamp = stamp
        names = []
        positions = []
        velocities = []
        efforts = []
        # The conversions of model.py, inlined with per-joint constants: this runs every cycle.
        rad_per_pulse = model.RAD_PER_PULSE
        zero = model.POSITION_ZERO_RAW
        rad_s = model.RAD_S_PER_VELOCITY_RAW
        for servo, name, nm_per_raw in self._joint_table:
            state = servo.state
            if not servo.fresh or state is None:
                continue   # never a stale or invented value
            names.append(name)
            positions.append((state[0] - zero) * rad_per_pulse)
            velocities.append(state[1] * rad_s)
            efforts.append(state[2] * nm_per_raw)
        if not names:
            return   # nobody answered: nothing to say (and never a stale value)
        if len(names) == len(self._all_names):
            names = self._all_names
        msg.name = names
        msg.position = positions
        msg.velocity = velocities
        msg.effort = efforts
        self.joint_states_pub.publish(msg)

    def _servo_state(self, servo: Servo) -> ServoState:
        msg = ServoState()
        msg.name = servo.name
        msg.id = servo.servo_id
        msg.model_number = servo.model_number
        msg.firmware_version = servo.firmware_version
        msg.operating_mode = servo.mode
        msg.comm_errors = min(servo.comm_errors, 2 ** 32 - 1)
        state = servo.state
        if state is None or not servo.fresh:
            # Not answering: no stale values here either (comm_errors says why).
            for attr in ('position', 'velocity', 'current', 'pwm', 'input_voltage',
                         'temperature'):
                setattr(msg, attr, math.nan)
            return msg
        msg.position = model.position_to_rad(state[IDX_POSITION])
        msg.velocity = model.velocity_to_rad_s(state[IDX_VELOCITY])
        msg.current = model.current_to_a(state[IDX_CURRENT])
        if not servo.health_time:
            msg.pwm = msg.input_voltage = msg.temperature = math.nan
            return msg
        msg.torque_enabled = bool(state[IDX_TORQUE])
        msg.pwm = model.pwm_to_ratio(state[IDX_PWM])
        msg.input_voltage = model.voltage_to_v(state[IDX_VOLTAGE])
        msg.temperature = float(state[IDX_TEMPERATURE])
        msg.moving = bool(state[IDX_MOVING])
        msg.moving_status = state[IDX_MOVING_STATUS]
        msg.hardware_error_status = state[IDX_HW_ERROR]
        msg.hardware_errors = ct.decode_hardware_errors(state[IDX_HW_ERROR])
        return msg

    def _servo_states(self, stamp: Any) -> ServoStateArray:
        msg = ServoStateArray()
        msg.header.stamp = stamp
        msg.servos = [self._servo_state(servo) for servo in self.manager.order]
        return msg

    def _diagnostics(self, stamp: Any) -> DiagnosticArray:
        manager = self.manager
        bus = manager.bus
        array = DiagnosticArray()
        array.header.stamp = stamp
        budget = manager.bus_budget()
        measured = self._rate.rate_hz
        node_name = self.get_fully_qualified_name()
        bus_status = DiagnosticStatus(name=f'{node_name}: bus {self.config.port}',
                                      hardware_id=self.config.port)
        bus_status.level = DiagnosticStatus.OK
        bus_status.message = f'{measured:.0f} Hz'
        requested = 1.0 / self._loop_period_s
        if manager.port_lost:
            bus_status.level = DiagnosticStatus.ERROR
            bus_status.message = f'port lost, reconnecting: {manager.port_error}'
        elif measured < 0.9 * min(requested, budget.rate_limit_hz):
            bus_status.level = DiagnosticStatus.WARN
            bus_status.message = (f'{measured:.0f} Hz, below the requested {requested:g} Hz '
                                  f'(bus limit {budget.rate_limit_hz:.0f} Hz)')
        values = {
            'port': self.config.port, 'baud_rate': self.config.baud_rate,
            'loop_rate_requested_hz': f'{1.0 / self._loop_period_s:g}',
            'loop_rate_measured_hz': f'{measured:.1f}',
            'bus_limit_hz': f'{budget.rate_limit_hz:.0f}',
            'cycles': manager.cycles, 'read_failures': manager.read_failures,
            'timeouts': bus.timeouts if bus else 0, 'corrupt_replies': bus.corrupt if bus else 0,
            'status_errors': bus.status_errors if bus else 0,
            'retries': manager.retries, 'retry_successes': manager.retry_successes,
            'recoveries': manager.recoveries, 'port_lost': manager.port_lost,
        }
        bus_status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        array.status.append(bus_status)
        for servo in manager.order:
            array.status.append(self._servo_diagnostic(servo))
        return array

    def _servo_diagnostic(self, servo: Servo) -> DiagnosticStatus:
        status = DiagnosticStatus(name=f'{self.get_fully_qualified_name()}: {servo.name}',
                                  hardware_id=f'{self.config.port} id {servo.servo_id}')
        state = servo.state
        problems: List[str] = []
        level = DiagnosticStatus.OK
        if not servo.online:
            level = DiagnosticStatus.ERROR
            problems.append('not on the bus')
        elif not servo.fresh:
            level = DiagnosticStatus.ERROR
            problems.append('not answering')
        values = {'id': servo.servo_id, 'model_number': servo.model_number,
                  'firmware_version': servo.firmware_version, 'operating_mode': servo.mode,
                  'comm_errors': servo.comm_errors, 'restarts': servo.restarts,
                  'recoveries': servo.recoveries}
        if state is not None and servo.health_time:
            temperature = float(state[IDX_TEMPERATURE])
            voltage = model.voltage_to_v(state[IDX_VOLTAGE])
            errors = ct.decode_hardware_errors(state[IDX_HW_ERROR])
            values.update({'temperature_c': temperature, 'input_voltage_v': f'{voltage:.1f}',
                           'torque_enabled': bool(state[IDX_TORQUE]),
                           'hardware_errors': ', '.join(errors) or 'none'})
            if errors:
                level = DiagnosticStatus.ERROR
                problems.append('hardware error: ' + ', '.join(errors))
            if temperature >= self._thresholds['temperature_error']:
                level = DiagnosticStatus.ERROR
                problems.append(f'temperature {temperature:.0f} C')
            elif temperature >= self._thresholds['temperature_warn']:
                level = max(level, DiagnosticStatus.WARN)
                problems.append(f'temperature {temperature:.0f} C')
            if not self._thresholds['voltage_low'] <= voltage <= self._thresholds['voltage_high']:
                level = max(level, DiagnosticStatus.WARN)
                problems.append(f'input voltage {voltage:.1f} V')
        status.level = level
        status.message = '; '.join(problems) or 'OK'
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        return status

    # commands and services -----------------------------------------------------------------
    def _command_callback(self, kind: str):  # type: ignore[no-untyped-def]
        def callback(msg: JointCommand) -> None:
            if not self._active:
                self.get_logger().warning(f'{kind} command ignored: the node is not active',
                                          throttle_duration_sec=2.0)
                return
            try:
                result = self.manager.command(kind, list(msg.name), list(msg.value))
            except Exception as exc:  # noqa: B902 - a bad message must not stop the node
                self.get_logger().error(f'{kind} command failed: {exc}',
                                        throttle_duration_sec=2.0)
                return
            if not result.success:
                self.get_logger().error(f'{kind} command refused: {result.message}',
                                        throttle_duration_sec=2.0)
        return callback

    def _guard(self, response: Any, action) -> Any:  # type: ignore[no-untyped-def]
        """Run a service action; a callback never raises, and inactive refuses."""
        if not self._active:
            response.success = False
            response.message = 'the node is not active (lifecycle state)'
            return response
        try:
            result = action()
        except Exception as exc:  # noqa: B902 - services answer, they never raise
            response.success = False
            response.message = f'internal error: {exc}'
            return response
        response.success = result.success
        response.message = result.message
        return response

    def _set_goals_callback(self, kind: str):  # type: ignore[no-untyped-def]
        def callback(request: SetGoals.Request, response: SetGoals.Response) -> Any:
            return self._guard(response, lambda: self.manager.command_now(
                kind, list(request.name), list(request.value)))
        return callback

    def _on_set_mode(self, request: Any, response: Any) -> Any:
        return self._guard(response, lambda: self.manager.set_operating_mode(
            list(request.name), request.mode))

    def _on_set_torque(self, request: Any, response: Any) -> Any:
        return self._guard(response, lambda: self.manager.set_torque(
            list(request.name), request.enable))

    def _on_reboot(self, request: Any, response: Any) -> Any:
        return self._guard(response, lambda: self.manager.reboot(list(request.name)))

    def _on_read_register(self, request: Any, response: Any) -> Any:
        if not self._active:
            response.success = False
            response.message = 'the node is not active (lifecycle state)'
            return response
        try:
            value, message = self.manager.read_register(request.name, request.register_name)
        except Exception as exc:  # noqa: B902 - services answer, they never raise
            value, message = None, f'internal error: {exc}'
        response.success = value is not None
        response.value = value if value is not None else 0
        response.message = message
        return response

    def _on_write_register(self, request: Any, response: Any) -> Any:
        return self._guard(response, lambda: self.manager.write_register(
            request.name, request.register_name, request.value))


def _replace(config: cfg.DriverConfig, **changes: Any) -> cfg.DriverConfig:
    import dataclasses
    return dataclasses.replace(config, **changes)


def _interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt


def main(args: Optional[List[str]] = None) -> int:
    """Run the driver node until Ctrl-C or SIGTERM; non-zero exit when it cannot start."""
    # Our own signal handling: the context stays valid until the servos are safe, so the
    # shutdown (torque off, port closed) is done and logged before ROS goes away.
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    # Set explicitly: a process started in the background inherits SIGINT ignored.
    signal.signal(signal.SIGINT, _interrupt)
    signal.signal(signal.SIGTERM, _interrupt)
    node: Optional[DriverNode] = None
    code = 0
    try:
        node = DriverNode()
        node.start()
        if node.config.executor == 'events':
            from rclpy.experimental import EventsExecutor
            executor: Any = EventsExecutor()
        else:
            executor = SingleThreadedExecutor()
        executor.add_node(node)
        while rclpy.ok():
            executor.spin_once(timeout_sec=0.2)
    except StartupFailure as exc:
        if not exc.logged:
            logger = node.get_logger() if node else rclpy.logging.get_logger(NODE_NAME)
            logger.fatal(str(exc))
        code = 1
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.shutdown()
            node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == '__main__':
    sys.exit(main())
