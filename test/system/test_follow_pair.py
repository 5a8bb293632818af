"""
A leader-follower pair as it runs: two `virtual_bus` processes, two installed `node` processes.

The leader (namespace /leader: XL330-M077s, its arm passive, its gripper without torque) is moved
by hand through its simulator's console (`turn ID RAD SECONDS`); the follower (namespace /follower:
an XL430-W250 and two XL330-M288, the gripper in current_based_position) follows its joint_states.
Its simulator records every goal written on its wire (`--trace-goals`), so a far start is checked
step by step there: no goal step above follow.max_step. A client here calls `~/follow`, the
follower's services, and reads joint_states and /diagnostics. Every process is stopped and reaped,
every file is in the test's workdir.
"""

import pathlib
import signal
import threading
import time
from typing import Any, Dict, Iterator, List, Tuple

from diagnostic_msgs.msg import DiagnosticArray
from dxl_servo_driver.models import model_for
from dxl_servo_driver.models.units import units_for
from node_harness import Client, Collector, new_context
from processes import EXIT_TIMEOUT_S, NodeProcess, VirtualBusProcess
import pytest
import rclpy
from sensor_msgs.msg import JointState
from std_srvs.srv import SetBool
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

RATE_HZ = 100.0
MAX_STEP = 0.03
RAMP = 0.6
TIMEOUT = 0.3
BLOCK_ERROR = 0.3
BLOCK_TIME = 0.5
WAIT_S = 30.0   # bounds for waits on a busy machine, never how long something takes
LEADER_MODELS = ['XL330-M077'] * 3
FOLLOWER_MODELS = ['XL430-W250', 'XL330-M288', 'XL330-M288']
RAD = units_for(model_for(1060)).rad_per_pulse   # the XL430-W250's (4096 a turn, as every X)
# The gripper: the leader's trigger 0 (open) .. -0.6 (closed); the follower's 0 .. 1.2.
LEADER_CLOSED, FOLLOWER_CLOSED = -0.6, 1.2


def leader_yaml(port: str) -> str:
    return f"""/**:
  ros__parameters:
    port: "{port}"
    baud_rate: 1000000
    loop_rate: {RATE_HZ}
    latency_timer: 1.0
    ping_retries: 10                  # a loaded machine may answer a configure read late
    torque_on_start: false
    joints: [arm, elbow, grip]
    arm: {{id: 1, model: XL330-M077, torque: false}}
    elbow: {{id: 2, model: XL330-M077, torque: false}}
    grip: {{id: 3, model: XL330-M077, operating_mode: current_based_position, gripper: true,
           gripper_open: 0.0, gripper_closed: {LEADER_CLOSED}}}
"""


def follower_yaml(port: str) -> str:
    return f"""/**:
  ros__parameters:
    port: "{port}"
    baud_rate: 1000000
    loop_rate: {RATE_HZ}
    latency_timer: 1.0
    ping_retries: 10
    joints: [arm, elbow, grip]
    follow:
      topic: /leader/joint_states
      timeout: {TIMEOUT}
      max_step: {MAX_STEP}
      ramp_velocity: {RAMP}
      block_error: {BLOCK_ERROR}
      block_time: {BLOCK_TIME}
    arm: {{id: 1, model: XL430-W250, min_position: -2.0, max_position: 2.0}}
    elbow: {{id: 2, model: XL330-M288}}
    grip: {{id: 3, model: XL330-M288, operating_mode: current_based_position, gripper: true,
           gripper_open: 0.0, gripper_closed: {FOLLOWER_CLOSED}, follow_open: 0.0,
           follow_closed: {LEADER_CLOSED}}}
"""


class Pair:
    """Both buses, both nodes, a client on the follower (and the leader's joint_states)."""

    def __init__(self, workdir: pathlib.Path, domain_id: int, leader_start: float = 0.0) -> None:
        self.trace = workdir / 'follower_goals.txt'
        self.buses: List[VirtualBusProcess] = []
        self.nodes: List[NodeProcess] = []
        self.context = new_context(domain_id)
        self.client: Any = None
        try:
            self.leader_bus = self._bus(workdir / 'ttyLEADER', LEADER_MODELS)
            self.follower_bus = self._bus(workdir / 'ttyFOLLOWER', FOLLOWER_MODELS,
                                          '--trace-goals', str(self.trace))
            if leader_start:
                self.turn(1, leader_start, 0.0)
            self.leader = NodeProcess(workdir, leader_yaml(str(workdir / 'ttyLEADER')),
                                      '/leader', domain_id)
            self.nodes.append(self.leader)
            self.follower = NodeProcess(workdir, follower_yaml(str(workdir / 'ttyFOLLOWER')),
                                        '/follower', domain_id)
            self.nodes.append(self.follower)
            self.client = Client(self.context, namespace='/follower')
            node = self.client.node
            self.leader_states: Collector[JointState] = Collector()
            node.create_subscription(JointState, '/leader/joint_states', self.leader_states, 50)
            self.follow_client = node.create_client(SetBool,
                                                    '/follower/dxl_servo_driver/follow')
            self.trajectories = node.create_publisher(
                JointTrajectory, '/follower/dxl_servo_driver/joint_trajectory', 10)
        except BaseException:
            self.close()
            raise

    def _bus(self, link: pathlib.Path, models: List[str], *extra: str) -> VirtualBusProcess:
        bus = VirtualBusProcess([1, 2, 3], 1000000, link,
                                extra_args=['--models', *models, *extra])
        self.buses.append(bus)
        return bus

    def turn(self, servo_id: int, rad: float, seconds: float) -> None:
        answer = self.leader_bus.control(f'turn {servo_id} {rad} {seconds}')
        assert answer.startswith('ok'), answer

    def position(self, name: str, timeout_s: float = WAIT_S) -> float:
        """Return the follower's newest position of a joint (from its joint_states)."""
        msg = self.client.joint_states.wait(lambda m: name in m.name, timeout_s, fresh=True)
        return float(msg.position[list(msg.name).index(name)])

    def wait_at(self, name: str, rad: float, tolerance: float, what: str) -> None:
        """Wait for a joint_states of the follower, sent from now on, with name near rad."""
        deadline = time.monotonic() + WAIT_S
        while True:
            try:
                # Fresh: a message from before the test's last action does not count.
                self.client.joint_states.wait(
                    lambda m: name in m.name
                    and abs(m.position[list(m.name).index(name)] - rad) <= tolerance,
                    timeout_s=0.5, fresh=True)
                return
            except AssertionError as exc:
                self.follower.alive()
                if time.monotonic() > deadline:
                    raise AssertionError(
                        f'{what}: {exc}\nthe follower said:\n{self.follower.output()}\nthe '
                        f'leader said:\n{self.leader.output()}') from None

    def follow(self, engage: bool) -> Any:
        assert self.follow_client.wait_for_service(timeout_sec=WAIT_S)
        done = threading.Event()
        future = self.follow_client.call_async(SetBool.Request(data=engage))
        future.add_done_callback(lambda _: done.set())
        assert done.wait(WAIT_S), '~/follow did not answer'
        return future.result()

    def goals(self, servo_id: int) -> List[Tuple[float, int]]:
        """Return (monotonic time, raw goal) of every goal of a follower servo on its wire."""
        rows = []
        if self.trace.exists():
            for line in self.trace.read_text().splitlines():
                parts = line.split()
                if len(parts) == 3 and int(parts[1]) == servo_id:
                    rows.append((float(parts[0]), int(parts[2])))
        return rows

    def wait_output(self, node: NodeProcess, text: str) -> None:
        deadline = time.monotonic() + WAIT_S
        while text not in node.output():
            node.alive()
            assert time.monotonic() < deadline, f'{text!r} not said:\n{node.output()}'
            time.sleep(0.05)

    def close(self) -> None:
        if self.client is not None:
            self.client.close()
        rclpy.try_shutdown(context=self.context)
        for node in self.nodes:
            node.stop()
        for bus in self.buses:
            bus.stop()


@pytest.fixture
def far_pair(workdir: pathlib.Path, domain_id: int) -> Iterator[Pair]:
    pair = Pair(workdir, domain_id, leader_start=0.8)
    try:
        yield pair
    finally:
        pair.close()


def steps(goals: List[Tuple[float, int]]) -> List[int]:
    return [abs(b - a) for (_, a), (_, b) in zip(goals, goals[1:])]


def test_a_pair_ramps_follows_the_hand_maps_the_gripper_and_refuses_others(
        far_pair: Pair) -> None:
    pair = far_pair
    # A far start (the leader's horn at 0.8 rad, the follower's at 0): ramped there, never a
    # goal step above max_step on the follower's wire.
    pair.wait_at('arm', 0.8, 0.03, 'ramped to the leader')
    goals = pair.goals(1)
    assert len(goals) >= 0.8 / MAX_STEP, goals[:5]
    assert max(steps(goals)) <= MAX_STEP / RAD + 1
    # Ramped, not at max_step: about ramp_velocity / loop_rate a cycle.
    moving = [s for s in steps(goals) if s > 0]
    assert sorted(moving)[len(moving) // 2] <= 2.0 * RAMP / RATE_HZ / RAD

    # The hand turns the leader's horn: the follower follows within a bounded lag and error.
    turned_at = time.monotonic()
    pair.turn(1, -0.2, 1.0)
    pair.wait_at('arm', -0.2, 0.02, 'followed the hand')
    first_moved = next(t for t, raw in pair.goals(1) if t > turned_at
                       and raw < goals[-1][1] - 2)
    assert first_moved - turned_at < 1.0, 'the follower moved more than 1 s after the hand'
    assert max(steps(pair.goals(1))) <= MAX_STEP / RAD + 1

    # The gripper: the leader's travel 0..-0.6 maps onto the follower's 0..1.2.
    pair.turn(3, LEADER_CLOSED / 2.0, 0.2)
    pair.wait_at('grip', FOLLOWER_CLOSED / 2.0, 0.05, 'gripper half closed')

    # While following, other commanders are refused with the reason.
    response = pair.client.call('set_position', name=['arm'], value=[0.5])
    assert not response.success
    assert "joint 'arm' follows /leader/joint_states" in response.message
    msg = JointTrajectory(joint_names=['elbow'])
    msg.points = [JointTrajectoryPoint(positions=[0.4])]
    msg.points[0].time_from_start.sec = 1
    pair.trajectories.publish(msg)
    pair.wait_output(pair.follower, "trajectory refused: joint 'elbow' follows")
    # Disengaged, the follower is anyone's; engaged again, it is the leader's.
    assert pair.follow(False).success
    response = pair.client.call('set_position', name=['arm'], value=[0.5])
    assert response.success, response.message
    pair.wait_at('arm', 0.5, 0.03, 'commanded')
    engaged_at = time.monotonic()
    assert pair.follow(True).success
    pair.wait_at('arm', -0.2, 0.03, 'back with the leader')
    # From where the command left it (0.5), ramped back: no step above max_step.
    back = [(t, raw) for t, raw in pair.goals(1) if t > engaged_at]
    assert len(back) >= 0.7 / MAX_STEP
    assert max(steps(back)) <= MAX_STEP / RAD + 1

    for node in pair.nodes:
        node.proc.send_signal(signal.SIGINT)
    for node in pair.nodes:
        assert node.wait(EXIT_TIMEOUT_S) == 0, node.output()
        assert 'Traceback' not in node.output(), node.output()


def blocked_status(msg: DiagnosticArray) -> Dict[str, str]:
    for status in msg.status:
        values = {kv.key: kv.value for kv in status.values}
        if 'follow_blocked_joint' in values:
            return values
    return {}


def test_a_braked_joint_stops_the_follower_and_a_dead_leader_is_held(
        workdir: pathlib.Path, domain_id: int) -> None:
    pair = Pair(workdir, domain_id)
    try:
        pair.wait_at('arm', 0.0, 0.03, 'following')
        # A hand holds the follower's arm near 0 (end stops there): the leader goes on
        # without it, the arm stays far from its goal, the follower stops and says which.
        answer = pair.follower_bus.control('stops 1 -0.1 0.1')
        assert answer.startswith('ok'), answer
        pair.turn(1, 0.7, 0.3)
        pair.wait_output(pair.follower, "joint 'arm' is blocked")
        status = pair.follower.wait_message(pair.client.diagnostics,
                                            lambda m: bool(blocked_status(m)), WAIT_S)
        values = blocked_status(status)
        assert values['follow_blocked_joint'] == 'arm'
        assert float(values['follow_blocked_error_rad']) > BLOCK_ERROR
        assert values['follow_state'].startswith("stopped: joint 'arm' is blocked")
        # Stopped: the others may command it again.
        assert pair.client.call('set_position', name=['elbow'], value=[0.1]).success
        answer = pair.follower_bus.control('stops 1 off')
        assert answer.startswith('ok'), answer
        assert pair.follow(True).success
        pair.wait_at('arm', 0.7, 0.03, 'engaged again')

        # A brown-out of a leader servo: the leader restores it passive, without torque (the
        # hand can still turn it: the console's turn refuses a torqued horn), and it is
        # followed as before.
        answer = pair.leader_bus.control('powercycle 2')
        assert answer.startswith('ok'), answer
        pair.wait_output(pair.leader, "joint 'elbow': restored after its restart; passive")
        assert pair.leader_bus.control('get 2 torque_enable') == 'ok get 2 torque_enable=0'
        pair.turn(2, 0.4, 0.3)
        pair.wait_at('elbow', 0.4, 0.03, 'the elbow followed after its leader servo restarted')
        assert pair.leader_bus.control('get 2 torque_enable') == 'ok get 2 torque_enable=0'

        # The leader dies: the follower holds within follow.timeout (its goals stop), and
        # says so.
        killed_at = time.monotonic()
        pair.leader.stop(signal.SIGKILL)
        pair.wait_output(pair.follower, f's old (follow.timeout {TIMEOUT:g} s): holding where '
                         'it is')
        # Holding writes goal = present once, in the cycle after it says so: a hundred cycles
        # of the follower later that goal is on the wire, and it is the last.
        for _ in range(int(RATE_HZ)):
            held = pair.position('arm')
        assert abs(held - 0.7) < 0.03
        last = pair.goals(1)[-1][0]
        assert last - killed_at < TIMEOUT + 0.7, (last - killed_at)
        # ... and stays there: a hundred cycles more, no goal was written since.
        for _ in range(int(RATE_HZ)):
            held = pair.position('arm')
        assert abs(held - 0.7) < 0.03
        assert pair.goals(1)[-1][0] == last
        pair.follower.alive()
    finally:
        pair.close()
