"""
Nothing moves beyond its configured range, on any command path.

A gripper's range is its travel (gripper_open .. gripper_closed) narrowed by min_position and
max_position where set; a multi-turn joint's is min_position .. max_position. In
current_based_position and extended_position the servo itself takes goals over 256 turns, so
the driver is all that stands between a goal in the wrong units and a broken mechanism: a
GripperCommand of 50 rad once turned a one-radian claw eight times. Every path is driven here
with a goal beyond the range and must refuse it with the reason; at the end the simulated
servos' own Goal Position registers must still be inside their ranges, after enough cycles for
any goal that got through to have been written.
"""

import math
from typing import Any, Callable, Dict, Iterator, List, Tuple

from action_client import Client, result_of, send_goal
from action_msgs.msg import GoalStatus
from control_msgs.action import FollowJointTrajectory, GripperCommand, ParallelGripperCommand
from dxl_servo_driver.config import ConfigError, validate
from dxl_servo_driver.models import model_for
from dxl_servo_driver.models.units import units_for
from dxl_servo_driver_msgs.msg import GripperCommand as GripperTopic
from node_harness import NodeHarness, sim_params
import pytest
from sensor_msgs.msg import JointState
from trajectories import goal_of, trajectory

XM430 = units_for(model_for(1030))
JOINTS: Dict[str, Dict[str, Any]] = {
    # The report's claw: a travel of one radian and no min_position/max_position.
    'claw': {'id': 1, 'operating_mode': 'current_based_position', 'gripper': True,
             'gripper_open': 0.0, 'gripper_closed': 1.0},
    # Closing toward negative angles, its travel narrowed by a max_position.
    'pincer': {'id': 2, 'operating_mode': 'current_based_position', 'gripper': True,
               'gripper_open': 1.0, 'gripper_closed': -0.5, 'max_position': 0.8},
    # Multi-turn with a range of its own.
    'lift': {'id': 3, 'operating_mode': 'extended_position', 'min_position': -1.0,
             'max_position': 2.0},
}
IDS = {name: keys['id'] for name, keys in JOINTS.items()}
RANGES = {'claw': (0.0, 1.0), 'pincer': (-0.5, 0.8), 'lift': (-1.0, 2.0)}
# Beyond each range, above and below; 50 rad is the report's goal.
BEYOND = {name: (high + 49.0, low - 0.1) for name, (low, high) in RANGES.items()}


@pytest.fixture(scope='module')
def h() -> Iterator[NodeHarness]:
    with NodeHarness(sim_params(JOINTS, loop_rate=100.0)) as harness:
        harness.joint_states.wait(lambda m: len(m.name) == len(JOINTS))
        yield harness


def goal_rad(h: NodeHarness, name: str) -> float:
    """Return the simulated servo's own Goal Position, in rad (these joints have no frame)."""
    return XM430.position_to_rad(h.reg(IDS[name], 'goal_position'))


def action(h: NodeHarness, kind: Any, name: str) -> Client:
    assert h.client is not None
    client = Client(h.client.node, kind, f'{h.namespace}/dxl_servo_driver/{name}')
    assert client.wait_for_server(timeout_sec=10.0), f'no {name} server'
    return client


def ended(client: Client, goal: Any) -> Tuple[int, Any]:
    handle = send_goal(client, goal)
    assert handle.accepted   # refused goals are accepted and aborted with the reason
    response = result_of(client, handle, 10.0)
    return response.status, response.result


def gripper_topic(name: str, position: float) -> GripperTopic:
    return GripperTopic(name=name, position=position, ratio=math.nan, max_effort=0.0)


def joint_state(name: str, position: float) -> JointState:
    return JointState(name=[name], position=[position])


def paths(h: NodeHarness) -> Dict[str, Callable[[str, float], Tuple[bool, str]]]:
    """Every path that sends a joint a position goal: (accepted, what it said)."""
    assert h.node is not None
    arm = h.node.arm
    follow = action(h, FollowJointTrajectory, 'follow_joint_trajectory')

    def service(name: str, value: float) -> Tuple[bool, str]:
        response = h.call('set_position', name=[name], value=[value])
        return response.success, response.message

    def topic(name: str, value: float) -> Tuple[bool, str]:
        # What ~/commands/position's callback calls with the message's fields.
        result = h.node.manager.command('position', [name], [value])   # type: ignore[union-attr]
        return result.success, result.message

    def joint_command(name: str, value: float) -> Tuple[bool, str]:
        result = arm.joint_command(joint_state(name, value))
        return result.success, result.message

    def joint_trajectory(name: str, value: float) -> Tuple[bool, str]:
        result = arm.submit_trajectory(trajectory([name], [(0.5, [value], [])]))
        return result.success, result.message

    def follow_joint_trajectory(name: str, value: float) -> Tuple[bool, str]:
        status, result = ended(follow, goal_of([name], [(0.5, [value], [])]))
        return status == GoalStatus.STATUS_SUCCEEDED, result.error_string

    return {'set_position': service, 'commands/position': topic,
            'joint_command': joint_command, 'joint_trajectory': joint_trajectory,
            'follow_joint_trajectory': follow_joint_trajectory}


def cycles_pass(h: NodeHarness, count: int) -> None:
    """Wait for count more joint_states: a goal queued before now has been written by then."""
    seen = h.joint_states.received
    h.joint_states.wait(lambda _: h.joint_states.received >= seen + count, timeout_s=10.0)


def test_every_position_path_refuses_a_goal_beyond_the_range(h: NodeHarness) -> None:
    refused: List[str] = []
    for path, send in paths(h).items():
        for name, goals in BEYOND.items():
            for value in goals:
                accepted, message = send(name, value)
                assert not accepted, f'{path} took {value} for {name!r}'
                assert 'beyond' in message, (path, name, message)
                refused.append(f'{path} {name} {value:g}')
    cycles_pass(h, 5)
    for name, (low, high) in RANGES.items():
        assert low - 0.002 <= goal_rad(h, name) <= high + 0.002, name
    assert len(refused) == 5 * 3 * 2


def test_a_gripper_goal_beyond_the_travel_is_refused_on_its_own_paths(h: NodeHarness) -> None:
    assert h.node is not None
    for name in ('claw', 'pincer'):
        client = action(h, GripperCommand, f'{name}/gripper_cmd')
        parallel = action(h, ParallelGripperCommand, f'{name}/parallel_gripper_cmd')
        for value in BEYOND[name]:
            goal = GripperCommand.Goal()
            goal.command.position = value
            status, _ = ended(client, goal)
            assert status == GoalStatus.STATUS_ABORTED, (name, value)
            command = ParallelGripperCommand.Goal()
            command.command.name = [name]
            command.command.position = [value]
            status, _ = ended(parallel, command)
            assert status == GoalStatus.STATUS_ABORTED, (name, value)
            result = h.node.arm.gripper_command(gripper_topic(name, value))
            assert not result.success and 'beyond the travel' in result.message, result
    # A ratio outside 0..1 is refused too; one of exactly 1 is the closed end.
    bad = GripperTopic(name='pincer', position=math.nan, ratio=1.5, max_effort=0.0)
    assert not h.node.arm.gripper_command(bad).success
    cycles_pass(h, 5)
    for name in ('claw', 'pincer'):
        low, high = RANGES[name]
        assert low - 0.002 <= goal_rad(h, name) <= high + 0.002, name


def test_the_ends_of_the_travel_are_reached(h: NodeHarness) -> None:
    assert h.node is not None
    closed = GripperTopic(name='pincer', position=math.nan, ratio=1.0, max_effort=0.0)
    assert h.node.arm.gripper_command(closed).success
    h.wait_reg(IDS['pincer'], 'goal_position',
               lambda raw: abs(XM430.position_to_rad(raw) + 0.5) < 0.002)
    # The pincer's open end (1.0) is beyond its max_position (0.8): its ratio 0 is refused.
    opened = GripperTopic(name='pincer', position=math.nan, ratio=0.0, max_effort=0.0)
    result = h.node.arm.gripper_command(opened)
    assert not result.success and 'beyond its limits' in result.message, result
    goal = GripperCommand.Goal()
    goal.command.position = 1.0
    status, result = ended(action(h, GripperCommand, 'claw/gripper_cmd'), goal)
    assert status == GoalStatus.STATUS_SUCCEEDED and result.reached_goal


def test_the_range_is_shown_and_a_file_without_a_travel_is_refused(h: NodeHarness) -> None:
    assert h.node is not None
    # The limits in force, in joint units, for a gripper whose file gave none.
    assert h.node.get_parameter('claw.min_position').value == pytest.approx(0.0)
    assert h.node.get_parameter('claw.max_position').value == pytest.approx(1.0)
    params = sim_params({'claw': {'id': 1, 'operating_mode': 'current_based_position',
                                  'gripper': True}})
    with pytest.raises(ConfigError, match='claw.gripper_closed.*travel'):
        validate(params)
    params = sim_params({'claw': {**JOINTS['claw'], 'min_position': 1.5}})
    with pytest.raises(ConfigError, match="nothing of the gripper's travel"):
        validate(params)


WHEELS: Dict[str, Dict[str, Any]] = {
    # A wheel on a cable drum, say: velocity mode, yet it must not wind past its range.
    'drum': {'id': 1, 'operating_mode': 'velocity', 'min_position': -0.5, 'max_position': 1.0},
    # Reversed and in current mode: its goal's sign is the servo's, its range the joint's.
    'arm': {'id': 2, 'operating_mode': 'current', 'reverse': True, 'min_position': -0.8,
            'max_position': 0.6},
}


@pytest.fixture(scope='module')
def wheels() -> Iterator[NodeHarness]:
    with NodeHarness(sim_params(WHEELS, loop_rate=100.0)) as harness:
        harness.joint_states.wait(lambda m: len(m.name) == len(WHEELS))
        yield harness


def joint_position(h: NodeHarness, name: str) -> float:
    """Return where the joint is by its simulated servo's Present Position (joint frame)."""
    assert h.node is not None
    servo = h.node.manager.servos[name]
    return servo.position_rad(h.reg(WHEELS[name]['id'], 'present_position'))


@pytest.mark.parametrize('name, kind, value, end', [
    ('drum', 'velocity', 2.0, 1.0), ('drum', 'velocity', -2.0, -0.5),
    ('arm', 'current', -0.3, 0.6), ('arm', 'current', 0.3, -0.8)])
def test_a_joint_in_a_non_position_mode_stops_at_its_end(wheels: NodeHarness, name: str,
                                                         kind: str, value: float,
                                                         end: float) -> None:
    """
    Velocity, current and PWM goals have no position limit in the servo: the driver stops them.

    The goal toward the end goes to zero at the end (or two cycles before it at the present
    velocity); a new goal toward it is held at zero, one away from it is taken.
    """
    h = wheels
    servo_id = WHEELS[name]['id']
    register = f'goal_{kind}'
    assert h.call(f'set_{kind}', name=[name], value=[value]).success
    h.wait_reg(servo_id, register, lambda raw: raw != 0)
    # Stopped: the goal zeroed by the driver, the joint at rest near its end.
    h.wait_reg(servo_id, register, lambda raw: raw == 0, timeout_s=15.0)
    h.joint_states.wait(lambda m: abs(m.velocity[m.name.index(name)]) < 0.05, timeout_s=10.0)
    stopped = joint_position(h, name)
    print(f'{name} {kind} {value:g}: stopped at {stopped:.3f} for the end {end:g}')
    # What it moves in the cycles the stop takes to reach the wire and its deceleration: a
    # few hundredths in velocity mode, about 0.1 rad for the unloaded horn at 0.3 A (on a
    # loaded machine a late cycle adds to it); a joint never stopped would be turns away.
    assert abs(stopped - end) < 0.5, (stopped, end)
    # Toward the end again: held at zero; away from it: taken.
    assert h.call(f'set_{kind}', name=[name], value=[value]).success
    assert h.reg(servo_id, register) == 0
    assert h.call(f'set_{kind}', name=[name], value=[-value / 4]).success
    h.wait_reg(servo_id, register, lambda raw: raw != 0)
    # Back inside the range, then it holds.
    h.joint_states.wait(lambda m: abs(m.position[m.name.index(name)] - end) > 0.2,
                        timeout_s=10.0)
    assert h.call(f'set_{kind}', name=[name], value=[0.0]).success
