"""
A read on a device sleeps until its answers can all be there (Bus._read, SerialPort.paced).

A tty wakes a poller at every piece of a reply that comes: each servo's status packet on the
simulator with wire timing, each USB transfer on an adapter. Each wake-up is a context switch,
and at 100 Hz those cost more CPU than the cycle's own work. A sync read of six servos at
57600 bps, whose answers come 4 ms apart, is counted here by the reading thread's voluntary
context switches (Linux keeps them per thread). Behind an adapter whose answers come later
than the wire alone allows, the read learns that turnaround (Bus.turnaround_s) and sleeps
until then; the sleep ends on time with the thread's timer slack at 1 ns (timerslack).
"""

import pathlib
import statistics
import sys
import threading
import time
from typing import Callable, List, Tuple

from dxl_servo_driver.bus import Bus, TURNAROUND_ON_TIME
from dxl_servo_driver.serial_port import open_port
from dxl_servo_driver.sim.bus import SimBus
from dxl_servo_driver.sim.port import SimPortHandler
from dxl_servo_driver.sim.virtual_bus import configure_servos
from dxl_servo_driver.timerslack import fine_timer_slack
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


def run_in_thread(work: Callable[[], object]) -> object:
    """Run work() in a thread of its own (its timer slack changes) and return what it gave."""
    out: List[object] = []
    errors: List[BaseException] = []

    def run() -> None:
        try:
            out.append(work())
        except BaseException as exc:  # noqa: B902 - handed to the test's thread
            errors.append(exc)
    thread = threading.Thread(target=run)
    thread.start()
    thread.join(timeout=60.0)
    assert not thread.is_alive()
    if errors:
        raise errors[0]
    return out[0]


def thread_slack_ns() -> int:
    """Return the calling thread's timer slack (prctl PR_GET_TIMERSLACK)."""
    import ctypes
    return int(ctypes.CDLL(None, use_errno=True).prctl(30, 0, 0, 0, 0))


@pytest.mark.skipif(not sys.platform.startswith('linux'), reason='Linux timer slack')
def test_fine_timer_slack_is_the_calling_threads_own() -> None:
    before = thread_slack_ns()
    assert before > 1

    def set_and_read() -> int:
        assert fine_timer_slack()
        return thread_slack_ns()
    assert run_in_thread(set_and_read) == 1
    assert thread_slack_ns() == before   # this thread's own is untouched


def test_a_read_takes_what_is_there_without_waiting(
        virtual_bus: Callable[..., object]) -> None:
    vb = virtual_bus(IDS, 1_000_000)
    port = open_port(vb.device, 1_000_000)   # type: ignore[attr-defined]
    try:
        bus = Bus(port, 1_000_000, latency_timer_s=0.05)
        assert bus.ping(1) is not None
        # Nothing there: the read waits (and says so), to its timeout.
        began = time.monotonic()
        assert port.read(4, 0.05) == b''
        assert port.waited and time.monotonic() - began >= 0.045
        port.write(bytes.fromhex('ff ff fd 00 01 03 00 01 19 4e'))   # PING id 1
        deadline = time.monotonic() + 5.0
        while port.in_waiting < 14 and time.monotonic() < deadline:
            time.sleep(0.001)
        # All there: taken at once, no wait.
        answer = port.read(14, 1.0)
        assert len(answer) == 14 and answer[4] == 1 and not port.waited
    finally:
        port.close()


@pytest.mark.skipif(not pathlib.Path('/proc/thread-self/status').exists(),
                    reason='counts context switches in Linux /proc')
def test_the_turnaround_behind_a_slow_adapter_is_learned(
        virtual_bus: Callable[..., object]) -> None:
    # A 1 ms adapter: every answer comes 1 ms after its last byte crossed the wire. The read
    # learns to sleep that much longer, and then finds its block whole at most wake-ups.
    baud = 1_000_000
    vb = virtual_bus(IDS, baud, extra_args=['--timing', 'wire', '--return-delay-time', '0',
                                            '--latency-ms', '1'])
    port = open_port(vb.device, baud)   # type: ignore[attr-defined]
    try:
        bus = Bus(port, baud, latency_timer_s=0.004)

        def reads() -> Tuple[List[int], List[bool], float]:
            fine_timer_slack()
            bus.sync_read(PRESENT_POSITION, 4, IDS)
            waited = []
            for _ in range(150):
                assert bus.sync_read(PRESENT_POSITION, 4, IDS).clean
                waited.append(port.waited)
            counts, _ = switches_per_read(bus)
            return counts, waited, bus.turnaround_s
        counts, waited, turnaround_s = run_in_thread(reads)   # type: ignore[misc]
        assert 0.0008 <= turnaround_s <= 0.0025, turnaround_s
        # About TURNAROUND_ON_TIME of the reads found their block whole; a busy machine may
        # delay the simulator's answers, so the bound is loose.
        found = waited[-60:].count(False) / 60
        assert found >= TURNAROUND_ON_TIME - 0.3, waited
        # Woken once or twice, not by each of the six answers.
        assert statistics.median(counts) <= 2, counts
    finally:
        port.close()


def test_a_silent_servo_teaches_nothing(virtual_bus: Callable[..., object]) -> None:
    # Reads that did not get their block (id 9 never answers) neither raise nor lower it.
    vb = virtual_bus(IDS, 1_000_000, extra_args=['--timing', 'wire', '--return-delay-time', '0'])
    port = open_port(vb.device, 1_000_000)   # type: ignore[attr-defined]
    try:
        bus = Bus(port, 1_000_000, latency_timer_s=0.0)
        bus.turnaround_s = 0.0003
        for _ in range(5):
            assert not bus.sync_read(PRESENT_POSITION, 4, IDS + (9,)).clean
        assert bus.turnaround_s == 0.0003
        for _ in range(40):
            assert bus.sync_read(PRESENT_POSITION, 4, IDS).clean
        assert bus.turnaround_s < 0.0003   # the block was there: it comes down again
    finally:
        port.close()
