"""
Dynamixel Protocol 1.0 framing: checksum, packet encoding, the bus's framer and a stream parser.

Instruction packet: FF FF | ID | LEN | INSTRUCTION | PARAMS... | CHECKSUM, where LEN counts the
parameters plus 2 (instruction and checksum). A status packet has the same layout with the error
byte where the instruction was: FF FF | ID | LEN | ERROR | PARAMS... | CHECKSUM. The checksum is
the inverted low byte of the sum of every byte after the header (the e-manual's Protocol 1.0
page). Addresses and lengths are one byte; ids 0..253, 0xFE is the broadcast id.

Two things differ from Protocol 2.0 and shape this module:

- No byte stuffing: FF FF may appear inside the parameters (a data word 0xFFFF). The length field
  alone says where a packet ends; a header found inside a packet that checks is data. Only when
  the checksum fails does the bus's scan (resync) look for a header inside the bad packet again:
  noise may have forged a header whose length swallowed a real packet.
- A status packet has no instruction byte: a frame cannot tell whether it is a servo's answer or
  an instruction (our own request coming back on an echoing adapter). Frame1.is_status says only
  whether it can be a status (bit 7 of an error byte is never set); the bus tells its echo by
  comparing the frame with the packet it sent before it takes any frame for an answer.
"""

from dataclasses import dataclass
from enum import IntEnum
from typing import Dict, Sequence

from dxl_servo_driver.errors import BadRequest
from dxl_servo_driver.protocol.protocol2 import (
    Frame, frame_scanner, FrameLayout, Framer, Packet, StreamParser)

HEADER = b'\xff\xff'
BROADCAST_ID = 0xFE
MAX_ID = 253
MAX_ADDRESS = 255
# The length field is one byte and counts the parameters plus 2.
MAX_LENGTH = 255
MAX_PARAMS = MAX_LENGTH - 2
# Sizes on the wire.
STATUS_OVERHEAD = 6         # header 2, id, length, error, checksum
INSTRUCTION_OVERHEAD = 6    # header 2, id, length, instruction, checksum
READ_PACKET_SIZE = INSTRUCTION_OVERHEAD + 2   # READ: address, length
# Where the model number (2 bytes) is: a ping's status does not carry it.
MODEL_NUMBER_ADDRESS = 0
# The one option of RESET: the whole control table (it has no parameter).
RESET_ALL = 0xFF


class Instruction1(IntEnum):
    """Protocol 1.0 instruction codes."""

    PING = 0x01
    READ = 0x02
    WRITE = 0x03
    REG_WRITE = 0x04
    ACTION = 0x05
    RESET = 0x06
    REBOOT = 0x08
    SYNC_WRITE = 0x83
    BULK_READ = 0x92


class ErrorBit(IntEnum):
    """The bits of a Protocol 1.0 status packet's error byte (bit 7 is unused)."""

    INPUT_VOLTAGE = 0x01
    ANGLE_LIMIT = 0x02
    OVERHEATING = 0x04
    RANGE = 0x08
    CHECKSUM = 0x10
    OVERLOAD = 0x20
    INSTRUCTION = 0x40


ERROR_BIT_NAMES: Dict[int, str] = {
    ErrorBit.INPUT_VOLTAGE: 'input voltage error (outside the voltage limits)',
    ErrorBit.ANGLE_LIMIT: 'angle limit error (goal position outside the angle limits)',
    ErrorBit.OVERHEATING: 'overheating error (above the temperature limit)',
    ErrorBit.RANGE: 'range error (a value or address outside its range)',
    ErrorBit.CHECKSUM: 'checksum error (the servo received a corrupted packet)',
    ErrorBit.OVERLOAD: 'overload error (the load exceeds the torque limit)',
    ErrorBit.INSTRUCTION: 'instruction error (unknown instruction, or ACTION without REG_WRITE)',
}
# The bits that say this instruction was refused, and those that report the servo's hardware
# state (the alert of Protocol 2.0: the instruction itself was carried out).
REFUSAL_MASK = (ErrorBit.ANGLE_LIMIT | ErrorBit.RANGE | ErrorBit.CHECKSUM
                | ErrorBit.INSTRUCTION)
ALERT_MASK = ErrorBit.INPUT_VOLTAGE | ErrorBit.OVERHEATING | ErrorBit.OVERLOAD
_UNUSED_BIT = 0x80


def error_text(error: int) -> str:
    """Return the names of the bits set in an error byte, joined (empty for none)."""
    return ', '.join(name for bit, name in ERROR_BIT_NAMES.items() if error & bit)


def check_reach(address: int, length: int, other_params: int = 0) -> None:
    """Refuse an access Protocol 1.0 cannot express: one-byte addresses, 253 parameters."""
    if (address < 0 or length < 1 or address + length > MAX_ADDRESS + 1
            or length + other_params > MAX_PARAMS):
        raise BadRequest(f'{length} bytes at address {address}: Protocol 1.0 reaches addresses '
                         f'0..{MAX_ADDRESS} only, {MAX_PARAMS} parameters a packet')


def checksum(body: bytes | bytearray) -> int:
    """Return the checksum of the bytes between the header and the checksum itself."""
    return ~sum(body) & 0xFF


def _encode(servo_id: int, first: int, params: bytes) -> bytes:
    if len(params) > MAX_PARAMS:
        raise ValueError(f'{len(params)} parameters: a Protocol 1.0 packet holds at most '
                         f'{MAX_PARAMS}')
    body = bytes((servo_id & 0xFF, len(params) + 2, first & 0xFF)) + bytes(params)
    return HEADER + body + bytes((checksum(body),))


def encode_instruction(servo_id: int, instruction: int, params: bytes = b'') -> bytes:
    """Return a whole instruction packet as it goes on the wire."""
    return _encode(servo_id, instruction, params)


def encode_status(servo_id: int, error: int, params: bytes = b'') -> bytes:
    """Return a whole status packet as it goes on the wire."""
    return _encode(servo_id, error, params)


@dataclass(frozen=True)
class Frame1(Frame):
    """
    One whole Protocol 1.0 packet found in a buffer: an instruction or a status, undecided.

    instruction holds the byte after the length field: the instruction of an instruction
    packet, the error byte of a status packet. The caller decides which the frame is.
    """

    @property
    def framer(self) -> Framer:
        """Return PROTOCOL_1: this is a Protocol 1.0 packet."""
        return PROTOCOL_1

    def packet(self) -> Packet:
        """Decode the frame as an instruction packet, as a servo's receiver sees it."""
        return Packet(self.servo_id, self.instruction, self.raw[5:-1])

    @property
    def is_status(self) -> bool:
        """Return True when the frame can be a status packet (its error byte's bit 7 clear)."""
        return not self.instruction & _UNUSED_BIT

    def status(self) -> tuple[int, bytes]:
        """Return the frame read as a status packet: (error byte, parameters)."""
        return self.instruction, self.raw[5:-1]


# Where a Protocol 1.0 packet keeps what finding it takes (protocol.frame_scanner): FF FF, the id,
# a one-byte length, then the counted bytes ending in a checksum over all after the header.
LAYOUT_1 = FrameLayout(HEADER, 2, 3, 1, 2, MAX_LENGTH, checksum, 2, 1, True, Frame1)
# The whole Protocol 1.0 packets in a buffer (protocol.frame_scanner): a length field below 2 or
# above max_length (default MAX_LENGTH) is noise. A run of FF before the id is header padding: the
# packet starts at its last two FFs (an id is never FF). A packet that checks is taken whole, FF
# FF in its parameters included: there is no stuffing, the length field decides.
scan_frames = frame_scanner(LAYOUT_1)


def decode_packet(data: bytes) -> Packet:
    """
    Decode exactly one whole packet as an instruction; ValueError when it is not a valid one.

    A status packet decodes too: its error byte is then the Packet's instruction (and error).
    """
    data = bytes(data)
    if len(data) < 6 or not data.startswith(HEADER):
        raise ValueError('not a Protocol 1.0 packet (short or no header)')
    length = data[3]
    if length < 2 or len(data) != 4 + length:
        raise ValueError(f'length field {length} does not match {len(data)} bytes')
    if checksum(data[2:-1]) != data[-1]:
        raise ValueError('checksum mismatch')
    return Packet(data[2], data[4], data[5:-1], data[4])


class StreamParser1(StreamParser):
    """
    Incremental Protocol 1.0 parser (the simulated servos' receiver), as protocol.StreamParser.

    feed() returns the whole packets found, framed by this module's scan_frames() (the
    package's one scan, protocol.frame_scanner, with LAYOUT_1) without resync: garbage before a
    header is skipped, a length below 2 is noise, a packet whose checksum fails is reported with
    crc_ok False and skipped whole. A partial packet whose next byte comes later than
    inter_byte_timeout_s is discarded, as the servo's receiver does.
    """

    _scan = staticmethod(scan_frames)


class Protocol1Framer:
    """Protocol 1.0 framing (this module's functions), as the bus's Framer."""

    version = 1
    status_overhead = STATUS_OVERHEAD
    refusal_mask = int(REFUSAL_MASK)
    alert_mask = int(ALERT_MASK)
    ping_reply_params = 0       # a 1.0 ping's status carries nothing: the model is read
    model_number_address: int | None = MODEL_NUMBER_ADDRESS
    broadcast_ping = False
    sync_read = False           # BULK_READ instead
    fast_read = False
    multi_turn_clear = False
    echo_like_status = True     # a status has no instruction byte (module docstring)
    clean_block = False
    layout = LAYOUT_1
    check_name = 'checksum'
    bad_check_fate = 'refuse it'   # its status has the checksum error bit
    address_size = 1
    unanswered: frozenset[int] = frozenset({Instruction1.SYNC_WRITE})

    def encode(self, servo_id: int, instruction: int, params: bytes = b'') -> bytes:
        """Return a whole instruction packet as it goes on the wire."""
        return encode_instruction(servo_id, instruction, params)

    def scan(self, buffer: bytes | bytearray, pos: int, max_length: int,
             final: bool) -> tuple[list[Frame], int]:
        """Return the whole frames in buffer from pos on (scan_frames with resync)."""
        return scan_frames(buffer, pos, max_length=min(max_length, MAX_LENGTH), final=final)

    def error_text(self, code: int) -> str:
        """Return the names of the error bits set (error_text)."""
        return error_text(code)

    def address_param(self, address: int, length: int, other_params: int = 0) -> bytes:
        """Return the one-byte address; BadRequest for an access 1.0 cannot express."""
        check_reach(address, length, other_params)
        return bytes((address,))

    def address_length(self, address: int, length: int) -> bytes:
        """Return the one-byte address and length; BadRequest for what does not fit them."""
        check_reach(address, length)
        return bytes((address, length))

    def fit_read(self, address: int, length: int, before: int, extra: int) -> tuple[int, int]:
        """Return (before, extra) cut to addresses 0..255 and 253 parameters a read."""
        check_reach(address, length)
        extra = min(extra, MAX_PARAMS - length)
        room = MAX_ADDRESS + 1 - address - length
        before = min(address, extra, max(before, extra - room))
        return before, min(extra, before + room)

    def bulk_read_params(self, records: Sequence[tuple[int, int, int]]) -> bytes:
        """Return 0x00, then length, id, address of each record (the e-manual's layout)."""
        params = bytearray((0x00,))
        for servo_id, address, length in records:
            check_reach(address, length)
            params += bytes((length, servo_id, address))
        return bytes(params)

    def reset_params(self, option: int) -> bytes | None:
        """Return no parameter for option 0xFF (RESET resets everything); None for another."""
        return b'' if option == RESET_ALL else None

    def bulk_read_records(self, params: bytes) -> list[tuple[int, int, int]] | None:
        """Return the records after the leading 0x00 (length, id, address each); None: no 0x00."""
        if not params:
            return None
        return [(params[at + 1], params[at + 2], params[at])
                for at in range(1, len(params) - 2, 3)]

    def instruction_name(self, code: int) -> str:
        """Return the Instruction1's name, or `instruction 0x..`."""
        try:
            return Instruction1(code).name
        except ValueError:
            return f'instruction 0x{code:02x}'

    def refusal_text(self, error: int) -> str:
        """Return the refusal bits set, in hex, and their names ('': none)."""
        refused = error & REFUSAL_MASK
        return f'0x{refused:02x}: {error_text(refused)}' if refused else ''

    def alert_text(self, error: int) -> str:
        """Return the hardware state bits set, in hex, and their names ('': none)."""
        alert = error & ALERT_MASK
        return f'0x{alert:02x}: {error_text(alert)}' if alert else ''

    def ping_model(self, data: bytes) -> tuple[int, int] | None:
        """Return None: a ping's answer carries nothing (the model number is read)."""
        return None


PROTOCOL_1 = Protocol1Framer()
