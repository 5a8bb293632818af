"""
A leader's trigger (`<joint>.trigger: true`): a spring made of the motor, never commanded.

The joint runs in current-based position with its rest (trigger_position) as goal and its
spring's strength (trigger_current) as goal current; its torque is on even in a passive arm
with torque_on_start false. The simulator's `load` is a brake on the horn: with one stronger
than the spring the horn stays off its rest, pushing at the goal current and no more; without
it the horn springs back. Bad trigger parameters are refused before anything is written.
"""

import pathlib
import time
from typing import Any, Callable, Dict, Iterator

from conditions import wait_until
from dxl_servo_driver import config as cfg
from dxl_servo_driver.driver.transports import open_transport, Transport
from dxl_servo_driver.models import model_for, xm430
from dxl_servo_driver.models.units import units_for
from node_harness import NodeHarness, sim_params, startup_failure
from processes import NodeProcess, params_yaml, StartVirtualBus
import pytest

TRIGGER, LEAD = 1, 2
REST = 1.0            # rad
SPRING_A = 0.3        # A
BRAKE_NM = 5.0        # far above what 0.3 A gives an XM430 (about 0.55 N*m)
XM430 = model_for(xm430.MODEL_NUMBER)
UNITS = units_for(XM430)
JOINTS: Dict[str, Dict[str, Any]] = {
    'trig': {'id': TRIGGER, 'trigger': True, 'trigger_position': REST,
             'trigger_current': SPRING_A},
    'lead': {'id': LEAD, 'torque': False},
}


def braked(config: Any) -> Transport:
    """`port: sim` with the trigger's horn held by a brake before the node starts."""
    transport = open_transport(config)
    transport.simulator.set_load(TRIGGER, BRAKE_NM)   # type: ignore[attr-defined]
    return transport


@pytest.fixture(scope='module')
def h() -> Iterator[NodeHarness]:
    # A leader arm: a passive joint, no torque at start, and its trigger.
    with NodeHarness(sim_params(JOINTS, torque_on_start=False),
                     port_factory=braked) as harness:
        harness.joint_states.wait(lambda m: len(m.name) == 2)
        yield harness


def trigger_rad(h: NodeHarness) -> float:
    return UNITS.position_to_rad(h.reg(TRIGGER, 'present_position'))


def spring_raw() -> int:
    return UNITS.current_from_a(SPRING_A)


def test_the_trigger_is_torqued_in_a_passive_arm_and_pushes_at_its_current(
        h: NodeHarness) -> None:
    assert h.reg(TRIGGER, 'operating_mode') == 5   # current-based position
    assert h.reg(TRIGGER, 'torque_enable') == 1
    assert h.reg(LEAD, 'torque_enable') == 0
    assert h.reg(TRIGGER, 'goal_position') == UNITS.position_from_rad(REST)
    assert h.reg(TRIGGER, 'goal_current') == spring_raw()
    # The brake holds it off its rest: the motor pushes toward it at the goal current.
    wait_until(lambda: abs(h.reg(TRIGGER, 'present_current') - spring_raw()) <= 2, 5.0,
               'pushing at the spring current')
    assert abs(trigger_rad(h)) < 0.05


def test_it_springs_back_when_the_load_is_removed_at_its_current(h: NodeHarness) -> None:
    h.sim.set_load(TRIGGER, 0.0)
    highest = 0
    deadline = time.monotonic() + 10.0
    # Every sample on the way: the current never goes beyond the spring's.
    while abs(trigger_rad(h) - REST) > 0.03:
        highest = max(highest, abs(h.reg(TRIGGER, 'present_current')))
        assert time.monotonic() < deadline, f'still at {trigger_rad(h):.3f} rad'
        time.sleep(0.002)
    assert highest <= spring_raw() + 2, highest
    assert h.reg(TRIGGER, 'goal_current') == spring_raw()
    msg = h.joint_states.wait(lambda m: abs(m.position[m.name.index('trig')] - REST) < 0.03)
    assert msg.name[0] == 'trig'


def test_commands_to_the_trigger_are_refused_by_name(h: NodeHarness) -> None:
    for kind in ('position', 'current', 'velocity', 'pwm'):
        response = h.call(f'set_{kind}', name=['trig'], value=[0.1])
        assert not response.success
        assert "joint 'trig' is a trigger (trigger: true)" in response.message, response.message
    response = h.call('set_operating_mode', name=['trig'], mode='position')
    assert not response.success
    assert 'current_based_position, not position' in response.message
    response = h.call('write_register', name='trig', register_name='goal_current', value=500)
    assert not response.success and 'is a trigger' in response.message
    assert h.reg(TRIGGER, 'goal_current') == spring_raw()
    assert h.reg(TRIGGER, 'goal_position') == UNITS.position_from_rad(REST)


def test_torque_off_and_on_rearms_the_spring(h: NodeHarness) -> None:
    assert h.call('set_torque', name=['trig'], enable=False).success
    assert h.reg(TRIGGER, 'torque_enable') == 0
    with h.sim.lock:   # a hand moves the free horn away
        h.sim.servo(TRIGGER).dynamics.horn_position_pulse -= 1000
    wait_until(lambda: abs(trigger_rad(h) - REST) > 1.0, 5.0, 'moved by hand')
    response = h.call('set_torque', name=['trig'], enable=True)
    assert response.success, response.message
    wait_until(lambda: abs(trigger_rad(h) - REST) < 0.03, 10.0, 'sprung back')
    assert h.reg(TRIGGER, 'goal_current') == spring_raw()


def test_a_brownout_restores_the_spring(h: NodeHarness) -> None:
    assert h.node is not None
    servo = h.node.manager.servos['trig']
    restarts = servo.restarts
    h.sim.powercycle(TRIGGER)
    # The restore is a task: done when the servo is out of the task list again.
    wait_until(lambda: servo.restarts > restarts and 'trig' not in h.node.manager.tasks,
               15.0, 'restored')
    wait_until(lambda: h.reg(TRIGGER, 'torque_enable') == 1, 5.0, 'torque back')
    assert h.reg(TRIGGER, 'goal_current') == spring_raw()
    assert h.reg(TRIGGER, 'goal_position') == UNITS.position_from_rad(REST)
    assert h.reg(LEAD, 'torque_enable') == 0


def test_diagnostics_say_trigger(h: NodeHarness) -> None:
    msg = h.diagnostics.wait(lambda m: any(s.name.endswith(': trig') for s in m.status),
                             timeout_s=5.0)
    status = next(s for s in msg.status if s.name.endswith(': trig'))
    assert status.message.startswith('trigger (rest 1, spring 0.3 A)'), status.message


# bad parameters --------------------------------------------------------------------------

BASE = {'joints': ['g'], 'g.id': 1, 'g.trigger': True, 'g.trigger_position': 0.5,
        'g.trigger_current': 0.2}
BAD = {
    'another mode': ({'g.operating_mode': 'position'}, 'g.operating_mode',
                     'must be current_based_position, not position'),
    'no rest': ({'g.trigger_position': None}, 'g.trigger_position', 'a trigger needs'),
    'no current': ({'g.trigger_current': None}, 'g.trigger_current', 'a trigger needs'),
    'zero current': ({'g.trigger_current': 0.0}, 'g.trigger_current', 'below the minimum'),
    'passive trigger': ({'g.torque': False}, 'g.torque', 'a trigger is torqued'),
    'beyond the model': ({'g.model': 'XL330-M077', 'g.trigger_current': 2.0},
                         'g.trigger_current', "2 A is above the XL330-M077's Current Limit "
                         '(1.15 A)'),
    'beyond the file': ({'g.registers.current_limit': 100, 'g.trigger_current': 0.3},
                        'g.trigger_current', 'above g.registers.current_limit 100 (0.269 A)'),
    'beyond the range': ({'g.min_position': 0.0, 'g.max_position': 0.4},
                         'g.trigger_position', "beyond the joint's limits 0..0.4"),
    'a second servo': ({'g.secondary_id': 2}, 'g.secondary_id', 'a trigger has one servo'),
    'a model without the mode': ({'g.model': 'AX-12A'}, 'g.operating_mode',
                                 'AX-12A has no current_based_position mode'),
    'a model without current': ({'g.model': 'XL430-W250', 'g.operating_mode':
                                 'current_based_position'}, 'g.operating_mode',
                                'has no current_based_position mode'),
}


@pytest.mark.parametrize('case', sorted(BAD))
def test_bad_trigger_parameters_are_refused_naming_the_key(case: str) -> None:
    change, key, text = BAD[case]
    params = {k: v for k, v in {**BASE, **change}.items() if v is not None}
    with pytest.raises(cfg.ConfigError) as caught:
        cfg.validate(params)
    assert caught.value.key == key, str(caught.value)
    assert text in str(caught.value)


def test_trigger_keys_need_a_trigger() -> None:
    with pytest.raises(cfg.ConfigError, match='only a trigger'):
        cfg.validate({'joints': ['g'], 'g.id': 1, 'g.trigger_current': 0.2})


def test_a_trigger_defaults_to_current_based_position() -> None:
    joint = cfg.validate(BASE).joint('g')
    assert (joint.operating_mode, joint.trigger, joint.torque) == (
        'current_based_position', True, True)
    assert (joint.trigger_position, joint.trigger_current) == (0.5, 0.2)
    # A gripper too (its mode check sees the trigger's).
    joint = cfg.validate({**BASE, 'g.gripper': True, 'g.gripper_open': 0.0,
                          'g.gripper_closed': 1.0}).joint('g')
    assert joint.gripper and joint.operating_mode == 'current_based_position'


def test_a_spring_beyond_the_servos_own_limit_is_refused_at_configure(capfd: Any) -> None:
    # No model pinned, no limit in the file: the Current Limit the servo holds judges it.
    limit_a = UNITS.current_to_a(XM430.item('current_limit').initial)
    failure = startup_failure(sim_params({'g': {'id': 1, 'trigger': True,
                                                'trigger_position': 0.0,
                                                'trigger_current': limit_a + 0.5}}))
    assert 'configure failed' in str(failure)
    err = capfd.readouterr().err
    assert (f"joint 'g': trigger_current {limit_a + 0.5:g} A is above the XM430-W210's "
            f'Current Limit {limit_a:.4g} A (current_limit 1193)') in err, err


# on virtual_bus, driven from its console ---------------------------------------------------

def test_on_virtual_bus_the_console_load_holds_it_off_rest_and_it_springs_back(
        virtual_bus: StartVirtualBus, workdir: pathlib.Path) -> None:
    bus = virtual_bus([TRIGGER, LEAD], 1_000_000)
    assert bus.control(f'load {TRIGGER} {BRAKE_NM}').startswith('ok'), 'load refused'
    joints = {'trig': {'id': TRIGGER, 'trigger': 'true', 'trigger_position': REST,
                       'trigger_current': SPRING_A},
              'lead': {'id': LEAD, 'torque': 'false'}}
    node = NodeProcess(workdir, params_yaml(bus.device, joints, torque_on_start='false'))
    try:
        def until(predicate: Callable[[], bool], what: str, timeout_s: float = 30.0) -> None:
            deadline = time.monotonic() + timeout_s
            while not predicate():
                node.alive()
                assert time.monotonic() < deadline, f'{what}: not within {timeout_s} s\n' + (
                    node.output())
                time.sleep(0.05)

        until(lambda: bus.get(TRIGGER, 'torque_enable') == 1, 'the trigger torqued')
        assert bus.get(TRIGGER, 'goal_current') == spring_raw()
        assert bus.get(TRIGGER, 'goal_position') == UNITS.position_from_rad(REST)
        until(lambda: abs(bus.get(TRIGGER, 'present_current') - spring_raw()) <= 2,
              'pushing against the brake at the spring current')
        assert abs(UNITS.position_to_rad(bus.get(TRIGGER, 'present_position'))) < 0.05
        assert bus.control(f'load {TRIGGER} 0').startswith('ok')
        until(lambda: abs(UNITS.position_to_rad(bus.get(TRIGGER, 'present_position')) - REST)
              < 0.03, 'sprung back to rest')
        # A power cut on both: the trigger is restored as a spring, the passive joint off.
        for servo_id in (TRIGGER, LEAD):
            assert bus.control(f'powercycle {servo_id}').startswith('ok')
        until(lambda: "joint 'trig': restored after its restart" in node.output()
              and "joint 'lead': restored after its restart" in node.output(), 'restored')
        until(lambda: bus.get(TRIGGER, 'torque_enable') == 1, 'the spring back')
        assert bus.get(TRIGGER, 'goal_current') == spring_raw()
        assert bus.get(LEAD, 'torque_enable') == 0
    finally:
        node.stop()
