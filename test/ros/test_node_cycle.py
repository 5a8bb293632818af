"""The node's cycle drivers: its own thread (flat out, pipelined) and a ROS timer."""

import math
import time
from typing import Any, List

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


@pytest.mark.parametrize('driver', ['thread', 'timer'])
def test_a_cycle_that_waits_for_the_bus_stamps_its_read_after_the_wait(driver: str) -> None:
    # A service's transaction holds the bus (the manager's lock) for as long as its deadlines
    # allow; a cycle due meanwhile waits for it. Its samples are taken when its request goes
    # out, after the wait: a stamp taken before it dated them up to the whole wait too early.
    def stamp_s(msg: Any) -> float:
        return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9

    with NodeHarness(sim_params(JOINTS, cycle_driver=driver, loop_rate=100.0)) as h:
        assert h.node is not None
        h.joint_states.wait(lambda m: len(m.name) == 2)
        for _ in range(2):   # a hold begun between a cycle's read and its write shows nothing
            with h.node.manager.lock:
                held_from = time.time()
                time.sleep(0.3)
                held_to = time.time()
            during: List[float] = []

            def look(msg: Any) -> bool:
                if held_from < stamp_s(msg) < held_to:
                    during.append(stamp_s(msg))
                return stamp_s(msg) > held_to + 0.05

            # Every message kept, not only those after this call: the one of the cycle that
            # waited is published as soon as the lock is let go.
            h.joint_states.wait(look, fresh=False)
            assert during == [], f'stamped {held_to - during[0]:.3f} s before its read went out'
