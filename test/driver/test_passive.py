"""
Passive joints (`<joint>.torque: false`): read and published, never torqued, never commanded.

A leader arm is a file of passive joints. Its servos are set up (mode, EEPROM) like any, but no
Torque Enable = 1 ever reaches them: not at activate, not after a brown-out, a reboot, a
hardware-error recovery or a reconnection. Every command path naming one is refused by name.

What the servos are sent is read off the wire: every instruction packet the node writes goes
through a recording port before the simulated servos take it, and any write that would set a
passive servo's Torque Enable is kept. The in-process simulator (`port: sim`) answers.
"""

import math
import threading
import time
from typing import Any, Callable, Dict, Iterator, List, Tuple

from action_client import Client, result_of, send_goal
from action_msgs.msg import GoalStatus
from builtin_interfaces.msg import Duration
from conditions import wait_until
from control_msgs.action import FollowJointTrajectory, GripperCommand as GripperAction
from dxl_servo_driver import config as cfg
from dxl_servo_driver.driver.transports import open_transport, SimTransport, Transport
from dxl_servo_driver.models import model_for, xm430
from dxl_servo_driver.protocol import Instruction, StreamParser
from dxl_servo_driver.sim.port import SimPortHandler
from dxl_servo_driver_msgs.msg import GripperCommand
from node_harness import NodeHarness, sim_params
import pytest
from rcl_interfaces.msg import Log
from sensor_msgs.msg import JointState
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

TORQUE_ENABLE = model_for(xm430.MODEL_NUMBER).item('torque_enable').address
DRIVEN, LEAD, GRIP = 1, 2, 3
JOINTS: Dict[str, Dict[str, Any]] = {
    'drive': {'id': DRIVEN, 'operating_mode': 'position'},
    # Passive in a multi-turn mode: its mode is still set up (the servo must read right).
    'lead': {'id': LEAD, 'operating_mode': 'extended_position', 'torque': False},
    'grip': {'id': GRIP, 'operating_mode': 'current_based_position', 'torque': False,
             'gripper': True, 'gripper_open': 0.0, 'gripper_closed': 1.0},
}
PASSIVE = {'lead': LEAD, 'grip': GRIP}
REFUSED = 'is passive (torque: false)'


class Recorder:
    """A port that keeps every write of Torque Enable = 1 it carries, per servo id."""

    def __init__(self, inner: SimPortHandler) -> None:
        self.inner = inner
        self._parser = StreamParser()
        self._lock = threading.Lock()
        self.torque_on: List[int] = []      # ids sent Torque Enable != 0, in order
        self.packets = 0

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    @property
    def baudrate(self) -> int:
        return self.inner.baudrate

    @baudrate.setter
    def baudrate(self, baud_bps: int) -> None:
        self.inner.baudrate = baud_bps

    def write(self, data: bytes) -> int:
        with self._lock:
            for event in self._parser.feed(bytes(data), time.monotonic()):
                if event.crc_ok:
                    self.packets += 1
                    self.torque_on.extend(_torque_on_ids(event.packet.servo_id,
                                                         event.packet.instruction,
                                                         event.packet.params))
        return self.inner.write(data)

    def enabled(self, servo_id: int) -> int:
        """Return how many torque-on writes reached servo_id (broadcasts included)."""
        with self._lock:
            return sum(1 for each in self.torque_on if each in (servo_id, 0xFE))


def _covers(address: int, length: int) -> bool:
    return address <= TORQUE_ENABLE < address + length


def _torque_on_ids(servo_id: int, instruction: int, params: bytes) -> List[int]:
    """Return the ids a host instruction sets Torque Enable to non-zero in."""
    ids = []
    if instruction in (Instruction.WRITE, Instruction.REG_WRITE) and len(params) > 2:
        address = params[0] | params[1] << 8
        data = params[2:]
        if _covers(address, len(data)) and data[TORQUE_ENABLE - address]:
            ids.append(servo_id)
    elif instruction == Instruction.SYNC_WRITE and len(params) > 4:
        address, length = params[0] | params[1] << 8, params[2] | params[3] << 8
        for at in range(4, len(params) - length, 1 + length):
            data = params[at + 1:at + 1 + length]
            if _covers(address, length) and data[TORQUE_ENABLE - address]:
                ids.append(params[at])
    elif instruction == Instruction.BULK_WRITE:
        at = 0
        while at + 5 <= len(params):
            address, length = params[at + 1] | params[at + 2] << 8, params[at + 3] | (
                params[at + 4] << 8)
            data = params[at + 5:at + 5 + length]
            if _covers(address, length) and data[TORQUE_ENABLE - address]:
                ids.append(params[at])
            at += 5 + length
    return ids


def test_the_recorder_sees_a_torque_on_in_every_write_form() -> None:
    # The watch itself: it must see what it is there to see.
    assert _torque_on_ids(4, Instruction.WRITE, bytes([TORQUE_ENABLE, 0, 1])) == [4]
    assert _torque_on_ids(4, Instruction.WRITE, bytes([TORQUE_ENABLE, 0, 0])) == []
    sync = bytes([TORQUE_ENABLE, 0, 1, 0, 2, 1, 3, 0])
    assert _torque_on_ids(0xFE, Instruction.SYNC_WRITE, sync) == [2]
    bulk = bytes([5, TORQUE_ENABLE, 0, 1, 0, 1, 6, 116, 0, 1, 0, 9])
    assert _torque_on_ids(0xFE, Instruction.BULK_WRITE, bulk) == [5]


class Rig:
    """The harness, its recording port, and /rosout."""

    def __init__(self, **top: Any) -> None:
        self.ports: List[Recorder] = []

        def factory(config: Any) -> Transport:
            simulator = open_transport(config).simulator   # type: ignore[attr-defined]

            def make() -> Any:
                port = Recorder(SimPortHandler(simulator, 'sim', config.baud_rate))
                self.ports.append(port)
                return port
            return SimTransport(simulator, make)
        params = sim_params(JOINTS, hardware_error_recovery=True, recovery_interval=0.1, **top)
        self.h = NodeHarness(params, port_factory=factory)
        self.h.joint_states.wait(lambda m: len(m.name) == len(JOINTS))
        self.logs: List[Tuple[int, str]] = []
        namespace = self.h.namespace.strip('/')
        assert self.h.client is not None
        self.h.client.node.create_subscription(
            Log, '/rosout',
            lambda m: self.logs.append((m.level, m.msg)) if namespace in m.name else None, 200)

    def torque_ons(self, servo_id: int) -> int:
        return sum(port.enabled(servo_id) for port in self.ports)

    def has_log(self, text: str) -> bool:
        return any(text in line for _, line in list(self.logs))

    def assert_never_torqued(self) -> None:
        for name, servo_id in PASSIVE.items():
            assert self.torque_ons(servo_id) == 0, f'{name} was sent Torque Enable = 1'
            assert self.h.reg(servo_id, 'torque_enable') == 0


@pytest.fixture(scope='module')
def rig() -> Iterator[Rig]:
    made = Rig()
    try:
        yield made
    finally:
        made.h.close()


def servo(rig: Rig, name: str) -> Any:
    assert rig.h.node is not None
    return rig.h.node.manager.servos[name]


def test_activate_sets_up_the_passive_joints_and_never_torques_them(rig: Rig) -> None:
    # The driven joint got its torque: the recorder saw that one.
    assert rig.torque_ons(DRIVEN) >= 1
    assert rig.h.reg(DRIVEN, 'torque_enable') == 1
    rig.assert_never_torqued()
    # Its mode was set up all the same (extended position: 4, current-based position: 5).
    assert rig.h.reg(LEAD, 'operating_mode') == 4
    assert rig.h.reg(GRIP, 'operating_mode') == 5
    # Read and published like any joint: a hand turns it and joint_states follows.
    with rig.h.sim.lock:   # a hand turns the horn a quarter turn (torque is off)
        rig.h.sim.servo(LEAD).dynamics.horn_position_pulse += 1024
    msg = rig.h.joint_states.wait(
        lambda m: abs(m.position[m.name.index('lead')] - math.pi / 2) < 0.01)
    assert 'lead' in msg.name
    rig.assert_never_torqued()


def test_diagnostics_say_passive(rig: Rig) -> None:
    msg = rig.h.diagnostics.wait(lambda m: any(s.name.endswith(': lead') for s in m.status),
                                 timeout_s=5.0)
    status = next(s for s in msg.status if s.name.endswith(': lead'))
    assert status.message.startswith('passive'), status.message
    assert {v.key: v.value for v in status.values}['role'] == 'passive (torque: false)'
    driven = next(s for s in msg.status if s.name.endswith(': drive'))
    assert 'passive' not in driven.message


@pytest.mark.parametrize('kind', ['position', 'velocity', 'current', 'pwm'])
def test_every_set_service_refuses_a_passive_joint_by_name(rig: Rig, kind: str) -> None:
    for name in PASSIVE:
        response = rig.h.call(f'set_{kind}', name=[name], value=[0.1])
        assert not response.success
        assert f"joint '{name}' {REFUSED}" in response.message, response.message
    # With a driven joint in the same request: refused whole, nothing written to either.
    before = rig.h.reg(DRIVEN, 'goal_position')
    response = rig.h.call('set_position', name=['drive', 'lead'], value=[0.2, 0.2])
    assert not response.success and "joint 'lead'" in response.message
    assert rig.h.reg(DRIVEN, 'goal_position') == before
    rig.assert_never_torqued()


def test_command_topics_joint_command_and_trajectories_are_refused_by_name(rig: Rig) -> None:
    assert rig.h.client is not None
    node = rig.h.client.node
    prefix = f'{rig.h.namespace}/dxl_servo_driver'
    command = node.create_publisher(JointState, f'{prefix}/joint_command', 10)
    trajectory = node.create_publisher(JointTrajectory, f'{prefix}/joint_trajectory', 10)
    gripper = node.create_publisher(GripperCommand, f'{prefix}/gripper', 10)
    for publisher in (command, trajectory, gripper):
        wait_until(lambda: publisher.get_subscription_count() >= 1, 10.0, 'discovery')
    msg = JointTrajectory(joint_names=['drive', 'grip'])
    msg.points = [JointTrajectoryPoint(positions=[0.0, 0.5], time_from_start=Duration(sec=1))]
    sends: Dict[str, Callable[[], None]] = {
        f"position command refused: joint 'lead' {REFUSED}":
            lambda: rig.h.publish('position', ['lead'], [0.3]),
        f"joint_command refused: joint 'lead' {REFUSED}":
            lambda: command.publish(JointState(name=['lead'], position=[0.3])),
        f"trajectory refused: joint 'grip' {REFUSED}": lambda: trajectory.publish(msg),
        f"gripper refused: joint 'grip' {REFUSED}": lambda: gripper.publish(GripperCommand(
            name='grip', position=0.5, ratio=math.nan, max_effort=math.nan)),
    }
    before = rig.h.reg(GRIP, 'goal_position')
    for line, send in sends.items():
        # The node logs a refusal at most once a second: sent again until it is said.
        deadline = time.monotonic() + 10.0
        while not rig.has_log(line):
            assert time.monotonic() < deadline, f'no log line {line!r}: {rig.logs[-5:]}'
            send()
            again = time.monotonic() + 0.3
            while not rig.has_log(line) and time.monotonic() < again:
                time.sleep(0.01)
    assert rig.h.reg(GRIP, 'goal_position') == before
    rig.assert_never_torqued()


def _action_result(client: Client, goal: Any) -> Any:
    assert client.wait_for_server(timeout_sec=10.0)
    handle = send_goal(client, goal)
    if not handle.accepted:
        return None
    return result_of(client, handle, 10.0)


def test_actions_are_refused_by_name(rig: Rig) -> None:
    assert rig.h.client is not None
    prefix = f'{rig.h.namespace}/dxl_servo_driver'
    follow = Client(rig.h.client.node, FollowJointTrajectory,
                    f'{prefix}/follow_joint_trajectory')
    goal = FollowJointTrajectory.Goal()
    goal.trajectory.joint_names = ['lead']
    goal.trajectory.points = [JointTrajectoryPoint(positions=[0.1],
                                                   time_from_start=Duration(sec=1))]
    response = _action_result(follow, goal)
    assert response is not None and response.status == GoalStatus.STATUS_ABORTED
    assert response.result.error_code == FollowJointTrajectory.Result.INVALID_JOINTS
    assert f"joint 'lead' {REFUSED}" in response.result.error_string
    grip = Client(rig.h.client.node, GripperAction, f'{prefix}/gripper_cmd')
    goal = GripperAction.Goal()
    goal.command.position = 0.5
    response = _action_result(grip, goal)
    assert response is not None and response.status == GoalStatus.STATUS_ABORTED
    # GripperCommand's result has no error field: the log says why.
    wait_until(lambda: rig.has_log(f"refused: joint 'grip' {REFUSED}"), 10.0, 'the reason')
    rig.assert_never_torqued()


def test_torque_on_is_refused_by_name_and_all_joints_leaves_them_out(rig: Rig) -> None:
    response = rig.h.call('set_torque', name=['lead'], enable=True)
    assert not response.success
    assert f"joint 'lead' {REFUSED}" in response.message
    response = rig.h.call('set_torque', name=['drive', 'grip'], enable=True)
    assert not response.success and f"joint 'grip' {REFUSED}" in response.message
    response = rig.h.call('write_register', name='lead',
                          register_name='torque_enable', value=1)
    assert not response.success and 'torque_enable' in response.message
    response = rig.h.call('write_register', name='grip', register_name='goal_current',
                          value=100)
    assert not response.success and f"joint 'grip' {REFUSED}" in response.message
    # Every joint (no name): the driven one, never the passive ones.
    assert rig.h.call('set_torque', name=['drive'], enable=False).success
    wait_until(lambda: rig.h.reg(DRIVEN, 'torque_enable') == 0, 5.0, 'drive off')
    response = rig.h.call('set_torque', name=[], enable=True)
    assert response.success, response.message
    assert rig.h.reg(DRIVEN, 'torque_enable') == 1
    # Off is always taken: it is what a passive joint is.
    assert rig.h.call('set_torque', name=['lead'], enable=False).success
    rig.assert_never_torqued()


def test_a_mode_switch_of_a_passive_joint_leaves_it_off(rig: Rig) -> None:
    # Its mode is configuration (what it reads right in), not a command: taken, never torqued.
    response = rig.h.call('set_operating_mode', name=['lead'], mode='position')
    assert response.success, response.message
    assert rig.h.reg(LEAD, 'operating_mode') == 3
    response = rig.h.call('set_operating_mode', name=['lead'], mode='extended_position')
    assert response.success, response.message
    assert rig.h.reg(LEAD, 'operating_mode') == 4
    rig.assert_never_torqued()


def test_a_brownout_restores_the_passive_joints_without_torque(rig: Rig) -> None:
    assert rig.h.node is not None
    manager = rig.h.node.manager
    restarts = {name: servo(rig, name).restarts for name in ('drive', *PASSIVE)}
    for servo_id in (DRIVEN, LEAD, GRIP):
        rig.h.sim.powercycle(servo_id)
    wait_until(lambda: all(servo(rig, name).restarts > restarts[name] for name in restarts)
               and not any(name in manager.tasks for name in restarts), 15.0, 'restored')
    # The driven joint got its torque back (the restore ran), the passive ones did not.
    wait_until(lambda: rig.h.reg(DRIVEN, 'torque_enable') == 1, 10.0, 'drive torque back')
    assert rig.h.reg(LEAD, 'operating_mode') == 4   # its setup, restored
    rig.assert_never_torqued()
    # A sagging supply: the servo latches an input voltage error, and hardware_error_recovery
    # reboots it (again while the supply stays low) until the supply is back.
    recoveries = servo(rig, 'lead').recoveries
    rig.h.sim.set_voltage(LEAD, 5.0)
    wait_until(lambda: servo(rig, 'lead').recoveries > recoveries, 15.0, 'a recovery')
    rig.h.sim.set_voltage(LEAD, 12.0)
    wait_until(lambda: rig.h.reg(LEAD, 'hardware_error_status') == 0
               and 'lead' not in manager.tasks, 15.0, 'lead back after its brown-out')
    rig.assert_never_torqued()


def test_a_reboot_and_a_hardware_error_recovery_leave_them_off(rig: Rig) -> None:
    assert rig.h.node is not None
    manager = rig.h.node.manager
    response = rig.h.call('reboot', name=['lead', 'grip', 'drive'])
    assert response.success, response.message
    wait_until(lambda: rig.h.reg(DRIVEN, 'torque_enable') == 1, 10.0, 'drive torque back')
    rig.assert_never_torqued()
    recoveries = servo(rig, 'lead').recoveries
    rig.h.sim.inject_error(LEAD, 'overheat')
    wait_until(lambda: servo(rig, 'lead').recoveries > recoveries
               and 'lead' not in manager.tasks
               and rig.h.reg(LEAD, 'hardware_error_status') == 0, 15.0, 'recovered')
    rig.assert_never_torqued()


def test_a_reconnection_leaves_them_off(rig: Rig) -> None:
    port = rig.ports[-1]
    assert rig.h.node is not None
    manager = rig.h.node.manager
    port.inner.unplug_port()
    wait_until(lambda: manager.port_lost, 10.0, 'the port lost')
    for servo_id in (DRIVEN, LEAD, GRIP):   # the servos lost their power with the adapter
        rig.h.sim.powercycle(servo_id)
    restarts = {name: servo(rig, name).restarts for name in ('drive', *PASSIVE)}
    port.inner.plug_port()
    wait_until(lambda: not manager.port_lost and all(
        servo(rig, name).restarts > count and name not in manager.tasks
        for name, count in restarts.items()), 15.0, 'everyone restored')
    wait_until(lambda: rig.h.reg(DRIVEN, 'torque_enable') == 1, 10.0, 'drive torque back')
    rig.assert_never_torqued()


def test_a_file_of_passive_joints_is_a_leader_arm() -> None:
    joints = {f'j{i}': {'id': i, 'torque': False} for i in (1, 2, 3)}
    with NodeHarness(sim_params(joints)) as h:
        msg = h.joint_states.wait(lambda m: len(m.name) == 3)
        assert list(msg.name) == ['j1', 'j2', 'j3']
        assert [h.reg(i, 'torque_enable') for i in (1, 2, 3)] == [0, 0, 0]
        response = h.call('set_torque', name=[], enable=True)
        assert not response.success and 'every joint is passive' in response.message


def test_the_parameters_are_checked() -> None:
    base = {'joints': ['a'], 'a.id': 1}
    assert cfg.validate({**base, 'a.torque': False}).joint('a').torque is False
    assert cfg.validate(base).joint('a').torque is True
    with pytest.raises(cfg.ConfigError, match=r"'a.torque'.*expected true or false"):
        cfg.validate({**base, 'a.torque': 'no'})
