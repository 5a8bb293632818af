"""
The whole-block decode of the usual cycle read (bus.BlockTemplate) against the careful path.

The fast path may only take a block the careful path takes as whole and clean (every reply
there, in order, every CRC good, every error byte 0), and must give the same values; anything
else it leaves to the careful path. Checked on every reply block a faulty adapter (the fault
fixture: late, duplicated, truncated, noisy, dropped and echoed replies) delivered to sync and
fast sync reads of simulated servos, and on every one-byte change, cut and extension of a clean
block.
"""

import struct
from typing import Dict, Iterator, List, Optional, Tuple

from dxl_servo_driver.bus import Bus
from dxl_servo_driver.bus.group_reads import BlockTemplate, parse_clean, sync_read_packet
from dxl_servo_driver.driver import state_block
from dxl_servo_driver.models import model_for
from dxl_servo_driver.protocol import (
    fast_sync_size, Instruction, parse_fast_status, STATUS_OVERHEAD)
from dxl_servo_driver.sim.bus import SimBus
from dxl_servo_driver.sim.faulty_port import FaultyPort
from dxl_servo_driver.sim.port import SimPortHandler
from dxl_servo_driver.sim.virtual_bus import configure_servos
import pytest

BAUD = 1_000_000
IDS = (1, 2, 3, 4)
BLOCK = state_block.state_block(model_for(1030), 'present_current')
LENGTH = BLOCK.tagged_size
FIELDS = BLOCK.tagged_struct.format.lstrip('<')
PROFILES: Dict[str, Dict[str, object]] = {
    'late': {'late_probability': 0.3, 'late_ms': (0.0, 3.0)},
    'duplicate': {'duplicate_probability': 0.3},
    'truncate': {'truncate_probability': 0.3},
    'noise': {'noise_probability': 0.3, 'noise_bytes': (1, 12)},
    'drop': {'drop_probability': 0.2},
    'echo': {'echo': True, 'drop_probability': 0.1},
}
READS_PER_PROFILE = 60


class Recorder:
    """A raw port that keeps what each read returned after a (fast) sync read went out."""

    def __init__(self, port: FaultyPort) -> None:
        self.port = port
        self.blocks: List[Tuple[bytes, bytes]] = []   # (request, what its first read gave)
        self._request = b''

    @property
    def baudrate(self) -> int:
        return self.port.baudrate

    @baudrate.setter
    def baudrate(self, baud_bps: int) -> None:
        self.port.baudrate = baud_bps

    @property
    def in_waiting(self) -> int:
        return self.port.in_waiting

    def write(self, data: bytes) -> int:
        reading = data[7] in (Instruction.SYNC_READ, Instruction.FAST_SYNC_READ)
        self._request = bytes(data) if reading else b''
        return self.port.write(data)

    def read(self, size: int, timeout_s: float) -> bytes:
        data = self.port.read(size, timeout_s)
        if self._request:
            # The first read of a sync read: what the bus parses.
            self.blocks.append((self._request, data))
            self._request = b''
        return data

    def reset_input_buffer(self) -> None:
        self.port.reset_input_buffer()

    def close(self) -> None:
        self.port.close()


def careful(buffer: bytes, fast: bool) -> Optional[List[Tuple[int, ...]]]:
    """Return each servo's values when the careful path takes buffer as whole, clean, no error."""
    if fast:
        if len(buffer) != fast_sync_size(LENGTH, len(IDS)):
            return None
        parts, whole = parse_fast_status(buffer, 0, IDS, (LENGTH,) * len(IDS))
        if not whole or any(error for error, _ in parts.values()):
            return None
        return [BLOCK.decode_tagged(parts[servo_id][1]) for servo_id in IDS]
    results = parse_clean(buffer, IDS, (LENGTH,) * len(IDS))
    if results is None:
        return None
    return [BLOCK.decode_tagged(results[servo_id]) for servo_id in IDS]


def fast_path(template: BlockTemplate, buffer: bytes) -> Optional[List[Tuple[int, ...]]]:
    values = template.parse(buffer)
    if values is None:
        return None
    count = template.fields_per_servo
    return [values[k * count:(k + 1) * count] for k in range(len(IDS))]


@pytest.fixture(scope='module')
def recorded() -> Iterator[Dict[Tuple[str, bool], List[Tuple[bytes, bytes]]]]:
    """Reply blocks of sync and fast sync reads behind each fault profile (seeded)."""
    sim = SimBus(list(IDS), seed=5, boot_time_s=0.0)
    configure_servos(sim, BAUD, None)
    blocks: Dict[Tuple[str, bool], List[Tuple[bytes, bytes]]] = {}
    for seed, (name, faults) in enumerate(PROFILES.items(), start=1):
        faulty = FaultyPort(SimPortHandler(sim, 'sim', BAUD), seed=seed)
        recorder = Recorder(faulty)
        bus = Bus(recorder, BAUD, latency_timer_s=0.0, return_delay_s=0.0)
        for servo_id in IDS:
            bus.write(servo_id, BLOCK.indirect_map_address(), BLOCK.indirect_map_bytes())
        faulty.set(**faults)
        for fast in (False, True):
            recorder.blocks.clear()
            for _ in range(READS_PER_PROFILE):
                bus.begin_sync_read(BLOCK.read_address, LENGTH, IDS, fast, fields=FIELDS).collect()
            blocks[name, fast] = list(recorder.blocks)
        faulty.close()
    yield blocks


@pytest.mark.parametrize('fast', [False, True], ids=['sync', 'fast_sync'])
def test_on_the_fault_fixture_the_fast_path_takes_exactly_what_the_careful_path_takes(
        recorded: Dict[Tuple[str, bool], List[Tuple[bytes, bytes]]], fast: bool) -> None:
    template = BlockTemplate(IDS, LENGTH, FIELDS, fast)
    refused = 0
    for profile in PROFILES:
        blocks = recorded[profile, fast]
        assert len(blocks) == READS_PER_PROFILE
        taken = 0
        for packet, buffer in blocks:
            if buffer.startswith(packet):
                buffer = buffer[len(packet):]   # the local echo: the bus strips it first
            expected = careful(buffer, fast)
            assert fast_path(template, buffer) == expected, (profile, buffer.hex())
            taken += expected is not None
        assert taken > 0, profile
        refused += len(blocks) - taken
    # The faults spoilt blocks too (49 of 360 fast, more in sync): the refusing side was
    # exercised as well.
    assert refused >= 20, refused


def clean_block(fast: bool) -> bytes:
    sim = SimBus(list(IDS), seed=2, boot_time_s=0.0)
    configure_servos(sim, BAUD, None)
    port = SimPortHandler(sim, 'sim', BAUD)
    bus = Bus(port, BAUD, latency_timer_s=0.0, return_delay_s=0.0)
    for servo_id in IDS:
        bus.write(servo_id, BLOCK.indirect_map_address(), BLOCK.indirect_map_bytes())
    packet = sync_read_packet(BLOCK.read_address, LENGTH, IDS, fast)
    port.write(packet)
    return port.read(4096, 0.0)


@pytest.mark.parametrize('fast', [False, True], ids=['sync', 'fast_sync'])
def test_every_one_byte_change_cut_and_extension_is_judged_alike(fast: bool) -> None:
    template = BlockTemplate(IDS, LENGTH, FIELDS, fast)
    block = clean_block(fast)
    values = careful(block, fast)
    assert values is not None and fast_path(template, block) == values
    assert all(v[0] for v in values)   # a servo's sample, not a block of zeros
    variants = [block[:cut] for cut in range(len(block))]
    variants += [block + b'\x00', b'\xff' + block, block + block]
    for position in range(len(block)):
        for value in {block[position] ^ 0x01, block[position] ^ 0x80, 0x00, 0xFF, 0xFD}:
            variants.append(block[:position] + bytes((value,)) + block[position + 1:])
    for variant in variants:
        if variant == block:
            continue
        assert fast_path(template, variant) == careful(variant, fast), variant.hex()
        assert fast_path(template, variant) is None, variant.hex()


def test_an_alert_goes_the_careful_way() -> None:
    # A reply whose error byte has the alert bit (a hardware error) is an answer the careful
    # path takes with its alert: never the fast path, which would lose the alert.
    block = bytearray(clean_block(False))
    reply = STATUS_OVERHEAD + LENGTH
    block[8] = 0x80   # the first reply's error byte
    crc_at = reply - 2
    from dxl_servo_driver.protocol import crc16
    struct.pack_into('<H', block, crc_at, crc16(bytes(block[:crc_at])))
    template = BlockTemplate(IDS, LENGTH, FIELDS, False)
    assert template.parse(bytes(block)) is None
    assert careful(bytes(block), False) is None


def test_fields_must_fill_the_read() -> None:
    with pytest.raises(ValueError, match='take 12 bytes, the read 10'):
        BlockTemplate(IDS, 10, FIELDS, False)
