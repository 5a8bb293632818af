"""
What the driver knows of each servo, and the small pieces every part of it shares.

The servo table (Roster) is the one state the parts share: each part is handed it, and the
fields of a Servo say which part writes them.
"""

from dataclasses import dataclass, field
import time
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple

from dxl_servo_driver import models
from dxl_servo_driver.config import JointConfig
from dxl_servo_driver.driver import state_block
from dxl_servo_driver.driver import tasks
from dxl_servo_driver.driver.clock import TickClock
from dxl_servo_driver.driver.state_block import GoalSlot, StateBlock
from dxl_servo_driver.driver.tasks import Steps
from dxl_servo_driver.errors import Refused
from dxl_servo_driver.models import modes, xm430
from dxl_servo_driver.models.units import JointFrame, Units, units_for

Log = Callable[[str], None]
BLOCK = state_block.BLOCK_SHAPE   # decodes every model's block; where it lives is Servo.block
_I = BLOCK.index
IDX_POSITION = _I['present_position']
IDX_VELOCITY = _I['present_velocity']
IDX_EFFORT = _I['effort']   # present_current, or present_load on models without current
IDX_TICK = _I['realtime_tick']
IDX_PWM = _I['present_pwm']
IDX_VOLTAGE = _I['present_input_voltage']
IDX_TEMPERATURE = _I['present_temperature']
IDX_MOVING = _I['moving']
IDX_MOVING_STATUS = _I['moving_status']
IDX_HW_ERROR = _I['hardware_error_status']
IDX_TORQUE = _I['torque_enable']
IDX_CANARY = BLOCK.canary_index
WARN_INTERVAL_S = 2.0


class ManagerError(Refused):
    """A failure the user must act on (missing servo, wrong model, port), said in one line."""


@dataclass
class Servo:
    """What the manager knows of one configured servo."""

    joint: JointConfig
    mode: str
    # The table, units and state block of the model it answered with at configure (before:
    # the configured model, or the XM430 manual's).
    model: models.Model
    units: Units
    block: StateBlock
    model_number: int = 0
    firmware_version: int = 0
    online: bool = False            # answered at configure (or since)
    state: Optional[Tuple[int, ...]] = None   # last good state block (raw)
    health_time: float = 0.0        # time of the last whole-block read (0 = health unknown)
    fresh: bool = False             # state was read in the latest cycle
    comm_errors: int = 0
    consecutive_failures: int = 0
    stale_refused: int = 0          # samples refused as older than their request
    torque_wanted: bool = False
    torque_maybe_on: bool = False   # a torque-on was sent and no torque-off confirmed since
    goal_raw: Dict[str, int] = field(default_factory=dict)   # last goal written, per register
    # The indirect goal slot mapped for its mode (None: goals are written per register); every
    # hold checks it by reading back what it wrote through it.
    goal_slot: Optional[GoalSlot] = None
    slot_refused: bool = False      # a write through the slot did not read back: never again
    last_command_s: float = 0.0     # for command_timeout
    timed_out: bool = False
    # Stopped at the end of its range in a velocity, current or PWM mode: +1 max_position,
    # -1 min_position, 0 neither (goals.Goals.check_ranges).
    at_end: int = 0
    end_goal_raw: int = 0           # the goal it was stopped with (a brake reverses it)
    limits: Dict[str, int] = field(default_factory=dict)
    homing_offset: int = 0          # the servo's Homing Offset, as last read or written
    # Whole turns (pulses) the driver adds to Present Position and takes from position goals,
    # so the joint's position stays continuous when the servo re-initialises it (torque on,
    # mode change, reboot, power cut). Always 0 in position mode (single turn).
    turn_offset: int = 0
    tick: TickClock = field(default_factory=TickClock)
    restarts: int = 0
    switching: bool = False         # a mode switch is under way: commands wait for it
    recoveries: int = 0
    last_recovery_s: float = -1e9
    status: str = ''                # what is being done to it (restoring, rebooting, ...)
    # A restore the lost port cut short: done again when the servo answers, whatever its setup
    # looks like then (the configuration may be back and the torque not yet).
    restore_due: bool = False

    @property
    def name(self) -> str:
        """Return the joint name."""
        return self.joint.name

    @property
    def servo_id(self) -> int:
        """Return the servo id."""
        return self.joint.servo_id

    def joint_pulses(self, raw: int) -> int:
        """Return a Present Position value in the joint's continuous frame (turns kept)."""
        return raw + self.turn_offset

    def last_joint_pulses(self) -> Optional[int]:
        """Return the last position read, in the joint's frame; None if never read."""
        return self.state[IDX_POSITION] + self.turn_offset if self.state is not None else None

    def goal_position_range(self) -> Tuple[int, int]:
        """Return the Goal Position values taken now: its limits (position mode), else all."""
        if self.mode in modes.SINGLE_TURN and self.limits:
            return self.limits['min_position_limit'], self.limits['max_position_limit']
        return -self.model.extended_position_limit, self.model.extended_position_limit

    def joint_position_range(self) -> Tuple[float, float]:
        """Return the lowest and highest position the joint may be sent to (joint units)."""
        ends = sorted(self.position_rad(raw) for raw in self.goal_position_range())
        low, high = ends
        configured_low, configured_high = self.joint.position_limits()
        if configured_low is not None:
            low = max(low, configured_low)
        if configured_high is not None:
            high = min(high, configured_high)
        return low, high

    def position_rad(self, raw: int) -> float:
        """Return a position register value (present or goal) as the joint's angle (rad)."""
        return self.units.position_to_rad(raw + self.turn_offset)

    def present_rad(self) -> Optional[float]:
        """Return the joint's angle read in the latest cycle (rad); None if not read then."""
        if self.state is None or not self.fresh:
            return None
        return self.position_rad(self.state[IDX_POSITION])

    def set_model(self, table: models.Model) -> None:
        """Take the table, units and state block of a model."""
        self.model = table
        self.units = units_for(table, self.joint.torque_constant_nm_per_a, frame_of(self.joint))
        self.block = state_block.state_block(table, self.units.effort_register)

    @classmethod
    def of(cls, joint: JointConfig) -> 'Servo':
        """Return the servo of a joint, with its configured model's table (or the manual's)."""
        table = joint.model or models.model_for(xm430.MODEL_NUMBER)
        units = units_for(table, joint.torque_constant_nm_per_a, frame_of(joint))
        return cls(joint, joint.operating_mode, table, units,
                   state_block.state_block(table, units.effort_register))


def frame_of(joint: JointConfig) -> JointFrame:
    """Return the frame a joint's configuration gives it (offset, reverse, ratio)."""
    return JointFrame(joint.offset, joint.reverse, joint.ratio)


class Roster:
    """
    The configured servos: by name, in configuration order, by id.

    `joints` are the joints' servos, in the order of joint_states; `order` is every servo on
    the bus, the second servos of joints that have one (`secondary_id`) after them: what is
    read, configured, enabled and switched off. `secondary` maps a joint to its second servo.
    """

    def __init__(self, joints: Sequence[JointConfig]) -> None:
        self.joints: List[Servo] = [Servo.of(joint) for joint in joints]
        self.secondary: Dict[str, Servo] = {
            joint.name: Servo.of(joint.secondary()) for joint in joints
            if joint.secondary_id is not None}
        self.order: List[Servo] = self.joints + list(self.secondary.values())
        self.by_name: Dict[str, Servo] = {servo.name: servo for servo in self.order}
        self.by_id: Dict[int, Servo] = {servo.servo_id: servo for servo in self.order}

    def with_secondaries(self, servos: Sequence[Servo]) -> List[Servo]:
        """Return the servos and the second servos of their joints (what moves together)."""
        out = list(servos)
        for servo in servos:
            second = self.secondary.get(servo.name)
            if second is not None and second not in out:
                out.append(second)
        return out

    def active(self) -> List[Servo]:
        """Return the servos that answered at configure."""
        return [servo for servo in self.order if servo.online]


@dataclass
class PortState:
    """Whether the adapter is lost (written by the port watch, read by whoever refuses)."""

    lost: bool = False
    error: str = ''


@dataclass
class Result:
    """The answer to a request: success, a message meant for a person, and a value if any."""

    success: bool
    message: str
    value: Any = None


class Throttle:
    """At most one message per key per interval."""

    def __init__(self, log: Log, interval_s: float = WARN_INTERVAL_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._log = log
        self._interval_s = interval_s
        self._clock = clock
        self._last: Dict[str, float] = {}

    def __call__(self, key: str, message: str) -> None:
        """Log message unless the same key was logged within the interval."""
        now = self._clock()
        last = self._last.get(key)
        if last is not None and now - last < self._interval_s:
            return
        self._last[key] = now
        self._log(message)


class StaleGuard:
    """Refuses samples older than their request (a late reply of an earlier one), counted."""

    def __init__(self, warn: Log, clock: Callable[[], float] = time.monotonic) -> None:
        self._warn_throttled = Throttle(warn, clock=clock)
        self.refused = 0

    def check(self, servo: Servo, tick: int, sent_s: float, received_s: float) -> bool:
        """Return True when the sample's Realtime Tick dates it after its request."""
        if servo.tick.check(tick, sent_s, received_s):
            return True
        self.refuse(servo)
        return False

    def refuse(self, servo: Servo) -> None:
        """Count and say a sample its TickClock refused (it answers an earlier request)."""
        servo.fresh = False
        servo.stale_refused += 1
        self.refused += 1
        self._warn_throttled(f'stale:{servo.name}',
                             f'joint {servo.name!r}: refused a reply older than its request '
                             '(a late reply of an earlier one); nothing published for it')


def clamp_position(servo: Servo, raw: int) -> int:
    """Return a Goal Position within the range the servo takes now (goal_position_range)."""
    low, high = servo.goal_position_range()
    return min(max(raw, low), high)


def run(steps: Steps) -> None:
    """Run an activity's steps to the end, at once (a synchronous caller; waits are slept)."""
    for wake_s in steps:
        if wake_s is not None:
            tasks.wait(wake_s)
