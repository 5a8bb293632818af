"""
Both protocols on one bus, as a user runs them: `virtual_bus` and the installed node.

The issue's interface, exactly: `virtual_bus --ids 1 2 3 4 --models 12 30 350 1020` puts an
AX-12A (Protocol 1.0), an MX-28(2.0), an XL-320 and an XM430-W350 on one pty at the default
57,600 bps; the node, configured from a YAML file whose AX-12A joint says `protocol: 1.0`,
finds each, drives each in SI and publishes them together, and leaves every torque off when it
stops.
"""

import pathlib
import time
from typing import Any, Dict, Optional

from dxl_servo_driver.models import model_for
from dxl_servo_driver.models.units import units_for
from node_harness import Client
from processes import NodeProcess, params_yaml, START_TIMEOUT_S, VirtualBusProcess

JOINTS: Dict[str, Dict[str, Any]] = {
    'ax': {'id': 1, 'protocol': 1.0, 'operating_mode': 'position'},
    'mx': {'id': 2, 'operating_mode': 'velocity'},
    'xl': {'id': 3, 'operating_mode': 'position'},
    'xm': {'id': 4, 'operating_mode': 'current'},
}
MODELS = {'ax': 12, 'mx': 30, 'xl': 350, 'xm': 1020}


def test_one_bus_of_both_protocols_from_a_file(workdir: pathlib.Path, client: Client,
                                               domain_id: int) -> None:
    link = str(workdir / 'ttyDXL')
    bus = VirtualBusProcess(extra_args=['--ids', '1', '2', '3', '4', '--models', '12', '30',
                                        '350', '1020', '--link', link])
    node: Optional[NodeProcess] = None
    try:
        node = NodeProcess(workdir, params_yaml(link, JOINTS, baud_rate=57600, loop_rate=20.0),
                           domain_id=domain_id)
        node.wait_message(client.joint_states, lambda m: len(m.name) == 4, START_TIMEOUT_S)
        output = node.output()
        for text in ('AX-12A (model 12)', 'MX-28(2.0) (model 30)', 'XL-320 (model 350)',
                     'XM430-W350 (model 1020)'):
            assert text in output, output
        client.publish('position', ['ax', 'xl'], [0.3, -0.2])
        client.publish('velocity', ['mx'], [1.0])
        client.publish('current', ['xm'], [0.1])
        msg = node.wait_message(
            client.joint_states,
            lambda m: abs(m.position[0] - 0.3) < 0.05 and abs(m.position[2] + 0.2) < 0.05
            and abs(m.velocity[1] - 1.0) < 0.15, 20.0)
        assert msg.name == list(JOINTS)
        # Each goal went out in its servo's own protocol and unit.
        units = {name: units_for(model_for(number)) for name, number in MODELS.items()}
        assert bus.get(1, 'goal_position') == units['ax'].position_from_rad(0.3)
        assert bus.get(3, 'goal_position') == units['xl'].position_from_rad(-0.2)
        assert bus.get(2, 'goal_velocity') == units['mx'].velocity_from_rad_s(1.0)
        assert bus.get(4, 'goal_current') == units['xm'].current_from_a(0.1)
        # The AX-12A's Moving Speed carries no goal in joint mode; its angle limits say joint.
        assert (bus.get(1, 'cw_angle_limit'), bus.get(1, 'ccw_angle_limit')) == (0, 1023)
        # The published position is the servo's, in its unit. The joint may still be coming to
        # rest: a sample read after one get (stamped later) and published before the next lies
        # between the two.
        before = bus.get(1, 'present_position')
        asked_s = time.time()
        later = node.wait_message(
            client.joint_states,
            lambda m: m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 > asked_s, 10.0)
        after = bus.get(1, 'present_position')
        low, high = sorted(units['ax'].position_to_rad(raw) for raw in (before, after))
        assert low - 0.02 <= later.position[0] <= high + 0.02
        assert node.stop() == 0, node.output()
        for servo_id in (1, 2, 3, 4):
            bus.wait_get(servo_id, 'torque_enable', 0)
    finally:
        if node is not None:
            node.stop()
        bus.stop()
