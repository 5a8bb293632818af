"""Waiting on a condition, never on a sleep: the one helper the tests share for it."""

import time
from typing import Callable


def wait_until(predicate: Callable[[], bool], timeout_s: float, what: str,
               poll_s: float = 0.005) -> None:
    """Return once predicate() holds; fail naming `what` if it does not within timeout_s."""
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, f'{what}: not within {timeout_s} s'
        time.sleep(poll_s)
