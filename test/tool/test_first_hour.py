"""
A new user's first hour, replayed on `virtual_bus` over a pty as they would live it.

Six factory-new servos (each id 1 at 57,600 bps, Return Delay Time 250) are plugged in one by
one while `dxl setup` asks for them; `dxl scan` then finds the six at the bus's new baud rate;
`dxl calibrate` takes the arm's zero pose, directions and ranges while the simulator's hand turns
the horns; and the node, run on the file calibration wrote, publishes 0 rad at the zero pose.
Every command is the installed executable on a terminal (pexpect), answered as a user would.
"""

import pathlib
from typing import Dict, List, Tuple

from dxl_cli import finish, near, spawn, TOLERANCE, turn_horn
from node_harness import Client
from processes import NodeProcess, START_TIMEOUT_S, StartVirtualBus, VirtualBusProcess
import pytest

# The joints in the order they are plugged in: (name, id, model, zero pose in servo radians,
# whether the servo counts down as the joint turns its positive way).
ARM: Tuple[Tuple[str, int, str, float, bool], ...] = (
    ('shoulder_pan', 1, 'XM540-W270', 0.4, False),
    ('shoulder_lift', 2, 'XM540-W270', -0.6, True),
    ('elbow', 3, 'XM430-W350', 1.1, False),
    ('wrist_pitch', 4, 'XM430-W350', -0.3, False),
    ('wrist_roll', 5, 'XL430-W250', 0.2, True),
    ('gripper', 6, 'XL330-M288', 0.5, False),
)
PARAMS = """\
# My arm: six servos, set up and calibrated with dxl.
/**:
  ros__parameters:
    port: {port}
    baud_rate: 1000000
    loop_rate: 50.0
    joints: [shoulder_pan, shoulder_lift, elbow, wrist_pitch, wrist_roll, gripper]
""" + ''.join(f"""    {name}:
      id: {servo_id}
      model: {model}
      operating_mode: {'current_based_position' if name == 'gripper' else 'position'}
""" for name, servo_id, model, _, _ in ARM) + """      gripper: true
      gripper_open: 0.0
      gripper_closed: 1.0
"""
# How far each joint is moved through its range, from its zero (joint radians).
RANGE = (-0.8, 0.9)


def turn(bus: VirtualBusProcess, slot: int, rad: float, seconds: float = 0.3) -> None:
    """Turn the horn of the slot-th servo by hand; return once it reads there."""
    turn_horn(bus, f'#{slot}', ARM[slot - 1][2], rad, seconds)


@pytest.mark.process
def test_a_box_of_new_servos_becomes_a_calibrated_arm_that_publishes_zero_at_zero(
        virtual_bus: StartVirtualBus, client: Client, domain_id: int,
        tmp_path: pathlib.Path) -> None:
    link = tmp_path / 'ttyDXL'
    bus = virtual_bus([1] * len(ARM), 57600, link, unplugged=True, extra_args=[
        '--return-delay-time', '250', '--models', *[model for _, _, model, _, _ in ARM]])
    params = tmp_path / 'arm.yaml'
    params.write_text(PARAMS.format(port=link))

    # 1. Set up: each servo plugged in alone when asked (those set up before stay plugged).
    child = spawn('setup', '--port', str(link), '--params', str(params))
    try:
        for slot, (name, servo_id, model, _, _) in enumerate(ARM, start=1):
            child.expect(rf'\[{slot}/{len(ARM)}\] Connect .*{name}.*powered: ')
            assert bus.control(f'plug #{slot}').startswith('ok')
            child.sendline('')
            child.expect(rf'\[{slot}/{len(ARM)}\] .*{name}.*: id {servo_id}, 1000000 bps, '
                         'Return Delay Time 0: checked')
        child.expect('done: 6 servo')
        status, _ = finish(child)
    finally:
        child.close(force=True)
    assert status == 0
    for slot, (_, servo_id, _, _, _) in enumerate(ARM, start=1):
        assert bus.get(f'#{slot}', 'id') == servo_id
        assert bus.get(f'#{slot}', 'return_delay_time') == 0

    # 2. Scan: the six at 1 Mbps, nobody left at the factory rate.
    child = spawn('scan', '--port', str(link), '--stop-at-first')
    try:
        status, output = finish(child)
    finally:
        child.close(force=True)
    assert status == 0, output
    found = [line for line in output.splitlines() if 'baud 1000000' in line or
             '1000000 bps' in line]
    for _, servo_id, model, _, _ in ARM:
        assert any(f'id {servo_id}' in line and model in line for line in found), output

    # 3. Calibrate: the hand puts the arm in its zero pose, moves each joint its positive way,
    # then through its range.
    for slot, (_, _, _, zero, _) in enumerate(ARM, start=1):
        turn(bus, slot, zero, 0.0)
    child = spawn('calibrate', '--params', str(params))
    try:
        child.expect('zero pose.*press Enter: ')
        child.sendline('')
        for name, _, _, zero, _ in ARM:
            child.expect(rf'{name}: offset ([-+]\d+\.\d+) rad')
            assert abs(float(child.match.group(1)) - zero) < TOLERANCE
        signs: Dict[str, float] = {}
        for slot, (name, _, _, zero, counts_down) in enumerate(ARM, start=1):
            signs[name] = -1.0 if counts_down else 1.0
            child.expect(rf'Move {name} in its positive direction.*Enter: ')
            turn(bus, slot, zero + 0.4 * signs[name])
            child.sendline('')
            child.expect(rf'{name}: servo id \d+ counted .*reverse '
                         f'{"true" if counts_down else "false"}')
        child.expect('whole range')
        for slot, (name, _, _, zero, _) in enumerate(ARM, start=1):
            for joint_rad in RANGE:
                turn(bus, slot, zero + joint_rad * signs[name])
                child.expect(rf'{name} {near(joint_rad)} \[')
        child.sendline('')
        child.expect('Open the gripper fully and press Enter')
        turn(bus, len(ARM), ARM[-1][3] + RANGE[0])
        child.sendline('')
        child.expect(r'Write these changes to .*\? \[y/N\] ')
        child.sendline('y')
        child.expect('wrote')
        status, _ = finish(child)
    finally:
        child.close(force=True)
    assert status == 0
    text = params.read_text()
    assert text.startswith('# My arm: six servos'), text

    # 4. The node on that file, the arm back at its zero pose: 0 rad on every joint.
    for slot, (_, _, _, zero, _) in enumerate(ARM, start=1):
        turn(bus, slot, zero, 0.0)
    names: List[str] = [name for name, _, _, _, _ in ARM]
    node = NodeProcess(tmp_path, text, domain_id=domain_id)
    try:
        message = node.wait_message(client.joint_states, lambda m: list(m.name) == names,
                                    START_TIMEOUT_S)
        assert all(abs(position) < 0.01 for position in message.position), message.position
    finally:
        node.stop()
