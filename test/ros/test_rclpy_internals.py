"""
The rclpy internals the node leans on are still there (ros/lifecycle_guard.py).

rclpy's LifecycleNode gives no public hook to answer an impossible transition with success
false instead of an exception that ends the executor's spin, nor a public getter of the current
state. The node wraps `_service_change_state.callback` and reads `_state_machine.current_state`,
catching `_rclpy.RCLError`. These are private: this test fails the day an rclpy release renames
or reshapes them, instead of a node that silently stops guarding its lifecycle.
"""

from node_harness import NodeHarness, sim_params
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.lifecycle import LifecycleNode


def test_the_private_members_the_lifecycle_guard_uses_exist() -> None:
    assert issubclass(_rclpy.RCLError, Exception)
    with NodeHarness(sim_params({'j': {'id': 1, 'operating_mode': 'position'}})) as h:
        node = h.node
        assert isinstance(node, LifecycleNode)
        service = node._service_change_state
        assert callable(service.callback)
        # The guard replaced it with its own wrapper, and the state reads as a label.
        assert service.callback.__name__ == 'change_state'
        state_id, label = node._state_machine.current_state
        assert isinstance(state_id, int) and label == 'active'


def test_an_impossible_transition_is_refused_and_the_node_lives() -> None:
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState
    with NodeHarness(sim_params({'j': {'id': 1, 'operating_mode': 'position'}})) as h:
        assert h.client is not None and h.node is not None
        client = h.client.node.create_client(
            ChangeState, f'{h.namespace}/dxl_servo_driver/change_state')
        assert client.wait_for_service(timeout_sec=10.0)
        request = ChangeState.Request()
        request.transition.id = Transition.TRANSITION_ACTIVATE   # active already
        future = client.call_async(request)
        h.joint_states.wait(lambda m: future.done(), timeout_s=10.0)
        assert future.result() is not None and not future.result().success
        # Still cycling: a fresh message after the refusal.
        seen = h.joint_states.received
        h.joint_states.wait(lambda m: h.joint_states.received > seen + 2, timeout_s=10.0)
