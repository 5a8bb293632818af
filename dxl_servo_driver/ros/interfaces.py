"""
The node's command topics and services, each a thin call into the manager.

Topic callbacks only queue goals (the cycle writes them); services answer after the bus
transaction, never raise, and refuse while the node is not active.
"""

import time
from typing import Any, Callable, List, Protocol

from dxl_servo_driver.driver.manager import Manager, Result
from dxl_servo_driver.driver.tasks import Task
from dxl_servo_driver.models import modes
from dxl_servo_driver.ros.arm import Arm
from dxl_servo_driver_msgs.msg import GripperCommand, JointCommand
from dxl_servo_driver_msgs.srv import (
    ReadRegister, Reboot, SetGoals, SetOperatingMode, SetTorque, WriteRegister)
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory

REBOOT_WAIT_S = 10.0   # a reboot service waits this long for its servos to come back
NOT_ACTIVE = 'the node is not active (lifecycle state)'


class Host(Protocol):
    """What the interfaces need of the node."""

    manager: Manager
    arm: Arm

    @property
    def active(self) -> bool:
        """Say whether commands and services are taken: the node is active."""

    @property
    def cycle_threaded(self) -> bool:
        """Return whether a cycle thread (not the executor) steps the manager's tasks."""

    def create_subscription(self, *args: Any, **kwargs: Any) -> Any:
        """Create a subscription (rclpy Node)."""

    def create_service(self, *args: Any, **kwargs: Any) -> Any:
        """Create a service (rclpy Node)."""

    def get_logger(self) -> Any:
        """Return the node's logger (rclpy Node)."""


class Interfaces:
    """The command topics (~/commands/<kind>) and services (~/set_<kind>, ~/reboot, ...)."""

    def __init__(self, host: Host) -> None:
        self._host = host
        self.subscriptions = [
            host.create_subscription(JointCommand, f'~/commands/{kind}', self._refusable(
                f'{kind} command', self._queue(kind)), 10)
            for kind in modes.COMMAND_KINDS]
        # Arms: a trajectory executed in the driver's cycle, and what ros2_control's topic
        # bridge (JointStateTopicSystem) publishes as its commands.
        arm = host.arm
        self.subscriptions += [
            host.create_subscription(JointTrajectory, '~/joint_trajectory',
                                     self._refusable('trajectory', arm.submit_trajectory), 10),
            host.create_subscription(JointState, '~/joint_command',
                                     self._refusable('joint_command', arm.joint_command), 10),
            host.create_subscription(GripperCommand, '~/gripper',
                                     self._refusable('gripper', arm.gripper_command), 10),
        ]
        self.services = [
            host.create_service(SetGoals, f'~/set_{kind}', self._set_goals_callback(kind))
            for kind in modes.COMMAND_KINDS]
        self.services += [
            host.create_service(SetOperatingMode, '~/set_operating_mode', self._on_set_mode),
            host.create_service(SetTorque, '~/set_torque', self._on_set_torque),
            host.create_service(Reboot, '~/reboot', self._on_reboot),
            host.create_service(ReadRegister, '~/read_register', self._on_read_register),
            host.create_service(WriteRegister, '~/write_register', self._on_write_register),
        ]

    def _queue(self, kind: str) -> Callable[[JointCommand], Result]:
        def take(msg: JointCommand) -> Result:
            return self._host.manager.command(kind, list(msg.name), list(msg.value))
        return take

    def _refusable(self, what: str, take: Callable[[Any], Result]) -> Callable[[Any], None]:
        def callback(msg: Any) -> None:
            log = self._host.get_logger()
            if not self._host.active:
                log.warning(f'{what} ignored: the node is not active', throttle_duration_sec=2.0)
                return
            try:
                result = take(msg)
            except Exception as exc:  # noqa: B902 - a bad message must not stop the node
                result = Result(False, f'internal error: {exc!r}')
            if not result.success:
                log.error(f'{what} refused: {result.message}', throttle_duration_sec=1.0)
        return callback

    def _guard(self, response: Any, action: Callable[[], Any]) -> Any:
        """Run a service action; a callback never raises, and inactive refuses."""
        if not self._host.active:
            response.success = False
            response.message = NOT_ACTIVE
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
            return self._guard(response, lambda: self._host.manager.command_now(
                kind, list(request.name), list(request.value)))
        return callback

    def _on_set_mode(self, request: Any, response: Any) -> Any:
        return self._guard(response, lambda: self._host.manager.set_operating_mode(
            list(request.name), request.mode))

    def _on_set_torque(self, request: Any, response: Any) -> Any:
        return self._guard(response, lambda: self._host.manager.set_torque(
            list(request.name), request.enable))

    @staticmethod
    def _wait_tasks(tasks: List[Task]) -> None:
        # The cycle thread steps the reboots; this (executor) thread only waits for them.
        deadline = time.monotonic() + REBOOT_WAIT_S
        for task in tasks:
            task.finished.wait(max(0.0, deadline - time.monotonic()))
            if not task.done:
                task.cancel(f'did not finish within {REBOOT_WAIT_S:g} s')

    def _on_reboot(self, request: Any, response: Any) -> Any:
        # With a timer-driven cycle nobody else would step the reboots: they run here.
        wait = self._wait_tasks if self._host.cycle_threaded else None
        return self._guard(response, lambda: self._host.manager.reboot(list(request.name), wait))

    def _on_read_register(self, request: Any, response: Any) -> Any:
        if not self._host.active:
            response.success = False
            response.message = NOT_ACTIVE
            return response
        try:
            result = self._host.manager.read_register(request.name, request.register_name)
        except Exception as exc:  # noqa: B902 - services answer, they never raise
            result = Result(False, f'internal error: {exc!r}')
        response.success = result.success
        response.value = result.value if result.success else 0
        response.message = result.message
        return response

    def _on_write_register(self, request: Any, response: Any) -> Any:
        return self._guard(response, lambda: self._host.manager.write_register(
            request.name, request.register_name, request.value))
