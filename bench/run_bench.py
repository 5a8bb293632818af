"""
`make bench`: the driver against the stock SDK on a simulated bus paced like the real wire.

For N = 1, 6, 12, 24 servos at 1 and 4 Mbps (Return Delay Time 0), one `virtual_bus --timing
wire` serves five variants in turn, interleaved round by round so that machine noise hits all
alike:
- sdk_baseline: the plain dynamixel_sdk GroupSyncRead + GroupSyncWrite loop (worker process);
- bus: the node's cycle loop (driver/loop.CycleLoop) without ROS (worker process);
- node: the full node (its installed executable), driven through its lifecycle, joint_states
  counted by a subscriber here, commands published here and seen on the wire by the simulator;
- bus_fast, node_fast: the same two with Fast Sync Read (read_mode fast_sync).
CPU per cycle comes from each process's own accounting (process_time, /proc/PID/stat for the
node). The bus limit of each variant comes from the bytes it puts on the wire. The simulator's
own pacing (how late it delivered replies) is reported so that a slow simulator is not taken
for a slow driver; a case where it was late by more than a tenth of the bus time is marked as
paced by the simulator. A cycle counts only when every servo's sample came back good; the
others are counted apart, as failed.

Then the speed cases: the node on recorded replies (ceiling_node.py: an infinitely fast bus,
no simulator beside it) at N = 12, 24, 50; what `top` shows of the node at loop_rate 100 with 6
servos at 1 Mbps, split by thread; 12 servos behind a 1 ms adapter; and the cycle in one
process on recorded replies, hot and cold, with the memory blocks it leaves (cycle_cost.py);
a leader and a follower node, from a leader's horn turned to the follower's wire at 100, 200
and 500 Hz (teleop_latency.py; alone: `python bench/run_bench.py teleop`).
Results: bench-results/bench.json, bench-results/bench.png, a table and the targets on stdout.
"""

import json
import os
import pathlib
import platform
import random
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from typing import Any, Dict, List, Optional, Tuple

ROOT = pathlib.Path(__file__).resolve().parent.parent
# DDS of its own, before anything loads rclpy: another ROS process on the machine (a test run,
# a robot) must neither see the benchmark's traffic nor add to it. BENCH_DOMAIN_ID keeps one.
os.environ['ROS_DOMAIN_ID'] = os.environ.get(
    'BENCH_DOMAIN_ID', str(random.SystemRandom().randint(102, 232)))
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.pop('ROS_LOCALHOST_ONLY', None)
sys.path.insert(0, str(ROOT))

from dxl_servo_driver.driver import state_block  # noqa: E402 - after the path set-up above
from dxl_servo_driver.models import model_for  # noqa: E402
from dxl_servo_driver.models.units import units_for  # noqa: E402
from dxl_servo_driver.protocol import BITS_PER_BYTE  # noqa: E402

BAUDS = (1_000_000, 4_000_000)
COUNTS = (1, 6, 12, 24)
VARIANTS = ('sdk_baseline', 'bus', 'node', 'bus_fast', 'node_fast')
FAST_VARIANTS = ('bus_fast', 'node_fast')   # read_mode fast_sync: one status for all servos
ROUNDS = int(os.environ.get('BENCH_ROUNDS', '2'))
SECONDS = float(os.environ.get('BENCH_SECONDS', '1.5'))
NAMESPACE = '/bench'
NODE_NAME = 'dxl_servo_driver'
COMMAND_RATE_HZ = 50.0
CLOCK_TICK_S = 1.0 / os.sysconf('SC_CLK_TCK')
SDK_READ_BYTES = 10     # present_current + present_velocity + present_position
WRITE_BYTES = 4         # goal_position
HEALTH_RATE_HZ = 10.0   # the node reads its whole state block at state_rate (default 10 Hz)
SIM_PACED_SHARE = 0.1   # simulator late (p99) by more than this share of the bus time: its pace
CEILING_COUNTS = (12, 24, 50)   # the node on recorded replies (ceiling_node.py)
TOP_SECONDS = 20.0      # the `top` case: the node at loop_rate 100 watched this long
MANUAL_UNITS = units_for(model_for(1030))   # the simulated servos are the XM430 manual's


def percentile(values: List[float], fraction: float) -> float:
    """Return the value below which `fraction` of the values lie (nearest rank)."""
    ordered = sorted(values)
    index = min(len(ordered) - 1, max(0, int(round(fraction * len(ordered) + 0.5)) - 1))
    return ordered[index]


class VirtualBus:
    """A virtual_bus subprocess with wire timing and its control lines."""

    def __init__(self, n: int, baud: int, workdir: pathlib.Path, tag: str = '',
                 latency_ms: float = 0.0, model: Optional[int] = None) -> None:
        self.link = str(workdir / f'ttyBENCH_{n}_{baud}{tag}')
        self.trace = workdir / f'goals_{n}_{baud}{tag}.txt'
        models = [] if model is None else ['--models', *[str(model)] * n]
        self.process = subprocess.Popen(
            [sys.executable, '-m', 'dxl_servo_driver.sim.virtual_bus',
             '--ids', *[str(i) for i in range(1, n + 1)], '--baud', str(baud),
             '--timing', 'wire', '--return-delay-time', '0', '--link', self.link,
             '--latency-ms', str(latency_ms), '--trace-goals', str(self.trace), *models],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=ROOT)
        self.device = self.process.stdout.readline().strip()
        if not self.device:
            raise RuntimeError('virtual_bus did not start')

    def control(self, line: str) -> str:
        """Send one control line; return its one-line answer."""
        self.process.stdin.write(line + '\n')
        self.process.stdin.flush()
        return self.process.stdout.readline().strip()

    def pacing(self) -> Dict[str, float]:
        """Return how late the simulator delivered its replies (stats control line)."""
        answer = self.control('stats')
        fields = dict(part.split('=', 1) for part in answer.split()[2:] if '=' in part)
        return {key: float(value) for key, value in fields.items()}

    def goals(self) -> List[Tuple[float, int, int]]:
        """Return (time, id, raw goal) of every goal the simulator saw on the wire."""
        if not self.trace.exists():
            return []
        rows = []
        for line in self.trace.read_text().splitlines():
            t, servo_id, value = line.split()
            rows.append((float(t), int(servo_id), int(value)))
        return rows

    def close(self) -> None:
        """Stop the subprocess."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()


def usual_bus_s(n: int, baud: int) -> float:
    """Return the wire time of the node's usual cycle: the tagged sync read and a goal each."""
    return ((state_block.sync_read_bytes(n, state_block.BLOCK_SHAPE.tagged_size)
             + state_block.sync_write_bytes(n, WRITE_BYTES)) * BITS_PER_BYTE / baud)


def run_worker(variant: str, n: int, baud: int, link: str) -> Dict[str, float]:
    """Run the sdk or bus loop in its own process."""
    name = {'sdk_baseline': 'sdk', 'bus': 'bus', 'bus_fast': 'bus_fast'}[variant]
    out = subprocess.run(
        [sys.executable, str(ROOT / 'bench' / 'workers.py'), name, str(n), str(baud), link,
         str(SECONDS)], capture_output=True, text=True, cwd=ROOT, timeout=60)
    if out.returncode != 0:
        raise RuntimeError(f'{variant} worker failed: {out.stderr.strip()[-500:]}')
    return json.loads(out.stdout.strip().splitlines()[-1])


def cpu_seconds(pid: int) -> float:
    """Return user + system CPU seconds of a process, from /proc."""
    fields = pathlib.Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) * CLOCK_TICK_S


class NodeUnderTest:
    """The installed node executable, driven through its lifecycle by a client node here."""

    def __init__(self, n: int, baud: int, link: str, workdir: pathlib.Path,
                 namespace: str = NAMESPACE, read_mode: str = 'sync',
                 latency_timer_ms: float = 0.0, protocol: float = 2.0,
                 ceiling: bool = False, loop_rate_hz: float = 10000.0) -> None:
        import rclpy
        from rclpy.experimental import EventsExecutor
        from dxl_servo_driver_msgs.msg import JointCommand
        from lifecycle_msgs.srv import ChangeState
        from sensor_msgs.msg import JointState
        from ament_index_python.packages import get_package_prefix
        self.n = n
        self.joints = [f'j{i}' for i in range(1, n + 1)]
        tag = namespace.strip('/')
        params = workdir / f'params_{n}_{baud}_{tag}.yaml'
        lines = ['/**:', '  ros__parameters:', f'    port: {link}', f'    baud_rate: {baud}',
                 f'    read_mode: {read_mode}', f'    latency_timer: {latency_timer_ms}',
                 f'    protocol: {protocol}',
                 f'    loop_rate: {loop_rate_hz}', '    autostart: false',
                 f'    state_rate: {HEALTH_RATE_HZ}', f'    joints: [{", ".join(self.joints)}]']
        # Extra node parameters for experiments, e.g. BENCH_NODE_EXTRA='executor: events'.
        extra = os.environ.get('BENCH_NODE_EXTRA', '').split(';')
        lines += [f'    {item.strip()}' for item in extra if item.strip()]
        for i, joint in enumerate(self.joints, start=1):
            lines += [f'    {joint}:', f'      id: {i}', '      operating_mode: position']
        params.write_text('\n'.join(lines) + '\n')
        exe = pathlib.Path(get_package_prefix('dxl_servo_driver')) / 'lib' / 'dxl_servo_driver'
        # The ceiling: the node on recorded replies (port: sim, link unused).
        command = ([sys.executable, str(ROOT / 'bench' / 'ceiling_node.py')] if ceiling
                   else [str(exe / 'node')])
        self.log = open(workdir / f'node_{n}_{baud}_{tag}.log', 'w')
        self.process = subprocess.Popen(
            [*command, '--ros-args', '--params-file', str(params),
             '-r', f'__ns:={namespace}'], stdout=self.log, stderr=subprocess.STDOUT, cwd=ROOT)
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.client = rclpy.create_node(f'bench_client_{tag}', context=self.context)
        self.count = 0
        self.partial = 0
        self.counting = False
        from rclpy.serialization import serialize_message
        full = JointState(name=self.joints, position=[0.0] * n, velocity=[0.0] * n,
                          effort=[0.0] * n)
        self.full_size = len(serialize_message(full))
        # raw=True: the counter gets the serialized bytes, saving the deserialisation that
        # would otherwise compete with the node and the simulator for the two cores.
        self.client.create_subscription(JointState, f'{namespace}/joint_states',
                                        self._on_state, 100, raw=True)
        self.publisher = self.client.create_publisher(
            JointCommand, f'{namespace}/{NODE_NAME}/commands/position', 10)
        self.change = self.client.create_client(ChangeState,
                                                f'{namespace}/{NODE_NAME}/change_state')
        # An EventsExecutor takes a message for about a third of the CPU a
        # SingleThreadedExecutor does, and every microsecond the counter spends is taken from
        # the node under test on this machine's two cores. spin() would hold the interpreter:
        # spin_once in a loop, as the node's own main does.
        self.executor = EventsExecutor(context=self.context)
        self.executor.add_node(self.client)
        self._spinning = True
        self.spinner = threading.Thread(target=self._spin, daemon=True)
        self.spinner.start()
        self._msg_type = JointCommand
        self._change_type = ChangeState
        if not self.change.wait_for_service(timeout_sec=20.0):
            raise RuntimeError('the node did not come up (see its log in the bench work dir)')

    def _spin(self) -> None:
        while self._spinning:
            self.executor.spin_once(timeout_sec=0.1)

    def _on_state(self, msg: bytes) -> None:
        # Every joint answered in that cycle: the message carries all N names (serialized
        # size grows with the names; a message with fewer joints is shorter).
        if self.counting:
            if len(msg) >= self.full_size:
                self.count += 1
            else:
                self.partial += 1   # a cycle that did not read every servo: failed

    def transition(self, transition_id: int) -> None:
        """Ask for a lifecycle transition and wait for it."""
        request = self._change_type.Request()
        request.transition.id = transition_id
        future = self.change.call_async(request)
        deadline = time.monotonic() + 20.0
        while not future.done() and time.monotonic() < deadline:
            time.sleep(0.01)
        if not future.done() or not future.result().success:
            raise RuntimeError(f'lifecycle transition {transition_id} failed')

    def measure(self) -> Dict[str, Any]:
        """Activate, count joint_states and publish commands for SECONDS, deactivate."""
        self.transition(1)   # configure
        self.transition(3)   # activate
        time.sleep(0.3)      # warm-up
        published: List[Tuple[float, int]] = []
        self.count = 0
        self.partial = 0
        cpu0 = cpu_seconds(self.process.pid)
        wall0 = time.monotonic()
        self.counting = True
        next_command = wall0
        k = 0
        while time.monotonic() - wall0 < SECONDS:
            now = time.monotonic()
            if now >= next_command:
                raw = 1000 + (k % 2000)
                k += 1
                msg = self._msg_type()
                msg.name = self.joints
                msg.value = [MANUAL_UNITS.position_to_rad(raw)] * self.n
                published.append((time.monotonic(), raw))
                self.publisher.publish(msg)
                next_command += 1.0 / COMMAND_RATE_HZ
            time.sleep(0.002)
        self.counting = False
        wall = time.monotonic() - wall0
        cpu = cpu_seconds(self.process.pid) - cpu0
        cycles = self.count
        self.transition(4)   # deactivate
        self.transition(2)   # cleanup: releases the port for the other variants
        return {'cycles': cycles, 'wall_s': wall, 'cpu_s': cpu, 'failures': self.partial,
                'published': published, 'window': (wall0, wall0 + wall)}

    def close(self) -> None:
        """Stop the node and the client."""
        self._spinning = False
        self.spinner.join(timeout=5.0)
        self.executor.shutdown()
        self.client.destroy_node()
        import rclpy
        rclpy.try_shutdown(context=self.context)
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
            try:
                self.process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self.log.close()


def wire_bytes(variant: str, n: int, rate_hz: float, writes_per_cycle: float) -> float:
    """Return the average bytes one cycle of a variant puts on the wire."""
    if variant == 'sdk_baseline':
        return (state_block.sync_read_bytes(n, SDK_READ_BYTES)
                + state_block.sync_write_bytes(n, WRITE_BYTES))
    block = state_block.BLOCK_SHAPE
    # Every read of the node's cycle carries the tick (each sample is dated).
    if variant in FAST_VARIANTS:
        read = state_block.fast_sync_read_bytes(n, block.tagged_size)
    else:
        read = state_block.sync_read_bytes(n, block.tagged_size)
    if variant in ('bus', 'bus_fast'):
        return read + state_block.sync_write_bytes(n, WRITE_BYTES)
    # The node reads the whole block HEALTH_RATE_HZ times a second and writes only when a
    # command arrived.
    full_share = min(1.0, HEALTH_RATE_HZ / rate_hz) if rate_hz else 0.0
    extra = full_share * n * (block.size - block.tagged_size)
    return read + extra + writes_per_cycle * state_block.sync_write_bytes(n, WRITE_BYTES)


def command_latencies(published: List[Tuple[float, int]],
                      seen: List[Tuple[float, int, int]]) -> List[float]:
    """Return publication-to-wire latencies (s) of the commands the simulator saw."""
    first_seen: Dict[int, float] = {}
    for t, servo_id, value in seen:
        if servo_id == 1 and value not in first_seen:
            first_seen[value] = t
    latencies = []
    for t_pub, raw in published:
        t_seen = first_seen.get(raw)
        if t_seen is not None and t_seen >= t_pub:
            latencies.append(t_seen - t_pub)
    return latencies


def run_case_retried(n: int, baud: int, workdir: pathlib.Path,
                     failures: List[str]) -> List[Dict[str, Any]]:
    """Run a case; once more if it fails (and say so); never abort the run for one case."""
    for attempt in (1, 2):
        try:
            return run_case(n, baud, workdir)
        except Exception as exc:  # noqa: B902 - one case must not end the whole benchmark
            line = f'bench: N={n} at {baud} bps failed (attempt {attempt} of 2): {exc}'
            print(line, file=sys.stderr, flush=True)
            failures.append(line)
    return []


def run_case(n: int, baud: int, workdir: pathlib.Path) -> List[Dict[str, Any]]:
    """Measure the three variants on one simulated bus."""
    bus = VirtualBus(n, baud, workdir)
    nodes: Dict[str, NodeUnderTest] = {}
    samples: Dict[str, List[Dict[str, Any]]] = {variant: [] for variant in VARIANTS}
    try:
        nodes['node'] = NodeUnderTest(n, baud, bus.link, workdir)
        nodes['node_fast'] = NodeUnderTest(n, baud, bus.link, workdir, f'{NAMESPACE}_fast',
                                           'fast_sync')
        for round_index in range(ROUNDS):
            shift = round_index % len(VARIANTS)
            for variant in VARIANTS[shift:] + VARIANTS[:shift]:
                if variant in nodes:
                    samples[variant].append(nodes[variant].measure())
                else:
                    samples[variant].append(run_worker(variant, n, baud, bus.link))
        pacing = bus.pacing()
        seen = bus.goals()
    finally:
        for node in nodes.values():
            node.close()
        bus.close()
    rows = []
    for variant in VARIANTS:
        runs = samples[variant]
        cycles = sum(run['cycles'] for run in runs)
        wall = sum(run['wall_s'] for run in runs)
        cpu = sum(run['cpu_s'] for run in runs)
        rate = cycles / wall if wall else 0.0
        writes_per_cycle = 1.0
        latencies: List[float] = []
        if variant in nodes:
            writes = 0
            for run in runs:
                start, end = run['window']
                # Both nodes publish the same goal values: only this run's own goals count.
                own = [row for row in seen if start <= row[0] <= end + 0.1]
                writes += len({t for t, servo_id, _ in own if servo_id == 1 and t <= end})
                latencies += command_latencies(run['published'], own)
            writes_per_cycle = writes / cycles if cycles else 0.0
        per_cycle_bytes = wire_bytes(variant, n, rate, writes_per_cycle)
        bus_time_s = per_cycle_bytes * BITS_PER_BYTE / baud
        row: Dict[str, Any] = {
            'n': n, 'baud': baud, 'variant': variant,
            'rate_hz': round(rate, 1),
            'bus_limit_hz': round(1.0 / bus_time_s, 1),
            'rate_ratio': round(rate * bus_time_s, 3),
            'cpu_per_cycle_over_bus_time':
                round((cpu / cycles) / bus_time_s, 3) if cycles else None,
            'cpu_per_cycle_us': round(cpu / cycles * 1e6, 1) if cycles else None,
            'bytes_per_cycle': round(per_cycle_bytes, 1),
            'cycles': cycles,
            # Cycles that did not read every servo well (not counted in rate_hz); a node's:
            # joint_states that lacked a joint (one with none is not published at all).
            'failed_cycles': sum(run['failures'] for run in runs),
            # The workers say why: samples missing at the deadline, or refused as stale.
            'missing_samples': sum(run.get('missing_samples', 0) for run in runs),
            'stale_samples': sum(run.get('stale_samples', 0) for run in runs),
            'slack_ms_at_end': [run['slack_ms'] for run in runs if 'slack_ms' in run],
            'sim_late_p50_us': pacing.get('late_p50_us'),
            'sim_late_p99_us': pacing.get('late_p99_us'),
            # The simulator set the pace: its replies were late (p99) by more than a tenth of
            # the cycle's wire time, so the rate says more of it than of the driver.
            'sim_paced': (pacing.get('late_p99_us') or 0.0) > SIM_PACED_SHARE * bus_time_s * 1e6,
        }
        if variant in nodes:
            row['writes_per_cycle'] = round(writes_per_cycle, 3)
            row['commands_seen'] = len(latencies)
            if latencies:
                row['command_latency_p50_ms'] = round(statistics.median(latencies) * 1e3, 3)
                row['command_latency_p99_ms'] = round(percentile(latencies, 0.99) * 1e3, 3)
            else:
                row['command_latency_p50_ms'] = row['command_latency_p99_ms'] = None
        rows.append(row)
    return rows


def node_rate(run: Dict[str, Any]) -> float:
    """Return a node run's joint_states rate."""
    return run['cycles'] / run['wall_s'] if run['wall_s'] else 0.0


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
    """Run the scale cases of the speed issue: N = 50, two buses at once, a 1 ms adapter."""
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


def machine() -> Dict[str, Any]:
    """Describe the machine the figures come from."""
    cpu = 'unknown'
    try:
        for line in pathlib.Path('/proc/cpuinfo').read_text().splitlines():
            if line.startswith('model name'):
                cpu = line.split(':', 1)[1].strip()
                break
    except OSError:
        pass
    return {'cpu': cpu, 'cores': os.cpu_count(), 'python': platform.python_version(),
            'kernel': platform.release(), 'rounds': ROUNDS, 'seconds_per_round': SECONDS,
            'date': time.strftime('%Y-%m-%d')}


def per_added_servo_us(rows: List[Dict[str, Any]], first: int, last: int,
                       key: str = 'cpu_per_cycle_us') -> Optional[float]:
    """Return the CPU each added servo costs a cycle between two N of these rows."""
    at = {row['n']: row[key] for row in rows if row.get(key) is not None}
    if first not in at or last not in at:
        return None
    return round((at[last] - at[first]) / (last - first), 2)


def targets(rows: List[Dict[str, Any]], extra: Dict[str, Any]) -> List[str]:
    """Check one run's figures against the speed issue's goals (the README's Benchmark)."""
    at = {row['variant']: row for row in rows if row['n'] == 12 and row['baud'] == 4_000_000}
    if not {'node', 'sdk_baseline'} <= set(at):
        return ['N = 12 at 4 Mbps was not measured']
    node, sdk = at['node'], at['sdk_baseline']
    period_ms = 1e3 / node['rate_hz'] if node['rate_hz'] else float('inf')
    bus_ms = 1e3 / node['bus_limit_hz']
    checks: List[Tuple[str, Optional[bool], Any]] = [
        ('node cpu <= 0.25 x bus time (N = 12, 4 Mbps)',
         node['cpu_per_cycle_over_bus_time'] <= 0.25, node['cpu_per_cycle_over_bus_time']),
        ('node rate_ratio >= 0.9 (N = 12, 4 Mbps)',
         None if node['sim_paced'] else node['rate_ratio'] >= 0.9,
         f'{node["rate_ratio"]}' + (' (the simulator set the pace)' if node['sim_paced']
                                    else '')),
        (f'node latency p99 <= period + bus time ({period_ms + bus_ms:.2f} ms)',
         node['command_latency_p99_ms'] is not None
         and node['command_latency_p99_ms'] <= period_ms + bus_ms,
         node['command_latency_p99_ms']),
        ('node faster than sdk_baseline', node['rate_hz'] > sdk['rate_hz'],
         f'{node["rate_hz"]} vs {sdk["rate_hz"]} Hz'),
    ]
    node_rows = [row for row in rows if row['variant'] == 'node' and row['baud'] == 4_000_000]
    added = per_added_servo_us(node_rows, 12, 24)
    if added is not None:
        checks.append(('node cpu per added servo <= 5 us (N = 24 against 12, 4 Mbps)',
                       added <= 5.0, f'{added} us'))
    ceiling = extra.get('ceiling') or []
    for last in (24, 50):
        added = per_added_servo_us(ceiling, 12, last)
        if added is not None:
            checks.append((f'ceiling cpu per added servo <= 5 us (N = {last} against 12)',
                           added <= 5.0, f'{added} us'))
    at_12 = [row for row in ceiling if row['n'] == 12]
    if at_12:
        checks.append(('ceiling >= 3 x the 4 Mbps bus limit (N = 12)',
                       at_12[0]['over_4mbps_limit'] >= 3.0,
                       f'{at_12[0]["rate_hz"]} Hz, {at_12[0]["over_4mbps_limit"]} x'))
    latency = extra.get('adapter_latency')
    if latency:
        checks.append(('behind a 1 ms adapter >= 0.95 of what it allows',
                       latency['ratio'] >= 0.95, latency['ratio']))
    top = extra.get('top')
    if top:
        floor = top.get('floor') or {}
        checks.append(('top: loop_rate 100, 6 servos at 1 Mbps <= 2 % of a core',
                       top['cpu_percent'] <= 2.0, f'{top["cpu_percent"]} %'
                       + (f' (the floor: {floor["cpu_percent"]} %)' if floor else '')))
    failed = sum(row['failed_cycles'] for row in rows)
    checks.append(('0 failed cycles in every fault-free case', failed == 0,
                   ', '.join(f'{row["variant"]} N={row["n"]} {row["baud"]}: '
                             f'{row["failed_cycles"]}' for row in rows
                             if row['failed_cycles']) or '0'))
    above = [row for row in rows if row['rate_ratio'] > 1.0]
    checks.append(('no rate above its wire limit', not above,
                   ', '.join(f'{row["variant"]} N={row["n"]}: {row["rate_ratio"]}'
                             for row in above) or 'none'))
    word = {True: 'met   ', False: 'MISSED', None: 'n/a   '}
    return [f'{word[ok]}  {name}: {value}' for name, ok, value in checks]


def table(rows: List[Dict[str, Any]]) -> str:
    """Format the results as a text table."""
    head = (f'{"baud":>8} {"N":>3} {"variant":<13} {"rate Hz":>8} {"limit Hz":>9} '
            f'{"ratio":>6} {"cpu/bus":>8} {"cpu us":>7} {"lat p50":>8} {"lat p99":>8} '
            f'{"sim p99us":>9} {"failed":>6} {"paced":>5}')
    lines = [head, '-' * len(head)]
    for row in rows:
        p50 = row.get('command_latency_p50_ms')
        p99 = row.get('command_latency_p99_ms')
        lines.append(
            f'{row["baud"]:>8} {row["n"]:>3} {row["variant"]:<13} {row["rate_hz"]:>8.0f} '
            f'{row["bus_limit_hz"]:>9.0f} {row["rate_ratio"]:>6.2f} '
            f'{row["cpu_per_cycle_over_bus_time"]:>8.2f} {row["cpu_per_cycle_us"]:>7.0f} '
            f'{(f"{p50:.2f}" if p50 is not None else "-"):>8} '
            f'{(f"{p99:.2f}" if p99 is not None else "-"):>8} '
            f'{row["sim_late_p99_us"] or 0:>9.0f} {row["failed_cycles"]:>6} '
            f'{"sim" if row.get("sim_paced") else "":>5}')
    return '\n'.join(lines)


def plot(rows: List[Dict[str, Any]], path: pathlib.Path) -> None:
    """Draw rate ratio and CPU ratio against N for each baud and variant."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    figure, axes = plt.subplots(2, len(BAUDS), figsize=(11, 7), sharex=True)
    for column, baud in enumerate(BAUDS):
        for variant in VARIANTS:
            points = sorted((r['n'], r['rate_ratio'], r['cpu_per_cycle_over_bus_time'])
                            for r in rows if r['baud'] == baud and r['variant'] == variant)
            if not points:
                continue
            ns = [p[0] for p in points]
            axes[0][column].plot(ns, [p[1] for p in points], marker='o', label=variant)
            axes[1][column].plot(ns, [p[2] for p in points], marker='o', label=variant)
        axes[0][column].set_title(f'{baud / 1e6:g} Mbps, Return Delay Time 0')
        axes[0][column].set_ylabel('rate / bus limit')
        axes[0][column].set_ylim(0, 1.1)
        axes[0][column].axhline(1.0, color='grey', linewidth=0.5)
        axes[1][column].set_ylabel('CPU per cycle / bus time')
        axes[1][column].set_xlabel('servos on the bus (N)')
        axes[1][column].set_xticks(list(COUNTS))
        axes[0][column].legend()
    figure.suptitle('dxl_servo_driver vs dynamixel_sdk on virtual_bus --timing wire')
    figure.tight_layout()
    figure.savefig(path, dpi=90)
    plt.close(figure)


def protocol1_line(row: Dict[str, Any]) -> str:
    """Return the Protocol 1.0 case as one line."""
    return (f'{row["case"]}: node {row["rate_hz"]} Hz of a {row["bus_limit_hz"]} Hz bus limit '
            f'({row["rate_ratio"]}), {row["bytes_per_cycle"]} bytes per cycle, CPU '
            f'{row["cpu_per_cycle_us"]} us per cycle')


def main() -> int:
    """Run every case, write the JSON and the plot, print the table."""
    out_dir = ROOT / 'bench-results'
    out_dir.mkdir(exist_ok=True)
    if sys.argv[1:] == ['scale']:
        return main_scale(out_dir)
    if sys.argv[1:] == ['teleop']:
        from teleop_latency import lines as teleop_lines
        with tempfile.TemporaryDirectory(prefix='dxl-bench-') as tmp:
            print('\n'.join(teleop_lines(teleop_case(pathlib.Path(tmp)))))
        return 0
    if sys.argv[1:] == ['protocol1']:
        with tempfile.TemporaryDirectory(prefix='dxl-bench-') as tmp:
            print(protocol1_line(protocol1_case(pathlib.Path(tmp))))
        return 0
    counts = [int(c) for c in os.environ.get('BENCH_COUNTS', ' '.join(map(str, COUNTS))).split()]
    bauds = [int(b) for b in os.environ.get('BENCH_BAUDS', ' '.join(map(str, BAUDS))).split()]
    rows: List[Dict[str, Any]] = []
    failures: List[str] = []
    print(f'bench: ROS_DOMAIN_ID {os.environ["ROS_DOMAIN_ID"]}, localhost discovery',
          file=sys.stderr)
    with tempfile.TemporaryDirectory(prefix='dxl-bench-') as tmp:
        workdir = pathlib.Path(tmp)
        for baud in bauds:
            for n in counts:
                print(f'bench: N={n} at {baud} bps ...', file=sys.stderr, flush=True)
                rows.extend(run_case_retried(n, baud, workdir, failures))
        print('bench: Protocol 1.0, N=12 AX-12A at 1000000 bps ...', file=sys.stderr, flush=True)
        try:
            p1: Optional[Dict[str, Any]] = protocol1_case(workdir)
        except Exception as exc:  # noqa: B902 - one case must not end the whole benchmark
            p1 = None
            failures.append(f'bench: Protocol 1.0 case failed: {exc}')
        extra = speed_cases(workdir, failures)
    crc = crc_comparison()
    result = {'machine': machine(), 'cases': rows, 'crc': crc, 'protocol1': p1, **extra}
    (out_dir / 'bench.json').write_text(json.dumps(result, indent=1) + '\n')
    plot(rows, out_dir / 'bench.png')
    print(table(rows))
    print()
    for line in extra_lines(extra):
        print(line)
    if p1 is not None:
        print(protocol1_line(p1))
    print(f'CRC of one cycle\'s replies (N = {crc["n"]}): {crc["implementation"]} '
          f'{crc["compiled_us_per_cycle"]} us, pure Python {crc["python_us_per_cycle"]} us '
          f'(ratio {crc["ratio"]})')
    print()
    for line in targets(rows, extra):
        print(line)
    for line in failures:
        print(line)
    print(f'\nwritten: {out_dir / "bench.json"}, {out_dir / "bench.png"}')
    return 0


def speed_cases(workdir: pathlib.Path, failures: List[str]) -> Dict[str, Any]:
    """Run the speed issue's cases: the ceiling, `top`, a 1 ms adapter, the in-process cycle."""
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
        from cycle_cost import lines as cost_lines
        lines += cost_lines(extra['cycle_cost'])
    if extra.get('teleop'):
        from teleop_latency import lines as teleop_lines
        lines += teleop_lines(extra['teleop'])
    return lines


def teleop_case(workdir: pathlib.Path) -> Dict[str, Any]:
    """Run bench/teleop_latency.py's case (a leader and a follower, their latency)."""
    from teleop_latency import teleop_case as run   # it imports this module: not at the top
    return run(workdir)


def main_scale(out_dir: pathlib.Path) -> int:
    """Run `make bench-scale` (N = 50, two buses at once, a 1 ms adapter): bench-scale.json."""
    failures: List[str] = []
    print(f'bench: ROS_DOMAIN_ID {os.environ["ROS_DOMAIN_ID"]}, localhost discovery',
          file=sys.stderr)
    with tempfile.TemporaryDirectory(prefix='dxl-bench-') as tmp:
        result = scale(pathlib.Path(tmp), failures)
    result['machine'] = machine()
    (out_dir / 'bench-scale.json').write_text(json.dumps(result, indent=1) + '\n')
    print(table(result['n50']))
    print()
    for row in result['two_buses']:
        print(f'{row["case"]}: N={row["n"]} at {row["baud"]} bps: alone {row["alone_hz"]} Hz, '
              f'together {row["together_hz"]} Hz ({row["together_over_alone"]} of alone; '
              f'bus limit {row["bus_limit_hz"]} Hz)')
    latency = result['adapter_latency']
    print(f'{latency["case"]}: N={latency["n"]} at {latency["baud"]} bps: {latency["rate_hz"]} Hz '
          f'of the {latency["allowed_hz"]} Hz it allows ({latency["ratio"]})')
    for line in failures:
        print(line)
    print(f'\nwritten: {out_dir / "bench-scale.json"}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
