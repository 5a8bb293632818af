"""
One simulated servo's control-table memory: EEPROM and RAM, access, ranges, limits, indirection.

The layout is the servo's model's (models.Model; the XM430 manual's model 1030 by default): its
items, its reserved addresses (read 0, a write is an access error), its operating modes (another
value is a data range error) and its indirect banks. Each model's layout is compiled once (Table)
and shared by every servo of that model, with the addresses the servo reads on every packet.

Two ways in:
- get()/set() by name: raw internal access for the physics and the servo's own bookkeeping
  (no access or range checks), the register store protocol of
  present_registers.RegisterStore;
- read()/plan_write()/commit(): what the bus sees, with the manual's checks, raising TableError
  with the status error code.  A write is planned on a copy and committed whole, so a packet with
  any error writes nothing.
"""

import struct
from typing import Callable

from dxl_servo_driver.models import Item, Model, model_for, ModelError, modes
from dxl_servo_driver.models.xm430 import MODEL_NUMBER, MODEL_NUMBERS, TABLE_SIZE
from dxl_servo_driver.protocol import ErrorCode

_FORMATS = {(1, False): '<B', (1, True): '<b', (2, False): '<H', (2, True): '<h',
            (4, False): '<I', (4, True): '<i'}
_U16 = struct.Struct('<H')
# Counted in ms under a time-based Drive Mode (bit 2), 0..32,767 (registers.TIME_PROFILE_MAX_MS).
_TIME_PROFILE = frozenset({'profile_velocity', 'profile_acceleration'})
TIME_PROFILE_MAX_MS = 32_767
# Goal PWM / Goal Current power on at these (EEPROM) limits, where the model has them.
_GOALS_FROM_LIMITS = (('goal_pwm', 'pwm_limit'), ('goal_current', 'current_limit'))
# The XM430 manual's model (1030): a servo's model unless one is given.
MANUAL_MODEL = model_for(MODEL_NUMBER)
# The models whose table is the XM430 manual's (plus later items) and whose physics is its fit.
MANUAL_MODEL_NUMBERS = frozenset(MODEL_NUMBERS)


class _DirectionCodec:
    """struct.Struct's unpack_from/pack_into for a value stored by direction bit or offset."""

    def __init__(self, item: Item) -> None:
        self._item = item
        self.format = f'<{"B" if item.size == 1 else "H"}'

    def unpack_from(self, data: bytes | bytearray, address: int) -> tuple[int]:
        return (self._item.decode(data[address:address + self._item.size]),)

    def pack_into(self, data: bytearray, address: int, value: int) -> None:
        item = self._item
        if item.direction_bit:   # the physics may exceed the magnitude
            value = max(1 - item.direction_bit, min(item.direction_bit - 1, value))
        else:
            top = (1 << (8 * item.size)) - 1
            value = max(-item.raw_zero, min(top - item.raw_zero, value))
        data[address:address + item.size] = item.encode(value)


class _ModeCodec:
    """A mode register read and written as the XM430 manual's Operating Mode values."""

    def __init__(self, item: Item, model: Model) -> None:
        self.address = item.address
        self.format = '<B'
        self._to_manual = {number: modes.BY_NAME[name].number
                           for name, number in model.modes.items()}
        self._to_model = {manual: number for number, manual in self._to_manual.items()}

    def unpack_from(self, data: bytes | bytearray, address: int) -> tuple[int]:
        return (self._to_manual.get(data[address], -1),)

    def pack_into(self, data: bytearray, address: int, value: int) -> None:
        data[address] = self._to_model.get(value, data[address])


class TableError(Exception):
    """A control-table access refused with a status error code."""

    def __init__(self, code: ErrorCode, message: str) -> None:
        super().__init__(message)
        self.code = code


class Table:
    """
    One model's control table laid out for the simulator: built once per model (table_for).

    A bus may hold fifty servos of one model; they share this rather than each building it.
    """

    def __init__(self, model: Model) -> None:
        self.model = model
        # The manual's table reaches 661 (its second indirect bank); its models never end sooner.
        self.size = max(model.table_end, TABLE_SIZE) if model.number in MANUAL_MODEL_NUMBERS \
            else model.table_end
        # What the servo keeps without a register for it (hardware_errors()): after the table,
        # out of the bus's reach.
        self.internal = _internal_items(model, self.size)
        self.memory_size = max((item.address + item.size for item in self.internal),
                               default=self.size)
        items = (*model.items, *self.internal)
        self.by_name: dict[str, Item] = {item.name: item for item in items}
        # address -> the item covering it (None for reserved addresses)
        self.owner: list[Item | None] = [None] * self.size
        for item in model.items:
            for offset in range(item.size):
                self.owner[item.address + offset] = item
        self.structs: dict[str, struct.Struct | _DirectionCodec | _ModeCodec] = {
            item.name: _DirectionCodec(item) if item.direction_bit or item.raw_zero
            else struct.Struct(_FORMATS[(item.size, item.signed)]) for item in items}
        # name -> (unpack_from, address) and (pack_into, address, mask, wrap threshold):
        # get() and set() run tens of times per servo per millisecond.
        self.getters = {item.name: (self.structs[item.name].unpack_from, item.address)
                        for item in items}
        self.setters = {item.name: self._setter(item) for item in items}
        # The X names of registers this table calls otherwise (Model.roles) reach them too.
        for role, own in model.roles.items():
            if own in self.by_name and role not in self.by_name:
                self.by_name[role] = self.by_name[own]
                self.structs[role] = self.structs[own]
                self.getters[role] = self.getters[own]
                self.setters[role] = self.setters[own]
        # The physics counts modes as the XM430 manual does: a mode register of other values
        # (the XL-320's Control Mode, 2 for joint) reads and writes as those by that name.
        register = model.mode_register
        if register and register != 'operating_mode' and register in self.by_name:
            codec = _ModeCodec(self.by_name[register], model)
            self.structs['operating_mode'] = codec
            self.getters['operating_mode'] = (codec.unpack_from, codec.address)
            self.setters['operating_mode'] = (codec.pack_into, codec.address, 0xFF, 0x100)
        # indirect data address -> address of the indirect address item that maps it
        self.indirect: dict[int, int] = {data: address for address, data in model.indirect}
        self.indirect_low = min(self.indirect, default=self.size)
        self.banks = _banks(model.indirect)
        self.valid_modes = frozenset(model.modes.values())
        # In the manual's numbers, as get('operating_mode') gives them on every table.
        self.position_mode = modes.BY_NAME['position'].number if 'position' in model.modes \
            else None
        self.multi_turn_modes = frozenset(
            modes.BY_NAME[name].number for name in ('extended_position', 'current_based_position')
            if name in model.modes)
        self.eeprom = tuple(item for item in items if item.area == 'eeprom')
        # Every RAM byte (the Y has RAM items among its EEPROM ones): a reboot zeroes them.
        self.ram_bytes = tuple(address for item in items if item.area == 'ram'
                               for address in range(item.address, item.address + item.size))
        self.ram_initial = tuple((item.name, item.initial) for item in items
                                 if item.area == 'ram' and item.initial)
        # Where the table powers a goal on at its limit (the X: Goal PWM at PWM Limit), it
        # follows the limit the EEPROM holds; a table that starts it at 0 (the Y) does not.
        self.goals_from_limits = tuple(
            (goal, limit) for goal, limit in _GOALS_FROM_LIMITS
            if goal in self.by_name and limit in self.by_name
            and self.by_name[goal].initial == self.by_name[limit].initial)
        self.homing = self.by_name['homing_offset']
        # The one-byte items read by address on every packet (Memory.raw[address]).
        self.torque_address = self._byte_address('torque_enable')
        self.id_address = self._byte_address('id')
        self.baud_address = self._byte_address('baud_rate')
        self.return_delay_address = self._byte_address('return_delay_time')
        self.status_return_address = self._byte_address('status_return_level')
        self.error_status_address = self._byte_address('hardware_error_status')
        # Hardware Error Status: bit of each error name, and every bit that means something.
        self.error_bits: dict[str, int] = {
            name: bit for bit, name in _error_bits(model).items()}
        self.error_mask = 0
        for bit in _error_bits(model):
            self.error_mask |= bit

    def _byte_address(self, name: str) -> int:
        item = self.by_name[name]
        if item.size != 1:
            raise ValueError(f'{self.model.label}: {name} is {item.size} bytes, not one')
        return item.address

    def _setter(self, item: Item) -> tuple[Callable[..., None], int, int, int]:
        bits = 8 * item.size
        modulus = 1 << bits
        # A direction-bit or offset value wraps as a signed one would; the codec clamps it.
        threshold = 1 << (bits - 1) if item.signed or item.direction_bit or item.raw_zero \
            else modulus
        return self.structs[item.name].pack_into, item.address, modulus - 1, threshold


def _error_bits(model: Model) -> dict[int, str]:
    """
    Return the hardware error bits the simulated servo latches.

    The model's; a table whose errors are not bits (the Y's Error Code) is simulated with the
    XM430 manual's, kept internally (it reports no error code: not modelled).
    """
    return model.hardware_error_bits or dict(MANUAL_MODEL.hardware_error_bits)


# The registers the physics reads (by the XM430 manual's names) that a table may lack, and
# what the simulated servo holds in their place: None is the manual's initial value.
_PHYSICS_REGISTERS: tuple[tuple[str, int | None], ...] = (
    ('hardware_error_status', 0), ('shutdown', None), ('operating_mode', None),
    ('position_p_gain', None), ('position_i_gain', 0), ('position_d_gain', 0),
    ('feedforward_1st_gain', 0), ('feedforward_2nd_gain', 0), ('velocity_p_gain', None),
    ('velocity_i_gain', None), ('goal_pwm', None), ('pwm_limit', None), ('goal_current', 0),
    ('current_limit', 0), ('profile_velocity', 0), ('profile_acceleration', 0),
    ('homing_offset', 0), ('moving_threshold', None), ('moving', 0), ('moving_status', 0),
    ('position_trajectory', 0), ('velocity_trajectory', 0), ('realtime_tick', 0),
    ('present_pwm', 0))


def _internal_items(model: Model, start: int) -> tuple[Item, ...]:
    """
    Return what a servo keeps without a register for it, at start.. (beyond the bus's reach).

    Every servo latches its hardware errors and shuts down on some of them, has a mode, gains
    and limits its physics runs by; a Protocol 1.0 table says its errors only in its status
    packets (its Alarm Shutdown is the shutdown mask, by role) and its mode by its angle limits,
    the Y its errors by an Error Code, the XL-320 has no PWM. The simulator keeps what the
    table lacks here, out of the bus's reach: the manual's values (a gain the table lacks acts
    as the manual's default; the error mask is every error), the servo's own where it has them
    (its PWM full scale).
    """
    mask = 0
    for bit in _error_bits(model):
        mask |= bit
    own = {'shutdown': mask, 'goal_pwm': model.pwm_full_raw, 'pwm_limit': model.pwm_full_raw,
           'operating_mode': modes.BY_NAME['position'].number}
    items = []
    address = start
    for name, value in _PHYSICS_REGISTERS:
        if model.has(name):
            continue
        manual = MANUAL_MODEL.item(name)
        initial = own.get(name, manual.initial if value is None else value)
        area = 'eeprom' if manual.area == 'eeprom' else 'ram'
        items.append(Item(name, address, manual.size, area, 'R', initial, -(1 << 31),
                          (1 << 31) - 1, manual.signed, None, manual.unit,
                          f'(simulator) {manual.description}'))
        address += manual.size
    return tuple(items)


def _banks(pairs: tuple[tuple[int, int], ...]) -> tuple[tuple[int, int, int], ...]:
    """
    Return the indirect banks as (first data address, first address entry, end of the entries).

    A bank is a run of entries 2 bytes apart whose data bytes follow one another (the X430 has
    two: 168.. with data at 224.., and 578.. with data at 634..).
    """
    banks: list[list[int]] = []
    previous: tuple[int, int] | None = None
    for address, data in pairs:
        if previous is not None and address == previous[0] + 2 and data == previous[1] + 1:
            banks[-1][2] = address + 2
        else:
            banks.append([data, address, address + 2])
        previous = (address, data)
    return tuple((data, low, high) for data, low, high in sorted(banks))


# Keyed by the model object: a Table is built once per model, whatever the number of servos.
_TABLES: dict[int, Table] = {}


def table_for(model: Model) -> Table:
    """Return the (shared) simulator table of a model."""
    table = _TABLES.get(id(model))
    if table is None or table.model is not model:
        table = Table(model)
        _TABLES[id(model)] = table
    return table


class Memory:
    """The control table of one servo; EEPROM survives reset_ram(), RAM does not."""

    def __init__(self, model: Model | None = None, firmware_version: int | None = None) -> None:
        table = table_for(MANUAL_MODEL if model is None else model)
        self.table = table
        self.model = table.model
        self._firmware = self._check_firmware(table.model, firmware_version)
        self._getters = table.getters
        self._setters = table.setters
        self._data = bytearray(table.memory_size)
        self._read_plans: dict[tuple[int, int], tuple[bytes, list[tuple[int, int]]]] = {}
        # The table's bytes, for fast reads of 1-byte items by address (never replaced).
        self.raw = self._data
        self.factory_reset()

    @staticmethod
    def _check_firmware(model: Model, firmware_version: int | None) -> int | None:
        if firmware_version is None:
            return None
        if not 0 <= firmware_version <= 255:
            raise ValueError(f'firmware version {firmware_version} outside 0..255')
        # The table must be the one this firmware has, or the servo would lie about its layout.
        try:
            matching = model_for(model.number, firmware_version)
        except ModelError:
            matching = model  # a model outside the catalogue: trust the caller
        if matching.min_firmware != model.min_firmware:
            raise ValueError(f'firmware {firmware_version} has the {matching.label} table, '
                             f'not the {model.label} one')
        return firmware_version

    def has(self, name: str) -> bool:
        """Return whether the model's table has this item."""
        return name in self._getters

    def item(self, name: str) -> Item:
        """Return the model's item with this name (KeyError if it has none)."""
        return self.table.by_name[name]

    # ---- raw access (register store protocol) -------------------------------------------------
    def get(self, name: str) -> int:
        """Return the item's value (signed per the item), without checks."""
        unpack_from, address = self._getters[name]
        return unpack_from(self._data, address)[0]

    def set(self, name: str, value: int) -> None:  # noqa: A003 (register store protocol)
        """Store value (wrapped to the item's size), without checks."""
        pack_into, address, mask, threshold = self._setters[name]
        value = int(value) & mask
        if value >= threshold:
            value -= mask + 1
        pack_into(self._data, address, value)

    def snapshot(self) -> dict[str, int]:
        """Return every item's value by name."""
        data = self._data
        return {name: unpack_from(data, address)[0]
                for name, (unpack_from, address) in self._getters.items()}

    # ---- resets -------------------------------------------------------------------------------
    def factory_reset(self, keep_id: bool = False, keep_baud: bool = False) -> None:
        """Restore the factory EEPROM (optionally keeping id / baud) and the RAM defaults."""
        table = self.table
        data = self._data
        saved_id, saved_baud = data[table.id_address], data[table.baud_address]
        for item in table.eeprom:
            self.set(item.name, item.initial)
        if self._firmware is not None:
            self.set('firmware_version', self._firmware)
        if keep_id:
            data[table.id_address] = saved_id
        if keep_baud:
            data[table.baud_address] = saved_baud
        self.reset_ram()

    def reset_ram(self) -> None:
        """Return every RAM item to its power-on value (reboot, power cycle)."""
        table = self.table
        data = self._data
        for address in table.ram_bytes:
            data[address] = 0
        for name, initial in table.ram_initial:
            self.set(name, initial)
        # Goal PWM / Goal Current power on at the (EEPROM) limits.
        for goal, limit in table.goals_from_limits:
            self.set(goal, self.get(limit))

    # ---- bus access ---------------------------------------------------------------------------
    def target(self, address: int) -> int:
        """Return the address a bus access at address reaches (through its indirect entry)."""
        entry = self.table.indirect.get(address)
        if entry is None:
            return address
        return _U16.unpack_from(self._data, entry)[0] % self.table.size

    def read(self, address: int, length: int) -> bytes:
        """Return length bytes from address, through indirect data; reserved bytes read 0."""
        if length < 1:
            raise TableError(ErrorCode.DATA_LENGTH, 'read length must be at least 1')
        end = address + length
        table = self.table
        if address < 0 or end > table.size:
            raise TableError(ErrorCode.ACCESS, f'read {address}..{end - 1} beyond the table')
        data = self._data
        if end <= table.indirect_low:
            return bytes(data[address:end])
        # A sync read of indirect data runs every cycle: the byte-by-byte resolution is done
        # once per (address, length, mapping) and kept as runs of consecutive source bytes.
        mapping = b''
        for data_low, low, high in table.banks:
            if end > data_low:
                mapping += data[low:high]
        key = (address, length)
        cached = self._read_plans.get(key)
        if cached is None or cached[0] != mapping:
            cached = (mapping, self._plan_read(address, end))
            self._read_plans[key] = cached
        return b''.join([data[start:stop] for start, stop in cached[1]])

    def _plan_read(self, address: int, end: int) -> list[tuple[int, int]]:
        data = self._data
        indirect = self.table.indirect
        size = self.table.size
        runs: list[tuple[int, int]] = []
        for source in range(address, end):
            entry = indirect.get(source)
            if entry is not None:
                # One level of indirection: the target's stored byte.
                source = _U16.unpack_from(data, entry)[0] % size
            if runs and runs[-1][1] == source:
                runs[-1] = (runs[-1][0], source + 1)
            else:
                runs.append((source, source + 1))
        return runs

    def plan_write(self, address: int, payload: bytes) -> tuple[bytearray, frozenset[str]]:
        """
        Check a bus write of payload at address; return the new memory and the items written.

        Order of checks: empty/out of table/reserved byte -> access or length, a multi-byte item
        covered only in part -> data length, read-only or EEPROM while torque is on -> access,
        static range -> data range, dynamic limit -> data limit.
        """
        if not payload:
            raise TableError(ErrorCode.DATA_LENGTH, 'write without data')
        end = address + len(payload)
        table = self.table
        size = table.size
        if address < 0 or end > size:
            raise TableError(ErrorCode.ACCESS, f'write {address}..{end - 1} beyond the table')
        data = self._data
        if end <= table.indirect_low:
            physical = dict(zip(range(address, end), payload))
        else:
            physical = {}
            indirect = table.indirect
            for offset, byte in enumerate(payload):
                target = address + offset
                mapping = indirect.get(target)
                if mapping is not None:
                    target = _U16.unpack_from(data, mapping)[0] % size
                physical[target] = byte
        owner = table.owner
        items: dict[str, Item] = {}
        for target in physical:
            item = owner[target]
            if item is None:
                raise TableError(ErrorCode.ACCESS, f'address {target} is not defined')
            items[item.name] = item
        for item in items.values():
            for target in range(item.address, item.address + item.size):
                if target not in physical:
                    raise TableError(ErrorCode.DATA_LENGTH,
                                     f'{item.name} ({item.size} bytes) written only in part')
        torque_on = data[table.torque_address] != 0
        for item in items.values():
            if item.access != 'RW':
                raise TableError(ErrorCode.ACCESS, f'{item.name} is read-only')
            if item.area == 'eeprom' and torque_on:
                raise TableError(ErrorCode.ACCESS, f'{item.name} is EEPROM, locked by torque')
        new = bytearray(data)
        for target, byte in physical.items():
            new[target] = byte
        structs = table.structs
        timed = self._timed(new, items)
        for name, item in items.items():
            value = structs[name].unpack_from(new, item.address)[0]
            if timed and name in _TIME_PROFILE:
                # Drive Mode bit 2: times in ms, neither a speed's range nor bounded by a limit.
                if not 0 <= value <= TIME_PROFILE_MAX_MS:
                    raise TableError(ErrorCode.DATA_RANGE, f'{name}={value} outside 0..'
                                     f'{TIME_PROFILE_MAX_MS} ms (time-based profile)')
                continue
            if not item.minimum <= value <= item.maximum:
                raise TableError(ErrorCode.DATA_RANGE,
                                 f'{name}={value} outside {item.minimum}..{item.maximum}')
            if name in ('operating_mode', self.model.mode_register) \
                    and value not in table.valid_modes:
                raise TableError(ErrorCode.DATA_RANGE,
                                 f'operating mode {value} does not exist on the '
                                 f'{self.model.name}')
        for name, item in items.items():
            if item.limit is not None and not (timed and name in _TIME_PROFILE):
                self._check_limit(new, item, structs[name].unpack_from(new, item.address)[0])
        homing = table.homing
        ignored = self.model.homing_position_mode_limit
        if (homing.name in items and ignored is not None
                and self._value(new, 'operating_mode') == table.position_mode):
            offset = self._value(new, homing.name)
            if abs(offset) > ignored:
                # Manual: in position mode an invalid homing offset is ignored (not an error).
                stop = homing.address + homing.size
                new[homing.address:stop] = data[homing.address:stop]
        return new, frozenset(items)

    def _timed(self, new: bytearray, items: dict[str, Item]) -> bool:
        """Return whether a write touches the profile registers under a time-based Drive Mode."""
        bit = self.model.time_profile_bit
        if bit is None or not any(name in _TIME_PROFILE for name in items):
            return False
        return bool(self._value(new, 'drive_mode') >> bit & 1)

    def commit(self, new: bytearray) -> None:
        """Install memory returned by plan_write()."""
        self._data[:] = new

    def write(self, address: int, payload: bytes) -> frozenset[str]:
        """Check and commit a bus write; return the names of the items written."""
        new, names = self.plan_write(address, payload)
        self.commit(new)
        return names

    def _value(self, data: bytearray, name: str) -> int:
        unpack_from, address = self._getters[name]
        return unpack_from(data, address)[0]

    def _check_limit(self, new: bytearray, item: Item, value: int) -> None:
        table = self.table
        if item.name == 'goal_position':
            mode = self._value(new, 'operating_mode')
            if mode == table.position_mode:
                low = self._value(new, 'min_position_limit')
                high = self._value(new, 'max_position_limit')
            elif mode in table.multi_turn_modes:
                low = -self.model.extended_position_limit
                high = self.model.extended_position_limit
            else:
                return
        else:
            assert item.limit is not None
            high = self._value(new, item.limit)
            low = -high if item.signed else 0
        if not low <= value <= high:
            raise TableError(ErrorCode.DATA_LIMIT,
                             f'{item.name}={value} outside the limit {low}..{high}')
