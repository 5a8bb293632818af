"""
Wire timing of a half-duplex Dynamixel bus, shared by the in-process port and the pty server.

Model (README.md, The simulator: `--timing wire`):

* A UART frame is 10 bits per byte (start, 8 data, stop), so n bytes take n * 10 / baud seconds.
* An instruction of n bytes whose first byte leaves the host at t0 reaches the servos at
  t0 + n * 10 / baud. The host's transmitter is serial: a write issued while an earlier one is
  still on the wire starts when that one ends.
* Status packet k starts after the previous status packet ended (or, for the first, after the
  instruction ended) plus that servo's Return Delay Time, and takes m * 10 / baud.
* USB adapter latency timer, modelled simply: the adapter hands a status packet to the host
  `latency_s` after the packet's last byte reached it. A real FTDI chip flushes its buffer when its
  latency timer expires, anywhere from 0 to the timer setting after the data arrived; using the
  full setting is the worst case and keeps the model deterministic.
* Servos answering one request at the same place in the wire order (sharing an id) collide:
  sim/bus.py hands this module their replies already combined (sim/collision.py), one reply
  from the first one's start. A host writing while servos still answer is not modelled.
"""

import collections
import math
import threading
import time
from typing import Callable, Iterable, Protocol

from dxl_servo_driver import timerslack
from dxl_servo_driver.protocol import BITS_PER_BYTE

SPIN_S = 200e-6     # hybrid wait: sleep until this long before the deadline, then spin
FINE_SPIN_S = 40e-6  # the same once the thread's timer slack is 1 ns (sleeps wake ~10 us late)


def fine_timer_slack() -> float:
    """
    Ask Linux to wake this thread's sleeps on time; return the spin margin that then suffices.

    With the default slack short sleeps end 50-80 us late and a pacer must spin for long before
    each deadline, burning a core; with the slack at 1 ns (dxl_servo_driver.timerslack) a short
    spin keeps the pacing and frees the CPU.
    """
    return FINE_SPIN_S if timerslack.fine_timer_slack() else SPIN_S


class ReplyLike(Protocol):
    """What the scheduler needs of a sim.bus.Reply."""

    @property
    def data(self) -> bytes:
        """Whole status packet as it goes on the wire."""
        ...

    @property
    def return_delay_s(self) -> float:
        """Return Delay Time of the answering servo."""
        ...


def byte_time_s(baud_bps: int) -> float:
    """Return the time one byte occupies the wire at baud_bps."""
    return BITS_PER_BYTE / float(baud_bps)


class WireScheduler:
    """Compute when each status packet of the bus reaches the host."""

    def __init__(self, latency_s: float = 0.0) -> None:
        if not latency_s >= 0.0:
            raise ValueError(f'latency must be >= 0 s, got {latency_s!r}')
        self.latency_s = float(latency_s)
        self._tx_free_s = float('-inf')  # when the host's transmitter is idle again

    def instruction_end_s(self, now_s: float, n_bytes: int, baud_bps: int) -> float:
        """Record n_bytes written by the host at now_s; return when they reached the servos."""
        start_s = max(now_s, self._tx_free_s)
        end_s = start_s + n_bytes * byte_time_s(baud_bps)
        self._tx_free_s = end_s
        return end_s

    def schedule(self, instruction_end_s: float, replies: Iterable[ReplyLike],
                 baud_bps: int) -> list[tuple[float, bytes]]:
        """Return (delivery time at the host, bytes) for each reply, in wire order."""
        out: list[tuple[float, bytes]] = []
        line_free_s = instruction_end_s
        for reply in replies:
            start_s = line_free_s + max(0.0, reply.return_delay_s)
            end_s = start_s + len(reply.data) * byte_time_s(baud_bps)
            line_free_s = end_s
            out.append((end_s + self.latency_s, reply.data))
        return out


def hybrid_wait(until_s: float, clock: Callable[[], float] = time.monotonic,
                sleep: Callable[[float], None] = time.sleep, spin_s: float = SPIN_S) -> None:
    """
    Wait until clock() >= until_s.

    Sleeps until spin_s before the deadline (the OS wakes a sleeper late by tens to hundreds
    of microseconds), then spins on the clock. With spin_s == 0 it only sleeps, which is what an
    injected (fake) clock and sleep need.
    """
    while True:
        remaining_s = until_s - clock()
        if remaining_s <= 0.0:
            return
        if remaining_s > spin_s:
            sleep(remaining_s - spin_s if spin_s > 0.0 else remaining_s)
        # else: spin; the loop re-reads the clock


class LatenessStats:
    """How late replies were delivered versus their schedule (thread-safe)."""

    MAX_SAMPLES = 100_000  # percentiles over the most recent samples; count and max are exact

    def __init__(self) -> None:
        self._lock = threading.Lock()
        # Sorted only when asked: a record is on the simulator's delivery path, once per reply,
        # where keeping 100,000 samples sorted would cost more than delivering the reply.
        self._recent: collections.deque[float] = collections.deque(maxlen=self.MAX_SAMPLES)
        self._count = 0
        self._max_us = 0.0

    def record(self, late_s: float) -> None:
        """Record one delivery that happened late_s after its scheduled time."""
        late_us = late_s * 1e6 if late_s > 0.0 else 0.0
        with self._lock:
            self._count += 1
            if late_us > self._max_us:
                self._max_us = late_us
            self._recent.append(late_us)

    def summary(self) -> dict[str, float]:
        """Return count, p50, p99 and max lateness in microseconds."""
        with self._lock:
            ordered = sorted(self._recent)
            count, max_us = self._count, self._max_us
        return {
            'replies': count,
            'late_p50_us': _percentile(ordered, 0.50),
            'late_p99_us': _percentile(ordered, 0.99),
            'late_max_us': max_us,
        }

    def line(self) -> str:
        """Return the summary as 'replies=N late_p50_us=… late_p99_us=… late_max_us=…'."""
        s = self.summary()
        return (f"replies={int(s['replies'])} late_p50_us={s['late_p50_us']:.1f} "
                f"late_p99_us={s['late_p99_us']:.1f} late_max_us={s['late_max_us']:.1f}")


def _percentile(sorted_values: list[float], fraction: float) -> float:
    """Nearest-rank percentile of an ascending list; 0.0 when empty."""
    if not sorted_values:
        return 0.0
    rank = max(1, math.ceil(fraction * len(sorted_values)))
    return sorted_values[min(rank, len(sorted_values)) - 1]
