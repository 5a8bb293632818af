"""
The two loops the benchmark compares with the node, each run in its own process.

`python bench/workers.py sdk|bus N BAUD PORT SECONDS` prints one JSON line: cycles, wall seconds,
CPU seconds (this process's own accounting), failed cycles and why, after WARM_UP_S of cycles
not counted (as the node's measure). Both loops do what a control loop does:
read position, velocity and current of every servo, then write a goal position to every servo.
The bus loop is the node's own (driver/loop.CycleLoop, in its thread), without ROS. A cycle
counts only when every servo's sample came back good (for the bus loop: and dated after its
request); any other is a failed cycle, counted apart and not as a cycle, so a rate is never
made of cycles that read nothing (or something old).
"""

import collections
import json
import sys
import threading
import time
from typing import Any, Callable, Counter, Dict, List

# Cycles run before the measured ones, as the node's measure warms up: caches filled, the
# deadline slack fitted to the machine.
WARM_UP_S = 0.3
# The bus loop runs flat out, as the node in the benchmark (loop_rate far above the bus limit).
LOOP_RATE_HZ = 10000.0


def measure(cycle: Callable[[Counter[str]], bool], seconds: float) -> Dict[str, float]:
    """
    Run cycle() for WARM_UP_S, then for seconds, counting the second stretch only.

    cycle(why) returns whether every servo's sample came back good; it counts in why what went
    wrong. A cycle that was not good is counted as failed, never as a cycle.
    """
    why: Counter[str] = collections.Counter()
    warm_until = time.monotonic() + WARM_UP_S
    while time.monotonic() < warm_until:
        cycle(why)
    why.clear()
    cycles = failures = 0
    wall0 = time.monotonic()
    cpu0 = time.process_time()
    while time.monotonic() - wall0 < seconds:
        if cycle(why):
            cycles += 1
        else:
            failures += 1
    return {'cycles': cycles, 'wall_s': time.monotonic() - wall0,
            'cpu_s': time.process_time() - cpu0, 'failures': failures, **why}


def sdk_loop(n: int, baud: int, port_name: str, seconds: float) -> Dict[str, float]:
    """Run the loop every dynamixel_sdk user writes: GroupSyncRead + GroupSyncWrite."""
    import dynamixel_sdk as sdk
    port = sdk.PortHandler(port_name)
    if not port.openPort() or not port.setBaudRate(baud):
        raise SystemExit(f'cannot open {port_name} at {baud}')
    packet = sdk.PacketHandler(2.0)
    # present_current (126, 2) + present_velocity (128, 4) + present_position (132, 4)
    reader = sdk.GroupSyncRead(port, packet, 126, 10)
    writer = sdk.GroupSyncWrite(port, packet, 116, 4)
    ids = range(1, n + 1)
    for servo_id in ids:
        reader.addParam(servo_id)
        writer.addParam(servo_id, [0x00, 0x08, 0x00, 0x00])

    def cycle(why: Counter[str]) -> bool:
        good = reader.txRxPacket() == sdk.COMM_SUCCESS
        for servo_id in ids:
            if reader.isAvailable(servo_id, 126, 10):
                reader.getData(servo_id, 132, 4)
                reader.getData(servo_id, 128, 4)
                reader.getData(servo_id, 126, 2)
            else:
                good = False
                why['missing_samples'] += 1
        writer.txPacket()
        return good
    figures = measure(cycle, seconds)
    port.closePort()
    return figures


class Tally:
    """
    The bus loop's publish callback: its cycles counted as measure() counts the sdk loop's.

    Called by the loop's thread after each cycle: the first WARM_UP_S are not counted, then
    `seconds` are; `done` is set at the end. A cycle is good when its read went well and every
    servo's sample was taken fresh (dated after its request); a failed one says why from the
    manager's counters (read failures: no reply by the deadline; refused as stale), which move
    only in a cycle that failed.
    """

    def __init__(self, manager: Any, seconds: float) -> None:
        self._manager = manager
        self._servos = list(manager.order)
        self._seconds = seconds
        self._warm_until = time.monotonic() + WARM_UP_S
        self._wall0 = 0.0
        self._cpu0 = 0.0
        self._stats = manager.stats
        self.figures: Dict[str, float] = {}
        self.why: Counter[str] = collections.Counter()
        self.cycles = self.failures = 0
        self.done = threading.Event()

    def __call__(self, stamp_ns: int, read_ok: bool) -> None:
        """Count one cycle of the loop."""
        if self.done.is_set():
            return
        now = time.monotonic()
        if not self._wall0:
            if now >= self._warm_until:
                self._wall0, self._cpu0 = now, time.process_time()
                self._stats = self._manager.stats
            return
        if read_ok and all(servo.fresh for servo in self._servos):
            self.cycles += 1
        else:
            self.failures += 1
            stats = self._manager.stats
            self.why['missing_samples'] += stats.read_failures - self._stats.read_failures
            self.why['stale_samples'] += stats.stale_refused - self._stats.stale_refused
            self._stats = stats
        if now - self._wall0 >= self._seconds:
            self.figures = {'cycles': self.cycles, 'wall_s': time.monotonic() - self._wall0,
                            'cpu_s': time.process_time() - self._cpu0,
                            'failures': self.failures,
                            **{key: count for key, count in self.why.items() if count}}
            self.done.set()


class Goals:
    """The bus loop's one cycle step: a goal position for every servo, every cycle."""

    def __init__(self, manager: Any, joints: List[str]) -> None:
        self._manager = manager
        self._joints = joints
        self._centre = [0.0] * len(joints)   # 0 rad: raw 2048, the centre of a turn

    def idle(self) -> bool:
        """Never idle: the cycle writes every time, so no read is chained."""
        return False

    def prepare_goals(self, now_s: float) -> None:
        """Queue this cycle's goals."""
        self._manager.command('position', self._joints, self._centre)

    def watch_samples(self, read_ok: bool) -> None:
        """Nothing to judge."""


def bus_loop(n: int, baud: int, port_name: str, seconds: float,
             fast: bool = False) -> Dict[str, float]:
    """
    Run the node's cycle loop without ROS: driver/loop.CycleLoop on a Manager of the port.

    The loop the node runs (its thread, flat out, pipelined, every sample dated by its Realtime
    Tick, the usual clean block decoded whole, a late reply answered with more deadline slack),
    given a goal position for every servo every cycle; fast: Fast Sync Read. Unlike the
    node: the tagged part of the block only (no health reads after the first) and no retries,
    so a cycle with a sample missing fails.
    """
    sys.path.insert(0, '.')
    from dxl_servo_driver.config import validate
    from dxl_servo_driver.driver.loop import CycleLoop, PrintLog
    from dxl_servo_driver.driver.manager import Manager
    joints = [f'j{i}' for i in range(1, n + 1)]
    params: Dict[str, Any] = {
        'port': port_name, 'baud_rate': baud, 'latency_timer': 0.0,
        'read_mode': 'fast_sync' if fast else 'sync', 'read_retries': 0,
        'loop_rate': LOOP_RATE_HZ, 'joints': joints}
    for servo_id, joint in enumerate(joints, start=1):
        params[f'{joint}.id'] = servo_id
        params[f'{joint}.operating_mode'] = 'position'
    log = PrintLog(verbose=False)
    manager = Manager(validate(params), info=lambda line: None, warn=lambda line: None,
                      error=log.error)
    manager.configure()
    manager.activate()
    manager.health_period_s = 1e9   # the bus limit of this variant counts the tagged read
    tally = Tally(manager, seconds)
    loop = CycleLoop(lambda: manager, LOOP_RATE_HZ, tally, log, steps=[Goals(manager, joints)])
    loop.start('thread', manager.bus_budget().cycle_time_s)
    try:
        finished = tally.done.wait(WARM_UP_S + seconds + 30.0)
    finally:
        loop.stop()
    bus = manager.bus
    assert bus is not None
    # The deadline slack at the end (raised when a reply came after it).
    slack = {'slack_ms': bus.slack_s * 1e3, 'slack_raised': bus.counters.slack_raised}
    manager.deactivate()
    manager.close()
    if not finished:
        raise SystemExit(f'the bus loop did not finish ({loop.failure!r})')
    return {**tally.figures, **slack}


def main() -> None:
    """Run one loop and print its figures as JSON."""
    variant, n, baud, port_name, seconds = sys.argv[1:6]
    if variant == 'bus_fast':
        figures = bus_loop(int(n), int(baud), port_name, float(seconds), fast=True)
    else:
        loop = {'sdk': sdk_loop, 'bus': bus_loop}[variant]
        figures = loop(int(n), int(baud), port_name, float(seconds))
    print(json.dumps(figures), flush=True)


if __name__ == '__main__':
    main()
