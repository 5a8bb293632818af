"""
Test helper: a clock of the test's own, for timing logic a busy machine must not decide.

Installed (FakeClock.install), it is what time.monotonic() reads and what time.sleep() advances
for every caller that looks them up when it calls (the bus's layers do); the simulator and its
wire-timed port take it as their clock and sleep. A read then finds its bytes exactly when the
wire model says they come, and wakes exactly when it asked to, whatever else the machine is doing.
Each sleep is counted: a sleep is a wake-up of the reading thread.
"""

import time
from typing import Any, List

from dxl_servo_driver.sim.bus import SimBus
from dxl_servo_driver.sim.port import SimPortHandler
import pytest


class FakeClock:
    """Monotonic seconds that pass only when someone sleeps."""

    def __init__(self, start_s: float = 1000.0) -> None:
        self.now_s = start_s
        self.sleeps: List[float] = []

    def monotonic(self) -> float:
        """Return the time now."""
        return self.now_s

    def sleep(self, seconds: float) -> None:
        """Let seconds pass (time.sleep's contract: never negative)."""
        if seconds < 0.0:
            raise ValueError('sleep length must be non-negative')
        self.sleeps.append(seconds)
        self.now_s += seconds

    def install(self, monkeypatch: pytest.MonkeyPatch) -> 'FakeClock':
        """Make time.monotonic and time.sleep this clock's until the test ends."""
        monkeypatch.setattr(time, 'monotonic', self.monotonic)
        monkeypatch.setattr(time, 'sleep', self.sleep)
        return self

    def sim(self, ids: Any, **kwargs: Any) -> SimBus:
        """Return simulated servos on this clock, booted at once."""
        return SimBus(list(ids), clock=self.monotonic, boot_time_s=0.0, **kwargs)

    def port(self, sim: SimBus, baud_bps: int, latency_s: float = 0.0) -> SimPortHandler:
        """Return a port in front of sim whose replies come at wire speed on this clock."""
        return SimPortHandler(sim, 'sim', baud_bps, timing='wire', latency_s=latency_s,
                              clock=self.monotonic, sleep=self.sleep)


class LatePort:
    """A wire-timed port whose replies can be made later from any moment (a slower adapter)."""

    def __init__(self, clock: FakeClock, sim: SimBus, baud_bps: int) -> None:
        self._clock = clock
        self._sim = sim
        self._baud_bps = baud_bps
        self.port = clock.port(sim, baud_bps)

    def late(self, latency_s: float) -> None:
        """Bring the replies of the requests from now on latency_s after the wire."""
        self.port = self._clock.port(self._sim, self._baud_bps, latency_s)

    @property
    def baudrate(self) -> int:
        """Return the port's line speed."""
        return self.port.baudrate

    @baudrate.setter
    def baudrate(self, baud_bps: int) -> None:
        self.port.baudrate = baud_bps

    def __getattr__(self, name: str) -> Any:
        return getattr(self.port, name)


class PacedPort:
    """
    A wire-timed simulated port that says what a device says of its timing.

    paced: its bytes never come sooner than the wire brings them (a reader may sleep until
    then); waited: whether the last read began before all it asked for was there.
    """

    paced = True

    def __init__(self, port: SimPortHandler) -> None:
        self.port = port
        self.waited = False

    def read(self, size: int, timeout_s: float) -> bytes:
        """Read as the port does, noting whether the bytes were all there already."""
        self.waited = self.port.in_waiting < size
        return self.port.read(size, timeout_s)

    @property
    def baudrate(self) -> int:
        """Return the port's line speed."""
        return self.port.baudrate

    @baudrate.setter
    def baudrate(self, baud_bps: int) -> None:
        self.port.baudrate = baud_bps

    def __getattr__(self, name: str) -> Any:
        return getattr(self.port, name)
