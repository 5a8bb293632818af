"""
A full-turn joint's limits of +-pi: the servo's ends, not a refused start.

Through the joint's frame pi is servo position 2048 + 2048 = 4096, one tick beyond the 0..4095
of Max Position Limit; the official stacks take it as the servo's end. Within a tick the driver
does too, and says so in the log; a limit farther out is still refused at configure.
"""

import math

from dxl_servo_driver.config import validate
from dxl_servo_driver.driver.manager import ManagerError
from manager_rig import params, Rig, XM430_UNITS
import pytest

TICK = 2.0 * math.pi / 4096


def full_turn(low: float, high: float) -> dict:
    return params(**{'arm.min_position': low, 'arm.max_position': high})


def test_a_limit_of_pi_is_the_servos_end_and_two_ticks_beyond_is_refused() -> None:
    rig = Rig()
    manager = rig.manager(validate(full_turn(-math.pi, math.pi)))
    manager.configure()
    manager.activate()
    assert (rig.reg(1, 'min_position_limit'), rig.reg(1, 'max_position_limit')) == (0, 4095)
    notes = [line for line in rig.logs if 'one tick beyond' in line]
    assert notes == ["joint 'arm': max_position 3.14159 is servo position 4096, one tick beyond "
                     'the 0..4095 of max_position_limit: taken as its end, 4095']
    # A goal at the limit is taken (the servo's end), not refused.
    result = manager.command('position', ['arm'], [math.pi])
    assert result.success, result.message
    manager.close()
    # One tick more, two beyond 4095: refused at configure.
    rig = Rig()
    high = math.pi + TICK   # pi is 4096 already: one more tick is two beyond 4095
    assert XM430_UNITS.position_from_rad(high) == 4097
    manager = rig.manager(validate(full_turn(-math.pi, high)))
    with pytest.raises(ManagerError, match=r'max_position 3\.14313 is servo position 4097, '
                                           r'beyond the 0\.\.4095 of max_position_limit'):
        manager.configure()
    manager.close()
    # Two ticks below 0 likewise.
    rig = Rig()
    manager = rig.manager(validate(full_turn(-math.pi - 2 * TICK, 1.0)))
    with pytest.raises(ManagerError, match='servo position -2, beyond the 0..4095 of '
                                           'min_position_limit'):
        manager.configure()
    manager.close()
