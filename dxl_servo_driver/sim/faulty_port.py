"""
A raw port behind a faulty adapter, in process: fault_engine.FaultEngine in front of a RawPort.

The wrapped port is the bus layer's RawPort interface, typically the simulator's SimPortHandler;
the bus above sees the adapter's faults on every reply.
"""

import time
from typing import Optional

from dxl_servo_driver.port import RawPort
from dxl_servo_driver.sim.fault_engine import FaultControls, FaultEngine, Faults

# FaultyPort: a wrapped port that is not 'instant' may produce bytes at any time; a waiting
# read looks at it this often.
POLL_S = 0.001


class FaultyPort(FaultControls):
    """
    A raw port behind a faulty adapter, in process.

    Bytes the wrapped port makes readable are moved into the engine at once; read() then
    blocks, sleeping on the engine's condition, until the bytes it wants are released or the
    timeout passes (even with an 'instant' wrapped port, which would return at once).
    """

    def __init__(self, port: RawPort, faults: Optional[Faults] = None,
                 seed: Optional[int] = 0, protocol: int = 2) -> None:
        self.port = port
        self.engine = FaultEngine(faults, seed, protocol=protocol)
        self._cond = self.engine.cond
        # An 'instant' SimPortHandler only produces bytes inside write(), which notifies.
        self._polled = getattr(port, 'timing', None) != 'instant'

    @property
    def baudrate(self) -> int:
        """Return the wrapped port's line speed."""
        return self.port.baudrate

    @baudrate.setter
    def baudrate(self, baud_bps: int) -> None:
        # What the adapter already received stays: it was read off the bus at the old speed.
        with self._cond:
            self.port.baudrate = baud_bps

    @property
    def in_waiting(self) -> int:
        """Return how many bytes are readable now (after the faults)."""
        with self._cond:
            self._pump()
            return self.engine.readable(time.monotonic())

    def write(self, data: bytes) -> int:
        """Send bytes to the servos; with echo they come back first."""
        payload = bytes(data)
        with self._cond:
            self._pump()  # earlier replies stay ahead of the echo
            written = self.port.write(payload)
            self.engine.host_bytes(payload[:written], time.monotonic())
            self._pump()
            return written

    def read(self, size: int, timeout_s: float) -> bytes:
        """Block until size bytes are readable or timeout_s passed; return what arrived."""
        out = bytearray()
        deadline_s = time.monotonic() + max(0.0, timeout_s)
        with self._cond:
            while True:
                self._pump()
                now_s = time.monotonic()
                out += self.engine.take(now_s, size - len(out))
                if len(out) >= size or now_s >= deadline_s:
                    return bytes(out)
                wake_s = deadline_s
                next_s = self.engine.next_event_s()
                if next_s is not None:
                    wake_s = min(wake_s, next_s)
                if self._polled:
                    wake_s = min(wake_s, now_s + POLL_S)
                self._cond.wait(max(0.0, wake_s - now_s))

    def reset_input_buffer(self) -> None:
        """Drop the bytes readable now; frozen, delayed and late bytes arrive later."""
        with self._cond:
            self._pump()
            self.engine.discard_readable(time.monotonic())
            self.port.reset_input_buffer()

    def close(self) -> None:
        """Close the wrapped port; what the adapter held is lost."""
        with self._cond:
            self.engine.reset()
            self.port.close()

    def unplug_port(self) -> None:
        """Yank the adapter (the wrapped port's unplug_port); what it held is lost."""
        with self._cond:
            getattr(self.port, 'unplug_port')()
            self.engine.reset()

    def plug_port(self) -> None:
        """Plug the adapter back in (the wrapped port's plug_port)."""
        with self._cond:
            getattr(self.port, 'plug_port')()
            self._cond.notify_all()

    def _pump(self) -> None:
        """Move what the wrapped port has received into the engine (raises while unplugged)."""
        count = self.port.in_waiting
        if count:
            data = self.port.read(count, 0.0)
            self.engine.servo_bytes(data, time.monotonic())
