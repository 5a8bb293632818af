"""
Transports by name: what `port` opens, each backend imported only when chosen.

A transport opens the port the bus runs on, and knows what to do when it is lost: a real
adapter comes back as a new device (closed at the loss, opened again), the simulated one is
the same port plugged back (kept, and asked whether it is back). The driver sees only this
interface, never which backend is behind it. As python-can does with its interfaces, a backend's
module is imported when it is chosen, so the driver never loads the simulator for real hardware;
this is the one module of the driver that names the simulator.

`port: sim` is the simulator: one simulated servo per joint, of the joint's configured model.
Anything else is a serial device. Tests and tools that build their own simulated servos hand
the driver a factory of their own (Manager's port_factory).
"""

import importlib
from typing import Any, Callable, Dict, Optional, Protocol

from dxl_servo_driver.config import DriverConfig
from dxl_servo_driver.port import open_port as open_serial, RawPort


class Transport(Protocol):
    """What the driver needs of a backend: a port, and what a loss of it means."""

    name: str   # what the log says of it (the device, or 'sim')

    def open_port(self) -> RawPort:
        """Open the port; PortError with a clear reason when it cannot."""

    def release(self, port: RawPort) -> None:
        """Let go of what a lost port holds."""

    def reopen(self, port: RawPort) -> RawPort:
        """Return the port back after a loss; PortError (or OSError) while it is still gone."""


PortFactory = Callable[[DriverConfig], Transport]


class SerialTransport:
    """A serial device by path: closed when lost, opened again when it is back."""

    def __init__(self, device: str, baud_bps: int) -> None:
        self.name = device
        self._baud_bps = baud_bps

    def open_port(self) -> RawPort:
        """Open the device."""
        return open_serial(self.name, self._baud_bps)

    def release(self, port: RawPort) -> None:
        """Close the lost device: it comes back as a new one."""
        port.close()

    def reopen(self, port: RawPort) -> RawPort:
        """Open the device again (PortError while it is not there)."""
        return self.open_port()


class SimTransport:
    """
    Simulated servos behind an in-process port: the port survives a loss (an unplug).

    The simulator is made when the transport is (make_sim), or given; `simulator` is it, for
    whoever made the transport.
    """

    def __init__(self, simulator: Any, make_port: Callable[[], RawPort]) -> None:
        self.name = 'sim'
        self.simulator = simulator
        self._make_port = make_port
        self._port: Optional[RawPort] = None

    def open_port(self) -> RawPort:
        """Open a port on the simulated servos (a new one each configure)."""
        self._port = self._make_port()
        return self._port

    def release(self, port: RawPort) -> None:
        """Keep the port: the simulated adapter is plugged back, not replaced."""

    def reopen(self, port: RawPort) -> RawPort:
        """Return the same port once it answers again (in_waiting raises while unplugged)."""
        port.in_waiting
        return port


def _sim(config: DriverConfig) -> Transport:
    sim_bus = importlib.import_module('dxl_servo_driver.sim.bus')
    sim_port = importlib.import_module('dxl_servo_driver.sim.port')
    setup = importlib.import_module('dxl_servo_driver.sim.virtual_bus')
    # Every servo of the configuration: a joint's second servo (secondary_id) too.
    servos = list(config.joints) + [
        joint.secondary() for joint in config.joints if joint.secondary_id is not None]
    ids = [joint.servo_id for joint in servos]
    chosen = {joint.servo_id: joint.model for joint in servos if joint.model is not None}
    simulator = sim_bus.SimBus(ids, models=chosen) if chosen else sim_bus.SimBus(ids)
    setup.configure_servos(simulator, config.baud_rate, None,
                           {joint.servo_id: joint.protocol for joint in servos})
    return SimTransport(
        simulator, lambda: sim_port.SimPortHandler(simulator, 'sim', config.baud_rate))


def _serial(config: DriverConfig) -> Transport:
    return SerialTransport(config.port, config.baud_rate)


TRANSPORTS: Dict[str, PortFactory] = {'sim': _sim, 'serial': _serial}


def transport_name(port: str) -> str:
    """Return the transport a `port` value selects."""
    return port if port in TRANSPORTS else 'serial'


def open_transport(config: DriverConfig) -> Transport:
    """Return the transport the configuration's `port` names (nothing is opened yet)."""
    return TRANSPORTS[transport_name(config.port)](config)
