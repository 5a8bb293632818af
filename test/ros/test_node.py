"""
The driver node in-process on `port: sim`: every topic and service of README.md.

Each test runs a real DriverNode over the real manager, bus layer and simulator (no mocks) and
checks what it did against the simulated servos' registers. Expected raw values are computed
here from the XM430 manual's model's units (models/units.py), not from what the node did.
"""

import math
import threading
import time
from typing import Any, Dict, Iterator, List, Sequence, Tuple

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from dxl_servo_driver.models import model_for, modes, xm430
from dxl_servo_driver.models.units import units_for
from lifecycle_msgs.msg import Transition
from node_harness import NodeHarness, sim_params, startup_failure
import pytest

# The units of the XM430 manual's model, every joint's here (models/units.py).
UNITS = units_for(model_for(xm430.MODEL_NUMBER))
RAD_PER_PULSE = UNITS.rad_per_pulse
RAD_S_PER_RAW = UNITS.rad_s_per_velocity_raw
A_PER_RAW = UNITS.a_per_current_raw
PWM_FULL_RAW = UNITS.pwm_full_raw
TORQUE_CONSTANT_NM_PER_A = UNITS.torque_constant_nm_per_a
GOALS = ('goal_position', 'goal_velocity', 'goal_current', 'goal_pwm')
KIND_REGISTER = {'position': 'goal_position', 'velocity': 'goal_velocity',
                 'current': 'goal_current', 'pwm': 'goal_pwm'}

# One joint per operating mode family. arm's RAM registers are ones a mode change and a reboot
# reset on the servo (profile_velocity -> 0, position_p_gain -> 800): seeing them again proves
# the node restored them.
ARM_PROFILE_VELOCITY_RAW = 200
ARM_P_GAIN_RAW = 900
ARM_MIN_RAW, ARM_MAX_RAW = 1024, 3072
WHEEL_VELOCITY_LIMIT_RAW = 200
HAND_CURRENT_LIMIT_RAW = 600
FAN_PWM_LIMIT_RAW = 700
JOINTS: Dict[str, Dict[str, Any]] = {
    'arm': {'id': 1, 'operating_mode': 'position', 'registers': {
        'min_position_limit': ARM_MIN_RAW, 'max_position_limit': ARM_MAX_RAW,
        'profile_velocity': ARM_PROFILE_VELOCITY_RAW, 'position_p_gain': ARM_P_GAIN_RAW}},
    'wheel': {'id': 2, 'operating_mode': 'velocity',
              'registers': {'velocity_limit': WHEEL_VELOCITY_LIMIT_RAW}},
    'hand': {'id': 3, 'operating_mode': 'current',
             'registers': {'current_limit': HAND_CURRENT_LIMIT_RAW}},
    'fan': {'id': 4, 'operating_mode': 'pwm', 'registers': {'pwm_limit': FAN_PWM_LIMIT_RAW}},
    'gripper': {'id': 5, 'operating_mode': 'current_based_position',
                'registers': {'current_limit': 400}},
}
IDS = {name: keys['id'] for name, keys in JOINTS.items()}
MODE_RAW = modes.numbers(*modes.NAMES)


def pos_raw(rad: float) -> int:
    return UNITS.zero_raw + round(rad / RAD_PER_PULSE)


def pos_rad(raw: int) -> float:
    return (raw - UNITS.zero_raw) * RAD_PER_PULSE


def goal_raw(kind: str, value: float) -> int:
    if kind == 'position':
        return pos_raw(value)
    if kind == 'velocity':
        return round(value / RAD_S_PER_RAW)
    if kind == 'current':
        return round(value / A_PER_RAW)
    return round(value * PWM_FULL_RAW)


@pytest.fixture
def h() -> Iterator[NodeHarness]:
    with NodeHarness(sim_params(JOINTS)) as harness:
        yield harness


def goals(h: NodeHarness, ids: Sequence[int]) -> Dict[Tuple[int, str], int]:
    return {(sid, name): h.reg(sid, name) for sid in ids for name in GOALS}


def cycles(h: NodeHarness, count: int = 3) -> None:
    """Wait until the node ran a few full cycles: read, publish, write."""
    for _ in range(count):
        h.joint_states.wait(timeout_s=5.0)


def stamp_s(msg: Any) -> float:
    """Return a message's stamp: when the node read the sample it carries (wall clock)."""
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


def status_named(array: DiagnosticArray, suffix: str) -> DiagnosticStatus:
    matches = [s for s in array.status if s.name.endswith(suffix)]
    assert len(matches) == 1, [s.name for s in array.status]
    return matches[0]


def values_of(status: DiagnosticStatus) -> Dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


# joint_states, servo_states, diagnostics ----------------------------------------------------

def test_joint_states_at_rest_equal_the_registers(h: NodeHarness) -> None:
    # Torque off and at rest, the registers do not change: the published SI values must equal
    # the manual's unit conversions of them exactly.
    assert h.call('set_torque', name=[], enable=False).success
    for sid in IDS.values():
        h.wait_reg(sid, 'present_velocity', lambda v: v == 0)
    msg = h.joint_states.wait(lambda m: len(m.name) == len(JOINTS))
    assert list(msg.name) == list(JOINTS)   # the order of the joints parameter
    assert msg.header.stamp.sec > 0
    for index, name in enumerate(msg.name):
        sid = IDS[name]
        assert msg.position[index] == pytest.approx(pos_rad(h.reg(sid, 'present_position')),
                                                    abs=1e-9)
        assert msg.velocity[index] == pytest.approx(0.0, abs=1e-9)
        current_a = h.reg(sid, 'present_current') * A_PER_RAW
        assert msg.effort[index] == pytest.approx(current_a * TORQUE_CONSTANT_NM_PER_A,
                                                  abs=1e-9)


def test_joint_states_follow_a_moving_servo(h: NodeHarness) -> None:
    assert h.call('set_velocity', name=['wheel'], value=[2.0]).success
    msg = h.joint_states.wait(
        lambda m: abs(m.velocity[m.name.index('wheel')] - 2.0) < 0.2)
    # The stamp is the read time, so it lies before now; the values were read at that time.
    stamp_s = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
    assert stamp_s <= time.time() + 0.01
    # Present Position counts turns in velocity mode: reads of a servo turning one way grow.
    first = h.joint_states.wait()
    later = h.joint_states.wait(
        lambda m: m.header.stamp.sec + m.header.stamp.nanosec * 1e-9
        > first.header.stamp.sec + first.header.stamp.nanosec * 1e-9 + 0.1)
    index = first.name.index('wheel')
    assert later.position[index] > first.position[index]
    assert pos_rad(h.reg(IDS['wheel'], 'present_position')) >= later.position[index]


def test_unplugged_joint_is_left_out_then_back(h: NodeHarness) -> None:
    h.joint_states.wait(lambda m: 'wheel' in m.name)
    h.sim.unplug(IDS['wheel'])
    h.joint_states.wait(lambda m: 'wheel' not in m.name)
    for _ in range(5):   # never a stale value while it does not answer
        msg = h.joint_states.wait()
        assert 'wheel' not in msg.name
        assert set(msg.name) == set(JOINTS) - {'wheel'}
        assert len(msg.position) == len(msg.velocity) == len(msg.effort) == len(msg.name)
    diag = h.diagnostics.wait(lambda d: status_named(d, ': wheel').level
                              == DiagnosticStatus.ERROR)
    assert 'not answering' in status_named(diag, ': wheel').message
    assert status_named(diag, ': arm').level == DiagnosticStatus.OK
    states = h.servo_states.wait()
    wheel = [s for s in states.servos if s.name == 'wheel'][0]
    assert wheel.comm_errors > 0
    h.sim.plug(IDS['wheel'])
    h.joint_states.wait(lambda m: 'wheel' in m.name)
    # A plugged servo boots with torque off: the node gives it back its torque.
    h.wait_reg(IDS['wheel'], 'torque_enable', lambda v: v == 1)


def test_servo_restarting_on_its_own_gets_its_setup_back(h: NodeHarness) -> None:
    assert h.call('set_position', name=['arm'], value=[0.4]).success
    h.wait_reg(IDS['arm'], 'present_position', lambda v: abs(v - pos_raw(0.4)) <= 20)
    h.sim.powercycle(IDS['arm'])
    # Power-on: RAM defaults (profile_velocity 0, p gain 800, torque off) until the node
    # restores the configuration and the torque, holding where the horn is (a goal nobody
    # sent again is not replayed).
    h.wait_reg(IDS['arm'], 'torque_enable', lambda v: v == 1)
    assert h.reg(IDS['arm'], 'profile_velocity') == ARM_PROFILE_VELOCITY_RAW
    assert h.reg(IDS['arm'], 'position_p_gain') == ARM_P_GAIN_RAW
    # The goal is where the horn was when the torque came back (it may still be settling).
    held = h.reg(IDS['arm'], 'goal_position')
    h.wait_reg(IDS['arm'], 'present_position', lambda v: abs(v - held) <= 8)
    assert h.reg(IDS['arm'], 'goal_position') == held
    # The published position is where the horn is now (it coasted while unpowered), not the
    # goal sent before the restart.
    present = pos_rad(h.reg(IDS['arm'], 'present_position'))
    msg = h.joint_states.wait(
        lambda m: 'arm' in m.name
        and abs(m.position[list(m.name).index('arm')] - present) < 0.01)
    assert math.isfinite(msg.position[list(msg.name).index('arm')])


def test_servo_states_fields(h: NodeHarness) -> None:
    msg = h.servo_states.wait()
    assert msg.header.stamp.sec > 0
    assert [s.name for s in msg.servos] == list(JOINTS)
    for state in msg.servos:
        sid = IDS[state.name]
        assert state.id == sid
        assert state.model_number == h.reg(sid, 'model_number') == 1030
        assert state.firmware_version == h.reg(sid, 'firmware_version')
        assert state.operating_mode == JOINTS[state.name]['operating_mode']
        assert state.torque_enabled is True
        assert state.input_voltage == pytest.approx(h.reg(sid, 'present_input_voltage') * 0.1)
        assert state.temperature == pytest.approx(h.reg(sid, 'present_temperature'), abs=1.0)
        assert state.hardware_error_status == 0
        assert list(state.hardware_errors) == []
        assert state.comm_errors == 0
        assert math.isfinite(state.position) and math.isfinite(state.velocity)
        assert -1.0 <= state.pwm <= 1.0
    # A moving servo: position and motion flags follow the simulator. At 100 Hz (a runtime
    # parameter) the states cannot miss the motion, even when the machine is busy.
    assert h.set_parameter('state_rate', 100.0).successful
    assert h.call('set_position', name=['arm'], value=[-1.5]).success
    moving = h.servo_states.wait(lambda m: m.servos[0].moving)
    assert moving.servos[0].moving_status & 0x30 != 0   # a profile is running
    rest = h.servo_states.wait(lambda m: not m.servos[0].moving
                               and abs(m.servos[0].position + 1.5) < 0.02)
    assert rest.servos[0].moving_status & 0x01   # in position
    # The published position is the simulator's. Not moving is not still (the horn may creep
    # the last pulses into place): a sample taken between two reads of the register lies
    # between them.
    before = pos_rad(h.reg(IDS['arm'], 'present_position'))
    asked_s = time.time()
    later = h.servo_states.wait(lambda m: stamp_s(m) > asked_s)   # read after `before`
    after = pos_rad(h.reg(IDS['arm'], 'present_position'))
    assert min(before, after) - 0.01 <= later.servos[0].position <= max(before, after) + 0.01


def test_diagnostics_bus_and_one_status_per_servo(h: NodeHarness) -> None:
    # Once every servo was read (a busy machine may publish the first array before that, with
    # some servos still to come), a status for each.
    h.joint_states.wait(lambda m: len(m.name) == len(JOINTS), timeout_s=10.0)
    diag = h.diagnostics.wait(lambda d: len(d.status) == 1 + len(JOINTS), timeout_s=10.0)
    bus = [s for s in diag.status if ' bus ' in s.name]
    assert len(bus) == 1
    values = values_of(bus[0])
    assert values['port'] == 'sim' and values['baud_rate'] == '1000000'
    assert float(values['loop_rate_requested_hz']) == 100.0
    for key in ('loop_rate_measured_hz', 'timeouts', 'corrupt_replies', 'read_failures'):
        assert key in values
    for name, keys in JOINTS.items():
        status = status_named(diag, f': {name}')
        assert status.level == DiagnosticStatus.OK, status.message
        servo_values = values_of(status)
        assert servo_values['id'] == str(keys['id'])
        assert servo_values['model_number'] == '1030'
        assert servo_values['operating_mode'] == keys['operating_mode']
        assert servo_values['hardware_errors'] == 'none'


def test_hardware_error_decoded_by_name(h: NodeHarness) -> None:
    h.sim.inject_error(IDS['hand'], 'overload')
    diag = h.diagnostics.wait(
        lambda d: status_named(d, ': hand').level == DiagnosticStatus.ERROR, timeout_s=5.0)
    status = status_named(diag, ': hand')
    assert 'overload' in status.message
    assert 'overload' in values_of(status)['hardware_errors']
    assert status_named(diag, ': arm').level == DiagnosticStatus.OK
    states = h.servo_states.wait(lambda m: m.servos[2].hardware_error_status != 0)
    assert states.servos[2].name == 'hand'
    assert states.servos[2].hardware_error_status == 0x20
    assert list(states.servos[2].hardware_errors) == ['overload']
    # The shutdown cut the torque, and the servo still answers: it stays in joint_states.
    assert h.reg(IDS['hand'], 'torque_enable') == 0
    assert 'hand' in h.joint_states.wait().name


def test_diagnostics_warn_on_low_voltage(h: NodeHarness) -> None:
    # Below the node's voltage_low (10 V) but above the servo's min_voltage_limit (9.5 V), so no
    # input voltage error is latched: a warning, not an error.
    h.sim.set_voltage(IDS['fan'], 9.8)
    diag = h.diagnostics.wait(
        lambda d: status_named(d, ': fan').level == DiagnosticStatus.WARN, timeout_s=5.0)
    assert 'voltage' in status_named(diag, ': fan').message


# commands: topics and services ---------------------------------------------------------------

MOVES = [('position', 'arm', 0.8), ('velocity', 'wheel', 1.5), ('current', 'hand', 0.2),
         ('pwm', 'fan', 0.5), ('position', 'gripper', -0.6), ('current', 'gripper', 0.5)]


@pytest.mark.parametrize('kind,joint,value', MOVES)
def test_command_topic_writes_the_goal(h: NodeHarness, kind: str, joint: str,
                                       value: float) -> None:
    register = KIND_REGISTER[kind]
    expected = goal_raw(kind, value)
    assert h.reg(IDS[joint], register) != expected
    h.publish(kind, [joint], [value])
    assert abs(h.wait_reg(IDS[joint], register, lambda v: abs(v - expected) <= 1)
               - expected) <= 1


def test_position_topic_moves_the_servo(h: NodeHarness) -> None:
    h.publish('position', ['arm', 'gripper'], [-0.7, 0.5])
    msg = h.joint_states.wait(
        lambda m: abs(m.position[0] + 0.7) < 0.02 and abs(m.position[4] - 0.5) < 0.05)
    assert msg.name[0] == 'arm' and msg.name[4] == 'gripper'
    assert h.reg(IDS['arm'], 'goal_position') == pos_raw(-0.7)


def test_velocity_topic_turns_the_wheel(h: NodeHarness) -> None:
    h.publish('velocity', ['wheel'], [-1.0])
    h.joint_states.wait(lambda m: abs(m.velocity[1] + 1.0) < 0.1)


def test_latest_goal_wins(h: NodeHarness) -> None:
    for value in (0.1, 0.2, 0.3):
        h.publish('position', ['arm'], [value])
    h.wait_reg(IDS['arm'], 'goal_position', lambda v: v == pos_raw(0.3))
    cycles(h)
    assert h.reg(IDS['arm'], 'goal_position') == pos_raw(0.3)


@pytest.mark.parametrize('kind,joint,value', MOVES)
def test_set_goals_service_answers_after_the_write(h: NodeHarness, kind: str, joint: str,
                                                   value: float) -> None:
    response = h.call(f'set_{kind}', name=[joint], value=[value])
    # Read at once: the goal is on the servo when the answer arrives.
    assert abs(h.reg(IDS[joint], KIND_REGISTER[kind]) - goal_raw(kind, value)) <= 1
    assert response.success, response.message


def test_set_goals_service_several_joints(h: NodeHarness) -> None:
    response = h.call('set_position', name=['gripper', 'arm'], value=[0.25, -0.25])
    assert response.success, response.message
    assert h.reg(IDS['gripper'], 'goal_position') == pos_raw(0.25)
    assert h.reg(IDS['arm'], 'goal_position') == pos_raw(-0.25)


# clamping ------------------------------------------------------------------------------------

CLAMPS = [
    ('position', 'arm', 3.0, ARM_MAX_RAW),                 # beyond max_position_limit
    ('position', 'arm', -3.0, ARM_MIN_RAW),                # beyond min_position_limit
    ('velocity', 'wheel', 50.0, WHEEL_VELOCITY_LIMIT_RAW),
    ('velocity', 'wheel', -50.0, -WHEEL_VELOCITY_LIMIT_RAW),
    ('current', 'hand', 10.0, HAND_CURRENT_LIMIT_RAW),
    ('current', 'hand', -10.0, -HAND_CURRENT_LIMIT_RAW),
    ('pwm', 'fan', 1.0, FAN_PWM_LIMIT_RAW),
    ('pwm', 'fan', -5.0, -FAN_PWM_LIMIT_RAW),
]


@pytest.mark.parametrize('kind,joint,value,expected', CLAMPS)
def test_goal_clamped_to_the_limit(h: NodeHarness, kind: str, joint: str, value: float,
                                   expected: int) -> None:
    response = h.call(f'set_{kind}', name=[joint], value=[value])
    assert response.success, response.message
    assert h.reg(IDS[joint], KIND_REGISTER[kind]) == expected


def test_topic_goal_clamped_too(h: NodeHarness) -> None:
    h.publish('position', ['arm'], [2.9])
    h.wait_reg(IDS['arm'], 'goal_position', lambda v: v == ARM_MAX_RAW)
    h.wait_reg(IDS['arm'], 'present_position', lambda v: abs(v - ARM_MAX_RAW) <= 20)


def test_extended_position_is_not_clamped_to_one_turn(h: NodeHarness) -> None:
    assert h.call('set_operating_mode', name=['gripper'], mode='extended_position').success
    response = h.call('set_position', name=['gripper'], value=[10.0])
    assert response.success, response.message
    assert h.reg(IDS['gripper'], 'goal_position') == pos_raw(10.0)


# refusals: each writes nothing -------------------------------------------------------------

# Two joints per command kind: a refused message names the first (so a partial write would
# show), and a valid "marker" command for the second, on the same topic, proves the refused
# message was handled (one subscription handles its messages in order).
REFUSAL_JOINTS: Dict[str, Dict[str, Any]] = {
    'arm': {'id': 1, 'operating_mode': 'position'},
    'wheel': {'id': 2, 'operating_mode': 'velocity'},
    'hand': {'id': 3, 'operating_mode': 'current'},
    'fan': {'id': 4, 'operating_mode': 'pwm'},
    'gripper': {'id': 5, 'operating_mode': 'current_based_position'},
    'wheel2': {'id': 6, 'operating_mode': 'velocity'},
    'fan2': {'id': 7, 'operating_mode': 'pwm'},
}
REFUSAL_IDS = [keys['id'] for keys in REFUSAL_JOINTS.values()]
MARKER = {'position': 'gripper', 'velocity': 'wheel2', 'current': 'gripper', 'pwm': 'fan2'}
NAN, INF = float('nan'), float('inf')
REFUSALS = [
    ('unknown joint', 'position', ['arm', 'elbow'], [0.3, 0.3], 'unknown joint'),
    ('unknown joint only', 'velocity', ['nope'], [0.3], 'unknown joint'),
    ('fewer values', 'position', ['arm', 'gripper'], [0.3], 'length'),
    ('more values', 'pwm', ['fan'], [0.1, 0.2], 'length'),
    ('empty names', 'position', [], [], 'empty'),
    ('empty names with values', 'current', [], [0.1], ''),
    ('nan', 'position', ['arm'], [NAN], 'finite'),
    ('nan second', 'velocity', ['wheel', 'wheel'], [0.5, NAN], ''),
    ('inf', 'velocity', ['wheel'], [INF], 'finite'),
    ('-inf', 'current', ['hand'], [-INF], 'finite'),
    ('wrong topic velocity', 'velocity', ['arm'], [0.5], 'mode'),
    ('wrong topic in a list', 'velocity', ['wheel', 'arm'], [0.5, 0.5], 'mode'),
    ('wrong topic position', 'position', ['wheel'], [0.5], 'mode'),
    ('wrong topic pwm', 'pwm', ['hand'], [0.2], 'mode'),
    ('wrong topic current', 'current', ['fan'], [0.1], 'mode'),
]
REFUSAL_IDS_TEXT = [case[0] for case in REFUSALS]


@pytest.fixture
def rh() -> Iterator[NodeHarness]:
    with NodeHarness(sim_params(REFUSAL_JOINTS)) as harness:
        yield harness


MARKER_VALUE = {'position': 0.3, 'velocity': 0.4, 'current': 0.05, 'pwm': 0.2}


@pytest.mark.parametrize('case,kind,names,values,reason', REFUSALS, ids=REFUSAL_IDS_TEXT)
def test_refused_topic_command_writes_nothing(rh: NodeHarness, case: str, kind: str,
                                              names: List[str], values: List[float],
                                              reason: str) -> None:
    marker = MARKER[kind]
    marker_id = REFUSAL_JOINTS[marker]['id']
    register = KIND_REGISTER[kind]
    before = goals(rh, REFUSAL_IDS)
    marker_value = MARKER_VALUE[kind]
    expected_marker = goal_raw(kind, marker_value)
    assert before[(marker_id, register)] != expected_marker
    rh.publish(kind, names, values)
    rh.publish(kind, [marker], [marker_value])
    rh.wait_reg(marker_id, register, lambda v: v == expected_marker)
    after = goals(rh, REFUSAL_IDS)
    del before[(marker_id, register)], after[(marker_id, register)]
    assert after == before
    rh.joint_states.wait(lambda m: len(m.name) == len(REFUSAL_JOINTS))   # still running


@pytest.mark.parametrize('case,kind,names,values,reason', REFUSALS, ids=REFUSAL_IDS_TEXT)
def test_refused_service_call_writes_nothing(rh: NodeHarness, case: str, kind: str,
                                             names: List[str], values: List[float],
                                             reason: str) -> None:
    before = goals(rh, REFUSAL_IDS)
    response = rh.call(f'set_{kind}', name=names, value=values)
    assert not response.success
    assert reason in response.message.lower(), response.message
    cycles(rh)   # nothing was queued for the cycle either
    assert goals(rh, REFUSAL_IDS) == before


def test_refusal_of_a_joint_missing_from_the_node(rh: NodeHarness) -> None:
    response = rh.call('set_torque', name=['elbow'], enable=False)
    assert not response.success and 'elbow' in response.message
    assert all(rh.reg(sid, 'torque_enable') == 1 for sid in REFUSAL_IDS)


# set_operating_mode, set_torque, reboot ----------------------------------------------------

def test_set_operating_mode_restores_registers_and_torque(h: NodeHarness) -> None:
    sid = IDS['arm']
    response = h.call('set_operating_mode', name=['arm'], mode='velocity')
    assert response.success, response.message
    # The mode change reset these on the servo (profile_velocity 0, p gain 800): given back.
    assert h.reg(sid, 'operating_mode') == MODE_RAW['velocity']
    assert h.reg(sid, 'profile_velocity') == ARM_PROFILE_VELOCITY_RAW
    assert h.reg(sid, 'position_p_gain') == ARM_P_GAIN_RAW
    assert h.reg(sid, 'torque_enable') == 1
    assert h.reg(sid, 'goal_velocity') == 0
    states = h.servo_states.wait(lambda m: m.servos[0].operating_mode == 'velocity')
    assert states.servos[0].torque_enabled
    # Commands follow the new mode.
    assert not h.call('set_position', name=['arm'], value=[0.2]).success
    assert h.call('set_velocity', name=['arm'], value=[1.0]).success
    assert h.reg(sid, 'goal_velocity') == goal_raw('velocity', 1.0)
    h.joint_states.wait(lambda m: abs(m.velocity[0] - 1.0) < 0.1)
    # Back to position while it turns: it must stop where it is, not jump.
    response = h.call('set_operating_mode', name=['arm'], mode='position')
    assert response.success, response.message
    assert h.reg(sid, 'operating_mode') == MODE_RAW['position']
    assert h.reg(sid, 'profile_velocity') == ARM_PROFILE_VELOCITY_RAW
    assert h.reg(sid, 'position_p_gain') == ARM_P_GAIN_RAW
    assert h.reg(sid, 'torque_enable') == 1
    # Goal and present position of one moment (the horn still brakes: read one after the
    # other, they were apart by what it moved in between).
    registers = h.sim.registers(sid)
    assert abs(registers['goal_position'] - registers['present_position']) <= 50


def test_set_operating_mode_keeps_torque_off(h: NodeHarness) -> None:
    assert h.call('set_torque', name=['wheel'], enable=False).success
    response = h.call('set_operating_mode', name=['wheel'], mode='pwm')
    assert response.success, response.message
    assert h.reg(IDS['wheel'], 'operating_mode') == MODE_RAW['pwm']
    assert h.reg(IDS['wheel'], 'torque_enable') == 0
    # The mode change set goal_pwm to pwm_limit; the node brought it back to zero.
    assert h.reg(IDS['wheel'], 'goal_pwm') == 0


@pytest.mark.parametrize('names,mode,reason', [
    (['arm'], 'turbo', 'unknown operating mode'),
    ([], 'velocity', 'no joint'),
    (['arm', 'elbow'], 'velocity', 'elbow'),
])
def test_set_operating_mode_refused(h: NodeHarness, names: List[str], mode: str,
                                    reason: str) -> None:
    response = h.call('set_operating_mode', name=names, mode=mode)
    assert not response.success
    assert reason in response.message
    assert h.reg(IDS['arm'], 'operating_mode') == MODE_RAW['position']
    assert h.reg(IDS['arm'], 'torque_enable') == 1


def test_set_torque_off_and_on(h: NodeHarness) -> None:
    response = h.call('set_torque', name=['arm', 'wheel'], enable=False)
    assert response.success, response.message
    assert h.reg(IDS['arm'], 'torque_enable') == 0
    assert h.reg(IDS['wheel'], 'torque_enable') == 0
    assert h.reg(IDS['hand'], 'torque_enable') == 1
    states = h.servo_states.wait(lambda m: not m.servos[0].torque_enabled)
    assert not states.servos[1].torque_enabled and states.servos[2].torque_enabled
    assert 'arm' in h.joint_states.wait().name   # still read and published
    response = h.call('set_torque', name=[], enable=True)   # empty = all
    assert response.success, response.message
    for sid in IDS.values():
        assert h.reg(sid, 'torque_enable') == 1
    assert abs(h.reg(IDS['arm'], 'goal_position') - h.reg(IDS['arm'], 'present_position')) <= 2
    response = h.call('set_torque', name=[], enable=False)
    assert response.success
    assert all(h.reg(sid, 'torque_enable') == 0 for sid in IDS.values())


def test_reboot_restores_configuration_mode_and_torque(h: NodeHarness) -> None:
    sid = IDS['arm']
    # A runtime change of a configured register: reboot gives the configured value back.
    assert h.call('write_register', name='arm', register_name='profile_velocity',
                  value=333).success
    assert h.call('set_torque', name=['hand'], enable=False).success
    h.sim.inject_error(sid, 'overload')
    h.wait_reg(sid, 'torque_enable', lambda v: v == 0)   # the shutdown
    response = h.call('reboot', name=['arm', 'hand'])
    assert response.success, response.message
    assert h.reg(sid, 'hardware_error_status') == 0
    assert h.reg(sid, 'profile_velocity') == ARM_PROFILE_VELOCITY_RAW
    assert h.reg(sid, 'position_p_gain') == ARM_P_GAIN_RAW
    assert h.reg(sid, 'operating_mode') == MODE_RAW['position']
    assert h.reg(sid, 'torque_enable') == 1
    assert abs(h.reg(sid, 'goal_position') - h.reg(sid, 'present_position')) <= 2
    assert h.reg(IDS['hand'], 'torque_enable') == 0   # it was off: it stays off
    assert h.reg(IDS['hand'], 'operating_mode') == MODE_RAW['current']
    states = h.servo_states.wait(lambda m: m.servos[0].hardware_error_status == 0)
    assert list(states.servos[0].hardware_errors) == []
    # The state block (indirect map, RAM) works again: arm is published and movable.
    assert h.call('set_position', name=['arm'], value=[0.3]).success
    h.joint_states.wait(lambda m: 'arm' in m.name and abs(m.position[0] - 0.3) < 0.02)


def test_reboot_keeps_a_mode_set_at_runtime(h: NodeHarness) -> None:
    sid = IDS['arm']
    assert h.call('set_operating_mode', name=['arm'], mode='velocity').success
    response = h.call('reboot', name=['arm'])
    assert response.success, response.message
    assert h.reg(sid, 'operating_mode') == MODE_RAW['velocity']
    assert h.reg(sid, 'profile_velocity') == ARM_PROFILE_VELOCITY_RAW
    assert h.reg(sid, 'torque_enable') == 1
    assert h.reg(sid, 'goal_velocity') == 0
    assert h.call('set_velocity', name=['arm'], value=[0.5]).success
    assert h.reg(sid, 'goal_velocity') == goal_raw('velocity', 0.5)


def test_reboot_of_an_unknown_joint_refused(h: NodeHarness) -> None:
    response = h.call('reboot', name=['elbow'])
    assert not response.success and 'elbow' in response.message


# read_register / write_register ------------------------------------------------------------

def test_read_register_by_name_and_by_address(h: NodeHarness) -> None:
    response = h.call('read_register', name='arm', register_name='model_number')
    assert response.success and response.value == 1030
    response = h.call('read_register', name='arm', register_name='max_position_limit')
    assert response.success and response.value == ARM_MAX_RAW
    response = h.call('read_register', name='wheel', register_name='44')   # velocity_limit
    assert response.success, response.message
    assert response.value == WHEEL_VELOCITY_LIMIT_RAW
    # Present Temperature is at 146 (the manual's "(144)" is a typo). It changes by itself (the
    # servo warms up): the answer lies between reads of the register before and after.
    before = h.reg(IDS['hand'], 'present_temperature')
    response = h.call('read_register', name='hand', register_name='146')
    after = h.reg(IDS['hand'], 'present_temperature')
    assert response.success and min(before, after) <= response.value <= max(before, after)
    assert h.call('set_velocity', name=['wheel'], value=[-1.0]).success   # signed registers
    response = h.call('read_register', name='wheel', register_name='goal_velocity')
    assert response.success and response.value == goal_raw('velocity', -1.0) < 0


@pytest.mark.parametrize('joint,register', [
    ('arm', 'no_such_register'), ('arm', '66'),   # 66: between led (65) and 68, no item
    ('elbow', 'present_position'), ('', 'present_position'), ('arm', ''),
])
def test_read_register_refused(h: NodeHarness, joint: str, register: str) -> None:
    response = h.call('read_register', name=joint, register_name=register)
    assert not response.success
    assert response.message


def test_write_register_by_name_and_by_address(h: NodeHarness) -> None:
    response = h.call('write_register', name='arm', register_name='profile_velocity', value=123)
    assert response.success, response.message
    assert h.reg(IDS['arm'], 'profile_velocity') == 123
    response = h.call('write_register', name='arm', register_name='112', value=124)
    assert response.success, response.message
    assert h.reg(IDS['arm'], 'profile_velocity') == 124
    response = h.call('write_register', name='arm', register_name='led', value=1)
    assert response.success and h.reg(IDS['arm'], 'led') == 1


def test_eeprom_write_with_torque_on_refused_with_the_reason(h: NodeHarness) -> None:
    before = h.reg(IDS['wheel'], 'velocity_limit')
    response = h.call('write_register', name='wheel', register_name='velocity_limit', value=150)
    assert not response.success
    assert 'torque' in response.message and 'EEPROM' in response.message
    assert h.reg(IDS['wheel'], 'velocity_limit') == before
    # With torque off it goes through, and the node clamps to the new limit.
    assert h.call('set_torque', name=['wheel'], enable=False).success
    response = h.call('write_register', name='wheel', register_name='velocity_limit', value=150)
    assert response.success, response.message
    assert h.reg(IDS['wheel'], 'velocity_limit') == 150
    assert h.call('set_torque', name=['wheel'], enable=True).success
    assert h.call('set_velocity', name=['wheel'], value=[100.0]).success
    assert h.reg(IDS['wheel'], 'goal_velocity') == 150


@pytest.mark.parametrize('register,value', [
    ('present_position', 5),        # read-only
    ('model_number', 1),            # read-only EEPROM
    ('profile_velocity', 5000),     # above the register's range
    ('led', -1),
    ('torque_enable', 0),           # the driver's own: set_torque
    ('operating_mode', 1),          # the driver's own: set_operating_mode
])
def test_write_register_refused(h: NodeHarness, register: str, value: int) -> None:
    before = h.sim.registers(IDS['arm'])
    response = h.call('write_register', name='arm', register_name=register, value=value)
    assert not response.success
    assert response.message
    after = h.sim.registers(IDS['arm'])
    for name in ('model_number', 'profile_velocity', 'led', 'torque_enable', 'operating_mode'):
        assert after[name] == before[name]


# command_timeout, runtime parameters, lifecycle ----------------------------------------------

def test_command_timeout_zeroes_velocity_goals() -> None:
    # The goal is seen while it lasts (command_timeout): long enough that a test thread kept
    # off the CPU for a moment still sees it.
    timeout_s = 1.0
    with NodeHarness(sim_params(JOINTS, command_timeout=timeout_s)) as h:
        arm_goal = h.reg(IDS['arm'], 'goal_position')
        sent_s = time.monotonic()
        h.publish('velocity', ['wheel'], [1.0])
        h.publish('pwm', ['fan'], [0.3])
        h.wait_reg(IDS['wheel'], 'goal_velocity', lambda v: v == goal_raw('velocity', 1.0))
        h.wait_reg(IDS['wheel'], 'goal_velocity', lambda v: v == 0)
        h.wait_reg(IDS['fan'], 'goal_pwm', lambda v: v == 0)
        # It cannot fire before the timeout counted from the command (true on any machine).
        assert time.monotonic() - sent_s >= timeout_s
        assert h.reg(IDS['arm'], 'goal_position') == arm_goal   # position goals are kept
        # A fresh command is obeyed again.
        h.publish('velocity', ['wheel'], [0.5])
        h.wait_reg(IDS['wheel'], 'goal_velocity', lambda v: v == goal_raw('velocity', 0.5))


def test_without_command_timeout_goals_stay(h: NodeHarness) -> None:
    assert h.call('set_velocity', name=['wheel'], value=[1.0]).success
    cycles(h, 30)
    assert h.reg(IDS['wheel'], 'goal_velocity') == goal_raw('velocity', 1.0)


def test_runtime_parameters(h: NodeHarness) -> None:
    result = h.set_parameter('loop_rate', 50.0)
    assert result.successful, result.reason
    assert h.node is not None and h.node.get_parameter('loop_rate').value == 50.0
    diag = h.diagnostics.wait(
        lambda d: values_of(d.status[0]).get('loop_rate_requested_hz') == '50', timeout_s=5.0)
    assert diag.status[0].name.endswith('bus sim')
    # The measured rate comes down (a slow machine only makes it lower still).
    h.diagnostics.wait(
        lambda d: float(values_of(d.status[0])['loop_rate_measured_hz']) < 60.0, timeout_s=5.0)
    for value in (0.0, 1e6):
        result = h.set_parameter('loop_rate', value)
        assert not result.successful and result.reason
    assert h.node.get_parameter('loop_rate').value == 50.0
    result = h.set_parameter('port', '/dev/ttyUSB1')
    assert not result.successful and result.reason
    assert h.node.get_parameter('port').value == 'sim'
    result = h.set_parameter('arm.id', 9)
    assert not result.successful and result.reason
    result = h.set_parameter('command_timeout', 0.25)
    assert result.successful, result.reason


def test_parameters_are_described(h: NodeHarness) -> None:
    assert h.node is not None
    descriptor = h.node.describe_parameter('loop_rate')
    assert descriptor.description and not descriptor.read_only
    assert descriptor.floating_point_range[0].from_value > 0.0
    # Read at configure: settable while unconfigured only (see the test below); joints never.
    assert not h.node.describe_parameter('port').read_only
    assert 'Read at configure' in h.node.describe_parameter('port').description
    assert h.node.describe_parameter('joints').read_only
    assert 'address' in h.node.describe_parameter('arm.registers.profile_velocity').description


def test_lifecycle_services_answer(h: NodeHarness) -> None:
    assert h.call('get_state').current_state.label == 'active'


def test_not_active_without_autostart() -> None:
    with NodeHarness(sim_params(JOINTS, autostart=False)) as h:
        assert h.call('get_state').current_state.label == 'unconfigured'
        response = h.call('set_position', name=['arm'], value=[0.5])
        assert not response.success and 'not active' in response.message
        assert h.joint_states.received == 0
        assert h.node is not None and h.sim is None   # the port is not even open
        # What `ros2 lifecycle set` does.
        for transition in (Transition.TRANSITION_CONFIGURE, Transition.TRANSITION_ACTIVATE):
            assert h.call('change_state', transition=Transition(id=transition)).success
        assert h.call('get_state').current_state.label == 'active'
        assert h.call('set_position', name=['arm'], value=[0.5]).success
        assert h.reg(IDS['arm'], 'goal_position') == pos_raw(0.5)
        h.joint_states.wait(lambda m: len(m.name) == len(JOINTS))
        transition = Transition(id=Transition.TRANSITION_DEACTIVATE)
        assert h.call('change_state', transition=transition).success
        assert h.reg(IDS['arm'], 'torque_enable') == 0   # torque_off_on_shutdown
        assert not h.call('set_position', name=['arm'], value=[0.1]).success


def change(h: NodeHarness, transition_id: int) -> bool:
    return bool(h.call('change_state', transition=Transition(id=transition_id)).success)


def test_parameters_set_while_unconfigured_are_used_by_the_next_configure() -> None:
    with NodeHarness(sim_params(JOINTS, autostart=False)) as h:
        assert h.set_parameter('arm.registers.profile_velocity', 77).successful
        assert h.set_parameter('torque_on_start', False).successful
        assert change(h, Transition.TRANSITION_CONFIGURE)
        assert change(h, Transition.TRANSITION_ACTIVATE)
        assert h.reg(IDS['arm'], 'profile_velocity') == 77
        assert h.reg(IDS['arm'], 'torque_enable') == 0
        # While configured they are refused, saying when they can change.
        result = h.set_parameter('arm.registers.profile_velocity', 88)
        assert not result.successful and 'read at configure' in result.reason
        assert not h.set_parameter('joints', ['arm']).successful
        assert change(h, Transition.TRANSITION_DEACTIVATE)
        assert change(h, Transition.TRANSITION_CLEANUP)
        # A bad value is taken as given, and the configure that reads it says what is wrong.
        assert h.set_parameter('arm.registers.profile_velocity', -5).successful
        assert not change(h, Transition.TRANSITION_CONFIGURE)
        assert h.call('get_state').current_state.label == 'unconfigured'
        assert h.set_parameter('arm.registers.profile_velocity', 99).successful
        assert h.set_parameter('torque_on_start', True).successful
        assert change(h, Transition.TRANSITION_CONFIGURE)
        assert change(h, Transition.TRANSITION_ACTIVATE)
        assert h.reg(IDS['arm'], 'profile_velocity') == 99
        assert h.reg(IDS['arm'], 'torque_enable') == 1
        h.joint_states.wait(lambda m: len(m.name) == len(JOINTS))


def test_harness_leaves_no_thread_running() -> None:
    before = set(threading.enumerate())
    h = NodeHarness(sim_params(JOINTS))
    h.joint_states.wait()
    assert len(set(threading.enumerate()) - before) >= 2   # the bus cycle and the executor
    h.close()
    deadline = time.monotonic() + 5.0
    while set(threading.enumerate()) - before and time.monotonic() < deadline:
        time.sleep(0.01)
    assert not set(threading.enumerate()) - before


def test_shutdown_torque_off() -> None:
    h = NodeHarness(sim_params(JOINTS))
    try:
        sim = h.sim
        assert sim.read_register(IDS['arm'], 'torque_enable') == 1
    finally:
        h.close()
    assert all(sim.read_register(sid, 'torque_enable') == 0 for sid in IDS.values())


def test_shutdown_keeps_torque_when_asked() -> None:
    h = NodeHarness(sim_params(JOINTS, torque_off_on_shutdown=False))
    try:
        sim = h.sim
    finally:
        h.close()
    assert all(sim.read_register(sid, 'torque_enable') == 1 for sid in IDS.values())


# invalid configuration -------------------------------------------------------------------

@pytest.mark.parametrize('joints,top,key', [
    ({'a': {'id': 1}, 'b': {'id': 1}}, {}, 'b.id'),
    ({'a': {'id': 300}}, {}, 'a.id'),
    ({'a': {'operating_mode': 'position'}}, {}, 'a.id'),
    ({'a': {'id': 1, 'operating_mode': 'turbo'}}, {}, 'a.operating_mode'),
    ({'a': {'id': 1, 'registers': {'bogus': 1}}}, {}, 'a.registers.bogus'),
    ({'a': {'id': 1, 'registers': {'present_position': 1}}}, {},
     'a.registers.present_position'),
    ({'a': {'id': 1, 'registers': {'profile_velocity': 99999}}}, {},
     'a.registers.profile_velocity'),
    ({'a': {'id': 1}}, {'baud_rate': 12345}, 'baud_rate'),
    ({'a': {'id': 1}}, {'loop_rate': -5.0}, 'loop_rate'),
])
def test_invalid_configuration_names_the_key(joints: Dict[str, Any], top: Dict[str, Any],
                                             key: str) -> None:
    exc = startup_failure(sim_params(joints, **top))
    message = str(exc)
    assert repr(key) in message or key in message, message
    assert '\n' not in message


def test_duplicate_joint_name_refused() -> None:
    params = sim_params({'a': {'id': 1}})
    params['joints'] = ['a', 'a']
    assert 'joints' in str(startup_failure(params))
