"""
A follower arm: this node's joints copy a leader node's joint_states in this node's own cycle.

A leader-follower pair (docs/teleoperation.md) is two ordinary driver nodes: the leader's joints
have no torque and are moved by hand; the follower's `follow.topic` is the leader's
joint_states. Following is a CycleStep (driver/loop.py) beside the arm's: the subscription only
hands the newest leader message to `offer` (one attribute assignment, no lock, never a write);
`prepare_goals` takes it right before the cycle's goal write and queues one position goal per
followed joint through the manager, like any command; `watch_samples` judges the fresh samples.

What each cycle does with the newest leader message:
- Stale (none yet, or older than follow.timeout by its stamp or by its receipt): nothing is
  queued, so every joint holds its last goal; said once, and once again when fresh messages
  come back. Resuming ramps like engaging.
- Mapping: the leader publishes joint positions in its own joint frame (its offset, reverse and
  ratio applied), and this node's goals are in this node's joint frame, so a joint copies its
  leader joint's value as it is; a gripper maps the leader's travel follow_open..follow_closed
  linearly onto its own gripper_open..gripper_closed. Beyond this joint's limits the goal is
  clamped to them (a throttled warning), never refused.
- Never a jump: every goal moves at most follow.max_step from the last one. Engaging (or
  resuming) with a joint farther than follow.engage_tolerance from its target moves it there
  at follow.ramp_velocity first.
- Blocked: a joint (not a gripper: closing on an object is what it is for) whose sample stays
  farther than follow.block_error from its goal for follow.block_time stops the follower: it is
  held where it is, the log and /diagnostics name it and its error, and it stays stopped until
  engaged again.
- One commander at a time: while engaged, the followed joints take only the follower's goals
  (Manager.hold): commands, trajectories and gripper goals of anyone else are refused with the
  reason, so two commanders never take turns writing one joint.

Threads: offer() runs in the executor, engage()/disengage() in a service's callback, the rest in
the cycle. The engaged state changes under a small lock; the leader's sample is one reference.
"""

from dataclasses import dataclass
import math
import threading
import time
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple

from dxl_servo_driver.config import DriverConfig, JointConfig
from dxl_servo_driver.driver.roles import ManagerForFollower
from dxl_servo_driver.driver.servo import IDX_POSITION, Result, Throttle

__all__ = ['FOLLOWER', 'Follower', 'LeaderSample', 'gripper_map']

FOLLOWER = 'follower'   # the owner of the follower's goals (Manager.hold)
# A cycle later than this after the last one ramps as if it came on time (a stalled loop must
# not turn its wait into one long step; max_step bounds it anyway).
LONGEST_STEP_S = 0.1


@dataclass(frozen=True)
class LeaderSample:
    """The newest leader message: names, positions, its stamp and when it came."""

    names: Tuple[str, ...]
    positions: Tuple[float, ...]
    stamp_ns: int        # header.stamp on the node's clock, ns (0: unstamped)
    received_s: float    # monotonic


def gripper_map(joint: JointConfig) -> Tuple[float, float]:
    """Return (scale, offset): this joint's goal = scale * the leader's position + offset."""
    if (not joint.gripper or joint.follow_open is None or joint.follow_closed is None
            or joint.follow_open == joint.follow_closed):
        return 1.0, 0.0
    scale = ((joint.gripper_closed - joint.gripper_open)
             / (joint.follow_closed - joint.follow_open))
    return scale, joint.gripper_open - scale * joint.follow_open


class _Joint:
    """One followed joint: its leader joint, the map, its last goal, whether it ramps."""

    def __init__(self, joint: JointConfig) -> None:
        self.name = joint.name
        self.leader = joint.follow or joint.name
        self.scale, self.offset = gripper_map(joint)
        self.gripper = joint.gripper
        self.goal: Optional[float] = None   # the last goal queued (joint units)
        self.ramping = False
        self.over_since: Optional[float] = None   # monotonic: since when it is far from its goal


class Follower:
    """The follower's CycleStep; engage/disengage; facts for /diagnostics."""

    def __init__(self, manager: Callable[[], ManagerForFollower], config: DriverConfig,
                 log: Any, stamp_now: Callable[[], int] = time.time_ns,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._manager_of = manager
        self._log = log
        self._stamp_now = stamp_now    # now on the clock of the leader's stamps, ns
        self._clock = clock
        self._lock = threading.Lock()
        self._warn = Throttle(log.warning, clock=clock)
        self.latest: Optional[LeaderSample] = None
        self.engaged = False
        self.stopped_why = ''
        self.blocked: Optional[Tuple[str, float]] = None   # (joint, its error in rad)
        self.taken = 0   # leader messages taken into goals (diagnostics, bench)
        self.last_taken: Optional[Tuple[LeaderSample, float]] = None   # and when (monotonic)
        self.take(config)

    def take(self, config: DriverConfig) -> None:
        """Take a configuration (the node's, again at a reconfigure)."""
        self.config = config
        self.topic = config.follow_topic
        self._joints = [_Joint(joint) for joint in config.joints
                        if joint.follow is not None and not joint.secondary_of]
        self._names = [joint.name for joint in self._joints]
        self._index_of: Tuple[Tuple[str, ...], List[Optional[int]]] = ((), [])
        self._restart = False   # engaged: start from where each joint is
        self._resume = False    # engaged or the leader back: ramp the joints that are far
        self._stale = False
        self._last_s = 0.0

    @property
    def active(self) -> bool:
        """Return whether this node is a follower at all (follow.topic set, a joint followed)."""
        return bool(self.topic) and bool(self._joints)

    # the leader ------------------------------------------------------------------------------
    def offer(self, names: Sequence[str], positions: Sequence[float], stamp_ns: int) -> None:
        """Keep the newest leader message (the subscription's callback; never writes)."""
        self.latest = LeaderSample(tuple(names), tuple(positions), stamp_ns, self._clock())

    def age_s(self, sample: Optional[LeaderSample], now_s: float) -> float:
        """Return how old a leader message is: by its receipt or its stamp, whichever is more."""
        if sample is None:
            return math.inf
        age = now_s - sample.received_s
        if sample.stamp_ns:
            age = max(age, (self._stamp_now() - sample.stamp_ns) * 1e-9)
        return age

    # engaging ---------------------------------------------------------------------------------
    def engage(self) -> Result:
        """Start following: from where each joint is, ramping to the leader where it is far."""
        if not self.active:
            return Result(False, "this node is not a follower (set follow.topic to a leader's "
                          'joint_states)')
        with self._lock:
            if self.engaged:
                return Result(True, f'already following {self.topic}')
            self._manager_of().hold(
                self._names, FOLLOWER, f'follows {self.topic} (one commander at a time): '
                'disengage the follower first (~/follow false)')
            self.engaged = True
            self._restart = True
            self.stopped_why = ''
            self.blocked = None
        self._log.info(f'following {self.topic}: {", ".join(self._names)}')
        return Result(True, f'following {self.topic}')

    def disengage(self, why: str = 'disengaged (~/follow false)') -> Result:
        """Stop following: every joint holds its last goal; others may command it again."""
        with self._lock:
            if not self.engaged:
                return Result(True, f'not following ({self.stopped_why or "not engaged"})')
            self.engaged = False
            self.stopped_why = why
            self._manager_of().release(FOLLOWER)
        self._log.info(f'stopped following {self.topic}: {why}')
        return Result(True, f'stopped following {self.topic}')

    def start(self) -> None:
        """At activation: engaged if follow.engaged says so."""
        self.blocked = None
        self.stopped_why = ''
        if self.active and self.config.follow_engaged:
            self.engage()

    def stop(self, why: str) -> None:
        """At deactivation: not engaged, the joints released (said only if it was engaged)."""
        if self.engaged:
            self.disengage(why)
        self._manager_of().release(FOLLOWER)

    # the cycle --------------------------------------------------------------------------------
    def idle(self) -> bool:
        """Return True when not following: the cycle may chain its reads."""
        return not self.engaged

    def prepare_goals(self, now_s: float) -> None:
        """Queue this cycle's goals from the newest leader message (before the goal write)."""
        if not self.engaged:
            return
        manager = self._manager_of()
        if self._restart:
            self._restart = False
            self._resume = True
            self._last_s = 0.0
            for joint in self._joints:
                joint.goal = _present(manager, joint.name, fresh_only=False)
                joint.over_since = None
        sample = self.latest
        age = self.age_s(sample, now_s)
        if age > self.config.follow_timeout:
            if not self._stale:
                self._stale = True
                self._log.warning(
                    f'follower: no message on {self.topic} yet: holding where it is'
                    if sample is None else
                    f'follower: the last message on {self.topic} is {age:.3f} s old (follow.'
                    f'timeout {self.config.follow_timeout:g} s): holding where it is')
            self._resume = True
            self._last_s = 0.0
            return
        if self._stale:
            self._stale = False
            self._log.info(f'follower: fresh messages on {self.topic} again: following '
                           '(ramping where far)' if self.taken else
                           f'follower: the leader is heard on {self.topic}: following '
                           '(ramping where far)')
        assert sample is not None
        names, goals = self._step(manager, sample, now_s)
        self.taken += 1
        self.last_taken = (sample, self._clock())
        if not names:
            return
        result = manager.command('position', names, goals, owner=FOLLOWER)
        if not result.success:
            self.disengage(f'its goals were refused: {result.message}')

    def _step(self, manager: ManagerForFollower, sample: LeaderSample,
              now_s: float) -> Tuple[List[str], List[float]]:
        """Return this cycle's goals: the leader's, mapped, clamped, no step above the limits."""
        config = self.config
        dt = now_s - self._last_s if self._last_s else 1.0 / config.loop_rate
        self._last_s = now_s
        ramp = config.follow_ramp_velocity * min(max(dt, 0.0), LONGEST_STEP_S)
        max_step = config.follow_max_step
        index = self._index(sample.names)
        resume, self._resume = self._resume, False
        names: List[str] = []
        goals: List[float] = []
        for joint, at in zip(self._joints, index):
            starting = resume
            if joint.goal is None:   # no sample of it yet: nowhere to start from
                joint.goal = _present(manager, joint.name, fresh_only=False)
                if joint.goal is None:
                    continue
                starting = True   # its first goal: ramped like an engaged joint's
            if at is None:
                self._warn(f'missing:{joint.name}', f"follower: the leader's joint_states on "
                           f'{self.topic} has no joint {joint.leader!r}: {joint.name!r} holds')
                continue
            value = sample.positions[at]
            if not math.isfinite(value):
                self._warn(f'nan:{joint.name}', f'follower: leader joint {joint.leader!r} is '
                           f'{value}: {joint.name!r} holds')
                continue
            target = self._clamped(manager, joint, joint.scale * value + joint.offset)
            if starting:
                joint.ramping = abs(target - joint.goal) > config.follow_engage_tolerance
            limit = min(max_step, ramp) if joint.ramping else max_step
            step = min(max(target - joint.goal, -limit), limit)
            joint.goal += step
            if joint.ramping and abs(target - joint.goal) <= config.follow_engage_tolerance:
                joint.ramping = False
            names.append(joint.name)
            goals.append(joint.goal)
        return names, goals

    def _index(self, names: Tuple[str, ...]) -> List[Optional[int]]:
        """Return where each followed joint's leader joint is in the message (cached)."""
        if names != self._index_of[0]:
            where = {name: i for i, name in enumerate(names)}
            self._index_of = (names, [where.get(joint.leader) for joint in self._joints])
        return self._index_of[1]

    def _clamped(self, manager: ManagerForFollower, joint: _Joint, target: float) -> float:
        servo = manager.servos.get(joint.name)
        if servo is None:
            return target
        low, high = servo.joint_position_range()
        if low <= target <= high:
            return target
        clamped = min(max(target, low), high)
        self._warn(f'clamp:{joint.name}', f'follower: {joint.name!r} would follow to '
                   f'{target:.4f}, beyond its limits {low:.4f}..{high:.4f}: clamped to '
                   f'{clamped:.4f}')
        return clamped

    def watch_samples(self, read_ok: bool) -> None:
        """Stop following when a joint stays far from its goal (blocked) for block_time."""
        config = self.config
        if not self.engaged or not read_ok or config.follow_block_error <= 0.0:
            return
        manager = self._manager_of()
        now = self._clock()
        for joint in self._joints:
            if joint.gripper or joint.goal is None:
                continue
            present = _present(manager, joint.name, fresh_only=True)
            if present is None:
                continue
            error = abs(joint.goal - present)
            if error <= config.follow_block_error:
                joint.over_since = None
                continue
            if joint.over_since is None:
                joint.over_since = now
            if now - joint.over_since >= config.follow_block_time:
                self._blocked(manager, joint, present, error)
                return

    def _blocked(self, manager: ManagerForFollower, joint: _Joint, present: float,
                 error: float) -> None:
        self.blocked = (joint.name, error)
        why = (f'joint {joint.name!r} is blocked: {error:.3f} rad from its goal for '
               f'{self.config.follow_block_time:g} s (follow.block_error '
               f'{self.config.follow_block_error:g} rad)')
        self._log.error(f'follower: {why}: following stopped, holding where it is (~/follow '
                        'true engages again)')
        # Held where it is, not pushed on against whatever stops it.
        joint.goal = present
        manager.command('position', [joint.name], [present], owner=FOLLOWER)
        self.disengage(why)

    # what /diagnostics says ------------------------------------------------------------------
    def state(self) -> str:
        """Return what the follower does now, in a few words."""
        if not self.active:
            return 'not a follower'
        if not self.engaged:
            return f'stopped: {self.stopped_why}' if self.stopped_why else 'not engaged'
        if self._stale:
            return 'holding: the leader is silent'
        if any(joint.ramping for joint in self._joints):
            return 'ramping to the leader'
        return 'following'

    def facts(self) -> Dict[str, str]:
        """Return the follower's lines of /diagnostics."""
        if not self.active:
            return {}
        age = self.age_s(self.latest, self._clock())
        facts = {'follow_topic': self.topic, 'follow_state': self.state(),
                 'follow_leader_age_s': f'{age:.3f}' if math.isfinite(age) else 'none',
                 'follow_messages_taken': str(self.taken)}
        if self.blocked is not None:
            facts['follow_blocked_joint'] = self.blocked[0]
            facts['follow_blocked_error_rad'] = f'{self.blocked[1]:.4f}'
        return facts


def _present(manager: ManagerForFollower, name: str, fresh_only: bool) -> Optional[float]:
    servo = manager.servos.get(name)
    if servo is None or servo.state is None or (fresh_only and not servo.fresh):
        return None
    return servo.present_rad() if fresh_only else servo.position_rad(servo.state[IDX_POSITION])
