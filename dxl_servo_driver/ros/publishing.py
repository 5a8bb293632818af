"""
What the node publishes: joint_states, ~/servo_states and /diagnostics.

joint_states and ~/servo_states exist while the node is configured (lifecycle publishers: they
publish only while active); /diagnostics always, since it says why nothing else does. The cycle
hands `Publishing.publish` each read; /diagnostics come from an executor timer instead, so they
still speak when the cycle has stopped or stalled.
"""

import time
from typing import Any, Callable, Dict, Protocol

from diagnostic_msgs.msg import DiagnosticArray
from dxl_servo_driver import config as cfg
from dxl_servo_driver.driver.manager import Manager
from dxl_servo_driver.ros.arm import Arm
from dxl_servo_driver.ros.cycle import CycleRunner
from dxl_servo_driver.ros.diagnostics import diagnostics
from dxl_servo_driver.ros.follow import Follow
from dxl_servo_driver.ros.messages import JointTable, servo_states, time_msg
from dxl_servo_driver_msgs.msg import ServoStateArray
from sensor_msgs.msg import JointState

__all__ = ['Host', 'Publishing']


class Host(Protocol):
    """What the publishing needs of the node."""

    manager: Manager
    config: cfg.DriverConfig
    arm: Arm
    follow: Follow

    @property
    def cycle(self) -> CycleRunner:
        """Return the node's cycle runner (what /diagnostics says of the cycle)."""

    def lifecycle_state(self) -> str:
        """Return the node's lifecycle state's label."""

    def create_publisher(self, *args: Any, **kwargs: Any) -> Any:
        """Create a publisher (rclpy Node)."""

    def create_lifecycle_publisher(self, *args: Any, **kwargs: Any) -> Any:
        """Create a lifecycle publisher (rclpy LifecycleNode)."""

    def destroy_lifecycle_publisher(self, publisher: Any) -> Any:
        """Destroy a lifecycle publisher (rclpy LifecycleNode)."""

    def create_timer(self, period_s: float, callback: Callable[[], None]) -> Any:
        """Create an executor timer (rclpy Node)."""

    def get_fully_qualified_name(self) -> str:
        """Return the node's full name: the diagnostics' names start with it."""

    def get_clock(self) -> Any:
        """Return the node's clock (rclpy Node)."""

    def get_logger(self) -> Any:
        """Return the node's logger (rclpy Node)."""


class Publishing:
    """The node's publishers, the rates they publish at, and the diagnostics' levels."""

    def __init__(self, host: Host) -> None:
        self._host = host
        self._joints = JointTable(host.manager.joints)
        self.joint_states_pub: Any = None
        self.servo_states_pub: Any = None
        self.diagnostics_pub = host.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.state_period_s = 0.0
        self._last_state_s = 0.0
        # The diagnostics' WARN/ERROR levels, by parameter name (config.THRESHOLDS).
        self.thresholds: Dict[str, float] = {}
        self.take(host.config)
        # Diagnostics come from the executor, not the cycle: they still speak when the cycle
        # has stopped or stalled.
        self._timer = host.create_timer(1.0, self.publish_diagnostics)

    def take(self, config: cfg.DriverConfig) -> None:
        """Take a configuration's state_rate and thresholds."""
        self.set_state_rate(config.state_rate)
        self.thresholds = {name: getattr(config, name) for name in cfg.THRESHOLDS}

    def set_state_rate(self, state_rate_hz: float) -> None:
        """Publish servo_states at this rate (0: never)."""
        self.state_period_s = (1.0 / state_rate_hz) if state_rate_hz else 0.0
        # servo_states and the 1 Hz diagnostics need the health part of the state block.
        self._host.manager.health_period_s = min(1.0, self.state_period_s or 1.0)

    def configured(self) -> None:
        """Take the servos configure found (their models known now); make the publishers."""
        self._joints = JointTable(self._host.manager.joints)
        problem = self._joints.check_wire()
        if problem:
            self._host.get_logger().warning(f'{problem}: joint_states go out as message objects '
                                            '(slower)')
        if self.joint_states_pub is None:
            self.joint_states_pub = self._host.create_lifecycle_publisher(
                JointState, 'joint_states', 10)
            self.servo_states_pub = self._host.create_lifecycle_publisher(
                ServoStateArray, '~/servo_states', 10)

    def drop(self) -> None:
        """Destroy joint_states and servo_states (cleanup, error)."""
        for publisher in (self.joint_states_pub, self.servo_states_pub):
            if publisher is not None:
                self._host.destroy_lifecycle_publisher(publisher)
        self.joint_states_pub = self.servo_states_pub = None

    def publish(self, stamp_ns: int, read_ok: bool) -> None:
        """Publish a cycle's read: joint_states, and servo_states when their period is up."""
        # The arm watched these samples first (Arm.watch_samples, a step of the cycle).
        if read_ok and self.joint_states_pub is not None:
            msg = self._joints.message(stamp_ns)
            if msg is not None:
                self.joint_states_pub.publish(msg)
        now = time.monotonic()
        if self.state_period_s and now - self._last_state_s >= self.state_period_s:
            self._last_state_s = now
            if self.servo_states_pub is not None:
                host = self._host
                self.servo_states_pub.publish(
                    servo_states(host.manager.order, time_msg(stamp_ns), host.arm.grasping()))

    def publish_diagnostics(self) -> None:
        """Publish /diagnostics (the timer's callback); a failure is logged, never raised."""
        host = self._host
        try:
            self.diagnostics_pub.publish(diagnostics(
                host.get_fully_qualified_name(), host.config, host.manager,
                host.cycle.facts(), host.lifecycle_state(), self.thresholds,
                host.get_clock().now().to_msg(),
                {**host.arm.facts(), **host.follow.follower.facts()}, host.arm.grasping()))
        except Exception as exc:  # noqa: B902 - a report must not stop the executor
            host.get_logger().error(f'diagnostics failed: {exc!r}', throttle_duration_sec=10.0)
