"""
FollowJointTrajectory and the gripper actions as MoveIt sends them, through real rclpy clients.

The node runs on the simulated bus at the wire's timing (every byte takes its time at 1 Mbps).

What is checked is what a MoveIt user sees: the status and error_code of each result, the
error_string naming the cause, feedback at its rate, and where the simulated servos really were
(their own registers, not the driver's report) at every point, at the end, after a cancel.
"""

import math
import re
import time
from typing import Any, Callable, Dict, Iterator, List, Sequence, Tuple

from action_client import Client, in_executor
from action_msgs.msg import GoalStatus
from builtin_interfaces.msg import Duration
from conditions import wait_until
from control_msgs.action import FollowJointTrajectory, GripperCommand, ParallelGripperCommand
from control_msgs.msg import JointTolerance
from dxl_servo_driver.arm.gripper import GripperError
from dxl_servo_driver.driver.transports import open_transport, SimTransport, Transport
from dxl_servo_driver.models import model_for
from dxl_servo_driver.models.units import units_for
from dxl_servo_driver.sim.port import SimPortHandler
from node_harness import NodeHarness, sim_params
import pytest
from rclpy.qos import QoSProfile
from trajectories import goal_of
from truth import Messages, stamp_s

Result = FollowJointTrajectory.Result
XM430_UNITS = units_for(model_for(1030))
ARM = ('j1', 'j2', 'j3', 'j4', 'j5', 'j6')
JOINTS: Dict[str, Dict[str, Any]] = {
    name: {'id': index + 1, 'operating_mode': 'position'} for index, name in enumerate(ARM)}
JOINTS['j2']['operating_mode'] = 'extended_position'
JOINTS['wheel'] = {'id': 7, 'operating_mode': 'velocity'}
JOINTS['claw'] = {'id': 8, 'operating_mode': 'current_based_position', 'gripper': True,
                  'gripper_open': 0.0, 'gripper_closed': 1.5}
IDS = {name: keys['id'] for name, keys in JOINTS.items()}


def wire_transport(config: Any) -> Transport:
    """`port: sim`, each reply taking its time on the wire (no instant replies)."""
    simulator = open_transport(config).simulator   # type: ignore[attr-defined]
    return SimTransport(simulator, lambda: SimPortHandler(simulator, 'sim', config.baud_rate,
                                                          timing='wire'))


def arm_harness(**top: Any) -> NodeHarness:
    harness = NodeHarness(sim_params(JOINTS, loop_rate=100.0, **top), port_factory=wire_transport)
    harness.joint_states.wait(lambda m: len(m.name) == len(JOINTS))
    return harness


@pytest.fixture(scope='module')
def h() -> Iterator[NodeHarness]:
    with arm_harness() as harness:
        yield harness


def sim_rad(h: NodeHarness, name: str) -> float:
    """Where the simulated servo is: its Present Position register (rad)."""
    return XM430_UNITS.position_to_rad(h.reg(IDS[name], 'present_position'))


class Goal:
    """One goal sent by an action client: its feedback, its result."""

    def __init__(self, client: Client, goal: Any) -> None:
        self.feedback: List[Tuple[float, Any]] = []
        self._node = client.owner
        self.sent_s = time.monotonic()
        future = in_executor(self._node, lambda: client.send_goal_async(
            goal, feedback_callback=lambda msg: self.feedback.append(
                (time.monotonic(), msg.feedback))))
        wait_until(future.done, 10.0, 'the goal answered')
        self.handle = future.result()
        assert self.handle.accepted
        self.ended_s = math.nan
        self._result = in_executor(self._node, self.handle.get_result_async)
        self._result.add_done_callback(lambda _: setattr(self, 'ended_s', time.monotonic()))

    def result(self, timeout_s: float = 15.0) -> Tuple[int, Any]:
        """Return (status, result) once the goal ended."""
        wait_until(self._result.done, timeout_s, 'the goal ended')
        # The future is done before the executor ran its done callbacks (rclpy schedules them
        # as a task): wait for the one that dates the end, or ended_s is still NaN.
        wait_until(lambda: not math.isnan(self.ended_s), 5.0, 'the end dated')
        response = self._result.result()
        return response.status, response.result

    @property
    def done(self) -> bool:
        return self._result.done()

    def cancel(self) -> None:
        future = in_executor(self._node, self.handle.cancel_goal_async)
        wait_until(future.done, 10.0, 'the cancel answered')


def client_of(h: NodeHarness) -> Client:
    assert h.client is not None
    client = Client(h.client.node, FollowJointTrajectory,
                    f'{h.namespace}/dxl_servo_driver/follow_joint_trajectory')
    assert client.wait_for_server(timeout_sec=10.0), 'no follow_joint_trajectory server'
    return client


def tolerance(name: str, position: float = 0.0, velocity: float = 0.0,
              acceleration: float = 0.0) -> JointTolerance:
    return JointTolerance(name=name, position=position, velocity=velocity,
                          acceleration=acceleration)


def here(h: NodeHarness, joints: Sequence[str]) -> List[float]:
    return [sim_rad(h, name) for name in joints]


def settled(h: NodeHarness, joints: Sequence[str]) -> List[float]:
    """Wait until the joints are still (two reads 50 ms apart agree); return where they are."""
    deadline = time.monotonic() + 5.0
    before = here(h, joints)
    while True:
        time.sleep(0.05)
        now = here(h, joints)
        if max(abs(a - b) for a, b in zip(before, now)) < 0.003:
            return now
        assert time.monotonic() < deadline, 'the joints never came to rest'
        before = now


def wave(start: Sequence[float], points: int, duration_s: float, amplitude: float
         ) -> List[Tuple[float, List[float], List[float]]]:
    """Return an out-and-back move of every joint, at rest at both ends, with its velocities."""
    plan = []
    # Each joint its own amplitude, toward the middle of its range.
    scale = [-math.copysign(amplitude * (1.0 + 0.15 * j), s) for j, s in enumerate(start)]
    for k in range(1, points + 1):
        t = duration_s * k / points
        phase = 2 * math.pi * t / duration_s
        plan.append((t, [s + a * (1 - math.cos(phase)) / 2 for s, a in zip(start, scale)],
                     [a * math.pi / duration_s * math.sin(phase) for a in scale]))
    return plan


def longest_pause_s(states: Messages) -> float:
    """Return the longest time between two joint_states the node published, by their stamps."""
    stamps = sorted(stamp_s(msg) for msg in list(states.items))
    return max((b - a for a, b in zip(stamps, stamps[1:])), default=0.0)


def test_a_six_joint_trajectory_is_followed_and_succeeds(h: NodeHarness) -> None:
    client = client_of(h)
    start = settled(h, ARM)
    plan = wave(start, 30, 3.0, 0.8)   # up to 1.4 rad away and back, 1.5 rad/s at most
    states = Messages(h)
    goal = Goal(client, goal_of(ARM, plan))
    status, result = goal.result()
    final = [abs(a - b) for a, b in zip(here(h, ARM), plan[-1][1])]
    # How far behind the path each joint was, as the node saw it in one cycle (its feedback:
    # desired and actual of the same sample), so that no clock of this test's is in it.
    errors = [abs(error) for _, feedback in goal.feedback for error in feedback.error.positions]
    # A cycle the machine held up leaves the servos on an older goal: the path runs on at up to
    # 1.5 rad/s meanwhile. The longest pause between two published samples says how long.
    pause_s = longest_pause_s(states)
    allowed = 0.15 + 1.5 * max(0.0, pause_s - 0.02)
    print(f'error in {len(goal.feedback)} feedback: max {max(errors):.4f} rad (allowed '
          f'{allowed:.3f}: longest pause {pause_s * 1e3:.0f} ms); final {max(final):.4f} rad; '
          f'{goal.ended_s - goal.sent_s:.2f} s')
    assert status == GoalStatus.STATUS_SUCCEEDED, result.error_string
    assert result.error_code == Result.SUCCESSFUL
    # The servos follow the sampled path with their own lag (no profile, the default PID).
    assert max(errors) < allowed, errors
    assert max(final) < 0.05, final   # goal_tolerance: the default 0.05 rad
    # Feedback at action_monitor_rate (20 Hz) over the 3 s, never more often; each from a
    # fresh sample (fewer where a busy machine held the node up).
    assert 10 <= len(goal.feedback) <= 20.0 * (goal.ended_s - goal.sent_s) + 5, (
        len(goal.feedback))
    stamp, last = goal.feedback[-1]
    assert list(last.joint_names) == list(ARM)
    for name, desired, actual, error in zip(last.joint_names, last.desired.positions,
                                            last.actual.positions, last.error.positions):
        assert error == pytest.approx(desired - actual)
        assert abs(actual - sim_rad(h, name)) < 0.1


REFUSALS: Dict[str, Tuple[Callable[[List[float]], Any], int, str]] = {
    'unknown joint': (lambda p: goal_of(['j1', 'nope'], [(1.0, [p[0], 0.0], [])]),
                      Result.INVALID_JOINTS, "unknown joint 'nope'"),
    'velocity joint': (lambda p: goal_of(['j1', 'wheel'], [(1.0, [p[0], 0.0], [])]),
                       Result.INVALID_JOINTS, "joint 'wheel' is in velocity mode"),
    'times not increasing': (
        lambda p: goal_of(['j1'], [(1.0, [p[0]], []), (1.0, [p[0]], [])]),
        Result.INVALID_GOAL, 'not after the previous point'),
    'lengths disagree': (lambda p: goal_of(['j1', 'j3'], [(1.0, [p[0]], [])]),
                         Result.INVALID_GOAL, '1 positions for 2 joints'),
    'not a number': (lambda p: goal_of(['j1'], [(1.0, [math.nan], [])]),
                     Result.INVALID_GOAL, "joint 'j1' has position nan"),
    'infinite velocity': (lambda p: goal_of(['j1'], [(1.0, [p[0]], [math.inf])]),
                          Result.INVALID_GOAL, "joint 'j1' has velocity inf"),
    'beyond the limits': (lambda p: goal_of(['j1'], [(1.0, [4.0], [])]),
                          Result.INVALID_GOAL, 'beyond its limits'),
    'no points': (lambda p: goal_of(['j1'], []), Result.INVALID_GOAL, 'no points'),
    'tolerance of another joint': (
        lambda p: goal_of(['j1'], [(1.0, [p[0]], [])], path_tolerance=[tolerance('j3', 0.1)]),
        Result.INVALID_GOAL, "path_tolerance of 'j3': no such joint"),
    'negative tolerance': (
        lambda p: goal_of(['j1'], [(1.0, [p[0]], [])], goal_tolerance=[tolerance('j1', -2.0)]),
        Result.INVALID_GOAL, 'position -2.0 is neither'),
    'acceleration tolerance': (
        lambda p: goal_of(['j1'], [(1.0, [p[0]], [])],
                          path_tolerance=[tolerance('j1', acceleration=1.0)]),
        Result.INVALID_GOAL, 'acceleration tolerances cannot be checked'),
}


def old_goal(h: NodeHarness, p: List[float]) -> Any:
    goal = goal_of(['j1'], [(0.5, [p[0]], [])])
    stamp = h.node.get_clock().now().nanoseconds - 2 * 10 ** 9   # type: ignore[union-attr]
    goal.trajectory.header.stamp.sec, goal.trajectory.header.stamp.nanosec = divmod(stamp,
                                                                                    10 ** 9)
    return goal


@pytest.mark.parametrize('case', sorted(REFUSALS) + ['old header stamp'])
def test_a_bad_goal_ends_with_its_error_code_and_nothing_moves(h: NodeHarness,
                                                               case: str) -> None:
    client = client_of(h)
    positions = here(h, ARM)
    goals_before = {name: h.reg(IDS[name], 'goal_position') for name in ARM}
    if case == 'old header stamp':
        goal, code, reason = old_goal(h, positions), Result.OLD_HEADER_TIMESTAMP, 'ended'
    else:
        make, code, reason = REFUSALS[case]
        goal = make(positions)
    status, result = Goal(client, goal).result()
    assert status == GoalStatus.STATUS_ABORTED
    assert result.error_code == code, result.error_string
    assert reason in result.error_string
    time.sleep(0.1)   # what a wrongly accepted goal would have written by now
    assert {name: h.reg(IDS[name], 'goal_position') for name in ARM} == goals_before


def test_cancel_holds_the_joints_where_they_are(h: NodeHarness) -> None:
    client = client_of(h)
    start = settled(h, ['j1', 'j3'])
    goal = Goal(client, goal_of(['j1', 'j3'], [(2.0, [s + 1.5 for s in start], [])]))
    wait_until(lambda: all(a - s > 0.3 for a, s in zip(here(h, ['j1', 'j3']), start)), 5.0,
               'the joints on the way')
    goal.cancel()
    status, result = goal.result()
    assert status == GoalStatus.STATUS_CANCELED, result.error_string
    assert result.error_code == Result.SUCCESSFUL
    at_cancel = here(h, ['j1', 'j3'])
    time.sleep(0.2)
    later = here(h, ['j1', 'j3'])
    moved = [abs(a - b) for a, b in zip(at_cancel, later)]
    print(f'after the cancel: {at_cancel} -> {later} (0.2 s)')
    # Held where they were (the last sample ahead of them is not what they go to): within
    # 0.05 rad 0.2 s on, and far from the goal's end.
    assert max(moved) < 0.05, moved
    assert all(abs(a - (s + 1.5)) > 0.2 for a, s in zip(later, start))


def test_a_goal_sharing_a_joint_preempts_the_running_one(h: NodeHarness) -> None:
    client = client_of(h)
    start = settled(h, ['j1', 'j3'])
    first = Goal(client, goal_of(['j1', 'j3'], [(3.0, [s + 1.0 for s in start], [])]))
    time.sleep(0.5)
    second = Goal(client, goal_of(['j3'], [(0.5, [start[1] - 0.3], [])]))
    status, result = first.result()
    assert status == GoalStatus.STATUS_ABORTED
    assert 'preempted by goal' in result.error_string and "'j3'" in result.error_string
    assert second.handle.goal_id.uuid.tobytes().hex()[:8] in result.error_string
    status, result = second.result()
    assert status == GoalStatus.STATUS_SUCCEEDED, result.error_string
    assert abs(sim_rad(h, 'j3') - (start[1] - 0.3)) < 0.05


def test_goals_on_disjoint_joints_run_side_by_side(h: NodeHarness) -> None:
    client = client_of(h)
    start = settled(h, ['j1', 'j4'])
    states = Messages(h)
    a = Goal(client, goal_of(['j1'], [(1.5, [start[0] + 0.5], [])]))
    b = Goal(client, goal_of(['j4'], [(1.0, [start[1] - 0.5], [])]))
    for goal in (a, b):
        status, result = goal.result()
        assert status == GoalStatus.STATUS_SUCCEEDED, result.error_string
    assert abs(sim_rad(h, 'j1') - (start[0] + 0.5)) < 0.05
    assert abs(sim_rad(h, 'j4') - (start[1] - 0.5)) < 0.05
    # Both under way at once: one sample (one moment, the node's) has both halfway.
    both = [msg for msg in list(states.items)
            if {'j1', 'j4'} <= set(msg.name)
            and start[0] + 0.1 < msg.position[list(msg.name).index('j1')] < start[0] + 0.4
            and start[1] - 0.4 < msg.position[list(msg.name).index('j4')] < start[1] - 0.1]
    assert both, 'no sample with both joints on their way'


def test_a_brake_on_one_joint_violates_the_path_tolerance(h: NodeHarness) -> None:
    client = client_of(h)
    start = settled(h, ['j5', 'j6'])
    h.sim.set_load(IDS['j5'], 6.0)   # beyond the XM430's 4.1 N*m stall torque
    states = Messages(h)
    try:
        goal = Goal(client, goal_of(['j5', 'j6'], [(2.0, [s + 1.0 for s in start], [])],
                                    path_tolerance=[tolerance('j5', 0.1),
                                                    tolerance('j6', 0.1)]))
        status, result = goal.result()
        after_s = goal.ended_s - goal.sent_s
        print(f'path violation after {after_s:.2f} s: {result.error_string}')
        assert status == GoalStatus.STATUS_ABORTED
        assert result.error_code == Result.PATH_TOLERANCE_VIOLATED
        assert "joint 'j5'" in result.error_string
        # 0.1 rad behind a ramp of 0.5 rad/s: about 0.2 s, the lag of the free joint aside,
        # and however long a busy machine held the node's cycle up meanwhile.
        assert after_s < 0.6 + longest_pause_s(states), after_s
        held = here(h, ['j6'])
        time.sleep(0.3)
        assert abs(here(h, ['j6'])[0] - held[0]) < 0.03   # the free joint holds too
    finally:
        h.sim.set_load(IDS['j5'], 0.0)


def test_a_joint_short_of_its_goal_violates_the_goal_tolerance(h: NodeHarness) -> None:
    client = client_of(h)
    start = settled(h, ['j4'])
    h.sim.set_load(IDS['j4'], 6.0)
    try:
        goal = Goal(client, goal_of(['j4'], [(0.3, [start[0] + 0.5], [])],
                                    goal_time_tolerance=Duration(sec=0, nanosec=200_000_000)))
        status, result = goal.result()
        assert status == GoalStatus.STATUS_ABORTED
        assert result.error_code == Result.GOAL_TOLERANCE_VIOLATED, result.error_string
        assert "'j4'" in result.error_string
        # Not before its time and tolerance (0.5 s); soon after (a busy machine: 3 s).
        assert 0.4 < goal.ended_s - goal.sent_s < 3.0
    finally:
        h.sim.set_load(IDS['j4'], 0.0)


def run_until_midway(joints: Sequence[str]) -> Tuple[NodeHarness, Goal]:
    h = arm_harness()
    client = client_of(h)
    start = settled(h, joints)
    goal = Goal(client, goal_of(joints, [(3.0, [s + 1.0 for s in start], [])]))
    wait_until(lambda: all(a - s > 0.1 for a, s in zip(here(h, joints), start)), 5.0,
               'the joints on their way')
    assert not goal.done
    return h, goal


def test_a_deactivate_ends_a_running_goal() -> None:
    h, goal = run_until_midway(['j1', 'j2'])
    with h:
        event_s = time.monotonic()
        response = h.call('change_state', transition=__import__(
            'lifecycle_msgs.msg', fromlist=['Transition']).Transition(
                id=4))   # deactivate
        assert response.success
        status, result = goal.result(5.0)
        assert status == GoalStatus.STATUS_ABORTED
        assert 'deactivated' in result.error_string
        assert goal.ended_s - event_s < 1.5


def test_a_port_loss_ends_a_running_goal() -> None:
    h, goal = run_until_midway(['j1', 'j2'])
    with h:
        port = h.node.manager.port   # type: ignore[union-attr]
        event_s = time.monotonic()
        port.unplug_port()
        status, result = goal.result(5.0)
        assert status == GoalStatus.STATUS_ABORTED
        assert 'the port is lost' in result.error_string, result.error_string
        assert goal.ended_s - event_s < 1.5
        port.plug_port()


def test_a_servo_that_stops_answering_ends_a_running_goal() -> None:
    h, goal = run_until_midway(['j1', 'j2'])
    with h:
        event_s = time.monotonic()
        h.sim.unplug(IDS['j2'])
        status, result = goal.result(5.0)
        assert status == GoalStatus.STATUS_ABORTED
        assert "joint 'j2' stopped answering" in result.error_string, result.error_string
        assert goal.ended_s - event_s < 1.5
        h.sim.plug(IDS['j2'])


def test_a_latched_hardware_error_ends_a_running_goal() -> None:
    h, goal = run_until_midway(['j1', 'j2'])
    with h:
        injected_s = time.monotonic()
        h.sim.inject_error(IDS['j1'], 'overload')
        status, result = goal.result(5.0)
        assert status == GoalStatus.STATUS_ABORTED
        assert "joint 'j1' latched a hardware error" in result.error_string, result.error_string
        assert 'overload' in result.error_string
        assert goal.ended_s - injected_s < 1.0
        # The other joint comes to rest short of the goal's end, and nothing resumes the goal.
        held = settled(h, ['j2'])[0]
        time.sleep(0.5)
        assert abs(sim_rad(h, 'j2') - held) < 0.02


def gripper_client(h: NodeHarness, action: str = 'gripper_cmd') -> Client:
    assert h.client is not None
    client = Client(h.client.node, GripperCommand,
                    f'{h.namespace}/dxl_servo_driver/{action}')
    assert client.wait_for_server(timeout_sec=10.0), f'no {action} server'
    return client


def grip(position: float, max_effort: float = 0.0) -> Any:
    goal = GripperCommand.Goal()
    goal.command.position = position
    goal.command.max_effort = max_effort
    return goal


def test_a_gripper_goal_with_nothing_in_the_way_reaches_it(h: NodeHarness) -> None:
    client = gripper_client(h)
    goal = Goal(client, grip(1.0))
    status, result = goal.result()
    assert status == GoalStatus.STATUS_SUCCEEDED
    assert result.reached_goal and not result.stalled
    assert abs(result.position - 1.0) <= 0.05
    assert abs(sim_rad(h, 'claw') - 1.0) <= 0.05
    # Back open, through the joint's own action name.
    status, result = Goal(gripper_client(h, 'claw/gripper_cmd'), grip(0.0)).result()
    assert status == GoalStatus.STATUS_SUCCEEDED and result.reached_goal


def test_a_gripper_goal_stalls_on_an_object_at_its_effort_without_overload(
        h: NodeHarness) -> None:
    client = gripper_client(h)
    sid = IDS['claw']
    torque_constant = XM430_UNITS.torque_constant_nm_per_a
    max_effort = 0.3 * torque_constant   # N*m: 0.3 A on the XM430
    h.sim.set_load(sid, 3.0)   # an object the claw cannot push through at 0.3 A
    try:
        goal = Goal(client, grip(1.5, max_effort))
        status, result = goal.result()
        print(f'stalled at {result.position:.3f} rad with {result.effort:.3f} N*m '
              f'(max_effort {max_effort:.3f} N*m); {len(goal.feedback)} feedback')
        assert status == GoalStatus.STATUS_SUCCEEDED
        assert result.stalled and not result.reached_goal
        assert result.position < 1.5 - 0.05
        assert result.effort == pytest.approx(max_effort, rel=0.3)
        assert h.reg(sid, 'goal_current') == XM430_UNITS.current_from_a(0.3)
        # Held with the limited current: never the overload latch.
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline:
            assert h.reg(sid, 'hardware_error_status') == 0
            time.sleep(0.05)
    finally:
        h.sim.set_load(sid, 0.0)
    status, result = Goal(client, grip(0.0)).result()
    assert status == GoalStatus.STATUS_SUCCEEDED and result.reached_goal


def test_a_gripper_goal_beyond_its_current_limit_is_refused(h: NodeHarness) -> None:
    before = (h.reg(IDS['claw'], 'goal_position'), h.reg(IDS['claw'], 'goal_current'))
    status, result = Goal(gripper_client(h), grip(1.0, 500.0)).result()
    assert status == GoalStatus.STATUS_ABORTED
    time.sleep(0.1)
    assert (h.reg(IDS['claw'], 'goal_position'), h.reg(IDS['claw'], 'goal_current')) == before


def parallel_client(h: NodeHarness, action: str = 'parallel_gripper_cmd') -> Client:
    assert h.client is not None
    client = Client(h.client.node, ParallelGripperCommand,
                    f'{h.namespace}/dxl_servo_driver/{action}')
    assert client.wait_for_server(timeout_sec=10.0), f'no {action} server'
    return client


def parallel(position: Sequence[float], velocity: Sequence[float] = (),
             effort: Sequence[float] = (), name: Sequence[str] = ('claw',)) -> Any:
    """Return a ParallelGripperCommand goal as MoveIt fills it (arrays empty when not given)."""
    goal = ParallelGripperCommand.Goal()
    goal.command.name = list(name)
    goal.command.position = [float(value) for value in position]
    goal.command.velocity = [float(value) for value in velocity]
    goal.command.effort = [float(value) for value in effort]
    return goal


def opened(h: NodeHarness, client: Client) -> None:
    """Open the claw and wait for it to be there."""
    status, result = Goal(client, parallel([0.0])).result()
    assert status == GoalStatus.STATUS_SUCCEEDED and result.reached_goal
    wait_until(lambda: abs(sim_rad(h, 'claw')) < 0.05, 10.0, 'the claw open')


def still(h: NodeHarness, name: str, for_s: float) -> float:
    """Wait until a joint's goal stays unchanged for for_s (nothing walks it on); return it."""
    sid = IDS[name]
    deadline = time.monotonic() + 10.0
    goal = h.reg(sid, 'goal_position')
    since = time.monotonic()
    while time.monotonic() - since < for_s:
        assert time.monotonic() < deadline, f'the goal of {name} never stayed put'
        time.sleep(0.02)
        now = h.reg(sid, 'goal_position')
        if now != goal:
            goal, since = now, time.monotonic()
    return XM430_UNITS.position_to_rad(goal)


def test_a_parallel_gripper_goal_stalls_on_an_object_and_then_opens(h: NodeHarness) -> None:
    """A ParallelGripperCommand as MoveIt sends it closes onto an object, holds it, opens."""
    client = parallel_client(h)
    sid = IDS['claw']
    max_effort = 0.3 * XM430_UNITS.torque_constant_nm_per_a   # N*m: 0.3 A on the XM430
    h.sim.set_load(sid, 3.0)   # an object the claw cannot push through at 0.3 A
    try:
        goal = Goal(client, parallel([1.5], effort=[max_effort]))
        status, result = goal.result()
        state = result.state
        print(f'stalled at {state.position} rad with {state.effort} N*m '
              f'(effort {max_effort:.3f} N*m); {len(goal.feedback)} feedback')
        assert status == GoalStatus.STATUS_SUCCEEDED
        assert result.stalled and not result.reached_goal
        assert list(state.name) == ['claw']
        assert len(state.position) == len(state.velocity) == len(state.effort) == 1
        assert state.position[0] < 1.5 - 0.05
        assert abs(state.velocity[0]) < 0.2   # stopped
        assert state.effort[0] == pytest.approx(max_effort, rel=0.3)
        assert h.reg(sid, 'goal_current') == XM430_UNITS.current_from_a(0.3)
        assert goal.feedback, 'no feedback'
        assert all(list(msg.state.name) == ['claw'] for _, msg in goal.feedback)
        # Held by what it grips, with the limited current: where it stopped, never the
        # overload latch.
        held = sim_rad(h, 'claw')
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline:
            assert h.reg(sid, 'hardware_error_status') == 0
            assert abs(sim_rad(h, 'claw') - held) < 0.05
            time.sleep(0.05)
    finally:
        h.sim.set_load(sid, 0.0)
    status, result = Goal(client, parallel([0.0], velocity=[2.0])).result()
    assert status == GoalStatus.STATUS_SUCCEEDED
    assert result.reached_goal and not result.stalled
    assert abs(result.state.position[0]) <= 0.05
    wait_until(lambda: abs(sim_rad(h, 'claw')) < 0.05, 10.0, 'the claw open')


def test_a_parallel_gripper_goal_moves_no_faster_than_its_velocity(h: NodeHarness) -> None:
    client = parallel_client(h, 'claw/parallel_gripper_cmd')
    opened(h, client)
    start = sim_rad(h, 'claw')
    speed = 1.0
    goal = Goal(client, parallel([1.2], velocity=[speed]))
    ahead = -math.inf
    while not goal.done:
        rad = sim_rad(h, 'claw')
        # Dated after the read, from before the goal was sent: the walk may only be later.
        allowed = start + speed * (time.monotonic() - goal.sent_s)
        ahead = max(ahead, rad - allowed)
        time.sleep(0.01)
    status, result = goal.result()
    print(f'{goal.ended_s - goal.sent_s:.2f} s for 1.2 rad at {speed} rad/s; at most '
          f'{ahead:+.3f} rad from the walk')
    assert status == GoalStatus.STATUS_SUCCEEDED and result.reached_goal
    assert ahead < 0.05
    assert goal.ended_s - goal.sent_s >= (1.2 - start - 0.05 - 0.05) / speed


def test_a_canceled_parallel_gripper_goal_holds_where_it_is(h: NodeHarness) -> None:
    client = parallel_client(h)
    opened(h, client)
    goal = Goal(client, parallel([1.5], velocity=[0.3]))
    wait_until(lambda: sim_rad(h, 'claw') > 0.3, 10.0, 'the claw on its way')
    goal.cancel()
    status, result = goal.result()
    assert status == GoalStatus.STATUS_CANCELED
    assert not result.reached_goal and result.state.position[0] < 1.4
    # Its goal is where it stopped, and nothing walks it on.
    assert still(h, 'claw', 0.5) < 1.4


def test_a_parallel_gripper_goal_is_preempted_by_the_next(h: NodeHarness) -> None:
    client = parallel_client(h)
    opened(h, client)
    first = Goal(client, parallel([1.5], velocity=[0.3]))
    wait_until(lambda: sim_rad(h, 'claw') > 0.2, 10.0, 'the claw on its way')
    # The same joint through its own action name: one goal at a time per gripper.
    second = Goal(parallel_client(h, 'claw/parallel_gripper_cmd'), parallel([0.0]))
    assert first.result()[0] == GoalStatus.STATUS_ABORTED
    status, result = second.result()
    assert status == GoalStatus.STATUS_SUCCEEDED and result.reached_goal
    assert abs(still(h, 'claw', 0.3)) < 0.05


class Unheard:
    """A listener for goals that must be refused before anything is heard of them."""

    feedback_period_s = 0.05

    def feedback(self, sample: Any) -> None:
        raise AssertionError(f'a refused goal had feedback {sample}')

    def ended(self, outcome: Any) -> None:
        raise AssertionError(f'a refused goal ended {outcome}')


REFUSED_PARALLEL = [
    (parallel([1.7]), 'beyond the travel'),
    (parallel([-0.3], effort=[0.2]), 'beyond the travel'),
    (parallel([0.5], name=['j1']), "the one joint of this action, 'claw'; got 'j1'"),
    (parallel([0.5], name=['claw', 'claw']), 'the one joint of this action'),
    (parallel([0.5], name=[]), 'got none'),
    (parallel([]), 'one position'),
    (parallel([math.nan]), 'not a finite number'),
    (parallel([math.inf]), 'not a finite number'),
    (parallel([0.5, 0.6]), 'one position'),
    (parallel([0.5], velocity=[1.0, 1.0]), 'velocity must be empty or hold one value'),
    (parallel([0.5], effort=[0.1, 0.1]), 'effort must be empty or hold one value'),
    (parallel([0.5], velocity=[-1.0]), 'velocity -1.0 is not a finite speed'),
    (parallel([0.5], effort=[math.nan]), 'effort nan is not a finite effort'),
    (parallel([0.5], effort=[500.0]), 'above the current limit'),
]


def test_a_parallel_gripper_goal_that_cannot_be_done_is_refused(h: NodeHarness) -> None:
    assert h.node is not None
    sid = IDS['claw']
    client = parallel_client(h)
    before = (h.reg(sid, 'goal_position'), h.reg(sid, 'goal_current'))
    for goal, why in REFUSED_PARALLEL:
        # The reason, as the log says it ...
        with pytest.raises(GripperError, match=re.escape(why)):
            h.node.arm.submit_parallel_gripper_goal('claw', goal.command, Unheard())
        # ... and the action's answer: aborted at once, nothing written.
        status, result = Goal(client, goal).result()
        assert status == GoalStatus.STATUS_ABORTED, why
        assert not result.reached_goal and not result.stalled
    seen = h.joint_states.received
    h.joint_states.wait(lambda _: h.joint_states.received >= seen + 5, timeout_s=10.0)
    assert (h.reg(sid, 'goal_position'), h.reg(sid, 'goal_current')) == before


def test_effort_is_refused_where_the_grippers_mode_has_no_current_control(
        h: NodeHarness) -> None:
    assert h.node is not None
    sid = IDS['claw']
    client = parallel_client(h)
    assert h.call('set_operating_mode', name=['claw'], mode='position').success
    try:
        before = h.reg(sid, 'goal_position')
        goal = parallel([0.5], effort=[0.2])
        with pytest.raises(GripperError, match='command.effort 0.2 N.m needs current control: '
                           "gripper 'claw' is in position mode, which has none"):
            h.node.arm.submit_parallel_gripper_goal('claw', goal.command, Unheard())
        status, _ = Goal(client, goal).result()
        assert status == GoalStatus.STATUS_ABORTED
        seen = h.joint_states.received
        h.joint_states.wait(lambda _: h.joint_states.received >= seen + 5, timeout_s=10.0)
        assert h.reg(sid, 'goal_position') == before
    finally:
        assert h.call('set_operating_mode', name=['claw'],
                      mode='current_based_position').success


def test_the_arm_example_takes_moveits_two_actions() -> None:
    """config/arm_sim.yaml, as `make run PARAMS=config/arm_sim.yaml` runs it."""
    import pathlib
    import yaml
    from dxl_servo_driver.config import validate
    from dxl_servo_driver.models import model_named
    from dxl_servo_driver.models.units import JointFrame
    from dxl_servo_driver.tool.yaml_edit import flatten
    path = pathlib.Path(__file__).resolve().parents[2] / 'config' / 'arm_sim.yaml'
    params = flatten(yaml.safe_load(path.read_text())['/**']['ros__parameters'])
    config = validate(params)
    arm = [joint.name for joint in config.joints if not joint.gripper]
    # Each joint's position from its simulated servo's register, through the file's frame.
    units = {joint.name: units_for(model_named(params[f'{joint.name}.model']),
                                   frame=JointFrame(joint.offset, joint.reverse, joint.ratio))
             for joint in config.joints}
    ids = {joint.name: joint.servo_id for joint in config.joints}
    with NodeHarness(params) as h:
        h.joint_states.wait(lambda m: len(m.name) == len(config.joints))

        def joint_rad(name: str) -> float:
            return units[name].position_to_rad(h.reg(ids[name], 'present_position'))

        target = [0.5, -0.4, 0.8, -0.3, 2.0]
        start = [joint_rad(name) for name in arm]
        plan = [(1.0, [(s + t) / 2 for s, t in zip(start, target)], []), (2.0, target, [])]
        status, result = Goal(client_of(h), goal_of(arm, plan)).result()
        assert status == GoalStatus.STATUS_SUCCEEDED, result.error_string
        for name, goal in zip(arm, target):
            assert joint_rad(name) == pytest.approx(goal, abs=0.03), name   # goal_tolerance
        # The shoulder's second servo (id 7, facing the other way) went with the joint.
        second = units_for(model_named('XM540-W270'),
                           frame=JointFrame(0.0, False, 1.0)).position_to_rad(
                               h.reg(7, 'present_position'))
        assert second == pytest.approx(target[1], abs=0.03)
        assert joint_rad('shoulder_lift') == pytest.approx(second, abs=0.03)
        # The belt-driven wrist roll: its horn turned twice as far as the joint.
        horn = units_for(model_named('XL430-W250')).position_to_rad(
            h.reg(ids['wrist_roll'], 'present_position'))
        assert horn == pytest.approx(4.0, abs=0.06)
        # The gripper as config/moveit's controller drives it: <node>/<joint>/<action_ns>.
        status, result = Goal(parallel_client(h, 'gripper/parallel_gripper_cmd'),
                              parallel([1.0], name=['gripper'])).result()
        assert status == GoalStatus.STATUS_SUCCEEDED and result.reached_goal
        assert result.state.position[0] == pytest.approx(1.0, abs=0.03)
        # Reached on the way in; the XL330 overshoots (0.09-0.17 rad seen) before it settles:
        # it must settle there, not be at one moment read after the result.
        wait_until(lambda: abs(joint_rad('gripper') - 1.0) < 0.03, 10.0, 'the gripper settled')


def test_a_burst_of_goals_is_answered_whole() -> None:
    """
    Fifty goals sent at once by one client: every one is answered, and every result comes.

    The middleware's default request queue (depth 10) dropped all but about 15 of them, and
    their client waited forever (actions.ACTION_QUEUE_DEPTH; with it back at 10 this fails).
    The client's own goal and result queues are deeper, as docs/moveit.md says a client sending
    or asking more than ten at once must make them: a default client, on a loaded machine, lost
    its own burst before the server saw it (2 runs in 6 beside three busy loops).
    """
    with arm_harness() as fresh:
        burst(fresh)


def burst(h: NodeHarness) -> None:
    assert h.client is not None
    deep = QoSProfile(depth=100)
    client = Client(h.client.node, FollowJointTrajectory,
                    f'{h.namespace}/dxl_servo_driver/follow_joint_trajectory',
                    goal_service_qos_profile=deep, result_service_qos_profile=deep)
    assert client.wait_for_server(timeout_sec=10.0), 'no follow_joint_trajectory server'
    start = here(h, ['j1'])[0]
    futures = in_executor(h.client.node, lambda: [
        client.send_goal_async(goal_of(['j1'], [(0.5, [start + 0.001 * k], [])]))
        for k in range(50)])
    wait_until(lambda: all(future.done() for future in futures), 20.0,
               f'all 50 goals answered ({sum(f.done() for f in futures)} were)')
    handles = [future.result() for future in futures]
    assert all(handle.accepted for handle in handles)
    results = in_executor(h.client.node,
                          lambda: [handle.get_result_async() for handle in handles])
    wait_until(lambda: all(result.done() for result in results), 20.0,
               f'all 50 results come ({sum(r.done() for r in results)} did)')
    statuses = [result.result().status for result in results]
    # Each goal preempted the one before it; the last ran to its end.
    assert statuses[-1] == GoalStatus.STATUS_SUCCEEDED, statuses
    assert statuses[:-1] == [GoalStatus.STATUS_ABORTED] * 49, statuses
