"""
Joints as the robot sees them: offset, reverse, ratio and limits on every interface.

joint = (-1 if reverse else 1) * ratio * (servo - offset), servo in the radians of the horn
(raw 2048 = 0). Each test reads the simulated servo's own registers and computes the joint's
value from them by that formula, so a sign, an offset or a ratio applied the wrong way round
fails here.
"""

import math
import time
from typing import Any, Dict, Iterator

from action_client import Client, result_of, send_goal
from action_msgs.msg import GoalStatus
from control_msgs.action import FollowJointTrajectory, GripperCommand
from dxl_servo_driver.models import model_for
from dxl_servo_driver.models.units import units_for
from node_harness import NodeHarness, sim_params
import pytest
from sensor_msgs.msg import JointState
from trajectories import trajectory
from trajectory_msgs.msg import JointTrajectoryPoint

XM430 = units_for(model_for(1030))
FRAMES: Dict[str, Dict[str, Any]] = {
    # A reversed joint whose 0 is 0.5 rad round the horn, with limits of its own.
    'elbow': {'id': 1, 'operating_mode': 'position', 'offset': 0.5, 'reverse': True,
              'min_position': -1.0, 'max_position': 1.2},
    # A 1:3 gearbox after the horn, multi-turn.
    'wrist': {'id': 2, 'operating_mode': 'extended_position', 'ratio': 1.0 / 3.0},
    # A reversed wheel.
    'wheel': {'id': 3, 'operating_mode': 'velocity', 'reverse': True},
    # A reversed current-mode joint behind a 2:1 reduction (ratio 0.5): effort goes through both.
    'hand': {'id': 4, 'operating_mode': 'current', 'reverse': True, 'ratio': 0.5},
    # A linear gripper: a rack and pinion of 1 cm per servo radian, its joint in m and N.
    'finger': {'id': 5, 'operating_mode': 'current_based_position', 'ratio': 0.01,
               'gripper': True, 'gripper_open': 0.0, 'gripper_closed': 0.012,
               'goal_tolerance': 0.0005},   # m: tolerances are in the joint's units too
    # Multi-turn at start, with limits only a single-turn mode writes to the servo.
    'tilt': {'id': 6, 'operating_mode': 'extended_position', 'min_position': -1.0,
             'max_position': 1.0},
    # Limits wider than one turn: position mode cannot hold them.
    'spin': {'id': 7, 'operating_mode': 'extended_position', 'min_position': -4.0,
             'max_position': 4.0},
}
IDS = {name: keys['id'] for name, keys in FRAMES.items()}


def joint_of(name: str, servo_rad: float) -> float:
    keys = FRAMES[name]
    sign = -1.0 if keys.get('reverse') else 1.0
    return sign * keys.get('ratio', 1.0) * (servo_rad - keys.get('offset', 0.0))


def servo_of(name: str, joint: float) -> float:
    keys = FRAMES[name]
    sign = -1.0 if keys.get('reverse') else 1.0
    return joint / (sign * keys.get('ratio', 1.0)) + keys.get('offset', 0.0)


@pytest.fixture(scope='module')
def h() -> Iterator[NodeHarness]:
    with NodeHarness(sim_params(FRAMES)) as harness:
        harness.joint_states.wait(lambda m: len(m.name) == len(FRAMES))
        yield harness


def servo_rad(h: NodeHarness, name: str, register: str = 'present_position') -> float:
    return XM430.position_to_rad(h.reg(IDS[name], register))


def published(h: NodeHarness, name: str) -> Any:
    msg = h.joint_states.wait(lambda m: name in m.name, timeout_s=5.0)
    i = list(msg.name).index(name)
    return msg.position[i], msg.velocity[i], msg.effort[i]


def test_joint_states_are_in_the_joints_frame(h: NodeHarness) -> None:
    for name in ('elbow', 'wrist'):
        expected = joint_of(name, servo_rad(h, name))
        position = h.joint_states.wait(
            lambda m: name in m.name and abs(
                m.position[list(m.name).index(name)] - expected) < 0.01, timeout_s=5.0)
        assert position is not None
    # The elbow's horn sits at 0 rad: the joint reads -(0 - 0.5) = 0.5, not -0.5.
    expected = joint_of('elbow', servo_rad(h, 'elbow'))
    assert published(h, 'elbow')[0] == pytest.approx(expected, abs=0.01)


def test_a_position_command_goes_to_the_servo_through_the_frame(h: NodeHarness) -> None:
    h.publish('position', ['elbow', 'wrist'], [0.8, 2.0])
    for name, goal in (('elbow', 0.8), ('wrist', 2.0)):
        want = servo_of(name, goal)
        h.wait_reg(IDS[name], 'goal_position',
                   lambda raw, want=want: abs(XM430.position_to_rad(raw) - want) < 0.003)
    # The wrist's servo turns 3 times as far: 6 rad for 2 rad of joint.
    assert servo_rad(h, 'wrist', 'goal_position') == pytest.approx(6.0, abs=0.003)
    # The elbow's servo goes the other way: 0.5 - 0.8 = -0.3 rad.
    assert servo_rad(h, 'elbow', 'goal_position') == pytest.approx(-0.3, abs=0.003)
    h.joint_states.wait(lambda m: abs(m.position[list(m.name).index('elbow')] - 0.8) < 0.02)


def test_a_velocity_command_is_reversed_and_joint_states_say_so(h: NodeHarness) -> None:
    h.publish('velocity', ['wheel'], [1.0])
    h.wait_reg(IDS['wheel'], 'goal_velocity', lambda raw: XM430.velocity_to_rad_s(
        raw if raw < 2 ** 31 else raw - 2 ** 32) == pytest.approx(-1.0, abs=0.03))
    msg = h.joint_states.wait(lambda m: abs(m.velocity[list(m.name).index('wheel')] - 1.0) < 0.05)
    assert msg is not None
    h.publish('velocity', ['wheel'], [0.0])


def test_beyond_min_or_max_position_is_refused_whole(h: NodeHarness) -> None:
    time.sleep(0.1)
    before = h.reg(IDS['elbow'], 'goal_position'), h.reg(IDS['wrist'], 'goal_position')
    response = h.call('set_position', name=['wrist', 'elbow'], value=[1.0, 1.5])
    assert not response.success
    assert "joint 'elbow': position 1.5 is beyond its limits -1.0..1.2" in response.message
    assert (h.reg(IDS['elbow'], 'goal_position'), h.reg(IDS['wrist'], 'goal_position')) == before


def test_the_limits_are_the_servos_position_limits(h: NodeHarness) -> None:
    # Reversed: the joint's max (1.2) is the servo's lowest angle, 0.5 - 1.2 = -0.7 rad.
    low = XM430.position_to_rad(h.reg(IDS['elbow'], 'min_position_limit'))
    high = XM430.position_to_rad(h.reg(IDS['elbow'], 'max_position_limit'))
    assert low == pytest.approx(servo_of('elbow', 1.2), abs=0.003)
    assert high == pytest.approx(servo_of('elbow', -1.0), abs=0.003)
    # The limits in force are listed, in joint units, for a joint whose file gave none.
    assert h.node is not None
    shown = h.node.get_parameter('wrist.max_position').value
    assert shown == pytest.approx(256 * 2 * math.pi / 3, rel=0.01)


def test_a_trajectory_runs_in_joint_units(h: NodeHarness) -> None:
    assert h.node is not None
    assert h.node.arm.submit_trajectory(trajectory(['elbow'], [(1.0, [-0.5], [])])).success
    h.wait_reg(IDS['elbow'], 'present_position',
               lambda raw: abs(XM430.position_to_rad(raw) - servo_of('elbow', -0.5)) < 0.03)
    # Beyond the joint's own limits: refused whole.
    reply = h.node.arm.submit_trajectory(trajectory(['elbow'], [(1.0, [-1.1], [])]))
    assert not reply.success and 'beyond its limits -1..1.19' in reply.message, reply


def action_client(h: NodeHarness, kind: Any, action: str) -> Client:
    assert h.client is not None
    client = Client(h.client.node, kind, f'{h.namespace}/dxl_servo_driver/{action}')
    assert client.wait_for_server(timeout_sec=10.0), f'no {action} server'
    return client


def test_follow_joint_trajectory_speaks_joint_units(h: NodeHarness) -> None:
    client = action_client(h, FollowJointTrajectory, 'follow_joint_trajectory')
    goal = FollowJointTrajectory.Goal()
    goal.trajectory.joint_names = ['elbow', 'wrist']
    point = JointTrajectoryPoint()
    point.positions = [0.3, 1.0]
    point.time_from_start.sec = 1
    goal.trajectory.points.append(point)
    start = [joint_of(name, servo_rad(h, name)) for name in ('elbow', 'wrist')]
    assert abs(start[0] - 0.3) > 0.2, 'the elbow must have somewhere to go'
    feedback: list = []
    response = result_of(client, send_goal(client, goal, feedback.append))
    assert response.status == GoalStatus.STATUS_SUCCEEDED, response.result.error_string
    # Where the servos are, by the formula (the elbow's horn near 0.5 - 0.3, the wrist's near
    # 3 rad), within the goal tolerance: 0.05 in joint units.
    assert joint_of('elbow', servo_rad(h, 'elbow')) == pytest.approx(0.3, abs=0.05)
    assert joint_of('wrist', servo_rad(h, 'wrist')) == pytest.approx(1.0, abs=0.05)
    assert servo_rad(h, 'wrist') > 2.8   # 1 rad of joint took about 3 of the servo
    # Feedback in joint units: the elbow's actual went from its start toward 0.3 (its servo
    # went the other way), the last one nearer the end than the start.
    last = feedback[-1].feedback
    actual = last.actual.positions[0]
    assert abs(actual - 0.3) < abs(start[0] - 0.3) / 2
    assert (actual - start[0]) * (0.3 - start[0]) > 0
    assert list(last.error.positions) == pytest.approx(
        [d - a for d, a in zip(last.desired.positions, last.actual.positions)])


def test_joint_command_effort_goes_through_ratio_and_reverse(h: NodeHarness) -> None:
    assert h.client is not None
    pub = h.client.node.create_publisher(
        JointState, f'{h.namespace}/dxl_servo_driver/joint_command', 10)
    deadline = time.monotonic() + 10.0
    while pub.get_subscription_count() < 1:
        assert time.monotonic() < deadline
        time.sleep(0.01)
    # 0.2 N*m at the joint is 0.1 N*m at the servo (2:1), the other way round (reversed).
    pub.publish(JointState(name=['hand'], effort=[0.2]))
    kt = XM430.torque_constant_nm_per_a
    want = XM430.current_from_a(-0.2 * 0.5 / kt)
    h.wait_reg(IDS['hand'], 'goal_current',
               lambda raw: (raw - 2 ** 16 if raw >= 2 ** 15 else raw) == want)
    # And joint_states' effort is the servo's torque brought back through the frame: once the
    # servo's current has reached its goal, the 0.2 N*m that was asked (a sign or a ratio the
    # wrong way round would give -0.2, 0.05 or 0.8).
    h.wait_reg(IDS['hand'], 'present_current',
               lambda raw: abs((raw - 2 ** 16 if raw >= 2 ** 15 else raw) - want) <= 2)
    h.joint_states.wait(
        lambda m: 'hand' in m.name and abs(m.effort[list(m.name).index('hand')] - 0.2) < 0.03,
        timeout_s=5.0)
    pub.publish(JointState(name=['hand'], effort=[0.0]))


def test_a_linear_gripper_takes_metres_and_newtons(h: NodeHarness) -> None:
    client = action_client(h, GripperCommand, 'gripper_cmd')
    goal = GripperCommand.Goal()
    goal.command.position = 0.008   # m: the servo turns 0.8 rad
    response = result_of(client, send_goal(client, goal))
    assert response.status == GoalStatus.STATUS_SUCCEEDED and response.result.reached_goal
    assert servo_rad(h, 'finger') == pytest.approx(0.8, abs=0.06)   # 0.5 mm = 0.05 rad
    assert response.result.position == pytest.approx(0.008, abs=0.0006)
    # An object in the way, 0.3 A of grip: 0.3 A * 1.783 N*m/A over 0.01 m/rad = 53.5 N.
    kt = XM430.torque_constant_nm_per_a
    h.sim.set_load(IDS['finger'], 3.0)
    try:
        goal.command.position = 0.012
        goal.command.max_effort = 0.3 * kt / 0.01
        response = result_of(client, send_goal(client, goal))
        result = response.result
        assert response.status == GoalStatus.STATUS_SUCCEEDED, result
        assert result.stalled and not result.reached_goal
        assert h.reg(IDS['finger'], 'goal_current') == XM430.current_from_a(0.3)
        assert result.effort == pytest.approx(goal.command.max_effort, rel=0.3)
    finally:
        h.sim.set_load(IDS['finger'], 0.0)


def test_a_switch_into_position_mode_writes_the_joints_limits(h: NodeHarness) -> None:
    tilt = IDS['tilt']
    default_high = h.reg(tilt, 'max_position_limit')
    assert default_high != XM430.position_from_rad(1.0)   # extended mode: not written
    response = h.call('set_operating_mode', name=['tilt'], mode='position')
    assert response.success, response.message
    assert h.reg(tilt, 'min_position_limit') == XM430.position_from_rad(-1.0)
    assert h.reg(tilt, 'max_position_limit') == XM430.position_from_rad(1.0)
    assert h.call('set_operating_mode', name=['tilt'], mode='extended_position').success
    # Limits a single turn cannot hold: the switch is refused before anything changes.
    response = h.call('set_operating_mode', name=['spin'], mode='position')
    assert not response.success
    assert "joint 'spin': min_position -4 is servo position" in response.message
    assert h.reg(IDS['spin'], 'operating_mode') == 4
    assert h.reg(IDS['spin'], 'torque_enable') == 1
