"""
Fuzz: random messages at every command topic and driver service of a running node (`port: sim`).

A seeded generator (DXL_FUZZ_SEED to replay another run) builds JointCommand messages and
SetGoals / SetOperatingMode / SetTorque / Reboot / ReadRegister / WriteRegister requests with
random names (known, unknown, empty, unicode, very long), mismatched lengths, awkward floats (NaN,
+-inf, huge, tiny, -0.0) and random modes, registers and values. An oracle written here from
README.md and the XM430 manual (not from the package's code; the units are the model's,
models/units.py) says for each input whether it must be refused and, if not, which raw goal the
simulated servo must hold afterwards. Every refusal must leave all goal registers as they were;
every service call must be answered (a refusal with success False and a message); after the
storm the node still publishes joint_states and obeys a normal command.
"""

import math
import os
import random
from typing import Any, Callable, Dict, Iterator, List, Optional, Sequence, Tuple

from dxl_servo_driver.models import model_for, modes, xm430
from dxl_servo_driver.models.units import units_for
from node_harness import NodeHarness, sim_params
import pytest

SEED = int(os.environ.get('DXL_FUZZ_SEED', '5051'))
OPERATIONS = 1500   # a fixed budget: about 10-20 s on a busy 2-core machine

# The units of the XM430 manual's model, every joint's here (models/units.py).
UNITS = units_for(model_for(xm430.MODEL_NUMBER))
RAD_PER_PULSE = UNITS.rad_per_pulse
RAD_S_PER_RAW = UNITS.rad_s_per_velocity_raw
A_PER_RAW = UNITS.a_per_current_raw
PWM_FULL_RAW = UNITS.pwm_full_raw
EXTENDED_LIMIT_RAW = xm430.EXTENDED_POSITION_LIMIT   # goal position range in modes 4 and 5
# Finite values beyond this are absurd for any joint: the driver may refuse them ('out of any
# range') instead of clamping; either answer is accepted, but it must be one of the two cleanly.
ABSURD = 1e9

JOINTS: Dict[str, Dict[str, Any]] = {
    'arm': {'id': 1, 'operating_mode': 'position', 'registers': {
        'min_position_limit': 1024, 'max_position_limit': 3072, 'profile_velocity': 100}},
    'spin': {'id': 2, 'operating_mode': 'extended_position'},
    'wheel': {'id': 3, 'operating_mode': 'velocity', 'registers': {'velocity_limit': 200}},
    'hand': {'id': 4, 'operating_mode': 'current', 'registers': {'current_limit': 300}},
    'fan': {'id': 5, 'operating_mode': 'pwm', 'registers': {'pwm_limit': 500}},
    'grip': {'id': 6, 'operating_mode': 'current_based_position',
             'registers': {'current_limit': 400}},
}
IDS = {name: keys['id'] for name, keys in JOINTS.items()}
KIND_REGISTER = modes.GOAL_REGISTERS
GOAL_REGISTERS = tuple(KIND_REGISTER.values())
# Which command kinds drive a joint in each mode, as the README states it: written here on its
# own, not taken from models.modes, so a wrong mode table is caught.
MODE_KINDS = {
    'current': {'current'}, 'velocity': {'velocity'}, 'position': {'position'},
    'extended_position': {'position'}, 'current_based_position': {'position', 'current'},
    'pwm': {'pwm'},
}
MODES = tuple(MODE_KINDS)

# The registers the fuzzer uses, from the XM430 manual's table: name -> (address, access, area,
# minimum, maximum). Values of the 'static' ones cannot change under the node.
REGISTERS: Dict[str, Tuple[int, str, str, int, int]] = {
    'model_number': (0, 'R', 'eeprom', 0, 65535),
    'firmware_version': (6, 'R', 'eeprom', 0, 255),
    'id': (7, 'RW', 'eeprom', 0, 252),
    'baud_rate': (8, 'RW', 'eeprom', 0, 7),
    'return_delay_time': (9, 'RW', 'eeprom', 0, 254),
    'operating_mode': (11, 'RW', 'eeprom', 0, 16),
    'moving_threshold': (24, 'RW', 'eeprom', 0, 1023),
    'pwm_limit': (36, 'RW', 'eeprom', 0, 885),
    'current_limit': (38, 'RW', 'eeprom', 0, 1193),
    'velocity_limit': (44, 'RW', 'eeprom', 0, 1023),
    'torque_enable': (64, 'RW', 'ram', 0, 1),
    'led': (65, 'RW', 'ram', 0, 1),
    'hardware_error_status': (70, 'R', 'ram', 0, 255),
    'velocity_p_gain': (78, 'RW', 'ram', 0, 32767),
    'position_p_gain': (84, 'RW', 'ram', 0, 32767),
    'goal_pwm': (100, 'RW', 'ram', -885, 885),
    'goal_current': (102, 'RW', 'ram', -1193, 1193),
    'goal_velocity': (104, 'RW', 'ram', -1023, 1023),
    'profile_acceleration': (108, 'RW', 'ram', 0, 32767),
    'goal_position': (116, 'RW', 'ram', -2 ** 31, 2 ** 31 - 1),
    'present_position': (132, 'R', 'ram', -2 ** 31, 2 ** 31 - 1),
    'present_temperature': (146, 'R', 'ram', 0, 255),
    'indirect_address_1': (168, 'RW', 'ram', 64, 661),
    'indirect_data_1': (224, 'RW', 'ram', 0, 255),
}
BY_ADDRESS = {entry[0]: name for name, entry in REGISTERS.items()}
STATIC_REGISTERS = ('model_number', 'firmware_version', 'led', 'position_p_gain',
                    'velocity_p_gain', 'return_delay_time', 'moving_threshold', 'pwm_limit',
                    'current_limit', 'velocity_limit', 'profile_acceleration', 'id')
# Registers the driver must keep for itself: a new id or baud loses the servo, torque and mode
# bypass its safety ordering (goal = present first), the indirect map carries its state block,
# and goal position / velocity are what the command interfaces (with clamping) are for.
DRIVER_OWNED = {'id', 'baud_rate', 'operating_mode', 'torque_enable', 'goal_position',
                'goal_velocity', 'indirect_address_1', 'indirect_data_1'}
# Not the start of any item: inside model_number, reserved, inside goal_position, past the table.
# (12 is not in the XM430 manual's table but is Secondary ID on the simulated XM430-W350, as the
# SDK's table and e-manual have it: models.MANUAL_DIFFERENCES.)
BAD_ADDRESSES = (1, 15, 117, 700, 65536, 2 ** 40)
# A lower limit would make goals clamp to nothing and the marker command below undetectable.
LIMIT_FLOOR = {'pwm_limit': 50, 'current_limit': 50, 'velocity_limit': 50}

UNKNOWN_NAMES = ('', ' ', 'Arm', 'arm ', 'ghost', 'ärm', '关节', '\U0001f9be', 'a' * 5000,
                 'wheel\n', 'x' * 300 + 'arm', 'hand\t')
AWKWARD_FLOATS = (math.nan, -math.nan, math.inf, -math.inf, 0.0, -0.0, 5e-324, -1e-300, 1e-9,
                  1e300, -1e300, 1.7976931348623157e308, 1e9, -1e9, 1.0000001e9, 2e9, 1e6,
                  -1e6, 123456.789)
UNKNOWN_MODES = ('', 'Position', 'POSITION', 'torque', 'position ', 'extended', '3', 'pwm\x7f',
                 'régime', 'p' * 2000)


class Oracle:
    """What the node must do with a request: README.md's rules, the manual's limits, units."""

    def __init__(self, h: NodeHarness) -> None:
        self.h = h
        self.modes = {name: keys['operating_mode'] for name, keys in JOINTS.items()}

    def limit(self, name: str, register: str) -> int:
        return self.h.reg(IDS[name], register)

    def raw_goal(self, name: str, kind: str, value: float) -> int:
        """Return the raw goal the servo must get: the model's units, clamped to its limits."""
        mode = self.modes[name]
        if kind == 'position':
            raw = round(value / RAD_PER_PULSE) + UNITS.zero_raw
            if mode == 'position':
                low = self.limit(name, 'min_position_limit')
                high = self.limit(name, 'max_position_limit')
            else:
                # Turns kept by the driver across a restart are not in the servo's count.
                assert self.h.node is not None
                raw -= self.h.node.manager.servos[name].turn_offset
                low, high = -EXTENDED_LIMIT_RAW, EXTENDED_LIMIT_RAW
            return min(max(raw, low), high)
        if kind == 'velocity':
            raw, bound = round(value / RAD_S_PER_RAW), self.limit(name, 'velocity_limit')
        elif kind == 'current':
            raw, bound = round(value / A_PER_RAW), self.limit(name, 'current_limit')
        else:
            raw, bound = round(value * PWM_FULL_RAW), self.limit(name, 'pwm_limit')
        return min(max(raw, -bound), bound)

    def goals(self, kind: str, names: Sequence[str], values: Sequence[float]
              ) -> Tuple[Optional[bool], Dict[Tuple[int, str], int]]:
        """
        Return (verdict, goals written if accepted).

        The verdict is False (must be refused), True (must be accepted) or None (absurd but
        finite values: either).
        """
        if not names or len(names) != len(values) or len(set(names)) != len(names):
            return False, {}
        if any(name not in IDS for name in names):
            return False, {}
        if any(not math.isfinite(value) for value in values):
            return False, {}
        if any(kind not in MODE_KINDS[self.modes[name]] for name in names):
            return False, {}
        written = {(IDS[name], KIND_REGISTER[kind]): self.raw_goal(name, kind, value)
                   for name, value in zip(names, values) if abs(value) <= ABSURD}
        if any(abs(value) > ABSURD for value in values):
            return None, {}
        return True, written

    @staticmethod
    def register(key: str) -> Optional[str]:
        """Return the register a name or decimal address means, None if it means none."""
        key = key.strip()
        if key in REGISTERS:
            return key
        if key and all(c in '0123456789' for c in key):
            return BY_ADDRESS.get(int(key))
        return None

    def write_verdict(self, joint: str, key: str, value: int) -> Tuple[bool, Optional[str]]:
        register = self.register(key)
        if joint not in IDS or register is None:
            return False, register
        _, access, area, low, high = REGISTERS[register]
        if access != 'RW' or register in DRIVER_OWNED or not low <= value <= high:
            return False, register
        sid = IDS[joint]
        if area == 'eeprom' and self.h.reg(sid, 'torque_enable'):
            return False, register   # README.md: an EEPROM write while torque is on is refused
        if register in ('goal_pwm', 'goal_current'):
            # The manual: beyond PWM Limit / Current Limit the servo answers Data Limit Error.
            limit = self.h.reg(sid, 'pwm_limit' if register == 'goal_pwm' else 'current_limit')
            if abs(value) > limit:
                return False, register
        return True, register


class Fuzzer:
    """One random operation at a time against the harness, each checked by the oracle."""

    def __init__(self, h: NodeHarness, seed: int) -> None:
        self.h = h
        self.rng = random.Random(seed)
        self.oracle = Oracle(h)
        self.snapshot = self.goals()
        self.counts: Dict[str, int] = {}
        self.outcomes: Dict[str, Tuple[int, int]] = {}   # action -> (accepted, refused)
        self.refused = 0
        self.step = 0

    def goals(self) -> Dict[Tuple[int, str], int]:
        return {(sid, reg): self.h.reg(sid, reg) for sid in IDS.values() for reg in GOAL_REGISTERS}

    def where(self) -> str:
        return f'(DXL_FUZZ_SEED={SEED}, operation {self.step})'

    # random pieces ----------------------------------------------------------------------------
    def name(self) -> str:
        if self.rng.random() < 0.85:
            return self.rng.choice(list(IDS))
        return self.rng.choice(UNKNOWN_NAMES)

    def names(self, allow_empty: bool = True) -> List[str]:
        roll = self.rng.random()
        if roll < 0.06 and allow_empty:
            return []
        if roll < 0.1:
            return [self.rng.choice(list(IDS)) for _ in range(self.rng.randint(2, 40))]
        count = self.rng.choice((1, 1, 1, 2, 2, 3, 6))
        return [self.name() for _ in range(count)]

    def goal_names(self, kind: str) -> List[str]:
        """Names for a goal: half the time joints that take `kind` now, else anything."""
        takers = [name for name in IDS if kind in MODE_KINDS[self.oracle.modes[name]]]
        if takers and self.rng.random() < 0.5:
            return self.rng.sample(takers, self.rng.randint(1, len(takers)))
        return self.names()

    def value(self, kind: str) -> float:
        roll = self.rng.random()
        if roll < 0.15:
            return self.rng.choice(AWKWARD_FLOATS)
        scale = {'position': 25.0, 'velocity': 8.0, 'current': 4.0, 'pwm': 1.5}[kind]
        if roll < 0.25:
            scale *= 1000.0
        return self.rng.uniform(-scale, scale)

    def values(self, kind: str, count: int) -> List[float]:
        if self.rng.random() < 0.12:
            count = max(0, count + self.rng.choice((-2, -1, 1, 3)))
        return [self.value(kind) for _ in range(count)]

    def register_key(self) -> str:
        roll = self.rng.random()
        name = self.rng.choice(list(REGISTERS))
        if roll < 0.45:
            return name
        if roll < 0.75:
            return str(REGISTERS[name][0]) if self.rng.random() < 0.85 else (
                f' {REGISTERS[name][0]} ')
        return self.rng.choice(
            [str(a) for a in BAD_ADDRESSES]
            + ['', ' ', '-1', '+84', '0x54', '84.0', 'LED', 'Goal_Position', 'goal position',
               'présent', '²', '\U0001f9be', 'z' * 4000, 'led;id', '9' * 40])

    def register_value(self, register: Optional[str]) -> int:
        roll = self.rng.random()
        if register in LIMIT_FLOOR and roll < 0.6:
            return self.rng.randint(LIMIT_FLOOR[register], REGISTERS[register][4])
        if register is not None and roll < 0.75:
            low, high = REGISTERS[register][3:]
            return self.rng.randint(max(low, -2000), min(high, 2000))
        return self.rng.choice((-1, 0, 1, 886, 1194, 32768, 2 ** 31, -2 ** 31 - 1, 2 ** 63 - 1,
                                -2 ** 63))

    # the operations ---------------------------------------------------------------------------
    def run(self, operations: int) -> None:
        actions: List[Tuple[Callable[[], None], int]] = [
            (self.topic, 30), (self.set_goals, 30), (self.set_mode, 7), (self.set_torque, 7),
            (self.reboot, 2), (self.read_register, 11), (self.write_register, 13)]
        population = [action for action, _ in actions]
        weights = [weight for _, weight in actions]
        for self.step in range(operations):
            action = self.rng.choices(population, weights)[0]
            self.counts[action.__name__] = self.counts.get(action.__name__, 0) + 1
            action()

    def check_goals(self, expected: Dict[Tuple[int, str], int], what: str) -> None:
        now = self.goals()
        wrong = {key: (now[key], expected[key]) for key in expected if now[key] != expected[key]}
        assert not wrong, f'{what}: goal registers (now, expected) {wrong} {self.where()}'
        self.snapshot = now

    def tally(self, what: str, accepted: bool) -> None:
        action = what.split()[0]
        done, refused = self.outcomes.get(action, (0, 0))
        self.outcomes[action] = (done + accepted, refused + (not accepted))
        self.refused += not accepted

    def answered(self, response: Any, verdict: Optional[bool], what: str) -> None:
        if verdict is not None:
            assert response.success == verdict, (
                f'{what}: success {response.success} ({response.message!r}), expected '
                f'{verdict} {self.where()}')
        self.tally(what, response.success)
        if not response.success:
            assert response.message.strip(), f'{what}: refusal without a message {self.where()}'

    def marker(self, kind: str) -> Optional[Tuple[str, int, float]]:
        """Return a joint that takes `kind` now and a goal for it unlike the one it holds."""
        takers = [name for name in IDS if kind in MODE_KINDS[self.oracle.modes[name]]]
        if not takers:
            return None
        name = takers[0]
        register = KIND_REGISTER[kind]
        held = self.snapshot[(IDS[name], register)]
        if kind == 'position':
            value = (2000 - UNITS.zero_raw) * RAD_PER_PULSE
            raw = self.oracle.raw_goal(name, kind, value)
            if raw == held:
                value = (2100 - UNITS.zero_raw) * RAD_PER_PULSE
                raw = self.oracle.raw_goal(name, kind, value)
            return name, raw, value
        raw = 20 if held != 20 else -20
        unit = {'velocity': RAD_S_PER_RAW, 'current': A_PER_RAW, 'pwm': 1.0 / PWM_FULL_RAW}[kind]
        return name, raw, raw * unit

    def topic(self) -> None:
        kind = self.rng.choice(tuple(KIND_REGISTER))
        marker = self.marker(kind)
        if marker is None:
            return
        names = self.goal_names(kind)
        values = self.values(kind, len(names))
        verdict, written = self.oracle.goals(kind, names, values)
        self.h.publish(kind, names, values)
        # The marker follows on the same topic: once it is written, the fuzz message (delivered
        # before it, in order) was handled, and nothing else may have changed.
        marker_name, marker_raw, marker_value = marker
        self.h.publish(kind, [marker_name], [marker_value])
        register = KIND_REGISTER[kind]
        self.h.wait_reg(IDS[marker_name], register, lambda v: v == marker_raw, timeout_s=10.0)
        expected = dict(self.snapshot)
        if verdict is None:
            # Absurd values: refused or clamped; the other joints of the message either way.
            now = self.goals()
            accepted = any(now[key] != expected[key] for key in expected
                           if key != (IDS[marker_name], register))
            if accepted:
                _, written = self.oracle.goals(
                    kind, names, [max(min(v, ABSURD), -ABSURD) for v in values])
            verdict = accepted
        if verdict:
            expected.update(written)
        self.tally(f'topic_{kind}', verdict)
        expected[(IDS[marker_name], register)] = marker_raw
        self.check_goals(expected, f'topic {kind} {names!r:.200} {values!r:.200}')

    def set_goals(self) -> None:
        kind = self.rng.choice(tuple(KIND_REGISTER))
        names = self.goal_names(kind)
        values = self.values(kind, len(names))
        verdict, written = self.oracle.goals(kind, names, values)
        response = self.h.call(f'set_{kind}', name=names, value=values)
        what = f'set_{kind} {names!r:.200} {values!r:.200}'
        self.answered(response, verdict, what)
        expected = dict(self.snapshot)
        if response.success:
            if verdict is None:
                _, written = self.oracle.goals(
                    kind, names, [max(min(v, ABSURD), -ABSURD) for v in values])
            expected.update(written)
        self.check_goals(expected, what)

    def set_mode(self) -> None:
        names = self.names()
        mode = self.rng.choice(MODES) if self.rng.random() < 0.6 else self.rng.choice(
            UNKNOWN_MODES)
        verdict = bool(names) and mode in MODES and all(name in IDS for name in names)
        response = self.h.call('set_operating_mode', name=names, mode=mode)
        what = f'set_operating_mode {names!r:.200} {mode!r:.100}'
        self.answered(response, verdict, what)
        if response.success:
            for name in names:
                self.oracle.modes[name] = mode
                assert self.h.reg(IDS[name], 'operating_mode') == {
                    'current': 0, 'velocity': 1, 'position': 3, 'extended_position': 4,
                    'current_based_position': 5, 'pwm': 16}[mode], what
            self.snapshot = self.goals()   # goal = present, by design
        else:
            self.check_goals(dict(self.snapshot), what)

    def set_torque(self) -> None:
        names = self.names()
        enable = self.rng.random() < 0.6
        verdict = all(name in IDS for name in names)
        response = self.h.call('set_torque', name=names, enable=enable)
        what = f'set_torque {names!r:.200} {enable}'
        self.answered(response, verdict, what)
        if response.success:
            for name in names or list(IDS):
                assert self.h.reg(IDS[name], 'torque_enable') == int(enable), what
            self.snapshot = self.goals()   # torque on: goal = present first
        else:
            self.check_goals(dict(self.snapshot), what)

    def reboot(self) -> None:
        names = self.names(allow_empty=False)[:2]
        verdict = all(name in IDS for name in names)
        response = self.h.call('reboot', name=names, timeout_s=20.0)
        what = f'reboot {names!r:.200}'
        self.answered(response, verdict, what)
        if response.success:
            for name in names:
                assert self.h.reg(IDS[name], 'operating_mode') == {
                    'current': 0, 'velocity': 1, 'position': 3, 'extended_position': 4,
                    'current_based_position': 5, 'pwm': 16}[self.oracle.modes[name]], what
            self.snapshot = self.goals()
        else:
            self.check_goals(dict(self.snapshot), what)

    def read_register(self) -> None:
        joint = self.name() if self.rng.random() < 0.9 else ''
        key = self.register_key()
        register = self.oracle.register(key)
        verdict = joint in IDS and register is not None
        response = self.h.call('read_register', name=joint, register_name=key)
        what = f'read_register {joint!r:.100} {key!r:.100}'
        self.answered(response, verdict, what)
        if response.success and register in STATIC_REGISTERS:
            assert response.value == self.h.reg(IDS[joint], register), what
        self.check_goals(dict(self.snapshot), what)

    def write_register(self) -> None:
        joint = self.name() if self.rng.random() < 0.9 else ''
        key = self.register_key()
        value = self.register_value(self.oracle.register(key))
        verdict, register = self.oracle.write_verdict(joint, key, value)
        before = self.h.reg(IDS[joint], register) if joint in IDS and register else None
        response = self.h.call('write_register', name=joint, register_name=key, value=value)
        what = f'write_register {joint!r:.100} {key!r:.100} {value}'
        self.answered(response, verdict, what)
        expected = dict(self.snapshot)
        if joint in IDS and register is not None:
            now = self.h.reg(IDS[joint], register)
            if response.success:
                assert now == value, what
                if register in GOAL_REGISTERS:
                    expected[(IDS[joint], register)] = value
            elif register in STATIC_REGISTERS:
                assert now == before, f'{what}: refused but written {self.where()}'
        self.check_goals(expected, what)


@pytest.fixture
def h() -> Iterator[NodeHarness]:
    with NodeHarness(sim_params(JOINTS)) as harness:
        yield harness


def test_random_storm_of_commands_and_requests(h: NodeHarness) -> None:
    h.joint_states.wait(lambda m: len(m.name) == len(JOINTS))
    fuzzer = Fuzzer(h, SEED)
    fuzzer.run(OPERATIONS)
    # Every kind of operation ran, and both answers were seen many times.
    assert set(fuzzer.counts) == {'topic', 'set_goals', 'set_mode', 'set_torque', 'reboot',
                                  'read_register', 'write_register'}, fuzzer.counts
    assert OPERATIONS // 5 < fuzzer.refused < OPERATIONS * 4 // 5, fuzzer.refused
    for action, (accepted, refused) in fuzzer.outcomes.items():
        assert accepted and refused, f'{action}: {accepted} accepted, {refused} refused'
    assert len(fuzzer.outcomes) == 4 + 4 + 5, fuzzer.outcomes
    # The node survived: its cycle runs, joint_states come with every joint, commands work.
    assert h.node is not None and h.node._thread is not None and h.node._thread.is_alive()
    msg = h.joint_states.wait(lambda m: len(m.name) == len(JOINTS))
    assert sorted(msg.name) == sorted(JOINTS)
    assert all(math.isfinite(x) for x in list(msg.position) + list(msg.velocity))
    assert h.call('set_torque', name=[], enable=True).success
    for name in JOINTS:
        assert h.call('set_operating_mode', name=[name], mode='position').success
    response = h.call('set_position', name=['arm', 'spin'], value=[0.25, -0.5])
    assert response.success, response.message
    assert h.reg(IDS['arm'], 'goal_position') == UNITS.zero_raw + round(0.25 / RAD_PER_PULSE)
    assert h.reg(IDS['spin'], 'goal_position') == UNITS.zero_raw + round(-0.5 / RAD_PER_PULSE)
    h.publish('position', ['wheel'], [0.4])
    h.wait_reg(IDS['wheel'], 'goal_position',
               lambda v: v == UNITS.zero_raw + round(0.4 / RAD_PER_PULSE))
    h.joint_states.wait(lambda m: abs(m.position[m.name.index('arm')] - 0.25) < 0.02
                        if 'arm' in m.name else False, timeout_s=10.0)


def test_status_return_level_cannot_be_written(h: NodeHarness) -> None:
    # Status Return Level 0 silences every reply but PING's: the servo would vanish from the
    # node for good (and the driver's state block uses this byte to notice restarts).
    response = h.call('write_register', name='arm', register_name='status_return_level',
                      value=0)
    assert not response.success and response.message
    assert h.reg(IDS['arm'], 'status_return_level') == 2
    h.joint_states.wait(lambda m: 'arm' in m.name)
