"""
A simulated servo speaking Protocol 1.0: an X servo whose Protocol Version register (13) is 1.

The same control table, the same writes and side effects as in Protocol 2.0 (SimServo's
memory and write()); only the packets differ (protocol1.py): one-byte addresses, so items above
address 255 are out of reach, and an error byte of bits. Choices where the ROBOTIS e-manual
(Protocol 1.0) is silent, all documented here:

- The table's refusals become error bits: a value out of range, a read-only or reserved
  address, a length that does not fit, an access beyond address 255 -> Range; a goal position
  beyond the position limits -> Angle Limit (another limit -> Range); a write the servo will not
  carry out (torque on while a shutdown error is latched) -> Instruction.
- The hardware errors the 1.0 error byte names (input voltage, overheating, overload) are set
  in every status while latched in Hardware Error Status, as the 1.0 servos report their alarms;
  the X's motor-encoder and electrical-shock errors have no bit (the register still holds them).
- Malformed parameters (a READ without exactly address and length, a WRITE without data, a
  RESET or REBOOT with parameters) -> Range. Malformed SYNC_WRITE / BULK_READ packets are
  ignored (broadcast: nobody answers); sent to one id they are an Instruction error.
- A packet with a bad checksum addressed to this id gets a status with the Checksum bit (the
  e-manual's error bit), subject to Status Return Level as judged by its unverified instruction
  byte; broadcast: silence.
- No broadcast PING in 1.0: a PING to 0xFE is not answered. A broadcast RESET is ignored (ids
  would collide). RESET restores every EEPROM item (id and baud rate included) and restarts.
- Status Return Level: 0 answers PING only, 1 PING and READ (BULK_READ too), 2 everything.
- Writing Protocol Version takes effect after the write's status went out, in the protocol the
  write came in (SimServo reads the register per packet).
"""

import struct

from dxl_servo_driver.protocol import ErrorCode, Packet, ParseEvent
from dxl_servo_driver.protocol.protocol1 import (
    BROADCAST_ID, encode_status, ErrorBit, Instruction1, MAX_ADDRESS)
from dxl_servo_driver.sim.memory import TableError
from dxl_servo_driver.sim.servo import SimServo

_KIND_PING, _KIND_READ, _KIND_OTHER = 0, 1, 2
# Hardware Error Status names (models' hardware_error_bits) with a bit in the 1.0 error byte.
_HARDWARE_BITS = {'input_voltage': ErrorBit.INPUT_VOLTAGE, 'overheating': ErrorBit.OVERHEATING,
                  'overload': ErrorBit.OVERLOAD}
_SYNC_BULK = (Instruction1.SYNC_WRITE, Instruction1.BULK_READ)


def reply_order(packet: Packet) -> dict[int, int] | None:
    """Return id -> wire rank for a broadcast BULK_READ (the order of its records), else None."""
    params = packet.params
    if (packet.instruction != Instruction1.BULK_READ or packet.servo_id != BROADCAST_ID
            or not params or params[0] != 0 or (len(params) - 1) % 3):
        return None
    order: dict[int, int] = {}
    for rank, servo_id in enumerate(params[2::3]):
        order.setdefault(servo_id, rank)
    return order


def handle(servo: SimServo, event: ParseEvent, now_s: float) -> bytes | None:
    """Act on one Protocol 1.0 packet heard at now_s; return the status packet to send, if any."""
    packet = event.packet
    if not servo.hears(packet.servo_id, 1, now_s):
        return None
    broadcast = packet.servo_id == BROADCAST_ID
    if not event.crc_ok:   # a broadcast is never answered, even to say it was corrupt
        return None if broadcast else _status(
            servo, ErrorBit.CHECKSUM, b'', _kind(packet.instruction))
    my_id, instruction, params = servo.servo_id, packet.instruction, packet.params
    if instruction in _SYNC_BULK:
        if not broadcast:
            return _status(servo, ErrorBit.INSTRUCTION, b'', _KIND_OTHER)
        if instruction == Instruction1.SYNC_WRITE:
            _sync_write(servo, my_id, params)
            return None
        return _bulk_read(servo, my_id, params)
    if instruction == Instruction1.PING:
        return None if broadcast else _status(servo, 0, b'', _KIND_PING)
    if instruction == Instruction1.READ:
        if broadcast:
            return None
        if len(params) != 2:
            return _status(servo, ErrorBit.RANGE, b'', _KIND_READ)
        return _read_reply(servo, params[0], params[1])
    if instruction == Instruction1.WRITE:
        if len(params) < 2:
            return _reply_write(servo, broadcast, ErrorBit.RANGE)
        return _reply_write(servo, broadcast, _write(servo, params[0], params[1:]))
    if instruction == Instruction1.REG_WRITE:
        return _reply_write(servo, broadcast, _reg_write(servo, params))
    if instruction == Instruction1.ACTION:
        registered = servo.take_registered()
        if registered is None:
            return _reply_write(servo, broadcast, ErrorBit.INSTRUCTION)
        return _reply_write(servo, broadcast, _write(servo, *registered))
    if instruction == Instruction1.RESET:
        return _reset(servo, broadcast, params, now_s)
    if instruction == Instruction1.REBOOT:
        if params:
            return _reply_write(servo, broadcast, ErrorBit.RANGE)
        reply = _reply_write(servo, broadcast, 0)
        servo.restart(now_s)
        return reply
    return None if broadcast else _status(servo, ErrorBit.INSTRUCTION, b'', _KIND_OTHER)


def _kind(instruction: int) -> int:
    if instruction == Instruction1.PING:
        return _KIND_PING
    if instruction in (Instruction1.READ, Instruction1.BULK_READ):
        return _KIND_READ
    return _KIND_OTHER


def _status(servo: SimServo, error: int, params: bytes, kind: int) -> bytes | None:
    memory = servo.memory
    level = memory.get('status_return_level')
    if kind == _KIND_READ and level < 1 or kind == _KIND_OTHER and level < 2:
        return None
    latched = memory.get('hardware_error_status')
    if latched:
        for bit, name in servo.model.hardware_error_bits.items():
            if latched & bit and name in _HARDWARE_BITS:
                error |= _HARDWARE_BITS[name]
    return encode_status(servo.servo_id, error, params)


def _reply_write(servo: SimServo, broadcast: bool, error: int) -> bytes | None:
    return None if broadcast else _status(servo, error, b'', _KIND_OTHER)


def _reach(address: int, length: int) -> bool:
    """Return whether length bytes at address are within Protocol 1.0's reach."""
    return length >= 1 and address + length <= MAX_ADDRESS + 1


def _error_bits(servo: SimServo, code: int, address: int, length: int) -> int:
    """Return the 1.0 error bit for a table refusal (a Protocol 2.0 error code)."""
    if code == ErrorCode.DATA_LIMIT:
        goal = servo.memory.item('goal_position')
        if address < goal.address + goal.size and goal.address < address + length:
            return ErrorBit.ANGLE_LIMIT
        return ErrorBit.RANGE
    if code == ErrorCode.RESULT_FAIL:
        return ErrorBit.INSTRUCTION
    return ErrorBit.RANGE if code else 0


def _read_reply(servo: SimServo, address: int, length: int) -> bytes | None:
    if not _reach(address, length):
        return _status(servo, ErrorBit.RANGE, b'', _KIND_READ)
    try:
        data = servo.memory.read(address, length)
    except TableError as error:
        return _status(servo, _error_bits(servo, error.code, address, length), b'', _KIND_READ)
    return _status(servo, 0, data, _KIND_READ)


def _write(servo: SimServo, address: int, payload: bytes) -> int:
    """Apply a write (SimServo.write: all or nothing); return the 1.0 error bits."""
    if not _reach(address, len(payload)):
        return ErrorBit.RANGE
    return _error_bits(servo, servo.write(address, payload), address, len(payload))


def _reg_write(servo: SimServo, params: bytes) -> int:
    if len(params) < 2 or not _reach(params[0], len(params) - 1):
        return ErrorBit.RANGE
    address, payload = params[0], bytes(params[1:])
    try:
        servo.memory.plan_write(address, payload)
    except TableError as error:
        return _error_bits(servo, error.code, address, len(payload))
    servo.register(address, payload)
    return 0


def _reset(servo: SimServo, broadcast: bool, params: bytes, now_s: float) -> bytes | None:
    if params:
        return _reply_write(servo, broadcast, ErrorBit.RANGE)
    if broadcast:
        return None
    reply = _reply_write(servo, broadcast, 0)
    servo.memory.factory_reset()
    servo.restart(now_s)
    return reply


def _sync_write(servo: SimServo, my_id: int, params: bytes) -> None:
    if len(params) < 2:
        return
    address, length = params[0], params[1]
    stride = length + 1
    if length == 0 or (len(params) - 2) % stride:
        return
    for start in range(2, len(params), stride):
        if params[start] == my_id:
            _write(servo, address, params[start + 1:start + stride])
            return


def _bulk_read(servo: SimServo, my_id: int, params: bytes) -> bytes | None:
    if not params or params[0] != 0 or (len(params) - 1) % 3:
        return None
    for length, servo_id, address in struct.iter_unpack('<BBB', params[1:]):
        if servo_id == my_id:
            return _read_reply(servo, address, length)
    return None
