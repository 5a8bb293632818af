"""
Arms: trajectories executed in the driver's cycle, and ros2_control's joint-state commands.

Everything runs on the in-process simulator (`port: sim`); positions are checked against the
simulator's own registers and the published joint_states.
"""

import math
import time
from typing import Any, Callable, Dict, List, Sequence, Tuple

from builtin_interfaces.msg import Time
from conditions import wait_until
from dxl_servo_driver.models import model_for
from dxl_servo_driver.models.units import units_for
from dxl_servo_driver_msgs.msg import GripperCommand
from node_harness import at_once, NodeHarness, sim_params
import pytest
from sensor_msgs.msg import JointState
from trajectories import trajectory
from trajectory_msgs.msg import JointTrajectory

XM430_UNITS = units_for(model_for(1030))
JOINTS = {
    'shoulder': {'id': 1, 'operating_mode': 'position'},
    'elbow': {'id': 2, 'operating_mode': 'extended_position'},
    'wrist': {'id': 3, 'operating_mode': 'current_based_position'},
    'wheel': {'id': 4, 'operating_mode': 'velocity'},
    'hand': {'id': 5, 'operating_mode': 'current'},
    'claw': {'id': 6, 'operating_mode': 'current_based_position', 'gripper': True,
             'gripper_open': 0.0, 'gripper_closed': 1.5},
}
IDS = {name: keys['id'] for name, keys in JOINTS.items()}
ARM = ('shoulder', 'elbow', 'wrist')
# A trajectory stamped this far ahead starts at its stamp on the node's clock, not when the
# message happens to arrive: the test knows its time 0.
START_LEAD_S = 0.5
# How near its time the arm must pass each point. The servos' own lag is a few hundredths of a
# second; the rest is for a busy machine, which may hold back the cycle (and so the goals) or
# the sampler below for a while.
NEAR_TIME_S = 0.25


@pytest.fixture(scope='module')
def h() -> Any:
    with NodeHarness(sim_params(JOINTS, loop_rate=100.0)) as harness:
        harness.joint_states.wait(lambda m: len(m.name) == len(JOINTS))
        yield harness


def publisher(h: NodeHarness, kind: Any, topic: str) -> Any:
    assert h.client is not None
    pub = h.client.node.create_publisher(kind, f'{h.namespace}/dxl_servo_driver/{topic}', 10)
    deadline = time.monotonic() + 10.0
    while pub.get_subscription_count() < 1:
        assert time.monotonic() < deadline, f'the driver does not subscribe to {topic}'
        time.sleep(0.01)
    return pub


def position(h: NodeHarness, name: str) -> float:
    return XM430_UNITS.position_to_rad(h.reg(IDS[name], 'present_position'))


def arm_rad(h: NodeHarness) -> Tuple[float, List[float]]:
    """Return where the arm's joints are, at one moment, and that moment."""
    now_s, raws = at_once(h, [IDS[name] for name in ARM])
    return now_s, [XM430_UNITS.position_to_rad(raw) for raw in raws]


def stamped(msg: JointTrajectory, lead_s: float) -> Tuple[JointTrajectory, float]:
    """Stamp a trajectory lead_s from now; return it and its start on the monotonic clock."""
    start_s = time.monotonic() + lead_s
    wall_ns = time.time_ns() + int(lead_s * 1e9)
    msg.header.stamp = Time(sec=wall_ns // 10 ** 9, nanosec=wall_ns % 10 ** 9)
    return msg, start_s


def positions_now(h: NodeHarness) -> Dict[str, float]:
    msg = h.joint_states.wait(lambda m: len(m.name) == len(JOINTS))
    return dict(zip(msg.name, msg.position))


def test_a_trajectory_is_followed_point_by_point(h: NodeHarness) -> None:
    assert h.node is not None
    pub = publisher(h, JointTrajectory, 'joint_trajectory')
    start = positions_now(h)
    finished = h.node.arm.trajectories.finished
    # Three joints (three position modes), cubic segments (velocities given) then linear.
    plan = [(1.0, [0.4, 1.0, -0.3], [0.3, 0.5, 0.0]),
            (2.0, [0.6, 2.5, -0.1], [0.0, 1.0, 0.1]),
            (3.0, [0.2, 4.0, 0.2], [0.0, 0.0, 0.0])]
    msg, began = stamped(trajectory(ARM, plan), START_LEAD_S)
    pub.publish(msg)
    # Where the arm was, sampled all along (each sample at one moment, with its time): a read
    # at a point's time from a thread that woke up late compared a joint moving at up to
    # 2 rad/s with where it should have been earlier.
    samples: List[Tuple[float, List[float]]] = []
    while time.monotonic() < began + plan[-1][0] + NEAR_TIME_S:
        samples.append(arm_rad(h))
        time.sleep(0.005)
    errors: List[float] = []
    for t, goal, _ in plan:
        near = [max(abs(p - g) for p, g in zip(positions, goal))
                for at, positions in samples if abs(at - (began + t)) <= NEAR_TIME_S]
        assert near, f'no sample within {NEAR_TIME_S} s of the point at {t} s'
        errors.append(min(near))
    print(f'tracking error at the points: max {max(errors):.4f} rad, '
          f'mean {sum(errors) / len(errors):.4f} rad')
    # The servos follow the sampled path with their own lag: they pass each point, at its time,
    # within a few hundredths of a radian.
    assert max(errors) < 0.15, errors
    # The end: the trajectory is judged (within its goal tolerance after its settle time) and
    # the servos are there.
    wait_until(lambda: h.node is not None and h.node.arm.trajectories.finished > finished,
               15.0, 'the trajectory was not judged')
    final: List[float] = []

    def arrived() -> bool:
        final[:] = [abs(p - g) for p, g in zip(arm_rad(h)[1], plan[-1][1])]
        return max(final) < 0.05
    wait_until(arrived, 15.0, 'the arm did not get to the last point')
    print(f'final error {max(final):.4f} rad')
    # The path passed through the points, not straight to the end: the elbow went up by 4 rad
    # in three steps, the shoulder came back.
    assert start['elbow'] < 1.0
    status = bus_status(h, lambda values: int(values['trajectories_finished']) > finished)
    assert float(status['last_trajectory_final_error_rad']) < 0.05


def bus_status(h: NodeHarness,
               predicate: Callable[[Dict[str, str]], bool] = lambda values: True
               ) -> Dict[str, str]:
    def values(m: Any) -> Dict[str, str]:
        status = [s for s in m.status if ' bus ' in s.name]
        return {kv.key: kv.value for kv in status[0].values} if status else {}
    msg = h.diagnostics.wait(lambda m: bool(values(m)) and predicate(values(m)), timeout_s=5.0)
    return values(msg)


REFUSALS = {
    'velocity joint': (['shoulder', 'wheel'], [(1.0, [0.1, 0.1], [])], 'velocity mode'),
    'unknown joint': (['shoulder', 'nose'], [(1.0, [0.1, 0.1], [])], "unknown joint 'nose'"),
    'times going back': (['shoulder'], [(1.0, [0.1], []), (0.5, [0.2], [])], 'not after'),
    'NaN': (['shoulder'], [(1.0, [math.nan], [])], 'nan'),
    # Velocities are checked as positions are (not only as far as the positions go).
    'infinite velocity': (['shoulder'], [(1.0, [0.1], [math.inf])], 'has velocity inf'),
    'beyond limits': (['shoulder'], [(1.0, [3.5], [])], 'beyond its limits'),
    'ragged': (['shoulder', 'elbow'], [(1.0, [0.1], [])], '1 positions for 2 joints'),
}


@pytest.mark.parametrize('case', sorted(REFUSALS))
def test_a_bad_trajectory_is_refused_whole(h: NodeHarness, case: str) -> None:
    joints, plan, reason = REFUSALS[case]
    assert h.node is not None
    time.sleep(0.1)
    before = {name: h.reg(IDS[name], 'goal_position') for name in ARM}
    accepted = h.node.arm.trajectories.accepted
    reply = h.node.arm.submit_trajectory(trajectory(joints, plan))
    assert not reply.success and reason in reply.message, reply
    assert h.node.arm.trajectories.accepted == accepted
    time.sleep(0.1)
    assert {name: h.reg(IDS[name], 'goal_position') for name in ARM} == before


def test_a_new_trajectory_replaces_the_rest_of_the_running_one(h: NodeHarness) -> None:
    assert h.node is not None
    pub = publisher(h, JointTrajectory, 'joint_trajectory')
    here = position(h, 'elbow')
    finished = h.node.arm.trajectories.finished
    # 3 rad in 4 s: under way after 0.4 s, halfway only after 2 s (a busy machine has time to
    # send the second one while the first is in the middle).
    pub.publish(trajectory(['elbow'], [(4.0, [here + 3.0], [])]))
    wait_until(lambda: position(h, 'elbow') > here + 0.3,
               15.0, 'the first trajectory did not start')
    middle = position(h, 'elbow')
    assert here + 0.3 < middle < here + 1.5
    # The new one starts from where the first had taken the joint, not from its start.
    pub.publish(trajectory(['elbow'], [(0.5, [middle], [])]))
    # The first ends as preempted (not judged); the second is judged once at its end.
    wait_until(lambda: h.node is not None and h.node.arm.trajectories.finished > finished,
               15.0, 'the second trajectory was not judged')
    assert abs(position(h, 'elbow') - middle) < 0.2
    assert position(h, 'elbow') < here + 2.0   # the first one's end was never reached


def joint_state(names: Sequence[str], positions: Sequence[float] = (),
                velocities: Sequence[float] = (), efforts: Sequence[float] = ()) -> JointState:
    msg = JointState()
    msg.name = list(names)
    msg.position = [float(v) for v in positions]
    msg.velocity = [float(v) for v in velocities]
    msg.effort = [float(v) for v in efforts]
    return msg


def test_joint_command_applies_each_array_by_mode(h: NodeHarness) -> None:
    assert h.node is not None
    pub = publisher(h, JointState, 'joint_command')
    # What JointStateTopicSystem sends: every array index-aligned with name; a position-mode
    # joint ignores its velocity and effort, a velocity joint takes velocity, a current joint
    # takes effort / torque constant.
    names = ['shoulder', 'wheel', 'hand', 'wrist']
    pub.publish(joint_state(names, positions=[0.3, math.nan, math.nan, -0.2],
                            velocities=[0.0, 1.5, 0.0, 0.0],
                            efforts=[0.0, 0.0, 0.2, 0.4]))
    kt = 4.1 / 2.3
    h.wait_reg(IDS['shoulder'], 'goal_position', lambda v: v == XM430_UNITS.position_from_rad(0.3))
    h.wait_reg(IDS['wheel'], 'goal_velocity', lambda v: v == XM430_UNITS.velocity_from_rad_s(1.5))
    h.wait_reg(IDS['hand'], 'goal_current', lambda v: v == XM430_UNITS.current_from_a(0.2 / kt))
    h.wait_reg(IDS['wrist'], 'goal_current', lambda v: v == XM430_UNITS.current_from_a(0.4 / kt))
    h.wait_reg(IDS['wrist'], 'goal_position', lambda v: v == XM430_UNITS.position_from_rad(-0.2))
    # Empty arrays are not given at all.
    assert h.node.arm.joint_command(joint_state(['shoulder'], positions=[0.1])).success
    # Written before the next test looks at the goals (it must find nothing queued).
    h.wait_reg(IDS['shoulder'], 'goal_position',
               lambda v: v == XM430_UNITS.position_from_rad(0.1))


JOINT_COMMAND_REFUSALS = {
    'NaN used': (joint_state(['shoulder'], positions=[math.nan]), 'not a finite'),
    'wrong length': (joint_state(['shoulder', 'wheel'], positions=[0.1]), 'index-aligned'),
    'nothing its mode takes': (joint_state(['wheel'], positions=[0.1]), 'takes velocity'),
    'unknown': (joint_state(['nose'], positions=[0.1]), "unknown joint 'nose'"),
    'empty': (joint_state(['shoulder']), 'no position, velocity or effort'),
    'beyond range': (joint_state(['wheel'], velocities=[1e12]), 'out of any range'),
}


@pytest.mark.parametrize('case', sorted(JOINT_COMMAND_REFUSALS))
def test_a_bad_joint_command_is_refused_whole(h: NodeHarness, case: str) -> None:
    assert h.node is not None
    msg, reason = JOINT_COMMAND_REFUSALS[case]
    before = {sid: (h.reg(sid, 'goal_position'), h.reg(sid, 'goal_velocity'))
              for sid in IDS.values()}
    reply = h.node.arm.joint_command(msg)
    assert not reply.success and reason in reply.message, reply
    time.sleep(0.05)
    assert {sid: (h.reg(sid, 'goal_position'), h.reg(sid, 'goal_velocity'))
            for sid in IDS.values()} == before


def gripper(name: str, position: float = math.nan, ratio: float = math.nan,
            max_effort: float = math.nan) -> GripperCommand:
    return GripperCommand(name=name, position=position, ratio=ratio, max_effort=max_effort)


def claw_state(h: NodeHarness, predicate: Any, timeout_s: float = 10.0) -> Any:
    msg = h.servo_states.wait(lambda m: any(s.name == 'claw' and predicate(s) for s in m.servos),
                              timeout_s=timeout_s)
    return [s for s in msg.servos if s.name == 'claw'][0]


def test_a_gripper_closes_on_an_object_and_holds_it_without_overload(h: NodeHarness) -> None:
    pub = publisher(h, GripperCommand, 'gripper')
    sid = IDS['claw']
    h.sim.set_load(sid, 3.0)   # an object the claw cannot push through at 0.3 A
    pub.publish(gripper('claw', ratio=1.0, max_effort=0.3))
    held = claw_state(h, lambda s: s.grasping)
    assert held.position < 1.5 - 0.05 and held.hardware_error_status == 0
    # Held for 3 s with the limited current: never the overload latch.
    currents = []
    deadline = time.monotonic() + 3.0
    while time.monotonic() < deadline:
        assert h.reg(sid, 'hardware_error_status') == 0
        currents.append(abs(XM430_UNITS.current_to_a(h.reg(sid, 'present_current'))))
        time.sleep(0.05)
    print(f'holding: present current {min(currents):.3f}..{max(currents):.3f} A at a 0.3 A '
          'limit, no hardware error')
    assert max(currents) <= 0.3 * 1.1
    assert h.reg(sid, 'goal_current') == XM430_UNITS.current_from_a(0.3)
    assert claw_state(h, lambda s: True).grasping
    status = h.diagnostics.wait(lambda m: any(s.name.endswith(': claw') for s in m.status))
    values = {kv.key: kv.value for kv in
              [s for s in status.status if s.name.endswith(': claw')][0].values}
    assert values['grasping'] == 'True'
    # Let go: open (ratio 0) with the object gone, the grasp ends and the claw goes home.
    h.sim.set_load(sid, 0.0)
    pub.publish(gripper('claw', ratio=0.0))
    claw_state(h, lambda s: not s.grasping and abs(s.position) < 0.05)


GRIPPER_REFUSALS = {
    'not a gripper': (gripper('wrist', ratio=0.5), 'not a gripper'),
    'both goals': (gripper('claw', position=0.2, ratio=0.5), 'the other NaN'),
    'no goal': (gripper('claw'), 'the other NaN'),
    'ratio out of range': (gripper('claw', ratio=1.5), 'outside 0 (open) .. 1 (closed)'),
    'too much current': (gripper('claw', ratio=0.5, max_effort=50.0), 'above the current limit'),
    'unknown': (gripper('nose', ratio=0.5), "unknown joint 'nose'"),
}


@pytest.mark.parametrize('case', sorted(GRIPPER_REFUSALS))
def test_a_bad_gripper_command_is_refused(h: NodeHarness, case: str) -> None:
    assert h.node is not None
    msg, reason = GRIPPER_REFUSALS[case]
    time.sleep(0.1)
    before = (h.reg(IDS['claw'], 'goal_position'), h.reg(IDS['claw'], 'goal_current'))
    reply = h.node.arm.gripper_command(msg)
    assert not reply.success and reason in reply.message, reply
    time.sleep(0.05)
    assert (h.reg(IDS['claw'], 'goal_position'), h.reg(IDS['claw'], 'goal_current')) == before
