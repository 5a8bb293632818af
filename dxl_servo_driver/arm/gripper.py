"""
Grippers: goals from a gripper command, and grasp detection. No bus, no ROS.

A gripper is a current_based_position joint: its goal current bounds the current the position
controller may use, so closing on an object stops there and holds it with that current instead
of overloading. A grasp is a gripper stalled short of its goal with its current at the limit.
A goal with a speed (ParallelGripperCommand's velocity) is walked to: its setpoint moves from
where the gripper was at that speed, one step a cycle, whatever the servo's own profile.
"""

from collections import deque
from dataclasses import dataclass
import math
from typing import Deque, Optional, Protocol, Sequence, Tuple

from dxl_servo_driver.errors import BadRequest

__all__ = ['GraspDetector', 'GripperError', 'GripperListener', 'GripperOutcome', 'GripperRun',
           'GripperSample', 'GripperSpec', 'gripper_goal', 'parallel_command']

# Stalled: slower than this ...
STALL_RAD_S = 0.05
# ... for this long, ...
STALL_S = 0.2
# ... farther than this from the goal, ...
SHORT_OF_GOAL_RAD = 0.05
# ... with at least this share of the goal current.
AT_LIMIT = 0.7
# A goal this close beyond an end of the travel is taken as that end (float rounding).
TRAVEL_ROUNDING = 1e-9


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
    (open) to 1 (closed). A position beyond the travel (open .. closed) is refused, not
    clipped: a goal the mechanism cannot reach says the caller's units or its model of the
    gripper are wrong, and the gripper must not be driven into its stops on a guess. So is
    max_effort above the current limit.
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
    # A ratio of exactly 1 may land a rounding error past the end: that is the end.
    low, high = sorted((spec.open_rad, spec.closed_rad))
    if low - TRAVEL_ROUNDING <= goal < low:
        goal = low
    elif high < goal <= high + TRAVEL_ROUNDING:
        goal = high
    if not low <= goal <= high:
        raise GripperError(f'position {goal:g} is beyond the travel of gripper {spec.name!r}: '
                           f'{spec.open_rad:g} (open) .. {spec.closed_rad:g} (closed), '
                           'its gripper_open and gripper_closed')
    if math.isnan(max_effort) or max_effort == 0.0:
        return goal, None
    if not math.isfinite(max_effort) or max_effort < 0.0:
        raise GripperError(f'max_effort {max_effort} A is not a positive current')
    if max_effort > spec.current_limit_a + 1e-9:
        raise GripperError(f'max_effort {max_effort:g} A is above the current limit '
                           f'{spec.current_limit_a:g} A of joint {spec.name!r}')
    return goal, max_effort


def parallel_command(joint: str, names: Sequence[str], positions: Sequence[float],
                     velocities: Sequence[float], efforts: Sequence[float]
                     ) -> Tuple[float, float, float]:
    """
    Return (position, speed, effort) of a ParallelGripperCommand's command for joint.

    The command is a JointState naming this one joint, with one position and, optionally, one
    velocity (the most speed on the way) and one effort (the most it may close with); an empty
    array is not given, and so is 0 (MoveIt fills them only when configured: 0 here means the
    configured profile, or the configured goal current, as GripperCommand's max_effort 0 does).
    Raises GripperError naming what is wrong; the travel and the current limit are the
    arm's to check.
    """
    if list(names) != [joint]:
        given = ', '.join(repr(name) for name in names) or 'none'
        raise GripperError(f'command.name must be the one joint of this action, {joint!r}; '
                           f'got {given}')
    if len(positions) != 1:
        raise GripperError(f'command.position must hold one position (rad) for {joint!r}, '
                           f'got {len(positions)} values')
    for field, values in (('velocity', velocities), ('effort', efforts)):
        if len(values) > 1:
            raise GripperError(f'command.{field} must be empty or hold one value for '
                               f'{joint!r} (as command.name), got {len(values)}')
    position = positions[0]
    if not math.isfinite(position):
        raise GripperError(f'command.position {position} is not a finite number')
    speed = velocities[0] if velocities else 0.0
    effort = efforts[0] if efforts else 0.0
    if not math.isfinite(speed) or speed < 0.0:
        raise GripperError(f'command.velocity {speed} is not a finite speed >= 0 (the most '
                           'the gripper may move at; 0: no limit)')
    if not math.isfinite(effort) or effort < 0.0:
        raise GripperError(f'command.effort {effort} is not a finite effort >= 0 (the most '
                           'the gripper may close with; 0: the configured goal current)')
    return position, speed, effort


class GraspDetector:
    """
    Grasp of one gripper: stalled short of its goal, at its current limit, long enough.

    Positions and velocities are the joint's; scale (joint units per servo radian) puts the
    thresholds, which are the servo's, in them.
    """

    def __init__(self, scale: float = 1.0) -> None:
        self._stalled_since: Optional[float] = None
        self._scale = abs(scale)
        self.grasping = False

    def update(self, now_s: float, position: float, velocity: float, current: float,
               goal_position: float, goal_current: float) -> bool:
        """Take one sample; return whether the gripper holds an object now."""
        stalled = abs(velocity) < STALL_RAD_S * self._scale
        short = abs(goal_position - position) > SHORT_OF_GOAL_RAD * self._scale
        limited = goal_current > 0.0 and abs(current) >= AT_LIMIT * goal_current
        if stalled and short and limited:
            if self._stalled_since is None:
                self._stalled_since = now_s
            self.grasping = now_s - self._stalled_since >= STALL_S
        else:
            self._stalled_since = None
            self.grasping = False
        return self.grasping


# A gripper goal that stopped moving this long short of its goal, not at its current limit,
# ended somewhere it was not sent (blocked by something that is not an object in its grip).
STOPPED_S = 0.5

# How a gripper goal ended (GripperOutcome.how).
REACHED = 'reached'
STALLED = 'stalled'
STOPPED_SHORT = 'stopped_short'
PREEMPTED = 'preempted'
CANCELED = 'canceled'
ABORTED = 'aborted'


@dataclass(frozen=True)
class GripperSample:
    """What a gripper goal reports: position (rad), effort (N*m), stalled, reached, velocity."""

    position: float
    effort: float
    stalled: bool
    reached_goal: bool
    velocity: float = 0.0   # rad/s


@dataclass(frozen=True)
class GripperOutcome:
    """How a gripper goal ended, why (for a person), and the last sample."""

    how: str
    message: str
    sample: Optional[GripperSample]


class GripperListener(Protocol):
    """Who is told of a gripper goal's progress (an action goal). Called from the cycle."""

    feedback_period_s: float

    def feedback(self, sample: GripperSample) -> None:
        """Take one feedback sample."""

    def ended(self, outcome: GripperOutcome) -> None:
        """Take the end of the goal (exactly once)."""


class GripperRun:
    """
    One gripper goal, watched at every cycle until it ends.

    It ends when it reached its goal, stalled on an object, stopped short, or was preempted,
    canceled or aborted.

    goal_raw is the Goal Position it queued: when the servo's goal is something else, another
    command took the gripper (a ~/gripper message, a trajectory, a service) and the goal ends.
    With a speed (joint units per second) and where the gripper was (start_rad), the goal is
    walked to: next_setpoint gives each cycle's goal, and queued takes the raw value it became.
    """

    def __init__(self, joint: str, goal_rad: float, goal_raw: int, tolerance_rad: float,
                 listener: GripperListener, now_s: float, scale: float = 1.0,
                 start_rad: Optional[float] = None, speed: float = 0.0) -> None:
        self.joint = joint
        self._still_below = STALL_RAD_S * abs(scale)   # joint units per second
        self.goal_rad = goal_rad
        # The last few Goal Positions this goal queued: a step written a cycle late is ours.
        self._queued: Deque[int] = deque([goal_raw], maxlen=4)
        walked = speed > 0.0 and start_rad is not None and start_rad != goal_rad
        self._walk = (start_rad, now_s, speed) if walked else None
        self.setpoint = start_rad if walked else goal_rad
        self.tolerance_rad = tolerance_rad
        self.listener = listener
        self.cancel_requested = False
        self._written = False   # the servo's goal was seen to be ours
        self._next_feedback_s = now_s
        self._still_since: Optional[float] = None
        self.last: Optional[GripperSample] = None

    @property
    def walking(self) -> bool:
        """Return True while the setpoint of a goal with a speed is short of the goal."""
        return self.setpoint != self.goal_rad

    def next_setpoint(self, now_s: float) -> Optional[float]:
        """Return this cycle's goal of a goal walked at its speed (None: nothing to queue)."""
        if self._walk is None or not self.walking:
            return None
        start, start_s, speed = self._walk
        assert start is not None
        distance = self.goal_rad - start
        # From the time it began, not per cycle: a late cycle catches up, never adds up.
        travelled = speed * max(0.0, now_s - start_s)
        self.setpoint = (self.goal_rad if travelled >= abs(distance)
                         else start + math.copysign(travelled, distance))
        return self.setpoint

    def queued(self, goal_raw: int) -> None:
        """Take the raw Goal Position one of its steps was queued as."""
        self._queued.append(goal_raw)

    def watch(self, now_s: float, position: Optional[float], velocity: float, effort: float,
              grasping: bool, goal_raw_now: Optional[int], trouble: str
              ) -> Optional[GripperOutcome]:
        """Take one cycle (position None: no fresh sample); return the outcome if it ends."""
        if trouble:
            return GripperOutcome(ABORTED, f'joint {self.joint!r} {trouble}', self.last)
        if goal_raw_now in self._queued:
            self._written = True
        elif self._written:
            return GripperOutcome(PREEMPTED, f'joint {self.joint!r} was given another goal',
                                  self.last)
        if self.cancel_requested:
            return GripperOutcome(CANCELED, 'canceled: the gripper holds where it is',
                                  self.last)
        if position is None:
            return None
        reached = abs(position - self.goal_rad) <= self.tolerance_rad
        sample = GripperSample(position, effort, grasping, reached, velocity)
        self.last = sample
        if now_s >= self._next_feedback_s:
            self._next_feedback_s = now_s + self.listener.feedback_period_s
            self.listener.feedback(sample)
        if reached:
            return GripperOutcome(REACHED, f'reached {position:.4f} rad', sample)
        if grasping:
            return GripperOutcome(STALLED, f'stalled at {position:.4f} rad holding '
                                  f'{effort:.3f} N*m: an object in its grip', sample)
        if abs(velocity) < self._still_below and not self.walking:
            # A slow walk is not a stop: judged only once the setpoint is the goal.
            if self._still_since is None:
                self._still_since = now_s
            elif now_s - self._still_since >= STOPPED_S:
                return GripperOutcome(STOPPED_SHORT, f'stopped at {position:.4f} rad, '
                                      f'{abs(position - self.goal_rad):.4f} rad short of its '
                                      'goal, below its current limit', sample)
        else:
            self._still_since = None
        return None
