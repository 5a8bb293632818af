"""
Soak: the node on `port: sim` at its default rate for DXL_SOAK_SECONDS (default 600).

Not in the default run (marker `soak`; select with `pytest -m soak test/system/test_soak.py -s`).
Every servo loses 1 % of its replies; commands stream at 50 Hz on three topics; the process's
resident memory is sampled every 10 s. At the end one summary line is printed (duration, cycles,
measured rate, comm errors, retries, restarts, RSS) and the test asserts the node is alive and
still obeys, logged no unexpected error, never restarted a servo, and did not grow its memory
beyond a bound.
"""

import math
import os
import re
import threading
import time
from typing import Any, Dict, Iterator, List

from dxl_servo_driver.models import model_for, xm430
from dxl_servo_driver.models.units import units_for
from node_harness import NodeHarness, sim_params
import pytest
from rcl_interfaces.msg import Log

SOAK_S = float(os.environ.get('DXL_SOAK_SECONDS', '600'))
COMMAND_HZ = 50.0
RSS_SAMPLE_S = 10.0
RSS_GROWTH_BOUND_KB = 20 * 1024
DROP = 0.01
# ERROR lines a lossy bus may cause; anything else at ERROR or FATAL is a failure.
EXPECTED_ERRORS = re.compile(r'read failed|no status packet|did not answer')
# The units of the XM430 manual's model, every joint's here (models/units.py).
UNITS = units_for(model_for(xm430.MODEL_NUMBER))
RAD_PER_PULSE = UNITS.rad_per_pulse

# Like config/sim.yaml: one joint per command family, default loop_rate (100 Hz).
JOINTS: Dict[str, Dict[str, Any]] = {
    'shoulder': {'id': 1, 'operating_mode': 'position',
                 'registers': {'profile_velocity': 60, 'profile_acceleration': 20,
                               'return_delay_time': 0}},
    'wheel': {'id': 2, 'operating_mode': 'velocity',
              'registers': {'profile_acceleration': 50, 'return_delay_time': 0}},
    'gripper': {'id': 3, 'operating_mode': 'current_based_position',
                'registers': {'current_limit': 400, 'return_delay_time': 0}},
}


def rss_kb() -> int:
    """Return this process's resident set size (the node, its client and the simulator)."""
    with open('/proc/self/status') as status:
        for line in status:
            if line.startswith('VmRSS:'):
                return int(line.split()[1])
    raise AssertionError('no VmRSS in /proc/self/status')


class LogWatch:
    """The node's /rosout messages at ERROR and above."""

    def __init__(self, h: NodeHarness) -> None:
        self._lock = threading.Lock()
        self.errors: List[str] = []
        self.count = 0
        assert h.client is not None
        self._sub = h.client.node.create_subscription(Log, '/rosout', self._on_log, 100)
        self._namespace = h.namespace.strip('/')

    def _on_log(self, msg: Log) -> None:
        if self._namespace not in msg.name or msg.level < Log.ERROR:
            return
        with self._lock:
            self.count += 1
            if not EXPECTED_ERRORS.search(msg.msg):
                self.errors.append(f'[{msg.level}] {msg.msg}')


@pytest.fixture
def h() -> Iterator[NodeHarness]:
    params = sim_params(JOINTS)
    params.pop('loop_rate')   # the node's default rate
    with NodeHarness(params) as harness:
        yield harness


@pytest.mark.soak
def test_soak(h: NodeHarness, capsys: pytest.CaptureFixture[str]) -> None:
    assert h.node is not None
    manager = h.node.manager
    logs = LogWatch(h)
    # The harness's collectors keep 2000 messages each: at 100 + 10 + 1 Hz that is growth for
    # the first half hour which is the test's, not the node's. Keep few.
    for collector in (h.joint_states, h.servo_states, h.diagnostics):
        collector._keep = 20
    h.joint_states.wait(lambda m: len(m.name) == len(JOINTS))
    for sid in (1, 2, 3):
        h.sim.set_drop(sid, DROP)
    rss_samples = [rss_kb()]
    cycles_start = manager.stats.cycles
    received_start = h.joint_states.received
    start = time.monotonic()
    next_command = start
    next_sample = start + RSS_SAMPLE_S
    sent = 0
    while True:
        now = time.monotonic()
        if now - start >= SOAK_S:
            break
        t = now - start
        h.publish('position', ['shoulder', 'gripper'],
                  [0.8 * math.sin(0.5 * t), 0.3 + 0.2 * math.sin(0.3 * t)])
        h.publish('velocity', ['wheel'], [2.0 * math.sin(0.2 * t)])
        h.publish('current', ['gripper'], [0.5 + 0.3 * math.sin(0.7 * t)])
        sent += 1
        if now >= next_sample:
            rss_samples.append(rss_kb())
            next_sample += RSS_SAMPLE_S
        next_command += 1.0 / COMMAND_HZ
        time.sleep(max(0.0, next_command - time.monotonic()))
    duration_s = time.monotonic() - start
    rss_samples.append(rss_kb())
    cycles = manager.stats.cycles - cycles_start
    published = h.joint_states.received - received_start
    servos = manager.order
    comm_errors = sum(servo.comm_errors for servo in servos)
    restarts = sum(servo.restarts for servo in servos)
    bus = manager.bus
    # Growth after the first sample: the first seconds include one-time allocations.
    baseline_kb = rss_samples[1] if len(rss_samples) > 2 else rss_samples[0]
    growth_kb = rss_samples[-1] - baseline_kb
    summary = (
        f'soak: {duration_s:.0f} s, {cycles} cycles, {cycles / duration_s:.1f} Hz measured '
        f'(requested {1.0 / h.node._loop_period_s:g} Hz), {published} joint_states, '
        f'{sent} command rounds, comm errors {comm_errors} (read failures '
        f'{manager.stats.read_failures}, timeouts {bus.timeouts if bus else 0}, corrupt '
        f'{bus.corrupt if bus else 0}), retries {manager.stats.retries} '
        f'({manager.stats.retry_successes} '
        f'succeeded), restarts {restarts}, errors logged {logs.count}, RSS '
        f'{rss_samples[0] / 1024:.1f} MB start, {baseline_kb / 1024:.1f} MB after '
        f'{RSS_SAMPLE_S:g} s, {rss_samples[-1] / 1024:.1f} MB end, growth '
        f'{growth_kb / 1024:+.1f} MB (samples MB: '
        f'{", ".join(f"{kb / 1024:.1f}" for kb in rss_samples)})')
    with capsys.disabled():
        print('\n' + summary)

    assert h.node._thread is not None and h.node._thread.is_alive(), summary
    assert not logs.errors, '\n'.join(logs.errors[:20])
    assert restarts == 0, summary   # lost replies are not restarts
    assert cycles > 0 and published > 0, summary
    assert manager.stats.retries > 0, summary   # 1 % drops over the run: the retry path ran
    assert growth_kb < RSS_GROWTH_BOUND_KB, summary
    # Still obeying at the end.
    response = h.call('set_position', name=['shoulder'], value=[0.5])
    assert response.success, response.message
    assert h.reg(1, 'goal_position') == UNITS.zero_raw + round(0.5 / RAD_PER_PULSE)
    h.joint_states.wait(lambda m: len(m.name) == len(JOINTS), timeout_s=5.0)
