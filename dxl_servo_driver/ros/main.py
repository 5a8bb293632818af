"""
`ros2 run dxl_servo_driver node`: start the node, spin it, stop it safely on a signal.

Signals only set a flag: the shutdown (cycle stopped, torque off, port closed) runs in order
while ROS is still up, and later signals never cut it short.
"""

import signal
import sys
import threading
from typing import Any, List, Optional

from dxl_servo_driver import config as cfg
from dxl_servo_driver.driver.manager import open_transport, PortFactory
from dxl_servo_driver.errors import Interrupted
from dxl_servo_driver.ros.node import DriverNode, NODE_NAME, StartupFailure
import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.signals import SignalHandlerOptions


class _Signals:
    """
    SIGINT/SIGTERM as a request, never as an exception in the middle of a transaction.

    The first signal asks the node to stop; the main loop then shuts it down in order (cycle
    stopped, torque off, port closed). Later signals are counted and change nothing: the
    torque-off is never cut short.
    """

    def __init__(self) -> None:
        self.received = 0
        self.stop = threading.Event()
        self._node_stop: Optional[threading.Event] = None

    def attach(self, node_stop: threading.Event) -> None:
        """Pass a stop request on to the node's long activities too."""
        self._node_stop = node_stop
        if self.stop.is_set():
            node_stop.set()

    def __call__(self, signum: int, frame: Any) -> None:
        self.received += 1
        self.stop.set()
        if self._node_stop is not None:
            self._node_stop.set()


def _params_files(argv: List[str]) -> List[str]:
    """Return the --params-file arguments of a ROS command line."""
    files = []
    in_ros_args = False
    for index, arg in enumerate(argv):
        if arg == '--ros-args':
            in_ros_args = True
        elif arg == '--':
            in_ros_args = False
        elif in_ros_args and arg == '--params-file' and index + 1 < len(argv):
            files.append(argv[index + 1])
    return files


def main(args: Optional[List[str]] = None, port_factory: PortFactory = open_transport) -> int:
    """
    Run the driver node until Ctrl-C or SIGTERM; non-zero exit when it cannot start.

    port_factory: what opens the port (the benchmark's recorded-reply port; default by `port`).
    """
    logger = rclpy.logging.get_logger(NODE_NAME)
    argv = list(sys.argv if args is None else args)
    signals = _Signals()
    # Our own signal handling: the context stays valid until the servos are safe, so the
    # shutdown (torque off, port closed) is done and logged while ROS is still up. Set
    # explicitly: a process started in the background inherits SIGINT ignored.
    signal.signal(signal.SIGINT, signals)
    signal.signal(signal.SIGTERM, signals)
    # ROS reads parameter files in C and answers a bad one with a traceback: check them first.
    for path in _params_files(argv):
        try:
            cfg.check_parameter_file(path)
        except cfg.ParameterFileError as exc:
            logger.fatal(str(exc))
            return 1
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except (_rclpy.RCLError, RuntimeError, ValueError) as exc:
        logger.fatal(f'cannot start ROS: {str(exc).splitlines()[0]}')
        return 1
    node: Optional[DriverNode] = None
    code = 0
    try:
        try:
            node = DriverNode(port_factory)
        except (ValueError, TypeError, _rclpy.RCLError) as exc:
            # A parameter ROS itself refuses (an empty list on the command line, ...).
            raise StartupFailure(f'invalid configuration: {exc}') from None
        signals.attach(node.stop_requested)
        node.start()
        if node.config.executor == 'events':
            from rclpy.experimental import EventsExecutor
            executor: Any = EventsExecutor()
        else:
            executor = SingleThreadedExecutor()
        executor.add_node(node)
        while rclpy.ok() and not signals.stop.is_set():
            executor.spin_once(timeout_sec=0.2)
    except StartupFailure as exc:
        if not exc.logged:
            (node.get_logger() if node else logger).fatal(str(exc))
        code = 1
    except Interrupted:
        (node.get_logger() if node else logger).info('stop requested during start-up')
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.shutdown()
            if signals.received > 1:
                node.get_logger().info(f'{signals.received - 1} more stop signal(s) received '
                                       'while stopping: the shutdown was completed anyway')
            node.destroy_node()
        rclpy.try_shutdown()
        # The servos are safe now. Python puts the default action back on SIGINT and SIGTERM
        # when it finalizes, so a late signal would kill the exit (code -2, seen under load);
        # an ignored signal is left ignored.
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
    return code


if __name__ == '__main__':
    sys.exit(main())
