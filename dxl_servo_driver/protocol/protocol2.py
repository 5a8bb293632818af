"""
Dynamixel Protocol 2.0 framing: CRC-16, byte stuffing, packet encoding and an incremental parser.

Packet layout: FF FF FD 00 | ID | LEN_L LEN_H | INSTRUCTION | PARAMS... | CRC_L CRC_H, where LEN
counts instruction, (stuffed) parameters and CRC.  A status packet's instruction is 0x55 and its
first parameter is the error byte.  Byte stuffing: inside instruction + parameters every
FF FF FD is followed by an extra FD so the header never appears inside a packet.  The CRC covers
the whole packet as sent (stuffed), header included.
"""

from dataclasses import dataclass
from enum import IntEnum
import importlib
import os
import struct
from typing import Callable, cast, NamedTuple, Protocol, Sequence

HEADER = b'\xff\xff\xfd\x00'
BROADCAST_ID = 0xFE
MAX_ID = 252
# A status packet's error byte: bit 7 the alert (a hardware error is latched), bits 0..6 the
# ErrorCode of this instruction.
ALERT_BIT = 0x80
ERROR_CODE_MASK = 0x7F
# CLEAR's parameters for clearing the multi-turn count (the e-manual's CLEAR instruction).
CLEAR_MULTI_TURN = b'\x01\x44\x58\x4c\x22'
# Sizes on the wire (8N1 serial: a start bit, 8 data bits, a stop bit per byte).
BITS_PER_BYTE = 10
STATUS_OVERHEAD = 11        # header 4, id, length 2, instruction, error, crc 2
INSTRUCTION_OVERHEAD = 10   # header 4, id, length 2, instruction, crc 2
READ_PACKET_SIZE = INSTRUCTION_OVERHEAD + 4   # READ: address 2, length 2
# Fast Sync Read and Fast Bulk Read: one status packet for every servo asked (see
# encode_fast_status).
FAST_HEAD_SIZE = 8          # header 4, id FE, length 2, instruction 0x55
FAST_PART_OVERHEAD = 4      # error, id, crc 2 around each servo's data
# Upper bound of the length field this parser accepts (the SDK's own buffers are 1024 bytes);
# a larger value is taken as line noise and the parser resyncs.
MAX_PACKET_LENGTH = 4096
DEFAULT_INTER_BYTE_TIMEOUT_S = 0.05
RETURN_DELAY_UNIT_S = 2e-6   # a servo's Return Delay Time register counts 2 us

_STUFF_PATTERN = b'\xff\xff\xfd'
_STUFFED_PATTERN = b'\xff\xff\xfd\xfd'


class Instruction(IntEnum):
    """Protocol 2.0 instruction codes."""

    PING = 0x01
    READ = 0x02
    WRITE = 0x03
    REG_WRITE = 0x04
    ACTION = 0x05
    FACTORY_RESET = 0x06
    REBOOT = 0x08
    CLEAR = 0x10
    STATUS = 0x55
    SYNC_READ = 0x82
    SYNC_WRITE = 0x83
    FAST_SYNC_READ = 0x8A
    BULK_READ = 0x92
    BULK_WRITE = 0x93
    FAST_BULK_READ = 0x9A


class ErrorCode(IntEnum):
    """Status packet error codes (bits 0..6 of the error byte)."""

    RESULT_FAIL = 1
    INSTRUCTION = 2
    CRC = 3
    DATA_RANGE = 4
    DATA_LENGTH = 5
    DATA_LIMIT = 6
    ACCESS = 7


def _make_crc_table() -> tuple[int, ...]:
    # CRC-16 with polynomial 0x8005, MSB first, initial 0 (the e-manual's table).
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


_CRC_TABLE = _make_crc_table()


def _make_crc_word_table() -> tuple[int, ...]:
    # Two bytes per step: a 16-bit CRC fed 16 bits is a function of (crc ^ word) alone.
    table = _CRC_TABLE
    words = []
    for word in range(65536):
        crc = table[word >> 8]
        words.append(((crc << 8) & 0xFF00) ^ table[(crc >> 8) ^ (word & 0xFF)])
    return tuple(words)


_CRC_WORD_TABLE = _make_crc_word_table()
_WORD_STRUCTS: dict[int, struct.Struct] = {}


def crc16_python(data: bytes | bytearray, crc: int = 0, /) -> int:
    """Return the Protocol 2.0 CRC-16 of data, continuing from crc (pure Python)."""
    words = len(data) >> 1
    if words:
        unpacker = _WORD_STRUCTS.get(words)
        if unpacker is None:
            unpacker = _WORD_STRUCTS.setdefault(words, struct.Struct(f'>{words}H'))
        word_table = _CRC_WORD_TABLE
        for word in unpacker.unpack_from(data):
            crc = word_table[crc ^ word]
    if len(data) & 1:
        crc = ((crc << 8) & 0xFF00) ^ _CRC_TABLE[(crc >> 8) ^ data[-1]]
    return crc


def _compiled_crc16() -> 'Crc16 | None':
    """
    Return fastcrc's CRC-16/UMTS (the Protocol 2.0 CRC: poly 0x8005, init 0) when installed.

    It is compiled (Rust) and some 30 times faster per status packet than crc16_python;
    DXL_PURE_CRC=1 keeps the pure one (the benchmark compares the two).
    """
    if os.environ.get('DXL_PURE_CRC') == '1':
        return None
    try:
        umts = cast(Crc16, getattr(importlib.import_module('fastcrc.crc16'), 'umts'))
    except (ImportError, AttributeError):
        return None
    return umts if umts(b'\x01\x02\x03') == crc16_python(b'\x01\x02\x03') else None


class Crc16(Protocol):
    """crc16(data) or crc16(data, crc_so_far), positional."""

    def __call__(self, data: bytes | bytearray, crc: int = 0, /) -> int:
        """Return the CRC-16 of data, continuing from crc."""


_COMPILED_CRC16 = _compiled_crc16()
CRC_IMPLEMENTATION = 'fastcrc' if _COMPILED_CRC16 is not None else 'python'
# The hot path calls this name directly: no wrapper between it and the compiled function.
crc16: Crc16 = _COMPILED_CRC16 if _COMPILED_CRC16 is not None else crc16_python


def stuff(payload: bytes) -> bytes:
    """Insert the stuffing byte FD after every FF FF FD of instruction + parameters."""
    if _STUFF_PATTERN not in payload:
        return bytes(payload)
    return bytes(payload).replace(_STUFF_PATTERN, _STUFFED_PATTERN)


def unstuff(payload: bytes) -> bytes:
    """Remove the stuffing byte after every FF FF FD (the inverse of stuff)."""
    if _STUFFED_PATTERN not in payload:
        return bytes(payload)
    return bytes(payload).replace(_STUFFED_PATTERN, _STUFF_PATTERN)


def _encode(servo_id: int, body: bytes) -> bytes:
    stuffed = stuff(body)
    head = HEADER + struct.pack('<BH', servo_id & 0xFF, len(stuffed) + 2)
    packet = head + stuffed
    return packet + struct.pack('<H', crc16(packet))


def encode_instruction(servo_id: int, instruction: int, params: bytes = b'') -> bytes:
    """Return a whole instruction packet as it goes on the wire."""
    return _encode(servo_id, bytes((instruction & 0xFF,)) + bytes(params))


def encode_status(servo_id: int, error: int, params: bytes = b'') -> bytes:
    """Return a whole status packet (instruction 0x55) as it goes on the wire."""
    return _encode(servo_id, bytes((Instruction.STATUS, error & 0xFF)) + bytes(params))


@dataclass
class Packet:
    """A decoded packet; error is meaningful only for status packets."""

    servo_id: int
    instruction: int
    params: bytes
    error: int = 0


@dataclass(frozen=True)
class ParseEvent:
    """One whole packet found in the byte stream; crc_ok is False when its CRC did not match."""

    packet: Packet
    crc_ok: bool
    raw: bytes


@dataclass(frozen=True)
class Frame:
    """
    One whole packet found in a buffer, not yet decoded.

    start and end are its offsets in the buffer scanned. The body (instruction and parameters)
    is unstuffed only when asked, so a frame that is skipped costs no copy.
    """

    start: int
    end: int
    servo_id: int
    instruction: int
    crc_ok: bool
    raw: bytes

    @property
    def framer(self) -> 'Framer':
        """Return the framer of the protocol this frame is a packet of (its scan found it)."""
        return PROTOCOL_2

    def packet(self) -> Packet:
        """Decode the frame (the error byte is split off for a status packet)."""
        return _packet_from_body(self.servo_id, unstuff(self.raw[7:-2]) if self.crc_ok
                                 else self.raw[7:-2])

    @property
    def is_status(self) -> bool:
        """Return True for a status packet (a servo's answer)."""
        return self.instruction == Instruction.STATUS

    def status(self) -> tuple[int, bytes]:
        """Return a status frame's (error byte, parameters), the parameters unstuffed."""
        raw = self.raw
        if len(raw) < STATUS_OVERHEAD:
            return 0, b''
        data = raw[9:-2]
        if _STUFFED_PATTERN in data:
            data = unstuff(data)
        return raw[8], data


def _packet_from_body(servo_id: int, body: bytes) -> Packet:
    instruction = body[0]
    params = body[1:]
    if instruction == Instruction.STATUS and params:
        return Packet(servo_id, instruction, bytes(params[1:]), params[0])
    return Packet(servo_id, instruction, bytes(params))


class FrameLayout(NamedTuple):
    """
    Where a protocol's packets keep what finding them in a byte stream takes (frame_scanner).

    A packet: header, id, length field, then the bytes the length counts: the instruction (a 1.0
    status: its error byte), the parameters and the check over raw[check_from:] before it.
    """

    header: bytes
    id_at: int              # the id's offset
    length_at: int          # the length field's offset; the counted bytes follow it
    length_size: int        # bytes of the length field (little-endian): 1 or 2
    min_length: int         # a length field below this is noise
    max_length: int         # and above this, unless the caller bounds it otherwise
    check: Callable[[bytes], int]   # the check's value of raw[check_from:-check_size]
    check_from: int
    check_size: int         # bytes of the check (little-endian): 1 or 2
    # FF bytes before the id are the header's (1.0: a run of FF, the id never FF); 2.0's
    # header ends in FD 00, so the search itself finds where it starts.
    padded_header: bool
    frame: 'type[Frame]'    # the class of the frames found


def _partial_header_start(buffer: bytes | bytearray, pos: int, header: bytes) -> int:
    # A trailing part of a header (2.0: FF, FF FF, FF FF FD) may be a header still arriving.
    end = len(buffer)
    if end <= pos or buffer[end - 1] not in header:   # the usual end: a packet's last byte
        return end
    for keep in range(len(header) - 1, 0, -1):
        if end - keep >= pos and buffer[end - keep:end] == header[:keep]:
            return end - keep
    return end


def frame_scanner(layout: FrameLayout) -> Callable[..., tuple[list[Frame], int]]:
    """
    Return the scan for whole packets of a layout: the one framing routine of the package.

    scan(buffer, pos=0, max_length=layout.max_length, final=False, resync=True) returns the
    whole packets in buffer from pos on, and where unconsumed bytes begin: the bus's and the
    simulator's, in either protocol (scan_frames, protocol1's). Bytes before a header are noise;
    so is a header whose length field is below min_length or above max_length: the scan goes on
    at its next byte. A packet whose check fails is reported (crc_ok False); with resync the scan
    then looks for a header inside it (noise may have forged a header whose length swallowed a
    real packet), without it the whole claimed length is skipped (what a servo's receiver does).
    A packet that checks is taken whole. The offset returned is where an incomplete packet (or a
    partial header) starts, or len(buffer); with final (no more bytes will come), an incomplete
    packet is noise too. The layout's facts are bound here once, local names of the scan: it
    runs on every reply the bus reads and every byte the simulator hears.
    """
    (header, id_at, length_at, length_size, min_length, longest, check, check_from, check_size,
     padded_header, frame) = layout
    body_at = length_at + length_size
    length_high = length_at + 1
    wide_length = length_size == 2
    wide_check = check_size == 2
    check_end = -check_size

    def scan(buffer: bytes | bytearray, pos: int = 0, max_length: int = longest,
             final: bool = False, resync: bool = True) -> tuple[list[Frame], int]:
        frames: list[Frame] = []
        end = len(buffer)
        while True:
            start = buffer.find(header, pos)
            if start < 0:
                return frames, (end if final else _partial_header_start(buffer, pos, header))
            if padded_header:
                while start + id_at < end and buffer[start + id_at] == 0xFF:
                    start += 1
            if start + body_at > end:
                if final:
                    pos = start + 1
                    continue
                return frames, start
            length = (buffer[start + length_at] | (buffer[start + length_high] << 8)
                      if wide_length else buffer[start + length_at])
            if length < min_length or length > max_length:
                pos = start + 1
                continue
            stop = start + body_at + length
            if stop > end:
                if final:
                    pos = start + 1
                    continue
                return frames, start
            raw = bytes(buffer[start:stop])
            crc_ok = check(raw[check_from:check_end]) == (
                raw[-2] | (raw[-1] << 8) if wide_check else raw[-1])
            frames.append(frame(start, stop, raw[id_at], raw[body_at], crc_ok, raw))
            pos = stop if crc_ok or not resync else start + 1

    return scan


LAYOUT_2 = FrameLayout(HEADER, 4, 5, 2, 3, MAX_PACKET_LENGTH, crc16, 0, 2, False, Frame)
# The whole Protocol 2.0 packets in a buffer (frame_scanner): a length field below 3 or above
# max_length (default MAX_PACKET_LENGTH) is noise.
scan_frames = frame_scanner(LAYOUT_2)


def fast_status_size(lengths: Sequence[int]) -> int:
    """Return the bytes of a fast read's status whose parts carry these data lengths."""
    return FAST_HEAD_SIZE + sum(lengths) + len(lengths) * FAST_PART_OVERHEAD


def fast_status_head(lengths: Sequence[int]) -> bytes:
    """Return the first bytes of a fast read's status whose parts carry these data lengths."""
    return HEADER + struct.pack('<BHB', BROADCAST_ID,
                                1 + sum(lengths) + len(lengths) * FAST_PART_OVERHEAD,
                                Instruction.STATUS)


def fast_sync_size(length: int, count: int) -> int:
    """Return the bytes of a Fast Sync Read status for count servos of length bytes each."""
    return fast_status_size((length,) * count)


def fast_sync_head(length: int, count: int) -> bytes:
    """Return the first bytes of a Fast Sync Read status for count servos of length bytes."""
    return fast_status_head((length,) * count)


def encode_fast_status(parts: Sequence[tuple[int, int, bytes]], lengths: Sequence[int]) -> bytes:
    """
    Return the one status packet of a Fast Sync Read or Fast Bulk Read as it goes on the wire.

    Each (error, id, data) part is followed by the CRC of every byte before it, so the last CRC
    is the packet's own. The length field counts the data lengths of every servo asked (the
    first servo sends the header before the others answer), so a part left out makes the packet
    shorter than its length field says. No byte stuffing: the length is fixed before the data
    is known (the SDK reads these packets unstuffed too).
    """
    packet = bytearray(fast_status_head(lengths))
    crc = crc16(packet)
    for error, servo_id, data in parts:
        start = len(packet)
        packet.append(error & 0xFF)
        packet.append(servo_id & 0xFF)
        packet += data
        crc = crc16(packet[start:], crc)
        packet += struct.pack('<H', crc)
        crc = crc16(packet[-2:], crc)
    return bytes(packet)


def encode_fast_sync_status(parts: list[tuple[int, int, bytes]], count: int) -> bytes:
    """Return a Fast Sync Read status for count servos asked (encode_fast_status)."""
    return encode_fast_status(parts, (len(parts[0][2]) if parts else 0,) * count)


def encode_fast_bulk_status(parts: Sequence[tuple[int, int, bytes]],
                            lengths: Sequence[int]) -> bytes:
    """Return a Fast Bulk Read status; lengths: every record's, in order (encode_fast_status)."""
    return encode_fast_status(parts, lengths)


def parse_fast_status(buffer: bytes | bytearray, start: int, ids: tuple[int, ...],
                      lengths: Sequence[int]) -> tuple[dict[int, tuple[int, bytes]], bool]:
    """
    Take apart the status of a Fast Sync Read or Fast Bulk Read that begins at buffer[start].

    ids are the servos asked in the order asked, lengths the data length each was asked for (a
    Fast Sync Read's all equal). Returns id -> (error byte, data) for every part whose id is
    one asked, after the id of the part before it (parts come in the order asked; a silent
    servo's part is missing, not empty), that has its id's length and whose CRC (over all
    bytes before it) checks, and whether the packet was whole: its head as expected, every
    part there and checked, the last one ending the packet. Parsing stops at the first part
    that does not check (every later CRC covers it, and its length says where the next one
    starts).
    """
    parts: dict[int, tuple[int, bytes]] = {}
    if buffer[start:start + FAST_HEAD_SIZE] != fast_status_head(lengths):
        return parts, False
    order = {servo_id: index for index, servo_id in enumerate(ids)}
    crc = crc16(buffer[start:start + FAST_HEAD_SIZE])
    pos = start + FAST_HEAD_SIZE
    end = len(buffer)
    last = -1
    while pos + FAST_PART_OVERHEAD <= end and len(parts) < len(ids):
        # The id, not yet checked, gives the part's length: a wrong one fails the CRC below.
        index = order.get(buffer[pos + 1], -1)
        if index <= last:
            break
        body_end = pos + 2 + lengths[index]
        if body_end + 2 > end:
            break
        crc = crc16(buffer[pos:body_end], crc)
        if crc != buffer[body_end] | (buffer[body_end + 1] << 8):
            break
        last = index
        parts[buffer[pos + 1]] = (buffer[pos], bytes(buffer[pos + 2:body_end]))
        crc = crc16(buffer[body_end:body_end + 2], crc)
        pos = body_end + 2
    return parts, len(parts) == len(ids)


def parse_fast_sync_status(buffer: bytes | bytearray, start: int, ids: tuple[int, ...],
                           length: int) -> tuple[dict[int, tuple[int, bytes]], bool]:
    """Take apart a Fast Sync Read status: parse_fast_status with every length equal."""
    return parse_fast_status(buffer, start, ids, (length,) * len(ids))


def decode_packet(data: bytes) -> Packet:
    """Decode exactly one whole packet; ValueError when it is not a valid packet."""
    data = bytes(data)
    if len(data) < 10 or not data.startswith(HEADER):
        raise ValueError('not a Protocol 2.0 packet (short or no header)')
    length = data[5] | (data[6] << 8)
    if length < 3 or len(data) != 7 + length:
        raise ValueError(f'length field {length} does not match {len(data)} bytes')
    if crc16(data[:-2]) != (data[-2] | (data[-1] << 8)):
        raise ValueError('CRC mismatch')
    return _packet_from_body(data[4], unstuff(data[7:-2]))


class StreamParser:
    """
    Incremental Protocol 2.0 parser (the simulated servos' receiver).

    feed() takes the bytes as they arrive and returns the whole packets found, framed by
    scan_frames() without resync: garbage before a header is skipped, a length field below 3 or
    above MAX_PACKET_LENGTH is noise, a packet whose CRC fails is reported with crc_ok False (its
    id and raw bytes as received) and skipped whole. A partial packet whose next byte comes
    later than inter_byte_timeout_s is discarded, as the servo's receiver does.
    """

    # The framing routine: this protocol's; protocol1.StreamParser1 swaps in Protocol 1.0's.
    _scan = staticmethod(scan_frames)

    def __init__(self, inter_byte_timeout_s: float = DEFAULT_INTER_BYTE_TIMEOUT_S) -> None:
        self.inter_byte_timeout_s = inter_byte_timeout_s
        self._buffer = bytearray()
        self._last_byte_s: float | None = None

    def reset(self) -> None:
        """Forget any partial packet."""
        self._buffer.clear()
        self._last_byte_s = None

    @property
    def pending(self) -> int:
        """Return how many bytes wait for the rest of their packet."""
        return len(self._buffer)

    def feed(self, chunk: bytes, now_s: float) -> list['ParseEvent']:
        """Add bytes received at now_s; return the packets completed by them."""
        buffer = self._buffer
        if (buffer and self._last_byte_s is not None
                and now_s - self._last_byte_s > self.inter_byte_timeout_s):
            buffer.clear()
        if chunk:
            buffer += chunk
            self._last_byte_s = now_s
        if not buffer:
            return []
        frames, rest = self._scan(buffer, resync=False)
        del buffer[:rest]
        return [ParseEvent(frame.packet(), frame.crc_ok, frame.raw) for frame in frames]


# What each ErrorCode of a status packet means, as a refusal is reported (Framer.error_text).
ERROR_TEXT: dict[int, str] = {
    ErrorCode.RESULT_FAIL: 'result fail (the servo could not process the instruction)',
    ErrorCode.INSTRUCTION: 'instruction error (unknown instruction, or ACTION without REG_WRITE)',
    ErrorCode.CRC: 'CRC error (the servo received a corrupted packet)',
    ErrorCode.DATA_RANGE: 'data range error (value outside the register range)',
    ErrorCode.DATA_LENGTH: 'data length error (wrong number of bytes for the register)',
    ErrorCode.DATA_LIMIT: 'data limit error (value beyond the limit register)',
    ErrorCode.ACCESS: 'access error (read-only register, or EEPROM while torque is on)',
}


class Framer(Protocol):
    """
    What the bus needs of a protocol: the seam a Protocol 1.0 framer plugs into.

    A framer encodes instruction packets and finds whole frames in received bytes; each frame
    says its id, whether its checksum held, whether it is a status packet and, if so, its error
    byte and parameters (Frame.status). In Protocol 1.0 a status packet has no instruction
    byte, so is_status only says a frame can be one: the bus compares a frame with the packet
    it sent before it takes it for an answer.

    Everything else the bus does differently by protocol is a fact or a method here, so the
    bus asks the framer rather than its version: the instructions a protocol has (sync read,
    the fast reads, broadcast ping, CLEAR, a reset's options), how an address and a length are
    written (2.0: two bytes each; 1.0: one, and what does not fit is refused: BadRequest), how
    a ping's answer gives the model number, how an error byte reads; and, for the trace decoder
    (tool/trace_decode.py), how a request's parameters read back. The instruction codes the
    bus sends in both (PING, READ, WRITE, FACTORY_RESET/RESET, REBOOT, SYNC_WRITE, BULK_READ)
    are the same bytes in both protocols, as are ACTION's and REG_WRITE's.
    """

    version: int                # the protocol's major version: 1 or 2 (for messages)
    status_overhead: int        # bytes of a status packet around its parameters
    refusal_mask: int           # error byte bits that say the instruction was refused
    alert_mask: int             # error byte bits that report a hardware error (not a refusal)
    ping_reply_params: int      # parameters of a ping's answer (2.0: model number, firmware)
    # Where the model number (2 bytes) is read when a ping's answer does not carry it (1.0:
    # address 0); None: the answer carries it.
    model_number_address: int | None
    broadcast_ping: bool        # every servo answers a ping to the broadcast id
    sync_read: bool             # SYNC_READ exists (1.0 has BULK_READ only)
    fast_read: bool             # FAST_SYNC_READ and FAST_BULK_READ exist
    multi_turn_clear: bool      # CLEAR exists (the multi-turn count's reset)
    # Our own packets coming back (the local echo) look like status packets: the bus keeps the
    # last few it sent, so a late echo of one is never taken for an answer.
    echo_like_status: bool
    # Its status packets have the layout the bus's whole-block parses compare byte for byte
    # (group_reads.BlockTemplate, the clean parse of a sync or bulk read): 2.0's.
    clean_block: bool
    layout: FrameLayout         # where its packets keep what its scan reads (frame_scanner)
    check_name: str             # what a packet's check is called: 'CRC' or 'checksum'
    bad_check_fate: str         # what a servo does with a request whose check fails: for a person
    address_size: int           # bytes of an address, and of a length, in a request's parameters
    # Instructions no servo answers, even sent to one id (besides any sent to the broadcast id).
    unanswered: frozenset[int]

    def encode(self, servo_id: int, instruction: int, params: bytes = b'') -> bytes:
        """Return a whole instruction packet as it goes on the wire."""

    def scan(self, buffer: bytes | bytearray, pos: int, max_length: int,
             final: bool) -> tuple[list[Frame], int]:
        """Return the whole frames in buffer from pos on, and where unconsumed bytes begin."""

    def error_text(self, code: int) -> str:
        """Return what the refusal bits of an error byte say, for a person."""

    def address_param(self, address: int, length: int, other_params: int = 0) -> bytes:
        """Return the address parameter of an access of length bytes (BadRequest: unreachable)."""

    def address_length(self, address: int, length: int) -> bytes:
        """Return the address and length parameters of an access (BadRequest: unreachable)."""

    def fit_read(self, address: int, length: int, before: int, extra: int) -> tuple[int, int]:
        """
        Return (before, extra) cut so a widened read stays inside what the protocol reaches.

        The read of length bytes at address is widened by extra bytes, before of them ahead of
        address (the bus's length tag); BadRequest when the read itself is out of reach.
        """

    def bulk_read_params(self, records: Sequence[tuple[int, int, int]]) -> bytes:
        """Return the parameters of a BULK_READ of (id, address, length) records."""

    def reset_params(self, option: int) -> bytes | None:
        """Return the parameters of a FACTORY_RESET with option; None: the protocol has none."""

    def bulk_read_records(self, params: bytes) -> list[tuple[int, int, int]] | None:
        """Return a BULK_READ's (id, address, length) records; None: params cannot be one."""

    def instruction_name(self, code: int) -> str:
        """Return the name of an instruction code, or `instruction 0x..` for one it has not."""

    def refusal_text(self, error: int) -> str:
        """Return the refusal an error byte reports, code and meaning, for a person ('': none)."""

    def alert_text(self, error: int) -> str:
        """Return the hardware state an error byte reports, for a person ('': none)."""

    def ping_model(self, data: bytes) -> tuple[int, int] | None:
        """Return (model number, firmware) a ping's answer carries; None when it carries none."""


class Protocol2Framer:
    """Protocol 2.0 framing (this module's functions), as the bus's Framer."""

    version = 2
    status_overhead = STATUS_OVERHEAD
    refusal_mask = ERROR_CODE_MASK
    alert_mask = ALERT_BIT
    ping_reply_params = 3
    model_number_address: int | None = None
    broadcast_ping = True
    sync_read = True
    fast_read = True
    multi_turn_clear = True
    echo_like_status = False    # a status has instruction 0x55: no packet we send has
    clean_block = True
    layout = LAYOUT_2
    check_name = 'CRC'
    bad_check_fate = 'refuse it'   # its status has the CRC error (ErrorCode.CRC)
    address_size = 2
    unanswered: frozenset[int] = frozenset({Instruction.SYNC_WRITE, Instruction.BULK_WRITE})

    def encode(self, servo_id: int, instruction: int, params: bytes = b'') -> bytes:
        """Return a whole instruction packet as it goes on the wire."""
        return encode_instruction(servo_id, instruction, params)

    def scan(self, buffer: bytes | bytearray, pos: int, max_length: int,
             final: bool) -> tuple[list[Frame], int]:
        """Return the whole frames in buffer from pos on (scan_frames with resync)."""
        return scan_frames(buffer, pos, max_length=max_length, final=final)

    def error_text(self, code: int) -> str:
        """Return the ErrorCode's text (ERROR_TEXT), or the code's number for another."""
        return ERROR_TEXT.get(code, str(code))

    def address_param(self, address: int, length: int, other_params: int = 0) -> bytes:
        """Return the address in two bytes (every access fits: nothing is checked)."""
        return struct.pack('<H', address)

    def address_length(self, address: int, length: int) -> bytes:
        """Return the two-byte address and the two-byte length."""
        return struct.pack('<HH', address, length)

    def fit_read(self, address: int, length: int, before: int, extra: int) -> tuple[int, int]:
        """Return (before, extra) as they are: two-byte fields hold every widened read."""
        return before, extra

    def bulk_read_params(self, records: Sequence[tuple[int, int, int]]) -> bytes:
        """Return id, address (2 bytes), length (2 bytes) of each record (FAST_BULK_READ's too)."""
        params = bytearray()
        for servo_id, address, length in records:
            params += struct.pack('<BHH', servo_id, address, length)
        return bytes(params)

    def reset_params(self, option: int) -> bytes | None:
        """Return the option byte (0xFF all, 0x01 all but the id, 0x02 but id and baud)."""
        return bytes((option,))

    def bulk_read_records(self, params: bytes) -> list[tuple[int, int, int]] | None:
        """Return the records of id, address (2 bytes), length (2 bytes) (FAST_BULK_READ's too)."""
        return [cast(tuple[int, int, int], struct.unpack_from('<BHH', params, at))
                for at in range(0, len(params) - 4, 5)]

    def instruction_name(self, code: int) -> str:
        """Return the Instruction's name, or `instruction 0x..`."""
        try:
            return Instruction(code).name
        except ValueError:
            return f'instruction 0x{code:02x}'

    def refusal_text(self, error: int) -> str:
        """Return the ErrorCode's number and text ('unknown' for another number; '': none)."""
        code = error & ERROR_CODE_MASK
        return f'{code}: {ERROR_TEXT.get(code, "unknown")}' if code else ''

    def alert_text(self, error: int) -> str:
        """Return that the alert bit is set: the Hardware Error Status register says which."""
        return '(hardware error: read hardware_error_status)' if error & ALERT_BIT else ''

    def ping_model(self, data: bytes) -> tuple[int, int] | None:
        """Return the model number (2 bytes) and firmware (1) a ping's answer starts with."""
        if len(data) < self.ping_reply_params:
            return None
        return data[0] | (data[1] << 8), data[2]


PROTOCOL_2 = Protocol2Framer()
