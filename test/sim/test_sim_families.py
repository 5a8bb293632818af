"""
Every model beyond the X series, simulated: it answers in its own protocol as its table says.

Through the driver's own bus (so through each protocol's framing): the ping answers with the
model number, every item reads its initial value, and a servo of a Protocol 1.0 model does not
hear Protocol 2.0 (nor a 2.0 one 1.0). test_sim_models.py holds the X series to more.
"""

from dxl_servo_driver.bus import Bus, FRAMERS
from dxl_servo_driver.errors import CommError
from dxl_servo_driver.models import ALL_MODELS, Model, X_MODELS
from dxl_servo_driver.sim.bus import SimBus
from dxl_servo_driver.sim.port import SimPortHandler
import pytest

OTHERS = [model for model in ALL_MODELS if model not in X_MODELS]
every_other_model = pytest.mark.parametrize('model', OTHERS, ids=lambda m: m.label)
# What the physics sets at power-on rather than the table's initial value: the horn at the
# model's zero, the supply at its nominal voltage, the room's temperature, the servo's clock.
AT_BOOT = {'present_position', 'goal_position', 'position_trajectory', 'present_input_voltage',
           'present_temperature', 'present_motor_temperature', 'present_inverter_temperature',
           'realtime_tick'}


def bus_for(model: Model, framer_version: float) -> tuple[SimBus, Bus]:
    clock = [0.0]
    sim = SimBus([1], clock=lambda: clock[0], boot_time_s=0.0, models={1: model})
    baud = model.bauds[model.item('baud_rate').initial]
    bus = Bus(SimPortHandler(sim, 'sim', baud), baud, latency_timer_s=0.0,
              framer=FRAMERS[framer_version])
    return sim, bus


@every_other_model
def test_the_servo_answers_in_its_own_protocol_with_its_table(model: Model) -> None:
    sim, bus = bus_for(model, model.protocol)
    assert bus.ping(1) == model.number
    for item in model.items:
        value = bus.read_item(1, item)
        if item.name in AT_BOOT:
            continue
        assert value == item.initial, item.name
    position = model.item('present_position')
    assert bus.read_item(1, position) == model.position_zero_raw
    voltage = bus.read_item(1, model.item('present_input_voltage'))
    assert abs(voltage * model.voltage_unit_v - model.physics.nominal_voltage_v) < 0.2


@every_other_model
def test_the_other_protocol_gets_no_answer(model: Model) -> None:
    _, bus = bus_for(model, 2.0 if model.protocol == 1.0 else 1.0)
    with pytest.raises(CommError):
        bus.ping(1, probe=True)
