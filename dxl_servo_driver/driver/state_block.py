"""
The packed state block, the goal slot and what one cycle costs on the wire.

Where each model's state lives in its indirect entries (one sync read fetches every servo's
block), the goal slot after it (one sync write carries every joint's goals whatever its mode),
and the bytes and time of one cycle on the bus (the rate the bus can carry). Pure data and
arithmetic over the per-model tables of models/: no I/O.
"""

from dataclasses import dataclass
import struct
from typing import Callable, Mapping, Optional

from dxl_servo_driver.models import Item, Model, modes
from dxl_servo_driver.protocol import (
    BITS_PER_BYTE, fast_status_size, fast_sync_size, INSTRUCTION_OVERHEAD, RETURN_DELAY_UNIT_S,
    STATUS_OVERHEAD)
from dxl_servo_driver.protocol.protocol1 import (
    INSTRUCTION_OVERHEAD as INSTRUCTION_OVERHEAD_1, STATUS_OVERHEAD as STATUS_OVERHEAD_1)


@dataclass(frozen=True)
class BlockField:
    """One register inside the packed state block."""

    name: str
    offset: int
    size: int


class BlockShape:
    """
    The state of one servo, packed through indirect addresses: fields, sizes, decoders.

    The registers below are scattered over the table (64, 68, 70, 120..146); mapping them to
    consecutive indirect data bytes lets one sync read fetch all of them from every servo.
    The block has three parts. The motion part (position, velocity, effort: the 10 bytes any
    control loop reads) and the Realtime Tick after it (the tagged read, 12 bytes) are read every
    cycle: the tick dates every sample, so a late reply never passes for the answer (TickClock).
    The health part after it (a canary, pwm, voltage, temperature, moving, errors, torque) comes
    only when diagnostics or servo_states need it, by reading the whole block in that cycle's one
    sync read instead.

    Effort is Present Current, or Present Load on the models that sense no current (same
    address and size): the block is laid out per model, its positions are the same for all.

    The canary maps status_return_level, which the driver never sets to 0: after a reboot or a
    power cut the indirect addresses return to their defaults and the whole block reads 0. A
    motion part of all zeros is therefore checked against the canary before anything is
    published: that is how the driver notices a servo that restarted on its own.
    """

    FIELDS: tuple[tuple[str, str], ...] = (
        ('present_position', 'i'),
        ('present_velocity', 'i'),
        ('effort', 'h'),              # present_current or present_load
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
        self.index: dict[str, int] = {name: i for i, name in enumerate(self.names)}
        self.canary_index: int = self.index['status_return_level']

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
        if self.tagged_size <= length < self.size:
            return self.decode_tagged   # a block without a tick read a few bytes on (a tag)
        if length == self.motion_size:
            return self.decode_motion
        raise ValueError(f'no state block part is {length} bytes long')

    def restarted(self, values: tuple[int, ...]) -> bool:
        """Return True when the values show the indirect mapping was lost (servo restarted)."""
        return values[self.canary_index] == 0


# The same for every model: the cycle decodes every servo's block with it.
BLOCK_SHAPE = BlockShape()


class StateBlock(BlockShape):
    """
    Where one model's state block lives, and how its bytes become the shape's values.

    Behind each field is the model's register for it (`Model.roles`: a family whose manual
    calls Present Velocity "Present Speed"); a field whose model has no such register is left
    out and decodes as 0, and `has(field)` says not to believe that 0.

    Two layouts. Indirect (every X, MX(2.0), P and PRO(A) table): the fields packed into the
    first indirect data bytes, one read per cycle of the motion part and the tick (tagged) or
    of the whole block. A table with fewer indirect entries than the block has bytes (the X330
    before firmware 53: 20) leaves Present PWM out (`compact`). Direct (a table without enough
    indirect entries: the XL-320): the model's own registers, one read of the span from the
    first to the last of them, whatever the part asked; no canary and, where the table has
    none, no Realtime Tick (`has_tick`), so such samples are dated by the bus alone.
    """

    # What an indirect table too small for the whole block leaves out.
    COMPACT_DROPS = ('present_pwm',)
    _CODES = {(1, False): 'B', (1, True): 'b', (2, False): 'H', (2, True): 'h',
              (4, False): 'I', (4, True): 'i'}

    def __init__(self, model: Model, effort_register: str) -> None:
        super().__init__()
        self.model = model
        self.effort_register = effort_register
        present = tuple(name for name in self.names
                        if model.has(effort_register if name == 'effort' else name))
        self._registers = {name: model.item(effort_register if name == 'effort' else name).name
                           for name in present}
        block_bytes = sum(model.item(self._registers[name]).size for name in present)
        # Indirect when the table has entries enough (the compact X330 drops PWM to fit).
        fits = [name for name in present if name not in self.COMPACT_DROPS]
        fits_bytes = sum(model.item(self._registers[name]).size for name in fits)
        self.direct = len(model.indirect) < fits_bytes
        self.compact = not self.direct and len(model.indirect) < block_bytes
        kept = fits if self.compact else list(present)
        self.present = frozenset(kept)
        self.has_pwm = 'present_pwm' in self.present
        self.has_tick = 'realtime_tick' in self.present
        # The canary works where a reboot clears the indirect map (RAM, as on the X): the P,
        # PRO(A) and Y keep theirs in EEPROM, so their block reads on after a restart.
        self.has_canary = not self.direct and model.by_address(model.indirect[0][0]).area == 'ram'
        self._positions = tuple(self.index[name] for name in kept)
        # Present Speed / Load of the older tables (bit 10 the direction, not a sign) and the
        # MX(1.0)'s Current (2,048 is none): read unsigned, then decoded by their item.
        self._recoded = tuple(
            (self.index[name], model.item(self._registers[name])) for name in kept
            if model.item(self._registers[name]).direction_bit
            or model.item(self._registers[name]).raw_zero)
        if self.direct:
            self._layout_direct(model, kept)
        else:
            self._layout_indirect(model, kept)
        # The X layout: the struct's values are the shape's, in order, nothing to move.
        self._as_shape = (self._positions == tuple(range(len(self.names)))
                          and not self._recoded)

    def _layout_indirect(self, model: Model, kept: list[str]) -> None:
        fields = []
        offset = 0
        codes = ''
        for name in kept:
            item = model.item(self._registers[name])
            fields.append(BlockField(item.name, offset, item.size))
            codes += self._code(item)
            offset += item.size
        self.fields: tuple[BlockField, ...] = tuple(fields)
        self.struct = struct.Struct('<' + codes)
        self.size = offset
        self.read_address: int = model.indirect[0][1]
        self.map_address: int = model.indirect[0][0]
        # The block's data bytes must be consecutive (one read): true of every bank's start.
        data = [pair[1] for pair in model.indirect[:self.size]]
        if data != list(range(data[0], data[0] + self.size)):
            raise ValueError(f'{model.label}: the first {self.size} indirect data bytes are '
                             'not consecutive')
        # The cycle reads the motion part (and the tick) alone; they lead the block.
        motion = [name for name in self.names[:self.TAGGED_FIELDS] if name in self.present]
        self.motion_size = sum(f.size for f in fields[:min(len(motion), self.MOTION_FIELDS)])
        self.tagged_size = sum(f.size for f in fields[:len(motion)])
        self.motion_struct = struct.Struct('<' + codes[:min(len(motion), self.MOTION_FIELDS)])
        self.tagged_struct = struct.Struct('<' + codes[:len(motion)])

    def _layout_direct(self, model: Model, kept: list[str]) -> None:
        items = sorted(((model.item(self._registers[name]), name) for name in kept),
                       key=lambda pair: pair[0].address)
        start = items[0][0].address
        codes = ''
        fields = []
        order = []
        position = start
        for item, name in items:
            if item.address < position:
                raise ValueError(f'{model.label}: {item.name} overlaps another state register')
            codes += 'x' * (item.address - position) + self._code(item)
            fields.append(BlockField(item.name, item.address - start, item.size))
            order.append(self.index[name])
            position = item.address + item.size
        self.fields = tuple(fields)
        self.struct = struct.Struct('<' + codes)
        self.size = position - start
        self.read_address = start
        self.map_address = -1
        self._positions = tuple(order)
        # One span, read whole whatever part the cycle asks for.
        self.motion_size = self.tagged_size = self.size
        self.motion_struct = self.tagged_struct = self.struct

    def _code(self, item: Item) -> str:
        # A direction-bit value is read unsigned and given its sign afterwards (_spread).
        return self._CODES[item.size, item.signed and not item.direction_bit]

    def has(self, field_name: str) -> bool:
        """Return whether the model has the register behind this field (else it reads 0)."""
        return field_name in self.present

    def _spread(self, values: tuple[int, ...]) -> tuple[int, ...]:
        """Return values decoded in layout order at their positions in FIELDS (0 elsewhere)."""
        whole = [0] * len(self.names)
        for index, value in zip(self._positions, values):
            whole[index] = value
        for index, item in self._recoded:
            whole[index] = item.decode(whole[index].to_bytes(item.size, 'little'))
        return tuple(whole)

    def decode(self, data: bytes, offset: int = 0) -> tuple[int, ...]:
        """Return the block's raw values, in the positions of FIELDS (0 for left-out ones)."""
        values = self.struct.unpack_from(data, offset)
        return values if self._as_shape else self._spread(values)

    def decode_motion(self, data: bytes, offset: int = 0) -> tuple[int, ...]:
        """Return the raw values of the motion part, at their FIELDS positions."""
        if self.direct:
            return self.decode(data, offset)[:self.MOTION_FIELDS]
        return self.motion_struct.unpack_from(data, offset)

    def decode_tagged(self, data: bytes, offset: int = 0) -> tuple[int, ...]:
        """Return the raw values of the motion part and the tick, at their FIELDS positions."""
        if self.direct:
            return self.decode(data, offset)[:self.TAGGED_FIELDS]
        values = self.tagged_struct.unpack_from(data, offset)
        return values if self.has_tick else values + (0,)

    def restarted(self, values: tuple[int, ...]) -> bool:
        """Return True when the values show the indirect mapping was lost (servo restarted)."""
        return self.has_canary and values[self.canary_index] == 0

    def register(self, field_name: str) -> str:
        """Return the register behind a block field (effort: current or load)."""
        return self._registers.get(field_name, field_name)

    def indirect_map(self) -> list[int]:
        """Return the target address of each indirect byte, in order (one per block byte)."""
        targets: list[int] = []
        for field in self.fields:
            base = self.model.item(field.name).address
            targets.extend(base + k for k in range(field.size))
        return targets

    def indirect_map_bytes(self) -> bytes:
        """Return the data of one WRITE to indirect_address_1.. that sets up the whole block."""
        return b''.join(struct.pack('<H', address) for address in self.indirect_map())

    def indirect_map_address(self) -> int:
        """Return the address of the first indirect address register the block uses."""
        return self.map_address


_BLOCKS: dict[tuple[int, int, str], StateBlock] = {}


def state_block(model: Model, effort_register: str) -> StateBlock:
    """Return the (shared) state block of a model."""
    key = (model.number, model.min_firmware, effort_register)
    block = _BLOCKS.get(key)
    if block is None:
        block = _BLOCKS[key] = StateBlock(model, effort_register)
    return block


# The goal slot: the indirect entries after the state block, mapped to the goal registers of
# the servo's operating mode, so that one sync write at one address carries every joint's goals
# whatever their modes (one sync write per cycle, docs/bus.md: goals in one sync write).
GOAL_SLOT_SIZE = 6


class GoalSlot:
    """
    One mode's goal registers, laid out in GOAL_SLOT_SIZE indirect data bytes.

    A sync write has one length for every servo in it. A servo whose goals are shorter than the
    write (a current goal of 2 bytes in a write of 4) repeats its own goal bytes: the entries
    after its registers map the same registers again, from their first byte, and the data
    repeats the same values. A write of any length up to GOAL_SLOT_SIZE therefore sets every
    goal register of the slot whole, and touches nothing else.
    """

    def __init__(self, model: Model, mode: str, map_address: int, data_address: int) -> None:
        self.registers = modes.BY_NAME[mode].slot
        self.data_address = data_address
        self.map_address = map_address
        items = [model.item(name) for name in self.registers]
        self._structs = tuple(struct.Struct('<' + {1: 'b', 2: 'h', 4: 'i'}[item.size])
                              for item in items)
        targets: list[int] = []
        self.needs: dict[str, int] = {}
        for name, item in zip(self.registers, items):
            targets.extend(range(item.address, item.address + item.size))
            # Bytes a write of this goal must carry, by the name the driver asks with (a
            # PRO's Goal Torque is its goal_current).
            self.needs[name] = len(targets)
        self.targets = tuple(targets[k % len(targets)] for k in range(GOAL_SLOT_SIZE))

    def map_bytes(self) -> bytes:
        """Return the data of one WRITE to the slot's indirect address entries."""
        return b''.join(struct.pack('<H', address) for address in self.targets)

    def holds(self, goals: Mapping[str, int]) -> bool:
        """Return whether goals has a value for every register of the slot."""
        return all(name in goals for name in self.registers)

    def pack(self, goals: Mapping[str, int], length: int) -> bytes:
        """Return length slot bytes holding these goals (KeyError if one is unknown)."""
        image = b''.join(packer.pack(goals[name])
                         for packer, name in zip(self._structs, self.registers))
        return (image * (GOAL_SLOT_SIZE // len(image) + 1))[:length]


def goal_slot(model: Model, block: StateBlock, mode: str) -> Optional[GoalSlot]:
    """
    Return the goal slot of a servo in a mode, None when its table has no room for one.

    The slot takes the GOAL_SLOT_SIZE indirect entries after the state block; the X330 before
    firmware 53 (20 entries, all taken by its compact block) has none.
    """
    if block.direct:
        return None
    first = block.size
    entries = model.indirect[first:first + GOAL_SLOT_SIZE]
    if len(entries) < GOAL_SLOT_SIZE or mode not in modes.BY_NAME:
        return None
    data = [pair[1] for pair in entries]
    addresses = [pair[0] for pair in entries]
    if (data != list(range(data[0], data[0] + GOAL_SLOT_SIZE))
            or addresses != list(range(addresses[0], addresses[0] + 2 * GOAL_SLOT_SIZE, 2))):
        return None
    if any(not model.has(name) for name in modes.BY_NAME[mode].slot):
        return None
    return GoalSlot(model, mode, addresses[0], data[0])


# Protocol 2.0 framing sizes, for bus timing.


def sync_read_bytes(n_servos: int, data_length: int) -> int:
    """Return the bytes on the wire of one sync read (instruction + every status packet)."""
    instruction = INSTRUCTION_OVERHEAD + 4 + n_servos
    return instruction + n_servos * (STATUS_OVERHEAD + data_length)


def fast_sync_read_bytes(n_servos: int, data_length: int) -> int:
    """Return the bytes on the wire of one fast sync read (instruction + its one status)."""
    return INSTRUCTION_OVERHEAD + 4 + n_servos + fast_sync_size(data_length, n_servos)


def bulk_read_bytes(lengths: list[int]) -> int:
    """Return the bytes on the wire of one BULK_READ (5 bytes a record) and every status."""
    return INSTRUCTION_OVERHEAD + 5 * len(lengths) + sum(STATUS_OVERHEAD + n for n in lengths)


def fast_bulk_read_bytes(lengths: list[int]) -> int:
    """Return the bytes on the wire of one FAST_BULK_READ and its one status."""
    return INSTRUCTION_OVERHEAD + 5 * len(lengths) + fast_status_size(lengths)


def sync_write_bytes(n_servos: int, data_length: int) -> int:
    """Return the bytes on the wire of one sync write."""
    return INSTRUCTION_OVERHEAD + 4 + n_servos * (1 + data_length)


# Protocol 1.0 framing sizes (protocol1.py): no CRC, one-byte lengths and addresses.


def read_bytes_1(length: int) -> int:
    """Return the bytes on the wire of one Protocol 1.0 READ and its status packet."""
    return INSTRUCTION_OVERHEAD_1 + 2 + STATUS_OVERHEAD_1 + length


def bulk_read_bytes_1(lengths: list[int]) -> int:
    """Return the bytes on the wire of one Protocol 1.0 BULK_READ and every status packet."""
    return (INSTRUCTION_OVERHEAD_1 + 1 + 3 * len(lengths)
            + sum(STATUS_OVERHEAD_1 + length for length in lengths))


def sync_write_bytes_1(n_servos: int, data_length: int) -> int:
    """Return the bytes on the wire of one Protocol 1.0 SYNC_WRITE."""
    return INSTRUCTION_OVERHEAD_1 + 2 + n_servos * (1 + data_length)


@dataclass(frozen=True)
class Transaction:
    """One transaction of a cycle: its bytes on the wire and the replies it waits for."""

    what: str
    bytes_on_wire: int
    replies: int          # each waits its servo's Return Delay Time (a fast read: one)


@dataclass(frozen=True)
class BusBudget:
    """What one cycle costs on the wire and the rate the bus can sustain."""

    bytes_per_cycle: int
    wire_time_s: float
    return_delay_s: float
    latency_s: float
    transactions: tuple[Transaction, ...] = ()

    @property
    def cycle_time_s(self) -> float:
        """Return the shortest possible cycle."""
        return self.wire_time_s + self.return_delay_s + self.latency_s

    @property
    def rate_limit_hz(self) -> float:
        """Return the highest loop rate the bus can carry."""
        return 1.0 / self.cycle_time_s


def plan_budget(transactions: list[Transaction], baud_bps: int,
                return_delay_time_raw: int = 0, latency_timer_s: float = 0.0) -> BusBudget:
    """
    Return the cost of one cycle made of these transactions.

    Every read (a transaction with replies) waits the USB adapter's latency timer once before
    the host sees its replies, and each reply its servo's Return Delay Time.
    """
    total = sum(each.bytes_on_wire for each in transactions)
    reads = sum(1 for each in transactions if each.replies)
    return BusBudget(
        bytes_per_cycle=total, wire_time_s=total * BITS_PER_BYTE / baud_bps,
        return_delay_s=sum(each.replies for each in transactions) * return_delay_time_raw
        * RETURN_DELAY_UNIT_S,
        latency_s=reads * latency_timer_s, transactions=tuple(transactions))


def bus_budget(n_servos: int, baud_bps: int, return_delay_time_raw: int = 0,
               latency_timer_s: float = 0.0, read_length: Optional[int] = None,
               write_length: int = 4, fast: bool = False) -> BusBudget:
    """
    Return the cost of one cycle: a sync read of the state block and one sync write of goals.

    Each servo waits its Return Delay Time (2 us per unit) before answering (in a fast sync
    read only the first: the others follow it on the wire); the USB adapter's latency timer
    holds the replies once per cycle before the host sees them.
    """
    length = read_length
    if length is None:   # what the cycle reads: the motion part and the tick
        length = BLOCK_SHAPE.tagged_size
    read = (fast_sync_read_bytes if fast else sync_read_bytes)(n_servos, length)
    total = read + sync_write_bytes(n_servos, write_length)
    return BusBudget(
        bytes_per_cycle=total,
        wire_time_s=total * BITS_PER_BYTE / baud_bps,
        return_delay_s=(1 if fast else n_servos) * return_delay_time_raw * RETURN_DELAY_UNIT_S,
        latency_s=latency_timer_s)
