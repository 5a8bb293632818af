"""What the simulator's servo really did, sampled, to judge the samples a node published."""

import bisect
import threading
import time
from typing import Any, List

from node_harness import NodeHarness
from sensor_msgs.msg import JointState


def stamp_s(msg: Any) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


class Truth:
    """The simulator's wheel position sampled every millisecond, with wall-clock times."""

    def __init__(self, h: NodeHarness, servo_id: int) -> None:
        self._h = h
        self._id = servo_id
        self.times: List[float] = []
        self.raws: List[int] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            raw = self._h.reg(self._id, 'present_position')
            self.times.append(time.time())
            self.raws.append(raw)
            time.sleep(0.001)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()

    def between(self, start_s: float, end_s: float) -> List[int]:
        """Return the raw positions sampled in [start_s, end_s], with one sample either side."""
        low = max(0, bisect.bisect_left(self.times, start_s) - 1)
        high = min(len(self.times), bisect.bisect_right(self.times, end_s) + 1)
        return self.raws[low:high]


class Messages:
    """Every joint_states message, kept."""

    def __init__(self, h: NodeHarness) -> None:
        assert h.client is not None
        self.items: List[JointState] = []
        self._sub = h.client.node.create_subscription(
            JointState, f'{h.namespace}/joint_states', self.items.append, 200)
