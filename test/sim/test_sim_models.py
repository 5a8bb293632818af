"""
The simulator as every supported model: tables, modes, units, indirection and physics per model.

Everything goes through packets on a SimBus with a hand-moved clock (physics runs only when a
test moves it), except the loads and supply voltages a test applies, which are not registers.
"""

import struct

from dxl_servo_driver.models import (
    Model, model_for, model_named, SUPPORTED, unsupported_reason, X_MODELS)
from dxl_servo_driver.models.names import OTHER_MODELS
from dxl_servo_driver.protocol import (
    BROADCAST_ID, decode_packet, encode_instruction, ErrorCode, Instruction, Packet)
from dxl_servo_driver.sim import motor
from dxl_servo_driver.sim.bus import SimBus
from dxl_servo_driver.sim.control import handle_line
from dxl_servo_driver.sim.dynamics import ServoDynamics
from dxl_servo_driver.sim.memory import Memory
from dxl_servo_driver.sim.servo import SimServo
from dxl_servo_driver.sim.virtual_bus import _parse_args, configure_servos, StartupError
import pytest

BAUD = 57600
FORMATS = {(1, False): '<B', (1, True): '<b', (2, False): '<H', (2, True): '<h',
           (4, False): '<I', (4, True): '<i'}
TOLERANCE = 0.05
# One model per family and unit: the XM430 manual's table, XL430 (load), XM540, XL330 (1 mA,
# 5 V), XH430-V (1.34 mA, 24 V), plus the fastest (XL330-M077) and a 11.1 V X330.
PHYSICS_MODELS = (1020, 1060, 1120, 1200, 1040, 1190, 1210)
LOAD_MODELS = tuple(model for model in X_MODELS if model.load_unit_ratio is not None)


def label(model: Model) -> str:
    """Return a test id: number, name and the firmware range of a split table."""
    text = f'{model.number}-{model.name}'
    if len(SUPPORTED[model.number]) > 1:
        text += f'-fw{model.min_firmware}+'
    return text


# The X series only: the simulator does not build the other families yet.
every_model = pytest.mark.parametrize('model', X_MODELS, ids=label)


class Bench:
    """One servo of a model on a SimBus with a hand-moved clock; packets in, packets out."""

    def __init__(self, model: Model, servo_id: int = 1) -> None:
        self.now_s = 0.0
        self.model = model
        self.servo_id = servo_id
        self.bus = SimBus([servo_id], clock=lambda: self.now_s, seed=1, boot_time_s=0.0,
                          models={servo_id: model})
        self.servo = self.bus.servo(servo_id)
        # The power-on baud: 57,600 but on the XM335 (1 Mbps).
        self.baud = model.bauds[model.item('baud_rate').initial]

    def one(self, instruction: int, params: bytes = b'', baud: int | None = None) -> Packet:
        """Send one instruction to the servo (at its power-on baud); return its only status."""
        packet = encode_instruction(self.servo_id, instruction, params)
        replies = self.bus.feed(packet, self.baud if baud is None else baud)
        assert len(replies) == 1, replies
        return decode_packet(replies[0].data)

    def write_bytes(self, address: int, data: bytes) -> int:
        """Write raw bytes; return the status error byte."""
        return self.one(Instruction.WRITE, struct.pack('<H', address) + data).error

    def write(self, name: str, value: int) -> int:
        """Write one of the model's items by name; return the status error byte."""
        item = self.model.item(name)
        return self.write_bytes(item.address,
                                struct.pack(FORMATS[(item.size, item.signed)], value))

    def read_bytes(self, address: int, length: int) -> Packet:
        """Read raw bytes; return the status packet."""
        return self.one(Instruction.READ, struct.pack('<HH', address, length))

    def read(self, name: str) -> int:
        """Read one item through a READ packet (asserting it succeeds)."""
        item = self.model.item(name)
        status = self.read_bytes(item.address, item.size)
        assert status.error == 0, (name, status)
        return int(struct.unpack(FORMATS[(item.size, item.signed)], status.params)[0])

    def run(self, seconds: float) -> None:
        """Advance the clock in 1 ms steps, bringing the physics along."""
        for _ in range(int(round(seconds * 1000))):
            self.now_s += 0.001
            self.bus.read_register(self.servo_id, 'realtime_tick')

    def full_pwm(self) -> None:
        """Mode 16, torque on, Goal PWM at the PWM limit."""
        assert self.write('operating_mode', 16) == 0
        assert self.write('torque_enable', 1) == 0
        assert self.write('goal_pwm', self.read('pwm_limit')) == 0


# ---- identity and table ------------------------------------------------------------------------
@every_model
def test_ping_reports_the_model_number_and_firmware(model: Model) -> None:
    bench = Bench(model)
    status = bench.one(Instruction.PING)
    assert status.error == 0
    number, firmware = struct.unpack('<HB', status.params)
    assert number == model.number
    assert firmware == model.item('firmware_version').initial
    if model.family in ('XL330', 'XC330'):
        # The X330's indirect block moved at firmware 53: each table reports its own version.
        assert firmware == (52 if model.min_firmware == 0 else model.min_firmware)
    elif model.family == 'XM335':
        # One table, the X330's from firmware 53: it reports that version.
        assert firmware == 53
    else:
        assert firmware == 45


def test_a_bus_mixes_models_and_broadcast_ping_tells_them_apart() -> None:
    now_s = 0.0
    models = {2: model_named('XL430-W250'), 3: model_for(1200, 52)}
    bus = SimBus([1, 2, 3], clock=lambda: now_s, boot_time_s=0.0, models=models)
    replies = bus.feed(encode_instruction(BROADCAST_ID, Instruction.PING), BAUD)
    found = {decode_packet(reply.data).servo_id: struct.unpack('<HB', decode_packet(
        reply.data).params) for reply in replies}
    assert found == {1: (1030, 45), 2: (1060, 45), 3: (1200, 52)}
    assert bus.model(1) is model_for(1030)
    assert bus.model(2) is model_for(1060)


def test_firmware_override_is_reported_and_must_fit_the_table() -> None:
    old = model_for(1200, 50)
    assert old.min_firmware == 0
    bench_now = 0.0
    bus = SimBus([4], clock=lambda: bench_now, boot_time_s=0.0, models={4: old},
                 firmware={4: 50})
    reply = bus.feed(encode_instruction(4, Instruction.PING), BAUD)
    assert struct.unpack('<HB', decode_packet(reply[0].data).params) == (1200, 50)
    # It survives a factory reset (the firmware is not an EEPROM value a reset restores).
    bus.feed(encode_instruction(4, Instruction.FACTORY_RESET, b'\x02'), BAUD)
    assert bus.read_register(4, 'firmware_version') == 50
    # A firmware from another table's range would make the servo lie about its layout.
    with pytest.raises(ValueError, match='firmware 60'):
        SimBus([1], models={1: old}, firmware={1: 60})
    with pytest.raises(ValueError):
        SimBus([1], firmware={1: 256})


@every_model
def test_every_item_reads_its_initial_value_through_the_bus(model: Model) -> None:
    bench = Bench(model)
    # No initial value in the table: the simulator powers on with the horn at 2048.
    at_boot = {'present_position', 'goal_position', 'position_trajectory'}
    for item in model.items:
        value = bench.read(item.name)
        if item.name in at_boot:
            assert value == 2048, item.name
        else:
            assert value == item.initial, item.name
    assert bench.read('present_input_voltage') == round(10 * model.physics.nominal_voltage_v)
    # One read of the whole table works and ends exactly at its last byte.
    assert len(bench.read_bytes(0, model.table_end).params) == model.table_end
    assert bench.read_bytes(0, model.table_end + 1).error == ErrorCode.ACCESS


@every_model
def test_reserved_addresses_read_zero_and_refuse_writes(model: Model) -> None:
    bench = Bench(model)
    covered = {item.address + offset for item in model.items for offset in range(item.size)}
    reserved = [address for address in range(model.table_end) if address not in covered]
    assert reserved  # every table has gaps
    for address in reserved:
        assert bench.read_bytes(address, 1).params == b'\x00', address
        assert bench.write_bytes(address, b'\x01') == ErrorCode.ACCESS, address
    assert bench.write_bytes(model.table_end, b'\x01') == ErrorCode.ACCESS


@pytest.mark.parametrize('number, address, lacks', [
    (1270, 65, 'led'), (1280, 65, 'led'), (1170, 65, 'led'), (1180, 65, 'led'),
    (1310, 65, 'led'),
    (1060, 102, 'goal_current'), (1060, 38, 'current_limit'), (1070, 102, 'goal_current'),
    (1080, 38, 'current_limit'), (1090, 102, 'goal_current'), (1160, 102, 'goal_current'),
])
def test_writing_an_item_the_model_lacks_is_an_access_error(number: int, address: int,
                                                            lacks: str) -> None:
    model = model_for(number)
    assert not model.has(lacks)
    bench = Bench(model)
    size = model_for(1030).item(lacks).size
    assert bench.write_bytes(address, bytes(size)) == ErrorCode.ACCESS
    # The same write is fine on the XM430 manual's model.
    assert Bench(model_for(1030)).write_bytes(address, bytes(size)) == 0


def test_model_specific_items_are_writable_where_they_exist() -> None:
    x540 = Bench(model_for(1120))
    assert x540.write('external_port_mode_2', 1) == 0
    assert x540.read('external_port_mode_2') == 1
    assert x540.write('external_port_data_3', 4095) == 0
    assert x540.write('external_port_data_3', 4096) == ErrorCode.DATA_RANGE
    x330 = Bench(model_for(1200))
    assert x330.write('pwm_slope', 10) == 0
    assert x330.read('pwm_slope') == 10
    # The XM430 manual's model has neither.
    manual = Bench(model_for(1030))
    assert manual.write_bytes(62, b'\x0a') == ErrorCode.ACCESS
    assert manual.write_bytes(152, b'\x00\x00') == ErrorCode.ACCESS


@pytest.mark.parametrize('model', LOAD_MODELS, ids=label)
def test_models_without_current_sensing_have_four_modes(model: Model) -> None:
    bench = Bench(model)
    for mode in (0, 2, 5):
        assert bench.write('operating_mode', mode) == ErrorCode.DATA_RANGE, mode
        assert bench.read('operating_mode') == 3
    for mode in (1, 3, 4, 16, 3):
        assert bench.write('operating_mode', mode) == 0, mode
        assert bench.read('operating_mode') == mode
    # Each of them runs (the physics never asks for the current items the model lacks).
    for mode in (1, 4, 16):
        assert bench.write('torque_enable', 0) == 0
        assert bench.write('operating_mode', mode) == 0
        assert bench.write('torque_enable', 1) == 0
        bench.run(0.05)


@pytest.mark.parametrize('model', [m for m in X_MODELS if m.current_unit_a is not None],
                         ids=label)
def test_models_with_current_sensing_have_six_modes(model: Model) -> None:
    bench = Bench(model)
    assert bench.write('operating_mode', 2) == ErrorCode.DATA_RANGE
    for mode in (0, 1, 3, 4, 5, 16):
        assert bench.write('operating_mode', mode) == 0, mode


@pytest.mark.parametrize('model', [m for m in X_MODELS
                                   if m.family in ('XL330', 'XC330', 'XM335')], ids=label)
def test_x330_baud_register_stops_at_4_mbps(model: Model) -> None:
    bench = Bench(model)
    assert bench.write('baud_rate', 7) == ErrorCode.DATA_RANGE
    assert bench.write('baud_rate', 6) == 0
    assert bench.servo.baud_bps == 4_000_000
    ping = encode_instruction(1, Instruction.PING)
    assert bench.bus.feed(ping, BAUD) == []
    assert len(bench.bus.feed(ping, 4_000_000)) == 1


def test_4_5_mbps_is_a_baud_of_the_others() -> None:
    bench = Bench(model_for(1060))
    assert bench.write('baud_rate', 7) == 0
    assert bench.servo.baud_bps == 4_500_000


@every_model
def test_indirect_mapping_at_the_model_s_own_addresses(model: Model) -> None:
    bench = Bench(model)
    position = model.item('present_position').address
    first_data = model.indirect[0][1]
    for n in range(4):
        assert bench.write(f'indirect_address_{n + 1}', position + n) == 0
    bench.full_pwm()
    bench.run(0.05)
    direct = bench.read_bytes(position, 4).params
    assert bench.read_bytes(first_data, 4).params == direct
    assert struct.unpack('<i', direct)[0] != 2048  # it moved: not an initial value by chance
    # Writing through the last entry reaches its target (Torque Enable here).
    last = len(model.indirect)
    torque = model.item('torque_enable').address
    assert bench.write(f'indirect_address_{last}', torque) == 0
    assert bench.write_bytes(model.indirect[-1][1], b'\x00') == 0
    assert bench.read('torque_enable') == 0
    # An entry may point anywhere in RAM up to the table's last byte, no further.
    assert bench.write('indirect_address_2', model.table_end - 1) == 0
    assert bench.write('indirect_address_2', model.table_end) == ErrorCode.DATA_RANGE


def test_x330_tables_differ_by_firmware() -> None:
    old, new = SUPPORTED[1200]
    assert (old.indirect[0], len(old.indirect), new.indirect[0], len(new.indirect)) == (
        (168, 208), 20, (168, 224), 28)
    old_bench, new_bench = Bench(old), Bench(new)
    # 224 is Indirect Data 17 of the old table and Indirect Data 1 of the new one.
    for bench, entry in ((old_bench, 17), (new_bench, 1)):
        assert bench.write(f'indirect_address_{entry}', 64) == 0
        assert bench.write_bytes(224, b'\x01') == 0
        assert bench.read('torque_enable') == 1
    assert old_bench.read_bytes(228, 1).error == ErrorCode.ACCESS
    assert new_bench.read_bytes(251, 1).error == 0


# ---- units and physics -------------------------------------------------------------------------
def test_manual_models_keep_the_manual_motor_and_the_others_share_theirs() -> None:
    assert motor.motor_for(model_for(1030)) is motor.MANUAL_MOTOR
    assert motor.motor_for(model_for(1020)) is motor.MANUAL_MOTOR
    assert Memory().model is model_for(1030)
    bus = SimBus([1, 2], boot_time_s=0.0, models={1: model_for(1060), 2: model_for(1060)})
    one, two = bus.servo(1), bus.servo(2)
    assert one.memory.table is two.memory.table  # built once per model, not per servo
    assert one.dynamics.motor is two.dynamics.motor
    assert Memory(model_for(1060)).table is one.memory.table


def _no_load_rpm(model: Model) -> float:
    bench = Bench(model)
    bench.full_pwm()
    bench.run(1.5)  # the slowest (XL330-M288) has a 0.2 s mechanical time constant
    assert bench.read('present_pwm') == model.pwm_full_raw
    return bench.read('present_velocity') * model.velocity_unit_rpm


@pytest.mark.parametrize('number', PHYSICS_MODELS)
def test_no_load_speed_at_the_nominal_voltage_matches_the_datasheet(number: int) -> None:
    model = model_for(number)
    point = model.physics.nominal
    assert Bench(model).read('present_input_voltage') == round(point.voltage_v * 10)
    measured = _no_load_rpm(model)
    assert abs(measured / point.no_load_speed_rpm - 1.0) < TOLERANCE, measured


def _stalled(model: Model, load_nm: float) -> tuple[Bench, int]:
    """Return a bench at full PWM against load_nm after 0.3 s, and its start position."""
    bench = Bench(model)
    bench.bus.set_load(1, load_nm)
    start = bench.read('present_position')
    bench.full_pwm()
    bench.run(0.3)
    return bench, start


@pytest.mark.parametrize('number', PHYSICS_MODELS)
def test_stall_current_and_torque_at_the_nominal_voltage_match_the_datasheet(
        number: int) -> None:
    model = model_for(number)
    point = model.physics.nominal
    bench, start = _stalled(model, 100.0 * point.stall_torque_nm)
    assert bench.read('present_position') == start
    dynamics = bench.servo.dynamics
    if model.current_unit_a is not None:
        # Present Current in the model's own unit (2.69 mA, 1.34 mA for the XH430-V, 1 mA X330).
        current_a = bench.read('present_current') * model.current_unit_a
    else:
        current_a = dynamics.current_a
        assert bench.read('present_load') == 1000
    assert abs(current_a / point.stall_current_a - 1.0) < TOLERANCE, current_a
    delivered_nm = dynamics.motor_torque_nm - dynamics.motor.coulomb_friction_nm
    assert abs(delivered_nm / point.stall_torque_nm - 1.0) < TOLERANCE, delivered_nm
    # Seen from outside: the horn breaks free 5 % below the datasheet torque, holds 5 % above.
    for share, moves in ((0.95, True), (1.05, False)):
        bench, start = _stalled(model, share * point.stall_torque_nm)
        assert (bench.read('present_position') != start) is moves, share


@every_model
def test_position_mode_settles_with_the_model_s_default_gains(model: Model) -> None:
    bench = Bench(model)
    assert bench.write('torque_enable', 1) == 0
    goal = bench.read('present_position') + 1000
    assert bench.write('goal_position', goal) == 0
    bench.run(2.5)
    settled = []
    for _ in range(10):
        bench.run(0.05)
        settled.append(bench.read('present_position'))
    # The XL430's D gain 4000 is part of this: taken per velocity unit it would oscillate.
    assert all(abs(position - goal) <= 20 for position in settled), settled
    assert bench.read('moving_status') & 0x01


def test_present_current_counts_in_each_model_s_unit() -> None:
    # The same 0.7 A stall of the XH430-V350 is 522 counts of 1.34 mA (260 of 2.69 mA).
    bench, _ = _stalled(model_for(1040), 10.0)
    assert bench.read('present_current') == pytest.approx(0.7 / 1.34e-3, rel=TOLERANCE)
    bench, _ = _stalled(model_for(1200), 10.0)
    assert bench.read('present_current') == pytest.approx(1470, rel=TOLERANCE)


def test_present_load_of_an_xl430_under_a_known_load() -> None:
    model = model_for(1060)
    stall_nm = model.physics.nominal.stall_torque_nm
    for goal_velocity, sign in ((10, 1), (-10, -1)):
        bench = Bench(model)
        # Half the stall torque as a brake; velocity mode turns slowly against it.
        bench.bus.set_load(1, 0.5 * stall_nm)
        assert bench.write('operating_mode', 1) == 0
        assert bench.write('torque_enable', 1) == 0
        assert bench.write('goal_velocity', goal_velocity) == 0
        bench.run(1.0)
        assert bench.read('present_velocity') == goal_velocity
        load = bench.read('present_load')
        # 500 (0.1 % units) plus a little friction, in the direction of the motion.
        assert 500 <= sign * load <= 530, load
    # Held still at full PWM the other way: the full (negative) share, clamped.
    bench = Bench(model)
    bench.bus.set_load(1, 10.0)
    assert bench.write('operating_mode', 16) == 0
    assert bench.write('torque_enable', 1) == 0
    assert bench.write('goal_pwm', -model.pwm_full_raw) == 0
    bench.run(0.2)
    assert bench.read('present_load') == -1000
    # Torque off: nothing.
    assert bench.write('torque_enable', 0) == 0
    bench.run(0.01)
    assert bench.read('present_load') == 0
    with pytest.raises(ValueError, match='present_current'):
        bench.bus.read_register(1, 'present_current')


def test_default_supply_is_the_model_s_nominal_voltage() -> None:
    for number, volts in ((1200, 5.0), (1060, 11.1), (1040, 24.0), (1030, 12.0)):
        bench = Bench(model_for(number))
        assert bench.servo.dynamics.input_voltage_v == volts
        assert bench.read('present_input_voltage') == round(volts * 10)
        # Within the model's own voltage limits: no input voltage error at power-on.
        bench.run(0.01)
        assert bench.read('hardware_error_status') == 0


# ---- control lines and virtual_bus -------------------------------------------------------------
def test_control_lines_resolve_addresses_in_each_servo_s_table() -> None:
    bus = SimBus([1, 2, 3], boot_time_s=0.0,
                 models={2: model_for(1060), 3: model_for(1270)})
    assert handle_line('get 1 126', bus) == 'ok get 1 present_current=0'
    assert handle_line('get 2 126', bus) == 'ok get 2 present_load=0'
    assert handle_line('get 2 0', bus) == 'ok get 2 model_number=1060'
    answer = handle_line('get 2 present_current', bus)
    assert answer is not None and answer.startswith('error: ') and 'XL430-W250' in answer
    answer = handle_line('get 3 65', bus)
    assert answer is not None and answer.startswith('error: ') and 'address 65' in answer
    assert handle_line('get 1 65', bus) == 'ok get 1 led=0'
    dump = handle_line('dump 2', bus)
    assert dump is not None and ' present_load=' in dump and 'present_current' not in dump


def test_virtual_bus_models_option() -> None:
    args = _parse_args(['--ids', '1', '2', '--models', 'xl430-w250'])
    assert args.models == {1: model_for(1060), 2: model_for(1060)}
    args = _parse_args(['--ids', '3', '1', '--models', '1200', 'XM430-W350'])
    assert args.models == {3: model_for(1200), 1: model_for(1020)}
    args = _parse_args(['--ids', '1', '--models', 'XL330-M288', '--firmware', '52'])
    assert args.models == {1: SUPPORTED[1200][0]} and args.firmware == 52
    args = _parse_args(['--ids', '1', '2'])
    assert args.models == {1: model_for(1030), 2: model_for(1030)}


# A model still refused, by its name (whichever names.py has left).
REFUSED = min(OTHER_MODELS)


@pytest.mark.parametrize('argv, fragment', [
    (['--ids', '1', '--models', 'XL999-W1'], '--models XL999-W1: no supported model is named'),
    (['--ids', '1', '--models', str(REFUSED)],
     f'--models {REFUSED}: ' + unsupported_reason(REFUSED)),
    (['--ids', '1', '--models', '4242'], '--models 4242: ' + unsupported_reason(4242)),
    (['--ids', '1', '2', '3', '--models', '1060', '1060'], '(3 ids, 2 models)'),
    (['--ids', '1', '--models', '1200', '--baud', '4500000'], 'servo 1 (XL330-M288) supports'),
    (['--ids', '1', '--firmware', '256'], '--firmware 256'),
])
def test_virtual_bus_refuses_bad_models(capsys: pytest.CaptureFixture[str], argv: list[str],
                                        fragment: str) -> None:
    with pytest.raises(SystemExit) as info:
        _parse_args(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert fragment in err and err.count('\n') == 1, err


def test_configure_refuses_a_baud_the_model_lacks() -> None:
    bus = SimBus([1, 2], boot_time_s=0.0, models={2: model_for(1190)})
    with pytest.raises(StartupError, match='servo 2 .*XL330-M077.* 4500000'):
        configure_servos(bus, 4_500_000, None)
    configure_servos(bus, 4_000_000, 0)
    assert [bus.read_register(i, 'baud_rate') for i in (1, 2)] == [6, 6]


def test_bus_refuses_models_for_ids_it_does_not_have() -> None:
    with pytest.raises(ValueError, match=r'models names ids \[9\]'):
        SimBus([1, 2], models={9: model_for(1060)})
    with pytest.raises(ValueError, match=r'firmware names ids \[3\]'):
        SimBus([1, 2], firmware={3: 45})


def test_a_servo_refuses_dynamics_of_another_model() -> None:
    with pytest.raises(ValueError, match='XL430-W250'):
        SimServo(1, ServoDynamics(model=model_for(1060)), 0.0, model=model_for(1120))
    servo = SimServo(1, ServoDynamics(model=model_for(1060)), 0.0, model=model_for(1060))
    assert servo.model is model_for(1060)
