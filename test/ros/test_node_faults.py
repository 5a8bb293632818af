"""
Faults at the node level on `port: sim`: port loss, power cuts, hardware errors, lost replies.

The simulator injects each fault under the node (SimPortHandler.unplug_port, SimBus.powercycle /
inject_error / set_drop) and the tests check what a user sees: joint_states never carry a stale
or wrong value, /diagnostics says what happened, services answer, and the node recovers what it
can by itself.
"""

import math
import threading
import time
from typing import Any, Dict, Iterator, List, Optional, Tuple

from conditions import wait_until
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from dxl_servo_driver.models import model_for, xm430
from dxl_servo_driver.models.units import units_for
from node_harness import NodeHarness, sim_params
import pytest
from sensor_msgs.msg import JointState

# The XM430 manual's model, every joint's here: its units (models/units.py) and error bits.
MANUAL = model_for(xm430.MODEL_NUMBER)
UNITS = units_for(MANUAL)
RAD_PER_PULSE = UNITS.rad_per_pulse
PULSES_PER_REV = UNITS.pulses_per_rev
SERVICE_DEADLINE_S = 5.0   # "never hang": generous for a busy machine, far below forever
OVERLOAD = {name: bit for bit, name in MANUAL.hardware_error_bits.items()}['overload']


def pos_raw(rad: float) -> int:
    return UNITS.zero_raw + round(rad / RAD_PER_PULSE)


def stamp_s(msg: Any) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


def bus_status(array: DiagnosticArray) -> DiagnosticStatus:
    matches = [s for s in array.status if s.name.endswith(': bus sim')]
    assert len(matches) == 1, [s.name for s in array.status]
    return matches[0]


def servo_status(array: DiagnosticArray, joint: str) -> DiagnosticStatus:
    matches = [s for s in array.status if s.name.endswith(f': {joint}')]
    assert len(matches) == 1, [s.name for s in array.status]
    return matches[0]


def values_of(status: DiagnosticStatus) -> Dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


class Recorder:
    """
    Every joint_states message with the time it arrived and the simulator's positions then.

    Each message is compared with the registers it claims to report: those are read in the
    subscription callback, right when the message arrives.
    """

    def __init__(self, h: NodeHarness, ids: Dict[str, int]) -> None:
        self._h = h
        self._ids = ids
        self._lock = threading.Lock()
        self.entries: List[Tuple[JointState, float, Dict[str, int]]] = []
        assert h.client is not None
        self._sub = h.client.node.create_subscription(
            JointState, f'{h.namespace}/joint_states', self._on_message, 100)

    def _on_message(self, msg: JointState) -> None:
        positions = {name: self._h.reg(sid, 'present_position')
                     for name, sid in self._ids.items()}
        with self._lock:
            self.entries.append((msg, time.time(), positions))

    def since(self, wall_s: float) -> List[Tuple[JointState, float, Dict[str, int]]]:
        """Return the entries of messages stamped after wall_s (the node's read time)."""
        with self._lock:
            return [entry for entry in self.entries if stamp_s(entry[0]) > wall_s]


def with_joint(recorder: Recorder, wall_s: float,
               name: str) -> List[Tuple[JointState, float, Dict[str, int]]]:
    """Return the recorded messages stamped after wall_s that carry the joint."""
    return [entry for entry in recorder.since(wall_s) if name in entry[0].name]


def call_within(h: NodeHarness, service: str, **fields: Any) -> Any:
    start = time.monotonic()
    response = h.call(service, timeout_s=SERVICE_DEADLINE_S, **fields)
    assert time.monotonic() - start < SERVICE_DEADLINE_S
    return response


# port loss --------------------------------------------------------------------------------

PORT_JOINTS: Dict[str, Dict[str, Any]] = {
    'arm': {'id': 1, 'operating_mode': 'position', 'registers': {'profile_velocity': 100}},
    'wheel': {'id': 2, 'operating_mode': 'velocity'},
}


@pytest.fixture
def ph() -> Iterator[NodeHarness]:
    with NodeHarness(sim_params(PORT_JOINTS)) as harness:
        yield harness


def test_port_lost_and_back(ph: NodeHarness) -> None:
    h = ph
    assert h.node is not None
    recorder = Recorder(h, {'arm': 1, 'wheel': 2})
    h.joint_states.wait(lambda m: len(m.name) == 2)
    port = h.node.manager.port
    port.unplug_port()
    # Taken after the unplug: a read stamped between a time taken before it and the unplug
    # itself (a test thread descheduled there) is a sample of the live port, rightly published.
    unplugged_s = time.time()
    # The adapter and the servos' supply go together (a USB hub losing power): arm restarts.
    h.sim.powercycle(1)
    array = h.diagnostics.wait(lambda a: bus_status(a).level == DiagnosticStatus.ERROR,
                               timeout_s=5.0)
    bus = bus_status(array)
    assert 'port lost' in bus.message, bus.message
    assert values_of(bus)['port_lost'] == 'True'
    # Services answer at once, refusing with the reason; nothing hangs on the dead port.
    for service, fields in (
            ('set_position', {'name': ['arm'], 'value': [0.3]}),
            ('set_velocity', {'name': ['wheel'], 'value': [1.0]}),
            ('set_torque', {'name': [], 'enable': True}),
            ('set_operating_mode', {'name': ['wheel'], 'mode': 'pwm'}),
            ('reboot', {'name': ['wheel']}),
            ('read_register', {'name': 'arm', 'register_name': 'led'}),
            ('write_register', {'name': 'arm', 'register_name': 'led', 'value': 1})):
        response = call_within(h, service, **fields)
        assert not response.success, (service, response.message)
        assert response.message.strip(), service
    received = h.joint_states.received
    time.sleep(1.0)
    assert h.joint_states.received == received, 'joint_states while the port is lost'
    # No message read after the unplug was published: none, stale or invented.
    assert recorder.since(unplugged_s) == []
    assert h.node._thread is not None and h.node._thread.is_alive()

    port.plug_port()
    msg = h.joint_states.wait(lambda m: len(m.name) == 2, timeout_s=10.0)
    assert stamp_s(msg) > unplugged_s
    h.wait_reg(1, 'torque_enable', lambda v: v == 1, timeout_s=5.0)
    assert h.reg(2, 'torque_enable') == 1
    assert h.reg(1, 'profile_velocity') == 100   # the restarted servo got its setup back
    array = h.diagnostics.wait(lambda a: bus_status(a).level != DiagnosticStatus.ERROR,
                               timeout_s=5.0)
    assert values_of(bus_status(array))['port_lost'] == 'False'
    # What was published after the return matches the servos, which are at rest (each
    # message against the registers read when it arrived, a moment later: only while nothing
    # moves, so before the goal below).
    returned = recorder.since(unplugged_s)
    for msg, _, positions in returned:
        for name, position in zip(msg.name, msg.position):
            assert abs(position - UNITS.position_to_rad(positions[name])) < 0.05, name
    response = call_within(h, 'set_position', name=['arm'], value=[0.3])
    assert response.success, response.message
    assert h.reg(1, 'goal_position') == pos_raw(0.3)


# power cut in extended position mode --------------------------------------------------------

def test_multi_turn_position_survives_a_power_cycle() -> None:
    joints = {'spin': {'id': 1, 'operating_mode': 'extended_position'}}
    with NodeHarness(sim_params(joints)) as h:
        assert h.node is not None
        target_rad = 2.4 * 2.0 * math.pi   # several turns: beyond what one turn can hold
        assert h.call('set_position', name=['spin'], value=[target_rad]).success
        h.joint_states.wait(lambda m: abs(m.position[0] - target_rad) < 0.01, timeout_s=15.0)
        recorder = Recorder(h, {'spin': 1})
        cut_s = time.time()
        h.sim.powercycle(1)
        # The node notices the restart and gives the servo its setup back, torque on.
        h.wait_reg(1, 'torque_enable', lambda v: v == 1, timeout_s=5.0)
        deadline = time.monotonic() + 5.0
        while h.node.manager.servos['spin'].restarts < 1:
            assert time.monotonic() < deadline, 'the restart was not noticed'
            time.sleep(0.01)
        # A cycle in which the servo did not answer publishes a message without it. Some with
        # it, waited for (a sleep gave a busy machine too few, or none).
        wait_until(lambda: len(with_joint(recorder, cut_s, 'spin')) >= 10,
                   15.0, 'no joint_states with the joint after the power cycle')
        after = with_joint(recorder, cut_s, 'spin')
        tolerance_rad = math.radians(10.0)   # the horn coasts while unpowered; a turn is 360
        turn_offset = h.node.manager.servos['spin'].turn_offset
        for msg, _, positions in after:
            # Never the one-turn value the servo reports at boot.
            assert abs(msg.position[0] - target_rad) < tolerance_rad, msg.position[0]
        # The turns are kept by the driver, not in EEPROM: the servo itself counts within a turn
        # from its boot, and nothing was written to its homing offset.
        assert turn_offset % PULSES_PER_REV == 0 and turn_offset != 0
        assert 0 <= h.reg(1, 'present_position') < PULSES_PER_REV
        assert h.reg(1, 'homing_offset') == 0
        # It holds where it is (the goal sent before the cut is not replayed on its own).
        assert abs(h.reg(1, 'goal_position') - h.reg(1, 'present_position')) <= 8
        held = (h.reg(1, 'goal_position') + turn_offset - UNITS.zero_raw) * RAD_PER_PULSE
        assert abs(held - target_rad) < tolerance_rad


# hardware errors ------------------------------------------------------------------------------

ERROR_JOINTS: Dict[str, Dict[str, Any]] = {
    'gripper': {'id': 1, 'operating_mode': 'current_based_position',
                'registers': {'current_limit': 400, 'profile_velocity': 80}},
    'wrist': {'id': 2, 'operating_mode': 'position'},
}


def test_overload_recovered_when_recovery_is_on() -> None:
    with NodeHarness(sim_params(ERROR_JOINTS, hardware_error_recovery=True)) as h:
        h.joint_states.wait(lambda m: len(m.name) == 2)
        # The LED is not configuration: a reboot of the wrist would turn it off for good.
        assert h.call('write_register', name='wrist', register_name='led', value=1).success
        h.sim.inject_error(1, 'overload')
        array = h.diagnostics.wait(
            lambda a: int(values_of(bus_status(a))['recoveries']) >= 1, timeout_s=10.0)
        assert int(values_of(servo_status(array, 'gripper'))['recoveries']) >= 1
        assert values_of(servo_status(array, 'wrist'))['recoveries'] == '0'
        h.wait_reg(1, 'hardware_error_status', lambda v: v == 0, timeout_s=5.0)
        h.wait_reg(1, 'torque_enable', lambda v: v == 1, timeout_s=5.0)
        assert h.reg(1, 'profile_velocity') == 80   # configuration restored after the reboot
        assert h.reg(1, 'operating_mode') == 5
        # Only the faulty servo was rebooted.
        assert h.reg(2, 'led') == 1 and h.reg(2, 'torque_enable') == 1
        array = h.diagnostics.wait(
            lambda a: servo_status(a, 'gripper').level == DiagnosticStatus.OK, timeout_s=5.0)
        assert values_of(servo_status(array, 'gripper'))['hardware_errors'] == 'none'


def test_overload_stays_latched_when_recovery_is_off() -> None:
    with NodeHarness(sim_params(ERROR_JOINTS)) as h:
        h.joint_states.wait(lambda m: len(m.name) == 2)
        h.sim.inject_error(1, 'overload')
        array = h.diagnostics.wait(
            lambda a: servo_status(a, 'gripper').level == DiagnosticStatus.ERROR,
            timeout_s=5.0)
        status = servo_status(array, 'gripper')
        assert 'overload' in status.message, status.message
        assert 'overload' in values_of(status)['hardware_errors']
        assert values_of(bus_status(array))['recoveries'] == '0'
        array = h.diagnostics.wait(timeout_s=5.0)   # one more second: still latched
        assert servo_status(array, 'gripper').level == DiagnosticStatus.ERROR
        assert h.reg(1, 'hardware_error_status') & OVERLOAD
        assert h.reg(1, 'torque_enable') == 0   # the manual's Shutdown default
        assert servo_status(array, 'wrist').level == DiagnosticStatus.OK


# lost replies -----------------------------------------------------------------------------------

DROP_JOINTS: Dict[str, Dict[str, Any]] = {
    'a': {'id': 1, 'operating_mode': 'position'},
    'b': {'id': 2, 'operating_mode': 'position'},
    'wheel': {'id': 3, 'operating_mode': 'velocity'},
    'gone': {'id': 4, 'operating_mode': 'position'},
}
WHEEL_RAD_S = 3.0


def test_lost_replies_never_give_stale_values() -> None:
    # At 50 Hz a cycle has time for the sync read that waits out the silent servo and for the
    # retries of the others (at 100 Hz the silent servo's wait leaves no time for them).
    with NodeHarness(sim_params(DROP_JOINTS, loop_rate=50.0)) as h:
        ids = {name: keys['id'] for name, keys in DROP_JOINTS.items()}
        assert h.call('set_velocity', name=['wheel'], value=[WHEEL_RAD_S]).success
        h.joint_states.wait(lambda m: len(m.name) == 4
                            and abs(m.velocity[2] - WHEEL_RAD_S) < 0.1, timeout_s=10.0)
        recorder = Recorder(h, ids)
        dropped_s = time.time()
        for sid in (1, 2, 3):
            h.sim.set_drop(sid, 0.01)
        h.sim.set_drop(4, 1.0)   # every reply lost: it must be in no message from now on
        # Three seconds of it, and joint_states kept coming through it: waited for, not
        # counted after a sleep (a busy machine publishes fewer in a second).
        wait_until(lambda: time.time() > dropped_s + 3.0 and len(recorder.since(dropped_s)) >= 20,
                   15.0, 'joint_states stopped coming')
        entries = recorder.since(dropped_s)
        previous: Optional[Tuple[float, float]] = None
        for msg, arrival, positions in entries:
            assert 'gone' not in msg.name
            assert len(msg.name) == len(msg.position) == len(msg.velocity) == len(msg.effort)
            for name, position in zip(msg.name, msg.position):
                registered_rad = (positions[name] - UNITS.zero_raw) * RAD_PER_PULSE
                if name == 'wheel':
                    # Read before it arrived: behind the servo now, by what the wheel turned
                    # from the read (after the stamp) to its arrival (after the registers were
                    # read), at twice its speed for the velocity loop's wandering.
                    behind = 2.0 * WHEEL_RAD_S * (arrival - stamp_s(msg)) + 3 * RAD_PER_PULSE
                    assert registered_rad - behind <= position <= registered_rad
                else:
                    assert abs(position - registered_rad) <= 3 * RAD_PER_PULSE, name
            if 'wheel' in msg.name:
                now = (stamp_s(msg), msg.position[list(msg.name).index('wheel')])
                if previous is not None and now[0] - previous[0] >= 0.005:
                    # A turning wheel read twice gives two positions: equal means stale.
                    assert now[1] > previous[1], (previous, now)
                previous = now
        present = [entry for entry in entries if 'wheel' in entry[0].name]
        assert len(present) >= len(entries) // 2
        # Retried and failed reads, counted (waited for: how many cycles a second a busy
        # machine runs is not the point).
        array = h.diagnostics.wait(
            lambda a: int(values_of(bus_status(a))['retries']) > 0
            and int(values_of(bus_status(a))['read_failures']) > 0
            and servo_status(a, 'gone').level == DiagnosticStatus.ERROR, timeout_s=15.0)
        gone = servo_status(array, 'gone')
        assert 'not answering' in gone.message
        assert h.node is not None and h.node._thread is not None and h.node._thread.is_alive()


def test_position_mode_after_turns_were_kept_across_a_reboot() -> None:
    joints = {'spin': {'id': 1, 'operating_mode': 'extended_position'}}
    with NodeHarness(sim_params(joints)) as h:
        target_rad = 1.3 * 2.0 * math.pi
        assert h.call('set_position', name=['spin'], value=[target_rad]).success
        h.wait_reg(1, 'present_position', lambda v: abs(v - pos_raw(target_rad)) < 20,
                   timeout_s=15.0)
        assert h.call('reboot', name=['spin']).success
        # The turn is kept by the driver across the reboot (nothing written to EEPROM).
        assert h.node is not None
        assert h.node.manager.servos['spin'].turn_offset == PULSES_PER_REV
        assert h.reg(1, 'homing_offset') == 0
        # Published with the kept turn: where the horn is now (it may coast a little while the
        # servo boots), within a few degrees of the target rather than one turn away.
        kept = (h.reg(1, 'present_position') + PULSES_PER_REV - UNITS.zero_raw) * RAD_PER_PULSE
        assert abs(kept - target_rad) < math.radians(20.0)
        h.joint_states.wait(lambda m: abs(m.position[0] - kept) < 0.01)
        response = h.call('set_operating_mode', name=['spin'], mode='position')
        assert response.success, response.message
        # Position mode covers one turn: the kept turns are dropped and 0..4095 is published.
        assert h.node.manager.servos['spin'].turn_offset == 0
        assert 0 <= h.reg(1, 'present_position') <= PULSES_PER_REV - 1
        assert h.reg(1, 'torque_enable') == 1
        present = (h.reg(1, 'present_position') - UNITS.zero_raw) * RAD_PER_PULSE
        h.joint_states.wait(lambda m: abs(m.position[0] - present) < 0.01)
