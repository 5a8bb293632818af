"""
One simulated servo: Protocol 2.0 instruction handling and the register side effects.

A servo whose Protocol Version register is 1 hears Protocol 1.0 instead (sim/protocol1.py
dispatches those packets to the same memory and side effects) and ignores Protocol 2.0 packets.

The physics lives in dynamics.ServoDynamics; this class owns the control table (its model's:
items, modes, bauds, and the Firmware Version it reports), time, power and the latched hardware
errors.  Choices where the manual is silent (all documented here):
- A status packet answers with the id the servo had when the packet arrived (ID change: old id,
  then the new one); Status Return Level and Return Delay Time written by a packet already apply
  to that packet's own status.
- Malformed parameters: PING ignores parameters; READ needs exactly 4 parameter bytes, WRITE and
  REG_WRITE at least 3, FACTORY_RESET exactly 1, REBOOT none, CLEAR exactly 5, else Data Length
  error.  A FACTORY_RESET option other than 0x01/0x02/0xFF and CLEAR bytes other than
  01 44 58 4C 22 are a Data Range error.  Malformed SYNC/BULK packets (lengths that do not add up)
  are ignored by every servo: they are broadcast, nobody answers.
- SYNC_READ/FAST_SYNC_READ/SYNC_WRITE/BULK_READ/FAST_BULK_READ/BULK_WRITE are acted on only
  when sent to the broadcast id; sent to one servo's id they get an Instruction error.  A
  servo listed twice acts on its first entry.
- Broadcast: only PING (and the sync/bulk reads, by their id lists) is answered; every other
  instruction is carried out silently.  A broadcast FACTORY_RESET 0xFF is ignored (firmware).
- Writing torque_enable=1 while a hardware error bit that is set in `shutdown` is latched is
  refused with Result Fail (nothing written); REBOOT or a power cycle clears the latch.
- REG_WRITE is checked when it arrives (an error is answered and nothing is registered); ACTION
  applies it and answers with the write's result; a new REG_WRITE replaces an older one.
- REBOOT/FACTORY_RESET: the status goes out first, then the servo restarts: unresponsive for
  boot_time_s, RAM defaults, latched errors cleared, present position re-initialised within one
  turn, goal_position := present_position (as after power-on). FACTORY_RESET is accepted with
  torque on (it restarts the servo anyway).
- Power-on (powercycle, plug) is the same restart without touching EEPROM.
- Torque enable 0 -> 1 in a position mode holds the horn where it is (the dynamics) and sets
  goal_position := present_position, so the register shows the goal the servo holds. A driver
  should still write goal = present first: in the other modes the goals are kept as written.
- A packet with a bad CRC addressed to this id gets a CRC error status, subject to Status Return
  Level as judged by its (unverified) instruction byte; broadcast: silence.
"""

import struct
from typing import Callable, Protocol

from dxl_servo_driver.models import Model, modes
from dxl_servo_driver.models.base import TORQUE_MODE
from dxl_servo_driver.models.xm430 import TICK_PERIOD_MS
from dxl_servo_driver.protocol import (
    ALERT_BIT, BROADCAST_ID, CLEAR_MULTI_TURN, encode_status, ErrorCode, fast_status_size,
    Instruction, MAX_ID, MAX_PACKET_LENGTH, ParseEvent, RETURN_DELAY_UNIT_S)
from dxl_servo_driver.sim.dynamics import CONTROL_PERIOD_S
from dxl_servo_driver.sim.memory import Memory, TableError

# The Realtime Tick counts 0..its maximum (32767) ms, then wraps.
_ADDR_LEN = struct.Struct('<HH')
_U16 = struct.Struct('<H')
_KIND_PING, _KIND_READ, _KIND_OTHER = 0, 1, 2
_READ_INSTRUCTIONS = (Instruction.READ, Instruction.SYNC_READ, Instruction.FAST_SYNC_READ,
                      Instruction.BULK_READ, Instruction.FAST_BULK_READ)
_SYNC_BULK = (Instruction.SYNC_READ, Instruction.SYNC_WRITE, Instruction.FAST_SYNC_READ,
              Instruction.BULK_READ, Instruction.BULK_WRITE, Instruction.FAST_BULK_READ)


class Dynamics(Protocol):
    """What the servo needs from dynamics.ServoDynamics."""

    def advance(self, dt_s: float, regs: Memory) -> int:
        """Run the physics for dt_s; return detected hardware error bits."""

    def on_goal_position(self, regs: Memory) -> None:
        """goal_position was written."""

    def on_goal_velocity(self, regs: Memory) -> None:
        """goal_velocity was written."""

    def on_torque(self, enabled: bool, regs: Memory) -> None:
        """torque_enable changed."""

    def reinit_present_position(self, regs: Memory) -> None:
        """Re-initialise present_position within one turn."""

    def reset_controllers(self) -> None:
        """Reset integrators and profile state."""

    def set_load(self, load_nm: float) -> None:
        """Set the resisting torque at the horn."""

    def set_input_voltage(self, volts: float) -> None:
        """Set the supply voltage."""


class SimServo:
    """One servo on the simulated bus."""

    def __init__(self, servo_id: int, dynamics: Dynamics, now_s: float,
                 boot_time_s: float = 0.1, model: Model | None = None,
                 firmware_version: int | None = None) -> None:
        if not 0 <= servo_id <= MAX_ID:
            raise ValueError(f'servo id {servo_id} outside 0..{MAX_ID}')
        self.memory = Memory(model, firmware_version)
        self.model = self.memory.model
        # The one-byte registers read on every packet, by address (the model's, looked up once).
        table = self.memory.table
        self._id_address = table.id_address
        self._baud_address = table.baud_address
        self._return_delay_address = table.return_delay_address
        self._status_return_address = table.status_return_address
        self._error_status_address = table.error_status_address
        self._error_mask = table.error_mask
        protocol_item = table.by_name.get('protocol_version')
        self._protocol_address = None if protocol_item is None else protocol_item.address
        # Registers of one model moved by another's physics would be a servo that lies.
        dynamics_model = getattr(dynamics, 'model', self.model)
        if dynamics_model is not self.model:
            raise ValueError(f'the dynamics are of the {dynamics_model.label}, the table of the '
                             f'{self.model.label}')
        self._bauds = self.model.bauds
        # A Baud Rate value without a baud (not written by a bus: the table refuses it).
        self._fallback_bps = self._bauds[self.model.item('baud_rate').initial]
        self.memory.set('id', servo_id)
        self.dynamics = dynamics
        self.boot_time_s = boot_time_s
        self.powered = True
        self._last_s = now_s
        self._power_on_s = now_s
        self._ready_s = now_s
        self._registered: tuple[int, bytes] | None = None
        self._restart(now_s, boot_delay=False)

    # ---- state ---------------------------------------------------------------------------------
    @property
    def servo_id(self) -> int:
        """Return the id the servo answers to now."""
        return self.memory.raw[self._id_address]

    @property
    def baud_bps(self) -> int:
        """Return the baud rate the servo listens at."""
        return self._bauds.get(self.memory.raw[self._baud_address], self._fallback_bps)

    @property
    def return_delay_s(self) -> float:
        """Return the Return Delay Time (the register times its unit, 2 us)."""
        return self.memory.raw[self._return_delay_address] * RETURN_DELAY_UNIT_S

    @property
    def protocol_version(self) -> int:
        """Return the protocol it speaks now: its Protocol Version, else its model's one."""
        address = self._protocol_address
        return int(self.model.protocol) if address is None else self.memory.raw[address]

    def responsive(self, now_s: float) -> bool:
        """Return whether the servo hears packets at now_s (powered and booted)."""
        return self.powered and now_s >= self._ready_s

    @property
    def physics_time_s(self) -> float:
        """Return the time the physics was last advanced to."""
        return self._last_s

    def advance(self, now_s: float, lag_s: float = 0.0) -> None:
        """Run the physics up to now_s (unless it is less than lag_s behind) and latch errors."""
        dt_s = now_s - self._last_s
        memory = self.memory
        if self.powered and dt_s > 0.0:
            # The Realtime Tick is the servo's clock, not physics: current even while the
            # physics may lag (a driver dates samples by it).
            tick_ms = int((now_s - self._power_on_s) * 1000.0)
            memory.set('realtime_tick', max(tick_ms, 0) % TICK_PERIOD_MS)
        if dt_s < lag_s:
            return
        if dt_s <= 0.0:
            return
        if not self.powered:
            self._last_s = now_s
            return
        # The servo's controllers sample once per control period: packets closer together
        # than that see the registers of the last sample, which also keeps a busy bus cheap.
        if dt_s >= CONTROL_PERIOD_S:
            self._last_s = now_s
            self.latch_errors(self.dynamics.advance(dt_s, memory))

    def set_tick(self, now_s: float, tick_ms: int) -> None:
        """
        Make the Realtime Tick read tick_ms at now_s and count on from there.

        As if powered on that long ago, modulo the wrap: a servo that has run for hours, or a
        tick about to wrap.
        """
        if not 0 <= tick_ms < TICK_PERIOD_MS:
            raise ValueError(f'a Realtime Tick is 0..{TICK_PERIOD_MS - 1} ms, got {tick_ms}')
        self.advance(now_s)
        self._power_on_s = now_s - tick_ms / 1000.0
        self.memory.set('realtime_tick', tick_ms)

    def latch_errors(self, bits: int) -> None:
        """Latch hardware error bits; drop torque for those set in `shutdown`."""
        bits &= self._error_mask  # the model's bits only (7, 6 and 1 are unused)
        if not bits:
            return
        memory = self.memory
        memory.set('hardware_error_status', memory.get('hardware_error_status') | bits)
        if bits & memory.get('shutdown') and memory.get('torque_enable'):
            memory.set('torque_enable', 0)
            self.dynamics.on_torque(False, memory)

    def power_off(self, now_s: float) -> None:
        """Cut the power: torque drops, the servo stops hearing the bus."""
        self.advance(now_s)
        if self.powered and self.memory.get('torque_enable'):
            self.memory.set('torque_enable', 0)
            self.dynamics.on_torque(False, self.memory)
        self.powered = False

    def power_on(self, now_s: float) -> None:
        """Power back on: EEPROM kept, RAM defaults, boot_time_s until it answers."""
        self.advance(now_s)
        self.powered = True
        self._restart(now_s, boot_delay=True)

    def _restart(self, now_s: float, boot_delay: bool) -> None:
        memory = self.memory
        if memory.get('torque_enable'):
            memory.set('torque_enable', 0)
            self.dynamics.on_torque(False, memory)
        memory.reset_ram()
        self._registered = None
        self._last_s = now_s
        self._power_on_s = now_s
        self._ready_s = now_s + (self.boot_time_s if boot_delay else 0.0)
        dynamics = self.dynamics
        dynamics.reset_controllers()
        dynamics.reinit_present_position(memory)
        memory.set('goal_position', memory.get('present_position'))
        # Fill the present_* registers at once (a zero-length step).
        self.latch_errors(dynamics.advance(0.0, memory))

    # ---- packets -------------------------------------------------------------------------------
    def handle(self, event: ParseEvent, now_s: float) -> bytes | None:
        """Act on one packet heard at now_s; return the status packet to send, if any."""
        if not self.responsive(now_s) or self.protocol_version != 2:
            return None
        packet = event.packet
        my_id = self.servo_id
        target = packet.servo_id
        if target != my_id and target != BROADCAST_ID:
            return None
        instruction = packet.instruction
        if not event.crc_ok:
            if target == BROADCAST_ID:
                return None
            return self._status(my_id, ErrorCode.CRC, b'', self._kind(instruction))
        if instruction == Instruction.STATUS:
            return None  # another servo's status: not for us
        broadcast = target == BROADCAST_ID
        params = packet.params
        try:
            handler = _HANDLERS[instruction]
        except KeyError:
            if broadcast:
                return None
            return self._status(my_id, ErrorCode.INSTRUCTION, b'', _KIND_OTHER)
        if instruction in _SYNC_BULK and not broadcast:
            return self._status(my_id, ErrorCode.INSTRUCTION, b'', _KIND_OTHER)
        return handler(self, my_id, broadcast, params, now_s)

    @staticmethod
    def _kind(instruction: int) -> int:
        if instruction == Instruction.PING:
            return _KIND_PING
        if instruction in _READ_INSTRUCTIONS:
            return _KIND_READ
        return _KIND_OTHER

    def restart(self, now_s: float) -> None:
        """Restart as after REBOOT: unresponsive for boot_time_s, RAM defaults, errors cleared."""
        self._restart(now_s, boot_delay=True)

    def register(self, address: int, payload: bytes) -> None:
        """Keep a checked REG_WRITE until ACTION (a newer one replaces it)."""
        self._registered = (address, bytes(payload))
        self.memory.set('registered_instruction', 1)

    def take_registered(self) -> tuple[int, bytes] | None:
        """Return the REG_WRITE waiting for ACTION, and forget it (None: none waits)."""
        registered = self._registered
        if registered is not None:
            self._registered = None
            self.memory.set('registered_instruction', 0)
        return registered

    def _status(self, reply_id: int, error: int, params: bytes, kind: int) -> bytes | None:
        raw = self.memory.raw
        level = raw[self._status_return_address]
        if kind == _KIND_READ and level < 1 or kind == _KIND_OTHER and level < 2:
            return None
        if raw[self._error_status_address]:
            error |= ALERT_BIT
        return encode_status(reply_id, error, params)

    def _reply_write(self, my_id: int, broadcast: bool, error: int) -> bytes | None:
        if broadcast:
            return None
        return self._status(my_id, error, b'', _KIND_OTHER)

    # ---- writes and their side effects --------------------------------------------------------
    def write(self, address: int, payload: bytes) -> int:
        """Apply a bus write all-or-nothing; return the status error code (0 = success)."""
        memory = self.memory
        try:
            new, names = memory.plan_write(address, payload)
        except TableError as error:
            return error.code
        old_torque = memory.get('torque_enable')
        old_mode = memory.get('operating_mode')
        if 'torque_enable' in names and new[memory.table.torque_address]:
            if memory.get('hardware_error_status') & memory.get('shutdown'):
                return ErrorCode.RESULT_FAIL
        memory.commit(new)
        self._side_effects(self._as_roles(names), old_torque, old_mode)
        return 0

    def _as_roles(self, names: frozenset[str]) -> frozenset[str]:
        """
        Return the items written under the XM430 manual's names the side effects go by.

        Another table's own names get their roles (the AX's Moving Speed is goal_velocity, the
        XL-320's Control Mode operating_mode); a Protocol 1.0 table's CW/CCW Angle Limits are
        its mode too: the simulator's Operating Mode follows them.
        """
        model = self.model
        roles = {own: role for role, own in model.roles.items()}
        named = frozenset(roles.get(name, name) for name in names)
        if model.mode_register and model.mode_register in names:
            named |= {'operating_mode'}
        if not model.mode_register and named & {'min_position_limit', 'max_position_limit',
                                                TORQUE_MODE}:
            memory = self.memory
            mode = model.angle_limit_mode(
                memory.get('min_position_limit'), memory.get('max_position_limit'),
                memory.get(TORQUE_MODE) if memory.has(TORQUE_MODE) else 0)
            memory.set('operating_mode', modes.BY_NAME[mode].number)
            named |= {'operating_mode'}
        return named

    def _side_effects(self, names: frozenset[str], old_torque: int, old_mode: int) -> None:
        memory = self.memory
        dynamics = self.dynamics
        if 'operating_mode' in names and memory.get('operating_mode') != old_mode \
                and self.model.mode_register != 'operating_mode':
            # A wheel/joint switch (the XL-320, the Protocol 1.0 tables) resets nothing.
            dynamics.reinit_present_position(memory)
        elif 'operating_mode' in names and memory.get('operating_mode') != old_mode:
            memory.set('profile_velocity', 0)
            memory.set('profile_acceleration', 0)
            for goal, limit in memory.table.goals_from_limits:
                memory.set(goal, memory.get(limit))
            for name in modes.RESET_GAINS:
                memory.set(name, memory.item(name).initial)
            dynamics.reinit_present_position(memory)
        if 'torque_enable' in names:
            torque = memory.get('torque_enable')
            if torque != old_torque:
                if torque:
                    dynamics.reinit_present_position(memory)
                    if memory.get('operating_mode') in modes.POSITION_NUMBERS:
                        # The dynamics holds the horn where it is at torque on; the register
                        # says so too, rather than showing a goal the servo is not heading for.
                        memory.set('goal_position', memory.get('present_position'))
                dynamics.on_torque(bool(torque), memory)
        if 'goal_position' in names:
            dynamics.on_goal_position(memory)
        if 'goal_velocity' in names:
            dynamics.on_goal_velocity(memory)

    # ---- instructions --------------------------------------------------------------------------
    def _ping(self, my_id: int, broadcast: bool, params: bytes, now_s: float) -> bytes | None:
        # The model number and firmware come from the table, as a real servo reports them.
        memory = self.memory
        params = struct.pack('<HB', memory.get('model_number'), memory.get('firmware_version'))
        return self._status(my_id, 0, params, _KIND_PING)

    def _read_reply(self, my_id: int, address: int, length: int) -> bytes | None:
        try:
            data = self.memory.read(address, length)
        except TableError as error:
            return self._status(my_id, error.code, b'', _KIND_READ)
        return self._status(my_id, 0, data, _KIND_READ)

    def _read(self, my_id: int, broadcast: bool, params: bytes, now_s: float) -> bytes | None:
        if broadcast:
            return None
        if len(params) != 4:
            return self._status(my_id, ErrorCode.DATA_LENGTH, b'', _KIND_READ)
        address, length = _ADDR_LEN.unpack(params)
        return self._read_reply(my_id, address, length)

    def _write(self, my_id: int, broadcast: bool, params: bytes, now_s: float) -> bytes | None:
        if len(params) < 3:
            return self._reply_write(my_id, broadcast, ErrorCode.DATA_LENGTH)
        error = self.write(_U16.unpack_from(params)[0], params[2:])
        return self._reply_write(my_id, broadcast, error)

    def _reg_write(self, my_id: int, broadcast: bool, params: bytes,
                   now_s: float) -> bytes | None:
        if len(params) < 3:
            return self._reply_write(my_id, broadcast, ErrorCode.DATA_LENGTH)
        address = _U16.unpack_from(params)[0]
        try:
            self.memory.plan_write(address, params[2:])
        except TableError as error:
            return self._reply_write(my_id, broadcast, error.code)
        self._registered = (address, bytes(params[2:]))
        self.memory.set('registered_instruction', 1)
        return self._reply_write(my_id, broadcast, 0)

    def _action(self, my_id: int, broadcast: bool, params: bytes, now_s: float) -> bytes | None:
        registered = self._registered
        if registered is None:
            return self._reply_write(my_id, broadcast, ErrorCode.INSTRUCTION)
        self._registered = None
        self.memory.set('registered_instruction', 0)
        return self._reply_write(my_id, broadcast, self.write(*registered))

    def _factory_reset(self, my_id: int, broadcast: bool, params: bytes,
                       now_s: float) -> bytes | None:
        if len(params) != 1:
            return self._reply_write(my_id, broadcast, ErrorCode.DATA_LENGTH)
        option = params[0]
        if option not in (0x01, 0x02, 0xFF):
            return self._reply_write(my_id, broadcast, ErrorCode.DATA_RANGE)
        if broadcast and option == 0xFF:
            return None  # the firmware ignores a broadcast reset-all (ids would collide)
        reply = self._reply_write(my_id, broadcast, 0)
        self.memory.factory_reset(keep_id=option != 0xFF, keep_baud=option == 0x02)
        self._restart(now_s, boot_delay=True)
        return reply

    def _reboot(self, my_id: int, broadcast: bool, params: bytes, now_s: float) -> bytes | None:
        if params:
            return self._reply_write(my_id, broadcast, ErrorCode.DATA_LENGTH)
        reply = self._reply_write(my_id, broadcast, 0)
        self._restart(now_s, boot_delay=True)
        return reply

    def _clear(self, my_id: int, broadcast: bool, params: bytes, now_s: float) -> bytes | None:
        if len(params) != len(CLEAR_MULTI_TURN):
            return self._reply_write(my_id, broadcast, ErrorCode.DATA_LENGTH)
        if params != CLEAR_MULTI_TURN:
            return self._reply_write(my_id, broadcast, ErrorCode.DATA_RANGE)
        if self.memory.get('moving'):
            return self._reply_write(my_id, broadcast, ErrorCode.RESULT_FAIL)
        self.dynamics.reinit_present_position(self.memory)
        return self._reply_write(my_id, broadcast, 0)

    def _sync_read(self, my_id: int, broadcast: bool, params: bytes,
                   now_s: float) -> bytes | None:
        if len(params) < 5 or my_id not in params[4:]:
            return None
        address, length = _ADDR_LEN.unpack_from(params)
        return self._read_reply(my_id, address, length)

    def _fast_sync_read(self, my_id: int, broadcast: bool, params: bytes,
                        now_s: float) -> bytes | None:
        """
        Return this servo's part of a Fast Sync Read: error, id, data (SimBus frames the parts).

        Firmware older than the model's first with Fast Sync Read does not know the
        instruction: a broadcast unknown instruction is not answered. A read the table refuses
        answers its error code with zeros for data, so the parts after it keep their places.
        A request whose one status packet could not be framed (longer than a packet can be:
        the manual says nothing of it) is ignored, as malformed sync packets are.
        """
        if len(params) < 5 or my_id not in params[4:]:
            return None
        address, length = _ADDR_LEN.unpack_from(params)
        count = len(dict.fromkeys(params[4:]))
        return self._fast_part(my_id, address, length, (length,) * count)

    def _fast_bulk_read(self, my_id: int, broadcast: bool, params: bytes,
                        now_s: float) -> bytes | None:
        """
        Return this servo's part of a Fast Bulk Read (0x9A): error, id, its own record's data.

        As a Fast Sync Read's part (_fast_sync_read), from its own (address, length) record;
        a servo listed twice answers its first record. The SDK's Fast Bulk Read has the same
        parts and CRCs as its Fast Sync Read, the firmware that has one is taken to have the
        other.
        """
        if not params or len(params) % 5:
            return None
        records: dict[int, tuple[int, int]] = {}
        for start in range(0, len(params), 5):
            address, length = _ADDR_LEN.unpack_from(params, start + 1)
            records.setdefault(params[start], (address, length))
        record = records.get(my_id)
        if record is None:
            return None
        lengths = tuple(length for _, length in records.values())
        return self._fast_part(my_id, record[0], record[1], lengths)

    def _fast_part(self, my_id: int, address: int, length: int,
                   lengths: tuple[int, ...]) -> bytes | None:
        """Return this servo's part of a fast read whose parts carry lengths, if it answers."""
        memory = self.memory
        if not self.model.has_fast_sync_read(memory.get('firmware_version')):
            return None
        if memory.raw[self._status_return_address] < 1:
            return None
        if fast_status_size(lengths) > MAX_PACKET_LENGTH:
            return None
        try:
            data = memory.read(address, length)
            error = 0
        except TableError as exc:
            data = bytes(length)
            error = exc.code
        if memory.raw[self._error_status_address]:
            error |= ALERT_BIT
        return bytes((error, my_id)) + data

    def _sync_write(self, my_id: int, broadcast: bool, params: bytes,
                    now_s: float) -> bytes | None:
        if len(params) < 5:
            return None
        address, length = _ADDR_LEN.unpack_from(params)
        stride = length + 1
        if length == 0 or (len(params) - 4) % stride:
            return None
        for start in range(4, len(params), stride):
            if params[start] == my_id:
                self.write(address, params[start + 1:start + stride])
                break
        return None

    def _bulk_read(self, my_id: int, broadcast: bool, params: bytes,
                   now_s: float) -> bytes | None:
        if not params or len(params) % 5:
            return None
        for start in range(0, len(params), 5):
            if params[start] == my_id:
                address, length = _ADDR_LEN.unpack_from(params, start + 1)
                return self._read_reply(my_id, address, length)
        return None

    def _bulk_write(self, my_id: int, broadcast: bool, params: bytes,
                    now_s: float) -> bytes | None:
        records = parse_bulk_write(params)
        if records is None:
            return None
        for servo_id, address, data in records:
            if servo_id == my_id:
                self.write(address, data)
                break
        return None


def parse_bulk_write(params: bytes) -> list[tuple[int, int, bytes]] | None:
    """Split BULK_WRITE parameters into (id, address, data); None when malformed."""
    records = []
    start = 0
    size = len(params)
    if not size:
        return None
    while start < size:
        if size - start < 5:
            return None
        address, length = _ADDR_LEN.unpack_from(params, start + 1)
        end = start + 5 + length
        if length == 0 or end > size:
            return None
        records.append((params[start], address, bytes(params[start + 5:end])))
        start = end
    return records


_HANDLERS: dict[int, Callable[[SimServo, int, bool, bytes, float], 'bytes | None']] = {
    Instruction.PING: SimServo._ping,
    Instruction.READ: SimServo._read,
    Instruction.WRITE: SimServo._write,
    Instruction.REG_WRITE: SimServo._reg_write,
    Instruction.ACTION: SimServo._action,
    Instruction.FACTORY_RESET: SimServo._factory_reset,
    Instruction.REBOOT: SimServo._reboot,
    Instruction.CLEAR: SimServo._clear,
    Instruction.SYNC_READ: SimServo._sync_read,
    Instruction.SYNC_WRITE: SimServo._sync_write,
    Instruction.FAST_SYNC_READ: SimServo._fast_sync_read,
    Instruction.BULK_READ: SimServo._bulk_read,
    Instruction.BULK_WRITE: SimServo._bulk_write,
    Instruction.FAST_BULK_READ: SimServo._fast_bulk_read,
}
