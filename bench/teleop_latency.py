"""
The teleoperation case of `make bench`: from a leader's horn turned to the follower's wire.

Two `virtual_bus --timing wire` buses (6 servos each, 1 Mbps, Return Delay Time 0) and two
installed driver nodes: a leader (torque off, namespace /bench_leader) and a follower
(/bench_follower, follow.topic the leader's joint_states, max_step wide enough that one goal
carries the whole turn). For each sample a hand turns one leader servo at once (the console's
`turn ID RAD 0`), and the follower's simulator records when its Goal Position carrying the new
angle reached the follower's wire (`--trace-goals`, CLOCK_MONOTONIC like this process's).
p50/p99 of that latency at loop rates 100, 200 and 500 Hz (both nodes, set at run time), the
CPU of both nodes over the samples, and the stages:
- leader read: from the turn to the leader's next read going out (its joint_states stamp);
- publish: that read on the wire, collected, published, delivered (this process's subscriber
  on the leader's joint_states stands in for the follower's: the same message, the same
  machine);
- follower cycle: from that delivery to the follower's goal write going out (the wait for the
  follower's next cycle, its read, its prepare_goals);
- wire: the follower's sync write on the wire (computed from its bytes).
Run alone: `python bench/teleop_latency.py` prints the figures and the JSON.
"""

import json
import os
import pathlib
import random
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from typing import Any, Dict, List, Optional, Tuple

if __name__ == '__main__':   # run alone: the package of this source tree, as run_bench.py
    sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent))

from dxl_servo_driver.driver import state_block  # noqa: E402 - after the path set-up above
from dxl_servo_driver.protocol import BITS_PER_BYTE  # noqa: E402
from harness import (  # noqa: E402
    cpu_seconds, MANUAL_UNITS, own_dds_domain, percentile, ROOT, VirtualBus)

N = 6
BAUD = 1_000_000
RATES_HZ = (100.0, 200.0, 500.0)
SAMPLES = int(os.environ.get('BENCH_TELEOP_SAMPLES', '40'))
TURN_RAD = 0.3
SAMPLE_TIMEOUT_S = 2.0
LEADER_NS = '/bench_leader'
FOLLOWER_NS = '/bench_follower'
NODE = 'dxl_servo_driver'


def _params(path: pathlib.Path, link: str, leader: bool) -> pathlib.Path:
    lines = ['/**:', '  ros__parameters:', f'    port: {link}', f'    baud_rate: {BAUD}',
             '    latency_timer: 0.0', f'    loop_rate: {RATES_HZ[0]}',
             # Set-up reads tried again over a host's hiccup (two simulators may stall at
             # once on a busy machine), as the tests do.
             '    ping_retries: 10',
             f'    joints: [{", ".join(f"j{i}" for i in range(1, N + 1))}]']
    if leader:
        lines.append('    torque_on_start: false')
    else:
        lines += ['    follow:', f'      topic: {LEADER_NS}/joint_states',
                  '      max_step: 3.0', '      timeout: 0.5']
    for i in range(1, N + 1):
        lines += [f'    j{i}:', f'      id: {i}', '      operating_mode: position']
    path.write_text('\n'.join(lines) + '\n')
    return path


class Pair:
    """The two buses, the two nodes, and a client: leader joint_states, parameters."""

    def __init__(self, workdir: pathlib.Path) -> None:
        import rclpy
        from rclpy.experimental import EventsExecutor
        from rcl_interfaces.srv import SetParameters
        from sensor_msgs.msg import JointState
        from ament_index_python.packages import get_package_prefix
        self.leader_bus = VirtualBus(N, BAUD, workdir, tag='_teleop_leader')
        self.follower_bus = VirtualBus(N, BAUD, workdir, tag='_teleop_follower')
        exe = str(pathlib.Path(get_package_prefix('dxl_servo_driver')) / 'lib'
                  / 'dxl_servo_driver' / 'node')
        self.logs = []
        self.nodes: List[subprocess.Popen] = []
        for name, ns, bus, leader in (('leader', LEADER_NS, self.leader_bus, True),
                                      ('follower', FOLLOWER_NS, self.follower_bus, False)):
            params = _params(workdir / f'teleop_{name}.yaml', bus.link, leader)
            log = open(workdir / f'teleop_{name}.log', 'w')
            self.logs.append(log)
            self.nodes.append(subprocess.Popen(
                [exe, '--ros-args', '--params-file', str(params), '-r', f'__ns:={ns}'],
                stdout=log, stderr=subprocess.STDOUT, cwd=ROOT))
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.client = rclpy.create_node('bench_teleop_client', context=self.context)
        self._lock = threading.Lock()
        self.leader_msgs: List[Tuple[float, int, Tuple[Optional[float], ...]]] = []
        self.client.create_subscription(JointState, f'{LEADER_NS}/joint_states',
                                        self._on_leader, 100)
        self.set_params = [self.client.create_client(SetParameters, f'{ns}/{NODE}/set_parameters')
                           for ns in (LEADER_NS, FOLLOWER_NS)]
        self.executor = EventsExecutor(context=self.context)
        self.executor.add_node(self.client)
        self._spinning = True
        self.spinner = threading.Thread(target=self._spin, daemon=True)
        self.spinner.start()
        for client in self.set_params:
            if not client.wait_for_service(timeout_sec=30.0):
                raise RuntimeError('a node did not come up (see its log in the work dir)')

    def _spin(self) -> None:
        while self._spinning:
            self.executor.spin_once(timeout_sec=0.1)

    def _on_leader(self, msg: Any) -> None:
        received = time.monotonic()
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        with self._lock:
            # By joint index j1..jN: a joint whose read failed in a cycle is left out of that
            # cycle's joint_states (None here), so positions are placed by name.
            by_name = dict(zip(msg.name, msg.position))
            self.leader_msgs.append((received, stamp, tuple(
                by_name.get(f'j{i}') for i in range(1, N + 1))))
            del self.leader_msgs[:-2000]

    def set_rate(self, hz: float) -> None:
        """Set loop_rate on both nodes (a runtime parameter)."""
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter
        for client in self.set_params:
            request = SetParameters.Request(
                parameters=[Parameter('loop_rate', value=hz).to_parameter_msg()])
            future = client.call_async(request)
            deadline = time.monotonic() + 10.0
            while not future.done() and time.monotonic() < deadline:
                time.sleep(0.01)
            if not future.done() or not future.result().results[0].successful:
                raise RuntimeError(f'loop_rate {hz} was not taken')

    def leader_seen(self, after_s: float, index: int, raw: int) -> Optional[Tuple[float, int]]:
        """Return (receipt, stamp ns) of the first leader message after after_s showing raw."""
        want = MANUAL_UNITS.position_to_rad(raw)
        with self._lock:
            for received, stamp, positions in self.leader_msgs:
                position = positions[index]
                if received > after_s and position is not None and abs(position - want) < 2.5e-3:
                    return received, stamp
        return None

    def close(self) -> None:
        import rclpy
        self._spinning = False
        self.spinner.join(timeout=5.0)
        self.executor.shutdown()
        self.client.destroy_node()
        rclpy.try_shutdown(context=self.context)
        for node in self.nodes:
            if node.poll() is None:
                node.send_signal(2)
                try:
                    node.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    node.kill()
                    node.wait()
        for log in self.logs:
            log.close()
        self.leader_bus.close()
        self.follower_bus.close()


class Trace:
    """The follower's goal trace, read on from where the last look ended (it grows fast)."""

    def __init__(self, path: pathlib.Path) -> None:
        self._path = path
        self._offset = 0

    def find(self, servo_id: int, raw: int, after_s: float) -> Optional[float]:
        """Return when a goal of servo_id near raw reached the wire after after_s, if it did."""
        if not self._path.exists():
            return None
        with open(self._path) as trace:
            trace.seek(self._offset)
            text = trace.read()
        end = text.rfind('\n') + 1   # a line being written is read next time
        self._offset += end
        for line in text[:end].splitlines():
            t, sid, value = line.split()
            if float(t) > after_s and int(sid) == servo_id and abs(int(value) - raw) <= 2:
                return float(t)
        return None


def measure_rate(pair: Pair, hz: float, rng: random.Random) -> Dict[str, Any]:
    """Turn leader servos SAMPLES times at this loop rate; return latencies, stages, CPU."""
    pair.set_rate(hz)
    time.sleep(1.0)   # settled at the new rate
    wall_ns_minus_mono = time.time_ns() - time.monotonic_ns()
    write_s = state_block.sync_write_bytes(N, 4) * BITS_PER_BYTE / BAUD
    cpu0 = [cpu_seconds(node.pid) for node in pair.nodes]
    wall0 = time.monotonic()
    latencies: List[float] = []
    stages: Dict[str, List[float]] = {'leader_read': [], 'publish': [], 'follower_cycle': [],
                                      'wire': []}
    console: List[float] = []
    missed = 0
    trace = Trace(pair.follower_bus.trace)
    trace.find(0, 0, time.monotonic())   # skip what is there
    for k in range(SAMPLES):
        servo_id = 1 + k % N
        sign = 1 if (k // N) % 2 == 0 else -1
        rad = sign * TURN_RAD
        raw = MANUAL_UNITS.zero_raw + round(rad / MANUAL_UNITS.rad_per_pulse)
        sent = time.monotonic()
        answer = pair.leader_bus.control(f'turn {servo_id} {rad} 0')
        answered = time.monotonic()
        if not answer.startswith('ok'):
            raise RuntimeError(f'turn: {answer}')
        console.append(answered - sent)
        deadline = sent + SAMPLE_TIMEOUT_S
        on_wire = None
        while on_wire is None and time.monotonic() < deadline:
            time.sleep(0.002)
            on_wire = trace.find(servo_id, raw, sent)
        if on_wire is None:
            missed += 1
            print(f'bench: teleop at {hz:g} Hz: servo {servo_id} turned to {rad} rad, not on the '
                  f"follower's wire within {SAMPLE_TIMEOUT_S:g} s", file=sys.stderr, flush=True)
            continue
        latencies.append(on_wire - sent)
        seen = pair.leader_seen(sent, servo_id - 1, raw)
        if seen is not None:
            received, stamp_ns = seen
            read_s = (stamp_ns - wall_ns_minus_mono) * 1e-9
            stages['leader_read'].append(max(0.0, read_s - sent))
            stages['publish'].append(received - max(read_s, sent))
            stages['follower_cycle'].append(on_wire - write_s - received)
            stages['wire'].append(write_s)
        time.sleep(rng.uniform(0.02, 0.06))   # off any phase with the cycles
    wall = time.monotonic() - wall0
    cpu = [cpu_seconds(node.pid) - c for node, c in zip(pair.nodes, cpu0)]
    ms = (lambda values, q: round(1e3 * percentile(values, q), 2) if values else None)
    return {'loop_rate_hz': hz, 'samples': len(latencies), 'missed': missed,
            'p50_ms': ms(latencies, 0.5), 'p99_ms': ms(latencies, 0.99),
            'max_ms': round(1e3 * max(latencies), 2) if latencies else None,
            'stages_p50_ms': {name: ms(values, 0.5) for name, values in stages.items()},
            'console_p50_ms': ms(console, 0.5),
            'cpu_percent': {'leader': round(100.0 * cpu[0] / wall, 1),
                            'follower': round(100.0 * cpu[1] / wall, 1)}}


def teleop_case(workdir: pathlib.Path, attempts: int = 2) -> Dict[str, Any]:
    """Run the case at every loop rate; a pair that never starts following is tried again."""
    for attempt in range(1, attempts + 1):
        try:
            return _teleop_case(workdir)
        except RuntimeError as exc:
            # The nodes' logs are kept where the results go: a start that failed is read there.
            kept = ROOT / 'bench-results'
            kept.mkdir(exist_ok=True)
            for log in workdir.glob('teleop_*.log'):
                shutil.copy(log, kept / f'attempt{attempt}_{log.name}')
            if attempt == attempts:
                raise RuntimeError(f'{exc} (logs in {kept})') from exc
            print(f'bench: teleop attempt {attempt} of {attempts} failed: {exc}',
                  file=sys.stderr, flush=True)
    raise AssertionError('unreachable')


def _teleop_case(workdir: pathlib.Path) -> Dict[str, Any]:
    """Run the case at every loop rate (one pair of buses and nodes for all)."""
    pair = Pair(workdir)
    rng = random.Random(7)
    try:
        # The pair follows before anything is measured: the leader heard here, the follower
        # writing goals (its start-up is not a sample's latency).
        deadline = time.monotonic() + 60.0
        while not (pair.leader_msgs and pair.follower_bus.goals()):
            if time.monotonic() > deadline:
                raise RuntimeError('the pair did not start following within 60 s (see the '
                                   "nodes' logs: teleop_*.log in the work dir)")
            time.sleep(0.1)
        rows = [measure_rate(pair, hz, rng) for hz in RATES_HZ]
    finally:
        pair.close()
    return {'case': f'teleop: leader and follower, {N} servos each at {BAUD} bps', 'n': N,
            'baud': BAUD, 'rates': rows}


def lines(result: Dict[str, Any]) -> List[str]:
    """Return the case as text."""
    out = [result['case'] + ':']
    for row in result['rates']:
        stages = ', '.join(f'{name} {value}' for name, value in row['stages_p50_ms'].items())
        out.append(f'  {row["loop_rate_hz"]:g} Hz: p50 {row["p50_ms"]} ms, p99 {row["p99_ms"]} '
                   f'ms ({row["samples"]} samples, {row["missed"]} missed); stages p50 ms: '
                   f'{stages}; CPU leader {row["cpu_percent"]["leader"]} %, follower '
                   f'{row["cpu_percent"]["follower"]} %')
    return out


if __name__ == '__main__':
    own_dds_domain()
    with tempfile.TemporaryDirectory(prefix='dxl-bench-') as tmp:
        measured = teleop_case(pathlib.Path(tmp))
    print('\n'.join(lines(measured)))
    print(json.dumps(measured))
