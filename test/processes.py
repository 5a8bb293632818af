"""
Test helper: the package's programs as subprocesses, always stopped, reaped and cleaned up.

VirtualBusProcess runs `python -m dxl_servo_driver.sim.virtual_bus` (its device path, its
control lines); NodeProcess runs the installed `node` executable with a params file, an optional
namespace, its own output file and ROS_LOG_DIR. stop_process() is the one way either ends.
Nothing here imports rclpy.
"""

import os
import pathlib
import queue
import random
import re
import signal
import subprocess
import sys
import threading
import time
from typing import (
    Any, Callable, IO, List, Mapping, Optional, Protocol, Sequence, TypeVar, Union)

from ament_index_python.packages import get_package_prefix

ROOT = pathlib.Path(__file__).resolve().parent.parent
# Generous: a Python (+ ROS) process on a busy 2-core machine may start and answer slowly.
# Only failures wait this long.
LINE_TIMEOUT_S = 10.0
START_TIMEOUT_S = 30.0
EXIT_TIMEOUT_S = 10.0
M = TypeVar('M')
M_co = TypeVar('M_co', covariant=True)
PathLike = Union[str, 'os.PathLike[str]']


class Messages(Protocol[M_co]):
    """What NodeProcess.wait_message needs of node_harness.Collector (no rclpy import here)."""

    def wait(self, predicate: Callable[[M_co], bool], timeout_s: float,
             fresh: bool) -> M_co:
        """Return the first message matching predicate; AssertionError after timeout_s."""
        ...


def node_executable() -> str:
    """Return the node's path the way `ros2 run` finds it: <prefix>/lib/<package>/<exe>."""
    path = os.path.join(get_package_prefix('dxl_servo_driver'), 'lib', 'dxl_servo_driver',
                        'node')
    assert os.access(path, os.X_OK), f'{path} is not an executable (colcon build first)'
    return path


def stop_process(proc: 'subprocess.Popen[Any]', sig: int = signal.SIGINT,
                 timeout_s: float = EXIT_TIMEOUT_S) -> int:
    """
    Send sig unless it has exited, wait; SIGKILL if it does not exit in time. Always reaped.

    Return its exit code (-SIGKILL when it had to be killed).
    """
    if proc.poll() is None:
        proc.send_signal(sig)
        try:
            proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return proc.returncode


def _close(stream: Optional[IO[Any]]) -> None:
    if stream is not None:
        try:
            stream.close()
        except OSError:   # unflushed control text to a server that is gone
            pass


class VirtualBusProcess:
    """
    A virtual_bus subprocess: its stdout lines read on a thread, its stderr kept, its device.

    ids, baud_bps and link become --ids, --baud and --link when given (ids may repeat: servos
    sharing an id), unplugged adds --unplugged; extra_args follow as they are (so bad command
    lines can be tried too). With expect_device (the default) the
    constructor waits for the device path virtual_bus prints first, checks it (a /dev path, and
    the link points to it) and keeps it as `device`; if that fails, the process is stopped.
    Pipes: control lines go to stdin; stdout lines are queued, stderr lines kept, each by a
    thread of its own, so neither pipe can fill up and block the server.
    """

    def __init__(self, ids: Sequence[int] = (), baud_bps: Optional[int] = None,
                 link: Optional[PathLike] = None, extra_args: Sequence[str] = (),
                 stdin: Optional[int] = subprocess.PIPE, expect_device: bool = True,
                 start_timeout_s: float = START_TIMEOUT_S, unplugged: bool = False) -> None:
        args: List[str] = []
        if ids:
            args += ['--ids', *[str(i) for i in ids]]
        if unplugged:
            args.append('--unplugged')
        if baud_bps is not None:
            args += ['--baud', str(baud_bps)]
        if link is not None:
            args += ['--link', str(link)]
        self.link = None if link is None else pathlib.Path(link)
        self._device: Optional[str] = None
        self.left_link = False
        self._lines: 'queue.Queue[Optional[str]]' = queue.Queue()
        self._stderr: List[str] = []
        self.proc = subprocess.Popen(
            [sys.executable, '-m', 'dxl_servo_driver.sim.virtual_bus', *args, *extra_args],
            stdin=stdin, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            cwd=str(ROOT))
        self._readers = [threading.Thread(target=self._read_stdout, daemon=True),
                         threading.Thread(target=self._read_stderr, daemon=True)]
        for reader in self._readers:
            reader.start()
        if expect_device:
            try:
                device = self.next_line(start_timeout_s)
                if device is None:
                    self.stop()   # reaped: all of stderr is read
                    raise AssertionError(f'virtual_bus ended:\n{self.stderr_text()}')
                assert device.startswith('/dev/'), f'virtual_bus printed {device!r}, not a device'
                self._device = device
                if self.link is not None:
                    assert os.readlink(self.link) == device
            except BaseException:
                self.stop()
                raise

    @property
    def device(self) -> str:
        """Return the device path it printed (AssertionError if it was not waited for)."""
        assert self._device is not None, 'started with expect_device=False'
        return self._device

    def _read_stdout(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self._lines.put(line.rstrip('\n'))
        self._lines.put(None)

    def _read_stderr(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            self._stderr.append(line.rstrip('\n'))

    def next_line(self, timeout_s: float = LINE_TIMEOUT_S) -> Optional[str]:
        """Return the next stdout line, None once it ended; AssertionError after timeout_s."""
        try:
            return self._lines.get(timeout=timeout_s)
        except queue.Empty:
            raise AssertionError(f'virtual_bus said nothing within {timeout_s} s') from None

    def control(self, line: str, timeout_s: float = LINE_TIMEOUT_S) -> str:
        """Send one control line; return its one-line answer (AssertionError if none)."""
        assert self.proc.stdin is not None, 'virtual_bus was started without a stdin pipe'
        self.proc.stdin.write(line + '\n')
        self.proc.stdin.flush()
        answer = self.next_line(timeout_s)
        assert answer is not None, f'virtual_bus ended:\n{self.stderr_text()}'
        return answer

    def get(self, servo_id: Union[int, str], register: str) -> int:
        """Return one register of a servo (its id, or '#N') through the `get ID NAME` line."""
        answer = self.control(f'get {servo_id} {register}')
        match = re.fullmatch(rf'ok get {servo_id} {register}=(-?\d+)', answer)
        assert match, answer
        return int(match.group(1))

    def wait_get(self, servo_id: Union[int, str], register: str, expected: int,
                 timeout_s: float = LINE_TIMEOUT_S) -> None:
        """
        Wait until a register reads expected; AssertionError with its last value after timeout_s.

        What a node wrote before it answered may still be in the pty's buffer when the console
        is asked (the console has a thread of its own): a register written by another process
        is waited for, not read once.
        """
        deadline = time.monotonic() + timeout_s
        while True:
            value = self.get(servo_id, register)
            if value == expected:
                return
            if time.monotonic() > deadline:
                raise AssertionError(f'{register} of {servo_id} is {value}, not {expected}, '
                                     f'after {timeout_s} s')
            time.sleep(0.01)

    def stderr_lines(self, timeout_s: float = LINE_TIMEOUT_S) -> List[str]:
        """Return what it wrote to stderr, all of it once it has exited (waits for that)."""
        self.proc.wait(timeout_s)
        self._readers[1].join(timeout_s)
        return list(self._stderr)

    def stderr_text(self) -> str:
        """Return what it wrote to stderr so far (for failure messages)."""
        return '\n'.join(self._stderr)

    def stop(self, sig: int = signal.SIGTERM, timeout_s: float = EXIT_TIMEOUT_S) -> int:
        """
        Stop (sig, then SIGKILL), reap, close the pipes, remove its link; return the exit code.

        The link is removed only if it is still a symlink to this process's device, which
        virtual_bus should have done itself on exit: `left_link` says it had not. Idempotent.
        """
        code = stop_process(self.proc, sig, timeout_s)
        _close(self.proc.stdin)
        for reader in self._readers:
            reader.join(timeout=5.0)
        _close(self.proc.stdout)
        _close(self.proc.stderr)
        if (self.link is not None and self._device is not None and os.path.islink(self.link)
                and os.readlink(self.link) == self._device):
            self.left_link = True
            os.unlink(self.link)
        return code


StartVirtualBus = Callable[..., VirtualBusProcess]


def params_yaml(port: str, joints: Mapping[str, Mapping[str, Any]], baud_rate: int = 1000000,
                loop_rate: float = 50.0, **top: Any) -> str:
    """
    Return a node's params file: port, rates, the joints with their keys, then top keys.

    ping_retries is 30 unless given: the simulator and the node share a loaded machine with a
    second test worker, and a configure transaction answered late three times in a row (each
    late reply taken for the next attempt's, the deadline's slack still growing) stopped a
    node at start-up beside two busy loops. Attempts are counted, not timed: 30 at a 1 Mbps
    bus's deadlines outlast a simulator held up for about a third of a second. A test of
    retries gives its own.
    """
    top = {'ping_retries': 30, **top}
    lines = ['/**:', '  ros__parameters:', f'    port: "{port}"', f'    baud_rate: {baud_rate}',
             f'    loop_rate: {loop_rate}', f'    joints: [{", ".join(joints)}]']
    lines += [f'    {key}: {value}' for key, value in top.items()]
    for name, keys in joints.items():
        lines.append(f'    {name}:')
        lines += [f'      {key}: {value}' for key, value in keys.items()]
    return '\n'.join(lines) + '\n'


def fresh_domain_id() -> int:
    """
    Return a DDS domain for one test's node processes and client, away from the session's.

    With localhost-only discovery a participant is announced to a few participant ids only;
    the many in-process nodes of earlier tests can leave the session's domain crowded, and a
    late participant would then never be discovered.
    """
    return worker_domain(102, 200)


def worker_domain(low: int, high: int) -> int:
    """
    Return a random DDS domain in low..high that no other pytest-xdist worker of this run uses.

    make test runs two workers at once: each takes the domains of its own residue (gw0 the
    even ones, gw1 the odd ones), so that two tests running side by side never share one.
    """
    workers = int(os.environ.get('PYTEST_XDIST_WORKER_COUNT', '1') or 1)
    worker = int(os.environ.get('PYTEST_XDIST_WORKER', 'gw0')[2:] or 0)
    return random.SystemRandom().choice(
        [domain for domain in range(low, high + 1) if domain % workers == worker % workers])


class NodeProcess:
    """
    The installed node executable with a params file, in a namespace if one is given.

    Its params file, its output (stdout and stderr) and its ROS_LOG_DIR are in workdir, named
    after the namespace, so two nodes can share one workdir. With ros_args (a documented
    command line's words after `--ros-args`) the node gets those instead of the params file
    and namespace, run from cwd (relative paths in them are the reader's, from the repository).
    """

    def __init__(self, workdir: pathlib.Path, params_yaml: str, namespace: str = '',
                 domain_id: Optional[int] = None, ros_args: Optional[Sequence[str]] = None,
                 cwd: Optional[pathlib.Path] = None) -> None:
        tag = namespace.strip('/').replace('/', '_') or 'node'
        params = workdir / f'{tag}_params.yaml'
        if ros_args is None:
            params.write_text(params_yaml)
        self.output_path = workdir / f'{tag}_output.txt'
        env = dict(os.environ)
        if domain_id is not None:
            env['ROS_DOMAIN_ID'] = str(domain_id)
        env['ROS_LOG_DIR'] = str(workdir / f'{tag}_ros_log')   # its log files stay in workdir
        env['PYTHONUNBUFFERED'] = '1'
        remap = ['-r', f'__ns:={namespace}'] if namespace else []
        args = [*remap, '--params-file', str(params)] if ros_args is None else list(ros_args)
        with open(self.output_path, 'w') as output:
            self.proc = subprocess.Popen(
                [node_executable(), '--ros-args', *args],
                stdin=subprocess.DEVNULL, stdout=output, stderr=subprocess.STDOUT, env=env,
                cwd=str(cwd or workdir))

    def output(self) -> str:
        """Return what the node printed so far."""
        return self.output_path.read_text(errors='replace')

    def alive(self) -> None:
        """AssertionError, with its output, if the node has exited."""
        assert self.proc.poll() is None, (
            f'the node exited with {self.proc.returncode}:\n{self.output()}')

    def wait(self, timeout_s: float = START_TIMEOUT_S) -> int:
        """Wait for the node to exit; return its exit code (AssertionError after timeout_s)."""
        try:
            return self.proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            raise AssertionError(f'the node did not exit within {timeout_s} s:\n'
                                 + self.output()) from None

    def wait_message(self, collector: Messages[M], predicate: Callable[[M], bool],
                     timeout_s: float) -> M:
        """
        Wait for a matching message from collector while the node runs.

        AssertionError, with the node's output, when it exits first or after timeout_s.
        """
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                return collector.wait(predicate, timeout_s=0.25, fresh=False)
            except AssertionError:
                self.alive()
                if time.monotonic() > deadline:
                    raise AssertionError(f'no matching message within {timeout_s} s; node '
                                         f'output:\n{self.output()}') from None

    def stop(self, sig: int = signal.SIGINT, timeout_s: float = EXIT_TIMEOUT_S) -> int:
        """Stop the node (sig, then SIGKILL) and reap it; return its exit code."""
        return stop_process(self.proc, sig, timeout_s)
