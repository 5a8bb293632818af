"""
Control tables, units, modes and datasheet physics of the supported DYNAMIXEL models.

Pure data chosen by model number (and firmware version where the table differs): no I/O,
no ROS, no SDK. Both the driver and the simulator ask here for every address, size, unit,
mode and error bit: base (the types), xm430 (the XM430 manual's table, the base of the
others), layout (tables stated as differences), catalog (every model: the X series itself,
the other families from their own modules such as mx), modes (the one mode table), units
(raw <-> SI), names (the models refused, by name).
"""

from dxl_servo_driver.models.base import Item, Model, ModelError, Physics, VoltagePoint
from dxl_servo_driver.models.catalog import (
    ALL_MODELS, FAMILIES, MANUAL_DIFFERENCES, model_for, model_named, SUPPORTED,
    unsupported_reason, X_MODELS)

__all__ = [
    'ALL_MODELS', 'FAMILIES', 'Item', 'MANUAL_DIFFERENCES', 'Model', 'model_for', 'model_named',
    'ModelError', 'Physics', 'SUPPORTED', 'unsupported_reason', 'VoltagePoint', 'X_MODELS',
]
