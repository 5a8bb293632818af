"""
Test-session set-up shared by every test, and the fixtures the process-level tests share.

DDS is isolated before anything imports rclpy: a random ROS_DOMAIN_ID per test session and
localhost-only discovery, so parallel runs on one machine never see each other's nodes.

Hypothesis runs under the profile HYPOTHESIS_PROFILE names. `ci` (the default, make test):
derandomized, the same examples every run, no example database, so a run on a fresh clone is
the run on every machine. `fuzz` (make fuzz): at random, 20 times the examples, the failures it
finds kept in .hypothesis-fuzz/ and tried first the next time. Tests give their budgets as
multiples of the profile's max_examples and set nothing else.
"""

import os
import pathlib
import tempfile
from typing import Any, Iterator, List, TYPE_CHECKING

from hypothesis import HealthCheck, settings
from hypothesis.database import DirectoryBasedExampleDatabase
from processes import fresh_domain_id, StartVirtualBus, VirtualBusProcess, worker_domain
import pytest

if TYPE_CHECKING:
    from node_harness import Client

if 'DXL_TEST_KEEP_DOMAIN' not in os.environ:
    # Domain ids 1..101 keep the derived UDP ports inside the valid range on every RMW.
    # One worker's domains are none of another's (make test runs two: processes.py).
    os.environ['ROS_DOMAIN_ID'] = str(worker_domain(1, 101))
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ.pop('ROS_LOCALHOST_ONLY', None)

# No deadline and no too_slow health check in either profile: both measure time, and time on a
# loaded two-core machine is not a property of the code.
settings.register_profile(
    'ci', max_examples=100, derandomize=True, database=None, print_blob=True, deadline=None,
    suppress_health_check=[HealthCheck.too_slow])
settings.register_profile(
    'fuzz', max_examples=2000, derandomize=False, print_blob=True, deadline=None,
    database=DirectoryBasedExampleDatabase(
        str(pathlib.Path(__file__).resolve().parent.parent / '.hypothesis-fuzz')),
    suppress_health_check=[HealthCheck.too_slow])
settings.load_profile(os.environ.get('HYPOTHESIS_PROFILE', 'ci'))


# The tiers (markers), from what a test starts: `unit` runs the layers in this process (no ROS
# node, no subprocess: `make test-fast`), `node` starts the driver node in-process, `process`
# starts virtual_bus or node processes on ptys, `lint` runs the linters.
LINT_MODULES = frozenset({'test_flake8', 'test_pep257', 'test_mypy'})
PROCESS_FIXTURES = frozenset({'virtual_bus', 'workdir', 'client', 'domain_id'})
PROCESS_NAMES = frozenset({'VirtualBusProcess', 'NodeProcess', 'subprocess', 'pexpect'})
NODE_NAMES = frozenset({'NodeHarness', 'rclpy', 'faulty_harness', 'startup_failure'})


def tier(item: pytest.Item) -> str:
    """Return the tier of a collected test: lint, process, node or unit."""
    module = getattr(item, 'module', None)
    names = set(vars(module)) if module is not None else set()
    if module is not None and module.__name__ in LINT_MODULES:
        return 'lint'
    if PROCESS_FIXTURES & set(getattr(item, 'fixturenames', ())) or PROCESS_NAMES & names:
        return 'process'
    if NODE_NAMES & names:
        return 'node'
    return 'unit'


def pytest_collection_modifyitems(items: List[pytest.Item]) -> None:
    """Mark each test with its tier; refuse a Hypothesis test that overrides the profile."""
    for item in items:
        item.add_marker(tier(item))
    profile = settings.default
    strays = []
    for item in items:
        own = getattr(getattr(item, 'obj', None), '_hypothesis_internal_use_settings', None)
        if own is not None and (own.derandomize != profile.derandomize
                                or own.database is not profile.database):
            strays.append(item.nodeid)
    if strays:
        raise pytest.UsageError(
            'Hypothesis tests that set derandomize or database themselves (give them budgets '
            'only; test/conftest.py has the profiles): ' + ', '.join(strays))


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


@pytest.fixture
def workdir() -> Iterator[pathlib.Path]:
    """Yield a scratch directory for params files, node output and traces; removed afterwards."""
    with tempfile.TemporaryDirectory(prefix='dxl_test_') as path:
        yield pathlib.Path(path)


@pytest.fixture
def domain_id() -> int:
    """Return a DDS domain of this test's own, for node processes and their client."""
    return fresh_domain_id()


@pytest.fixture
def client(domain_id: int) -> Iterator['Client']:
    """Yield a client node on domain_id (topics and service calls); shut down after."""
    # Imported here: rclpy is loaded only once the DDS environment above is set.
    from node_harness import Client, new_context
    import rclpy
    context = new_context(domain_id)
    try:
        client = Client(context)
    except BaseException:
        rclpy.try_shutdown(context=context)
        raise
    try:
        yield client
    finally:
        client.close()
        rclpy.try_shutdown(context=context)
