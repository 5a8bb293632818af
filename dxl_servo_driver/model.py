"""
The servo model: SI conversions, operating modes, the packed state block, bus timing.

Pure data and arithmetic over the seed's control table (control_table.py); no I/O, no ROS, no SDK.
Every conversion comes as a pair (raw -> SI, SI -> raw) so the two can never drift apart.
"""

from dataclasses import dataclass
import math
import struct
from typing import Callable, Mapping, Optional

from dxl_servo_driver import control_table as ct

# Units of the seed (REP 103 on the ROS side).
PULSES_PER_REV = 4096
POSITION_ZERO_RAW = 2048                       # raw 2048 = 0 rad (the horn's centre)
RAD_PER_PULSE = 2.0 * math.pi / PULSES_PER_REV
RAD_S_PER_VELOCITY_RAW = 0.229 * 2.0 * math.pi / 60.0   # 0.229 rpm per unit
A_PER_CURRENT_RAW = 2.69e-3                    # 2.69 mA per unit
PWM_RAW_FULL = 885                             # 885 = 100 % duty
V_PER_VOLTAGE_RAW = 0.1
# Seed datasheet: 4.1 N·m stall torque at 2.3 A (12 V).
DEFAULT_TORQUE_CONSTANT_NM_PER_A = 4.1 / 2.3


def position_to_rad(raw: int) -> float:
    """Return a position register value (pulses) in radians."""
    return (raw - POSITION_ZERO_RAW) * RAD_PER_PULSE


def position_from_rad(rad: float) -> int:
    """Return the position register value (pulses) nearest to an angle in radians."""
    return int(round(rad / RAD_PER_PULSE)) + POSITION_ZERO_RAW


def velocity_to_rad_s(raw: int) -> float:
    """Return a velocity register value (0.229 rpm units) in rad/s."""
    return raw * RAD_S_PER_VELOCITY_RAW


def velocity_from_rad_s(rad_s: float) -> int:
    """Return the velocity register value nearest to a velocity in rad/s."""
    return int(round(rad_s / RAD_S_PER_VELOCITY_RAW))


def current_to_a(raw: int) -> float:
    """Return a current register value (2.69 mA units) in amperes."""
    return raw * A_PER_CURRENT_RAW


def current_from_a(amps: float) -> int:
    """Return the current register value nearest to a current in amperes."""
    return int(round(amps / A_PER_CURRENT_RAW))


def pwm_to_ratio(raw: int) -> float:
    """Return a PWM register value as a ratio of full output (-1..1)."""
    return raw / PWM_RAW_FULL


def pwm_from_ratio(ratio: float) -> int:
    """Return the PWM register value nearest to a ratio of full output."""
    return int(round(ratio * PWM_RAW_FULL))


def voltage_to_v(raw: int) -> float:
    """Return a voltage register value (0.1 V units) in volts."""
    return raw * V_PER_VOLTAGE_RAW


def voltage_from_v(volts: float) -> int:
    """Return the voltage register value nearest to a voltage."""
    return int(round(volts / V_PER_VOLTAGE_RAW))


def reinit_position(present_raw: int, homing_offset: int) -> int:
    """
    Return Present Position after the servo re-initialises it (torque on, mode change, CLEAR).

    The seed: it becomes the position within one turn (0..4095) plus the Homing Offset.
    """
    return (present_raw - homing_offset) % PULSES_PER_REV + homing_offset


def kept_turns(before_raw: int, after_raw: int) -> int:
    """Return the whole turns (in pulses) a re-initialisation took from before_raw."""
    return int(round((before_raw - after_raw) / PULSES_PER_REV)) * PULSES_PER_REV


@dataclass(frozen=True)
class CommandKind:
    """One kind of goal a joint accepts: its register, SI unit and conversions."""

    name: str
    register: str
    unit: str
    to_raw: Callable[[float], int]
    to_si: Callable[[int], float]


COMMAND_KINDS: dict[str, CommandKind] = {
    'position': CommandKind('position', 'goal_position', 'rad', position_from_rad,
                            position_to_rad),
    'velocity': CommandKind('velocity', 'goal_velocity', 'rad/s', velocity_from_rad_s,
                            velocity_to_rad_s),
    'current': CommandKind('current', 'goal_current', 'A', current_from_a, current_to_a),
    'pwm': CommandKind('pwm', 'goal_pwm', 'ratio', pwm_from_ratio, pwm_to_ratio),
}

MODE_NAMES: dict[int, str] = {value: name for name, value in ct.OPERATING_MODES.items()}
POSITION_MODES = frozenset({'position', 'extended_position', 'current_based_position'})

# Which command kinds drive a joint in each mode (SPEC section 2, Topics). In current-based
# position mode the current goal is the current limit of the position controller.
MODE_COMMANDS: dict[str, frozenset[str]] = {
    'current': frozenset({'current'}),
    'velocity': frozenset({'velocity'}),
    'position': frozenset({'position'}),
    'extended_position': frozenset({'position'}),
    'current_based_position': frozenset({'position', 'current'}),
    'pwm': frozenset({'pwm'}),
}

# What a mode change resets on the servo (seed, Operating Mode note 1): the driver re-applies the
# configured values of these after every mode switch.
MODE_CHANGE_RESETS = (
    'profile_velocity', 'profile_acceleration', 'goal_pwm', 'goal_current',
    'velocity_i_gain', 'velocity_p_gain', 'position_d_gain', 'position_i_gain',
    'position_p_gain', 'feedforward_2nd_gain', 'feedforward_1st_gain',
)

# Registers the driver manages itself; a configuration may not set them.
DRIVER_OWNED = frozenset(
    # status_return_level: the driver needs status packets, and the state block's restart
    # canary is that register.
    {'torque_enable', 'operating_mode', 'id', 'baud_rate', 'goal_position', 'goal_velocity',
     'status_return_level'}
    | {f'indirect_address_{n}' for n in range(1, ct.INDIRECT_COUNT + 1)}
    | {f'indirect_data_{n}' for n in range(1, ct.INDIRECT_COUNT + 1)})


# Registers a configuration or write_register may never set, and why.
REFUSED_REGISTERS: dict[str, str] = {
    'protocol_version': 'the driver speaks Protocol 2.0 only: 1 would switch the servo to '
                        'Protocol 1.0, after which it no longer answers the driver',
}


def writable_register(name: str, runtime: bool = False) -> ct.Item:
    """Return the item a configuration (or write_register) may write, or raise ValueError."""
    try:
        item = ct.BY_NAME[name]
    except KeyError:
        raise ValueError(f'unknown register {name!r} (not in the control table)') from None
    if item.access != 'RW':
        raise ValueError(f'register {name!r} is read-only')
    if name in REFUSED_REGISTERS:
        raise ValueError(f'register {name!r} cannot be written: {REFUSED_REGISTERS[name]}')
    if name in DRIVER_OWNED:
        if runtime:
            raise ValueError(f'{name} is managed by the driver: use the set_torque / '
                             'set_operating_mode / command interfaces')
        raise ValueError(f'register {name!r} is managed by the driver and cannot be configured')
    return item


# value register -> the register that bounds it: the servo refuses a value beyond it (data
# limit error), so the driver refuses it first, from a file or at run time alike.
_BOUNDED_BY = {'profile_velocity': 'velocity_limit', 'profile_acceleration': 'acceleration_limit',
               'goal_pwm': 'pwm_limit', 'goal_current': 'current_limit'}
# (low, high) pairs that must stay ordered.
_ORDERED = (('min_position_limit', 'max_position_limit'),
            ('min_voltage_limit', 'max_voltage_limit'))


def related_registers(name: str) -> tuple[str, ...]:
    """Return the registers whose values check_register_set needs to judge a write of name."""
    related: list[str] = []
    if name in _BOUNDED_BY:
        related.append(_BOUNDED_BY[name])
    for low, high in _ORDERED:
        if name == low:
            related.append(high)
        elif name == high:
            related.append(low)
    return tuple(related)


def check_register_set(values: Mapping[str, int], name: str, value: int, mode: str) -> None:
    """
    Raise ValueError when setting name to value contradicts the servo's other registers.

    values holds the current values of (at least) related_registers(name); mode is the joint's
    operating mode. The one rule book for parameter files and write_register.
    """
    bound = _BOUNDED_BY.get(name)
    if bound is not None and abs(value) > values[bound]:
        raise ValueError(f'{name} {value} exceeds {bound} ({values[bound]})')
    for low, high in _ORDERED:
        if name == low and value > values[high]:
            raise ValueError(f'{low} {value} is above {high} ({values[high]})')
        if name == high and value < values[low]:
            raise ValueError(f'{high} {value} is below {low} ({values[low]})')
    if (name == 'homing_offset' and mode == 'position'
            and abs(value) > ct.HOMING_OFFSET_POSITION_MODE_LIMIT):
        raise ValueError('position mode ignores a homing offset beyond +-1024 (the manual); '
                         'use extended_position for larger offsets')


def check_range(item: ct.Item, value: int) -> None:
    """Raise ValueError when a raw value is outside the item's static range."""
    if not item.minimum <= value <= item.maximum:
        unit = f' {item.unit}' if item.unit else ''
        raise ValueError(f'{value} is outside the range of {item.name}: '
                         f'{item.minimum}..{item.maximum}{unit}')


@dataclass(frozen=True)
class BlockField:
    """One register inside the packed state block."""

    name: str
    offset: int
    size: int


class StateBlock:
    """
    The state of one servo, packed through indirect addresses.

    The registers below are scattered over the table (64, 68, 70, 120..146); mapping them to
    consecutive indirect data bytes lets one sync read fetch all of them from every servo.
    The block has three parts. The motion part (position, velocity, current: the same 10 bytes
    any control loop reads) is read every cycle. The Realtime Tick follows it: the cycle reads it
    too (the tagged read) while the bus is suspicious, to date every sample (TickClock). The
    health part after it (a canary, pwm, voltage, temperature, moving, errors, torque) comes
    only when diagnostics or servo_states need it, by reading the whole block in that cycle's one
    sync read instead.

    The canary maps status_return_level, which the driver never sets to 0: after a reboot or a
    power cut the indirect addresses return to their defaults and the whole block reads 0. A
    motion part of all zeros is therefore checked against the canary before anything is
    published: that is how the driver notices a servo that restarted on its own.
    """

    FIELDS: tuple[tuple[str, str], ...] = (
        ('present_position', 'i'),
        ('present_velocity', 'i'),
        ('present_current', 'h'),
        # the tag
        ('realtime_tick', 'H'),
        # health part
        ('status_return_level', 'B'),
        ('present_pwm', 'h'),
        ('present_input_voltage', 'H'),
        ('present_temperature', 'B'),
        ('moving', 'B'),
        ('moving_status', 'B'),
        ('hardware_error_status', 'B'),
        ('torque_enable', 'B'),
    )
    MOTION_FIELDS = 3
    TAGGED_FIELDS = 4
    FIRST_INDIRECT = 1

    def __init__(self) -> None:
        self.names: tuple[str, ...] = tuple(name for name, _ in self.FIELDS)
        self.struct = struct.Struct('<' + ''.join(code for _, code in self.FIELDS))
        self.size: int = self.struct.size
        self.motion_struct = struct.Struct(
            '<' + ''.join(code for _, code in self.FIELDS[:self.MOTION_FIELDS]))
        self.motion_size: int = self.motion_struct.size
        self.tagged_struct = struct.Struct(
            '<' + ''.join(code for _, code in self.FIELDS[:self.TAGGED_FIELDS]))
        self.tagged_size: int = self.tagged_struct.size
        fields = []
        offset = 0
        for name, _ in self.FIELDS:
            item = ct.BY_NAME[name]
            fields.append(BlockField(name, offset, item.size))
            offset += item.size
        self.fields: tuple[BlockField, ...] = tuple(fields)
        assert offset == self.size, 'struct codes disagree with the control table sizes'
        self.index: dict[str, int] = {name: i for i, name in enumerate(self.names)}
        self.read_address: int = ct.indirect_data_address(self.FIRST_INDIRECT)
        self.canary_index: int = self.index['status_return_level']
        self.tick_index: int = self.index['realtime_tick']

    def indirect_map(self) -> list[int]:
        """Return the target address of each indirect byte, in order (one per block byte)."""
        targets: list[int] = []
        for field in self.fields:
            base = ct.BY_NAME[field.name].address
            targets.extend(base + k for k in range(field.size))
        return targets

    def indirect_map_bytes(self) -> bytes:
        """Return the data of one WRITE to indirect_address_1.. that sets up the whole block."""
        return b''.join(struct.pack('<H', address) for address in self.indirect_map())

    def indirect_map_address(self) -> int:
        """Return the address of the first indirect address register the block uses."""
        return ct.indirect_address_address(self.FIRST_INDIRECT)

    def decode(self, data: bytes, offset: int = 0) -> tuple[int, ...]:
        """Return the block's raw values, in FIELDS order."""
        return self.struct.unpack_from(data, offset)

    def decode_motion(self, data: bytes, offset: int = 0) -> tuple[int, ...]:
        """Return the raw values of the motion part (the first MOTION_FIELDS fields)."""
        return self.motion_struct.unpack_from(data, offset)

    def decode_tagged(self, data: bytes, offset: int = 0) -> tuple[int, ...]:
        """Return the raw values of the motion part and the tick (TAGGED_FIELDS fields)."""
        return self.tagged_struct.unpack_from(data, offset)

    def decoder(self, length: int) -> 'Callable[[bytes], tuple[int, ...]]':
        """Return the decoder of a read of length bytes (motion, tagged or whole)."""
        if length == self.size:
            return self.decode
        if length == self.tagged_size:
            return self.decode_tagged
        if length == self.motion_size:
            return self.decode_motion
        raise ValueError(f'no state block part is {length} bytes long')

    def restarted(self, values: tuple[int, ...]) -> bool:
        """Return True when the values show the indirect mapping was lost (servo restarted)."""
        return values[self.canary_index] == 0


STATE_BLOCK = StateBlock()

TICK_PERIOD_MS = 32768   # Realtime Tick counts milliseconds and wraps after 32767


def _wrap_ms(value: float) -> float:
    """Return value folded into [-TICK_PERIOD_MS / 2, TICK_PERIOD_MS / 2)."""
    half = TICK_PERIOD_MS / 2
    return (value + half) % TICK_PERIOD_MS - half


class TickClock:
    """
    Date a servo's samples by its Realtime Tick and refuse those older than their request.

    A status packet carries no sequence number, so a late reply of an earlier identical request
    looks like the answer to this one. The servo's tick does tell when the sample was taken.
    Tick and host clock differ by an unknown offset c = tick - t_host (ms). A reply to a request
    sent at s and received at r was sampled at some t in [s, r], so tick - r <= c: the largest
    (tick - r) seen is a lower bound of c (a late reply only lowers tick - r, so it can never
    raise the bound). A sample whose tick is below s + bound by more than tolerance_ms was taken
    before its request went out: it answers an earlier request. The bound is relaxed by
    drift_ppm between samples, for the two clocks' crystals.
    """

    def __init__(self, tolerance_ms: float = 2.0, drift_ppm: float = 300.0) -> None:
        self.tolerance_ms = tolerance_ms
        self.drift = drift_ppm * 1e-6
        self._bound_ms: Optional[float] = None
        self._bound_at_ms = 0.0
        self.refused = 0

    def reset(self) -> None:
        """Forget the offset (the servo restarted: its tick started again from 0)."""
        self._bound_ms = None

    def check(self, tick: int, sent_s: float, received_s: float) -> bool:
        """Return False when the sample was taken before sent_s; learn from it otherwise."""
        sent_ms = sent_s * 1000.0
        received_ms = received_s * 1000.0
        bound = self._bound_ms
        if bound is None:
            self._bound_ms = _wrap_ms(tick - received_ms)
            self._bound_at_ms = received_ms
            return True
        bound -= self.drift * max(0.0, received_ms - self._bound_at_ms)
        age_ms = _wrap_ms(bound - (tick - sent_ms))
        if age_ms > self.tolerance_ms:
            self.refused += 1
            return False
        rise = _wrap_ms((tick - received_ms) - bound)
        if rise > 0.0:
            bound += rise
        self._bound_ms = _wrap_ms(bound)
        self._bound_at_ms = received_ms
        return True


# Protocol 2.0 framing sizes, for bus timing.
STATUS_OVERHEAD_BYTES = 11       # header 4, id, length 2, instruction, error, crc 2
INSTRUCTION_OVERHEAD_BYTES = 10  # header 4, id, length 2, instruction, crc 2
BITS_PER_BYTE = 10               # 8N1: start + 8 data + stop


def sync_read_bytes(n_servos: int, data_length: int) -> int:
    """Return the bytes on the wire of one sync read (instruction + every status packet)."""
    instruction = INSTRUCTION_OVERHEAD_BYTES + 4 + n_servos
    return instruction + n_servos * (STATUS_OVERHEAD_BYTES + data_length)


def sync_write_bytes(n_servos: int, data_length: int) -> int:
    """Return the bytes on the wire of one sync write."""
    return INSTRUCTION_OVERHEAD_BYTES + 4 + n_servos * (1 + data_length)


@dataclass(frozen=True)
class BusBudget:
    """What one cycle costs on the wire and the rate the bus can sustain."""

    bytes_per_cycle: int
    wire_time_s: float
    return_delay_s: float
    latency_s: float

    @property
    def cycle_time_s(self) -> float:
        """Return the shortest possible cycle."""
        return self.wire_time_s + self.return_delay_s + self.latency_s

    @property
    def rate_limit_hz(self) -> float:
        """Return the highest loop rate the bus can carry."""
        return 1.0 / self.cycle_time_s


def bus_budget(n_servos: int, baud_bps: int, return_delay_time_raw: int = 0,
               latency_timer_s: float = 0.0, read_length: Optional[int] = None,
               write_length: int = 4) -> BusBudget:
    """
    Return the cost of one cycle: a sync read of the state block and one sync write of goals.

    Each servo waits its Return Delay Time (2 us per unit) before answering; the USB adapter's
    latency timer holds the replies once per cycle before the host sees them.
    """
    length = STATE_BLOCK.motion_size if read_length is None else read_length
    total = sync_read_bytes(n_servos, length) + sync_write_bytes(n_servos, write_length)
    return BusBudget(
        bytes_per_cycle=total,
        wire_time_s=total * BITS_PER_BYTE / baud_bps,
        return_delay_s=n_servos * return_delay_time_raw * 2e-6,
        latency_s=latency_timer_s)
