"""
Commands given as joint states (what ros2_control's topic bridge sends).

Which goal each joint takes from the position, velocity and effort arrays, by its operating
mode. No bus, no ROS.
"""

import math
from typing import Dict, List, Mapping, Sequence, Tuple

from dxl_servo_driver.errors import BadRequest
from dxl_servo_driver.models.modes import BY_NAME as MODES

__all__ = ['JointStateCommandError', 'split_joint_state']


class JointStateCommandError(BadRequest):
    """A joint-state command refused whole; the message says why."""


def split_joint_state(names: Sequence[str], arrays: Mapping[str, Sequence[float]],
                      modes: Mapping[str, str], torque_constants: Mapping[str, float]
                      ) -> Dict[str, Tuple[List[str], List[float]]]:
    """
    Return {goal kind: (joint names, values in the goal's SI unit)} for a joint-state command.

    arrays maps 'position', 'velocity', 'effort' to their arrays; an empty array is not given
    (the bridge leaves out what it does not command), a given one has one value per name.
    Effort becomes current through the joint's torque constant. Refused whole: an unknown
    joint, a joint named twice, an array of the wrong length, a NaN or infinite value, a joint
    that gets nothing its mode takes.
    """
    if not names:
        raise JointStateCommandError('no joint names')
    if len(set(names)) != len(names):
        raise JointStateCommandError('a joint is named twice')
    given = {key: list(values) for key, values in arrays.items() if len(values)}
    if not given:
        raise JointStateCommandError('no position, velocity or effort values')
    for key, values in given.items():
        if len(values) != len(names):
            raise JointStateCommandError(f'{len(values)} {key} values for {len(names)} names: '
                                         'the arrays are index-aligned with name')
    goals: Dict[str, Tuple[List[str], List[float]]] = {}
    for index, name in enumerate(names):
        mode = modes.get(name)
        if mode is None:
            raise JointStateCommandError(f'unknown joint {name!r}')
        taken = 0
        for source, kind in MODES[mode].joint_state:
            if source not in given:
                continue
            value = given[source][index]
            if not math.isfinite(value):
                raise JointStateCommandError(f'joint {name!r}: {source} {value} is not a finite '
                                             'number')
            if source == 'effort':
                value = value / torque_constants[name]
            joints, values = goals.setdefault(kind, ([], []))
            joints.append(name)
            values.append(value)
            taken += 1
        if not taken:
            wanted = ' or '.join(source for source, _ in MODES[mode].joint_state) or 'nothing'
            raise JointStateCommandError(
                f'joint {name!r} is in {mode} mode, which takes {wanted} from a joint-state '
                f'command; this one gives {", ".join(sorted(given))}')
    return goals
