"""
A read on a device sleeps until its answers can all be there (Bus._read, SerialPort.paced).

A tty wakes a poller at every piece of a reply that comes: each servo's status packet on the
simulator with wire timing, each USB transfer on an adapter. Each wake-up is a context switch,
and at 100 Hz those cost more CPU than the cycle's own work. A sync read of six servos at
57600 bps, whose answers come 4 ms apart, is counted here by the reading thread's voluntary
context switches (Linux keeps them per thread).
"""

import pathlib
import statistics
import time
from typing import Callable, List, Tuple

from dxl_servo_driver.bus import Bus
from dxl_servo_driver.serial_port import open_port
from dxl_servo_driver.sim.bus import SimBus
from dxl_servo_driver.sim.port import SimPortHandler
from dxl_servo_driver.sim.virtual_bus import configure_servos
import pytest

BAUD = 57_600
IDS = (1, 2, 3, 4, 5, 6)
PRESENT_POSITION = 132
READS = 5


def voluntary_switches() -> int:
    """Return how often this thread has given up the CPU to wait."""
    for line in pathlib.Path('/proc/thread-self/status').read_text().splitlines():
        if line.startswith('voluntary_ctxt_switches:'):
            return int(line.split()[1])
    raise AssertionError('no voluntary_ctxt_switches in /proc/thread-self/status')


def switches_per_read(bus: Bus) -> Tuple[List[int], List[bytes]]:
    """Return each read's context switches and the answers it got."""
    bus.sync_read(PRESENT_POSITION, 4, IDS)   # a first read: the simulator settles
    counts = []
    answers = []
    for _ in range(READS):
        before = voluntary_switches()
        result = bus.sync_read(PRESENT_POSITION, 4, IDS)
        counts.append(voluntary_switches() - before)
        assert result.clean, result.data
        answers.append(b''.join(result.data[servo_id] for servo_id in IDS))
    return counts, answers


@pytest.mark.skipif(not pathlib.Path('/proc/thread-self/status').exists(),
                    reason='counts context switches in Linux /proc')
def test_a_sync_read_on_a_device_wakes_once_not_once_per_answer(
        virtual_bus: Callable[..., object]) -> None:
    vb = virtual_bus(IDS, BAUD, extra_args=['--timing', 'wire', '--return-delay-time', '0'])
    counts = {}
    for paced in (True, False):
        port = open_port(vb.device, BAUD)   # type: ignore[attr-defined]
        try:
            if not paced:
                port.paced = False   # type: ignore[misc] - the poll-only read, to compare
            # A generous deadline: a busy machine may delay the simulator, which is not the
            # point here (the sleep ends on the wire time, never on the deadline).
            bus = Bus(port, BAUD, latency_timer_s=0.05)
            assert bus.least_return_delay_s == 0.0
            counts[paced], _ = switches_per_read(bus)
        finally:
            port.close()
    # Paced: the sleep, and at most one poll for an answer the simulator sent late. Polling
    # alone: woken by each of the six answers (a couple may come together).
    # (Medians: a busy machine may delay the simulator's answer or bunch two.)
    assert statistics.median(counts[True]) <= 2, counts
    assert statistics.median(counts[False]) >= 5, counts
    assert sum(counts[True]) * 2 <= sum(counts[False]), counts


def test_a_port_that_answers_at_once_is_never_waited_for() -> None:
    # The simulator in process (and the benchmark's recorded replies) answer at once: no
    # sleep for a wire they do not have. 9600 bps: the wire would take about 160 ms.
    sim = SimBus(list(IDS), boot_time_s=0.0)
    configure_servos(sim, 9600, None)
    port = SimPortHandler(sim, 'sim', 9600)
    bus = Bus(port, 9600, latency_timer_s=0.0)
    wire_s = bus.byte_time_s(14 + len(IDS) + len(IDS) * (11 + 4))
    began = time.monotonic()
    result = bus.sync_read(PRESENT_POSITION, 4, IDS)
    took_s = time.monotonic() - began
    assert result.clean
    assert took_s < 0.5 * wire_s, (took_s, wire_s)
