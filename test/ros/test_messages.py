"""
joint_states as CDR bytes laid out by the node, read back by the middleware's own parser.

The node publishes ready bytes instead of a JointState object (the Python-to-C conversion is
most of a publish); these tests hold the bytes to what rclpy's deserialisation makes of them,
for any set of names, and the node to its fallback when they would not match.
"""

import math
from types import SimpleNamespace
from typing import Any, List

from dxl_servo_driver.models import model_for
from dxl_servo_driver.models.units import units_for
from dxl_servo_driver.ros.messages import JointTable, time_msg
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState

UNITS = units_for(model_for(1020))


def _servo(name: str, position: int, velocity: int, effort: int, fresh: bool = True) -> Any:
    return SimpleNamespace(name=name, units=UNITS, state=(position, velocity, effort),
                           fresh=fresh, turn_offset=4096)


@pytest.mark.parametrize('names', [
    ['a'], ['j1', 'j2', 'j3'], ['shoulder_pan', 'x', 'ab', 'abc', 'abcd', 'abcde'],
    [f'joint_{k}' for k in range(50)], ['größe', '关节', 'ok'],
])
def test_the_bytes_are_the_message_they_mean(names: List[str]) -> None:
    servos = [_servo(name, 100 * k - 1000, 7 * k - 20, -3 * k) for k, name in enumerate(names)]
    table = JointTable(servos)  # type: ignore[arg-type]
    assert table.check_wire() == '' and table.serialize
    stamp_ns = 1_700_000_123 * 1_000_000_000 + 987_654_321
    data = table.message(stamp_ns)
    assert isinstance(data, bytes)
    msg = deserialize_message(data, JointState)
    expected = table.fill(time_msg(stamp_ns))
    assert list(msg.name) == names == list(expected.name)
    assert list(msg.position) == list(expected.position)
    assert list(msg.velocity) == list(expected.velocity)
    assert list(msg.effort) == list(expected.effort)
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1_700_000_123, 987_654_321)
    # The same size as the middleware's own serialisation of that message.
    assert len(data) == len(serialize_message(expected))
    # Values are in SI from the raw sample (turns kept): one checked by hand.
    assert math.isclose(msg.position[0], (-1000 + 4096 - UNITS.zero_raw) * UNITS.rad_per_pulse)


def test_only_fresh_joints_are_in_the_bytes_and_a_new_set_gets_its_layout() -> None:
    servos = [_servo('a', 1, 2, 3), _servo('b', 4, 5, 6, fresh=False), _servo('c', 7, 8, 9)]
    table = JointTable(servos)  # type: ignore[arg-type]
    table.check_wire()
    msg = deserialize_message(table.message(5), JointState)
    assert list(msg.name) == ['a', 'c']
    servos[1].fresh = True
    msg = deserialize_message(table.message(6), JointState)
    assert list(msg.name) == ['a', 'b', 'c'] and msg.header.stamp.nanosec == 6
    for servo in servos:
        servo.fresh = False
    assert table.message(7) is None   # nobody answered: nothing is published


def test_without_a_checked_layout_the_message_object_goes_out() -> None:
    table = JointTable([_servo('a', 1, 2, 3)])  # type: ignore[arg-type]
    msg = table.message(3_000_000_001)   # not checked: never bytes the middleware may misread
    assert isinstance(msg, JointState)
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (3, 1)
    table.serialize = False   # what a failed check leaves
    assert isinstance(table.message(1), JointState)
