"""
A Protocol 1.0 bus behind a misbehaving adapter: no stale sample, no wrong register value.

AX-12A servos (no Realtime Tick: their samples cannot be dated by the servo) on `port: sim`
through the fault fixture cutting replies by Protocol 1.0 framing: late copies of earlier
replies, duplicates, truncated replies, drops and the adapter's echo. What stands between them
and a stale sample is the bus (a reply is taken only for its own request; on a suspicious bus
it reads on to the deadline, so two answers from one id are refused) and the cycle's length
tag (a late reply of another cycle has another length). Every published wheel position is
checked against the simulator's own record of where the wheel was.
"""

import time
from typing import List

from dxl_servo_driver.models import model_for
from dxl_servo_driver.models.units import units_for
from dxl_servo_driver.sim.fault_engine import Faults
from node_harness import faulty_harness, sim_params
import pytest
from truth import Messages, stamp_s, Truth

AX = model_for(12)
UNITS = units_for(AX)
JOINTS = {
    'arm': {'id': 1, 'operating_mode': 'position'},
    'wheel': {'id': 2, 'operating_mode': 'velocity'},
    'hand': {'id': 3, 'operating_mode': 'position'},
}
WHEEL_RAD_S = 5.0   # about a pulse per ms: a sample a cycle late is 10 pulses off
SAMPLES = 50        # wheel samples judged under each fault profile, at least
PROFILES = {
    'late and duplicated replies': Faults(late_probability=0.05, late_ms=(1.0, 30.0),
                                          duplicate_probability=0.05),
    'truncated, noisy and dropped replies': Faults(truncate_probability=0.05,
                                                   noise_probability=0.05,
                                                   drop_probability=0.05),
    'echo': Faults(echo=True),
    'everything': Faults(echo=True, late_probability=0.03, duplicate_probability=0.03,
                         truncate_probability=0.03, noise_probability=0.03,
                         drop_probability=0.03),
}


def stale_samples(messages: List, truth: Truth, after_s: float, before_s: float,
                  why: List[str]) -> tuple[int, int]:
    """Count wheel samples the servo no longer held 2 ms before their stamp (or never held)."""
    checked = stale = 0
    for msg in messages:
        stamp = stamp_s(msg)
        names = list(msg.name)
        if 'wheel' not in names or not after_s < stamp < before_s:
            continue
        raw = UNITS.position_from_rad(msg.position[names.index('wheel')])
        age = truth.age_s(raw, stamp, 1)
        checked += 1
        if age is None or age > 0.002:
            stale += 1
            why.append(f'stamp {stamp:.4f}: raw {raw}, '
                       + ('never held' if age is None else f'held until {age * 1000:.1f} ms '
                          'before the stamp')
                       + f'; held in the 20 ms before: {truth.between(stamp - 0.02, stamp)}')
    return checked, stale


@pytest.mark.parametrize('profile', sorted(PROFILES))
def test_a_protocol_1_bus_publishes_no_stale_sample(profile: str) -> None:
    params = sim_params({name: {**keys, 'model': 'AX-12A'} for name, keys in JOINTS.items()},
                        protocol=1.0)
    with faulty_harness(params, Faults(), seed=11, protocol=1) as h:
        assert h.node is not None
        port = h.node.manager.port
        assert h.call('set_velocity', name=['wheel'], value=[WHEEL_RAD_S]).success
        h.joint_states.wait(lambda m: len(m.name) == 3
                            and abs(m.velocity[1] - WHEEL_RAD_S) < 0.3, timeout_s=10.0)
        messages = Messages(h)
        truth = Truth(h, 2)
        faulted_s = time.time()
        port.engine.set(**vars(PROFILES[profile]))
        wrong_reads = []

        def faulted_samples() -> int:
            return sum(1 for msg in list(messages.items)
                       if 'wheel' in msg.name and stamp_s(msg) > faulted_s)
        # Three seconds of faults at least, and enough samples under them (a busy machine
        # publishes fewer a second: the phase lasts until they are there).
        deadline = time.monotonic() + 3.0
        give_up = time.monotonic() + 30.0
        while time.monotonic() < deadline or faulted_samples() < SAMPLES:
            assert time.monotonic() < give_up, f'{faulted_samples()} samples in 30 s of faults'
            # Two one-byte registers of different values: a late reply to one read before
            # would be taken for the other.
            for register, value in (('id', 2), ('cw_angle_limit', 0)):
                response = h.call('read_register', name='wheel', register_name=register)
                if response.success and response.value != value:
                    wrong_reads.append(f'{register}={response.value}')
        port.engine.clear()
        cleared_s = time.time()
        truth.stop()
        assert h.node._thread is not None and h.node._thread.is_alive()
        assert h.node.cycle_failure is None and h.node.cycle_errors == 0
        why: List[str] = []
        checked, stale = stale_samples(messages.items, truth, faulted_s, cleared_s, why)
        assert checked >= SAMPLES and stale == 0, (checked, stale, why[:5])
        assert wrong_reads == []
        assert sum(port.stats.as_dict().values()) > 0, port.stats
        # Goals still go out in Protocol 1.0.
        h.publish('position', ['arm'], [0.3])
        h.wait_reg(1, 'goal_position', lambda v: v == UNITS.position_from_rad(0.3))
