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
import traceback
from typing import Any, Callable, Dict, List, Optional, Tuple

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from dxl_servo_driver import config as cfg
from dxl_servo_driver import control_table as ct
from dxl_servo_driver.errors import Interrupted
from dxl_servo_driver.manager import (
    IDX_EFFORT, IDX_HW_ERROR, IDX_MOVING, IDX_MOVING_STATUS, IDX_POSITION, IDX_PWM,
    IDX_TEMPERATURE, IDX_TORQUE, IDX_VELOCITY, IDX_VOLTAGE, Manager, ManagerError,
    Servo)
from dxl_servo_driver.tasks import Task
from dxl_servo_driver_msgs.msg import JointCommand, ServoState, ServoStateArray
from dxl_servo_driver_msgs.srv import (
    ReadRegister, Reboot, SetGoals, SetOperatingMode, SetTorque, WriteRegister)
from rcl_interfaces.msg import (
    FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType, SetParametersResult)
import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import JointState

NODE_NAME = 'dxl_servo_driver'
COMMAND_KINDS = ('position', 'velocity', 'current', 'pwm')
# Parameters that may change while the node runs; the others need a restart.
RUNTIME_PARAMS = ('loop_rate', 'state_rate', 'command_timeout', 'temperature_warn',
                  'temperature_error', 'voltage_low', 'voltage_high')
RATE_LOG_INTERVAL_S = 60.0
# A cycle that has not completed for this long (and five periods) is reported as stalled.
STALL_S = 1.0
REBOOT_WAIT_S = 10.0   # a reboot service waits this long for its servos to come back
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
        self.reset()

    def reset(self) -> None:
        """Start measuring afresh (a new activation)."""
        self._count = 0
        self._start = time.monotonic()
        self.rate_hz = 0.0
        self.windows = 0

    def tick(self) -> None:
        """Count one cycle."""
        self._count += 1
        now = time.monotonic()
        if now - self._start >= self._window_s:
            self.rate_hz = self._count / (now - self._start)
            self._count = 0
            self._start = now
            self.windows += 1


class Shortfall:
    """
    Decide whether the bus is why the loop falls short of loop_rate.

    A rate window below 90 % of the requested rate counts only when the bus work of the cycles
    (read, retries, write) took 90 % of the period or more; two such windows in a row blame the
    bus, once, with the measured rate. A loop slowed by a busy machine is reported as that.
    """

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """Forget the past (a new activation, a new loop_rate)."""
        self._bus_s = 0.0
        self._cycles = 0
        self._windows_bus = 0
        self._windows_cpu = 0
        self.blamed = False

    def add_cycle(self, bus_s: float) -> None:
        """Count one cycle and the time it spent on the bus."""
        self._bus_s += bus_s
        self._cycles += 1

    def window(self, measured_hz: float, requested_hz: float) -> str:
        """Close a rate window; return 'bus', 'machine' or '' (what to report, once)."""
        busy = self._bus_s / self._cycles if self._cycles else 0.0
        self._bus_s = 0.0
        self._cycles = 0
        if measured_hz >= 0.9 * requested_hz:
            self._windows_bus = self._windows_cpu = 0
            self.blamed = False
            return ''
        if busy >= 0.9 / requested_hz:
            self._windows_bus += 1
            self._windows_cpu = 0
        else:
            self._windows_cpu += 1
            self._windows_bus = 0
        if self.blamed:
            return ''
        if self._windows_bus >= 2:
            self.blamed = True
            return 'bus'
        if self._windows_cpu >= 2:
            self.blamed = True
            return 'machine'
        return ''


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
        # Set by a signal (main) or by shutdown(): every long activity stops at its next step.
        self.stop_requested = threading.Event()
        self.manager = Manager(self.config, info=log.info, warn=log.warning, error=log.error,
                               should_stop=self.stop_requested.is_set)
        self._active = False
        self._shut_down = False
        self._stop = threading.Event()
        self._wake = threading.Event()     # cuts the cycle's sleep short (stop, new loop_rate)
        self._thread: Optional[threading.Thread] = None
        self._timer: Any = None
        self._rate = RateMeter()
        self._shortfall = Shortfall()
        self._loop_period_s = 1.0 / self.config.loop_rate
        self._period_changed = False
        self._state_period_s = (1.0 / self.config.state_rate) if self.config.state_rate else 0.0
        self._set_health_period()
        self._thresholds = {name: getattr(self.config, name) for name in RUNTIME_PARAMS[3:]}
        self._last_state_s = 0.0
        self._joint_state = JointState()
        self._bus_cycle_s = 0.0
        self._read_stamp: Any = None
        self._read_began_s = 0.0
        self._next_rate_log_s = 0.0
        self._last_cycle_s = 0.0
        self.cycle_errors = 0
        self.cycle_failure: Optional[BaseException] = None
        assert (IDX_POSITION, IDX_VELOCITY, IDX_EFFORT) == (0, 1, 2)
        self._joint_table: List[Tuple[Servo, str, int, float, float, float]] = []
        self._build_joint_table()
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
        # Diagnostics come from the executor, not the cycle: they still speak when the cycle
        # has stopped or stalled.
        self._diagnostics_timer = self.create_timer(1.0, self._publish_diagnostics)
        # The cycle thread cannot change the lifecycle state itself; this does, within 0.2 s.
        # (A timer, not a guard condition: the EventsExecutor does not wait on those.)
        self._watchdog = self.create_timer(0.2, self._on_cycle_failed)
        self._guard_change_state()
        self.add_pre_set_parameters_callback(self._coerce_parameters)
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
            ]
            if joint.torque_constant_nm_per_a is not None:
                entries.append(
                    ('torque_constant', joint.torque_constant_nm_per_a,
                     "Effort = current x this [N*m/A]; unset: the model's datasheet stall "
                     'torque / stall current (seed: 4.1 N*m at 2.3 A).',
                     ParameterType.PARAMETER_DOUBLE))
            if joint.model is not None:
                entries.append(
                    ('model', joint.model.name,
                     'The model the servo must be (name or number); another is refused.',
                     ParameterType.PARAMETER_STRING))
            for register, value in joint.registers:
                item = cfg.describe_register(joint, register)
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

    def _coerce_parameters(self, params: List[Parameter]) -> List[Parameter]:
        # `ros2 param set ... loop_rate 50` sends an integer: a number is a number.
        out = []
        for param in params:
            spec = cfg.PARAMS_BY_NAME.get(param.name)
            if (spec is not None and spec.kind is float
                    and param.type_ == Parameter.Type.INTEGER):
                param = Parameter(param.name, Parameter.Type.DOUBLE, float(param.value))
            out.append(param)
        return out

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
        thresholds = dict(self._thresholds)
        thresholds.update({k: v for k, v in changes.items() if k in thresholds})
        try:
            cfg.check_thresholds(thresholds)
        except cfg.ConfigError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        for name, value in changes.items():
            if name == 'loop_rate':
                self._loop_period_s = 1.0 / value
                self._period_changed = True
                self._shortfall.reset()
                self._wake.set()
                if self._timer is not None:
                    self.destroy_timer(self._timer)
                    self._timer = self.create_timer(self._loop_period_s, self._timer_cycle)
            elif name == 'state_rate':
                self._state_period_s = (1.0 / value) if value else 0.0
                self._set_health_period()
            elif name == 'command_timeout':
                self.manager.config = _replace(self.manager.config, command_timeout=value)
            else:
                self._thresholds[name] = value
        return SetParametersResult(successful=True)

    # lifecycle -----------------------------------------------------------------------------
    def _guard_change_state(self) -> None:
        """Answer an impossible lifecycle request with success false, not a dead node."""
        service = self._service_change_state
        original = service.callback

        def change_state(request: Any, response: Any) -> Any:
            try:
                return original(request, response)
            except _rclpy.RCLError as exc:
                state = self._state_machine.current_state[1]
                transition = request.transition.label or str(request.transition.id)
                self.get_logger().warning(
                    f'lifecycle transition {transition!r} refused in state {state!r}: '
                    f'{str(exc).splitlines()[0]}')
                response.success = False
                return response
        service.callback = change_state

    def _lifecycle_state(self) -> str:
        return str(self._state_machine.current_state[1])

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Open the port, find and verify every servo, apply the configuration."""
        try:
            self.manager.configure()
        except ManagerError as exc:
            self.get_logger().error(str(exc))
            self.manager.close()
            return TransitionCallbackReturn.FAILURE
        except Interrupted:
            self.get_logger().warning('configure interrupted: stop requested')
            self.manager.close()
            return TransitionCallbackReturn.FAILURE
        self._build_joint_table()
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Goal = present, torque on, start the cycle."""
        try:
            self.manager.activate()
            self._bus_cycle_s = self.manager.bus_budget().cycle_time_s
        except ManagerError as exc:
            self.get_logger().error(str(exc))
            return TransitionCallbackReturn.FAILURE
        except Interrupted:
            self.get_logger().warning('activate interrupted: stop requested')
            return TransitionCallbackReturn.FAILURE
        self._stop.clear()
        self._wake.clear()
        self._rate.reset()
        self._shortfall.reset()
        self._next_rate_log_s = 0.0
        self._last_cycle_s = time.monotonic()
        self.cycle_failure = None
        self._active = True
        if self.config.cycle_driver == 'timer':
            self._timer = self.create_timer(self._loop_period_s, self._timer_cycle)
        else:
            self._thread = threading.Thread(target=self._run, name='dxl_bus_cycle',
                                            daemon=True)
            self._thread.start()
        self.get_logger().info(
            f'active: {len(self.manager.active_servos())} servos on {self.config.port} at '
            f'{self.config.baud_rate} bps, loop_rate {1.0 / self._loop_period_s:g} Hz')
        return super().on_activate(state)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Stop the cycle; torque off if torque_off_on_shutdown (ERROR after a cycle failure)."""
        self._stop_cycle()
        self._torque_off_and_say('deactivated')
        if self.cycle_failure is not None:
            return TransitionCallbackReturn.ERROR
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Close the port."""
        self.manager.close()
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Stop, torque off (if configured), close the port."""
        self.shutdown()
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        """After a failure: the cycle stopped, torque off, port closed; unconfigured."""
        self._stop_cycle()
        if self.manager.bus is not None:
            self._torque_off_and_say('error')
        self.manager.close()
        reason = f': {self.cycle_failure!r}' if self.cycle_failure is not None else ''
        self.get_logger().error(f'in the error state{reason}; port closed, node unconfigured '
                                '(configure and activate to try again)')
        return TransitionCallbackReturn.SUCCESS

    def _stop_cycle(self) -> None:
        self._active = False
        self._stop.set()
        self._wake.set()
        if self._timer is not None:
            self.destroy_timer(self._timer)
            self._timer = None
        if self._thread is not None:
            if self._thread is not threading.current_thread():
                self._thread.join(timeout=5.0)
                if self._thread.is_alive():
                    self.get_logger().error('the bus cycle did not stop within 5 s')
            self._thread = None

    def _torque_off_and_say(self, why: str) -> bool:
        """Torque off (when configured to) every servo that may be on; log what happened."""
        failures = self.manager.deactivate()
        if not self.config.torque_off_on_shutdown:
            self.get_logger().info(f'{why}: torque left on (torque_off_on_shutdown is false)')
            return True
        if failures:
            self.get_logger().error(f'{why}: torque off FAILED for {len(failures)} servo(s): '
                                    + '; '.join(failures))
            return False
        return True

    def shutdown(self) -> None:
        """Stop the cycle, apply torque_off_on_shutdown, close the port. Idempotent."""
        if self._shut_down:
            return
        self._shut_down = True
        self.stop_requested.set()
        self._stop_cycle()
        if self.manager.bus is None:
            self.manager.close()
            return
        ok = self._torque_off_and_say('stopped')
        self.manager.close()
        if ok:
            torque = 'torque off' if self.config.torque_off_on_shutdown else 'torque left on'
            self.get_logger().info(f'stopped: {torque}, port {self.config.port} closed')
        else:
            self.get_logger().error(f'stopped: port {self.config.port} closed; some servos may '
                                    'still have torque on (see above)')

    def start(self) -> None:
        """With autostart, configure and activate; StartupFailure when that fails."""
        if not self.config.autostart:
            self.get_logger().info('autostart is false: waiting for lifecycle transitions')
            return
        # on_configure / on_activate logged the reason: one clear line, not two.
        if self.trigger_configure() != TransitionCallbackReturn.SUCCESS:
            if self.stop_requested.is_set():
                raise Interrupted('stop requested while configuring')
            raise StartupFailure('configure failed', logged=True)
        if self.trigger_activate() != TransitionCallbackReturn.SUCCESS:
            if self.stop_requested.is_set():
                raise Interrupted('stop requested while activating')
            raise StartupFailure('activate failed', logged=True)

    # the cycle -----------------------------------------------------------------------------
    def _run(self) -> None:
        """Run the bus cycle in its thread; if it ever fails for good, say so and go to error."""
        try:
            self._cycle_loop()
        except BaseException as exc:  # noqa: B902 - never a silent death of the cycle
            self.cycle_failure = exc
            self.manager.abort_read()
            self.get_logger().fatal(
                f'the bus cycle stopped: {exc!r}; going to the error state (torque off)\n'
                + ''.join(traceback.format_exception(exc)))

    def _on_cycle_failed(self) -> None:
        # In the executor: the lifecycle moves through deactivate (ERROR) to on_error.
        if self.cycle_failure is not None and self._lifecycle_state() == 'active':
            self.trigger_deactivate()

    def _cycle_loop(self) -> None:
        """
        Read, write goals, step recovery, publish, pace; until stopped.

        When the next cycle is due at once (the loop runs as fast as the bus allows), the next
        read goes on the wire before this cycle is published, so publishing overlaps the bus
        transaction instead of adding to it. Any exception is logged, counted and survived.
        """
        next_s = time.monotonic()
        reading = False
        pipelined = False
        while not self._stop.is_set():
            try:
                if not pipelined:
                    reading = self._begin()
                stamp, began_s = self._read_stamp, self._read_began_s
                ok = reading and self._end(began_s)
                reading = False
                period = self._loop_period_s
                next_s += period
                now = time.monotonic()
                if next_s < now - period:
                    next_s = now   # behind: run as fast as the bus allows, without a backlog
                self.manager.cycle_write(tasks_until=next_s - self._bus_cycle_s)
                self._shortfall.add_cycle(time.monotonic() - began_s)
                pipelined = next_s - time.monotonic() <= self._bus_cycle_s
                if pipelined:
                    reading = self._begin()
                self._publish(stamp, ok)
            except Exception as exc:  # noqa: B902 - the cycle must survive anything
                self.cycle_errors += 1
                self.manager.abort_read()
                reading = pipelined = False
                self.get_logger().error(f'cycle failed: {exc!r}', throttle_duration_sec=2.0)
                self._stop.wait(0.05)
                next_s = time.monotonic()
            self._last_cycle_s = time.monotonic()
            self._tick_rate()
            if not pipelined:
                delay = next_s - time.monotonic()
                if delay > 0.0 and self._wake.wait(delay):
                    self._wake.clear()
                if self._period_changed:
                    self._period_changed = False
                    next_s = time.monotonic()
        self.manager.abort_read()   # never leave the bus held

    def _begin(self) -> bool:
        """Stamp and start a read; False when nothing is in flight (port lost, no servo)."""
        self._read_stamp = self.get_clock().now().to_msg()
        self._read_began_s = time.monotonic()
        return self.manager.cycle_begin()

    def _end(self, began_s: float) -> bool:
        # Lost or corrupted replies are read again while the cycle has time (or twice the bus
        # time when the loop runs as fast as the bus allows).
        retry_until = began_s + max(0.9 * self._loop_period_s, 2.0 * self._bus_cycle_s)
        return self.manager.cycle_end(retry_until)

    def _timer_cycle(self) -> None:
        try:
            began = self._begin()
            ok = began and self._end(self._read_began_s)
            now = time.monotonic()
            self.manager.cycle_write(tasks_until=now + 0.5 * self._loop_period_s)
            self._shortfall.add_cycle(time.monotonic() - self._read_began_s)
            self._publish(self._read_stamp, ok)
        except Exception as exc:  # noqa: B902 - the cycle must survive anything
            self.cycle_errors += 1
            self.manager.abort_read()
            self.get_logger().error(f'cycle failed: {exc!r}', throttle_duration_sec=2.0)
        self._last_cycle_s = time.monotonic()
        self._tick_rate()

    def _tick_rate(self) -> None:
        windows = self._rate.windows
        self._rate.tick()
        if self._rate.windows != windows:
            requested = 1.0 / self._loop_period_s
            blame = self._shortfall.window(self._rate.rate_hz, requested)
            budget = self.manager.bus_budget()
            if blame == 'bus':
                self.get_logger().warning(
                    f'the bus cannot keep loop_rate {requested:g} Hz: measured '
                    f'{self._rate.rate_hz:.1f} Hz (bus limit {budget.rate_limit_hz:.0f} Hz); '
                    'running as fast as it allows')
            elif blame == 'machine':
                self.get_logger().warning(
                    f'loop_rate {requested:g} Hz not reached: measured '
                    f'{self._rate.rate_hz:.1f} Hz while the bus had time to spare (the '
                    'machine is busy)')
        if time.monotonic() >= self._next_rate_log_s:
            self._log_rate()

    def _log_rate(self) -> None:
        # A first report once the rate has settled, then one a minute.
        first = self._next_rate_log_s == 0.0
        self._next_rate_log_s = time.monotonic() + (3.0 if first else RATE_LOG_INTERVAL_S)
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

    def _build_joint_table(self) -> None:
        # The conversions of models.units, inlined with per-joint constants (joint_states runs
        # every cycle); rebuilt once the servos said which model they are.
        self._joint_table = [
            (servo, servo.name, servo.units.zero_raw, servo.units.rad_per_pulse,
             servo.units.rad_s_per_velocity_raw, servo.units.effort_nm_per_raw)
            for servo in self.manager.order]

    def _publish_joint_states(self, stamp: Any) -> None:
        msg = self._joint_state
        msg.header.stamp = stamp
        names = []
        positions = []
        velocities = []
        efforts = []
        for servo, name, zero, rad_per_pulse, rad_s, nm_per_raw in self._joint_table:
            state = servo.state
            if not servo.fresh or state is None:
                continue   # never a stale or invented value
            names.append(name)
            positions.append((state[0] + servo.turn_offset - zero) * rad_per_pulse)
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
        units = servo.units
        msg.position = units.position_to_rad(state[IDX_POSITION] + servo.turn_offset)
        msg.velocity = units.velocity_to_rad_s(state[IDX_VELOCITY])
        # NaN on a model that senses no current (its effort comes from Present Load).
        msg.current = (units.current_to_a(state[IDX_EFFORT])
                       if units.effort_register == 'present_current' else math.nan)
        if not servo.health_time:
            msg.pwm = msg.input_voltage = msg.temperature = math.nan
            return msg
        msg.torque_enabled = bool(state[IDX_TORQUE])
        # NaN where the model's state block has no room for it (an X330 before firmware 53).
        msg.pwm = units.pwm_to_ratio(state[IDX_PWM]) if servo.block.has_pwm else math.nan
        msg.input_voltage = units.voltage_to_v(state[IDX_VOLTAGE])
        msg.temperature = float(state[IDX_TEMPERATURE])
        msg.moving = bool(state[IDX_MOVING])
        msg.moving_status = state[IDX_MOVING_STATUS]
        msg.hardware_error_status = state[IDX_HW_ERROR]
        msg.hardware_errors = servo.model.decode_hardware_errors(state[IDX_HW_ERROR])
        return msg

    def _servo_states(self, stamp: Any) -> ServoStateArray:
        msg = ServoStateArray()
        msg.header.stamp = stamp
        msg.servos = [self._servo_state(servo) for servo in self.manager.order]
        return msg

    def _publish_diagnostics(self) -> None:
        try:
            self.diagnostics_pub.publish(self._diagnostics(self.get_clock().now().to_msg()))
        except Exception as exc:  # noqa: B902 - a report must not stop the executor
            self.get_logger().error(f'diagnostics failed: {exc!r}', throttle_duration_sec=10.0)

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
        stalled_s = time.monotonic() - self._last_cycle_s
        state = self._lifecycle_state()
        if self.cycle_failure is not None:
            bus_status.level = DiagnosticStatus.ERROR
            bus_status.message = f'the bus cycle stopped: {self.cycle_failure!r}'
        elif state != 'active':
            bus_status.level = DiagnosticStatus.WARN
            bus_status.message = f'not active ({state})'
        elif manager.port_lost:
            bus_status.level = DiagnosticStatus.ERROR
            bus_status.message = f'port lost, reconnecting: {manager.port_error}'
        elif stalled_s > max(STALL_S, 5.0 * self._loop_period_s):
            bus_status.level = DiagnosticStatus.ERROR
            bus_status.message = f'the bus cycle has not completed for {stalled_s:.1f} s'
        elif measured < 0.9 * min(requested, budget.rate_limit_hz):
            bus_status.level = DiagnosticStatus.WARN
            bus_status.message = (f'{measured:.0f} Hz, below the requested {requested:g} Hz '
                                  f'(bus limit {budget.rate_limit_hz:.0f} Hz)')
        counters = bus.counters if bus is not None else None
        values = {
            'port': self.config.port, 'baud_rate': self.config.baud_rate,
            'lifecycle_state': state,
            'loop_rate_requested_hz': f'{requested:g}',
            'loop_rate_measured_hz': f'{measured:.1f}',
            'bus_limit_hz': f'{budget.rate_limit_hz:.0f}',
            'cycles': manager.cycles, 'cycle_errors': self.cycle_errors,
            'read_failures': manager.read_failures,
            'timeouts': counters.timeouts if counters else 0,
            'corrupt_replies': counters.corrupt if counters else 0,
            'status_errors': counters.status_errors if counters else 0,
            'discarded_replies': counters.stale if counters else 0,
            'stale_samples_refused': manager.stale_refused,
            'flushed_bytes': counters.flushed_bytes if counters else 0,
            'adapter_echo': bus.echo if bus is not None else False,
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
        elif servo.status:
            level = DiagnosticStatus.WARN
            problems.append(servo.status)
        elif not servo.fresh:
            level = DiagnosticStatus.ERROR
            problems.append('not answering')
        values = {'id': servo.servo_id, 'model': servo.model.name,
                  'model_number': servo.model_number,
                  'torque_constant_nm_per_a': f'{servo.units.torque_constant_nm_per_a:.4g}',
                  'effort_from': servo.units.effort_register,
                  'firmware_version': servo.firmware_version, 'operating_mode': servo.mode,
                  'comm_errors': servo.comm_errors, 'stale_samples_refused': servo.stale_refused,
                  'restarts': servo.restarts, 'recoveries': servo.recoveries,
                  'turn_offset_pulses': servo.turn_offset}
        if state is not None and servo.health_time:
            temperature = float(state[IDX_TEMPERATURE])
            voltage = servo.units.voltage_to_v(state[IDX_VOLTAGE])
            errors = servo.model.decode_hardware_errors(state[IDX_HW_ERROR])
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
    def _command_callback(self, kind: str) -> Callable[[JointCommand], None]:
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

    def _guard(self, response: Any, action: Callable[[], Any]) -> Any:
        """Run a service action; a callback never raises, and inactive refuses."""
        if not self._active:
            response.success = False
            response.message = 'the node is not active (lifecycle state)'
            return response
        try:
            result = action()
        except Exception as exc:  # noqa: B902 - services answer, they never raise
            response.success = False
            response.message = f'internal error: {exc!r}'
            return response
        response.success = result.success
        response.message = result.message
        return response

    def _set_goals_callback(self, kind: str) -> Callable[[Any, Any], Any]:
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

    def _wait_tasks(self, tasks: List[Task]) -> None:
        # The cycle thread steps the reboots; this (executor) thread only waits for them.
        deadline = time.monotonic() + REBOOT_WAIT_S
        for task in tasks:
            task.finished.wait(max(0.0, deadline - time.monotonic()))
            if not task.done:
                task.cancel(f'did not finish within {REBOOT_WAIT_S:g} s')

    def _on_reboot(self, request: Any, response: Any) -> Any:
        # With a timer-driven cycle nobody else would step the reboots: they run here.
        wait = self._wait_tasks if self._thread is not None else None
        return self._guard(response, lambda: self.manager.reboot(list(request.name), wait))

    def _on_read_register(self, request: Any, response: Any) -> Any:
        if not self._active:
            response.success = False
            response.message = 'the node is not active (lifecycle state)'
            return response
        try:
            value, message = self.manager.read_register(request.name, request.register_name)
        except Exception as exc:  # noqa: B902 - services answer, they never raise
            value, message = None, f'internal error: {exc!r}'
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


class _Signals:
    """
    SIGINT/SIGTERM as a request, never as an exception in the middle of a transaction.

    The first signal asks the node to stop; the main loop then shuts it down in order (cycle
    stopped, torque off, port closed). Later signals are counted and change nothing: the
    torque-off is never cut short.
    """

    def __init__(self) -> None:
        self.received = 0
        self.stop = threading.Event()
        self._node_stop: Optional[threading.Event] = None

    def attach(self, node_stop: threading.Event) -> None:
        """Pass a stop request on to the node's long activities too."""
        self._node_stop = node_stop
        if self.stop.is_set():
            node_stop.set()

    def __call__(self, signum: int, frame: Any) -> None:
        self.received += 1
        self.stop.set()
        if self._node_stop is not None:
            self._node_stop.set()


def _params_files(argv: List[str]) -> List[str]:
    """Return the --params-file arguments of a ROS command line."""
    files = []
    in_ros_args = False
    for index, arg in enumerate(argv):
        if arg == '--ros-args':
            in_ros_args = True
        elif arg == '--':
            in_ros_args = False
        elif in_ros_args and arg == '--params-file' and index + 1 < len(argv):
            files.append(argv[index + 1])
    return files


def main(args: Optional[List[str]] = None) -> int:
    """Run the driver node until Ctrl-C or SIGTERM; non-zero exit when it cannot start."""
    logger = rclpy.logging.get_logger(NODE_NAME)
    argv = list(sys.argv if args is None else args)
    signals = _Signals()
    # Our own signal handling: the context stays valid until the servos are safe, so the
    # shutdown (torque off, port closed) is done and logged while ROS is still up. Set
    # explicitly: a process started in the background inherits SIGINT ignored.
    signal.signal(signal.SIGINT, signals)
    signal.signal(signal.SIGTERM, signals)
    # ROS reads parameter files in C and answers a bad one with a traceback: check them first.
    for path in _params_files(argv):
        try:
            cfg.check_parameter_file(path)
        except cfg.ParameterFileError as exc:
            logger.fatal(str(exc))
            return 1
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except (_rclpy.RCLError, RuntimeError, ValueError) as exc:
        logger.fatal(f'cannot start ROS: {str(exc).splitlines()[0]}')
        return 1
    node: Optional[DriverNode] = None
    code = 0
    try:
        try:
            node = DriverNode()
        except (ValueError, TypeError, _rclpy.RCLError) as exc:
            # A parameter ROS itself refuses (an empty list on the command line, ...).
            raise StartupFailure(f'invalid configuration: {exc}') from None
        signals.attach(node.stop_requested)
        node.start()
        if node.config.executor == 'events':
            from rclpy.experimental import EventsExecutor
            executor: Any = EventsExecutor()
        else:
            executor = SingleThreadedExecutor()
        executor.add_node(node)
        while rclpy.ok() and not signals.stop.is_set():
            executor.spin_once(timeout_sec=0.2)
    except StartupFailure as exc:
        if not exc.logged:
            (node.get_logger() if node else logger).fatal(str(exc))
        code = 1
    except Interrupted:
        (node.get_logger() if node else logger).info('stop requested during start-up')
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.shutdown()
            if signals.received > 1:
                node.get_logger().info(f'{signals.received - 1} more stop signal(s) received '
                                       'while stopping: the shutdown was completed anyway')
            node.destroy_node()
        rclpy.try_shutdown()
    return code


if __name__ == '__main__':
    sys.exit(main())
