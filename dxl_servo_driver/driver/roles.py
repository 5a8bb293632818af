"""
What the parts that drive the manager call on it: the cycle loop's calls, the follower's.

The cycle loop (driver/loop.py) and the follower (driver/follow.py) are given a manager
(driver/manager.Manager) and are not built by it. They name here the few calls they make, so
that neither imports the manager, which imports the rest of driver/: the manager is the top of
its folder, imported only from above (test/package/test_layers.py). The manager has every call
below; mypy checks it (driver/manager.py).
"""

from typing import Callable, Mapping, Optional, Protocol, Sequence

from dxl_servo_driver.driver.context import Stats
from dxl_servo_driver.driver.servo import Result, Servo
from dxl_servo_driver.driver.state_block import BusBudget

__all__ = ['ManagerForFollower', 'ManagerForLoop']


class ManagerForLoop(Protocol):
    """The manager as the cycle loop drives it (driver/loop.CycleLoop)."""

    @property
    def stats(self) -> Stats:
        """Return what the cycle and recovery counted so far."""

    @property
    def read_in_flight(self) -> bool:
        """Return True while a cycle read is on the wire (begun, or chained by cycle_end)."""

    def cycle_begin(self, full: Optional[bool] = None,
                    stamp: Optional[Callable[[], None]] = None) -> bool:
        """Put the cycle's state read on the wire unless the port is lost; False when none is."""

    def cycle_end(self, retry_until: Optional[float] = None,
                  chain: Optional[Callable[[], None]] = None) -> bool:
        """Collect the read of cycle_begin(); False when the port was lost meanwhile."""

    def abort_read(self) -> None:
        """Give up the sync read in flight, if any, and release the locks (idempotent)."""

    def cycle_write(self, tasks_until: Optional[float] = None) -> None:
        """Command timeouts, pending goals, recovery steps; port loss handled."""

    def check_command_timeout(self) -> None:
        """Velocity, current and pwm goals fall back to zero after command_timeout or at an end."""

    def bus_budget(self) -> BusBudget:
        """Return what one cycle costs on this bus."""


class ManagerForFollower(Protocol):
    """The manager as the follower uses it (driver/follow.Follower): servos, goals, holds."""

    @property
    def servos(self) -> Mapping[str, Servo]:
        """Return the servos by joint name."""

    def command(self, kind: str, names: Sequence[str], values: Sequence[float],
                owner: str = '') -> Result:
        """Queue goals (topic path): written by the next cycle's sync write."""

    def hold(self, names: Sequence[str], owner: str, why: str) -> None:
        """Let only owner's goals reach these joints; others' are refused: 'joint <name> why'."""

    def release(self, owner: str) -> None:
        """Let everyone command the joints owner held."""
