"""
The follower's ROS side: the leader's joint_states subscription and the `~/follow` service.

The following itself is driver/follow.Follower, a step of the node's cycle: the subscription's
callback only hands it the newest message (names, positions, stamp), never writes; the cycle
takes it right before its goal write. `~/follow` (std_srvs/SetBool) engages (true) and
disengages (false) at run time; engaging ends the arm's trajectories and gripper goals (one
commander at a time: while the follower is engaged, the followed joints take no one else's).
A node without follow.topic has the service too, and answers that it is no follower.
"""

import time
from typing import Any, Protocol

from dxl_servo_driver import config as cfg
from dxl_servo_driver.driver.follow import Follower
from dxl_servo_driver.driver.manager import Manager
from dxl_servo_driver.ros.arm import Arm
from sensor_msgs.msg import JointState
from std_srvs.srv import SetBool

__all__ = ['Follow']

NOT_ACTIVE = 'the node is not active (lifecycle state)'


class Host(Protocol):
    """What the follower needs of the node."""

    manager: Manager
    config: cfg.DriverConfig
    arm: Arm

    @property
    def active(self) -> bool:
        """Say whether commands and services are taken: the node is active."""

    def get_logger(self) -> Any:
        """Return the node's logger (rclpy Node)."""

    def get_clock(self) -> Any:
        """Return the node's clock: the leader's stamps are on it."""

    def create_subscription(self, *args: Any, **kwargs: Any) -> Any:
        """Create a subscription (rclpy Node)."""

    def destroy_subscription(self, subscription: Any) -> Any:
        """Destroy a subscription (rclpy Node)."""

    def create_service(self, *args: Any, **kwargs: Any) -> Any:
        """Create a service (rclpy Node)."""


class Follow:
    """The leader's subscription, `~/follow`, and the Follower step the cycle runs."""

    def __init__(self, host: Host) -> None:
        self._host = host
        self.follower = Follower(lambda: host.manager, host.config, host.get_logger(),
                                 self._stamp_now)
        self._subscription: Any = None
        self._topic = ''
        self._subscribe(host.config.follow_topic)
        self.service = host.create_service(SetBool, '~/follow', self._on_follow)

    def _stamp_now(self) -> int:
        """Return now on the node's clock, ns (the leader's stamps are on the same clock)."""
        clock = self._host.get_clock()
        return clock.now().nanoseconds if clock.ros_time_is_active else time.time_ns()

    def _subscribe(self, topic: str) -> None:
        if topic == self._topic:
            return
        if self._subscription is not None:
            self._host.destroy_subscription(self._subscription)
            self._subscription = None
        self._topic = topic
        if topic:
            # Depth 1: only the newest message matters.
            self._subscription = self._host.create_subscription(
                JointState, topic, self._on_message, 1)

    def take(self, config: cfg.DriverConfig) -> None:
        """Take a new configuration (configure after parameters changed)."""
        self.follower.take(config)
        self._subscribe(config.follow_topic)

    def _on_message(self, msg: JointState) -> None:
        stamp = msg.header.stamp
        self.follower.offer(msg.name, msg.position, stamp.sec * 1_000_000_000 + stamp.nanosec)

    def start(self) -> None:
        """At activation: engaged when follow.engaged says so."""
        self.follower.start()

    def stop(self, why: str) -> None:
        """At deactivation: not following any more."""
        self.follower.stop(why)

    def _on_follow(self, request: Any, response: Any) -> Any:
        if not self._host.active:
            response.success, response.message = False, NOT_ACTIVE
            return response
        try:
            if request.data:
                was = self.follower.engaged
                result = self.follower.engage()
                if result.success and not was:
                    self._host.arm.cancel('preempted: the follower engaged (one commander at '
                                          'a time)')
            else:
                result = self.follower.disengage()
        except Exception as exc:  # noqa: B902 - services answer, they never raise
            response.success, response.message = False, f'internal error: {exc!r}'
            return response
        response.success, response.message = result.success, result.message
        return response
