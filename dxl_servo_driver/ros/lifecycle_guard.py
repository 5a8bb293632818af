"""
The rclpy lifecycle internals the node leans on, in one place.

rclpy's LifecycleNode (Jazzy, rclpy 7.1) has no public hook to answer an impossible transition
with success false, nor a public getter of the current state: both are read from its private
members here (`_service_change_state`, `_state_machine`, like `_rclpy.RCLError`), and
test/ros/test_rclpy_internals.py fails the day an rclpy release changes any of them.
"""

from typing import Any

from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.lifecycle import LifecycleNode

__all__ = ['guard_change_state', 'state_label']


def state_label(node: LifecycleNode) -> str:
    """Return the label of the node's lifecycle state ('unconfigured', 'active', ...)."""
    return str(node._state_machine.current_state[1])


def guard_change_state(node: LifecycleNode) -> None:
    """
    Answer an impossible lifecycle request with success false, not a dead node.

    The change_state service raises RCLError out of the executor for a transition the state
    does not have (`ros2 lifecycle set` of activate twice), which ends the spin. So the
    service's callback is wrapped: the refusal is logged and answered.
    """
    service = node._service_change_state
    original = service.callback

    def change_state(request: Any, response: Any) -> Any:
        try:
            return original(request, response)
        except _rclpy.RCLError as exc:
            state = node._state_machine.current_state[1]
            transition = request.transition.label or str(request.transition.id)
            node.get_logger().warning(
                f'lifecycle transition {transition!r} refused in state {state!r}: '
                f'{str(exc).splitlines()[0]}')
            response.success = False
            return response
    service.callback = change_state
