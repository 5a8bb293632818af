"""
Control tables, units, modes and datasheet physics of the supported DYNAMIXEL models.

Pure data chosen by model number (and firmware version where the table differs): no I/O,
no ROS, no SDK. Both the driver and the simulator ask here for every address, size, unit,
mode and error bit: base (the types), xm430 (the XM430 manual's table, the base of the
others), layout (tables stated as differences), catalog (every model: the X series itself,
the other families from their own modules such as mx), modes (the one mode table), units
(raw <-> SI), names (the models refused, by name), registers (what may be written where).

Adding a model or a family (the contract the rest of the package counts on):

- A model of a family we have is one entry of that family's figures (its module: the
  e-manual page's numbers: model number, bauds, limits, units, datasheet points) added to its
  list; catalog.ALL_MODELS gathers them. Nothing else changes.
- A family is one module here: `_item = layout.ItemMaker(eeprom_end=..., direction_bit=...)`,
  its items in the manual's column order (or `layout.build` over xm430.ITEMS, stating only
  its differences), and a `Model` (base.py: every field is commented there) per model, then
  its list added to catalog.
- The driver asks items by the XM430 manual's names; a table that names one otherwise maps it
  in `Model.roles` (the AX's moving_speed plays goal_velocity). Every table has model_number,
  firmware_version, id, baud_rate, return_delay_time, torque_enable and present_position; a
  mode register (`Model.mode_register`, or '' where angle limits select the mode); for each
  mode in `Model.modes` (names of modes.MODES, with the register's value) the goal registers
  modes.MODES lists; present_velocity and present_current or present_load (`current_unit_a`
  or `load_unit_ratio`), present_input_voltage and present_temperature. Optional, used where
  there: realtime_tick (dates samples), hardware_error_status, moving, present_pwm, the
  indirect entries (`Model.indirect`: one packed read of the state block; without them the
  block is read from the table's own registers), Fast Sync Read (`fast_sync_read_firmware`).
- `Model.bauds` maps the Baud Rate register's values to bit/s; `physics` is the datasheet's
  points (base.datasheet) the simulator drives its motor with.
- test/models/test_models.py and test/models/test_model_families.py hold every model to this
  (items sorted and disjoint, limits naming existing registers, modes, units and bauds agreeing,
  indirect entries matching, physics usable, the SDK's model files agreeing): run them first.
"""

from dxl_servo_driver.models.base import Item, Model, ModelError, Physics, VoltagePoint
from dxl_servo_driver.models.catalog import (
    ALL_MODELS, FAMILIES, MANUAL_DIFFERENCES, model_for, model_named, SUPPORTED,
    unsupported_reason, X_MODELS)

__all__ = [
    'ALL_MODELS', 'FAMILIES', 'Item', 'MANUAL_DIFFERENCES', 'Model', 'model_for', 'model_named',
    'ModelError', 'Physics', 'SUPPORTED', 'unsupported_reason', 'VoltagePoint', 'X_MODELS',
]
