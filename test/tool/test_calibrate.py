"""
`dxl calibrate` on a virtual_bus over a pty, driven by pexpect as a user at a terminal would.

The simulator's hand (`turn REF RAD [SECONDS]`) puts the horns where a user would put the
joints; `stops REF MIN MAX` gives a joint mechanical end stops for --find-stops. Each test reads
back the file written (config.validate must take it) and what the servos were left with.
"""

import os
import pathlib
import re
import subprocess
import threading
import time
from typing import Any, Callable, Dict, Iterator, List, Tuple

from dxl_cli import DXL, EXPECT_TIMEOUT_S, finish, near, TOLERANCE
from dxl_servo_driver import config
from dxl_servo_driver.bus import Bus
from dxl_servo_driver.models import model_named
from dxl_servo_driver.port.serial_device import open_port
from dxl_servo_driver.tool import calibrate, yaml_edit
from node_harness import Client
import pexpect
from processes import (
    NodeProcess, START_TIMEOUT_S, StartVirtualBus, stop_process, VirtualBusProcess)
import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
BAUD = 1000000
MODELS = ('XM430-W350', 'XM430-W350', 'XL330-M288')
RAD_PER_PULSE = [2 * 3.141592653589793 / model_named(name).pulses_per_rev for name in MODELS]
PARAMS = """\
# A three-joint test arm: its comments and layout must survive calibration.
/**:
  ros__parameters:
    port: {port}
    baud_rate: 1000000
    loop_rate: 50.0
    joints: [pan, lift, grip]
    pan:
      id: 1
      model: XM430-W350     # the base
      operating_mode: position
    lift:
      id: 2
      operating_mode: extended_position
      offset: 0.3           # a guess, before calibration

    grip:
      id: 3
      model: XL330-M288
      operating_mode: current_based_position
      gripper: true
      gripper_open: 0.0
      gripper_closed: 1.0
"""
# The zero pose, in servo radians: where the hand puts each horn (ids 1, 2, 3).
ZERO = {1: 0.7, 2: -1.3, 3: 0.5}


@pytest.fixture
def arm(virtual_bus: StartVirtualBus, tmp_path: pathlib.Path
        ) -> Iterator[Tuple[VirtualBusProcess, pathlib.Path]]:
    """Yield a virtual_bus with the arm's three servos, and its parameter file."""
    link = tmp_path / 'ttyDXL'
    bus = virtual_bus([1, 2, 3], BAUD, link, extra_args=['--models', *MODELS])
    help_text = bus.control('help')
    assert ' turn ' in f' {help_text} ' and ' stops ' in f' {help_text} ', help_text
    params = tmp_path / 'arm.yaml'
    params.write_text(PARAMS.format(port=link))
    yield bus, params


def spawn(*args: str) -> 'pexpect.spawn[str]':
    """Start the installed dxl on a pty."""
    return pexpect.spawn(DXL, list(args), encoding='utf-8', timeout=EXPECT_TIMEOUT_S,
                         dimensions=(24, 400))


def turn(bus: VirtualBusProcess, servo_id: int, rad: float, seconds: float = 0.0) -> None:
    """Turn a horn by hand, at the hand's speed; return once it is there (its position read)."""
    answer = bus.control(f'turn {servo_id} {rad} {seconds}')
    assert answer.startswith('ok'), answer
    model = model_named(MODELS[servo_id - 1])
    target = model.position_zero_raw + rad / RAD_PER_PULSE[servo_id - 1]
    deadline = time.monotonic() + EXPECT_TIMEOUT_S
    while abs(bus.get(servo_id, 'present_position') - target) > 1.0:
        assert time.monotonic() < deadline, f'the horn of id {servo_id} did not reach {rad}'
        time.sleep(0.02)


def loaded(path: pathlib.Path) -> Dict[str, Any]:
    """Return the file's parameters, checked by the driver's own validation."""
    params = yaml_edit.parameters_of(path.read_text())
    config.validate(params)
    return params


def with_bus(device: str, action: Any, baud_bps: int = BAUD) -> Any:
    """Open the pty through the driver's Bus, run action(bus), close it."""
    port = open_port(device, baud_bps)
    try:
        return action(Bus(port, baud_bps, latency_timer_s=0.2))
    finally:
        port.close()


def test_an_arm_calibrated_by_hand_then_the_node_publishes_zero_at_its_zero_pose(
        arm: Tuple[VirtualBusProcess, pathlib.Path], client: Client, domain_id: int,
        tmp_path: pathlib.Path) -> None:
    bus, params = arm
    before = params.read_text()
    for servo_id, rad in ZERO.items():
        turn(bus, servo_id, rad)
    child = spawn('calibrate', '--params', str(params), '--hint', 'pan=turn left')
    try:
        child.expect('torque off on 3 servos')
        # 1. zero pose.
        child.expect('zero pose.*press Enter: ')
        child.sendline('')
        for joint, servo_id in (('pan', 1), ('lift', 2), ('grip', 3)):
            child.expect(rf'{joint}: offset ([-+]\d+\.\d+) rad')
            assert abs(float(child.match.group(1)) - ZERO[servo_id]) < TOLERANCE
        # 2. direction: the pan's servo counts down as the joint turns its positive way.
        child.expect(r'Move pan in its positive direction \(turn left\).*Enter: ')
        turn(bus, 1, ZERO[1] - 0.5, 0.3)
        child.sendline('')
        child.expect('pan: servo id 1 counted down .*reverse true')
        child.expect('Move lift in its positive direction')
        child.sendline('')                 # not moved: asked again
        child.expect('lift: moved .* too small a move')
        child.expect('Move lift in its positive direction')
        turn(bus, 2, ZERO[2] + 0.5, 0.3)
        child.sendline('')
        child.expect('lift: servo id 2 counted up .*reverse false')
        child.expect('Move grip in its positive direction')
        turn(bus, 3, ZERO[3] + 0.4, 0.3)
        child.sendline('')
        child.expect('grip: servo id 3 counted up .*reverse false')
        # 3. range, watched live: each end is waited for on the display before the next turn.
        child.expect('whole range')
        for servo_id, joint, servo_rad, joint_rad in (
                (1, 'pan', ZERO[1] + 1.1, -1.1), (1, 'pan', ZERO[1] - 1.0, 1.0),
                (2, 'lift', ZERO[2] - 2.0, -2.0), (2, 'lift', ZERO[2] + 1.5, 1.5),
                (3, 'grip', ZERO[3] - 0.1, -0.1), (3, 'grip', ZERO[3] + 1.2, 1.2)):
            turn(bus, servo_id, servo_rad, 0.3)
            child.expect(rf'{joint} {near(joint_rad)} \[')
        child.sendline('')
        child.expect(r'pan: min_position (\S+), max_position (\S+)')
        assert abs(float(child.match.group(1)) + 1.15) < TOLERANCE
        # The gripper: it asks which end is open; the hand opens it.
        child.expect('Open the gripper fully and press Enter')
        turn(bus, 3, ZERO[3] - 0.05, 0.3)
        child.sendline('')
        child.expect(r'grip: gripper_open (\S+), gripper_closed (\S+)')
        child.expect(r'Write these changes to .*\? \[y/N\] ')
        diff = child.before
        assert '+      reverse: true' in diff and '-      offset: 0.3' in diff
        child.sendline('y')
        child.expect('wrote')
        status, _ = finish(child)
    finally:
        child.close(force=True)
    assert status == 0
    written = loaded(params)
    expected = {
        'pan.offset': ZERO[1], 'lift.offset': ZERO[2], 'grip.offset': ZERO[3],
        'pan.min_position': -1.15, 'pan.max_position': 1.05,
        'lift.min_position': -2.05, 'lift.max_position': 1.55,
        'grip.min_position': -0.15, 'grip.max_position': 1.25,
        'grip.gripper_open': -0.1, 'grip.gripper_closed': 1.2}
    for key, value in expected.items():
        assert abs(written[key] - value) < TOLERANCE, (key, written[key], value)
    assert written['pan.reverse'] is True
    assert written['lift.reverse'] is False and written['grip.reverse'] is False
    # Every line the calibration did not change is byte-identical, comments included.
    after = params.read_text().splitlines(keepends=True)
    kept = [line for line in before.splitlines(keepends=True) if line in after]
    assert [line for line in before.splitlines(keepends=True)
            if 'offset' not in line and 'gripper_' not in line] == \
        [line for line in kept if 'offset' not in line and 'gripper_' not in line]
    assert '      offset: ' in params.read_text() and '# a guess, before calibration' in \
        params.read_text()
    # Torque stays off after a calibration.
    assert [bus.get(servo_id, 'torque_enable') for servo_id in (1, 2, 3)] == [0, 0, 0]

    # The node on the calibrated file, the arm back in its zero pose: 0 rad on every joint.
    for servo_id, rad in ZERO.items():
        turn(bus, servo_id, rad)
    node = NodeProcess(tmp_path, params.read_text(), domain_id=domain_id)
    try:
        message = node.wait_message(
            client.joint_states, lambda m: list(m.name) == ['pan', 'lift', 'grip'],
            START_TIMEOUT_S)
        assert all(abs(position) < 0.01 for position in message.position), message.position
    finally:
        node.stop()


def test_ctrl_c_at_a_prompt_writes_nothing_and_puts_torque_back(
        arm: Tuple[VirtualBusProcess, pathlib.Path]) -> None:
    bus, params = arm
    before = params.read_text()
    with_bus(bus.device, lambda b: b.write(2, 64, bytes([1])))   # Torque Enable of id 2
    assert bus.get(2, 'torque_enable') == 1
    child = spawn('calibrate', '--params', str(params), '--step', 'direction')
    try:
        child.expect('Move pan in its positive direction')
        assert [bus.get(servo_id, 'torque_enable') for servo_id in (1, 2, 3)] == [0, 0, 0]
        child.sendintr()
        status, output = finish(child)
    finally:
        child.close(force=True)
    assert status == 130, output
    assert 'dxl calibrate: interrupted' in output
    assert params.read_text() == before
    assert [bus.get(servo_id, 'torque_enable') for servo_id in (1, 2, 3)] == [0, 1, 0]


def test_scripted_zero_with_yes_and_a_dry_run(
        arm: Tuple[VirtualBusProcess, pathlib.Path]) -> None:
    bus, params = arm
    for servo_id, rad in ZERO.items():
        turn(bus, servo_id, rad)
    done = subprocess.run([DXL, 'calibrate', '--params', str(params), '--step', 'zero',
                           '--yes'], stdin=subprocess.DEVNULL, capture_output=True, text=True,
                          timeout=EXPECT_TIMEOUT_S)
    assert done.returncode == 0, done.stderr
    written = loaded(params)
    for joint, servo_id in (('pan', 1), ('lift', 2), ('grip', 3)):
        assert abs(written[f'{joint}.offset'] - ZERO[servo_id]) < TOLERANCE
    # A dry run prints the diff and writes nothing.
    turn(bus, 1, 0.0)
    text = params.read_text()
    done = subprocess.run([DXL, 'calibrate', '--params', str(params), '--step', 'zero',
                           '--yes', '--dry-run', '--joints', 'pan'], stdin=subprocess.DEVNULL,
                          capture_output=True, text=True, timeout=EXPECT_TIMEOUT_S)
    assert done.returncode == 0, done.stderr
    assert '+      offset: 0.0' in done.stdout and params.read_text() == text


def read_until(proc: 'subprocess.Popen[bytes]', text: str) -> str:
    """Return what proc printed up to and with text (a prompt has no line break after it)."""
    assert proc.stdout is not None
    seen = b''
    deadline = time.monotonic() + EXPECT_TIMEOUT_S
    while text.encode() not in seen:
        assert time.monotonic() < deadline and proc.poll() is None, seen.decode()
        seen += os.read(proc.stdout.fileno(), 4096)
    return seen.decode()


def test_directions_scripted_through_a_pipe_all_joints_at_once(
        arm: Tuple[VirtualBusProcess, pathlib.Path]) -> None:
    bus, params = arm
    proc = subprocess.Popen([DXL, 'calibrate', '--params', str(params), '--step', 'direction',
                             '--together', '--joints', 'pan', 'lift', '--yes'],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT)
    try:
        read_until(proc, 'Move every joint in its positive direction')
        turn(bus, 1, -0.4, 0.2)     # counts down: reverse
        turn(bus, 2, 0.4, 0.2)      # counts up
        assert proc.stdin is not None
        proc.stdin.write(b'\n')
        proc.stdin.flush()
        output = read_until(proc, 'wrote')
        assert proc.wait(EXPECT_TIMEOUT_S) == 0, output
    finally:
        stop_process(proc)
        for stream in (proc.stdin, proc.stdout):
            if stream is not None:
                stream.close()
    written = loaded(params)
    assert written['pan.reverse'] is True and written['lift.reverse'] is False
    assert 'grip.reverse' not in written


def find_grip_stops(params: pathlib.Path, watch: Callable[[], None],
                    stop: threading.Event) -> Tuple[float, float]:
    """
    Find the gripper's stops (0.3 A, 1 rad/s) with watch() running; return them.

    The simulator has them at -0.4 and 1.6 rad (the console's `stops`).
    """
    watcher = threading.Thread(target=watch)
    watcher.start()
    try:
        child = spawn('calibrate', '--params', str(params), '--find-stops', 'grip', '--current',
                      '0.3', '--speed', '1.0', '--gripper-open', 'low', '--yes')
        try:
            child.expect(r'grip: stops at (\S+) and (\S+)', timeout=60.0)
            low, high = float(child.match.group(1)), float(child.match.group(2))
            status, output = finish(child)
        finally:
            child.close(force=True)
    finally:
        stop.set()
        watcher.join()
    assert status == 0, output
    assert abs(low + 0.4) < 0.01 and abs(high - 1.6) < 0.01
    return low, high


def test_find_stops_within_the_current_set(arm: Tuple[VirtualBusProcess, pathlib.Path]) -> None:
    bus, params = arm
    assert bus.control('stops 3 -0.4 1.6').startswith('ok')
    samples: List[Dict[str, int]] = []
    stop = threading.Event()

    def watch() -> None:
        while not stop.is_set():
            answer = bus.control('dump 3')
            samples.append({key: int(value) for key, value in
                            re.findall(r'(\w+)=(-?\d+)', answer)})
            stop.wait(0.02)   # paced: the console shares the simulator's process with the bus

    # Above the servo's Current Limit (1.75 A on an XL330-M288): refused, nothing moves.
    done = subprocess.run([DXL, 'calibrate', '--params', str(params), '--find-stops', 'grip',
                           '--current', '2.0', '--yes'], stdin=subprocess.DEVNULL,
                          capture_output=True, text=True, timeout=EXPECT_TIMEOUT_S)
    assert done.returncode == 2 and 'at most the Current Limit' in done.stderr, done.stderr
    low, high = find_grip_stops(params, watch, stop)
    written = loaded(params)
    assert abs(written['grip.min_position'] - (low + 0.05)) < TOLERANCE
    assert abs(written['grip.max_position'] - (high - 0.05)) < TOLERANCE
    assert written['grip.gripper_open'] == written['grip.min_position']
    assert written['grip.gripper_closed'] == written['grip.max_position']
    # The current never went above 0.3 A (300 raw of 1 mA), and it did push into the stops.
    on = [sample for sample in samples if sample['torque_enable'] == 1]
    assert len(on) > 20
    assert max(abs(sample['present_current']) for sample in on) <= 300
    assert max(sample['goal_current'] for sample in on) <= 300
    assert max(abs(sample['present_current']) for sample in on) >= 240
    # Torque off after, its mode as it was.
    assert bus.get(3, 'torque_enable') == 0 and bus.get(3, 'operating_mode') == 3


def test_find_stops_on_a_time_based_profile_moves_at_the_speed_given(
        arm: Tuple[VirtualBusProcess, pathlib.Path]) -> None:
    # An arm set up as Interbotix's are: Drive Mode's time-based bit, Profile Velocity 2000 ms.
    # The push must still go at --speed (not in 1.0 rad/s read as a few ms), and the servo's
    # own profile must be what it was after.
    bus, params = arm
    for name, value in (('drive_mode', 4), ('profile_velocity', 2000)):
        done = subprocess.run([DXL, 'set', '3', name, str(value), '--raw', '--port',
                               str(bus.link), '--baud', str(BAUD)], stdin=subprocess.DEVNULL,
                              capture_output=True, text=True, timeout=EXPECT_TIMEOUT_S)
        assert done.returncode == 0, done.stderr
    assert bus.control('stops 3 -0.4 1.6').startswith('ok')
    speeds: List[int] = []
    stop = threading.Event()

    def watch() -> None:
        while not stop.is_set():
            speeds.append(abs(bus.get(3, 'present_velocity')))
            stop.wait(0.01)

    find_grip_stops(params, watch, stop)
    # 1.0 rad/s is 42 of the XL330's 0.229 rpm (twice that allowed for the bounce off a stop);
    # a move timed at 42 ms instead reaches about 255.
    assert speeds and max(speeds) <= 84, max(speeds)
    assert (bus.get(3, 'drive_mode'), bus.get(3, 'profile_velocity')) == (4, 2000)


def test_a_bad_file_is_refused_with_the_drivers_message(tmp_path: pathlib.Path) -> None:
    params = tmp_path / 'bad.yaml'
    params.write_text(PARAMS.format(port='/dev/null').replace('id: 2', 'id: 1'))
    done = subprocess.run([DXL, 'calibrate', '--params', str(params)], stdin=subprocess.DEVNULL,
                          capture_output=True, text=True, timeout=EXPECT_TIMEOUT_S)
    assert done.returncode == 2
    assert done.stderr.strip() == (f"dxl calibrate: error: {params}: parameter 'lift.id': id 1 "
                                   "is already used by joint 'pan'")
    params.write_text('/**:\n  ros__parameters:\n\tjoints: [a]\n')
    done = subprocess.run([DXL, 'calibrate', '--params', str(params)], stdin=subprocess.DEVNULL,
                          capture_output=True, text=True, timeout=EXPECT_TIMEOUT_S)
    assert done.returncode == 2 and 'invalid YAML' in done.stderr, done.stderr


# README.md's "Configure a joint" file on a pty: its joint written inline, as a flow mapping.
ONE_JOINT = (ROOT / 'config' / 'one_joint.yaml').read_text()


def inline(port: pathlib.Path) -> str:
    """Return config/one_joint.yaml on this port."""
    assert 'port: sim ' in ONE_JOINT
    return ONE_JOINT.replace('port: sim ', f'port: {port} ')


def test_a_joint_written_inline_is_calibrated_by_hand_and_written_as_a_block(
        virtual_bus: StartVirtualBus, tmp_path: pathlib.Path) -> None:
    link = tmp_path / 'ttyDXL'
    bus = virtual_bus([1], 57600, link, extra_args=['--models', MODELS[0]])
    params = tmp_path / 'one_joint.yaml'
    params.write_text(inline(link))
    assert '    shoulder: {id: 1, operating_mode: position}\n' in params.read_text()
    turn(bus, 1, ZERO[1])
    child = spawn('calibrate', '--params', str(params))
    try:
        child.expect('zero pose.*press Enter: ')
        child.sendline('')
        child.expect(r'shoulder: offset ([-+]\d+\.\d+) rad')
        assert abs(float(child.match.group(1)) - ZERO[1]) < TOLERANCE
        child.expect('Move shoulder in its positive direction.*Enter: ')
        turn(bus, 1, ZERO[1] - 0.5, 0.3)
        child.sendline('')
        child.expect('shoulder: servo id 1 counted down.*reverse true')
        child.expect('whole range')
        for joint_rad in (-1.0, 0.8):
            turn(bus, 1, ZERO[1] - joint_rad, 0.3)
            child.expect(rf'shoulder {near(joint_rad)} \[')
        child.sendline('')
        child.expect(r'Write these changes to .*\? \[y/N\] ')
        child.sendline('y')
        child.expect('wrote')
        status, output = finish(child)
    finally:
        child.close(force=True)
    assert status == 0, output
    text = params.read_text()
    head, _, tail = inline(link).partition(
        '    shoulder: {id: 1, operating_mode: position}\n')
    assert text.startswith(head + '    shoulder:\n      id: 1\n      operating_mode: position\n')
    assert text.endswith(tail)
    written = loaded(params)
    assert abs(written['shoulder.offset'] - ZERO[1]) < TOLERANCE
    assert written['shoulder.reverse'] is True
    assert abs(written['shoulder.min_position'] - (-1.0 - calibrate.DEFAULT_MARGIN)) < TOLERANCE
    assert abs(written['shoulder.max_position'] - (0.8 + calibrate.DEFAULT_MARGIN)) < TOLERANCE


def test_a_joint_that_cannot_be_edited_is_refused_before_torque_goes_off(
        virtual_bus: StartVirtualBus, tmp_path: pathlib.Path) -> None:
    link = tmp_path / 'ttyDXL'
    bus = virtual_bus([1], 57600, link, extra_args=['--models', MODELS[0]])
    with_bus(bus.device, lambda b: b.write(1, 64, bytes([1])), 57600)   # Torque Enable
    params = tmp_path / 'one_joint.yaml'
    params.write_text(inline(link).replace(
        '{id: 1, operating_mode: position}', '{id: 1,\n               operating_mode: position}'))
    before = params.read_text()
    child = spawn('calibrate', '--params', str(params))
    try:
        status, output = finish(child)
    finally:
        child.close(force=True)
    assert status == 2, output
    assert "joint 'shoulder' is a flow mapping continued on the next lines" in output, output
    assert 'nothing was started' in output and 'zero pose' not in output, output
    assert params.read_text() == before
    assert bus.get(1, 'torque_enable') == 1


def test_a_joint_whose_servo_does_not_answer(virtual_bus: StartVirtualBus,
                                             tmp_path: pathlib.Path) -> None:
    link = tmp_path / 'ttyDXL'
    bus = virtual_bus([1, 2], BAUD, link, extra_args=['--models', *MODELS[:2]])
    params = tmp_path / 'arm.yaml'
    params.write_text(PARAMS.format(port=link))
    before = params.read_text()
    done = subprocess.run([DXL, 'calibrate', '--params', str(params), '--step', 'zero', '--yes'],
                          stdin=subprocess.DEVNULL, capture_output=True, text=True,
                          timeout=EXPECT_TIMEOUT_S)
    assert done.returncode == 1
    assert done.stderr.startswith("dxl calibrate: error: joint 'grip': id 3 does not answer")
    assert params.read_text() == before
    assert bus.get(1, 'torque_enable') == 0


def test_help_has_an_example() -> None:
    done = subprocess.run([DXL, 'calibrate', '--help'], capture_output=True, text=True,
                          timeout=EXPECT_TIMEOUT_S)
    assert done.returncode == 0
    assert 'dxl calibrate --params' in done.stdout


def test_a_joint_on_two_servos_gets_both_offsets_and_directions(
        virtual_bus: StartVirtualBus, tmp_path: pathlib.Path) -> None:
    link = tmp_path / 'ttyDXL'
    bus = virtual_bus([1, 2], BAUD, link, extra_args=['--models', *MODELS[:2]])
    params = tmp_path / 'shoulder.yaml'
    params.write_text(f'/**:\n  ros__parameters:\n    port: {link}\n    baud_rate: {BAUD}\n'
                      '    joints: [shoulder]\n    shoulder:\n      id: 1\n      secondary_id: 2\n'
                      '      secondary_reverse: false   # mounted mirrored?\n')
    turn(bus, 1, 0.4)
    turn(bus, 2, -0.6)
    proc = subprocess.Popen([DXL, 'calibrate', '--params', str(params), '--step', 'zero',
                             '--step', 'direction', '--yes'], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        read_until(proc, 'Move shoulder in its positive direction')
        turn(bus, 1, 0.9, 0.2)      # the joint's servo counts up ...
        turn(bus, 2, -1.1, 0.2)     # ... the one on the other side down
        assert proc.stdin is not None
        proc.stdin.write(b'\n')
        proc.stdin.flush()
        output = read_until(proc, 'wrote')
        assert proc.wait(EXPECT_TIMEOUT_S) == 0, output
    finally:
        stop_process(proc)
        for stream in (proc.stdin, proc.stdout):
            if stream is not None:
                stream.close()
    written = loaded(params)
    assert abs(written['shoulder.offset'] - 0.4) < TOLERANCE
    assert abs(written['shoulder.secondary_offset'] + 0.6) < TOLERANCE
    assert written['shoulder.reverse'] is False
    assert written['shoulder.secondary_reverse'] is True
    assert '      secondary_reverse: true    # mounted mirrored?\n' in params.read_text()


def test_the_urdf_says_which_way_is_positive() -> None:
    hints = calibrate.urdf_hints(str(ROOT / 'config' / 'moveit' / 'arm_sim.urdf'))
    assert hints['shoulder_lift'].startswith('counter-clockwise about its axis (0 1 0)')
    assert hints['shoulder_pan'].startswith('counter-clockwise about its axis (0 0 1)')
    assert 'tool_joint' not in hints     # fixed: no direction
