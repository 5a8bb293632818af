"""
The node's bus cycle: the loop of driver/loop.py, stamped by the ROS clock, said in the node's log.

The loop below ROS (driver/loop.CycleLoop) owns the cycle: read, samples, chaining, the steps
(the arm's trajectories and gripper goals), goal write, pacing, rate, both drivers (its own
thread dxl_bus_cycle, or an executor timer of the node's), never two threads. This side hands
it what only the node has: the publish callback, the stamp of the samples on the node's clock
(sim time included), the node's logger and timers; and turns what the loop measured into the
facts /diagnostics says of the cycle.
"""

import time
from typing import Any, Callable, Protocol, Sequence

from dxl_servo_driver.driver.loop import CycleLoop, CycleStep, Publish, RATE_LOG_INTERVAL_S
from dxl_servo_driver.driver.manager import Manager
from dxl_servo_driver.ros.diagnostics import CycleFacts

__all__ = ['CycleRunner', 'Host', 'RATE_LOG_INTERVAL_S']


class Host(Protocol):
    """What the runner needs of the node."""

    manager: Manager

    def get_logger(self) -> Any:
        """Return the node's logger."""

    def get_clock(self) -> Any:
        """Return the node's clock (stamps of the samples)."""

    def create_timer(self, period_s: float, callback: Callable[[], None]) -> Any:
        """Create an executor timer."""

    def destroy_timer(self, timer: Any) -> Any:
        """Destroy an executor timer."""


class CycleRunner(CycleLoop):
    """The node's cycle loop: its manager, clock, logger and timers; its diagnostics."""

    def __init__(self, host: Host, loop_rate_hz: float, publish: Publish,
                 steps: Sequence[CycleStep] = ()) -> None:
        self._host = host
        # The node's manager of the moment: a reconfigure replaces it.
        super().__init__(lambda: host.manager, loop_rate_hz, publish, host.get_logger(),
                         self._ros_stamp, steps, timers=host)

    def _ros_stamp(self) -> int:
        """Return the time of the read about to go on the wire on the node's clock, in ns."""
        clock = self._host.get_clock()
        # The ROS clock is the system clock (CLOCK_REALTIME, as time.time_ns) unless sim time
        # is active: read directly, it costs a tenth of building an rclpy Time every cycle.
        return clock.now().nanoseconds if clock.ros_time_is_active else time.time_ns()

    def facts(self) -> CycleFacts:
        """Return what the diagnostics say of the cycle."""
        return CycleFacts(self.rate.rate_hz, 1.0 / self.period_s,
                          time.monotonic() - self.last_cycle_s, self.cycle_errors, self.failure,
                          self.cycle_threads)
