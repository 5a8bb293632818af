"""
Step-wise activities that must not stall the bus cycle: restoring a servo, rebooting it.

An activity is a generator that does at most one bus transaction between two yields. The cycle
runs a few steps of each in the time it has left, so a servo being restored never holds up the
others for more than a cycle's budget; a synchronous caller (configure, a service in a
timer-driven node) runs the same generator to its end at once.

A step that has nothing to do before some time (a servo booting) yields that time, on the
runner's clock: it is left alone until then, never stepped in a loop. The cycle holds the bus
while it steps tasks, so a task spinning on the clock would keep every request from the bus.
"""

import threading
import time
from typing import Any, Callable, Dict, Generator, Iterable, List, Optional, Tuple

# A step yields None (one transaction done, or none) or a float, the time it wants to wake at.
# Typed Any: mypy accepts a bare `yield` only where the yield type is None or Any.
Steps = Generator[Any, None, None]


def wait(until_s: float, clock: Callable[[], float] = time.monotonic) -> None:
    """Sleep until clock() reaches until_s (in short sleeps: the clock may be a test's)."""
    while True:
        left_s = until_s - clock()
        if left_s <= 0.0:
            return
        time.sleep(min(left_s, 0.01))


class Task:
    """One activity on one joint: its steps, its outcome, and an event for whoever waits."""

    def __init__(self, joint: str, kind: str, steps: Steps,
                 not_before_s: float = 0.0) -> None:
        self.joint = joint
        self.kind = kind
        self._steps = steps
        self.not_before_s = not_before_s   # do not start before this time (retry back-off)
        self.finished = threading.Event()
        self.error: Optional[BaseException] = None

    @property
    def done(self) -> bool:
        """Return True once the task ended (success, failure or cancelled)."""
        return self.finished.is_set()

    def step(self) -> bool:
        """Run one step; return True when the task has ended. Exceptions end it and propagate."""
        try:
            wake_s = next(self._steps)
        except StopIteration:
            self.finished.set()
            return True
        except BaseException as exc:
            self.error = exc
            self.finished.set()
            raise
        if wake_s is not None:
            self.not_before_s = float(wake_s)
        return False

    def run_to_end(self, clock: Callable[[], float] = time.monotonic) -> None:
        """Run every remaining step now (a synchronous caller), sleeping through its waits."""
        while not self.step():
            wait(self.not_before_s, clock)

    def cancel(self, reason: str) -> None:
        """End the task without running its remaining steps."""
        if self.done:
            return
        self.error = RuntimeError(reason)
        self._steps.close()
        self.finished.set()


class TaskRunner:
    """
    The tasks in progress, at most one per joint, stepped round-robin within a time budget.

    It only steps them: run() hands back the tasks that ended (and the exception that ended a
    failed one), and their owner (driver/recovery.py) decides what that means.
    """

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._tasks: Dict[str, Task] = {}
        self._clock = clock
        self._turn = 0

    def __contains__(self, joint: str) -> bool:
        """Return True when the joint has a task in progress."""
        return joint in self._tasks

    @property
    def idle(self) -> bool:
        """Return True when no task is in progress."""
        return not self._tasks

    def get(self, joint: str) -> Optional[Task]:
        """Return the joint's task in progress, or None."""
        return self._tasks.get(joint)

    def tasks(self) -> List[Task]:
        """Return the tasks in progress."""
        return list(self._tasks.values())

    def add(self, task: Task) -> Task:
        """Start a task; one already running for that joint is cancelled (superseded)."""
        old = self._tasks.get(task.joint)
        if old is not None:
            old.cancel(f'superseded by {task.kind}')
        self._tasks[task.joint] = task
        return task

    def cancel_all(self, reason: str, joints: Optional[Iterable[str]] = None) -> None:
        """Cancel every task (or those of the given joints)."""
        names = list(self._tasks) if joints is None else list(joints)
        for name in names:
            task = self._tasks.pop(name, None)
            if task is not None:
                task.cancel(reason)

    def run(self, until_s: float) -> Tuple[int, List[Tuple[Task, Optional[Exception]]]]:
        """
        Step the tasks round-robin until until_s; return (steps run, the tasks that ended).

        At least one step runs when a task is ready, so recovery always progresses, even in a
        loop with no time to spare. An ended task leaves the runner; a failed one comes with
        the exception that ended it.
        """
        steps = 0
        ended: List[Tuple[Task, Optional[Exception]]] = []
        while True:
            ready = [t for t in self._tasks.values() if t.not_before_s <= self._clock()]
            if not ready:
                return steps, ended
            task = ready[self._turn % len(ready)]
            self._turn += 1
            try:
                finished = task.step()
            except Exception as exc:  # noqa: B902 - the owner decides what a failure means
                self._tasks.pop(task.joint, None)
                ended.append((task, exc))
            else:
                if finished:
                    self._tasks.pop(task.joint, None)
                    ended.append((task, None))
            steps += 1
            if self._clock() >= until_s:
                return steps, ended
