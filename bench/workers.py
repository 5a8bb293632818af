"""
The two loops the benchmark compares with the node, each run in its own process.

`python bench/workers.py sdk|bus N BAUD PORT SECONDS` prints one JSON line: cycles, wall seconds,
CPU seconds (this process's own accounting), failed cycles and why, after WARM_UP_S of cycles
not counted (as the node's measure). Both loops do what a control loop does:
read position, velocity and current of every servo, then write a goal position to every servo.
A cycle counts only when every servo's sample came back good (for the bus loop: and dated after
its request); any other is a failed cycle, counted apart and not as a cycle, so a rate is never
made of cycles that read nothing (or something old).
"""

import collections
import json
import struct
import sys
import time
from typing import Callable, Counter, Dict

# Cycles run before the measured ones, as the node's measure warms up: caches filled, the
# deadline slack fitted to the machine.
WARM_UP_S = 0.3


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


def bus_loop(n: int, baud: int, port_name: str, seconds: float,
             fast: bool = False) -> Dict[str, float]:
    """Run the driver's bus layer as the node's cycle does, without ROS (fast: Fast Sync Read)."""
    sys.path.insert(0, '.')
    from dxl_servo_driver import state_block
    from dxl_servo_driver.driver.clock import TickClock
    from dxl_servo_driver.bus import Bus
    from dxl_servo_driver.serial_port import open_port
    from dxl_servo_driver.models import model_for
    from dxl_servo_driver.timerslack import fine_timer_slack
    fine_timer_slack()   # as the node's cycle thread
    block = state_block.state_block(model_for(1030), 'present_current')
    bus = Bus(open_port(port_name, baud), baud, latency_timer_s=0.0, return_delay_s=0.0)
    ids = list(range(1, n + 1))
    for servo_id in ids:
        bus.write(servo_id, block.indirect_map_address(), block.indirect_map_bytes())
    goals = [(servo_id, struct.pack('<i', 2048)) for servo_id in ids]
    # As the node's cycle: every read carries the Realtime Tick, which dates each sample (a
    # stale one is a failure, and the next read lingers to get back in step).
    # The usual clean block is decoded whole by the bus (fields given), as in the node.
    length = block.tagged_size
    fields = block.tagged_struct.format.lstrip('<')
    count = block.TAGGED_FIELDS
    decode = block.decode_tagged
    tick = block.index['realtime_tick']
    clocks = {servo_id: TickClock() for servo_id in ids}
    linger = [False]

    def cycle(why: Counter[str]) -> bool:
        result = bus.begin_sync_read(block.read_address, length, ids, fast, linger[0],
                                     fields).collect()
        received = time.monotonic()
        linger[0] = False
        good = True
        whole = result.values
        for index, servo_id in enumerate(ids):
            if whole is not None:
                values = whole[index * count:(index + 1) * count]
            else:
                data = result.data[servo_id]
                if not isinstance(data, bytes):
                    good = False
                    why['missing_samples'] += 1
                    continue
                values = decode(data)
            if not clocks[servo_id].check(values[tick], result.sent_s, received):
                good = False
                linger[0] = True
                why['stale_samples'] += 1
        if linger[0]:
            bus.raise_slack()   # as the node's cycle: a late reply, more slack
        bus.sync_write(116, 4, goals)
        return good
    figures = measure(cycle, seconds)
    bus.close()
    # Why cycles failed: samples missing (no reply by the deadline) or refused as stale, and
    # the deadline slack at the end.
    figures['slack_ms'] = bus.slack_s * 1e3
    figures['slack_raised'] = bus.counters.slack_raised
    return figures


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
