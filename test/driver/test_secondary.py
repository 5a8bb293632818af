"""
Two servos on one joint (`<joint>.secondary_id`): one joint to ROS, two servos on the bus.

The lift is driven from both sides, its second servo mounted mirrored (secondary_reverse): every
goal must reach the second servo through its own frame, the other way round. A sign applied the
wrong way would have the two fight through the shaft; here the simulated servos are independent,
so the tests read where each one was sent and where each one is, and fail on a sign error.
"""

import time
from typing import Any, Iterator

from diagnostic_msgs.msg import DiagnosticStatus
from dxl_servo_driver.models import model_for
from dxl_servo_driver.models.units import units_for
from node_harness import at_once, NodeHarness, sim_params
import pytest
from trajectories import trajectory

XM430 = units_for(model_for(1030))
JOINTS = {
    'lift': {'id': 1, 'operating_mode': 'position', 'secondary_id': 2,
             'secondary_reverse': True, 'secondary_tolerance': 0.1},
    'elbow': {'id': 3, 'operating_mode': 'position'},
}
FIRST, SECOND = 1, 2


@pytest.fixture(scope='module')
def h() -> Iterator[NodeHarness]:
    with NodeHarness(sim_params(JOINTS)) as harness:
        harness.joint_states.wait(lambda m: len(m.name) == 2)
        yield harness


def rad(h: NodeHarness, servo_id: int, register: str = 'present_position') -> float:
    return XM430.position_to_rad(h.reg(servo_id, register))


def pair_gap(h: NodeHarness) -> float:
    """Return how far the mirrored pair is apart (they sum to 0), both read at one moment."""
    _, raws = at_once(h, (FIRST, SECOND))
    return abs(sum(XM430.position_to_rad(raw) for raw in raws))


def test_the_joint_is_one_entry_of_joint_states(h: NodeHarness) -> None:
    msg = h.joint_states.wait(lambda m: len(m.name) == 2)
    assert list(msg.name) == ['lift', 'elbow']


def test_every_goal_reaches_the_mirrored_second_servo(h: NodeHarness) -> None:
    h.publish('position', ['lift'], [0.8])
    h.wait_reg(FIRST, 'goal_position', lambda raw: abs(XM430.position_to_rad(raw) - 0.8) < 0.003)
    # The mirrored servo is sent to -0.8 rad: a sign error would send it to +0.8 and the two
    # would twist the shaft between them.
    assert rad(h, SECOND, 'goal_position') == pytest.approx(-0.8, abs=0.003)
    # Each gets there (the first is not necessarily there when the second is).
    h.wait_reg(SECOND, 'present_position',
               lambda raw: abs(XM430.position_to_rad(raw) + 0.8) < 0.02)
    h.wait_reg(FIRST, 'present_position',
               lambda raw: abs(XM430.position_to_rad(raw) - 0.8) < 0.02)
    h.joint_states.wait(lambda m: abs(m.position[0] - 0.8) < 0.02)


def test_a_trajectory_moves_both_servos_together(h: NodeHarness) -> None:
    assert h.node is not None
    assert h.node.arm.submit_trajectory(trajectory(['lift'], [(1.0, [-0.4], [])])).success
    gaps = []
    deadline = time.monotonic() + 1.5
    while time.monotonic() < deadline:
        gaps.append(pair_gap(h))
        time.sleep(0.02)
    print(f'the two servos apart on the way: at most {max(gaps):.4f} rad')
    assert max(gaps) < 0.05
    # The end (1 s, then the servos settle: a busy machine may delay both).
    h.wait_reg(FIRST, 'present_position',
               lambda raw: abs(XM430.position_to_rad(raw) + 0.4) < 0.03)
    assert pair_gap(h) < 0.05


def test_torque_and_mode_go_to_both(h: NodeHarness) -> None:
    assert h.call('set_torque', name=['lift'], enable=False).success
    assert h.reg(FIRST, 'torque_enable') == 0 and h.reg(SECOND, 'torque_enable') == 0
    assert h.reg(3, 'torque_enable') == 1   # the elbow is another joint
    assert h.call('set_torque', name=['lift'], enable=True).success
    assert h.reg(FIRST, 'torque_enable') == 1 and h.reg(SECOND, 'torque_enable') == 1
    assert h.call('set_operating_mode', name=['lift'], mode='extended_position').success
    assert h.reg(FIRST, 'operating_mode') == 4 and h.reg(SECOND, 'operating_mode') == 4
    assert h.call('set_operating_mode', name=['lift'], mode='position').success
    assert h.reg(FIRST, 'operating_mode') == 3 and h.reg(SECOND, 'operating_mode') == 3


def test_the_second_servo_is_not_commanded_on_its_own(h: NodeHarness) -> None:
    response = h.call('set_position', name=['lift (secondary)'], value=[0.1])
    assert not response.success
    assert "'lift (secondary)' is the second servo of joint 'lift'" in response.message
    # Its registers stay readable by its own name.
    response = h.call('read_register', name='lift (secondary)', register_name='id')
    assert response.success and response.value == SECOND


def lift_status(h: NodeHarness, predicate: Any) -> Any:
    msg = h.diagnostics.wait(lambda m: any(s.name.endswith(': lift') and predicate(s)
                                           for s in m.status), timeout_s=5.0)
    return [s for s in msg.status if s.name.endswith(': lift')][0]


def test_servos_that_fight_are_both_switched_off(h: NodeHarness) -> None:
    assert h.node is not None
    lift_status(h, lambda s: s.level == DiagnosticStatus.OK)
    here = rad(h, FIRST)
    h.sim.set_load(SECOND, 6.0)   # the second side held: beyond the XM430's stall torque
    try:
        h.publish('position', ['lift'], [here + 0.6])
        # Both switched off (one write each, the second a transaction after the first).
        h.wait_reg(FIRST, 'torque_enable', lambda value: value == 0, timeout_s=3.0)
        h.wait_reg(SECOND, 'torque_enable', lambda value: value == 0, timeout_s=1.0)
        # Stopped by 0.2 (twice the tolerance) plus what one cycle moves, not at the goal.
        assert pair_gap(h) < 0.35
        status = lift_status(h, lambda s: s.level == DiagnosticStatus.ERROR)
        assert 'disagreed by' in status.message and 'both torque off' in status.message
        assert 'disagreed' in h.node.manager.joint_trouble('lift')
    finally:
        h.sim.set_load(SECOND, 0.0)
    # The brake gone, enabled again: the second servo goes to where the first is, and once they
    # agree (and after the settling second) the pair is sound.
    gap = pair_gap(h)
    assert h.call('set_torque', name=['lift'], enable=True).success
    deadline = time.monotonic() + 10.0
    while pair_gap(h) > 0.02:
        assert time.monotonic() < deadline, f'still {gap:.3f} rad apart'
        time.sleep(0.01)
    time.sleep(1.2)   # past the settling time ...
    for _ in range(3):   # ... and cycles after it: judged again, and agreeing
        h.joint_states.wait()
    assert h.node.manager.joint_trouble('lift') == ''
    assert h.reg(FIRST, 'torque_enable') == 1 and h.reg(SECOND, 'torque_enable') == 1


def test_every_stop_switches_both_off() -> None:
    harness = NodeHarness(sim_params(JOINTS))
    with harness as h:
        h.joint_states.wait(lambda m: len(m.name) == 2)
        sim = h.sim
        assert sim.read_register(FIRST, 'torque_enable') == 1
        assert sim.read_register(SECOND, 'torque_enable') == 1
    # Shut down (torque_off_on_shutdown): the second servo too.
    assert sim.read_register(FIRST, 'torque_enable') == 0
    assert sim.read_register(SECOND, 'torque_enable') == 0
