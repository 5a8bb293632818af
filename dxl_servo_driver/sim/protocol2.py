"""
A simulated servo speaking Protocol 2.0: the instructions, answered from SimServo's memory.

sim/protocol1.py answers Protocol 1.0 the same way; both act through the servo's memory and its
write() (the side effects), so a servo behaves alike in either protocol. Choices where the
manual is silent (all documented here):
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
- REG_WRITE is checked when it arrives (an error is answered and nothing is registered); ACTION
  applies it and answers with the write's result; a new REG_WRITE replaces an older one.
- REBOOT/FACTORY_RESET: the status goes out first, then the servo restarts (SimServo.restart).
  FACTORY_RESET is accepted with torque on (it restarts the servo anyway).
- A packet with a bad CRC addressed to this id gets a CRC error status, subject to Status Return
  Level as judged by its (unverified) instruction byte; broadcast: silence.

The servo is typed by what the handlers use of it (Servo), not by servo.SimServo: SimServo.handle
dispatches here, so this module cannot import servo.py without an import circle.
"""

import struct
from typing import Callable, Protocol

from dxl_servo_driver.models import Model
from dxl_servo_driver.protocol import (
    ALERT_BIT, BROADCAST_ID, CLEAR_MULTI_TURN, encode_status, ErrorCode, fast_status_size,
    Instruction, MAX_PACKET_LENGTH, ParseEvent)
from dxl_servo_driver.sim.memory import Memory, TableError

_ADDR_LEN = struct.Struct('<HH')
_U16 = struct.Struct('<H')
_KIND_PING, _KIND_READ, _KIND_OTHER = 0, 1, 2
_READ_INSTRUCTIONS = (Instruction.READ, Instruction.SYNC_READ, Instruction.FAST_SYNC_READ,
                      Instruction.BULK_READ, Instruction.FAST_BULK_READ)
_SYNC_BULK = (Instruction.SYNC_READ, Instruction.SYNC_WRITE, Instruction.FAST_SYNC_READ,
              Instruction.BULK_READ, Instruction.BULK_WRITE, Instruction.FAST_BULK_READ)


class Servo(Protocol):
    """What the Protocol 2.0 handlers use of servo.SimServo."""

    memory: Memory

    @property
    def model(self) -> Model:
        """Return the servo's model."""

    @property
    def servo_id(self) -> int:
        """Return the id the servo answers to now."""

    @property
    def protocol_version(self) -> int:
        """Return the protocol it speaks now."""

    def hears(self, target: int, version: int, now_s: float) -> bool:
        """Return whether a packet of this protocol to target, heard at now_s, is its to act on."""

    def write(self, address: int, payload: bytes) -> int:
        """Apply a bus write all-or-nothing; return the status error code."""

    def restart(self, now_s: float) -> None:
        """Restart as after REBOOT."""

    def register(self, address: int, payload: bytes) -> None:
        """Keep a checked REG_WRITE until ACTION."""

    def take_registered(self) -> tuple[int, bytes] | None:
        """Return the REG_WRITE waiting for ACTION, and forget it."""

    def clear_multi_turn(self) -> None:
        """Re-initialise the present position within one turn (CLEAR)."""


Handler = Callable[[Servo, int, bool, bytes, float], 'bytes | None']


def handle(servo: Servo, event: ParseEvent, now_s: float) -> bytes | None:
    """Act on one Protocol 2.0 packet heard at now_s; return the status packet to send, if any."""
    packet = event.packet
    if not servo.hears(packet.servo_id, 2, now_s):
        return None
    my_id, instruction = servo.servo_id, packet.instruction
    broadcast = packet.servo_id == BROADCAST_ID
    if not event.crc_ok:   # a broadcast is never answered, even to say it was corrupt
        return None if broadcast else _status(servo, my_id, ErrorCode.CRC, b'', _kind(instruction))
    if instruction == Instruction.STATUS:
        return None  # another servo's status: not for us
    params = packet.params
    try:
        handler = HANDLERS[instruction]
    except KeyError:
        if broadcast:
            return None
        return _status(servo, my_id, ErrorCode.INSTRUCTION, b'', _KIND_OTHER)
    if instruction in _SYNC_BULK and not broadcast:
        return _status(servo, my_id, ErrorCode.INSTRUCTION, b'', _KIND_OTHER)
    return handler(servo, my_id, broadcast, params, now_s)


def _kind(instruction: int) -> int:
    if instruction == Instruction.PING:
        return _KIND_PING
    if instruction in _READ_INSTRUCTIONS:
        return _KIND_READ
    return _KIND_OTHER


def _status(servo: Servo, reply_id: int, error: int, params: bytes, kind: int) -> bytes | None:
    memory = servo.memory
    raw = memory.raw
    table = memory.table
    level = raw[table.status_return_address]
    if kind == _KIND_READ and level < 1 or kind == _KIND_OTHER and level < 2:
        return None
    if raw[table.error_status_address]:
        error |= ALERT_BIT
    return encode_status(reply_id, error, params)


def _reply_write(servo: Servo, my_id: int, broadcast: bool, error: int) -> bytes | None:
    if broadcast:
        return None
    return _status(servo, my_id, error, b'', _KIND_OTHER)


def _read_reply(servo: Servo, my_id: int, address: int, length: int) -> bytes | None:
    try:
        data = servo.memory.read(address, length)
    except TableError as error:
        return _status(servo, my_id, error.code, b'', _KIND_READ)
    return _status(servo, my_id, 0, data, _KIND_READ)


# ---- the instructions, one handler each: (servo, its id, broadcast, parameters, time) ---------
def _ping(servo: Servo, my_id: int, broadcast: bool, params: bytes,
          now_s: float) -> bytes | None:
    # The model number and firmware come from the table, as a real servo reports them.
    memory = servo.memory
    params = struct.pack('<HB', memory.get('model_number'), memory.get('firmware_version'))
    return _status(servo, my_id, 0, params, _KIND_PING)


def _read(servo: Servo, my_id: int, broadcast: bool, params: bytes,
          now_s: float) -> bytes | None:
    if broadcast:
        return None
    if len(params) != 4:
        return _status(servo, my_id, ErrorCode.DATA_LENGTH, b'', _KIND_READ)
    address, length = _ADDR_LEN.unpack(params)
    return _read_reply(servo, my_id, address, length)


def _write(servo: Servo, my_id: int, broadcast: bool, params: bytes,
           now_s: float) -> bytes | None:
    if len(params) < 3:
        return _reply_write(servo, my_id, broadcast, ErrorCode.DATA_LENGTH)
    error = servo.write(_U16.unpack_from(params)[0], params[2:])
    return _reply_write(servo, my_id, broadcast, error)


def _reg_write(servo: Servo, my_id: int, broadcast: bool, params: bytes,
               now_s: float) -> bytes | None:
    if len(params) < 3:
        return _reply_write(servo, my_id, broadcast, ErrorCode.DATA_LENGTH)
    address = _U16.unpack_from(params)[0]
    try:
        servo.memory.plan_write(address, params[2:])
    except TableError as error:
        return _reply_write(servo, my_id, broadcast, error.code)
    servo.register(address, params[2:])
    return _reply_write(servo, my_id, broadcast, 0)


def _action(servo: Servo, my_id: int, broadcast: bool, params: bytes,
            now_s: float) -> bytes | None:
    registered = servo.take_registered()
    if registered is None:
        return _reply_write(servo, my_id, broadcast, ErrorCode.INSTRUCTION)
    return _reply_write(servo, my_id, broadcast, servo.write(*registered))


def _factory_reset(servo: Servo, my_id: int, broadcast: bool, params: bytes,
                   now_s: float) -> bytes | None:
    if len(params) != 1:
        return _reply_write(servo, my_id, broadcast, ErrorCode.DATA_LENGTH)
    option = params[0]
    if option not in (0x01, 0x02, 0xFF):
        return _reply_write(servo, my_id, broadcast, ErrorCode.DATA_RANGE)
    if broadcast and option == 0xFF:
        return None  # the firmware ignores a broadcast reset-all (ids would collide)
    reply = _reply_write(servo, my_id, broadcast, 0)
    servo.memory.factory_reset(keep_id=option != 0xFF, keep_baud=option == 0x02)
    servo.restart(now_s)
    return reply


def _reboot(servo: Servo, my_id: int, broadcast: bool, params: bytes,
            now_s: float) -> bytes | None:
    if params:
        return _reply_write(servo, my_id, broadcast, ErrorCode.DATA_LENGTH)
    reply = _reply_write(servo, my_id, broadcast, 0)
    servo.restart(now_s)
    return reply


def _clear(servo: Servo, my_id: int, broadcast: bool, params: bytes,
           now_s: float) -> bytes | None:
    if len(params) != len(CLEAR_MULTI_TURN):
        return _reply_write(servo, my_id, broadcast, ErrorCode.DATA_LENGTH)
    if params != CLEAR_MULTI_TURN:
        return _reply_write(servo, my_id, broadcast, ErrorCode.DATA_RANGE)
    if servo.memory.get('moving'):
        return _reply_write(servo, my_id, broadcast, ErrorCode.RESULT_FAIL)
    servo.clear_multi_turn()
    return _reply_write(servo, my_id, broadcast, 0)


def _sync_read(servo: Servo, my_id: int, broadcast: bool, params: bytes,
               now_s: float) -> bytes | None:
    if len(params) < 5 or my_id not in params[4:]:
        return None
    address, length = _ADDR_LEN.unpack_from(params)
    return _read_reply(servo, my_id, address, length)


def _fast_sync_read(servo: Servo, my_id: int, broadcast: bool, params: bytes,
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
    return _fast_part(servo, my_id, address, length, (length,) * count)


def _fast_bulk_read(servo: Servo, my_id: int, broadcast: bool, params: bytes,
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
    return _fast_part(servo, my_id, record[0], record[1], lengths)


def _fast_part(servo: Servo, my_id: int, address: int, length: int,
               lengths: tuple[int, ...]) -> bytes | None:
    """Return this servo's part of a fast read whose parts carry lengths, if it answers."""
    memory = servo.memory
    if not servo.model.has_fast_sync_read(memory.get('firmware_version')):
        return None
    if memory.raw[memory.table.status_return_address] < 1:
        return None
    if fast_status_size(lengths) > MAX_PACKET_LENGTH:
        return None
    try:
        data = memory.read(address, length)
        error = 0
    except TableError as exc:
        data = bytes(length)
        error = exc.code
    if memory.raw[memory.table.error_status_address]:
        error |= ALERT_BIT
    return bytes((error, my_id)) + data


def _sync_write(servo: Servo, my_id: int, broadcast: bool, params: bytes,
                now_s: float) -> bytes | None:
    if len(params) < 5:
        return None
    address, length = _ADDR_LEN.unpack_from(params)
    stride = length + 1
    if length == 0 or (len(params) - 4) % stride:
        return None
    for start in range(4, len(params), stride):
        if params[start] == my_id:
            servo.write(address, params[start + 1:start + stride])
            break
    return None


def _bulk_read(servo: Servo, my_id: int, broadcast: bool, params: bytes,
               now_s: float) -> bytes | None:
    if not params or len(params) % 5:
        return None
    for start in range(0, len(params), 5):
        if params[start] == my_id:
            address, length = _ADDR_LEN.unpack_from(params, start + 1)
            return _read_reply(servo, my_id, address, length)
    return None


def _bulk_write(servo: Servo, my_id: int, broadcast: bool, params: bytes,
                now_s: float) -> bytes | None:
    records = parse_bulk_write(params)
    if records is None:
        return None
    for servo_id, address, data in records:
        if servo_id == my_id:
            servo.write(address, data)
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


# Read at every packet (not bound at import): a test may stand a handler in for one.
HANDLERS: dict[int, Handler] = {
    Instruction.PING: _ping,
    Instruction.READ: _read,
    Instruction.WRITE: _write,
    Instruction.REG_WRITE: _reg_write,
    Instruction.ACTION: _action,
    Instruction.FACTORY_RESET: _factory_reset,
    Instruction.REBOOT: _reboot,
    Instruction.CLEAR: _clear,
    Instruction.SYNC_READ: _sync_read,
    Instruction.SYNC_WRITE: _sync_write,
    Instruction.FAST_SYNC_READ: _fast_sync_read,
    Instruction.BULK_READ: _bulk_read,
    Instruction.BULK_WRITE: _bulk_write,
    Instruction.FAST_BULK_READ: _fast_bulk_read,
}
