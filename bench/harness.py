"""
What the benchmark's cases share: where things are, the simulated bus, the node under test.

- ROOT, and own_dds_domain(): a DDS domain of the benchmark's own (each entry point calls it
  before anything loads rclpy);
- VirtualBus: a `virtual_bus --timing wire` process, its console and its goal trace;
- NodeUnderTest: the installed node, driven through its lifecycle, its joint_states counted,
  commands published to it, its CPU from /proc;
- the figures every case takes: percentile, cpu_seconds, node_rate, usual_bus_s, machine.

Import it after the source tree is on sys.path (the bench scripts put it first): the benchmark
measures this tree's package, not an installed one.
"""

import os
import pathlib
import platform
import random
import signal
import subprocess
import sys
import threading
import time
from typing import Any, Dict, List, Optional, Tuple

from dxl_servo_driver.driver import state_block
from dxl_servo_driver.models import model_for
from dxl_servo_driver.models.units import units_for
from dxl_servo_driver.protocol import BITS_PER_BYTE

__all__ = ['CLOCK_TICK_S', 'COMMAND_RATE_HZ', 'cpu_seconds', 'HEALTH_RATE_HZ', 'machine',
           'MANUAL_UNITS', 'NAMESPACE', 'node_rate', 'NODE_NAME', 'NodeUnderTest',
           'own_dds_domain', 'percentile', 'ROOT', 'ROUNDS', 'SECONDS', 'usual_bus_s',
           'VirtualBus', 'WRITE_BYTES']

ROOT = pathlib.Path(__file__).resolve().parent.parent
ROUNDS = int(os.environ.get('BENCH_ROUNDS', '2'))
SECONDS = float(os.environ.get('BENCH_SECONDS', '1.5'))
NAMESPACE = '/bench'
NODE_NAME = 'dxl_servo_driver'
COMMAND_RATE_HZ = 50.0
CLOCK_TICK_S = 1.0 / os.sysconf('SC_CLK_TCK')
WRITE_BYTES = 4         # goal_position
HEALTH_RATE_HZ = 10.0   # the node reads its whole state block at state_rate (default 10 Hz)
MANUAL_UNITS = units_for(model_for(1030))   # the simulated servos are the XM430 manual's


def own_dds_domain() -> None:
    """
    Give the benchmark's ROS processes a DDS domain of their own, discovered on localhost only.

    Called once by each entry point, before anything loads rclpy or starts a node: another ROS
    process on the machine (a test run, a robot) must neither see the benchmark's traffic nor
    add to it. BENCH_DOMAIN_ID keeps one.
    """
    os.environ['ROS_DOMAIN_ID'] = os.environ.get(
        'BENCH_DOMAIN_ID', str(random.SystemRandom().randint(102, 232)))
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ.pop('ROS_LOCALHOST_ONLY', None)


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


def node_rate(run: Dict[str, Any]) -> float:
    """Return a node run's joint_states rate."""
    return run['cycles'] / run['wall_s'] if run['wall_s'] else 0.0


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
