"""
The speed cases of `make bench` and `make bench-scale`, beside the table.

The node on recorded replies (ceiling_node.py), what `top` shows of it and the floor under it
(floor_loop.py), 12 servos behind a 1 ms adapter, a Protocol 1.0 bus, the cycle in one process
(cycle_cost.py), the CRC implementations, a leader and a follower (teleop_latency.py); the
scale cases: N = 50, two buses at once. extra_lines() says them as text.
"""

import json
import os
import pathlib
import statistics
import subprocess
import sys
import threading
import time
from typing import Any, Dict, List, Optional, Tuple

from bus_cases import run_case_retried, wire_bytes
from dxl_servo_driver.driver import state_block
from dxl_servo_driver.models import model_for
from dxl_servo_driver.protocol import BITS_PER_BYTE
from harness import (
    CLOCK_TICK_S, NAMESPACE, node_rate, NodeUnderTest, ROOT, ROUNDS, usual_bus_s, VirtualBus)
from teleop_latency import lines as teleop_lines, teleop_case

CEILING_COUNTS = (12, 24, 50)   # the node on recorded replies (ceiling_node.py)
TOP_SECONDS = 20.0      # the `top` case: the node at loop_rate 100 watched this long


def two_buses(n: int, baud: int, workdir: pathlib.Path) -> List[Dict[str, Any]]:
    """
    Measure two buses at once, one node each (more buses, more nodes): alone, then together.

    On two cores the two simulators, two nodes and the counting client share the machine, so
    'together' against 'alone' is what a second bus costs the first here.
    """
    buses = [VirtualBus(n, baud, workdir, tag=f'_{index}') for index in (0, 1)]
    nodes: List[NodeUnderTest] = []
    try:
        for index, bus in enumerate(buses):
            nodes.append(NodeUnderTest(n, baud, bus.link, workdir, f'{NAMESPACE}_bus{index}'))
        alone: List[List[float]] = [[], []]
        together: List[List[float]] = [[], []]
        for _ in range(ROUNDS):
            for index, node in enumerate(nodes):
                alone[index].append(node_rate(node.measure()))
            runs: List[Dict[str, Any]] = [{}, {}]

            def measure(index: int) -> None:
                runs[index] = nodes[index].measure()
            threads = [threading.Thread(target=measure, args=(index,)) for index in (0, 1)]
            for thread in threads:
                thread.start()
            for thread in threads:
                thread.join()
            for index in (0, 1):
                together[index].append(node_rate(runs[index]))
    finally:
        for node in nodes:
            node.close()
        for bus in buses:
            bus.close()
    limit = 1.0 / usual_bus_s(n, baud)
    return [{'case': f'two buses, bus {index}', 'n': n, 'baud': baud,
             'alone_hz': round(statistics.mean(alone[index]), 1),
             'together_hz': round(statistics.mean(together[index]), 1),
             'together_over_alone': round(statistics.mean(together[index])
                                          / statistics.mean(alone[index]), 3),
             'bus_limit_hz': round(limit, 1)} for index in (0, 1)]


def adapter_latency(n: int, baud: int, latency_ms: float,
                    workdir: pathlib.Path) -> Dict[str, Any]:
    """
    Measure a realistic adapter: replies held latency_ms (a USB latency timer) before delivery.

    Each cycle waits that once (the read; the write has no reply), so the best a cycle can do
    is its bus time plus the latency: the node's rate is given against that, its bus time
    counted from the bytes it put on the wire (the read, and the goal writes the simulator saw:
    a cycle with no goal writes none).
    """
    bus = VirtualBus(n, baud, workdir, tag='_latency', latency_ms=latency_ms)
    node: Optional[NodeUnderTest] = None
    try:
        node = NodeUnderTest(n, baud, bus.link, workdir, f'{NAMESPACE}_latency',
                             latency_timer_ms=latency_ms)
        runs = [node.measure() for _ in range(ROUNDS)]
        seen = bus.goals()
    finally:
        if node is not None:
            node.close()
        bus.close()
    cycles = sum(run['cycles'] for run in runs)
    writes = sum(len({t for t, servo_id, _ in seen
                      if servo_id == 1 and run['window'][0] <= t <= run['window'][1]})
                 for run in runs)
    rate = statistics.mean(node_rate(run) for run in runs)
    per_cycle = wire_bytes('node', n, rate, writes / cycles if cycles else 1.0)
    allowed = 1.0 / (per_cycle * BITS_PER_BYTE / baud + latency_ms / 1000.0)
    return {'case': f'adapter latency {latency_ms:g} ms', 'n': n, 'baud': baud,
            'rate_hz': round(rate, 1), 'allowed_hz': round(allowed, 1),
            'ratio': round(rate / allowed, 3)}


def protocol1_case(workdir: pathlib.Path, n: int = 12, baud: int = 1_000_000,
                   number: int = 12) -> Dict[str, Any]:
    """
    Measure a Protocol 1.0 bus: N AX-12A (no BULK_READ: one READ each; no tick: tagged reads).

    The limit is the cycle's own transactions (the node's wire plan): N reads of the direct
    block with its mean tag, and a 1.0 sync write when a command arrived.
    """
    from dxl_servo_driver.bus import READ_TAGS
    bus = VirtualBus(n, baud, workdir, tag='_p1', model=number)
    node: Optional[NodeUnderTest] = None
    runs: List[Dict[str, Any]] = []
    try:
        node = NodeUnderTest(n, baud, bus.link, workdir, f'{NAMESPACE}_p1', protocol=1.0)
        runs = [node.measure() for _ in range(ROUNDS)]
        seen = bus.goals()
    finally:
        if node is not None:
            node.close()
        bus.close()
    model = model_for(number)
    block = state_block.state_block(model, 'present_load')
    length = block.size + (0 if block.has_tick else (READ_TAGS - 1) // 2)
    cycles = sum(run['cycles'] for run in runs)
    wall = sum(run['wall_s'] for run in runs)
    rate = cycles / wall if wall else 0.0
    writes = sum(len({t for t, servo_id, _ in seen if servo_id == 1 and start <= t <= end})
                 for run in runs for start, end in [run['window']])
    per_cycle = (n * state_block.read_bytes_1(length)
                 + (writes / cycles if cycles else 0.0) * state_block.sync_write_bytes_1(n, 2))
    bus_s = per_cycle * BITS_PER_BYTE / baud
    cpu = sum(run['cpu_s'] for run in runs)
    return {'case': f'Protocol 1.0: {n} x {model.name} at {baud} bps', 'n': n, 'baud': baud,
            'rate_hz': round(rate, 1), 'bus_limit_hz': round(1.0 / bus_s, 1),
            'rate_ratio': round(rate * bus_s, 3), 'bytes_per_cycle': round(per_cycle, 1),
            'cpu_per_cycle_us': round(cpu / cycles * 1e6, 1) if cycles else None,
            'cycles': cycles}


def scale(workdir: pathlib.Path, failures: List[str]) -> Dict[str, Any]:
    """Run the scale cases: N = 50, two buses at once, a 1 ms adapter."""
    print('bench: scale: N=50 at 4000000 bps ...', file=sys.stderr, flush=True)
    n50 = run_case_retried(50, 4_000_000, workdir, failures)
    print('bench: scale: two buses of 12 at 4000000 bps ...', file=sys.stderr, flush=True)
    both = two_buses(12, 4_000_000, workdir)
    print('bench: scale: 12 servos behind a 1 ms adapter ...', file=sys.stderr, flush=True)
    latency = adapter_latency(12, 4_000_000, 1.0, workdir)
    return {'n50': n50, 'two_buses': both, 'adapter_latency': latency}


def ceiling_cases(workdir: pathlib.Path) -> List[Dict[str, Any]]:
    """
    Measure the node on an infinitely fast bus: port sim, the cycle reads answered from records.

    Its rate is the node's own ceiling (loop_rate at its 10 kHz maximum: a rate there is the
    loop_rate's, not the node's) and its CPU per cycle the node's alone, no simulator beside
    it; set against the 4 Mbps bus limit of the same servos.
    """
    rows = []
    for n in CEILING_COUNTS:
        node = NodeUnderTest(n, 4_000_000, 'sim', workdir, f'{NAMESPACE}_ceiling{n}',
                             ceiling=True)
        try:
            runs = [node.measure() for _ in range(ROUNDS)]
        finally:
            node.close()
        cycles = sum(run['cycles'] for run in runs)
        wall = sum(run['wall_s'] for run in runs)
        cpu = sum(run['cpu_s'] for run in runs)
        rate = cycles / wall if wall else 0.0
        limit = 1.0 / usual_bus_s(n, 4_000_000)
        rows.append({'n': n, 'rate_hz': round(rate, 1),
                     'cpu_per_cycle_us': round(cpu / cycles * 1e6, 1) if cycles else None,
                     'bus_limit_4mbps_hz': round(limit, 1),
                     'over_4mbps_limit': round(rate / limit, 2)})
    return rows


def thread_ticks(pid: int) -> Dict[str, Tuple[str, int]]:
    """Return each thread's (name, user + system clock ticks) of a process."""
    ticks = {}
    for tid in os.listdir(f'/proc/{pid}/task'):
        try:
            stat = pathlib.Path(f'/proc/{pid}/task/{tid}/stat').read_text()
        except OSError:
            continue   # ended meanwhile
        name = stat[stat.index('(') + 1:stat.rindex(')')]
        fields = stat.rsplit(')', 1)[1].split()
        ticks[tid] = (name, int(fields[11]) + int(fields[12]))
    return ticks


def top_case(workdir: pathlib.Path) -> Dict[str, Any]:
    """
    Measure what `top` shows: the node at loop_rate 100, 6 servos, virtual_bus wire at 1 Mbps.

    CPU share of one core over TOP_SECONDS from /proc, split by thread: the cycle thread (the
    busiest Python thread but the main one), the executor (the main thread), Fast DDS's threads,
    the rest; and the resident memory.
    """
    n, baud = 6, 1_000_000
    bus = VirtualBus(n, baud, workdir, tag='_top')
    node: Optional[NodeUnderTest] = None
    try:
        node = NodeUnderTest(n, baud, bus.link, workdir, f'{NAMESPACE}_top', loop_rate_hz=100.0)
        node.transition(1)   # configure
        node.transition(3)   # activate
        time.sleep(1.0)
        pid = node.process.pid
        before = thread_ticks(pid)
        start = time.monotonic()
        node.count = 0
        node.counting = True
        time.sleep(TOP_SECONDS)
        node.counting = False
        after = thread_ticks(pid)
        wall = time.monotonic() - start
        rss_kb = next(int(line.split()[1]) for line in
                      pathlib.Path(f'/proc/{pid}/status').read_text().splitlines()
                      if line.startswith('VmRSS'))
        published = node.count
        node.transition(4)
        node.transition(2)   # the port released: the floor takes the same bus
        floor = floor_case(node, bus)
    finally:
        if node is not None:
            node.close()
        bus.close()
    used = {tid: (name, ticks - before.get(tid, (name, 0))[1])
            for tid, (name, ticks) in after.items()}
    groups = {'cycle thread': 0, 'executor (main thread)': 0, 'DDS threads': 0, 'other': 0}
    python = sorted((ticks, tid) for tid, (name, ticks) in used.items()
                    if tid != str(pid) and not name.startswith('dds.'))
    cycle_tid = python[-1][1] if python else ''
    for tid, (name, ticks) in used.items():
        group = ('executor (main thread)' if tid == str(pid) else 'DDS threads'
                 if name.startswith('dds.') else 'cycle thread' if tid == cycle_tid else 'other')
        groups[group] += ticks
    total = sum(groups.values())
    share = (lambda ticks: round(100.0 * ticks * CLOCK_TICK_S / wall, 2))
    return {'case': f'top: {n} servos, loop_rate 100, {baud} bps', 'seconds': round(wall, 1),
            'cpu_percent': share(total),
            'us_per_cycle': round(total * CLOCK_TICK_S / (100.0 * wall) * 1e6),
            'joint_states_hz': round(published / wall, 1), 'rss_mb': round(rss_kb / 1024),
            'threads_percent': {group: share(ticks) for group, ticks in groups.items()},
            'floor': floor,
            'over_floor': round(share(total) / floor['cpu_percent'], 2)
            if floor['cpu_percent'] else None}


def floor_case(node: NodeUnderTest, bus: VirtualBus) -> Dict[str, Any]:
    """
    Measure bench/floor_loop.py on the `top` case's bus: the least an rclpy driver does there.

    Its joint_states are counted by the same client as the node's (a subscriber costs the
    publisher: both are measured with one).
    """
    from sensor_msgs.msg import JointState
    namespace = f'{NAMESPACE}_floor'
    got = [0]
    subscription = node.client.create_subscription(
        JointState, f'{namespace}/joint_states', lambda msg: got.__setitem__(0, got[0] + 1),
        100, raw=True)
    try:
        out = subprocess.run(
            [sys.executable, str(ROOT / 'bench' / 'floor_loop.py'), bus.link,
             str(1_000_000), str(6), str(TOP_SECONDS), namespace],
            capture_output=True, text=True, cwd=ROOT, timeout=TOP_SECONDS + 60)
    finally:
        node.client.destroy_subscription(subscription)
    if out.returncode != 0:
        raise RuntimeError(f'floor_loop failed: {out.stderr.strip()[-500:]}')
    run = json.loads(out.stdout.strip().splitlines()[-1])
    return {'cpu_percent': round(100.0 * run['cpu_s'] / run['wall_s'], 2),
            'us_per_cycle': round(run['cpu_s'] / run['cycles'] * 1e6),
            'joint_states_received': got[0], 'cycles': run['cycles'],
            'whole_replies': run['whole_replies']}


def cycle_cost_case() -> Optional[Dict[str, Any]]:
    """Run bench/cycle_cost.py (the cycle in one process on recorded replies, hot and cold)."""
    out = subprocess.run([sys.executable, str(ROOT / 'bench' / 'cycle_cost.py'), '--json'],
                         capture_output=True, text=True, cwd=ROOT, timeout=300)
    if out.returncode != 0:
        raise RuntimeError(f'cycle_cost failed: {out.stderr.strip()[-500:]}')
    return json.loads(out.stdout.strip().splitlines()[-1])


def crc_comparison(n: int = 12, rounds: int = 5, cycles: int = 2000) -> Dict[str, Any]:
    """
    Time the CRC checks of one cycle's replies, compiled (fastcrc) against pure Python.

    The N status packets of a sync read of the motion part and tick, as the bus checks them; both
    implementations in this process, interleaved round by round, the best round of each kept.
    """
    from dxl_servo_driver import protocol
    replies = [protocol.encode_status(servo_id, 0, bytes(state_block.BLOCK_SHAPE.tagged_size))[:-2]
               for servo_id in range(1, n + 1)]
    timings: Dict[str, List[float]] = {'compiled': [], 'python': []}
    functions = {'compiled': protocol.crc16, 'python': protocol.crc16_python}
    for _ in range(rounds):
        for name, function in functions.items():
            start = time.perf_counter()
            for _ in range(cycles):
                for reply in replies:
                    function(reply)
            timings[name].append((time.perf_counter() - start) / cycles * 1e6)
    compiled, python = min(timings['compiled']), min(timings['python'])
    return {'n': n, 'implementation': protocol.CRC_IMPLEMENTATION,
            'compiled_us_per_cycle': round(compiled, 2), 'python_us_per_cycle': round(python, 2),
            'ratio': round(compiled / python, 3)}


def speed_cases(workdir: pathlib.Path, failures: List[str]) -> Dict[str, Any]:
    """Run the speed cases: the ceiling, `top`, a 1 ms adapter, the in-process cycle."""
    extra: Dict[str, Any] = {}
    cases = [
        ('ceiling', 'the node on recorded replies, N = 12, 24, 50',
         lambda: ceiling_cases(workdir)),
        ('top', f'top: the node at loop_rate 100 for {TOP_SECONDS:g} s',
         lambda: top_case(workdir)),
        ('adapter_latency', '12 servos behind a 1 ms adapter',
         lambda: adapter_latency(12, 4_000_000, 1.0, workdir)),
        ('cycle_cost', 'the cycle in one process, hot and cold', cycle_cost_case),
        ('teleop', 'a leader and a follower at 100, 200, 500 Hz',
         lambda: teleop_case(workdir)),
    ]
    for key, what, run in cases:
        print(f'bench: {what} ...', file=sys.stderr, flush=True)
        try:
            extra[key] = run()
        except Exception as exc:  # noqa: B902 - one case must not end the whole benchmark
            failures.append(f'bench: {what} failed: {exc}')
    return extra


def extra_lines(extra: Dict[str, Any]) -> List[str]:
    """Return the speed cases as text."""
    lines = []
    for row in extra.get('ceiling', []):
        lines.append(f'ceiling, N={row["n"]}: {row["rate_hz"]} Hz ({row["over_4mbps_limit"]} x '
                     f'the 4 Mbps bus limit {row["bus_limit_4mbps_hz"]} Hz), CPU '
                     f'{row["cpu_per_cycle_us"]} us per cycle')
    top = extra.get('top')
    if top:
        threads = ', '.join(f'{group} {share} %' for group, share in
                            top['threads_percent'].items())
        lines.append(f'{top["case"]}: {top["cpu_percent"]} % of a core ({top["us_per_cycle"]} us '
                     f'per cycle; {threads}), {top["rss_mb"]} MB resident, joint_states '
                     f'{top["joint_states_hz"]} Hz')
        floor = top.get('floor')
        if floor:
            lines.append(f'  floor (bench/floor_loop.py, the same bus): {floor["cpu_percent"]} % '
                         f'({floor["us_per_cycle"]} us per cycle); the node {top["over_floor"]} '
                         'x the floor')
    latency = extra.get('adapter_latency')
    if latency:
        lines.append(f'{latency["case"]}: N={latency["n"]} at {latency["baud"]} bps: '
                     f'{latency["rate_hz"]} Hz of the {latency["allowed_hz"]} Hz it allows '
                     f'({latency["ratio"]})')
    if extra.get('cycle_cost'):
        # Not at the top: cycle_cost imports the node, and with it rclpy.
        from cycle_cost import lines as cost_lines
        lines += cost_lines(extra['cycle_cost'])
    if extra.get('teleop'):
        lines += teleop_lines(extra['teleop'])
    return lines


def protocol1_line(row: Dict[str, Any]) -> str:
    """Return the Protocol 1.0 case as one line."""
    return (f'{row["case"]}: node {row["rate_hz"]} Hz of a {row["bus_limit_hz"]} Hz bus limit '
            f'({row["rate_ratio"]}), {row["bytes_per_cycle"]} bytes per cycle, CPU '
            f'{row["cpu_per_cycle_us"]} us per cycle')
