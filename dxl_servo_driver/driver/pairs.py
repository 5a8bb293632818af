"""
Joints on two servos (`<joint>.secondary_id`): how far apart they are; both off when they fight.

Both servos get every goal in the same sync write (driver/goals), each through its own frame;
here, after every read, the two positions are compared in joint units. Beyond the joint's
secondary_tolerance: a warning and a WARN in /diagnostics. Beyond twice it: both torque off at
once and an ERROR, because a shaft that slipped on one side, a horn on the wrong spline or a
sign wrong in the file would have the servos fight each other through the joint. The joint
stays off (every trajectory and goal on it ends: manager.joint_trouble) until torque is enabled
again on it.

A second servo reversed in firmware (Drive Mode bit 0, its own `secondary_registers`, as
Interbotix's shadows) needs nothing here: its Goal and Present Position count the other way round
its horn (the e-manual), so mounted mirrored it counts the joint's way; with secondary_reverse
false its frame takes the same goals as the first servo's and its Present Position compares as
it reads (test/driver/test_interbotix.py: its horn mirrored, the two registers equal, the gap
near 0). With secondary_reverse as well it would be mirrored twice, sent against the joint and
switched off by the check below as soon as the two part by twice the tolerance.

Why not the X series' Secondary ID register (12): a follower answers nothing and mirrors the
primary's packet as it is, so the driver could neither confirm a write reached it, nor give it
its own offset, nor read it to compare; a second servo of our own is read, written and watched
like the first.
"""

from typing import Callable, Dict, List, Sequence

from dxl_servo_driver.driver.context import Context
from dxl_servo_driver.driver.servo import IDX_POSITION, Result, Throttle

__all__ = ['Pairs']

# After a pair is enabled again, how long its two servos have to agree before it is judged.
SETTLE_S = 1.0


class Pairs:
    """The two-servo joints of one bus and what their last samples said."""

    def __init__(self, ctx: Context, torque_off: Callable[[Sequence[str]], Result]) -> None:
        self._ctx = ctx
        self._torque_off = torque_off
        self._warn = Throttle(ctx.log.warn, clock=ctx.clock)
        # Per joint: how far apart its servos were at the last sample both gave (joint units).
        self.apart: Dict[str, float] = {}
        # Per joint switched off for disagreeing: why.
        self.tripped: Dict[str, str] = {}
        # Per joint enabled again after that: until when the two may still be coming together.
        self._settling: Dict[str, float] = {}

    def check(self) -> None:
        """Compare each pair on this cycle's samples; switch both off when they fight."""
        roster = self._ctx.roster
        for name, second in roster.secondary.items():
            first = roster.by_name[name]
            if not (first.fresh and second.fresh) or first.state is None or second.state is None:
                continue
            gap = abs(first.position_rad(first.state[IDX_POSITION])
                      - second.position_rad(second.state[IDX_POSITION]))
            self.apart[name] = gap
            tolerance = first.joint.secondary_tolerance
            settling = self._settling.get(name)
            if settling is not None:
                if gap <= tolerance or self._ctx.clock() >= settling:
                    del self._settling[name]
                else:
                    continue   # the second servo is on its way to the first (set_torque)
            if name in self.tripped or gap <= tolerance:
                continue
            if gap <= 2.0 * tolerance:
                self._warn(f'pair:{name}', f'joint {name!r}: its two servos disagree by '
                           f'{gap:.4f} (secondary_tolerance {tolerance:g})')
                continue
            why = (f'its two servos disagreed by {gap:.4f}, beyond twice secondary_tolerance '
                   f'{tolerance:g}: both torque off')
            self.tripped[name] = why
            result = self._torque_off([name])
            self._ctx.log.error(f'joint {name!r}: {why}' + (
                '' if result.success else f' - FAILED: {result.message}') +
                ' (enable its torque again once the joint is sound)')

    def clear(self, names: Sequence[str]) -> None:
        """
        Forget why joints were switched off (their torque was enabled again).

        Their two servos get SETTLE_S to come back together (the second goes to where the first
        is) before a disagreement switches them off again.
        """
        for name in names or list(self.tripped):
            if self.tripped.pop(name, None) is not None:
                self._settling[name] = self._ctx.clock() + SETTLE_S

    def trouble(self, name: str) -> str:
        """Return why a joint is off for its pair ('' when it is not)."""
        return self.tripped.get(name, '')

    def facts(self, name: str) -> List[str]:
        """Return the pair's state as (level, text) for diagnostics: empty for a single servo."""
        if name not in self._ctx.roster.secondary:
            return []
        if name in self.tripped:
            return ['error', self.tripped[name]]
        gap = self.apart.get(name)
        if gap is not None and gap > self._ctx.roster.by_name[name].joint.secondary_tolerance:
            return ['warn', f'its two servos disagree by {gap:.4f}']
        return ['ok', f'{gap:.4f}' if gap is not None else 'unknown']
