"""
Test helper: the driver node on the in-process simulated bus, with a client node beside it.

NodeHarness owns a private rclpy Context, a DriverNode on `port: sim` started with the given
parameters, and a Client (a client node with command publishers, service clients and collectors
on the driver's topics) whose executor spins both in a background thread. close() stops and
destroys all of it and shuts the context down; it is idempotent, and the constructor cleans up
after itself when the node cannot start. Client alone drives a driver in another process.
"""

import itertools
import threading
import time
from typing import (
    Any, Callable, Dict, Generic, List, Mapping, Optional, Sequence, Tuple, TypeVar)

from diagnostic_msgs.msg import DiagnosticArray
from dxl_servo_driver.driver.transports import open_transport, PortFactory, SimTransport, Transport
from dxl_servo_driver.models import modes
from dxl_servo_driver.ros.node import DriverNode, NODE_NAME, StartupFailure
from dxl_servo_driver.sim.fault_engine import Faults
from dxl_servo_driver.sim.faulty_port import FaultyPort
from dxl_servo_driver.sim.port import SimPortHandler
from dxl_servo_driver_msgs.msg import JointCommand, ServoStateArray
from dxl_servo_driver_msgs.srv import (
    ReadRegister, Reboot, SetGoals, SetOperatingMode, SetTorque, WriteRegister)
from lifecycle_msgs.srv import ChangeState, GetState
from rcl_interfaces.msg import SetParametersResult
from rcl_interfaces.srv import SetParameters
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState

M = TypeVar('M')
SERVICE_TIMEOUT_S = 10.0    # generous deadlines: a busy 2-core machine may be slow
DISCOVERY_TIMEOUT_S = 10.0
COMMAND_KINDS = modes.COMMAND_KINDS
SERVICE_TYPES: Dict[str, Any] = {
    'set_position': SetGoals, 'set_velocity': SetGoals, 'set_current': SetGoals,
    'set_pwm': SetGoals, 'set_operating_mode': SetOperatingMode, 'set_torque': SetTorque,
    'reboot': Reboot, 'read_register': ReadRegister, 'write_register': WriteRegister,
    'set_parameters': SetParameters,   # what `ros2 param set` calls
    'get_state': GetState, 'change_state': ChangeState,   # what `ros2 lifecycle` calls
}
_COUNTER = itertools.count()


def sim_params(joints: Mapping[str, Mapping[str, Any]], **top: Any) -> Dict[str, Any]:
    """
    Return the flat parameter dictionary of a `port: sim` node.

    joints maps a joint name to its keys (`id`, `operating_mode`, `registers`: {name: raw}, ...);
    top-level parameters (loop_rate, command_timeout, ...) override the defaults given here.
    """
    flat: Dict[str, Any] = {
        'port': 'sim', 'baud_rate': 1000000, 'loop_rate': 100.0, 'latency_timer': 1.0,
        'joints': list(joints),
    }
    for name, keys in joints.items():
        for key, value in keys.items():
            if key == 'registers':
                for register, raw in value.items():
                    flat[f'{name}.registers.{register}'] = raw
            else:
                flat[f'{name}.{key}'] = value
    flat.update(top)
    return flat


def overrides(params: Mapping[str, Any]) -> List[Parameter]:
    """Return parameter overrides for a node (types inferred from the Python values)."""
    return [Parameter(name, value=value) for name, value in params.items()]


class Collector(Generic[M]):
    """Every message of one subscription, with a wait for one that matches a predicate."""

    def __init__(self, keep: int = 2000) -> None:
        self._cond = threading.Condition()
        self._messages: List[M] = []
        self._received = 0
        self._keep = keep

    def __call__(self, msg: M) -> None:
        """Store a message (the subscription callback)."""
        with self._cond:
            self._messages.append(msg)
            self._received += 1
            if len(self._messages) > self._keep:
                del self._messages[:len(self._messages) - self._keep]
            self._cond.notify_all()

    @property
    def received(self) -> int:
        """Return how many messages arrived so far."""
        with self._cond:
            return self._received

    def latest(self) -> Optional[M]:
        """Return the latest message, or None."""
        with self._cond:
            return self._messages[-1] if self._messages else None

    def wait(self, predicate: Callable[[M], bool] = lambda msg: True,
             timeout_s: float = 10.0, fresh: bool = True) -> M:
        """
        Return the first message matching predicate; AssertionError after timeout_s.

        With fresh (the default), only messages that arrive after this call count, so nothing
        published before the test's action can satisfy it.
        """
        deadline = time.monotonic() + timeout_s
        with self._cond:
            next_index = self._received if fresh else self._received - len(self._messages)
            last: Optional[M] = None
            while True:
                base = self._received - len(self._messages)   # global index of _messages[0]
                for index in range(max(next_index, base), self._received):
                    last = self._messages[index - base]
                    if predicate(last):
                        return last
                next_index = self._received
                remaining = deadline - time.monotonic()
                if remaining <= 0.0:
                    raise AssertionError(
                        f'no matching message within {timeout_s} s; last seen: {last!r}')
                self._cond.wait(remaining)


def new_context(domain_id: Optional[int] = None) -> Context:
    """
    Return an initialised private rclpy Context (in its own DDS domain when given).

    External-library logging (the log files under ~/.ros/log) is off: tests leave no files.
    """
    context = Context()
    rclpy.init(context=context, args=['--ros-args', '--disable-external-lib-logs'],
               domain_id=domain_id)
    return context


class Client:
    """
    A client node of the driver: collectors on its topics, command publishers, service clients.

    It spins, with any extra nodes given, in one executor on a background thread. The driver
    node is addressed by its default name in the given namespace ('' = the root), in-process
    or in another process.
    """

    def __init__(self, context: Context, extra_nodes: Sequence[Node] = (),
                 namespace: str = '') -> None:
        self.context = context
        self.node = rclpy.create_node(f'dxl_test_client_{next(_COUNTER)}', context=context)
        prefix = f'{namespace}/{NODE_NAME}'
        self.joint_states: Collector[JointState] = Collector()
        self.servo_states: Collector[ServoStateArray] = Collector()
        self.diagnostics: Collector[DiagnosticArray] = Collector()
        node = self.node
        node.create_subscription(JointState, f'{namespace}/joint_states', self.joint_states, 50)
        node.create_subscription(ServoStateArray, f'{prefix}/servo_states', self.servo_states,
                                 50)
        node.create_subscription(DiagnosticArray, '/diagnostics', self.diagnostics, 50)
        self.publishers = {kind: node.create_publisher(JointCommand, f'{prefix}/commands/{kind}',
                                                       10)
                           for kind in COMMAND_KINDS}
        self.clients = {name: node.create_client(kind, f'{prefix}/{name}')
                        for name, kind in SERVICE_TYPES.items()}
        self.executor = SingleThreadedExecutor(context=context)
        for extra in extra_nodes:
            self.executor.add_node(extra)
        self.executor.add_node(node)
        self._thread = threading.Thread(target=self._spin, name='client_spin', daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        try:
            self.executor.spin()
        except Exception:  # noqa: B902 - shutdown races end the spin; nothing to report
            pass

    def publish(self, kind: str, names: Sequence[str], values: Sequence[float],
                timeout_s: float = DISCOVERY_TIMEOUT_S) -> None:
        """Publish a JointCommand on ~/commands/<kind> once the driver subscribes to it."""
        publisher = self.publishers[kind]
        deadline = time.monotonic() + timeout_s
        while publisher.get_subscription_count() < 1:
            if time.monotonic() > deadline:
                raise AssertionError(f'the driver does not subscribe to commands/{kind}')
            time.sleep(0.01)
        msg = JointCommand()
        msg.name = list(names)
        msg.value = [float(v) for v in values]
        publisher.publish(msg)

    def call(self, service: str, timeout_s: float = SERVICE_TIMEOUT_S, **fields: Any) -> Any:
        """Call the driver's ~/<service> with the given request fields; return the response."""
        client = self.clients[service]
        if not client.wait_for_service(timeout_sec=DISCOVERY_TIMEOUT_S):
            raise AssertionError(f'service {service} is not available')
        request = SERVICE_TYPES[service].Request()
        for key, value in fields.items():
            setattr(request, key, value)
        done = threading.Event()
        future = client.call_async(request)
        future.add_done_callback(lambda _: done.set())
        if not done.wait(timeout_s):
            client.remove_pending_request(future)
            raise AssertionError(f'service {service} did not answer within {timeout_s} s')
        return future.result()

    def set_parameter(self, name: str, value: Any) -> SetParametersResult:
        """Set one parameter of the driver through its set_parameters service."""
        response = self.call('set_parameters',
                             parameters=[Parameter(name, value=value).to_parameter_msg()])
        assert len(response.results) == 1
        return response.results[0]

    def close(self) -> None:
        """Stop the executor and destroy the client node (the context stays up)."""
        self.executor.shutdown(timeout_sec=5.0)
        self._thread.join(timeout=5.0)
        self.node.destroy_node()


class NodeHarness:
    """
    The driver node on `port: sim` and a Client, in one private context.

    The node runs in a namespace of its own (more buses = more nodes, in namespaces), so its
    topics and services cannot mix with those of another test's node. /diagnostics is absolute:
    only one harness should run at a time. The node's port comes from port_factory (default:
    what `port: sim` opens); the simulated servos of the last configure are `sim`.
    """

    def __init__(self, params: Mapping[str, Any], start: bool = True,
                 port_factory: PortFactory = open_transport) -> None:
        self.namespace = f'/dxl_test_{next(_COUNTER)}'
        self.context = new_context()
        self.node: Optional[DriverNode] = None
        self.client: Optional[Client] = None
        self._closed = False
        self._simulator: Any = None

        def factory(config: Any) -> Transport:
            transport = port_factory(config)
            assert isinstance(transport, SimTransport), 'the harness drives simulated servos'
            self._simulator = transport.simulator
            return transport
        try:
            self.node = DriverNode(port_factory=factory, context=self.context,
                                   namespace=self.namespace,
                                   parameter_overrides=overrides(params))
            if start:
                self.node.start()
            self.client = Client(self.context, [self.node], self.namespace)
        except BaseException:
            self.close()
            raise
        self.joint_states = self.client.joint_states
        self.servo_states = self.client.servo_states
        self.diagnostics = self.client.diagnostics
        self.publish = self.client.publish
        self.call = self.client.call
        self.set_parameter = self.client.set_parameter

    @property
    def sim(self) -> Any:
        """Return the SimBus behind `port: sim`."""
        assert self.node is not None
        return self._simulator

    def reg(self, servo_id: int, name: str) -> int:
        """Return one register of a simulated servo, as the simulator holds it now."""
        return int(self.sim.read_register(servo_id, name))

    def wait_reg(self, servo_id: int, name: str, predicate: Callable[[int], bool],
                 timeout_s: float = 10.0) -> int:
        """Poll a simulated register until predicate(value); AssertionError after timeout_s."""
        deadline = time.monotonic() + timeout_s
        while True:
            value = self.reg(servo_id, name)
            if predicate(value):
                return value
            if time.monotonic() > deadline:
                raise AssertionError(f'id {servo_id} {name} = {value} after {timeout_s} s')
            time.sleep(0.01)

    def close(self) -> None:
        """Stop the node (torque_off_on_shutdown applies), destroy everything, end the context."""
        if self._closed:
            return
        self._closed = True
        if self.client is not None:
            self.client.close()
        if self.node is not None:
            self.node.shutdown()
            self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

    def __enter__(self) -> 'NodeHarness':
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def startup_failure(params: Mapping[str, Any]) -> StartupFailure:
    """
    Construct and start a node that must fail; return its StartupFailure.

    AssertionError if it started. Everything it created is destroyed.
    """
    context = new_context()
    node: Optional[DriverNode] = None
    try:
        try:
            node = DriverNode(context=context, parameter_overrides=overrides(params))
            node.start()
        except StartupFailure as exc:
            return exc
        raise AssertionError('the node started with an invalid configuration')
    finally:
        if node is not None:
            node.shutdown()
            node.destroy_node()
        rclpy.try_shutdown(context=context)


def faulty_harness(params: Mapping[str, Any], faults: Faults, seed: int = 1,
                   prepare: Optional[Callable[[Any], None]] = None,
                   wrap: Optional[Callable[[Any], Any]] = None,
                   protocol: int = 2) -> NodeHarness:
    """
    Start a `port: sim` node whose port goes through a FaultyPort (or wrap(port)).

    The simulated servos are made once (prepare(sim) may change them first); every configure
    opens a new port on them (after a cleanup closed the last one), as a node reopens its
    device. protocol: the framing the faults cut replies by (1 for a Protocol 1.0 bus).
    """
    made: Dict[str, Any] = {}

    def factory(config: Any) -> Transport:
        if 'sim' not in made:
            made['sim'] = open_transport(config).simulator   # type: ignore[attr-defined]
            if prepare is not None:
                prepare(made['sim'])
        sim = made['sim']

        def open_port() -> Any:
            port = FaultyPort(SimPortHandler(sim, 'sim', config.baud_rate), faults, seed,
                              protocol=protocol)
            return wrap(port) if wrap is not None else port
        return SimTransport(sim, open_port)
    return NodeHarness(params, port_factory=factory)


def at_once(h: NodeHarness, ids: Sequence[int],
            register: str = 'present_position') -> Tuple[float, List[int]]:
    """
    Return one register of several simulated servos at one moment, and that moment.

    Read one after the other, moving servos are read at different moments: a thread descheduled
    between two reads would see them apart by what they moved meanwhile.
    """
    sim = h.sim
    with sim.lock:   # no packet moves a servo meanwhile
        now_s = time.monotonic()   # the simulator's clock
        values = []
        for servo_id in ids:
            servo = sim.servo(servo_id)
            servo.advance(now_s)
            values.append(servo.memory.get(register))
    return now_s, values
