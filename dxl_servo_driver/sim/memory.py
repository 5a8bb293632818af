"""
One simulated servo's control-table memory: EEPROM and RAM, access, ranges, limits, indirection.

Two ways in:
- get()/set() by name: raw internal access for the physics and the servo's own bookkeeping
  (no access or range checks), the register store protocol of interfaces.md;
- read()/plan_write()/commit(): what the bus sees, with the manual's checks, raising TableError
  with the status error code.  A write is planned on a copy and committed whole, so a packet with
  any error writes nothing.
"""

import struct

from dxl_servo_driver.control_table import (
    BY_NAME, EEPROM_END, EXTENDED_POSITION_LIMIT, HOMING_OFFSET_POSITION_MODE_LIMIT,
    indirect_address_address, INDIRECT_COUNT, indirect_data_address, Item, ITEMS,
    OPERATING_MODES, TABLE_SIZE)
from dxl_servo_driver.protocol import ErrorCode

_FORMATS = {(1, False): '<B', (1, True): '<b', (2, False): '<H', (2, True): '<h',
            (4, False): '<I', (4, True): '<i'}
_VALID_MODES = frozenset(OPERATING_MODES.values())
_POSITION_MODE = OPERATING_MODES['position']
_MULTI_TURN_MODES = frozenset((OPERATING_MODES['extended_position'],
                               OPERATING_MODES['current_based_position']))


class TableError(Exception):
    """A control-table access refused with a status error code."""

    def __init__(self, code: ErrorCode, message: str) -> None:
        super().__init__(message)
        self.code = code


# address -> the item covering it (None for reserved addresses)
_OWNER: list[Item | None] = [None] * TABLE_SIZE
for _item in ITEMS:
    for _offset in range(_item.size):
        _OWNER[_item.address + _offset] = _item
# indirect data address -> address of the indirect address item that maps it
_INDIRECT_DATA_TO_ADDRESS: dict[int, int] = {
    indirect_data_address(n): indirect_address_address(n) for n in range(1, INDIRECT_COUNT + 1)}
_INDIRECT_DATA_LOW = min(_INDIRECT_DATA_TO_ADDRESS)
_STRUCTS: dict[str, struct.Struct] = {
    item.name: struct.Struct(_FORMATS[(item.size, item.signed)]) for item in ITEMS}
_U16 = struct.Struct('<H')
# The indirect address registers (bank 1: 168..223, bank 2: 578..633) and bank 2's data.
_INDIRECT_MAP_LOW, _INDIRECT_MAP_HIGH = indirect_address_address(1), indirect_data_address(1)
_UPPER_MAP_LOW = indirect_address_address(29)
_UPPER_MAP_HIGH = indirect_data_address(29)
_UPPER_BANK_LOW = indirect_data_address(29)
# name -> (unpack_from, address): get() runs tens of times per servo per millisecond.
_GETTERS = {item.name: (_STRUCTS[item.name].unpack_from, item.address) for item in ITEMS}


class Memory:
    """The control table of one servo; EEPROM survives reset_ram(), RAM does not."""

    def __init__(self) -> None:
        self._data = bytearray(TABLE_SIZE)
        self._read_plans: dict[tuple[int, int], tuple[bytes, list[tuple[int, int]]]] = {}
        # The table's bytes, for fast reads of 1-byte items by address (never replaced).
        self.raw = self._data
        self.factory_reset()

    # ---- raw access (register store protocol) -------------------------------------------------
    def get(self, name: str) -> int:
        """Return the item's value (signed per the item), without checks."""
        unpack_from, address = _GETTERS[name]
        return unpack_from(self._data, address)[0]

    def set(self, name: str, value: int) -> None:  # noqa: A003 (register store protocol)
        """Store value (wrapped to the item's size), without checks."""
        item = BY_NAME[name]
        bits = 8 * item.size
        value = int(value) & ((1 << bits) - 1)
        if item.signed and value >= 1 << (bits - 1):
            value -= 1 << bits
        _STRUCTS[name].pack_into(self._data, item.address, value)

    def snapshot(self) -> dict[str, int]:
        """Return every item's value by name."""
        data = self._data
        return {item.name: _STRUCTS[item.name].unpack_from(data, item.address)[0]
                for item in ITEMS}

    # ---- resets -------------------------------------------------------------------------------
    def factory_reset(self, keep_id: bool = False, keep_baud: bool = False) -> None:
        """Restore the factory EEPROM (optionally keeping id / baud) and the RAM defaults."""
        saved_id, saved_baud = self._data[7], self._data[8]
        for item in ITEMS:
            if item.area == 'eeprom':
                self.set(item.name, item.initial)
        if keep_id:
            self._data[7] = saved_id
        if keep_baud:
            self._data[8] = saved_baud
        self.reset_ram()

    def reset_ram(self) -> None:
        """Return every RAM item to its power-on value (reboot, power cycle)."""
        self._data[EEPROM_END:] = bytes(TABLE_SIZE - EEPROM_END)
        for item in ITEMS:
            if item.area == 'ram' and item.initial:
                self.set(item.name, item.initial)
        # Goal PWM / Goal Current power on at the (EEPROM) limits.
        self.set('goal_pwm', self.get('pwm_limit'))
        self.set('goal_current', self.get('current_limit'))

    # ---- bus access ---------------------------------------------------------------------------
    def read(self, address: int, length: int) -> bytes:
        """Return length bytes from address, through indirect data; reserved bytes read 0."""
        if length < 1:
            raise TableError(ErrorCode.DATA_LENGTH, 'read length must be at least 1')
        end = address + length
        if address < 0 or end > TABLE_SIZE:
            raise TableError(ErrorCode.ACCESS, f'read {address}..{end - 1} beyond the table')
        data = self._data
        if end <= _INDIRECT_DATA_LOW:
            return bytes(data[address:end])
        # A sync read of indirect data runs every cycle: the byte-by-byte resolution is done
        # once per (address, length, mapping) and kept as runs of consecutive source bytes.
        mapping = bytes(data[_INDIRECT_MAP_LOW:_INDIRECT_MAP_HIGH])
        if end > _UPPER_BANK_LOW:
            mapping += bytes(data[_UPPER_MAP_LOW:_UPPER_MAP_HIGH])
        key = (address, length)
        cached = self._read_plans.get(key)
        if cached is None or cached[0] != mapping:
            cached = (mapping, self._plan_read(address, end))
            self._read_plans[key] = cached
        return b''.join([data[start:stop] for start, stop in cached[1]])

    def _plan_read(self, address: int, end: int) -> list[tuple[int, int]]:
        data = self._data
        runs: list[tuple[int, int]] = []
        for source in range(address, end):
            indirect = _INDIRECT_DATA_TO_ADDRESS.get(source)
            if indirect is not None:
                # One level of indirection: the target's stored byte.
                source = _U16.unpack_from(data, indirect)[0] % TABLE_SIZE
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
        if address < 0 or end > TABLE_SIZE:
            raise TableError(ErrorCode.ACCESS, f'write {address}..{end - 1} beyond the table')
        data = self._data
        if end <= _INDIRECT_DATA_LOW:
            physical = dict(zip(range(address, end), payload))
        else:
            physical = {}
            for offset, byte in enumerate(payload):
                target = address + offset
                mapping = _INDIRECT_DATA_TO_ADDRESS.get(target)
                if mapping is not None:
                    target = _U16.unpack_from(data, mapping)[0] % TABLE_SIZE
                physical[target] = byte
        items: dict[str, Item] = {}
        for target in physical:
            item = _OWNER[target]
            if item is None:
                raise TableError(ErrorCode.ACCESS, f'address {target} is not defined')
            items[item.name] = item
        for item in items.values():
            for target in range(item.address, item.address + item.size):
                if target not in physical:
                    raise TableError(ErrorCode.DATA_LENGTH,
                                     f'{item.name} ({item.size} bytes) written only in part')
        torque_on = data[64] != 0
        for item in items.values():
            if item.access != 'RW':
                raise TableError(ErrorCode.ACCESS, f'{item.name} is read-only')
            if item.area == 'eeprom' and torque_on:
                raise TableError(ErrorCode.ACCESS, f'{item.name} is EEPROM, locked by torque')
        new = bytearray(data)
        for target, byte in physical.items():
            new[target] = byte
        for name, item in items.items():
            value = _STRUCTS[name].unpack_from(new, item.address)[0]
            if not item.minimum <= value <= item.maximum:
                raise TableError(ErrorCode.DATA_RANGE,
                                 f'{name}={value} outside {item.minimum}..{item.maximum}')
            if name == 'operating_mode' and value not in _VALID_MODES:
                raise TableError(ErrorCode.DATA_RANGE, f'operating mode {value} does not exist')
        for name, item in items.items():
            if item.limit is not None:
                self._check_limit(new, item, _STRUCTS[name].unpack_from(new, item.address)[0])
        if 'homing_offset' in items and self._value(new, 'operating_mode') == _POSITION_MODE:
            offset = self._value(new, 'homing_offset')
            if abs(offset) > HOMING_OFFSET_POSITION_MODE_LIMIT:
                # Manual: in position mode an invalid homing offset is ignored (not an error).
                new[20:24] = data[20:24]
        return new, frozenset(items)

    def commit(self, new: bytearray) -> None:
        """Install memory returned by plan_write()."""
        self._data[:] = new

    def write(self, address: int, payload: bytes) -> frozenset[str]:
        """Check and commit a bus write; return the names of the items written."""
        new, names = self.plan_write(address, payload)
        self.commit(new)
        return names

    @staticmethod
    def _value(data: bytearray, name: str) -> int:
        return _STRUCTS[name].unpack_from(data, BY_NAME[name].address)[0]

    def _check_limit(self, new: bytearray, item: Item, value: int) -> None:
        if item.name == 'goal_position':
            mode = self._value(new, 'operating_mode')
            if mode == _POSITION_MODE:
                low = self._value(new, 'min_position_limit')
                high = self._value(new, 'max_position_limit')
            elif mode in _MULTI_TURN_MODES:
                low, high = -EXTENDED_POSITION_LIMIT, EXTENDED_POSITION_LIMIT
            else:
                return
        else:
            assert item.limit is not None
            high = self._value(new, item.limit)
            low = -high if item.signed else 0
        if not low <= value <= high:
            raise TableError(ErrorCode.DATA_LIMIT,
                             f'{item.name}={value} outside the limit {low}..{high}')
