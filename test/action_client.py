"""An action client for tests whose requests go out from its node's executor thread."""

from typing import Any, Callable, List, Optional

from conditions import wait_until
from rclpy.action import ActionClient


class Client(ActionClient):
    """An ActionClient that remembers its node, for in_executor."""

    def __init__(self, node: Any, *args: Any, **kwargs: Any) -> None:
        super().__init__(node, *args, **kwargs)
        self.owner = node


def in_executor(node: Any, call: Callable[[], Any]) -> Any:
    """
    Return what call returns, run in the executor thread of node (a one-shot timer).

    rclpy's ActionClient files a request's future only after sending it: sent from another
    thread, an answer the executor takes in between is dropped as unexpected, and its goal is
    never answered. In the executor's own thread nothing is taken in between.
    """
    made: List[Any] = []

    def once() -> None:
        timer.cancel()
        made.append(call())
    timer = node.create_timer(0.001, once)
    wait_until(lambda: bool(made), 10.0, 'the executor ran the call')
    node.destroy_timer(timer)
    return made[0]


def send_goal(client: Client, goal: Any,
              feedback: Optional[Callable[[Any], None]] = None, timeout_s: float = 10.0) -> Any:
    """Send a goal; return its handle once the server answered."""
    future = in_executor(client.owner,
                         lambda: client.send_goal_async(goal, feedback_callback=feedback))
    wait_until(future.done, timeout_s, 'the goal answered')
    return future.result()


def result_of(client: Client, handle: Any, timeout_s: float = 15.0) -> Any:
    """Return a goal's result response (status, result) once it ended."""
    future = in_executor(client.owner, handle.get_result_async)
    wait_until(future.done, timeout_s, 'the goal ended')
    return future.result()
