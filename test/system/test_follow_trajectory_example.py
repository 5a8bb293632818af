"""
examples/follow_trajectory.py, run as a user runs it, against the installed node on the simulator.

The node runs config/arm_sim.yaml (the MoveIt page's arm, `port: sim`) in a namespace; the
example sends a FollowJointTrajectory goal on three of its joints and must print SUCCESSFUL and
exit 0; the joints must then be published at their goals (a joint_states subscriber of the
test's own, not the example's word). A joint the arm has not is named, exit 1, nothing sent.
"""

import os
import pathlib
import re
import subprocess
import sys
from typing import Dict

from node_harness import Client, Collector
from processes import NodeProcess, ROOT, START_TIMEOUT_S
import pytest
from sensor_msgs.msg import JointState

EXAMPLE = ROOT / 'examples' / 'follow_trajectory.py'
NAMESPACE = '/arm'
GOAL = {'shoulder_pan': 0.4, 'elbow': -0.5, 'wrist_roll': 0.8}
# The driver's goal_tolerance (0.05 rad by default), which a successful goal has met.
TOLERANCE = 0.05
RUN_TIMEOUT_S = 90.0


def run_example(domain_id: int, *args: str) -> 'subprocess.CompletedProcess[str]':
    """Run the example to its end on the test's DDS domain."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id), PYTHONUNBUFFERED='1')
    return subprocess.run(
        [sys.executable, str(EXAMPLE), *args, '--timeout', '30', '--ros-args', '-r',
         f'__ns:={NAMESPACE}'], cwd=str(ROOT), env=env, capture_output=True, text=True,
        timeout=RUN_TIMEOUT_S)


@pytest.mark.process
def test_the_example_moves_named_joints_and_prints_success(
        client: Client, domain_id: int, tmp_path: pathlib.Path) -> None:
    names = list(GOAL)
    node = NodeProcess(tmp_path, (ROOT / 'config' / 'arm_sim.yaml').read_text(),
                       namespace=NAMESPACE, domain_id=domain_id)
    # The client's own subscriber of the namespaced joint_states.
    collector: Collector[JointState] = Collector()
    client.node.create_subscription(JointState, f'{NAMESPACE}/joint_states', collector, 50)
    try:
        node.wait_message(collector, lambda m: set(names) <= set(m.name), START_TIMEOUT_S)
        done = run_example(domain_id, *[f'{n}={p}' for n, p in GOAL.items()],
                           '--duration', '1.5')
        told = f'{done.stdout}{done.stderr}\nnode:\n{node.output()}'
        assert done.returncode == 0, told
        assert re.search(r'^result: SUCCESSFUL', done.stdout, re.M), told
        # The joints arrive: published at their goals after the result.
        message = node.wait_message(collector, lambda m: arrived(dict(zip(m.name, m.position))),
                                    START_TIMEOUT_S)
        assert arrived(dict(zip(message.name, message.position))), told

        # A joint the arm has not: said, with the joints it has, and nothing sent.
        done = run_example(domain_id, 'no_such_joint=0.1')
        assert done.returncode == 1, done.stdout + done.stderr
        assert done.stderr.startswith(f'no_such_joint: not among the joints on '
                                      f'{NAMESPACE}/joint_states (shoulder_pan, '), done.stderr
        assert 'follow_joint_trajectory goal' not in node.output().split(
            'trajectory done')[-1], node.output()
        node.alive()
    finally:
        node.stop()


def arrived(positions: Dict[str, float]) -> bool:
    """Return whether every joint of GOAL is published within TOLERANCE of its goal."""
    return all(name in positions and abs(positions[name] - goal) < TOLERANCE
               for name, goal in GOAL.items())
