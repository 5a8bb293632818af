"""
Transports by name: what `port` opens, imported only when chosen.

`port: sim` is the simulator (one simulated servo per joint, of the joint's configured model);
anything else is a serial device. As python-can does with its interfaces, a backend's module
is imported when it is chosen, so the driver never loads the simulator for real hardware and
this is the one module that imports it.
"""

import importlib
from typing import Any, Callable, Dict, Tuple

from dxl_servo_driver.config import DriverConfig
from dxl_servo_driver.serial_port import open_port as open_serial, RawPort

# What a transport returns: the port, and the simulated bus behind it (None for hardware).
Opened = Tuple[RawPort, Any]
PortFactory = Callable[[DriverConfig], Opened]


def _open_serial(config: DriverConfig) -> Opened:
    return open_serial(config.port, config.baud_rate), None


def _open_sim(config: DriverConfig) -> Opened:
    bus_module = importlib.import_module('dxl_servo_driver.sim.bus')
    port_module = importlib.import_module('dxl_servo_driver.sim.port')
    setup = importlib.import_module('dxl_servo_driver.sim.virtual_bus')
    ids = [joint.servo_id for joint in config.joints]
    chosen = {joint.servo_id: joint.model for joint in config.joints if joint.model is not None}
    sim = bus_module.SimBus(ids, models=chosen) if chosen else bus_module.SimBus(ids)
    setup.configure_servos(sim, config.baud_rate, None)
    return port_module.SimPortHandler(sim, 'sim', config.baud_rate), sim


TRANSPORTS: Dict[str, PortFactory] = {'sim': _open_sim, 'serial': _open_serial}


def transport_name(port: str) -> str:
    """Return the transport a `port` value selects."""
    return port if port in TRANSPORTS else 'serial'


def open_transport(config: DriverConfig) -> Opened:
    """Open the configured port; PortError with a clear reason when it cannot."""
    return TRANSPORTS[transport_name(config.port)](config)
