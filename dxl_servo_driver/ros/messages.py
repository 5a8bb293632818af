"""
The messages the node publishes from the servos' raw state: joint_states and servo_states.

Only fresh samples are published (never a stale or invented value); every value is in SI
units through the servo's own model (models.units).
"""

import math
from typing import Any, List, Mapping, Optional, Sequence, Tuple

from dxl_servo_driver.manager import (
    IDX_EFFORT, IDX_HW_ERROR, IDX_MOVING, IDX_MOVING_STATUS, IDX_POSITION, IDX_PWM,
    IDX_TEMPERATURE, IDX_TORQUE, IDX_VELOCITY, IDX_VOLTAGE, Servo)
from dxl_servo_driver_msgs.msg import ServoState, ServoStateArray
from sensor_msgs.msg import JointState

assert (IDX_POSITION, IDX_VELOCITY, IDX_EFFORT) == (0, 1, 2)   # JointTable reads them so


class JointTable:
    """joint_states of a set of servos, with each joint's conversion factors inlined."""

    def __init__(self, servos: Sequence[Servo]) -> None:
        self.names = [servo.name for servo in servos]
        self._msg = JointState()
        # The conversions of models.units as per-joint constants: this runs every cycle.
        # Rebuilt (a new table) once the servos said which model they are.
        self._rows: List[Tuple[Servo, str, int, float, float, float]] = [
            (servo, servo.name, servo.units.zero_raw, servo.units.rad_per_pulse,
             servo.units.rad_s_per_velocity_raw, servo.units.effort_nm_per_raw)
            for servo in servos]

    def fill(self, stamp: Any) -> Any:
        """Return the JointState of the fresh servos (reused message), None if none is."""
        names = []
        positions = []
        velocities = []
        efforts = []
        for servo, name, zero, rad_per_pulse, rad_s, nm_per_raw in self._rows:
            state = servo.state
            if not servo.fresh or state is None:
                continue   # never a stale or invented value
            names.append(name)
            positions.append((state[0] + servo.turn_offset - zero) * rad_per_pulse)
            velocities.append(state[1] * rad_s)
            efforts.append(state[2] * nm_per_raw)
        if not names:
            return None   # nobody answered: nothing to say (and never a stale value)
        if len(names) == len(self.names):
            names = self.names
        msg = self._msg
        msg.header.stamp = stamp
        msg.name = names
        msg.position = positions
        msg.velocity = velocities
        msg.effort = efforts
        return msg


def servo_state(servo: Servo, grasping: bool = False) -> ServoState:
    """Return one servo's ServoState (NaN for what is not known)."""
    msg = ServoState()
    msg.name = servo.name
    msg.id = servo.servo_id
    msg.model_number = servo.model_number
    msg.model = servo.model.name
    msg.grasping = grasping
    msg.firmware_version = servo.firmware_version
    msg.operating_mode = servo.mode
    msg.comm_errors = min(servo.comm_errors, 2 ** 32 - 1)
    state = servo.state
    if state is None or not servo.fresh:
        # Not answering: no stale values here either (comm_errors says why).
        for attr in ('position', 'velocity', 'current', 'pwm', 'input_voltage', 'temperature'):
            setattr(msg, attr, math.nan)
        return msg
    units = servo.units
    msg.position = units.position_to_rad(state[IDX_POSITION] + servo.turn_offset)
    msg.velocity = units.velocity_to_rad_s(state[IDX_VELOCITY])
    # NaN on a model that senses no current (its effort comes from Present Load).
    msg.current = (units.current_to_a(state[IDX_EFFORT])
                   if units.effort_register == 'present_current' else math.nan)
    if not servo.health_time:
        msg.pwm = msg.input_voltage = msg.temperature = math.nan
        return msg
    msg.torque_enabled = bool(state[IDX_TORQUE])
    # NaN where the model's state block has no room for it (an X330 before firmware 53).
    msg.pwm = units.pwm_to_ratio(state[IDX_PWM]) if servo.block.has_pwm else math.nan
    msg.input_voltage = units.voltage_to_v(state[IDX_VOLTAGE])
    msg.temperature = float(state[IDX_TEMPERATURE])
    msg.moving = bool(state[IDX_MOVING])
    msg.moving_status = state[IDX_MOVING_STATUS]
    msg.hardware_error_status = state[IDX_HW_ERROR]
    msg.hardware_errors = servo.model.decode_hardware_errors(state[IDX_HW_ERROR])
    return msg


def servo_states(servos: Sequence[Servo], stamp: Any,
                 grasping: Optional[Mapping[str, bool]] = None) -> ServoStateArray:
    """Return the ServoStateArray of every configured servo."""
    msg = ServoStateArray()
    msg.header.stamp = stamp
    held = grasping or {}
    msg.servos = [servo_state(servo, held.get(servo.name, False)) for servo in servos]
    return msg
