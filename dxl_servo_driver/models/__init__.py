"""
Control tables, units, modes and datasheet physics of the supported DYNAMIXEL X series.

Pure data chosen by model number (and firmware version where the table differs): no I/O,
no ROS, no SDK.  Meant to drive both the driver and the simulator.
"""

from dxl_servo_driver.models.base import Item, Model, ModelError, Physics, VoltagePoint
from dxl_servo_driver.models.catalog import (
    ALL_MODELS, FAMILIES, model_for, model_named, SEED_DIFFERENCES, SUPPORTED,
    unsupported_reason)

__all__ = [
    'ALL_MODELS', 'FAMILIES', 'Item', 'Model', 'model_for', 'model_named', 'ModelError',
    'Physics', 'SEED_DIFFERENCES', 'SUPPORTED', 'unsupported_reason', 'VoltagePoint',
]
