"""
Files setting a time-based profile (Drive Mode bit 2) and a second servo's own registers.

Under bit 2 Profile Velocity and Profile Acceleration are times in ms (0..32,767, the
acceleration at most half the move, the e-manual), not speeds bounded by Velocity Limit;
without it they are speeds as before. Judged before the bus is touched, each refusal naming the
key and why.
"""

from typing import Any, Dict

from dxl_servo_driver.config import ConfigError, validate
import pytest

TIMED = {'drive_mode': 4, 'profile_velocity': 2000, 'profile_acceleration': 300,
         'velocity_limit': 131}


def one_joint(model: str = '', **registers: int) -> Dict[str, Any]:
    params: Dict[str, Any] = {'port': 'sim', 'joints': ['arm'], 'arm.id': 1}
    if model:
        params['arm.model'] = model
    params.update({f'arm.registers.{name}': value for name, value in registers.items()})
    return params


@pytest.mark.parametrize('model', ['', 'XM430-W350', 'XL430-W250', 'MX-64(2.0)'])
def test_a_time_based_profile_is_accepted(model: str) -> None:
    joint = validate(one_joint(model, **TIMED)).joint('arm')
    assert dict(joint.registers)['profile_velocity'] == 2000
    # Profile Velocity 0 is the step profile: the half rule has nothing to judge.
    validate(one_joint(model, **{**TIMED, 'profile_velocity': 0}))


@pytest.mark.parametrize('model, change, key, reason', [
    # The XM430 manual's table: 0..1023 as a speed.
    ('', {'drive_mode': 0}, 'profile_velocity',
     '2000 is outside the range of profile_velocity: 0..1023 0.229 rpm (drive_mode 0: a '
     'velocity-based profile; drive_mode bit 2 makes it a time, 0..32767 ms)'),
    # An XL430's Velocity Limit bounds a speed.
    ('XL430-W250', {'drive_mode': 1}, 'profile_velocity',
     'profile_velocity 2000 exceeds velocity_limit (131) (drive_mode 1: a velocity-based '
     'profile)'),
    ('XL430-W250', {'profile_acceleration': 1001}, 'profile_acceleration',
     'profile_acceleration 1001 ms is more than half of profile_velocity 2000 ms'),
    ('', {'profile_velocity': 32768}, 'profile_velocity',
     '32768 is outside the range of profile_velocity: 0..32767'),
])
def test_a_profile_wrong_for_its_drive_mode_is_refused(model: str, change: Dict[str, int],
                                                       key: str, reason: str) -> None:
    with pytest.raises(ConfigError) as refused:
        validate(one_joint(model, **{**TIMED, **change}))
    assert refused.value.key == f'arm.registers.{key}'
    assert reason in str(refused.value)


def pair(**extra: Any) -> Dict[str, Any]:
    params = one_joint(**TIMED)
    params.update({'arm.secondary_id': 2, **extra})
    return params


def test_the_second_servo_gets_its_own_registers_over_the_joints() -> None:
    joint = validate(pair(**{'arm.secondary_registers.drive_mode': 5})).joint('arm')
    assert dict(joint.registers)['drive_mode'] == 4
    second = dict(joint.secondary().registers)
    assert second == {**TIMED, 'drive_mode': 5}


@pytest.mark.parametrize('extra, key, reason', [
    ({'arm.secondary_registers.drive_mode': 1}, 'arm.registers.profile_velocity',
     'on the second servo (id 2): 2000 is outside the range of profile_velocity'),
    ({'arm.secondary_registers.drive_mode': 99}, 'arm.secondary_registers.drive_mode',
     'on the second servo (id 2): 99 is outside the range of drive_mode'),
    ({'arm.secondary_registers.torque_enable': 1}, 'arm.secondary_registers.torque_enable',
     'managed by the driver'),
    ({'arm.max_position': 1.0, 'arm.secondary_registers.max_position_limit': 3000},
     'arm.secondary_registers.max_position_limit', 'give the limits once'),
])
def test_the_second_servos_registers_are_judged(extra: Dict[str, Any], key: str,
                                                reason: str) -> None:
    with pytest.raises(ConfigError) as refused:
        validate(pair(**extra))
    assert refused.value.key == key
    assert reason in str(refused.value)


def test_second_servo_registers_need_a_second_servo() -> None:
    params = one_joint(**TIMED)
    params['arm.secondary_registers.drive_mode'] = 5
    with pytest.raises(ConfigError, match='only a joint with a arm.secondary_id has this') as e:
        validate(params)
    assert e.value.key == 'arm.secondary_registers.drive_mode'
