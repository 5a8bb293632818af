"""
The types of the model catalogue: datasheet physics and one model's control table.

Pure data: nothing here talks to a bus.
"""

from dataclasses import dataclass, field
import math

from dxl_servo_driver.errors import ConfigurationError

__all__ = ['datasheet', 'Item', 'Model', 'ModelError', 'Physics', 'TORQUE_MODE', 'VoltagePoint']

# A Protocol 1.0 table's switch into current (torque) control (the MX-64/106's RAM item).
TORQUE_MODE = 'torque_ctrl_mode_enable'


@dataclass(frozen=True)
class Item:
    """One control-table item: where it is, its size, access, values and unit."""

    name: str            # the manual's name in snake_case
    address: int
    size: int            # bytes
    area: str            # 'eeprom' or 'ram'
    access: str          # 'R' or 'RW'
    initial: int
    minimum: int
    maximum: int
    signed: bool
    limit: str | None    # the register that bounds it at run time (a data limit error)
    unit: str
    description: str
    # Present Speed / Load of the older tables: this bit is the direction (CW), the bits below
    # it the magnitude; 0 for a plain (two's complement or unsigned) value.
    direction_bit: int = 0
    # The raw value that means 0, for a register stored with an offset rather than a sign
    # (Current of the MX-64/106 on Protocol 1.0: 2,048 is no current); the decoded value is
    # raw - raw_zero, and minimum/maximum are decoded values. 0 for every other register.
    # Whoever reads the raw bytes without decode() (a struct over a block) must subtract it.
    raw_zero: int = 0

    def __post_init__(self) -> None:
        if self.direction_bit and self.raw_zero:
            raise ValueError(f'{self.name}: a direction bit and an offset zero exclude '
                             'each other')
        if self.raw_zero and self.signed:
            raise ValueError(f'{self.name}: an offset zero is stored unsigned')

    def decode(self, data: bytes | bytearray) -> int:
        """Return the value of the item's bytes (little-endian; the direction bit as a sign)."""
        if self.direction_bit:
            raw = int.from_bytes(data, 'little')
            magnitude = raw & (self.direction_bit - 1)
            return -magnitude if raw & self.direction_bit else magnitude
        if self.raw_zero:
            return int.from_bytes(data, 'little') - self.raw_zero
        return int.from_bytes(data, 'little', signed=self.signed)

    def encode(self, value: int) -> bytes:
        """Return the item's bytes holding value (OverflowError when it does not fit)."""
        if self.direction_bit:
            if abs(value) >= self.direction_bit:
                raise OverflowError(f'{self.name}: {value} outside its magnitude')
            value = (self.direction_bit | -value) if value < 0 else value
            return value.to_bytes(self.size, 'little')
        if self.raw_zero:
            return (value + self.raw_zero).to_bytes(self.size, 'little')
        return value.to_bytes(self.size, 'little', signed=self.signed)


class ModelError(ConfigurationError):
    """A model number, name or firmware the catalogue does not support."""


@dataclass(frozen=True)
class VoltagePoint:
    """One supply voltage of the datasheet: stall torque and current, no-load speed."""

    voltage_v: float
    stall_torque_nm: float
    stall_current_a: float
    no_load_speed_rpm: float

    @property
    def torque_constant_nm_per_a(self) -> float:
        """Return stall torque over stall current (output shaft, gearbox included)."""
        return self.stall_torque_nm / self.stall_current_a


@dataclass(frozen=True)
class Physics:
    """Datasheet figures of one model: gear ratio and the published voltage points."""

    gear_ratio: float
    nominal_voltage_v: float
    points: tuple[VoltagePoint, ...]
    source: str

    @property
    def nominal(self) -> VoltagePoint:
        """Return the point at the recommended voltage."""
        for point in self.points:
            if math.isclose(point.voltage_v, self.nominal_voltage_v):
                return point
        raise ModelError(f'no datasheet point at the nominal {self.nominal_voltage_v} V')

    def at(self, voltage_v: float) -> VoltagePoint:
        """
        Return the figures at a supply voltage.

        Linear between the published points; outside them the nearest point is returned
        unchanged, since the datasheet says nothing about voltages it does not list.
        """
        points = self.points
        if voltage_v <= points[0].voltage_v:
            return points[0]
        if voltage_v >= points[-1].voltage_v:
            return points[-1]
        for low, high in zip(points, points[1:]):
            if low.voltage_v <= voltage_v <= high.voltage_v:
                t = (voltage_v - low.voltage_v) / (high.voltage_v - low.voltage_v)
                return VoltagePoint(
                    voltage_v,
                    low.stall_torque_nm + t * (high.stall_torque_nm - low.stall_torque_nm),
                    low.stall_current_a + t * (high.stall_current_a - low.stall_current_a),
                    low.no_load_speed_rpm
                    + t * (high.no_load_speed_rpm - low.no_load_speed_rpm))
        raise AssertionError('unreachable: the points are sorted by voltage')


@dataclass(frozen=True)
class Model:
    """One supported model (and firmware range): control table, units, modes, physics."""

    number: int
    name: str
    family: str
    items: tuple[Item, ...]
    modes: dict[str, int] = field(hash=False)
    bauds: dict[int, int] = field(hash=False)
    current_unit_a: float | None
    load_unit_ratio: float | None
    velocity_unit_rpm: float
    # Pulses per output revolution. Not whole where the encoder spans less than a turn
    # (1,024 pulses over 300 degrees: 1,228.8 per revolution).
    pulses_per_rev: float
    position_zero_raw: int
    pwm_full_raw: int
    voltage_unit_v: float
    indirect: tuple[tuple[int, int], ...]
    hardware_error_bits: dict[int, str] = field(hash=False)
    physics: Physics
    min_firmware: int = 0
    fast_sync_read_firmware: int | None = None
    # The XM430 manual's name of a register -> this table's own name for it (an older manual
    # says Present Speed): the driver and the simulator ask by the first, users see the second.
    roles: dict[str, str] = field(default_factory=dict, hash=False)
    # One Profile Acceleration unit (the XM430 manual: 214.577 rev/min^2).
    acceleration_unit_rpm2: float = 214.577
    # Goal Position's range in the multi-turn modes (the XM430 manual: +-256 turns).
    extended_position_limit: int = 1_048_575
    # Position mode ignores a Homing Offset beyond this (the XM430 manual); None: no such rule.
    homing_position_mode_limit: int | None = 1024
    # The protocol the model speaks out of the box (an X servo may be switched to 1.0
    # through Protocol Type (13); the driver speaks 2.0 to it).
    protocol: float = 2.0
    # The register that selects the mode: 'operating_mode', 'control_mode' (XL-320, 1 wheel
    # 2 joint), or '' where the mode follows from the CW/CCW angle limits (Protocol 1.0:
    # both 0 is wheel mode, both 4095 multi-turn on the MX).
    mode_register: str = 'operating_mode'
    # The first RAM address: items below it are EEPROM, written only with torque off (64
    # on the X and MX, 512 on the P, PRO(A), RH-P12-RN and Y, 24 on Protocol 1.0 tables).
    # The Y states an area per item: below 512 some are RAM, and Item.area is what counts.
    eeprom_end: int = 64
    # Whether the servo answers BULK_READ (0x92): every Protocol 2.0 model; on Protocol 1.0
    # only the MX and the EX-106+ (not the AX, RX and DX).
    bulk_read: bool = True
    # Whether the servo answers REBOOT (0x08): every Protocol 2.0 model; no Protocol 1.0
    # one (the 1.0 instruction set has no REBOOT: clear an alarm shutdown by writing Torque
    # Limit again, or by a power cycle).
    reboot: bool = True
    # Max/Min Voltage Limit's unit where it is not voltage_unit_v (Present Input Voltage's):
    # the Y reads its input in 0.01 V and limits it in 0.1 V. None: the same unit.
    limit_voltage_unit_v: float | None = None
    # The Drive Mode bit that makes Profile Velocity and Profile Acceleration times in ms
    # (bit 2 on the X, the MX(2.0), the P and PRO(A): the e-manual's time-based profile);
    # None where there is none (the Y times its profiles in registers of their own).
    time_profile_bit: int | None = None
    _by_name: dict[str, Item] = field(
        init=False, repr=False, compare=False, hash=False, default_factory=dict)
    _by_address: dict[int, Item] = field(
        init=False, repr=False, compare=False, hash=False, default_factory=dict)

    def __post_init__(self) -> None:
        # Frozen: the lookup maps are filled once, here, through object.__setattr__'s
        # back door rather than rebuilt on every lookup.
        object.__setattr__(self, '_by_name', {item.name: item for item in self.items})
        object.__setattr__(self, '_by_address', {item.address: item for item in self.items})

    @property
    def label(self) -> str:
        """Return 'NAME (model N)' plus the firmware range when the table depends on it."""
        text = f'{self.name} (model {self.number}'
        if self.min_firmware:
            text += f', firmware {self.min_firmware}+'
        return text + ')'

    @property
    def reverse_bit(self) -> int | None:
        """Return the Drive Mode bit that reverses the direction (bit 0), None: no Drive Mode."""
        return 0 if self.has('drive_mode') else None

    def has_fast_sync_read(self, firmware: int) -> bool:
        """Return whether this model at this firmware answers Fast Sync Read (0x8A)."""
        first = self.fast_sync_read_firmware
        return first is not None and firmware >= first

    def item(self, name: str) -> Item:
        """Return the item with this snake_case name (or the one playing its role)."""
        found = self._by_name.get(name)
        if found is None:
            found = self._by_name.get(self.roles.get(name, ''))
            if found is None:
                raise KeyError(f'{self.label} has no control-table item named {name!r}')
        return found

    def has(self, name: str) -> bool:
        """Return whether the table has an item with this name (or one playing its role)."""
        return name in self._by_name or self.roles.get(name, '') in self._by_name

    def by_address(self, address: int) -> Item:
        """Return the item starting at this address."""
        try:
            return self._by_address[address]
        except KeyError:
            raise KeyError(
                f'{self.label} has no control-table item starting at address {address!r}'
            ) from None

    def role_of(self, name: str) -> str:
        """Return the XM430 manual's name of the item this table calls name (or name)."""
        for role, own in self.roles.items():
            if own == name:
                return role
        return name

    def lookup(self, key: str | int) -> Item:
        """Return the item with this name or start address."""
        if isinstance(key, str):
            return self.item(key)
        return self.by_address(key)

    @property
    def voltage_limit_unit_v(self) -> float:
        """Return the unit of Max/Min Voltage Limit in volts."""
        if self.limit_voltage_unit_v is None:
            return self.voltage_unit_v
        return self.limit_voltage_unit_v

    @property
    def table_end(self) -> int:
        """Return one past the last byte of the table."""
        return max(item.address + item.size for item in self.items)

    @property
    def stall_torque_nm(self) -> float:
        """Return the stall torque at the nominal voltage."""
        return self.physics.nominal.stall_torque_nm

    @property
    def torque_constant_nm_per_a(self) -> float:
        """Return stall torque over stall current at the nominal voltage."""
        return self.physics.nominal.torque_constant_nm_per_a

    def angle_limit_mode(self, low: int, high: int, torque_mode: int = 0) -> str:
        """
        Return the mode a Protocol 1.0 table's CW/CCW Angle Limits (low, high) select.

        Torque Ctrl Mode Enable set (torque_mode; the MX-64/106): current, whatever the limits.
        Both 0: wheel (velocity) mode; both at the top of their range: multi-turn (the MX's
        extended_position); anything else: joint (position) mode within them.
        """
        if torque_mode and 'current' in self.modes:
            return 'current'
        if low == high == 0 and 'velocity' in self.modes:
            return 'velocity'
        if (low == high == self.item('max_position_limit').maximum
                and 'extended_position' in self.modes):
            return 'extended_position'
        return 'position'

    def decode_hardware_errors(self, status: int) -> list[str]:
        """Return the names of the bits set in a Hardware Error Status value."""
        return [name for bit, name in self.hardware_error_bits.items() if status & bit]


def datasheet(gear_ratio: float, nominal_voltage_v: float,
              rows: tuple[tuple[float, float, float, float], ...], source: str) -> Physics:
    """Return Physics from (volts, stall N*m, stall A, no-load rpm) rows in any order."""
    points = tuple(VoltagePoint(*row) for row in sorted(rows))
    return Physics(gear_ratio, nominal_voltage_v, points, source)
