"""
The node's parameters as they change: the configuration read from them, a set taken.

The configuration is read from the parameters at construction and at every configure. Values
that the configuration left to the servos are shown as parameters once configure found them
(ros2 param get), yet stay the servos' until someone sets them. A set while the node runs is
checked by ros/parameters.check_changes, and each runtime parameter's change then does what
its hook (`RuntimeParameters.hooks`) says.
"""

import contextlib
import functools
from typing import Any, Callable, Dict, Iterator, List, Protocol, Sequence

from dxl_servo_driver import config as cfg
from dxl_servo_driver.driver.manager import Manager, Servo
from dxl_servo_driver.errors import DriverError
from dxl_servo_driver.ros import parameters
from dxl_servo_driver.ros.arm import Arm
from dxl_servo_driver.ros.cycle import CycleRunner
from dxl_servo_driver.ros.publishing import Publishing
from rcl_interfaces.msg import SetParametersResult
from rclpy.parameter import Parameter

__all__ = ['Host', 'RuntimeParameters']


class Host(Protocol):
    """What the runtime parameters need of the node."""

    config: cfg.DriverConfig
    manager: Manager
    arm: Arm
    publishing: Publishing

    @property
    def cycle(self) -> CycleRunner:
        """Return the node's cycle runner (loop_rate)."""

    def lifecycle_state(self) -> str:
        """Return the node's lifecycle state's label."""

    def get_parameters_by_prefix(self, prefix: str) -> Dict[str, Parameter]:
        """Return the node's parameters by name (rclpy Node)."""


class RuntimeParameters:
    """The configuration the node's parameters make, and what a change of one does."""

    def __init__(self, host: Host) -> None:
        self._host = host
        # Values declared from what the servos answered (see read), and whether the node is
        # declaring its own parameters (a set is then taken as it is).
        self._from_servos: Dict[str, Any] = {}
        self._declaring = False

    def read(self) -> cfg.DriverConfig:
        """Return the configuration of the parameters; ConfigError when they do not validate."""
        params = {name: p.value
                  for name, p in self._host.get_parameters_by_prefix('').items()}
        # A value the node declared from the servo (the torque constant in use) is not the
        # file's: unless someone set it since, the joint still leaves it to the servo.
        for name, value in self._from_servos.items():
            if params.get(name) == value:
                del params[name]
        return cfg.validate(params)

    def from_servos(self, servos: Sequence[Servo]) -> Dict[str, Any]:
        """Return (and remember) the values in use that the configuration left to the servos."""
        self._from_servos = {
            f'{servo.name}.torque_constant': servo.units.torque_constant_nm_per_a
            for servo in servos if servo.joint.torque_constant_nm_per_a is None}
        for servo in servos:
            # The limits in force when the file gives none: the servo's, in joint units.
            low, high = servo.joint_position_range()
            for key, value in (('min_position', low), ('max_position', high)):
                if getattr(servo.joint, key) is None:
                    self._from_servos[f'{servo.name}.{key}'] = value
        return self._from_servos

    @contextlib.contextmanager
    def declaring(self) -> Iterator[None]:
        """Take every set as it is while the node declares its own parameters."""
        self._declaring = True
        try:
            yield
        finally:
            self._declaring = False

    def on_set(self, params: List[Parameter]) -> SetParametersResult:
        """Take a set of parameters (rclpy's on-set callback): refused, or each change done."""
        if self._declaring:
            return SetParametersResult(successful=True)
        host = self._host
        try:
            changes = parameters.check_changes(params, host.lifecycle_state(),
                                               host.publishing.thresholds)
        except DriverError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        for name, value in changes.items():
            # Kept in the configuration too: configure compares it with the parameters.
            host.config = cfg.replace(host.config, **{name: value})
            self.hooks()[name](value)
        return SetParametersResult(successful=True)

    def hooks(self) -> Dict[str, Callable[[Any], None]]:
        """
        Return what a change of each runtime parameter does while the node runs.

        One entry per `runtime=True` parameter of config.PARAMS (test_parameters checks that
        none is missing): a new runtime parameter needs its hook here, or a set would fail.
        """
        host = self._host

        def command_timeout(value: float) -> None:
            host.manager.config = cfg.replace(host.manager.config, command_timeout=value)

        def goal_tolerance(value: float) -> None:
            host.arm.trajectories.tolerance_rad = value

        def read_from_config(value: Any) -> None:
            pass   # each new trajectory or goal reads it from the node's config

        hooks: Dict[str, Callable[[Any], None]] = {
            'loop_rate': host.cycle.set_rate, 'state_rate': host.publishing.set_state_rate,
            'command_timeout': command_timeout, 'goal_tolerance': goal_tolerance,
            'goal_time_tolerance': read_from_config, 'action_monitor_rate': read_from_config}
        for name in cfg.THRESHOLDS:   # the diagnostics' WARN/ERROR levels
            hooks[name] = functools.partial(host.publishing.thresholds.__setitem__, name)
        return hooks
