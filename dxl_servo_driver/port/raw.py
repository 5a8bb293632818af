"""
The byte-level port the bus reads and writes, as a serial device and the simulator offer it.

Below the bus and beside the simulator, so that the simulator's ports and the serial device
(serial_device.py) meet one statement of what the bus needs.
"""

from typing import Protocol

__all__ = ['port_paced', 'port_waited', 'RawPort']


class RawPort(Protocol):
    """
    The byte-level port the bus needs (a serial device, or the simulator's in-process port).

    A port raises PortError (or, the simulator's, an OSError) when the device is gone; the bus
    turns either into PortError.

    `paced` and `waited` are what a device says of its timing; they are read through
    port_paced() and port_waited(), which give a port that does not declare them (the
    simulator's ports, a test's wrapper) this protocol's defaults: not paced, never waited.
    """

    @property
    def paced(self) -> bool:
        """
        Say whether its bytes come at wire speed, never sooner (a device).

        A reader may then sleep until they can be there. A port that answers inside write()
        (the simulator's) is not paced.
        """

    @property
    def waited(self) -> bool:
        """Say whether the last read had to wait for its bytes (asked of a paced port only)."""

    @property
    def baudrate(self) -> int:
        """Return the line speed in bit/s."""

    @baudrate.setter
    def baudrate(self, baud_bps: int) -> None:
        """Change the line speed."""

    @property
    def in_waiting(self) -> int:
        """Return how many received bytes wait to be read."""

    def write(self, data: bytes) -> int:
        """Send bytes."""

    def read(self, size: int, timeout_s: float) -> bytes:
        """Block until size bytes arrived or timeout_s passed; return what arrived."""

    def reset_input_buffer(self) -> None:
        """Drop whatever was received and not read."""

    def close(self) -> None:
        """Release the port."""


def port_paced(port: RawPort) -> bool:
    """Return whether port's bytes come at wire speed (not paced if it does not say)."""
    return bool(getattr(port, 'paced', False))


def port_waited(port: RawPort) -> bool:
    """Return whether port's last read waited for its bytes (never, if it does not say)."""
    return bool(getattr(port, 'waited', False))
