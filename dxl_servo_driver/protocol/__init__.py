"""
Packets of both Dynamixel protocols: the facts of the wire, with no I/O.

The face of the protocol layer: the rest of the package imports packets from here. protocol2
holds Protocol 2.0 (packets, CRC-16, byte stuffing, the fast reads' one status) and the Framer
seam; protocol1 holds Protocol 1.0 (checksum, its packets, its Framer PROTOCOL_1). What differs
between the two is the framer's to say, never a branch on a version number elsewhere.
"""

from typing import Dict

from dxl_servo_driver.protocol import protocol1
from dxl_servo_driver.protocol.protocol2 import (
    ALERT_BIT, BITS_PER_BYTE, BROADCAST_ID, CLEAR_MULTI_TURN, crc16, crc16_python,
    CRC_IMPLEMENTATION, decode_packet, encode_fast_bulk_status, encode_fast_status,
    encode_fast_sync_status, encode_instruction, encode_status, ERROR_CODE_MASK, ERROR_TEXT,
    ErrorCode, FAST_HEAD_SIZE, FAST_PART_OVERHEAD, fast_status_head, fast_status_size,
    fast_sync_head, fast_sync_size, Frame, Framer, HEADER, Instruction, INSTRUCTION_OVERHEAD,
    MAX_ID, MAX_PACKET_LENGTH, Packet, parse_fast_status, parse_fast_sync_status, ParseEvent,
    PROTOCOL_2, READ_PACKET_SIZE, RETURN_DELAY_UNIT_S, scan_frames, STATUS_OVERHEAD,
    StreamParser, stuff, unstuff)

# The framer of each protocol version, as configurations name them.
FRAMERS: Dict[float, Framer] = {1.0: protocol1.PROTOCOL_1, 2.0: PROTOCOL_2}

__all__ = [
    'ALERT_BIT', 'BITS_PER_BYTE', 'BROADCAST_ID', 'CLEAR_MULTI_TURN', 'crc16', 'crc16_python',
    'CRC_IMPLEMENTATION', 'decode_packet', 'encode_fast_bulk_status', 'encode_fast_status',
    'encode_fast_sync_status', 'encode_instruction', 'encode_status', 'ERROR_CODE_MASK',
    'ERROR_TEXT', 'ErrorCode', 'FAST_HEAD_SIZE', 'FAST_PART_OVERHEAD', 'fast_status_head',
    'fast_status_size', 'fast_sync_head', 'fast_sync_size', 'Frame', 'Framer', 'FRAMERS', 'HEADER',
    'Instruction', 'INSTRUCTION_OVERHEAD', 'MAX_ID', 'MAX_PACKET_LENGTH', 'Packet',
    'parse_fast_status', 'parse_fast_sync_status', 'ParseEvent', 'PROTOCOL_2',
    'READ_PACKET_SIZE', 'RETURN_DELAY_UNIT_S', 'scan_frames', 'STATUS_OVERHEAD',
    'StreamParser', 'stuff', 'unstuff', 'protocol1',
]
