"""
The ROS 2 node: lifecycle transitions and the wiring of its parts over the manager.

Its parts live beside it in dxl_servo_driver.ros, each held by the node as an object or called
with it: parameters (declarations, what changes when) and runtime (the configuration read from
them, a runtime change's hook), the cycle runner (its own thread at loop_rate, so it never
waits on the executor), publishing (joint_states, servo_states, /diagnostics: messages and
diagnostics build them), interfaces (command topics and services), the arm (trajectories,
joint-state and gripper commands), lifecycle_guard (rclpy's lifecycle internals) and main
(`ros2 run`). Topic and service callbacks only queue goals or call the manager, whose lock
keeps one transaction on the bus at a time.
"""

import threading
from typing import Any, Dict, List, Optional

from dxl_servo_driver import config as cfg
from dxl_servo_driver.driver.manager import Manager, ManagerError, open_transport, PortFactory
from dxl_servo_driver.errors import DriverError, Interrupted
from dxl_servo_driver.ros import parameters
from dxl_servo_driver.ros.actions import Actions
from dxl_servo_driver.ros.arm import Arm
from dxl_servo_driver.ros.cycle import CycleRunner
from dxl_servo_driver.ros.follow import Follow
from dxl_servo_driver.ros.interfaces import Interfaces
from dxl_servo_driver.ros.lifecycle_guard import guard_change_state, state_label
from dxl_servo_driver.ros.publishing import Publishing
from dxl_servo_driver.ros.runtime import RuntimeParameters
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn

__all__ = ['DriverNode', 'NODE_NAME', 'StartupFailure']

NODE_NAME = 'dxl_servo_driver'


class StartupFailure(DriverError):
    """The node cannot start; the message says why, in one line (or it was logged already)."""

    def __init__(self, message: str, logged: bool = False) -> None:
        super().__init__(message)
        self.logged = logged


class DriverNode(LifecycleNode):
    """
    One bus of Dynamixel servos as a lifecycle node.

    The lifecycle transitions and the wiring: each a few lines handing work to the manager,
    the runtime parameters, the publishing, the arm, the actions and the cycle loop; what has
    logic of its own lives in those.
    """

    def __init__(self, port_factory: PortFactory = open_transport, **kwargs: Any) -> None:
        """
        Make the node; port_factory opens its port at every configure (tests: their own).

        kwargs go to rclpy's LifecycleNode (context, namespace, parameter_overrides, ...).
        """
        super().__init__(NODE_NAME, automatically_declare_parameters_from_overrides=True,
                         **kwargs)
        self._port_factory = port_factory
        self.runtime = RuntimeParameters(self)
        try:
            self.config = self.runtime.read()
        except cfg.ConfigError as exc:
            raise StartupFailure(f'invalid configuration: {exc}') from None
        parameters.declare(self, self.config)
        # Set by a signal (main) or by shutdown(): every long activity stops at its next step.
        self.stop_requested = threading.Event()
        self.manager = self._new_manager(self.config)
        self._active = False
        self._shut_down = False
        self.arm = Arm(self, self.config)
        # MoveIt's actions, on a node and executor of their own (ros/actions.py says why).
        self.actions = Actions(self)
        # A follower copies a leader's joint_states (follow.topic) in the cycle: a step too.
        self.follow = Follow(self)
        self.publishing = Publishing(self)
        # The cycle steps the arm (trajectories, gripper goals) and publishes what it read.
        self._runner = CycleRunner(self, self.config.loop_rate, self.publishing.publish,
                                   [self.arm, self.follow.follower])
        self._interfaces = Interfaces(self)
        # The cycle thread cannot change the lifecycle state itself; this does, within 0.2 s.
        # (A timer, not a guard condition: the EventsExecutor does not wait on those.)
        self._watchdog = self.create_timer(0.2, self._on_cycle_failed)
        guard_change_state(self)
        self.add_pre_set_parameters_callback(parameters.coerce)
        self.add_on_set_parameters_callback(self.runtime.on_set)

    # what the parts see of the node ---------------------------------------------------------
    @property
    def active(self) -> bool:
        """Return whether the node is active: commands and services are taken."""
        return self._active

    @property
    def cycle(self) -> CycleRunner:
        """Return the cycle runner."""
        return self._runner

    @property
    def cycle_threaded(self) -> bool:
        """Return whether the cycle runs in its own thread (not from an executor timer)."""
        return self._runner.thread is not None

    @property
    def cycle_errors(self) -> int:
        """Return the cycles that failed and were survived."""
        return self._runner.cycle_errors

    @property
    def cycle_failure(self) -> Optional[BaseException]:
        """Return what ended the cycle for good, if anything did."""
        return self._runner.failure

    @property
    def _thread(self) -> Optional[threading.Thread]:
        return self._runner.thread

    @property
    def _loop_period_s(self) -> float:
        return self._runner.period_s

    def lifecycle_state(self) -> str:
        """Return the label of the lifecycle state ('unconfigured', 'active', ...)."""
        return state_label(self)

    def _new_manager(self, config: cfg.DriverConfig) -> Manager:
        log = self.get_logger()
        return Manager(config, info=log.info, warn=log.warning, error=log.error,
                       port_factory=self._port_factory, should_stop=self.stop_requested.is_set)

    # lifecycle -----------------------------------------------------------------------------
    def _reconfigure(self) -> bool:
        """Take parameters set while unconfigured; False (logged) when they do not validate."""
        try:
            config = self.runtime.read()
        except cfg.ConfigError as exc:
            self.get_logger().error(f'invalid configuration: {exc}')
            return False
        if config != self.config:
            self.config = config
            self.manager = self._new_manager(config)
            self._runner.period_s = 1.0 / config.loop_rate
            self.publishing.take(config)
            self.arm.take(config)
            self.follow.take(config)
            self.get_logger().info('configure: using the parameters set since the last one')
        return True

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Read the parameters, open the port, find and verify every servo, apply them."""
        if not self._reconfigure():
            return TransitionCallbackReturn.FAILURE
        try:
            self.manager.configure()
            return self._configured()
        except ManagerError as exc:
            self.get_logger().error(str(exc))
        except Interrupted:
            self.get_logger().warning('configure interrupted: stop requested')
        except Exception as exc:   # noqa: B902 (a defect: said, and the node stays up)
            # rclpy would turn it into the error state without a word of why.
            self.get_logger().error(f'configure failed: internal error: '
                                    f'{type(exc).__name__}: {exc}')
        self.manager.close()
        return TransitionCallbackReturn.FAILURE

    def _configured(self) -> TransitionCallbackReturn:
        """Take what the servos said at configure: tables, values in use, publishers."""
        # The servos said which model they are: the values the configuration left to them are
        # shown (ros2 param get), and their conversions are known now.
        values = self.runtime.from_servos(self.manager.joints)
        with self.runtime.declaring():
            parameters.show_from_servos(self, values)
        self.publishing.configured()
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Goal = present, torque on, start the cycle."""
        if self._runner.running:
            # Never a second cycle beside one that did not stop (it would share the bus).
            self.get_logger().error('activate refused: the bus cycle of the last activation '
                                    'has not ended yet')
            return TransitionCallbackReturn.FAILURE
        try:
            self.manager.activate()
            bus_cycle_s = self.manager.bus_budget().cycle_time_s
        except ManagerError as exc:
            self.get_logger().error(str(exc))
            return TransitionCallbackReturn.FAILURE
        except Interrupted:
            self.get_logger().warning('activate interrupted: stop requested')
            return TransitionCallbackReturn.FAILURE
        self._active = True
        self.follow.start()
        self._runner.start(self.config.cycle_driver, bus_cycle_s)
        self.get_logger().info(
            f'active: {len(self.manager.active_servos())} servos on {self.config.port} at '
            f'{self.config.baud_rate} bps, loop_rate {1.0 / self._runner.period_s:g} Hz')
        if self.config.port == 'sim':
            self._say_what_to_try()
        return super().on_activate(state)

    def _say_what_to_try(self) -> None:
        """
        On the simulated bus (make run), log commands a newcomer can paste next.

        The ros2 command line's, and the same from the repository's examples/ scripts: ROS 2
        from PyPI (make setup without a ROS install) has no `ros2` command.
        """
        text = 'try next:\n  ' + '\n  '.join(self.what_to_try())
        examples = self.what_to_try_without_ros2()
        if examples:
            text += ('\nor, without the ros2 command line (ROS 2 from PyPI), from the repository '
                     'after `. tools/env.sh`:\n  ' + '\n  '.join(examples))
        self.get_logger().info(text)

    def what_to_try(self) -> List[str]:
        """Return an echo of joint_states and a goal for a position and a velocity joint."""
        ns = self.get_fully_qualified_name()
        by_mode = {servo.mode: servo.name for servo in reversed(self.manager.joints)}
        lines = [f'ros2 topic echo {self.resolve_topic_name("joint_states")}']
        # A velocity goal needs fresh commands when command_timeout is set: a stream.
        for mode, how, value in (('position', '--once', 0.5), ('velocity', '-r 10', 1.0)):
            if mode in by_mode:
                lines.append(f'ros2 topic pub {how} {ns}/commands/{mode} '
                             f'dxl_servo_driver_msgs/msg/JointCommand '
                             f'"{{name: [{by_mode[mode]}], value: [{value}]}}"')
        return lines

    def what_to_try_without_ros2(self) -> List[str]:
        """Return what_to_try's goals as examples/move_and_echo.py lines (it echoes too)."""
        by_mode = {servo.mode: servo.name for servo in reversed(self.manager.joints)}
        where = ''
        if self.get_name() != NODE_NAME:
            where += f' --driver {self.get_name()}'
        if self.get_namespace() != '/':
            where += f' --ros-args -r __ns:={self.get_namespace()}'
        lines = []
        for mode, how, value in (('position', '', 0.5), ('velocity', ' --rate 10', 1.0)):
            if mode in by_mode:
                kind = '' if mode == 'position' else f' --kind {mode}'
                lines.append(f'python examples/move_and_echo.py {by_mode[mode]} {value}{kind}'
                             f'{how}{where}')
        return lines

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Stop the cycle; torque off if torque_off_on_shutdown (ERROR after a cycle failure)."""
        self._stop_cycle('the driver was deactivated')
        self._torque_off_and_say('deactivated')
        if self.cycle_failure is not None:
            return TransitionCallbackReturn.ERROR
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Close the port; parameters may be changed until the next configure."""
        self.manager.close()
        self.publishing.drop()
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Stop, torque off (if configured), close the port."""
        self.shutdown()
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        """After a failure: the cycle stopped, torque off, port closed; unconfigured."""
        self._stop_cycle('the driver went to its error state')
        if self.manager.bus is not None:
            self._torque_off_and_say('error')
        self.manager.close()
        self.publishing.drop()
        reason = f': {self.cycle_failure!r}' if self.cycle_failure is not None else ''
        self.get_logger().error(f'in the error state{reason}; port closed, node unconfigured '
                                '(configure and activate to try again)')
        return TransitionCallbackReturn.SUCCESS

    def _stop_cycle(self, why: str) -> None:
        self._active = False
        self._runner.stop()
        self.arm.cancel(why)
        self.follow.stop(why)

    def _torque_off(self) -> str:
        """
        Torque off (when configured to) every servo that may be on: '' or what failed.

        What failed is one phrase for the log: the joints grouped by the reason they were not
        switched off ("torque off FAILED for 'a', 'b': the port is lost (...)").
        """
        try:
            failures = self.manager.deactivate()
        except Exception as exc:  # noqa: B902 - a stop must end with a true line, whatever broke
            return f'torque off FAILED: {exc!r}'
        by_reason: Dict[str, List[str]] = {}
        for name, why in failures:
            by_reason.setdefault(why, []).append(repr(name))
        return '; '.join(f'torque off FAILED for {", ".join(names)}: {why}'
                         for why, names in by_reason.items())

    def _torque_off_and_say(self, why: str) -> None:
        """Torque off (when configured to); an error line says what failed."""
        failed = self._torque_off()
        if failed:
            self.get_logger().error(f'{why}: {failed}')
        elif not self.config.torque_off_on_shutdown:
            self.get_logger().info(f'{why}: torque left on (torque_off_on_shutdown is false)')

    def shutdown(self) -> None:
        """Stop the cycle, apply torque_off_on_shutdown, close the port; one line says so."""
        if self._shut_down:
            return
        self._shut_down = True
        self.stop_requested.set()
        self._stop_cycle('the driver shut down')
        if self.manager.bus is None:
            self.manager.close()
            return
        failed = self._torque_off()
        self.manager.close()
        port = f'port {self.config.port} closed'
        if failed:
            self.get_logger().error(f'stopped: {failed}; {port}')
        elif self.config.torque_off_on_shutdown:
            self.get_logger().info(f'stopped: torque off, {port}')
        else:
            self.get_logger().info(f'stopped: torque left on (torque_off_on_shutdown is false), '
                                   f'{port}')

    def destroy_node(self) -> None:
        """Stop the action servers with the node (their results sent first)."""
        actions = getattr(self, 'actions', None)   # None: the constructor failed before
        if actions is not None:
            actions.close()
        super().destroy_node()

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

    def _on_cycle_failed(self) -> None:
        # In the executor: the lifecycle moves through deactivate (ERROR) to on_error.
        if self.cycle_failure is not None and self.lifecycle_state() == 'active':
            self.trigger_deactivate()
