"""
Joint trajectories executed in the driver's own cycle: checked, sampled, watched; no bus, no ROS.

A trajectory is checked whole before anything moves (known joints in a position mode, times
strictly increasing, finite values, positions within each joint's limits) and then sampled at
every cycle: cubic (Hermite) between two points that both give velocities, linear otherwise;
before its first point it moves from where the joints were commanded (or were) when it began,
after its last it holds the last point.

Several trajectories run side by side when their joints differ (two arms on one bus, an arm and a
head); one that shares a joint with a running one replaces it from its own start time, starting
from the positions the old one commanded then (the old one ends as preempted). Each is watched
against its tolerances, the way ros2_controllers' joint_trajectory_controller does: beyond a path
tolerance on a fresh sample it ends at once and its joints hold where they are; it succeeds once
every joint is within its goal tolerance after the last point, and fails when that has not happened
goal_time_s later. A trajectory may have a listener (an action goal) told of feedback and its end.
"""

from dataclasses import dataclass, field
import math
import threading
from typing import Callable, Dict, List, Optional, Protocol, Sequence, Tuple

from dxl_servo_driver.errors import BadRequest
from dxl_servo_driver.models import modes

__all__ = ['Executor', 'Feedback', 'Limits', 'Listener', 'Outcome', 'Point', 'Tolerances',
           'Trajectory', 'TrajectoryError', 'TrajectoryJointsError', 'validate']

# After the last point, how long the joints get to reach their goal tolerance by default.
SETTLE_S = 0.5

# How a trajectory ended (Outcome.how).
SUCCEEDED = 'succeeded'
PATH_VIOLATED = 'path_tolerance_violated'
GOAL_VIOLATED = 'goal_tolerance_violated'
PREEMPTED = 'preempted'
CANCELED = 'canceled'
ABORTED = 'aborted'


class TrajectoryError(BadRequest):
    """A trajectory refused whole; the message says why."""


class TrajectoryJointsError(TrajectoryError):
    """A trajectory refused for its joints (unknown, not on the bus, not in a position mode)."""


@dataclass(frozen=True)
class Point:
    """One waypoint: seconds from the start, positions (rad), velocities (rad/s) or empty."""

    time_s: float
    positions: Tuple[float, ...]
    velocities: Tuple[float, ...] = ()


@dataclass(frozen=True)
class Limits:
    """What the driver knows of one joint when a trajectory arrives."""

    mode: str
    low_rad: float
    high_rad: float
    online: bool = True


@dataclass(frozen=True)
class Tolerances:
    """
    Per joint (in the trajectory's joint order): path and goal tolerances; 0 = not checked.

    path_* apply while the trajectory runs (position rad, velocity rad/s), goal_* after its last
    point; goal_time_s is how long after the last point the goal tolerances may take.
    """

    path_position: Tuple[float, ...]
    path_velocity: Tuple[float, ...]
    goal_position: Tuple[float, ...]
    goal_velocity: Tuple[float, ...]
    goal_time_s: float = SETTLE_S

    @classmethod
    def goal_only(cls, joints: int, goal_rad: float, goal_time_s: float = SETTLE_S
                  ) -> 'Tolerances':
        """Return tolerances that check only the end position (the topic's trajectories)."""
        zeros = (0.0,) * joints
        return cls(zeros, zeros, (goal_rad,) * joints, zeros, goal_time_s)


@dataclass(frozen=True)
class Feedback:
    """One sample of a running trajectory: desired and actual per joint, from a fresh read."""

    joints: Tuple[str, ...]
    desired: Tuple[float, ...]
    desired_velocity: Tuple[float, ...]
    actual: Tuple[float, ...]
    actual_velocity: Tuple[float, ...]


@dataclass
class Outcome:
    """How a trajectory ended: how, why (for a person), the worst final error, joints beyond."""

    worst_rad: float
    beyond: List[Tuple[str, float]]
    how: str = SUCCEEDED
    message: str = ''


class Listener(Protocol):
    """Who is told of a trajectory's progress (an action goal). Called from the cycle thread."""

    feedback_period_s: float

    def feedback(self, sample: Feedback) -> None:
        """Take one feedback sample (at most once per feedback_period_s)."""

    def ended(self, outcome: Outcome) -> None:
        """Take the end of the trajectory (exactly once)."""


@dataclass(eq=False)
class Trajectory:
    """A validated trajectory with its start time on the driver's clock (monotonic seconds)."""

    joints: Tuple[str, ...]
    start_s: float
    points: Tuple[Point, ...]
    tolerances: Optional[Tolerances] = None
    listener: Optional[Listener] = None
    label: str = 'a trajectory'
    # Where each joint starts from; set when the trajectory begins.
    initial: Optional[Tuple[float, ...]] = None
    next_feedback_s: float = field(default=0.0)
    cancel_requested: bool = False

    @property
    def end_s(self) -> float:
        """Return the time of the last point."""
        return self.start_s + self.points[-1].time_s

    def sample(self, now_s: float) -> Tuple[float, ...]:
        """Return the positions at now_s (the trajectory has begun: initial is set)."""
        return self.sample_with_velocity(now_s)[0]

    def sample_with_velocity(self, now_s: float) -> Tuple[Tuple[float, ...], Tuple[float, ...]]:
        """Return (positions, velocities) at now_s (the trajectory has begun)."""
        assert self.initial is not None, 'sample() before the trajectory began'
        t = now_s - self.start_s
        points = self.points
        still = tuple(0.0 for _ in self.joints)
        if t >= points[-1].time_s:
            return points[-1].positions, points[-1].velocities or still
        before = Point(0.0, self.initial, still if points[0].velocities else ())
        for after in points:
            if t < after.time_s:
                return _interpolate(before, after, t)
            before = after
        return points[-1].positions, points[-1].velocities or still


def _interpolate(a: Point, b: Point, t: float) -> Tuple[Tuple[float, ...], Tuple[float, ...]]:
    span = b.time_s - a.time_s
    if span <= 0.0:
        return b.positions, tuple(0.0 for _ in b.positions)
    s = min(max((t - a.time_s) / span, 0.0), 1.0)
    if not a.velocities or not b.velocities:
        return (tuple(p0 + (p1 - p0) * s for p0, p1 in zip(a.positions, b.positions)),
                tuple((p1 - p0) / span for p0, p1 in zip(a.positions, b.positions)))
    # Cubic Hermite: positions and velocities met at both ends.
    h00 = 2 * s ** 3 - 3 * s ** 2 + 1
    h10 = s ** 3 - 2 * s ** 2 + s
    h01 = -2 * s ** 3 + 3 * s ** 2
    h11 = s ** 3 - s ** 2
    # Their derivatives in s; d/dt = d/ds / span.
    d00 = 6 * s ** 2 - 6 * s
    d10 = 3 * s ** 2 - 4 * s + 1
    d01 = -6 * s ** 2 + 6 * s
    d11 = 3 * s ** 2 - 2 * s
    ends = list(zip(a.positions, a.velocities, b.positions, b.velocities))
    return (tuple(h00 * p0 + h10 * span * v0 + h01 * p1 + h11 * span * v1
                  for p0, v0, p1, v1 in ends),
            tuple((d00 * p0 + d01 * p1) / span + d10 * v0 + d11 * v1
                  for p0, v0, p1, v1 in ends))


def validate(joints: Sequence[str], points: Sequence[Point], limits: Dict[str, Limits],
             start_s: float) -> Trajectory:
    """Return the trajectory, or raise TrajectoryError saying what is wrong with it."""
    names = tuple(joints)
    if not names:
        raise TrajectoryJointsError('no joint_names')
    if len(set(names)) != len(names):
        raise TrajectoryJointsError('a joint is named twice in joint_names')
    for name in names:
        joint = limits.get(name)
        if joint is None:
            raise TrajectoryJointsError(f'unknown joint {name!r}')
        if not joint.online:
            raise TrajectoryJointsError(f'joint {name!r} is not on the bus')
        if joint.mode not in modes.POSITION_MODES:
            raise TrajectoryJointsError(
                f'joint {name!r} is in {joint.mode} mode: trajectories drive joints in a '
                'position mode only')
    if not points:
        raise TrajectoryError('no points')
    previous = -math.inf
    for index, point in enumerate(points):
        where = f'point {index}'
        if not math.isfinite(point.time_s) or point.time_s < 0.0:
            raise TrajectoryError(f'{where}: time_from_start {point.time_s} is not a finite, '
                                  'non-negative time')
        if point.time_s <= previous:
            raise TrajectoryError(f'{where}: time_from_start {point.time_s:g} s is not after '
                                  f'the previous point ({previous:g} s)')
        previous = point.time_s
        if len(point.positions) != len(names):
            raise TrajectoryError(f'{where}: {len(point.positions)} positions for '
                                  f'{len(names)} joints')
        if point.velocities and len(point.velocities) != len(names):
            raise TrajectoryError(f'{where}: {len(point.velocities)} velocities for '
                                  f'{len(names)} joints (give none or one per joint)')
        for what, values in (('position', point.positions), ('velocity', point.velocities)):
            for name, value in zip(names, values):
                if not math.isfinite(value):
                    raise TrajectoryError(f'{where}: joint {name!r} has {what} {value}')
        for name, position in zip(names, point.positions):
            joint = limits[name]
            if not joint.low_rad <= position <= joint.high_rad:
                raise TrajectoryError(
                    f'{where}: joint {name!r} position {position:g} rad is beyond its limits '
                    f'{joint.low_rad:g}..{joint.high_rad:g} rad')
    return Trajectory(names, start_s, tuple(points))


# What the executor reads of a joint at each step: its fresh sample (position rad, velocity
# rad/s) or None when this cycle did not read it; and the last position known (for holding).
Sense = Callable[[str], Optional[Tuple[float, float]]]
Present = Callable[[str], Optional[float]]
# Why a joint cannot be driven now ('' when it can): it ends every trajectory that moves it.
Trouble = Callable[[str], str]


class Executor:
    """
    The trajectories of one driver: running, waiting for their start; this cycle's goals.

    step(now, sense, trouble) returns the goals to queue this cycle, {joint: rad}. `present(name)`
    gives a joint's last measured position (None if unknown): where a first trajectory starts
    and where joints hold when one ends early. `report` hears of every end (log, diagnostics).
    submit, cancel and step may be called from different threads.
    """

    def __init__(self, present: Present, report: Callable[[Outcome], None],
                 tolerance_rad: float = 0.05) -> None:
        self._present = present
        self._report = report
        self.tolerance_rad = tolerance_rad
        self._lock = threading.Lock()
        self._running: List[Trajectory] = []
        self._waiting: List[Trajectory] = []
        self._commanded: Dict[str, float] = {}
        # Ends decided outside step (cancel from another thread): told at the next step.
        self._ended: List[Tuple[Trajectory, Outcome]] = []
        self._hold: Dict[str, float] = {}
        self.accepted = 0
        self.finished = 0
        self.out_of_tolerance = 0
        self.last_outcome: Optional[Outcome] = None

    @property
    def busy(self) -> bool:
        """Return whether a trajectory runs or waits for its start time."""
        with self._lock:
            return bool(self._running or self._waiting)

    def running_joints(self) -> Dict[str, str]:
        """Return the joints driven now, each with the label of its trajectory."""
        with self._lock:
            return {name: run.label for run in self._running for name in run.joints}

    def submit(self, trajectory: Trajectory) -> None:
        """Take a validated trajectory: from its start it replaces those sharing its joints."""
        if trajectory.tolerances is None:
            trajectory.tolerances = Tolerances.goal_only(len(trajectory.joints),
                                                         self.tolerance_rad)
        joints = set(trajectory.joints)
        with self._lock:
            # One waiting to start at or after it on a shared joint never runs.
            keep = []
            for waiting in self._waiting:
                if waiting.start_s >= trajectory.start_s and joints & set(waiting.joints):
                    self._ended.append((waiting, self._preempted(waiting, trajectory)))
                else:
                    keep.append(waiting)
            self._waiting = keep + [trajectory]
            self._waiting.sort(key=lambda t: t.start_s)
            self.accepted += 1

    def cancel(self, trajectory: Optional[Trajectory] = None, why: str = '') -> None:
        """
        End one trajectory (or all) now: its joints hold where they are at the next step.

        With no trajectory, every one ends as aborted with `why` (the cycle stops: nothing is
        written any more, the joints keep their last goal); with one, it ends as canceled.
        """
        with self._lock:
            if trajectory is None:
                for run in self._running + self._waiting:
                    self._ended.append((run, Outcome(math.nan, [], ABORTED, why)))
                self._running.clear()
                self._waiting.clear()
                ended = list(self._ended)
                self._ended.clear()
            elif trajectory in self._waiting:
                # Not begun: nothing of it was written, nothing to hold.
                self._waiting.remove(trajectory)
                ended = [(trajectory, Outcome(math.nan, [], CANCELED,
                                              'canceled before its start time'))]
            else:
                trajectory.cancel_requested = True
                ended = []
        for run, outcome in ended:
            self._end(run, outcome)

    def step(self, now_s: float, sense: Optional[Sense] = None,
             trouble: Optional[Trouble] = None) -> Dict[str, float]:
        """Return this cycle's goals; begin, watch and end trajectories."""
        sense = sense or (lambda name: None)
        ended: List[Tuple[Trajectory, Outcome]] = []
        goals: Dict[str, float] = {}
        with self._lock:
            ended.extend(self._ended)
            self._ended.clear()
            while self._waiting and self._waiting[0].start_s <= now_s:
                self._begin(self._waiting.pop(0), ended)
            for run in list(self._running):
                outcome = self._watch(run, now_s, sense, trouble, goals)
                if outcome is not None:
                    self._running.remove(run)
                    ended.append((run, outcome))
            goals.update(self._hold)
            self._hold.clear()
            self._commanded.update(goals)
        for run, outcome in ended:
            self._end(run, outcome)
        return goals

    # inside the lock ----------------------------------------------------------------------------
    def _begin(self, trajectory: Trajectory, ended: List[Tuple[Trajectory, Outcome]]) -> None:
        joints = set(trajectory.joints)
        trajectory.initial = tuple(self._start_position(name) for name in trajectory.joints)
        for run in list(self._running):
            if joints & set(run.joints):
                self._running.remove(run)
                ended.append((run, self._preempted(run, trajectory)))
        self._running.append(trajectory)

    def _preempted(self, old: Trajectory, new: Trajectory) -> Outcome:
        shared = ', '.join(repr(name) for name in old.joints if name in new.joints)
        return Outcome(math.nan, [], PREEMPTED,
                       f'preempted by {new.label}, which drives {shared} too')

    def _start_position(self, name: str) -> float:
        commanded = self._commanded.get(name)
        if commanded is not None and any(name in run.joints for run in self._running):
            return commanded
        present = self._present(name)
        return present if present is not None else self._commanded.get(name, 0.0)

    def _watch(self, run: Trajectory, now_s: float, sense: Sense,
               trouble: Optional[Trouble], goals: Dict[str, float]) -> Optional[Outcome]:
        """Sample one running trajectory into goals; return its outcome if it ends now."""
        tolerances = run.tolerances
        assert tolerances is not None
        if trouble is not None:
            troubles = {name: trouble(name) for name in run.joints}
            first = next((name for name, why in troubles.items() if why), None)
            if first is not None:
                # The joints that still answer hold where they are; never resumed.
                self._hold_present(run, [name for name, why in troubles.items() if not why])
                return Outcome(math.nan, [], ABORTED, f'joint {first!r} {troubles[first]}')
        if run.cancel_requested:
            self._hold_present(run)
            return Outcome(math.nan, [], CANCELED, 'canceled: the joints hold where they are')
        desired, desired_velocity = run.sample_with_velocity(now_s)
        samples = [sense(name) for name in run.joints]
        fresh = all(sample is not None for sample in samples)
        if fresh:
            actual = tuple(sample[0] for sample in samples if sample is not None)
            actual_velocity = tuple(sample[1] for sample in samples if sample is not None)
            if now_s < run.end_s:
                beyond = _beyond(run.joints, desired, actual, desired_velocity, actual_velocity,
                                 tolerances.path_position, tolerances.path_velocity)
                if beyond:
                    self._hold_present(run)
                    return Outcome(math.nan, [], PATH_VIOLATED,
                                   f'path tolerance violated: {beyond}; the joints hold where '
                                   'they are')
            listener = run.listener
            if listener is not None and now_s >= run.next_feedback_s:
                run.next_feedback_s = now_s + listener.feedback_period_s
                listener.feedback(Feedback(run.joints, desired, desired_velocity, actual,
                                           actual_velocity))
        goals.update(zip(run.joints, desired))
        if now_s < run.end_s:
            return None
        last = run.points[-1]
        final_velocity = last.velocities or tuple(0.0 for _ in run.joints)
        if fresh:
            beyond = _beyond(run.joints, last.positions, actual, final_velocity,
                             actual_velocity, tolerances.goal_position,
                             tolerances.goal_velocity)
            if not beyond:
                return self._judged(run, actual, SUCCEEDED, '')
        if now_s >= run.end_s + tolerances.goal_time_s:
            present = tuple(self._present(name) for name in run.joints)
            return self._judged(run, present, GOAL_VIOLATED,
                                f'goal tolerance violated {tolerances.goal_time_s:g} s after '
                                'the last point')
        return None

    def _judged(self, run: Trajectory, actual: Sequence[Optional[float]], how: str,
                message: str) -> Outcome:
        tolerances = run.tolerances
        assert tolerances is not None
        beyond: List[Tuple[str, float]] = []
        worst = 0.0
        for name, goal, present, tolerance in zip(run.joints, run.points[-1].positions, actual,
                                                  tolerances.goal_position):
            error = math.inf if present is None else abs(present - goal)
            worst = max(worst, error)
            if tolerance > 0.0 and error > tolerance:
                beyond.append((name, error))
        if how == GOAL_VIOLATED and beyond:
            joints = ', '.join(f'{name!r} {error:.4f} rad' for name, error in beyond)
            message = f'{message}: {joints}'
        return Outcome(worst, beyond, how, message)

    def _hold_present(self, run: Trajectory, joints: Optional[Sequence[str]] = None) -> None:
        for name in run.joints if joints is None else joints:
            present = self._present(name)
            if present is not None:
                self._hold[name] = present

    # outside the lock ---------------------------------------------------------------------------
    def _end(self, run: Trajectory, outcome: Outcome) -> None:
        if outcome.how in (SUCCEEDED, GOAL_VIOLATED):
            self.finished += 1
            if outcome.beyond:
                self.out_of_tolerance += 1
            self.last_outcome = outcome
        self._report(outcome)
        if run.listener is not None:
            run.listener.ended(outcome)


def _beyond(joints: Sequence[str], desired: Sequence[float], actual: Sequence[float],
            desired_velocity: Sequence[float], actual_velocity: Sequence[float],
            position_tolerance: Sequence[float], velocity_tolerance: Sequence[float]) -> str:
    """Return the first joint beyond its tolerance, said for a person; '' when none is."""
    for index, name in enumerate(joints):
        error = actual[index] - desired[index]
        if position_tolerance[index] > 0.0 and abs(error) > position_tolerance[index]:
            return (f'joint {name!r} is {error:+.4f} rad from its setpoint (tolerance '
                    f'{position_tolerance[index]:g} rad)')
        error = actual_velocity[index] - desired_velocity[index]
        if velocity_tolerance[index] > 0.0 and abs(error) > velocity_tolerance[index]:
            return (f'joint {name!r} moves {error:+.4f} rad/s off its setpoint velocity '
                    f'(tolerance {velocity_tolerance[index]:g} rad/s)')
    return ''
