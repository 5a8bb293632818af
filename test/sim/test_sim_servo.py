"""
One simulated servo's instructions, error codes and register side effects, at the byte level.

The clock is injected and kept still unless a test moves it, so no physics runs between packets
and the results do not depend on the motor model or the machine's speed.
"""

import struct

from dxl_servo_driver.models import model_for, xm430
from dxl_servo_driver.protocol import (
    ALERT_BIT, BROADCAST_ID, crc16, decode_packet, encode_instruction, encode_status, ErrorCode,
    Instruction, Packet)
from dxl_servo_driver.sim import protocol2
from dxl_servo_driver.sim import servo as sim_servo
from dxl_servo_driver.sim.bus import SimBus
import pytest

MANUAL = model_for(xm430.MODEL_NUMBER)   # the XM430 manual's table

BAUD = 57600
FORMATS = {(1, False): '<B', (1, True): '<b', (2, False): '<H', (2, True): '<h',
           (4, False): '<I', (4, True): '<i'}


def pack(name: str, value: int) -> bytes:
    """Return the little-endian bytes of a register value."""
    item = MANUAL.item(name)
    return struct.pack(FORMATS[(item.size, item.signed)], value)


def write_params(name: str, value: int) -> bytes:
    """Return WRITE parameters for one item."""
    return struct.pack('<H', MANUAL.item(name).address) + pack(name, value)


def read_params(name: str) -> bytes:
    """Return READ parameters for one item."""
    item = MANUAL.item(name)
    return struct.pack('<HH', item.address, item.size)


class Bench:
    """A SimBus with a hand-moved clock."""

    def __init__(self, ids: tuple[int, ...] = (1,), boot_time_s: float = 0.1) -> None:
        self.now_s = 0.0
        self.bus = SimBus(ids, clock=lambda: self.now_s, seed=7, boot_time_s=boot_time_s)

    def raw(self, data: bytes, baud: int = BAUD) -> list[bytes]:
        return [reply.data for reply in self.bus.feed(data, baud)]

    def send(self, servo_id: int, instruction: int, params: bytes = b'',
             baud: int = BAUD) -> list[Packet]:
        return [decode_packet(data)
                for data in self.raw(encode_instruction(servo_id, instruction, params), baud)]

    def one(self, servo_id: int, instruction: int, params: bytes = b'') -> Packet:
        replies = self.send(servo_id, instruction, params)
        assert len(replies) == 1, replies
        return replies[0]

    def write(self, servo_id: int, name: str, value: int) -> int:
        """Write one item; return the status error byte."""
        return self.one(servo_id, Instruction.WRITE, write_params(name, value)).error

    def reg(self, servo_id: int, name: str) -> int:
        return self.bus.read_register(servo_id, name)


@pytest.fixture
def bench() -> Bench:
    return Bench()


# ---- instructions, checked against hand-built packets ------------------------------------------
def test_ping_reply_bytes(bench: Bench) -> None:
    replies = bench.raw(bytes.fromhex('FFFFFD0001030001194E'))
    assert replies == [encode_status(1, 0, bytes((0x06, 0x04, 45)))]
    assert bench.bus.feed(bytes.fromhex('FFFFFD0001030001194E'), BAUD)[0].return_delay_s == (
        pytest.approx(500e-6))


def test_read_model_number_bytes(bench: Bench) -> None:
    request = bytes.fromhex('FFFFFD000107000200000200')
    crc = crc16(request)
    replies = bench.raw(request + bytes((crc & 0xFF, crc >> 8)))
    assert replies == [encode_status(1, 0, bytes((0x06, 0x04)))]


def test_write_led_status_bytes_and_effect(bench: Bench) -> None:
    assert bench.raw(encode_instruction(1, Instruction.WRITE, bytes((65, 0, 1)))) == [
        bytes.fromhex('FFFFFD000104005500A10C')]
    assert bench.reg(1, 'led') == 1


def test_read_spanning_reserved_addresses_reads_zero(bench: Bench) -> None:
    status = bench.one(1, Instruction.READ, struct.pack('<HH', 24, 8))
    assert status.error == 0
    # moving_threshold 10 (24..27), reserved 28..30, temperature_limit 80 (31)
    assert status.params == bytes((10, 0, 0, 0, 0, 0, 0, 80))


def test_read_errors(bench: Bench) -> None:
    assert bench.one(1, Instruction.READ, struct.pack('<HH', 660, 4)).error == ErrorCode.ACCESS
    assert bench.one(1, Instruction.READ, struct.pack('<HH', 0, 0)).error == (
        ErrorCode.DATA_LENGTH)
    assert bench.one(1, Instruction.READ, bytes((0, 0, 2))).error == ErrorCode.DATA_LENGTH
    status = bench.one(1, Instruction.READ, struct.pack('<HH', 0, 662))
    assert status.error == 0 and len(status.params) == 662


def test_unknown_instruction_and_status_instruction(bench: Bench) -> None:
    assert bench.one(1, 0x7F).error == ErrorCode.INSTRUCTION
    assert bench.send(BROADCAST_ID, 0x7F) == []
    assert bench.send(1, Instruction.STATUS, b'\x00') == []


# ---- write errors --------------------------------------------------------------------------
@pytest.mark.parametrize('params,code', [
    (write_params('model_number', 1), ErrorCode.ACCESS),          # read-only
    (write_params('present_position', 5), ErrorCode.ACCESS),
    (bytes((28, 0, 1)), ErrorCode.ACCESS),                         # reserved address 28
    (bytes((0x95, 0x02, 1, 1)), ErrorCode.ACCESS),                 # beyond the table (662)
    (bytes((116, 0, 1, 2)), ErrorCode.DATA_LENGTH),                # half of goal_position
    (bytes((65, 0)), ErrorCode.DATA_LENGTH),                       # no data
    (write_params('operating_mode', 2), ErrorCode.DATA_RANGE),
    (write_params('led', 2), ErrorCode.DATA_RANGE),
    (write_params('id', 253), ErrorCode.DATA_RANGE),
    (write_params('return_delay_time', 255), ErrorCode.DATA_RANGE),
    (write_params('homing_offset', 1_044_480), ErrorCode.DATA_RANGE),
    (write_params('indirect_address_1', 63), ErrorCode.DATA_RANGE),
    (write_params('goal_velocity', 481), ErrorCode.DATA_LIMIT),    # velocity_limit 480
    (write_params('goal_velocity', -481), ErrorCode.DATA_LIMIT),
    (write_params('profile_velocity', 481), ErrorCode.DATA_LIMIT),
    (write_params('goal_position', 4096), ErrorCode.DATA_LIMIT),   # mode 3: 0..4095
    (write_params('goal_position', -1), ErrorCode.DATA_LIMIT),
])
def test_write_error_codes(bench: Bench, params: bytes, code: int) -> None:
    before = bench.bus.registers(1)
    status = bench.one(1, Instruction.WRITE, params)
    assert status.error == code
    assert status.params == b''
    assert bench.bus.registers(1) == before


def test_dynamic_limits_follow_the_limit_registers(bench: Bench) -> None:
    assert bench.write(1, 'pwm_limit', 300) == 0
    assert bench.write(1, 'current_limit', 200) == 0
    assert bench.write(1, 'acceleration_limit', 100) == 0
    assert bench.write(1, 'min_position_limit', 1000) == 0
    assert bench.write(1, 'max_position_limit', 3000) == 0
    assert bench.write(1, 'goal_pwm', 301) == ErrorCode.DATA_LIMIT
    assert bench.write(1, 'goal_pwm', -300) == 0
    assert bench.write(1, 'goal_current', -201) == ErrorCode.DATA_LIMIT
    assert bench.write(1, 'goal_current', 200) == 0
    assert bench.write(1, 'profile_acceleration', 101) == ErrorCode.DATA_LIMIT
    assert bench.write(1, 'profile_acceleration', 100) == 0
    assert bench.write(1, 'goal_position', 999) == ErrorCode.DATA_LIMIT
    assert bench.write(1, 'goal_position', 3001) == ErrorCode.DATA_LIMIT
    assert bench.write(1, 'goal_position', 3000) == 0
    # The static range still wins beyond the widest limit.
    assert bench.write(1, 'goal_pwm', 886) == ErrorCode.DATA_RANGE
    assert bench.write(1, 'operating_mode', 4) == 0
    assert bench.write(1, 'goal_position', -1_048_575) == 0
    assert bench.write(1, 'goal_position', 1_048_576) == ErrorCode.DATA_LIMIT
    assert bench.write(1, 'operating_mode', 1) == 0
    assert bench.write(1, 'goal_position', 5_000_000) == 0  # unused in velocity mode


def test_write_is_all_or_nothing(bench: Bench) -> None:
    # goal_velocity (104), profile_acceleration (108), profile_velocity (112) in one packet,
    # the last one beyond velocity_limit.
    params = struct.pack('<HiII', 104, 100, 50, 481)
    assert bench.one(1, Instruction.WRITE, params).error == ErrorCode.DATA_LIMIT
    assert (bench.reg(1, 'goal_velocity'), bench.reg(1, 'profile_acceleration')) == (0, 0)
    params = struct.pack('<HiII', 104, 100, 50, 480)
    assert bench.one(1, Instruction.WRITE, params).error == 0
    assert [bench.reg(1, name) for name in ('goal_velocity', 'profile_acceleration',
                                            'profile_velocity')] == [100, 50, 480]


# ---- EEPROM lock, torque, modes -------------------------------------------------------------
def test_eeprom_locked_while_torque_on(bench: Bench) -> None:
    assert bench.write(1, 'torque_enable', 1) == 0
    for name, value in (('id', 5), ('operating_mode', 1), ('homing_offset', 10),
                        ('shutdown', 0), ('velocity_limit', 100)):
        assert bench.write(1, name, value) == ErrorCode.ACCESS, name
    assert bench.reg(1, 'id') == 1
    assert bench.write(1, 'led', 1) == 0  # RAM stays writable
    assert bench.write(1, 'torque_enable', 0) == 0
    assert bench.write(1, 'velocity_limit', 100) == 0


def test_torque_enable_holds_present_and_goal_follows(bench: Bench) -> None:
    # A goal written with torque off is not acted on; torque on holds the horn where it is and
    # goal_position shows that (module docstring of sim/servo.py).
    assert bench.write(1, 'goal_position', 100) == 0
    assert bench.write(1, 'torque_enable', 1) == 0
    present = bench.reg(1, 'present_position')
    assert 0 <= present <= 4095
    assert present != 100
    assert bench.reg(1, 'goal_position') == present


def test_operating_mode_change_resets(bench: Bench) -> None:
    changes = {'profile_velocity': 100, 'profile_acceleration': 50, 'goal_pwm': 500,
               'goal_current': -300, 'velocity_i_gain': 1, 'velocity_p_gain': 2,
               'position_d_gain': 3, 'position_i_gain': 4, 'position_p_gain': 5,
               'feedforward_2nd_gain': 6, 'feedforward_1st_gain': 7, 'led': 1}
    for name, value in changes.items():
        assert bench.write(1, name, value) == 0, name
    assert bench.write(1, 'pwm_limit', 600) == 0
    assert bench.write(1, 'current_limit', 700) == 0
    bench.bus.servo(1).dynamics.horn_position_pulse = 3 * 4096 + 123.0
    assert bench.write(1, 'operating_mode', 4) == 0
    regs = bench.bus.registers(1)
    assert regs['profile_velocity'] == 0 and regs['profile_acceleration'] == 0
    assert regs['goal_pwm'] == 600 and regs['goal_current'] == 700
    for name in ('velocity_i_gain', 'velocity_p_gain', 'position_d_gain', 'position_i_gain',
                 'position_p_gain', 'feedforward_2nd_gain', 'feedforward_1st_gain'):
        assert regs[name] == MANUAL.item(name).initial, name
    assert regs['led'] == 1
    assert regs['present_position'] == 123  # re-initialised within one turn


def test_homing_offset_beyond_1024_ignored_in_position_mode(bench: Bench) -> None:
    assert bench.write(1, 'homing_offset', 1024) == 0
    assert bench.write(1, 'homing_offset', 2000) == 0  # accepted, ignored
    assert bench.reg(1, 'homing_offset') == 1024
    assert bench.write(1, 'operating_mode', 4) == 0
    assert bench.write(1, 'homing_offset', -2000) == 0
    assert bench.reg(1, 'homing_offset') == -2000


# ---- REG_WRITE / ACTION ---------------------------------------------------------------------
def test_reg_write_and_action(bench: Bench) -> None:
    assert bench.one(1, Instruction.ACTION).error == ErrorCode.INSTRUCTION
    assert bench.one(1, Instruction.REG_WRITE, write_params('led', 1)).error == 0
    assert bench.reg(1, 'registered_instruction') == 1
    assert bench.reg(1, 'led') == 0
    assert bench.one(1, Instruction.ACTION).error == 0
    assert bench.reg(1, 'led') == 1
    assert bench.reg(1, 'registered_instruction') == 0
    assert bench.one(1, Instruction.ACTION).error == ErrorCode.INSTRUCTION


def test_reg_write_errors_register_nothing(bench: Bench) -> None:
    status = bench.one(1, Instruction.REG_WRITE, write_params('goal_velocity', 1000))
    assert status.error == ErrorCode.DATA_LIMIT
    assert bench.reg(1, 'registered_instruction') == 0


def test_broadcast_action_moves_several_servos_silently() -> None:
    bench = Bench((1, 2, 3))
    for servo_id in (1, 3):
        status = bench.one(servo_id, Instruction.REG_WRITE, write_params('goal_velocity', 7))
        assert status.error == 0
    assert bench.send(BROADCAST_ID, Instruction.ACTION) == []
    assert [bench.reg(i, 'goal_velocity') for i in (1, 2, 3)] == [7, 0, 7]


# ---- REBOOT, FACTORY_RESET, CLEAR -----------------------------------------------------------
def test_reboot_replies_then_boots_with_ram_defaults() -> None:
    bench = Bench(boot_time_s=0.2)
    assert bench.write(1, 'return_delay_time', 0) == 0          # EEPROM, kept
    assert bench.write(1, 'led', 1) == 0                        # RAM, reset
    assert bench.write(1, 'torque_enable', 1) == 0
    bench.bus.inject_error(1, 'encoder')                        # not a shutdown bit by default
    assert bench.reg(1, 'hardware_error_status') == 0x08
    bench.bus.servo(1).dynamics.horn_position_pulse = -2 * 4096 + 10.0
    status = bench.one(1, Instruction.REBOOT)
    assert status.error == ALERT_BIT
    bench.now_s = 0.1
    assert bench.send(1, Instruction.PING) == []                # still booting
    bench.now_s = 0.25
    assert bench.one(1, Instruction.PING).error == 0            # error cleared, no alert
    regs = bench.bus.registers(1)
    assert regs['led'] == 0 and regs['torque_enable'] == 0
    assert regs['hardware_error_status'] == 0
    assert regs['return_delay_time'] == 0
    assert regs['present_position'] == 10
    assert regs['goal_pwm'] == 885 and regs['goal_current'] == 1193


def test_reboot_with_parameters_is_a_length_error(bench: Bench) -> None:
    assert bench.one(1, Instruction.REBOOT, b'\x01').error == ErrorCode.DATA_LENGTH
    assert bench.one(1, Instruction.PING).error == 0


@pytest.mark.parametrize('option,expect_id,expect_baud', [
    (0xFF, 1, 1), (0x01, 9, 1), (0x02, 9, 2)])
def test_factory_reset_options(option: int, expect_id: int, expect_baud: int) -> None:
    bench = Bench((9,), boot_time_s=0.0)
    for name, value in (('return_delay_time', 3), ('velocity_limit', 100)):
        assert bench.write(9, name, value) == 0
    assert bench.write(9, 'baud_rate', 2) == 0
    status = bench.send(9, Instruction.FACTORY_RESET, bytes((option,)), baud=115200)
    assert [(s.servo_id, s.error) for s in status] == [(9, 0)]
    regs = bench.bus.registers(expect_id)
    assert (regs['id'], regs['baud_rate']) == (expect_id, expect_baud)
    assert regs['return_delay_time'] == 250 and regs['velocity_limit'] == 480


def test_factory_reset_bad_parameters_and_broadcast_all() -> None:
    bench = Bench((4, 5), boot_time_s=0.0)
    assert bench.one(4, Instruction.FACTORY_RESET, b'').error == ErrorCode.DATA_LENGTH
    assert bench.one(4, Instruction.FACTORY_RESET, b'\x03').error == ErrorCode.DATA_RANGE
    assert bench.write(4, 'velocity_limit', 100) == 0
    assert bench.send(BROADCAST_ID, Instruction.FACTORY_RESET, b'\xff') == []
    assert bench.bus.servo_ids() == [4, 5]
    assert bench.reg(4, 'velocity_limit') == 100
    assert bench.send(BROADCAST_ID, Instruction.FACTORY_RESET, b'\x01') == []
    assert bench.reg(4, 'velocity_limit') == 480


def test_clear_multi_turn(bench: Bench) -> None:
    assert bench.write(1, 'operating_mode', 4) == 0
    bench.bus.servo(1).dynamics.horn_position_pulse = 5 * 4096 + 77.0
    bench.bus.servo(1).advance(0.001)
    bench.now_s = 0.001
    assert bench.reg(1, 'present_position') == 5 * 4096 + 77
    clear = b'\x01\x44\x58\x4c\x22'
    assert bench.one(1, Instruction.CLEAR, clear).error == 0
    assert bench.reg(1, 'present_position') == 77
    assert bench.one(1, Instruction.CLEAR, b'\x01\x44\x58\x4c').error == ErrorCode.DATA_LENGTH
    assert bench.one(1, Instruction.CLEAR, b'\x02\x44\x58\x4c\x22').error == (
        ErrorCode.DATA_RANGE)
    bench.bus.servo(1).memory.set('moving', 1)
    assert bench.one(1, Instruction.CLEAR, clear).error == ErrorCode.RESULT_FAIL


# ---- hardware errors, shutdown --------------------------------------------------------------
def test_shutdown_latches_and_refuses_torque(bench: Bench) -> None:
    assert bench.write(1, 'torque_enable', 1) == 0
    bench.bus.inject_error(1, 'overload')
    regs = bench.bus.registers(1)
    assert regs['hardware_error_status'] == 0x20 and regs['torque_enable'] == 0
    ping = bench.one(1, Instruction.PING)
    assert ping.error == ALERT_BIT
    assert bench.write(1, 'torque_enable', 1) == ALERT_BIT | ErrorCode.RESULT_FAIL
    assert bench.reg(1, 'torque_enable') == 0
    assert bench.write(1, 'led', 1) == ALERT_BIT  # other writes work, with the alert bit
    bench.bus.inject_error(1, 'voltage')
    assert bench.reg(1, 'hardware_error_status') == 0x21
    bench.bus.servo(1).boot_time_s = 0.0
    assert bench.one(1, Instruction.REBOOT).error == ALERT_BIT
    assert bench.reg(1, 'hardware_error_status') == 0
    assert bench.write(1, 'torque_enable', 1) == 0


def test_error_without_shutdown_bit_keeps_torque(bench: Bench) -> None:
    assert bench.write(1, 'torque_enable', 1) == 0
    bench.bus.inject_error(1, 'encoder')
    assert bench.reg(1, 'torque_enable') == 1
    assert bench.write(1, 'torque_enable', 0) == ALERT_BIT
    assert bench.write(1, 'torque_enable', 1) == ALERT_BIT


def test_inject_error_rejects_unknown_kind(bench: Bench) -> None:
    with pytest.raises(ValueError, match='unknown error kind'):
        bench.bus.inject_error(1, 'gremlins')


# ---- status return level, broadcast, id and baud changes ------------------------------------
def test_status_return_level(bench: Bench) -> None:
    assert bench.send(1, Instruction.WRITE, write_params('status_return_level', 1)) == []
    assert bench.send(1, Instruction.WRITE, write_params('led', 1)) == []
    assert bench.reg(1, 'led') == 1
    assert bench.one(1, Instruction.READ, read_params('led')).params == b'\x01'
    assert bench.one(1, Instruction.PING).error == 0
    assert bench.send(1, Instruction.WRITE, write_params('status_return_level', 0)) == []
    assert bench.send(1, Instruction.READ, read_params('led')) == []
    assert bench.send(1, Instruction.REBOOT, b'\x01') == []
    assert bench.one(1, Instruction.PING).error == 0
    assert bench.send(1, Instruction.WRITE, write_params('status_return_level', 2)) == [
        Packet(1, Instruction.STATUS, b'', 0)]


def test_broadcast_semantics() -> None:
    bench = Bench((1, 2, 3))
    assert bench.send(BROADCAST_ID, Instruction.WRITE, write_params('led', 1)) == []
    assert [bench.reg(i, 'led') for i in (1, 2, 3)] == [1, 1, 1]
    assert bench.send(BROADCAST_ID, Instruction.READ, read_params('led')) == []
    pings = bench.send(BROADCAST_ID, Instruction.PING)
    assert [(p.servo_id, p.params) for p in pings] == [(i, bytes((6, 4, 45))) for i in (1, 2, 3)]
    assert bench.send(BROADCAST_ID, Instruction.REG_WRITE, write_params('led', 0)) == []
    assert bench.send(BROADCAST_ID, Instruction.ACTION) == []
    assert [bench.reg(i, 'led') for i in (1, 2, 3)] == [0, 0, 0]


def test_broadcast_ping_in_ascending_id_order() -> None:
    bench = Bench((9, 2, 5))
    assert [p.servo_id for p in bench.send(BROADCAST_ID, Instruction.PING)] == [2, 5, 9]


def test_id_change_answers_with_old_id_then_new() -> None:
    bench = Bench((1, 2))
    status = bench.one(1, Instruction.WRITE, write_params('id', 7))
    assert status.servo_id == 1 and status.error == 0
    assert bench.send(1, Instruction.PING) == []
    assert bench.one(7, Instruction.PING).servo_id == 7
    assert bench.bus.servo_ids() == [2, 7]


def test_baud_change_answers_at_old_baud_then_listens_at_new() -> None:
    bench = Bench((1, 2))
    assert bench.write(1, 'baud_rate', 3) == 0
    assert [p.servo_id for p in bench.send(BROADCAST_ID, Instruction.PING)] == [2]
    pings = bench.send(BROADCAST_ID, Instruction.PING, baud=1_000_000)
    assert [p.servo_id for p in pings] == [1]


def test_return_delay_time_in_reply() -> None:
    bench = Bench((1, 2))
    assert bench.write(2, 'return_delay_time', 10) == 0
    replies = bench.bus.feed(encode_instruction(BROADCAST_ID, Instruction.PING), BAUD)
    expected = [(1, pytest.approx(500e-6)), (2, pytest.approx(20e-6))]
    assert [(r.servo_id, r.return_delay_s) for r in replies] == expected


def test_crc_error_status(bench: Bench) -> None:
    bad = bytearray(encode_instruction(1, Instruction.WRITE, write_params('led', 1)))
    bad[-2] ^= 0xFF
    assert bench.raw(bytes(bad)) == [encode_status(1, ErrorCode.CRC)]
    assert bench.reg(1, 'led') == 0
    bad_broadcast = bytearray(encode_instruction(BROADCAST_ID, Instruction.PING))
    bad_broadcast[-1] ^= 1
    assert bench.raw(bytes(bad_broadcast)) == []
    other = bytearray(encode_instruction(2, Instruction.PING))
    other[-1] ^= 1
    assert bench.raw(bytes(other)) == []


def test_realtime_tick_counts_ms_modulo_32768(bench: Bench) -> None:
    bench.now_s = 1.234
    assert bench.reg(1, 'realtime_tick') == 1234
    bench.now_s = 40.0
    assert bench.reg(1, 'realtime_tick') == 40000 % 32768


# ---- indirect addressing ----------------------------------------------------------------------
def test_indirect_led_example(bench: Bench) -> None:
    assert bench.write(1, 'indirect_address_1', 65) == 0
    assert bench.write(1, 'indirect_data_1', 1) == 0
    assert bench.reg(1, 'led') == 1
    assert bench.write(1, 'indirect_data_1', 0) == 0
    assert bench.reg(1, 'led') == 0
    assert bench.write(1, 'indirect_data_1', 2) == ErrorCode.DATA_RANGE  # LED's range


def test_indirect_goal_position_example_and_partial_write(bench: Bench) -> None:
    for offset in range(4):
        assert bench.write(1, f'indirect_address_{2 + offset}', 116 + offset) == 0
    assert bench.one(1, Instruction.WRITE, struct.pack('<Hi', 225, 1024)).error == 0
    assert bench.reg(1, 'goal_position') == 1024
    status = bench.one(1, Instruction.READ, struct.pack('<HH', 225, 4))
    assert struct.unpack('<i', status.params)[0] == 1024
    # Two of four bytes: a data length error, nothing written.
    status = bench.one(1, Instruction.WRITE, struct.pack('<HH', 225, 7))
    assert status.error == ErrorCode.DATA_LENGTH
    assert bench.reg(1, 'goal_position') == 1024
    # Through the indirection the target's limit applies.
    status = bench.one(1, Instruction.WRITE, struct.pack('<Hi', 225, 5000))
    assert status.error == ErrorCode.DATA_LIMIT


def test_indirect_read_only_target_and_upper_bank(bench: Bench) -> None:
    for offset in range(4):
        assert bench.write(1, f'indirect_address_{29 + offset}', 0x84 + offset) == 0
    bench.bus.servo(1).memory.set('present_position', -5)
    status = bench.one(1, Instruction.READ, struct.pack('<HH', 634, 4))
    assert struct.unpack('<i', status.params)[0] == -5
    status = bench.one(1, Instruction.WRITE, struct.pack('<Hi', 634, 0))
    assert status.error == ErrorCode.ACCESS
    assert bench.write(1, 'indirect_address_56', 67) == 0   # reserved RAM address
    assert bench.one(1, Instruction.READ, struct.pack('<HH', 661, 1)).params == b'\x00'
    assert bench.write(1, 'indirect_data_56', 1) == ErrorCode.ACCESS
    # Indirect address of a partial write of the indirect address item itself.
    assert bench.one(1, Instruction.WRITE, bytes((168, 0, 65))).error == ErrorCode.DATA_LENGTH


def test_stuffed_status_packet(bench: Bench) -> None:
    # Indirect data 1..3 map to themselves by default: plain RAM bytes.
    assert bench.one(1, Instruction.WRITE, bytes((224, 0, 0xFF, 0xFF, 0xFD))).error == 0
    replies = bench.raw(encode_instruction(1, Instruction.READ, struct.pack('<HH', 224, 3)))
    body = bytes.fromhex('FFFFFD0001080055 00FFFFFDFD'.replace(' ', ''))
    crc = crc16(body)
    assert replies == [body + bytes((crc & 0xFF, crc >> 8))]
    assert decode_packet(replies[0]).params == b'\xff\xff\xfd'


def test_the_2_0_handlers_are_protocol2s_and_read_at_every_packet(
        bench: Bench, monkeypatch: pytest.MonkeyPatch) -> None:
    # servo._HANDLERS is sim/protocol2.py's table itself: a handler stood in there is the one
    # that answers (test_fast_sync.py stands one in for FAST_SYNC_READ).
    assert sim_servo._HANDLERS is protocol2.HANDLERS
    assert sim_servo.parse_bulk_write is protocol2.parse_bulk_write
    monkeypatch.setitem(sim_servo._HANDLERS, Instruction.PING, lambda *args: None)
    assert bench.send(1, Instruction.PING) == []
    monkeypatch.undo()
    assert bench.one(1, Instruction.PING).error == 0
