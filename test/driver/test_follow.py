"""
Following a leader (driver/follow.Follower) in the follower's own cycle, below ROS.

The follower is an active manager on `port: sim` whose cycle loop (driver/loop.CycleLoop) runs
the Follower as its step; the test plays the leader by handing it messages (offer), as the
node's subscription does. What the follower did is read where it lands: the simulated servos'
Goal Position registers, recorded in the loop's own thread right after each cycle's write, so
every goal written is seen (and its step measured). The tests wait on conditions, never on the
clock.
"""

import math
import threading
from typing import Any, Callable, Dict, Iterator, List, Tuple

from dxl_servo_driver.config import ConfigError, DriverConfig, validate
from dxl_servo_driver.driver.follow import Follower
from dxl_servo_driver.driver.loop import CycleLoop
from dxl_servo_driver.driver.manager import Manager
from dxl_servo_driver.driver.transports import open_transport, Transport
import pytest

RATE_HZ = 100.0
WAIT_S = 30.0    # a bound on every wait (a busy machine), never how long one takes
RAD = 2.0 * math.pi / 4096.0   # one pulse of the XM430 of `port: sim`
MAX_STEP = 0.02
RAMP = 0.5       # rad/s
# The gripper: its own travel 0 (open) .. 1.0 rad (closed); the leader's 0.2 .. -0.6.
LEADER_OPEN, LEADER_CLOSED = 0.2, -0.6


def config(**top: Any) -> DriverConfig:
    params: Dict[str, Any] = {
        'port': 'sim', 'baud_rate': 1_000_000, 'latency_timer': 1.0, 'loop_rate': RATE_HZ,
        'joints': ['arm', 'elbow', 'grip'], 'follow.topic': '/leader/joint_states',
        'follow.max_step': MAX_STEP, 'follow.ramp_velocity': RAMP, 'follow.timeout': 0.3,
        'arm.id': 1, 'elbow.id': 2, 'elbow.follow': 'leader_elbow', 'elbow.min_position': -0.5,
        'elbow.max_position': 0.4, 'grip.id': 3,
        'grip.operating_mode': 'current_based_position', 'grip.gripper': True,
        'grip.gripper_open': 0.0, 'grip.gripper_closed': 1.0,
        'grip.follow_open': LEADER_OPEN, 'grip.follow_closed': LEADER_CLOSED}
    params.update(top)
    return validate(params)


class Log:
    """A Logger keeping its lines."""

    def __init__(self) -> None:
        self.lines: List[Tuple[str, str]] = []

    def _keep(self, level: str, message: str) -> None:
        self.lines.append((level, message))

    def info(self, message: str, **kwargs: Any) -> None:
        self._keep('info', message)

    def warning(self, message: str, **kwargs: Any) -> None:
        self._keep('warning', message)

    def error(self, message: str, **kwargs: Any) -> None:
        self._keep('error', message)

    def fatal(self, message: str, **kwargs: Any) -> None:
        self._keep('fatal', message)

    def said(self, level: str, part: str) -> int:
        return sum(1 for lv, message in self.lines if lv == level and part in message)


class Pair:
    """The follower (manager, loop, Follower) and what its wire carried, cycle by cycle."""

    IDS = {'arm': 1, 'elbow': 2, 'grip': 3}

    def __init__(self, **top: Any) -> None:
        self.transports: List[Transport] = []
        self.log = Log()

        def keep(cfg: DriverConfig) -> Transport:
            self.transports.append(open_transport(cfg))
            return self.transports[-1]

        cfg = config(**top)
        self.manager = Manager(cfg, info=self.log.info, warn=self.log.warning,
                               error=self.log.error, port_factory=keep)
        self.manager.configure()
        self.manager.activate()
        self.follower = Follower(lambda: self.manager, cfg, self.log)
        self.goals: Dict[str, List[float]] = {name: [] for name in self.IDS}
        self._changed = threading.Condition()
        self.cycles = 0
        self.loop = CycleLoop(lambda: self.manager, RATE_HZ, self._published, self.log,
                              steps=[self.follower])

    @property
    def sim(self) -> Any:
        return self.transports[-1].simulator

    def _published(self, stamp_ns: int, read_ok: bool) -> None:
        # Right after this cycle's write: every goal that reached the servos, in order.
        with self._changed:
            self.cycles += 1
            for name, servo_id in self.IDS.items():
                goal = self.manager.servos[name].position_rad(
                    self.sim.read_register(servo_id, 'goal_position'))
                if not self.goals[name] or self.goals[name][-1] != goal:
                    self.goals[name].append(goal)
            self._changed.notify_all()

    def start(self) -> None:
        self.follower.start()
        self.loop.start('thread', self.manager.bus_budget().cycle_time_s)

    def lead(self, arm: float, elbow: float = 0.0, grip: float = LEADER_OPEN) -> None:
        self.follower.offer(['grip', 'arm', 'leader_elbow'], [grip, arm, elbow], 0)

    def wait(self, condition: Callable[[], bool], what: str,
             feed: Callable[[], None] = lambda: None) -> None:
        """Wait for condition, calling feed at every cycle (a leader that keeps publishing)."""
        with self._changed:
            ok = self._changed.wait_for(lambda: (feed(), condition())[1], WAIT_S)
        assert ok, f'{what}: goals {[(n, g[-3:]) for n, g in self.goals.items()]}, log ' \
                   f'{self.log.lines[-5:]}'

    def goal(self, name: str) -> float:
        return self.goals[name][-1] if self.goals[name] else math.nan

    def steps(self, name: str) -> List[float]:
        goals = self.goals[name]
        return [abs(b - a) for a, b in zip(goals, goals[1:])]

    def close(self) -> None:
        self.loop.stop()
        self.follower.stop('the test ended')
        self.manager.deactivate()
        self.manager.close()


@pytest.fixture
def pair() -> Iterator[Pair]:
    made = Pair()
    try:
        yield made
    finally:
        made.close()


def near(a: float, b: float, tolerance: float = 2 * RAD) -> bool:
    return abs(a - b) <= tolerance


def test_the_follower_copies_the_leader_never_faster_than_max_step(pair: Pair) -> None:
    pair.start()
    pair.wait(lambda: near(pair.goal('arm'), 0.0), 'engaged at the leader',
              lambda: pair.lead(0.0))
    pair.wait(lambda: near(pair.goal('arm'), 0.3) and near(pair.goal('elbow'), -0.2),
              'followed', lambda: pair.lead(0.3, -0.2))
    # 0.3 rad at 0.02 rad a cycle: at least 15 goals, none a step above max_step.
    assert len(pair.goals['arm']) >= 15
    assert max(pair.steps('arm')) <= MAX_STEP + RAD
    # The elbow copies the leader's joint its `follow` names.
    assert near(pair.goal('elbow'), -0.2)


def test_the_gripper_maps_the_leaders_travel_onto_its_own(pair: Pair) -> None:
    pair.start()
    for leader, follower in ((LEADER_OPEN, 0.0), (LEADER_CLOSED, 1.0),
                             (0.5 * (LEADER_OPEN + LEADER_CLOSED), 0.5)):
        pair.wait(lambda: near(pair.goal('grip'), follower), f'gripper at {follower}',
                  lambda: pair.lead(0.0, grip=leader))


def test_beyond_its_limits_a_goal_is_clamped_with_a_warning(pair: Pair) -> None:
    pair.start()
    pair.wait(lambda: near(pair.goal('elbow'), 0.4), 'elbow at its max_position',
              lambda: pair.lead(0.0, 1.5))
    assert max(pair.goals['elbow']) <= 0.4 + RAD
    assert pair.log.said('warning', "'elbow' would follow to 1.5000, beyond its limits") >= 1


def test_a_far_start_ramps_then_follows(pair: Pair) -> None:
    pair.start()
    pair.wait(lambda: near(pair.goal('arm'), 0.8), 'ramped to the leader',
              lambda: pair.lead(0.8))
    # At 0.5 rad/s and 100 Hz: steps of about 5 mrad (a late cycle up to 0.1 s of ramp, never
    # above max_step), so about 160 goals on the way.
    assert len(pair.goals['arm']) >= 0.8 / MAX_STEP
    assert max(pair.steps('arm')) <= MAX_STEP + RAD
    steps = pair.steps('arm')
    assert sorted(steps)[len(steps) // 2] <= RAMP / RATE_HZ * 2.0


def test_a_silent_leader_is_held_and_resumed_with_a_ramp(pair: Pair) -> None:
    pair.start()
    pair.wait(lambda: near(pair.goal('arm'), 0.1), 'following', lambda: pair.lead(0.1))
    silent = 's old (follow.timeout 0.3 s): holding where it is'
    pair.wait(lambda: pair.log.said('warning', silent) == 1, 'held')
    held = len(pair.goals['arm'])
    assert pair.follower.state() == 'holding: the leader is silent'
    # A stale message (stamped long ago on the leader's clock) does not resume it.
    pair.follower.offer(['arm'], [0.9], 1)
    cycles = pair.cycles
    pair.wait(lambda: pair.cycles >= cycles + 50, 'fifty cycles')
    assert len(pair.goals['arm']) == held
    pair.wait(lambda: near(pair.goal('arm'), 0.6), 'resumed', lambda: pair.lead(0.6))
    assert pair.log.said('warning', silent) == 1   # said once
    assert pair.log.said('info', 'fresh messages on /leader/joint_states again') == 1
    assert max(pair.steps('arm')) <= MAX_STEP + RAD
    assert len(pair.goals['arm']) - held >= 0.5 / MAX_STEP


def test_while_following_other_commands_are_refused_with_the_reason(pair: Pair) -> None:
    pair.start()
    pair.wait(lambda: near(pair.goal('arm'), 0.0), 'engaged', lambda: pair.lead(0.0))
    refused = pair.manager.command('position', ['arm'], [0.2])
    assert not refused.success
    assert "joint 'arm' follows /leader/joint_states" in refused.message
    assert '~/follow false' in refused.message
    assert not pair.manager.check_goals('current', ['grip'], [0.1]).success
    pair.follower.disengage()
    assert pair.manager.command('position', ['arm'], [0.2]).success
    pair.wait(lambda: near(pair.goal('arm'), 0.2), 'commanded after disengaging')


def test_a_blocked_joint_stops_the_follower(pair: Pair) -> None:
    pair.start()
    pair.wait(lambda: near(pair.goal('arm'), 0.0), 'engaged', lambda: pair.lead(0.0))
    pair.sim.set_load(1, 20.0)   # far beyond what the motor can turn
    pair.wait(lambda: not pair.follower.engaged, 'stopped', lambda: pair.lead(1.0))
    assert pair.follower.blocked is not None and pair.follower.blocked[0] == 'arm'
    assert pair.log.said('error', "joint 'arm' is blocked") == 1
    facts = pair.follower.facts()
    assert facts['follow_blocked_joint'] == 'arm'
    assert float(facts['follow_blocked_error_rad']) > 0.5
    assert pair.follower.state().startswith("stopped: joint 'arm' is blocked")
    # Held where it is (not pushed on); the others may command it again.
    present = pair.manager.servos['arm'].present_rad()
    assert present is not None
    pair.wait(lambda: near(pair.goal('arm'), present, 0.05), 'held where it is')
    assert pair.manager.command('position', ['arm'], [0.0]).success


def test_not_engaged_at_start_until_asked() -> None:
    made = Pair(**{'follow.engaged': False})
    try:
        made.start()
        made.lead(0.3)
        assert made.follower.idle() and made.follower.state() == 'not engaged'
        assert made.manager.command('position', ['arm'], [0.0]).success
        assert made.follower.engage().success
        made.wait(lambda: near(made.goal('arm'), 0.3), 'engaged', lambda: made.lead(0.3))
    finally:
        made.close()


@pytest.mark.parametrize('keys, key, says', [
    ({'arm.follow_open': 0.1}, 'arm.follow_open', 'only a gripper'),
    ({'grip.follow_closed': 0.2}, 'grip.follow_closed', 'equals follow_open'),
    ({'follow.max_step': 0.0}, 'follow.max_step', 'below the minimum'),
])
def test_bad_follow_parameters_are_refused_by_name(keys: Dict[str, Any], key: str,
                                                   says: str) -> None:
    with pytest.raises(ConfigError) as error:
        config(**keys)
    assert error.value.key == key and says in str(error.value)


def test_a_joint_with_an_empty_follow_is_not_followed() -> None:
    cfg = config(**{'arm.follow': ''})
    assert [j.follow for j in cfg.joints] == [None, 'leader_elbow', 'grip']
