"""
A node whose adapter is lost keeps its descriptors: reconnect attempts leak nothing.

The node opens its port through a symlink (as /dev/ttyDXL); virtual_bus behind it is stopped
(the adapter unplugged), and then, while the node retries its port every second: the link
points nowhere (every open fails), the adapter comes back at a baud the servos do not use (the
port opens, nothing answers, the servos are probed every second), and ptys come and go under
the link. The node's open descriptors are counted all along: each phase must stay flat (+-2),
and with the port open or closed the count is what it was the first time.

The default run spends a few seconds per phase (DXL_FD_SECONDS, 15 in all); the soak run
(`pytest -m soak test/system/test_port_loss.py`) a minute of each.
"""

import os
import pathlib
import time
from typing import Dict, List

from processes import NodeProcess, params_yaml, StartVirtualBus, VirtualBusProcess
import pytest

BAUD = 1_000_000
OTHER_BAUD = 57_600
IDS = [1, 2, 3]
JOINTS = {f'j{i}': {'id': i, 'operating_mode': 'position'} for i in IDS}
SAMPLE_S = 0.25
FLAT = 2   # descriptors a phase may vary by (a DDS socket opened late, a log file rotated)


def descriptors(pid: int) -> int:
    return len(os.listdir(f'/proc/{pid}/fd'))


def wait_for(node: NodeProcess, text: str, timeout_s: float = 30.0) -> None:
    deadline = time.monotonic() + timeout_s
    while text not in node.output():
        node.alive()
        assert time.monotonic() < deadline, f'no {text!r}:\n{node.output()}'
        time.sleep(0.05)


def sample(node: NodeProcess, seconds: float) -> List[int]:
    counts = []
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        node.alive()
        counts.append(descriptors(node.proc.pid))
        time.sleep(SAMPLE_S)
    return counts


def run_phases(virtual_bus: StartVirtualBus, workdir: pathlib.Path, domain_id: int,
               phase_s: float) -> Dict[str, List[int]]:
    link = workdir / 'ttyDXL'
    first = virtual_bus(IDS, BAUD, link=link)
    node = NodeProcess(workdir, params_yaml(str(link), JOINTS), domain_id=domain_id)
    counts: Dict[str, List[int]] = {}
    try:
        wait_for(node, 'active:')
        counts['running'] = sample(node, 1.0)
        first.stop()   # unplugged: the pty and the link are gone
        wait_for(node, 'reconnects when the device returns')
        counts['no device'] = sample(node, phase_s)
        other = virtual_bus(IDS, OTHER_BAUD, link=link)
        wait_for(node, 'port back')
        counts['nobody answers'] = sample(node, phase_s)
        other.stop()
        deadline = time.monotonic() + phase_s
        coming_and_going: List[int] = []
        while time.monotonic() < deadline:
            short: VirtualBusProcess = virtual_bus(IDS, OTHER_BAUD, link=link)
            coming_and_going += sample(node, 1.2)   # the node retries once a second
            short.stop()
            coming_and_going += sample(node, 0.6)
        counts['ptys come and go'] = coming_and_going
        counts['no device again'] = sample(node, 2.5)
    finally:
        node.stop()
    return counts


def check_flat(counts: Dict[str, List[int]]) -> None:
    for phase in ('no device', 'nobody answers', 'no device again'):
        values = counts[phase]
        assert max(values) - min(values) <= FLAT, f'{phase}: {values}\n{counts}'
    closed = counts['no device']
    # Closed again after everything: as many as the first time it was closed.
    assert abs(min(counts['no device again']) - min(closed)) <= FLAT, counts
    # Open again (at a baud nobody answers): no more than while it ran.
    assert max(counts['nobody answers']) <= max(counts['running']) + FLAT, counts
    # Ptys coming and going: never beyond one open port's worth.
    assert max(counts['ptys come and go']) <= max(counts['running']) + FLAT, counts


def test_failed_reconnects_leak_no_descriptor(virtual_bus: StartVirtualBus,
                                              workdir: pathlib.Path, domain_id: int) -> None:
    seconds = float(os.environ.get('DXL_FD_SECONDS', '15'))
    check_flat(run_phases(virtual_bus, workdir, domain_id, seconds / 3))


@pytest.mark.soak
def test_a_minute_of_failed_reconnects_leaks_no_descriptor(
        virtual_bus: StartVirtualBus, workdir: pathlib.Path, domain_id: int) -> None:
    check_flat(run_phases(virtual_bus, workdir, domain_id, 60.0))
