"""
README.md's path, followed as a newcomer follows it, on `virtual_bus` over ptys.

"From an unboxed servo to a moving joint": its command lines are read from README.md and run
as written (the installed `dxl` and `node`; only the device, /dev/ttyDXL, is the test's pty, and
the adapter and udev lines, which are about a USB adapter, are left out): three factory-new
servos plugged in one by one while `dxl setup` asks, `dxl scan` writing my_arm.yaml, `dxl
calibrate` on that file with the horns turned by hand through the virtual_bus console, and the
node on the calibrated file publishing 0 rad at the zero pose and the range found.

docs/teleoperation.md's pair "Without `ros2 launch`": its two `virtual_bus` lines and two
`node` lines run as written (the two ptys moved into the test's folder); a hand turns the
leader's horn on its console and the follower's servo goes there.
"""

import math
import pathlib
import re
import shlex
from typing import Dict, List, Tuple

from conditions import wait_until
from dxl_cli import finish, near, spawn, TOLERANCE, turn_horn
from dxl_servo_driver.models import model_named
from dxl_servo_driver.tool import calibrate, yaml_edit
from node_harness import Client, Collector
from processes import (
    NodeProcess, ROOT, START_TIMEOUT_S, StartVirtualBus, VirtualBusProcess)
import pytest
from sensor_msgs.msg import JointState

README = (ROOT / 'README.md').read_text()
TELEOP = (ROOT / 'docs' / 'teleoperation.md').read_text()
BIN = '$bin/'
# The servos in the order they are plugged in: model, zero pose (servo rad), whether the
# servo counts down as its joint turns the positive way.
SERVOS: Tuple[Tuple[str, float, bool], ...] = (
    ('XM540-W270', 0.4, False),
    ('XM430-W350', -0.7, True),
    ('XL430-W250', 1.1, False),
)
RANGE = (-0.8, 0.9)   # joint rad, each joint moved through it from its zero
MARGIN = calibrate.DEFAULT_MARGIN   # what calibrate widens the range seen by


def section_lines(page: str, heading: str) -> List[List[str]]:
    """Return the `$bin/...` lines of the first code block under a heading, as words."""
    assert heading in page, f'no {heading!r} section'
    at = page.index(heading)
    block = page[at:].split('```')[1]
    return [shlex.split(line, comments=True) for line in block.splitlines()
            if line.startswith(BIN)]


def readme_commands() -> Dict[str, List[str]]:
    """Return the README's unboxed-servo lines by what they run (`dxl setup`, `node`, ...)."""
    commands: Dict[str, List[str]] = {}
    for words in section_lines(README, '## From an unboxed servo'):
        program = words[0][len(BIN):]
        key = f'{program} {words[1]}' if program == 'dxl' else program
        assert key not in commands, f'README.md runs {key} twice'
        commands[key] = words
    return commands


def on(words: List[str], device: pathlib.Path) -> List[str]:
    """Return a README dxl line's arguments with the adapter's device as the test's pty."""
    assert words[0] == f'{BIN}dxl', words
    assert '/dev/ttyDXL' in words, words
    return [str(device) if word == '/dev/ttyDXL' else word for word in words[1:]]


@pytest.mark.process
def test_the_readme_takes_unboxed_servos_to_a_calibrated_arm_the_node_runs(
        virtual_bus: StartVirtualBus, client: Client, domain_id: int,
        tmp_path: pathlib.Path) -> None:
    commands = readme_commands()
    assert list(commands) == ['dxl adapters', 'dxl setup', 'dxl scan', 'dxl calibrate', 'node']
    link = tmp_path / 'ttyDXL'
    bus = virtual_bus([1] * len(SERVOS), 57600, link, unplugged=True, extra_args=[
        '--return-delay-time', '250', '--models', *[model for model, _, _ in SERVOS]])
    # The file the README's lines name is made by them, in the folder they run in.
    args = on(commands['dxl setup'], link)
    # Run in an empty folder: a file the lines read must be one an earlier line writes.
    if '--params' in args:
        name = args[args.index('--params') + 1]
        assert (tmp_path / name).exists(), (
            f"README.md's `dxl setup` reads {name}, which no line before it writes")
    ids = [int(word) for word in args[args.index('--ids') + 1:] if word.isdigit()]
    assert len(ids) == len(SERVOS), args

    # 1. dxl setup: each servo plugged in alone when asked.
    child = spawn(*args, cwd=str(tmp_path))
    try:
        for slot, servo_id in enumerate(ids, start=1):
            child.expect(rf'\[{slot}/{len(ids)}\] Connect .*powered: ')
            assert bus.control(f'plug #{slot}').startswith('ok')
            child.sendline('')
            child.expect(rf'\[{slot}/{len(ids)}\] .*: id {servo_id}, (\d+) bps, '
                         'Return Delay Time 0: checked')
        status, output = finish(child)
    finally:
        child.close(force=True)
    assert status == 0, output

    # 2. dxl scan writes the file, in the folder the README's lines run in.
    child = spawn(*on(commands['dxl scan'], link), cwd=str(tmp_path))
    try:
        status, output = finish(child)
    finally:
        child.close(force=True)
    assert status == 0, output
    params = tmp_path / 'my_arm.yaml'
    assert params.exists(), output
    joints = [f'joint_{servo_id}' for servo_id in ids]
    assert f'joints: [{", ".join(joints)}]' in params.read_text(), params.read_text()

    # 3. dxl calibrate: the zero pose, each joint its positive way, then its range.
    for slot, (model, zero, _) in enumerate(SERVOS, start=1):
        turn_horn(bus, f'#{slot}', model, zero, 0.0)
    child = spawn(*on(commands['dxl calibrate'], link), cwd=str(tmp_path))
    try:
        child.expect('zero pose.*press Enter: ')
        child.sendline('')
        for name, (_, zero, _) in zip(joints, SERVOS):
            child.expect(rf'{name}: offset ([-+]\d+\.\d+) rad')
            assert abs(float(child.match.group(1)) - zero) < TOLERANCE
        for slot, (name, (model, zero, down)) in enumerate(zip(joints, SERVOS), start=1):
            child.expect(rf'Move {name} in its positive direction.*Enter: ')
            turn_horn(bus, f'#{slot}', model, zero + (-0.4 if down else 0.4))
            child.sendline('')
            child.expect(rf'{name}: servo id \d+ counted .*reverse {"true" if down else "false"}')
        child.expect('whole range')
        for slot, (name, (model, zero, down)) in enumerate(zip(joints, SERVOS), start=1):
            for joint_rad in RANGE:
                turn_horn(bus, f'#{slot}', model, zero + (-joint_rad if down else joint_rad))
                child.expect(rf'{name} {near(joint_rad)} \[')
        child.sendline('')
        child.expect(r'Write these changes to .*\? \[y/N\] ')
        child.sendline('y')
        child.expect('wrote')
        status, output = finish(child)
    finally:
        child.close(force=True)
    assert status == 0, output
    written = yaml_edit.parameters_of(params.read_text())
    for name, (_, zero, down) in zip(joints, SERVOS):
        assert abs(written[f'{name}.offset'] - zero) < TOLERANCE
        assert written[f'{name}.reverse'] is down
        assert abs(written[f'{name}.min_position'] - (RANGE[0] - MARGIN)) < TOLERANCE
        assert abs(written[f'{name}.max_position'] - (RANGE[1] + MARGIN)) < TOLERANCE

    # 4. The node on that file, as the README runs it; the arm back at its zero pose.
    assert commands['node'][1:] == ['--ros-args', '--params-file', 'my_arm.yaml']
    for slot, (model, zero, _) in enumerate(SERVOS, start=1):
        turn_horn(bus, f'#{slot}', model, zero, 0.0)
    node = NodeProcess(tmp_path, '', domain_id=domain_id, cwd=tmp_path,
                       ros_args=commands['node'][1:])
    try:
        message = node.wait_message(client.joint_states, lambda m: list(m.name) == joints,
                                    START_TIMEOUT_S)
        assert all(abs(position) < 0.01 for position in message.position), message.position
    finally:
        node.stop()

    # 5. The tuning line, on the same file: a step response of one of its joints.
    step = re.search(r'`\$bin/dxl (step [^`]*)`', README)
    assert step, 'README.md has no dxl step line'
    child = spawn(*shlex.split(step.group(1)), cwd=str(tmp_path))
    try:
        status, output = finish(child)
    finally:
        child.close(force=True)
    assert status == 0, output
    png = re.search(r'--png (\S+)', step.group(1))
    assert png and (tmp_path / png.group(1)).stat().st_size > 0, output


# ---- the leader and the follower, without ros2 launch ----------------------------------------

def teleop_commands(folder: pathlib.Path) -> List[List[str]]:
    """Return the doc's four lines, their /tmp ptys moved into folder."""
    lines = section_lines(TELEOP, '## Without `ros2 launch`')
    return [[re.sub(r'^/tmp/', f'{folder}/', word) if word.startswith('/tmp/') else
             word.replace(':=/tmp/', f':={folder}/') for word in words] for words in lines]


@pytest.mark.process
def test_the_teleoperation_recipe_without_ros2_launch_follows_a_hand_on_the_leader(
        virtual_bus: StartVirtualBus, client: Client, domain_id: int,
        tmp_path: pathlib.Path) -> None:
    lines = teleop_commands(tmp_path)
    assert [words[0] for words in lines] == [f'{BIN}virtual_bus'] * 2 + [f'{BIN}node'] * 2
    buses: List[VirtualBusProcess] = [virtual_bus(extra_args=words[1:]) for words in lines[:2]]
    leader_bus, follower_bus = buses
    collectors: Dict[str, Collector[JointState]] = {}
    for name in ('leader', 'follower'):
        collectors[name] = Collector()
        client.node.create_subscription(JointState, f'/{name}/joint_states', collectors[name],
                                        50)
    nodes = [NodeProcess(tmp_path, '', namespace=name, domain_id=domain_id, cwd=ROOT,
                         ros_args=words[words.index('--ros-args') + 1:])
             for name, words in zip(('leader', 'follower'), lines[2:])]
    try:
        for name, node in zip(('leader', 'follower'), nodes):
            node.wait_message(collectors[name], lambda m: 'shoulder_pan' in m.name,
                              START_TIMEOUT_S)
        # A hand turns the leader's shoulder_pan; the follower's servo goes there.
        turn_horn(leader_bus, '1', 'XL330-M077', 0.5, 0.5)
        pulses = model_named('XL430-W250').pulses_per_rev / (2.0 * math.pi)
        target = model_named('XL430-W250').position_zero_raw + 0.5 * pulses
        wait_until(lambda: abs(follower_bus.get(1, 'present_position') - target) < 0.02 * pulses,
                   START_TIMEOUT_S, "the follower's shoulder_pan at the leader's 0.5 rad",
                   poll_s=0.05)
        message = nodes[1].wait_message(
            collectors['follower'],
            lambda m: abs(dict(zip(m.name, m.position))['shoulder_pan'] - 0.5) < 0.02,
            START_TIMEOUT_S)
        assert abs(dict(zip(message.name, message.position))['shoulder_pan'] - 0.5) < 0.02
        for node in nodes:
            node.alive()
    finally:
        for node in nodes:
            node.stop()
