"""
The messages the node publishes from the servos' raw state: joint_states and servo_states.

Only fresh samples are published (never a stale or invented value); every value is in SI
units through the servo's own model (models.units).
"""

import math
import struct
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple

from builtin_interfaces.msg import Time
from dxl_servo_driver.driver.manager import (
    IDX_EFFORT, IDX_HW_ERROR, IDX_MOVING, IDX_MOVING_STATUS, IDX_POSITION, IDX_PWM,
    IDX_TEMPERATURE, IDX_TORQUE, IDX_VELOCITY, IDX_VOLTAGE, Servo)
from dxl_servo_driver_msgs.msg import ServoState, ServoStateArray
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState

assert (IDX_POSITION, IDX_VELOCITY, IDX_EFFORT) == (0, 1, 2)   # JointTable reads them so


class _Wire:
    """
    One joint_states layout in CDR (the bytes rmw puts on the wire), with the names in place.

    Publishing a JointState object converts it from Python to C on every publish, which costs
    more than the rest of publishing; the names, counts and paddings never
    change for one set of joints, so they are laid out once and each cycle only packs the stamp
    and three arrays.
    """

    def __init__(self, names: Sequence[str], frame_id: str = '') -> None:
        body = bytearray()

        def align(size: int) -> None:
            body.extend(bytes(-len(body) % size))

        def string(text: str) -> None:
            raw = text.encode()
            align(4)
            body.extend(struct.pack('<I', len(raw) + 1) + raw + b'\0')

        body.extend(bytes(8))   # header.stamp: sec, nanosec
        string(frame_id)
        align(4)
        body.extend(struct.pack('<I', len(names)))
        for name in names:
            string(name)
        self.offsets = []
        for _ in range(3):   # position, velocity, effort
            align(4)
            body.extend(struct.pack('<I', len(names)))
            align(8)
            self.offsets.append(len(_CDR_LE) + len(body))
            body.extend(bytes(8 * len(names)))
        self.buffer = bytearray(_CDR_LE + body)
        self.doubles = struct.Struct(f'<{len(names)}d')

    def pack(self, stamp_ns: int, positions: Sequence[float], velocities: Sequence[float],
             efforts: Sequence[float]) -> bytes:
        """Return the serialized message."""
        buffer = self.buffer
        sec, nanosec = divmod(stamp_ns, 1_000_000_000)
        _STAMP.pack_into(buffer, len(_CDR_LE), sec, nanosec)
        pack_into = self.doubles.pack_into
        pack_into(buffer, self.offsets[0], *positions)
        pack_into(buffer, self.offsets[1], *velocities)
        pack_into(buffer, self.offsets[2], *efforts)
        return bytes(buffer)


_CDR_LE = b'\x00\x01\x00\x00'   # encapsulation: plain CDR, little-endian
_STAMP = struct.Struct('<iI')
_WIRE_LAYOUTS = 16   # sets of fresh joints kept laid out (all fresh is the usual one)


class JointTable:
    """joint_states of a set of servos, with each joint's conversion factors inlined."""

    def __init__(self, servos: Sequence[Servo]) -> None:
        self.names = [servo.name for servo in servos]
        self._msg = JointState()
        # The conversions of models.units as per-joint constants: this runs every cycle.
        # Rebuilt (a new table) once the servos said which model they are.
        # The joint's frame folded in: position = (raw + turns - zero) * scale, zero shifted by
        # the offset (in pulses), scale signed.
        self._rows: List[Tuple[Servo, str, float, float, float, float]] = []
        for servo in servos:
            units = servo.units
            frame = units.frame
            self._rows.append((
                servo, servo.name, units.zero_raw + frame.offset_rad / units.rad_per_pulse,
                units.rad_per_pulse * frame.scale, units.rad_s_per_velocity_raw * frame.scale,
                units.effort_nm_per_raw))
        self._wires: Dict[Tuple[str, ...], _Wire] = {}
        # None until checked against the rmw's own deserialisation (check_wire).
        self.serialize: Optional[bool] = None
        self._all = tuple(self.names)

    def _values(self) -> Tuple[List[str], List[float], List[float], List[float]]:
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
        return names, positions, velocities, efforts

    def fill(self, stamp: Any) -> Any:
        """Return the JointState of the fresh servos (reused message), None if none is."""
        names, positions, velocities, efforts = self._values()
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

    def message(self, stamp_ns: int) -> Any:
        """
        Return what to publish for the fresh servos: CDR bytes, or a JointState; None if none.

        The bytes once check_wire() found the rmw reads them as the message they mean; the
        message object otherwise.
        """
        if not self.serialize:
            return self.fill(time_msg(stamp_ns))
        names, positions, velocities, efforts = self._values()
        if not names:
            return None
        key = self._all if len(names) == len(self._all) else tuple(names)
        wire = self._wires.get(key)
        if wire is None:
            if len(self._wires) >= _WIRE_LAYOUTS:
                self._wires.clear()
            wire = self._wires[key] = _Wire(key)
        return wire.pack(stamp_ns, positions, velocities, efforts)

    def check_wire(self) -> str:
        """
        Check the CDR bytes against the rmw's deserialisation; return '' or what differs.

        Serialisation is the rmw's business: a middleware that lays JointState out otherwise
        gets the message object instead (what differs is said once, by the node).
        """
        names = self.names or ['check']
        count = len(names)
        values = [[float(k) + 0.25 * column for k in range(count)] for column in range(3)]
        stamp_ns = 1_234_567_890_123_456_789
        try:
            msg = deserialize_message(_Wire(names).pack(stamp_ns, *values), JointState)
            problem = ''
            if (list(msg.name) != list(names) or list(msg.position) != values[0]
                    or list(msg.velocity) != values[1] or list(msg.effort) != values[2]
                    or (msg.header.stamp.sec, msg.header.stamp.nanosec)
                    != divmod(stamp_ns, 1_000_000_000) or msg.header.frame_id != ''):
                problem = 'the middleware reads joint_states bytes laid out here differently'
        except Exception as exc:  # noqa: B902 - any failure means: do not use the bytes
            problem = f'the middleware does not take joint_states bytes laid out here ({exc})'
        self.serialize = not problem
        return problem


def time_msg(stamp_ns: int) -> Time:
    """Return a builtin_interfaces/Time of a ROS time in nanoseconds."""
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    return Time(sec=sec, nanosec=nanosec)


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
    msg.position = servo.position_rad(state[IDX_POSITION])
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
