"""What a simulated servo really did, recorded by the simulator, to judge published samples."""

import bisect
import time
from typing import Any, List, Optional

from node_harness import NodeHarness
from sensor_msgs.msg import JointState


def stamp_s(msg: Any) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


class Truth:
    """
    Every Present Position one simulated servo held, and from when: no sampling, no thread.

    The servo's register changes only when its physics is advanced (SimServo.advance, under the
    bus lock: at a packet, a register read, a console command). Each new value is recorded
    there with the wall-clock time (what a node stamps with), read right after the change: a
    value's end is never dated early, so a sample judged older than its stamp really was (a
    thread sampling every millisecond is starved on a loaded machine, and its gaps would have
    to be guessed around). A reply carries the value held when its request arrived.
    """

    def __init__(self, h: NodeHarness, servo_id: int) -> None:
        self._servo = h.sim.servo(servo_id)
        self.times: List[float] = []   # when each value began to be held (wall clock)
        self.raws: List[int] = []
        advance = self._servo.advance
        memory = self._servo.memory

        def recorded(now_s: float, lag_s: float = 0.0) -> None:
            advance(now_s, lag_s)
            value = memory.get('present_position')
            if not self.raws or value != self.raws[-1]:
                self.times.append(time.time())
                self.raws.append(value)
        with h.sim.lock:
            recorded(time.monotonic())
            self._servo.advance = recorded   # type: ignore[method-assign]

    def stop(self) -> None:
        """Stop recording (the servo advances as before)."""
        del self._servo.advance

    def age_s(self, raw: int, stamp: float, tolerance: int = 0) -> Optional[float]:
        """
        Return how long before stamp the servo last held raw (within tolerance pulses).

        0.0 when it held it at or after stamp; None when it never held it (before the end of
        the record).
        """
        for index in range(len(self.raws) - 1, -1, -1):
            if abs(self.raws[index] - raw) <= tolerance:
                if index + 1 == len(self.raws):
                    return 0.0   # still held
                return max(0.0, stamp - self.times[index + 1])
        return None

    def between(self, start_s: float, end_s: float) -> List[int]:
        """Return the values held at some time in [start_s, end_s]."""
        low = max(0, bisect.bisect_right(self.times, start_s) - 1)
        high = bisect.bisect_right(self.times, end_s)
        return self.raws[low:high]


class Messages:
    """Every joint_states message, kept."""

    def __init__(self, h: NodeHarness) -> None:
        assert h.client is not None
        self.items: List[JointState] = []
        self._sub = h.client.node.create_subscription(
            JointState, f'{h.namespace}/joint_states', self.items.append, 200)
