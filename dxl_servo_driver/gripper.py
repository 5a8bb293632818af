"""
Grippers: goals from a gripper command, and grasp detection. No bus, no ROS.

A gripper is a current_based_position joint: its goal current bounds the current the position
controller may use, so closing on an object stops there and holds it with that current instead
of overloading. A grasp is a gripper stalled short of its goal with its current at the limit.
"""

from dataclasses import dataclass
import math
from typing import Optional, Tuple

from dxl_servo_driver.errors import BadRequest

__all__ = ['GraspDetector', 'GripperError', 'GripperSpec', 'gripper_goal']

# Stalled: slower than this ...
STALL_RAD_S = 0.05
# ... for this long, ...
STALL_S = 0.2
# ... farther than this from the goal, ...
SHORT_OF_GOAL_RAD = 0.05
# ... with at least this share of the goal current.
AT_LIMIT = 0.7


class GripperError(BadRequest):
    """A gripper command refused; the message says why."""


@dataclass(frozen=True)
class GripperSpec:
    """A gripper joint: its open and closed positions (rad) and its current limit (A)."""

    name: str
    open_rad: float
    closed_rad: float
    current_limit_a: float


def gripper_goal(spec: GripperSpec, position: float, ratio: float,
                 max_effort: float) -> Tuple[float, Optional[float]]:
    """
    Return (goal position rad, goal current A or None to keep the configured one).

    Exactly one of position and ratio is a number (the other NaN); the ratio runs from 0
    (open) to 1 (closed); max_effort above the current limit is refused, not clipped.
    """
    has_position = not math.isnan(position)
    has_ratio = not math.isnan(ratio)
    if has_position == has_ratio:
        raise GripperError('give the goal as position (rad) or as ratio (0 open .. 1 closed), '
                           'the other NaN')
    if has_ratio:
        if not 0.0 <= ratio <= 1.0:
            raise GripperError(f'ratio {ratio:g} is outside 0 (open) .. 1 (closed)')
        goal = spec.open_rad + ratio * (spec.closed_rad - spec.open_rad)
    else:
        if not math.isfinite(position):
            raise GripperError(f'position {position} is not a finite number')
        goal = position
    if math.isnan(max_effort) or max_effort == 0.0:
        return goal, None
    if not math.isfinite(max_effort) or max_effort < 0.0:
        raise GripperError(f'max_effort {max_effort} A is not a positive current')
    if max_effort > spec.current_limit_a + 1e-9:
        raise GripperError(f'max_effort {max_effort:g} A is above the current limit '
                           f'{spec.current_limit_a:g} A of joint {spec.name!r}')
    return goal, max_effort


class GraspDetector:
    """Grasp of one gripper: stalled short of its goal, at its current limit, long enough."""

    def __init__(self) -> None:
        self._stalled_since: Optional[float] = None
        self.grasping = False

    def update(self, now_s: float, position: float, velocity: float, current: float,
               goal_position: float, goal_current: float) -> bool:
        """Take one sample; return whether the gripper holds an object now."""
        stalled = abs(velocity) < STALL_RAD_S
        short = abs(goal_position - position) > SHORT_OF_GOAL_RAD
        limited = goal_current > 0.0 and abs(current) >= AT_LIMIT * goal_current
        if stalled and short and limited:
            if self._stalled_since is None:
                self._stalled_since = now_s
            self.grasping = now_s - self._stalled_since >= STALL_S
        else:
            self._stalled_since = None
            self.grasping = False
        return self.grasping
