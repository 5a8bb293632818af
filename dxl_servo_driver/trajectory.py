"""
Joint trajectories executed in the driver's own cycle: validation and sampling, no bus, no ROS.

A trajectory is checked whole before anything moves (known joints in a position mode, times
strictly increasing, finite values, positions within each servo's limits) and then sampled at
every cycle: cubic (Hermite) between two points that both give velocities, linear otherwise;
before its first point it moves from where the joints were commanded (or were) when it began,
after its last it holds the last point. A new trajectory replaces the rest of the running one
from its own start time, starting from the positions the old one commanded then.
"""

from dataclasses import dataclass, field
import math
from typing import Callable, Dict, List, Optional, Sequence, Tuple

from dxl_servo_driver.errors import BadRequest
from dxl_servo_driver.models import modes

__all__ = ['Executor', 'Limits', 'Outcome', 'Point', 'Trajectory', 'TrajectoryError',
           'validate']

# After the last point, how long the joints get to settle before the end is judged.
SETTLE_S = 0.5


class TrajectoryError(BadRequest):
    """A trajectory refused whole; the message says why."""


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


@dataclass
class Trajectory:
    """A validated trajectory with its start time on the driver's clock (monotonic seconds)."""

    joints: Tuple[str, ...]
    start_s: float
    points: Tuple[Point, ...]
    # Where each joint starts from; set when the trajectory begins.
    initial: Optional[Tuple[float, ...]] = None
    judged: bool = field(default=False)

    @property
    def end_s(self) -> float:
        """Return the time of the last point."""
        return self.start_s + self.points[-1].time_s

    def sample(self, now_s: float) -> Tuple[float, ...]:
        """Return the positions at now_s (the trajectory has begun: initial is set)."""
        assert self.initial is not None, 'sample() before the trajectory began'
        t = now_s - self.start_s
        points = self.points
        if t >= points[-1].time_s:
            return points[-1].positions
        before = Point(0.0, self.initial,
                       tuple(0.0 for _ in self.joints) if points[0].velocities else ())
        for after in points:
            if t < after.time_s:
                return _interpolate(before, after, t)
            before = after
        return points[-1].positions


def _interpolate(a: Point, b: Point, t: float) -> Tuple[float, ...]:
    span = b.time_s - a.time_s
    if span <= 0.0:
        return b.positions
    s = min(max((t - a.time_s) / span, 0.0), 1.0)
    if not a.velocities or not b.velocities:
        return tuple(p0 + (p1 - p0) * s for p0, p1 in zip(a.positions, b.positions))
    # Cubic Hermite: positions and velocities met at both ends.
    h00 = 2 * s ** 3 - 3 * s ** 2 + 1
    h10 = s ** 3 - 2 * s ** 2 + s
    h01 = -2 * s ** 3 + 3 * s ** 2
    h11 = s ** 3 - s ** 2
    return tuple(h00 * p0 + h10 * span * v0 + h01 * p1 + h11 * span * v1
                 for p0, v0, p1, v1 in zip(a.positions, a.velocities, b.positions, b.velocities))


def validate(joints: Sequence[str], points: Sequence[Point], limits: Dict[str, Limits],
             start_s: float) -> Trajectory:
    """Return the trajectory, or raise TrajectoryError saying what is wrong with it."""
    names = tuple(joints)
    if not names:
        raise TrajectoryError('no joint_names')
    if len(set(names)) != len(names):
        raise TrajectoryError('a joint is named twice in joint_names')
    if not points:
        raise TrajectoryError('no points')
    for name in names:
        joint = limits.get(name)
        if joint is None:
            raise TrajectoryError(f'unknown joint {name!r}')
        if not joint.online:
            raise TrajectoryError(f'joint {name!r} is not on the bus')
        if joint.mode not in modes.POSITION_MODES:
            raise TrajectoryError(f'joint {name!r} is in {joint.mode} mode: trajectories drive '
                                  'joints in a position mode only')
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
        for name, value in zip(names, point.positions + point.velocities):
            if not math.isfinite(value):
                raise TrajectoryError(f'{where}: joint {name!r} has {value}')
        for name, position in zip(names, point.positions):
            joint = limits[name]
            if not joint.low_rad <= position <= joint.high_rad:
                raise TrajectoryError(
                    f'{where}: joint {name!r} position {position:g} rad is beyond its limits '
                    f'{joint.low_rad:g}..{joint.high_rad:g} rad')
    return Trajectory(names, start_s, tuple(points))


@dataclass
class Outcome:
    """How a finished trajectory ended: the worst final error and the joints beyond tolerance."""

    worst_rad: float
    beyond: List[Tuple[str, float]]


class Executor:
    """
    The trajectories of one driver: the running one, the next ones, the goals of this cycle.

    step(now) returns the goals to queue this cycle, {joint: rad}; `present(name)` gives a
    joint's last measured position (None if unknown) for the start of a first trajectory and
    for judging the end against `tolerance_rad`.
    """

    def __init__(self, present: Callable[[str], Optional[float]],
                 report: Callable[[Outcome], None], tolerance_rad: float = 0.05) -> None:
        self._present = present
        self._report = report
        self.tolerance_rad = tolerance_rad
        self._running: Optional[Trajectory] = None
        self._waiting: List[Trajectory] = []
        self._commanded: Dict[str, float] = {}
        self.accepted = 0
        self.finished = 0
        self.out_of_tolerance = 0
        self.last_outcome: Optional[Outcome] = None

    @property
    def busy(self) -> bool:
        """Return whether a trajectory runs or waits for its start time."""
        return self._running is not None or bool(self._waiting)

    def submit(self, trajectory: Trajectory) -> None:
        """Take a validated trajectory: it replaces the running one from its start time."""
        # A later start replaces everything waiting that would start after it too.
        self._waiting = [t for t in self._waiting if t.start_s < trajectory.start_s]
        self._waiting.append(trajectory)
        self.accepted += 1

    def cancel(self) -> None:
        """Drop every trajectory (the joints hold what was last commanded)."""
        self._running = None
        self._waiting.clear()

    def step(self, now_s: float) -> Dict[str, float]:
        """Return this cycle's goals; begin trajectories whose time came, judge finished ones."""
        while self._waiting and self._waiting[0].start_s <= now_s:
            nxt = self._waiting.pop(0)
            nxt.initial = tuple(self._start_position(name) for name in nxt.joints)
            self._running = nxt
        running = self._running
        if running is None:
            return {}
        goals = dict(zip(running.joints, running.sample(now_s)))
        self._commanded.update(goals)
        if now_s >= running.end_s + SETTLE_S and not running.judged:
            running.judged = True
            self._judge(running)
            self._running = None
        return goals

    def _start_position(self, name: str) -> float:
        commanded = self._commanded.get(name)
        if commanded is not None and self._running is not None and name in self._running.joints:
            return commanded
        present = self._present(name)
        return present if present is not None else self._commanded.get(name, 0.0)

    def _judge(self, trajectory: Trajectory) -> None:
        beyond: List[Tuple[str, float]] = []
        worst = 0.0
        for name, goal in zip(trajectory.joints, trajectory.points[-1].positions):
            present = self._present(name)
            if present is None:
                beyond.append((name, math.inf))
                worst = math.inf
                continue
            error = abs(present - goal)
            worst = max(worst, error)
            if error > self.tolerance_rad:
                beyond.append((name, error))
        self.finished += 1
        if beyond:
            self.out_of_tolerance += 1
        outcome = Outcome(worst, beyond)
        self.last_outcome = outcome
        self._report(outcome)
