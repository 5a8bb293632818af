"""
The operating modes: one table, and everything the package knows of modes derived from it.

Each mode (XM430 manual, Operating Mode (11)) has the value the register takes; the kind of
goal that holds a joint in it (written at every hold, and what a streamed command falls back to
zero in); the command kinds it takes (a current command of a current-based position joint is
its current limit); its goal registers in the order of the goal slot (what changes most often
first, so the shortest write carries it); what it takes from a joint-state command (effort
becomes current through the torque constant); and whether it is a position mode (the joint is
held at its present position, and Present Position is re-initialised within one turn at torque
on and at every mode change: the driver keeps the whole turns). Which modes a model has is the
model's (models.Model.modes): a subset of these names.
"""

from dataclasses import dataclass
from typing import Dict, FrozenSet, Tuple

# The command kinds and the goal register each one writes.
GOAL_REGISTERS: Dict[str, str] = {'position': 'goal_position', 'velocity': 'goal_velocity',
                                  'current': 'goal_current', 'pwm': 'goal_pwm'}
COMMAND_KINDS: Tuple[str, ...] = tuple(GOAL_REGISTERS)


@dataclass(frozen=True)
class Mode:
    """One operating mode."""

    name: str
    number: int
    holding: str                          # the command kind that holds the joint
    commands: Tuple[str, ...]             # the command kinds it takes
    slot: Tuple[str, ...]                 # its goal registers, in goal-slot order
    joint_state: Tuple[Tuple[str, str], ...]   # (JointState array, command kind) it takes
    position: bool                        # held at present position; turns kept
    single_turn: bool = False             # within the position limits, no turns kept

    @property
    def holding_register(self) -> str:
        """Return the goal register that holds the joint (goal = present, or zero)."""
        return GOAL_REGISTERS[self.holding]


MODES: Tuple[Mode, ...] = (
    Mode('current', 0, 'current', ('current',), ('goal_current',), (('effort', 'current'),),
         position=False),
    Mode('velocity', 1, 'velocity', ('velocity',), ('goal_velocity',),
         (('velocity', 'velocity'),), position=False),
    Mode('position', 3, 'position', ('position',), ('goal_position',),
         (('position', 'position'),), position=True, single_turn=True),
    Mode('extended_position', 4, 'position', ('position',), ('goal_position',),
         (('position', 'position'),), position=True),
    # The effort (current) of a current-based position joint is its current limit: a gentle grip.
    Mode('current_based_position', 5, 'position', ('position', 'current'),
         ('goal_position', 'goal_current'), (('position', 'position'), ('effort', 'current')),
         position=True),
    Mode('pwm', 16, 'pwm', ('pwm',), ('goal_pwm',), (), position=False),
)
BY_NAME: Dict[str, Mode] = {mode.name: mode for mode in MODES}
BY_NUMBER: Dict[int, Mode] = {mode.number: mode for mode in MODES}
NAMES: Tuple[str, ...] = tuple(BY_NAME)
POSITION_MODES: FrozenSet[str] = frozenset(mode.name for mode in MODES if mode.position)
POSITION_NUMBERS: FrozenSet[int] = frozenset(mode.number for mode in MODES if mode.position)
# Single-turn: goals within the position limits, Present Position within one turn (no turns
# kept by the driver), and a Homing Offset beyond +-1024 ignored (the XM430 manual).
SINGLE_TURN: FrozenSet[str] = frozenset(mode.name for mode in MODES if mode.single_turn)


def numbers(*names: str) -> Dict[str, int]:
    """Return {name: register value} of these modes (a model's modes), in table order."""
    unknown = set(names) - set(BY_NAME)
    if unknown:
        raise KeyError(f'no operating mode {sorted(unknown)}')
    return {mode.name: mode.number for mode in MODES if mode.name in names}


# What a change of mode resets on the servo (the XM430 manual, Operating Mode, note 1): the
# profiles, goal PWM and goal current (to their limits) and the gains. The simulator does it;
# the driver gives back the configured values after every mode switch.
RESET_GAINS: Tuple[str, ...] = (
    'velocity_i_gain', 'velocity_p_gain', 'position_d_gain', 'position_i_gain',
    'position_p_gain', 'feedforward_2nd_gain', 'feedforward_1st_gain')
RESET_BY_MODE_CHANGE: Tuple[str, ...] = (
    'profile_velocity', 'profile_acceleration', 'goal_pwm', 'goal_current', *RESET_GAINS)
