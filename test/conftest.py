"""
Test-session set-up shared by every test, and the fixture that starts virtual_bus processes.

DDS is isolated before anything imports rclpy: a random ROS_DOMAIN_ID per test session and
localhost-only discovery, so parallel runs on one machine never see each other's nodes.
"""

import os
import random
from typing import Any, Iterator, List

from processes import StartVirtualBus, VirtualBusProcess
import pytest

if 'DXL_TEST_KEEP_DOMAIN' not in os.environ:
    # Domain ids 1..101 keep the derived UDP ports inside the valid range on every RMW.
    os.environ['ROS_DOMAIN_ID'] = str(random.SystemRandom().randint(1, 101))
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ.pop('ROS_LOCALHOST_ONLY', None)


@pytest.fixture
def virtual_bus() -> Iterator[StartVirtualBus]:
    """Start virtual_bus processes (VirtualBusProcess's arguments); all stopped at the end."""
    started: List[VirtualBusProcess] = []

    def start(*args: Any, **kwargs: Any) -> VirtualBusProcess:
        process = VirtualBusProcess(*args, **kwargs)
        started.append(process)
        return process

    yield start
    for process in started:
        process.stop()
