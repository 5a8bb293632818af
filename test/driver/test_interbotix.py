"""
An arm set up the way its maker's software sets it up: Interbotix's WidowX-250s.

Interbotix run the arm in time-based profiles (Drive Mode bit 2, Profile Velocity 2000 ms,
Profile Acceleration 300 ms), its shoulder and elbow on two servos each, the second ("shadow")
mounted mirrored and reversed in firmware (Drive Mode bit 0), and the waist's URDF limits at
+-pi. Expressed in this driver's file, that setup must start and behave on the simulator as on
the arm: a move takes the profile's time (judged by the servo's own Realtime Tick and Position
Trajectory, not the wall clock), the shadow's horn turns against the primary's while both count
the joint's way, and write_register judges profile_velocity as the time it is.
"""

import time
from typing import Any, Dict, Iterator, List, Tuple

from dxl_servo_driver.models import model_for
from dxl_servo_driver.models.units import units_for
from dxl_servo_driver.tool.yaml_edit import parameters_of
from node_harness import NodeHarness, startup_failure
import pytest

XM430 = units_for(model_for(1030))
WAIST, SHOULDER, SHADOW, WRIST, GRIPPER = 1, 2, 3, 8, 9
# The arm's motor registers and the time profile of its arm group, from Interbotix's wx250s
# configuration; the shadow's Drive Mode is its own 1 (reversed) with the group's bit 2.
WIDOWX = """
/**:
  ros__parameters:
    port: sim
    baud_rate: 1000000
    latency_timer: 1.0
    joints: [waist, shoulder, wrist_rotate, gripper]
    waist:
      id: 1
      min_position: -3.141592653589793
      max_position: 3.141592653589793
      registers: {drive_mode: 4, profile_velocity: 2000, profile_acceleration: 300,
                  velocity_limit: 131, return_delay_time: 0}
    shoulder:
      id: 2
      min_position: -1.88
      max_position: 1.99
      secondary_id: 3
      registers: {drive_mode: 4, profile_velocity: 2000, profile_acceleration: 300,
                  velocity_limit: 131, return_delay_time: 0}
      secondary_registers: {drive_mode: 5}
    wrist_rotate:
      id: 8
      model: XL430-W250
      registers: {drive_mode: 4, profile_velocity: 2000, profile_acceleration: 300,
                  velocity_limit: 131, return_delay_time: 0}
    gripper:
      id: 9
      registers: {return_delay_time: 0}
"""
PROFILE_MS, RISE_MS = 2000, 300


def widowx(**changes: Any) -> Dict[str, Any]:
    params = parameters_of(WIDOWX)
    params.update(changes)
    return params


@pytest.fixture(scope='module')
def h() -> Iterator[NodeHarness]:
    with NodeHarness(widowx()) as harness:
        harness.joint_states.wait(lambda m: len(m.name) == 4)
        yield harness


def snapshot(h: NodeHarness, servo_id: int, *names: str) -> List[int]:
    """Return registers of one servo at one moment of its own clock."""
    sim = h.sim
    with sim.lock:   # no packet moves it meanwhile
        servo = sim.servo(servo_id)
        servo.advance(time.monotonic())
        return [servo.memory.get(name) for name in names]


def test_the_file_is_taken_as_the_arm_takes_it(h: NodeHarness) -> None:
    for servo_id in (WAIST, SHOULDER, WRIST):
        assert h.reg(servo_id, 'drive_mode') == 4
        assert h.reg(servo_id, 'profile_velocity') == PROFILE_MS
        assert h.reg(servo_id, 'profile_acceleration') == RISE_MS
    assert h.reg(SHADOW, 'drive_mode') == 5   # its own, over the joint's 4
    assert h.reg(SHADOW, 'profile_velocity') == PROFILE_MS
    # The waist's +-pi are the ends of the servo's range.
    assert (h.reg(WAIST, 'min_position_limit'), h.reg(WAIST, 'max_position_limit')) == (0, 4095)


def test_a_move_takes_the_profiles_time(h: NodeHarness) -> None:
    start = h.reg(WAIST, 'present_position')
    goal = start + 1000
    h.publish('position', ['waist'], [XM430.position_to_rad(goal)])
    # Sampled at one moment each (tick, trajectory, velocity): in the cruise the trajectory is
    # a straight line whose slope says the time of the move, 2000 ms, whatever the polling.
    cruise: List[Tuple[int, int]] = []
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline:
        tick, trajectory, status = snapshot(h, WAIST, 'realtime_tick', 'position_trajectory',
                                            'moving_status')
        if status & 0x02 and 0.2 * 1000 < trajectory - start < 0.8 * 1000:
            cruise.append((tick, trajectory))
        if not status & 0x02 and h.reg(WAIST, 'goal_position') == goal:
            break
        time.sleep(0.01)
    assert len(cruise) >= 2, f'too few samples in the cruise: {cruise}'
    (t0, p0), (t1, p1) = cruise[0], cruise[-1]
    ticks = (t1 - t0) % 32768
    assert ticks >= 200, f'the cruise samples are {ticks} ms apart: too close to judge'
    speed = (p1 - p0) / ticks   # pulses per ms
    # A time-based trapezoid covers its distance at cruise speed in (t3 - t1).
    total_ms = RISE_MS + 1000 / speed
    print(f'cruise {speed:.4f} pulse/ms over {ticks} ticks: a move of {total_ms:.0f} ms')
    assert total_ms == pytest.approx(PROFILE_MS, rel=0.02)
    # The profile is trapezoidal (Moving Status 0x30) and ends at the goal.
    h.wait_reg(WAIST, 'present_position', lambda raw: abs(raw - goal) <= 3, timeout_s=10.0)
    assert h.reg(WAIST, 'moving_status') & 0x30 == 0x30
    h.joint_states.wait(lambda m: abs(m.position[0] - XM430.position_to_rad(goal)) < 0.01)


def test_the_firmware_reversed_shadow_counts_with_the_joint(h: NodeHarness) -> None:
    h.publish('position', ['shoulder'], [0.5])
    h.wait_reg(SHOULDER, 'present_position',
               lambda raw: abs(XM430.position_to_rad(raw) - 0.5) < 0.01, timeout_s=10.0)
    h.wait_reg(SHADOW, 'present_position',
               lambda raw: abs(XM430.position_to_rad(raw) - 0.5) < 0.01, timeout_s=5.0)
    # Both were sent the same goal: the shadow's firmware mirrors it, not the driver.
    assert h.reg(SHADOW, 'goal_position') == h.reg(SHOULDER, 'goal_position')
    # Its horn turned the other way: mirrored about the middle of the turn.
    first = h.sim.servo(SHOULDER).dynamics.physical_position_pulse
    second = h.sim.servo(SHADOW).dynamics.physical_position_pulse
    assert first - 2048 == pytest.approx(XM430.position_from_rad(0.5) - 2048, abs=20)
    assert first + second == pytest.approx(4096, abs=20)
    # The joint reads right, the pair agrees, both still hold.
    h.joint_states.wait(lambda m: abs(m.position[1] - 0.5) < 0.01)
    assert h.node is not None
    assert h.node.manager.pairs.apart['shoulder'] < 0.05
    assert h.reg(SHOULDER, 'torque_enable') == h.reg(SHADOW, 'torque_enable') == 1


def test_write_register_judges_profile_velocity_by_drive_mode(h: NodeHarness) -> None:
    ok = h.call('write_register', name='waist', register_name='profile_velocity', value=3000)
    assert ok.success, ok.message
    assert h.reg(WAIST, 'profile_velocity') == 3000
    too_long = h.call('write_register', name='waist', register_name='profile_velocity',
                      value=40000)
    assert not too_long.success
    assert '0..32767' in too_long.message
    half = h.call('write_register', name='waist', register_name='profile_acceleration',
                  value=1600)
    assert not half.success
    assert 'more than half of profile_velocity 3000 ms' in half.message
    # The XL430's Velocity Limit (131) does not bound a time.
    assert h.call('write_register', name='wrist_rotate', register_name='profile_velocity',
                  value=2500).success
    # A velocity-based servo (the gripper, Drive Mode 0) still counts a speed.
    speed = h.call('write_register', name='gripper', register_name='profile_velocity',
                   value=2000)
    assert not speed.success
    assert 'drive_mode 0: a velocity-based profile' in speed.message
    assert h.reg(GRIPPER, 'profile_velocity') == 0
    assert h.call('write_register', name='waist', register_name='profile_velocity',
                  value=PROFILE_MS).success
    # Clearing bit 2 would make the waist's 2000 ms a speed beyond its range: refused first.
    flip = h.call('write_register', name='waist', register_name='drive_mode', value=0)
    assert not flip.success
    assert '2000 is outside the range of profile_velocity: 0..1023' in flip.message
    assert h.reg(WAIST, 'drive_mode') == 4


def test_a_shadow_left_velocity_based_is_refused_with_the_reason() -> None:
    # Drive Mode 1 alone: the shadow would take the joint's 2000 as a speed.
    failure = startup_failure(widowx(**{'shoulder.secondary_registers.drive_mode': 1}))
    message = str(failure)
    assert "'shoulder.registers.profile_velocity'" in message
    assert 'on the second servo (id 3)' in message
    assert 'drive_mode 1: a velocity-based profile' in message
