"""
Building control tables from a shared base: removals, additions and per-item overrides.

Every family starts from the XM430 manual's layout (models.xm430.ITEMS) and states only how it
differs, so the numbers the families share live in one place.
"""

from dataclasses import dataclass, replace
from typing import Any, Iterable, Mapping, TypeAlias

from dxl_servo_driver.models.base import Item

EEPROM_END = 64  # addresses 0..63 are EEPROM (written only with torque off), 64.. RAM
U8 = 0xFF
FIRST_RAM_ADDRESS = EEPROM_END  # indirect addresses may point anywhere in RAM only

# A value an override may set on an Item field.
Value: TypeAlias = int | str | bool | None
Overrides: TypeAlias = Mapping[str, Mapping[str, Value]]


def item(name: str, address: int, size: int, access: str, initial: int, minimum: int,
         maximum: int, *, signed: bool = False, limit: str | None = None, unit: str = '',
         description: str = '', eeprom_end: int = EEPROM_END, direction_bit: int = 0,
         raw_zero: int = 0) -> Item:
    """
    Return an Item, its area derived from the address.

    EEPROM below eeprom_end (64 on the X: the default), RAM from it on.
    """
    area = 'eeprom' if address < eeprom_end else 'ram'
    return Item(name, address, size, area, access, initial, minimum, maximum, signed, limit,
                unit, description, direction_bit, raw_zero)


@dataclass(frozen=True)
class ItemMaker:
    """
    How one family writes its items: where its RAM begins and its direction bit, said once.

    Each family module makes one (`_item = ItemMaker(eeprom_end=512)`) and lists its items
    with it in the manual's order of columns: name, address, size, access, initial, minimum,
    maximum, then keywords. `direction=True` marks an item whose top bit is a sign (the older
    tables' Present Speed); `area` states an item's area where the family does so item by
    item (the Y) instead of by address.
    """

    eeprom_end: int = EEPROM_END
    direction_bit: int = 0

    def __call__(self, name: str, address: int, size: int, access: str, initial: int,
                 minimum: int, maximum: int, *, signed: bool = False, limit: str | None = None,
                 unit: str = '', description: str = '', direction: bool = False,
                 raw_zero: int = 0, area: str | None = None) -> Item:
        """Return the Item, its area from its address unless given."""
        if direction and not self.direction_bit:
            raise ValueError(f'{name}: this family has no direction bit')
        made = item(name, address, size, access, initial, minimum, maximum, signed=signed,
                    limit=limit, unit=unit, description=description,
                    eeprom_end=self.eeprom_end,
                    direction_bit=self.direction_bit if direction else 0, raw_zero=raw_zero)
        return made if area is None else replace(made, area=area)

    def identity(self, number: int) -> list[Item]:
        """Return the Protocol 2.0 tables' first items: Model Number, Information, Firmware."""
        return [
            self('model_number', 0, 2, 'R', number, 0, 0xFFFF, description='Model Number'),
            self('model_information', 2, 4, 'R', 0, 0, 0xFFFFFFFF,
                 description='Model Information'),
            # '-' in the e-manual for the PRO families: the simulator reports 0.
            self('firmware_version', 6, 1, 'R', 0, 0, 0xFF, description='Firmware Version'),
        ]


def build(base: Iterable[Item], *, remove: Iterable[str] = (), add: Iterable[Item] = (),
          override: Overrides | None = None) -> tuple[Item, ...]:
    """
    Return base without `remove`, plus `add`, with `override` applied, sorted by address.

    Naming an item that is not there (or adding one twice) raises ValueError at import
    time, so a typo in a family's differences cannot slip through as a silent no-op.
    """
    items = {existing.name: existing for existing in base}
    for name in remove:
        if name not in items:
            raise ValueError(f'cannot remove {name!r}: not in the layout')
        del items[name]
    for new in add:
        if new.name in items:
            raise ValueError(f'cannot add {new.name!r}: already in the layout')
        items[new.name] = new
    for name, changes in (override or {}).items():
        if name not in items:
            raise ValueError(f'cannot override {name!r}: not in the layout')
        # Any: the dataclass plugin types each field of replace(); the values were
        # typed as Value when the overrides were written.
        fields: dict[str, Any] = dict(changes)
        items[name] = replace(items[name], **fields)
    return tuple(sorted(items.values(), key=lambda each: each.address))


def indirect_pairs(*banks: tuple[int, int, int]) -> tuple[tuple[int, int], ...]:
    """
    Return (address of Indirect Address n, address of Indirect Data n) for n = 1, 2, ...

    Each bank is (first address entry, first data entry, count): addresses are 2 bytes
    apart, data 1 byte apart, and numbering continues from one bank to the next.
    """
    pairs: list[tuple[int, int]] = []
    for first_address, first_data, count in banks:
        pairs.extend((first_address + 2 * n, first_data + n) for n in range(count))
    return tuple(pairs)


def indirect_items(pairs: tuple[tuple[int, int], ...], last_ram_address: int, *,
                   first_ram_address: int = FIRST_RAM_ADDRESS,
                   eeprom_end: int = EEPROM_END) -> list[Item]:
    """
    Return the indirect_address_N / indirect_data_N items for these pairs.

    Each address entry powers on pointing at its own data byte (the e-manual's initial
    values) and accepts any RAM address from first_ram_address up to last_ram_address (the
    X defaults: 64 on; the P series 512..1,023). Their areas follow eeprom_end: the P
    series keeps its address entries in EEPROM.
    """
    items: list[Item] = []
    for number, (address, data) in enumerate(pairs, start=1):
        items.append(item(
            f'indirect_address_{number}', address, 2, 'RW', data, first_ram_address,
            last_ram_address, eeprom_end=eeprom_end,
            description=f'Indirect Address {number} '
                        f'(RAM address {first_ram_address}..{last_ram_address})'))
        items.append(item(f'indirect_data_{number}', data, 1, 'RW', 0, 0, U8,
                          eeprom_end=eeprom_end, description=f'Indirect Data {number}'))
    return items


def is_indirect(name: str) -> bool:
    """Return whether this is one of the indirect_address_N / indirect_data_N items."""
    return name.startswith(('indirect_address_', 'indirect_data_'))
