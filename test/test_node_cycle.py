"""The node's cycle drivers: its own thread (flat out, pipelined) and a ROS timer."""

import math

from node_harness import NodeHarness, sim_params
import pytest

JOINTS = {'arm': {'id': 1, 'operating_mode': 'position'},
          'wheel': {'id': 2, 'operating_mode': 'velocity'}}
PULSE_RAD = 2.0 * math.pi / 4096.0


def raw(rad: float) -> int:
    return int(round(rad / PULSE_RAD)) + 2048


@pytest.mark.parametrize('top', [
    {'cycle_driver': 'timer', 'loop_rate': 100.0},
    # Far above what the bus carries: the thread runs flat out with the next read on the wire
    # while the last cycle is published.
    {'cycle_driver': 'thread', 'loop_rate': 10000.0},
])
def test_the_cycle_reads_publishes_and_writes(top: dict) -> None:
    with NodeHarness(sim_params(JOINTS, **top)) as h:
        first = h.joint_states.wait(lambda m: list(m.name) == ['arm', 'wheel'])
        assert abs(first.position[0] - (h.reg(1, 'present_position') - 2048) * PULSE_RAD) < 0.05
        h.publish('position', ['arm'], [0.4])
        h.publish('velocity', ['wheel'], [1.0])
        h.wait_reg(1, 'goal_position', lambda v: v == raw(0.4), 5.0)
        h.wait_reg(2, 'goal_velocity', lambda v: v != 0, 5.0)
        h.joint_states.wait(lambda m: abs(m.position[0] - 0.4) < 0.03, timeout_s=10.0)
        # Services are answered while the cycle runs (flat out too).
        response = h.call('read_register', name='arm', register_name='present_temperature')
        assert response.success and 0 < response.value < 100
        response = h.call('set_torque', name=['wheel'], enable=False)
        assert response.success
        h.wait_reg(2, 'torque_enable', lambda v: v == 0, 5.0)
        # Runtime loop_rate change applies to both drivers.
        assert h.set_parameter('loop_rate', 50.0).successful
        h.joint_states.wait(lambda m: len(m.name) == 2)
