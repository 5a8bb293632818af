"""Whether a joint's registers and mode fit a servo model's control table."""

from dxl_servo_driver import models
from dxl_servo_driver.config.checks import ConfigError
from dxl_servo_driver.config.driver_config import JointConfig
from dxl_servo_driver.errors import ConfigurationError
from dxl_servo_driver.models import registers, xm430


def check_registers(joint: JointConfig, table: models.Model, lenient: bool = False) -> None:
    """
    Refuse (ConfigError) the first register of the joint the model refuses.

    lenient: a register this table lacks passes if another supported model has it.
    """
    values = {item.name: item.initial for item in table.items}
    checked = {}
    for register, value in joint.registers:
        key = joint.register_key(register)
        if lenient and not table.has(register) and any(
                other.has(register) for other in models.ALL_MODELS):
            continue
        try:
            item = registers.writable_register(table, register)
            registers.check_range(item, value, table)
        except ValueError as exc:
            whose = (f'on the second servo (id {joint.servo_id}): ' if joint.secondary_of
                     else '')
            raise ConfigError(key, whose + str(exc)) from None
        checked[register] = value
    # Values bounded by another register must respect it, as the servo would refuse them (data
    # limit error) at configure: the rules of registers.check_register_set, against the file's
    # values where it sets them and the table's initial values elsewhere.
    values.update(checked)
    # The lower bound of a crossed pair is named (min_position_limit, not max_...), and a
    # profile register rather than the Drive Mode that says what it counts.
    for register in sorted(checked, key=lambda r: (r.startswith('max_'), r == 'drive_mode')):
        try:
            registers.check_register_set(table, values, register, checked[register],
                                         joint.operating_mode)
        except ValueError as exc:
            whose = (f'on the second servo (id {joint.servo_id}): ' if joint.secondary_of
                     else '')
            raise ConfigError(joint.register_key(register), whose + str(exc)) from None


def describe_register(joint: JointConfig, register: str) -> models.Item:
    """Return the item a joint's register names: its model's, the XM430 manual's, or any."""
    for table in (joint.model, models.model_for(xm430.MODEL_NUMBER), *models.ALL_MODELS):
        if table is not None and table.has(register):
            return table.item(register)
    raise KeyError(register)


def check_joint_against(joint: JointConfig, table: models.Model) -> None:
    """Refuse (ConfigurationError) a joint's configuration that does not fit its servo's model."""
    if joint.operating_mode not in table.modes:
        raise ConfigurationError(f'it has no {joint.operating_mode} mode ({joint.name}.'
                                 f'operating_mode; its modes: {", ".join(table.modes)})')
    check_registers(joint, table)
