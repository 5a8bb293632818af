"""
A read on a device sleeps until its answers can all be there (Bus._read, SerialPort.paced).

A tty wakes a poller at every piece of a reply that comes: each servo's status packet on the
simulator with wire timing, each USB transfer on an adapter. Each wake-up is a context switch,
and at 100 Hz those cost more CPU than the cycle's own work. Behind an adapter whose answers come
later than the wire alone allows, the read learns that turnaround (Bus.turnaround_s) and sleeps
until then; the sleep ends on time with the thread's timer slack at 1 ns (timerslack).

Wake-ups and the turnaround learned are counted on the test's own clock (fake_clock): the
simulator's wire-timed port brings each answer when the wire model says, a paced port says so
(PacedPort), and every sleep (the bus's, the port's wait for the next answer) is a wake-up. On a
real device and a busy machine both depend on when the simulator process and the reader happen
to run (late answers, answers bunched, reads that wake late); that is the benchmark's to
measure. The device itself is checked for what it must do whatever the timing: a read takes what
is there without waiting.
"""

import statistics
import sys
import threading
import time
from typing import Callable, List, Tuple

from dxl_servo_driver.bus import Bus
from dxl_servo_driver.bus.wire import TURNAROUND_ON_TIME
from dxl_servo_driver.port.serial_device import open_port
from dxl_servo_driver.sim.bus import SimBus
from dxl_servo_driver.sim.port import SimPortHandler
from dxl_servo_driver.sim.virtual_bus import configure_servos
from dxl_servo_driver.timerslack import fine_timer_slack
from fake_clock import FakeClock, PacedPort
import pytest

BAUD = 57_600
IDS = (1, 2, 3, 4, 5, 6)
PRESENT_POSITION = 132
READS = 5


def wakes_per_read(bus: Bus, clock: FakeClock, reads: int = READS
                   ) -> Tuple[List[int], List[bool]]:
    """Return each read's wake-ups (sleeps on the clock) and whether its port had to wait."""
    bus.sync_read(PRESENT_POSITION, 4, IDS)   # a first read: the simulator settles
    counts = []
    waited = []
    for _ in range(reads):
        before = len(clock.sleeps)
        result = bus.sync_read(PRESENT_POSITION, 4, IDS)
        counts.append(len(clock.sleeps) - before)
        waited.append(bool(getattr(bus.port, 'waited', True)))
        assert result.clean, result.data
        clock.sleep(0.01)   # the rest of a cycle
    return counts, waited


def fake_bus(clock: FakeClock, baud_bps: int, paced: bool, latency_s: float = 0.0,
             latency_timer_s: float = 0.05) -> Bus:
    """Return a bus on simulated servos whose answers come at wire speed on the clock."""
    sim = clock.sim(IDS)
    configure_servos(sim, baud_bps, 0)   # Return Delay Time 0: the wire alone
    port = clock.port(sim, baud_bps, latency_s)
    return Bus(PacedPort(port) if paced else port, baud_bps, latency_timer_s=latency_timer_s)


def test_a_sync_read_on_a_device_wakes_once_not_once_per_answer(
        monkeypatch: pytest.MonkeyPatch) -> None:
    # Six answers 4 ms apart at 57600 bps.
    clock = FakeClock().install(monkeypatch)
    counts = {}
    for paced in (True, False):
        bus = fake_bus(clock, BAUD, paced)
        assert bus.least_return_delay_s == 0.0
        counts[paced], _ = wakes_per_read(bus, clock)
    # Paced: the sleep until the last answer is due, and the block is there. Polling alone:
    # woken by each of the six answers.
    assert statistics.median(counts[True]) <= 2, counts
    assert statistics.median(counts[False]) >= 5, counts
    assert sum(counts[True]) * 2 <= sum(counts[False]), counts


def test_a_port_that_answers_at_once_is_never_waited_for(
        monkeypatch: pytest.MonkeyPatch) -> None:
    # The simulator in process (and the benchmark's recorded replies) answer at once: no
    # sleep for a wire they do not have. 9600 bps: the wire would take about 160 ms. The waits
    # asked for are counted, not how long the read took (a busy machine decides that).
    sim = SimBus(list(IDS), boot_time_s=0.0)
    configure_servos(sim, 9600, None)
    waits: List[float] = []
    real_sleep = time.sleep

    def sleep(seconds: float) -> None:
        waits.append(seconds)
        real_sleep(seconds)
    monkeypatch.setattr(time, 'sleep', sleep)   # the bus's own (a paced read's)
    port = SimPortHandler(sim, 'sim', 9600, sleep=sleep)   # the port's, for bytes to come
    bus = Bus(port, 9600, latency_timer_s=0.0)
    wire_s = bus.byte_time_s(14 + len(IDS) + len(IDS) * (11 + 4))
    result = bus.sync_read(PRESENT_POSITION, 4, IDS)
    assert result.clean
    assert sum(waits) < 0.5 * wire_s, (waits, wire_s)
    assert bus.counters.deadline_waits == 0


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
        deadline = time.monotonic() + 30.0   # a busy machine may hold the simulator back
        while port.in_waiting < 14:
            assert time.monotonic() < deadline, f'{port.in_waiting} of 14 bytes came'
            time.sleep(0.001)
        # All there: taken at once, no wait.
        answer = port.read(14, 1.0)
        assert len(answer) == 14 and answer[4] == 1 and not port.waited
    finally:
        port.close()


def test_the_turnaround_behind_a_slow_adapter_is_learned(monkeypatch: pytest.MonkeyPatch) -> None:
    # A 1 ms adapter: every answer comes 1 ms after its last byte crossed the wire. The read
    # learns to sleep that much longer, and then finds its block whole at most wake-ups.
    clock = FakeClock().install(monkeypatch)
    bus = fake_bus(clock, 1_000_000, paced=True, latency_s=0.001, latency_timer_s=0.004)
    bus.sync_read(PRESENT_POSITION, 4, IDS)
    waited = []
    for _ in range(150):
        assert bus.sync_read(PRESENT_POSITION, 4, IDS).clean
        waited.append(bus.port.waited)
        clock.sleep(0.01)
    counts, _ = wakes_per_read(bus, clock)
    turnaround_s = bus.turnaround_s
    assert 0.0008 <= turnaround_s <= 0.0025, turnaround_s
    # About TURNAROUND_ON_TIME of the reads found their block whole.
    found = waited[-60:].count(False) / 60
    assert found >= TURNAROUND_ON_TIME - 0.3, waited
    # Woken once or twice, not by each of the six answers.
    assert statistics.median(counts) <= 2, counts


def test_a_silent_servo_teaches_nothing(monkeypatch: pytest.MonkeyPatch) -> None:
    # Reads that did not get their block (id 9 never answers) neither raise nor lower it.
    clock = FakeClock().install(monkeypatch)
    bus = fake_bus(clock, 1_000_000, paced=True, latency_timer_s=0.0)
    bus.turnaround_s = 0.0003
    for _ in range(5):
        assert not bus.sync_read(PRESENT_POSITION, 4, IDS + (9,)).clean
        clock.sleep(0.01)
    assert bus.turnaround_s == 0.0003
    for _ in range(40):
        assert bus.sync_read(PRESENT_POSITION, 4, IDS).clean
        clock.sleep(0.01)
    assert bus.turnaround_s < 0.0003   # the block was there: it comes down again
