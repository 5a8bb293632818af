"""
The driver's configuration: the one table of parameters, and their validation.

PARAMS (top level) and JOINT_PARAMS (`<joint>.<key>`) say of each parameter its type, default,
unit, range, description and when it is taken (at configure, at run time, only at a restart):
validation, the ROS declarations (`ros2 param describe`), the runtime checks and the tables of
docs/parameters.md (tools/param_table.py) all read them. `<joint>.registers.<name>` is the open
family of raw register values, judged against the servo's control table.

validate() takes the flat parameter dictionary a ROS parameter file gives (`joints`,
`<joint>.id`, `<joint>.registers.<name>`, ...) and returns a DriverConfig, or raises ConfigError
naming the offending key. It runs before the bus is touched, so a bad file never moves a servo.

The module is long (~630 lines) because the table is: about half of it is the parameters' own
descriptions, which docs/parameters.md and `ros2 param describe` print; splitting the table from
the checks that read it would put one fact in two places.
"""

import dataclasses
from dataclasses import dataclass, field
import math
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple

from dxl_servo_driver import models
from dxl_servo_driver.errors import ConfigurationError
from dxl_servo_driver.models import modes, xm430
from dxl_servo_driver.models import registers
from dxl_servo_driver.protocol import MAX_ID
import yaml  # type: ignore[import-untyped]


class ParameterFileError(ConfigurationError):
    """A parameter file ROS could not read; the message names the file and, if any, the key."""


class ConfigError(ConfigurationError):
    """An invalid configuration; key names the parameter at fault."""

    def __init__(self, key: str, message: str) -> None:
        super().__init__(f'parameter {key!r}: {message}')
        self.key = key


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: type, default, unit, description, range, and when it is taken."""

    name: str
    kind: type
    default: Any
    description: str
    unit: str = ''
    minimum: Optional[float] = None
    maximum: Optional[float] = None
    choices: Tuple[Any, ...] = ()
    runtime: bool = False      # changes while the node runs (else read at configure)
    threshold: bool = False    # a diagnostics threshold, checked against its pair
    restart: bool = False      # fixes which parameters exist: changed only by a restart
    shown: str = ''            # the default as the docs say it, when it is not a value
    only_for: str = ''         # a joint key only a joint with this key set has (gripper)
    noun: str = ''             # what an error calls a value of it ('unknown <noun> ...')


# Every baud some supported model takes (configure refuses one the servo's model lacks).
BAUDS = tuple(sorted({bps for model in models.ALL_MODELS for bps in model.bauds.values()}))
PROTOCOLS = (1.0, 2.0)
MISSING_SERVO_POLICIES = ('refuse', 'skip')
READ_MODES = ('sync', 'fast_sync', 'auto')
WRITE_MODES = ('indirect', 'per_register')

PARAMS: Tuple[ParamSpec, ...] = (
    ParamSpec('port', str, '/dev/ttyUSB0',
              'Serial device of the bus (e.g. /dev/ttyUSB0, /dev/ttyDXL), or "sim" for an '
              'in-process simulated servo per joint.'),
    ParamSpec('baud_rate', int, 57600, 'Baud rate of the bus (every servo must use it).',
              'bit/s', choices=BAUDS),
    ParamSpec('protocol', float, 2.0,
              'DYNAMIXEL protocol of the servos on the bus; a joint may speak the other one '
              '(`<joint>.protocol`): each group is read its own way in every cycle.',
              choices=PROTOCOLS),
    ParamSpec('loop_rate', float, 100.0,
              'Cycles per second: one packed read of every servo, publish, pending goals '
              'written. Above what the bus can carry, the node runs as fast as the bus allows.',
              'Hz', 0.1, 10000.0, runtime=True),
    ParamSpec('state_rate', float, 10.0, 'Rate of ~/servo_states.', 'Hz', 0.0, 1000.0,
              runtime=True),
    ParamSpec('joints', list, [], 'Joint names, in the order of joint_states.', restart=True,
              shown='(required)'),
    ParamSpec('torque_on_start', bool, True, 'Torque on when the node activates.'),
    ParamSpec('torque_off_on_shutdown', bool, True,
              'Torque off when the node deactivates or shuts down.'),
    ParamSpec('command_timeout', float, 0.0,
              'Velocity, current and PWM goals fall back to zero when no command arrived for '
              'this long (0 = off).', 's', 0.0, 3600.0, runtime=True),
    ParamSpec('autostart', bool, True, 'Configure and activate at start (lifecycle).'),
    ParamSpec('trace', str, '',
              'Bus trace file: every frame sent and received, with its time (monotonic us), '
              'one line each; `dxl trace FILE` decodes it. Written from configure on (a new '
              'file each time). Empty: off.'),
    ParamSpec('latency_timer', float, 16.0,
              'Latency timer of the USB adapter (16 ms is the Linux FTDI default; 1 ms with our '
              'udev rule). Used for reply deadlines and the bus-rate report. Checked at '
              "configure: where Linux says the adapter's (a USB serial device), that one is "
              'used; elsewhere replies that come later than it allows are timed and the timer '
              'they imply is used; either with a warning.', 'ms', 0.0, 255.0),
    ParamSpec('ping_retries', int, 3,
              'Pings per servo at configure before it counts as missing; also the attempts of '
              'every other configure and service transaction. Configure and activate also keep '
              'trying each for a second, for a busy computer.',
              '', 1, 100),
    ParamSpec('missing_servo', str, 'refuse',
              'A configured servo that does not answer at configure: refuse to start, or skip it '
              'and start without it.', choices=MISSING_SERVO_POLICIES),
    ParamSpec('read_retries', int, 1,
              'A servo whose reply was lost or corrupted is read again on its own this many times '
              'within the cycle, while the cycle has time left.', '', 0, 5),
    ParamSpec('read_mode', str, 'sync',
              'How the state is read each cycle: one SYNC_READ (a status packet per servo), one '
              'FAST_SYNC_READ (one status packet for all; X-series firmware 45+, X330 46+), or '
              'auto: fast when every servo has it, back to sync (until the next configure) when '
              'three fast reads in a row bring nothing back while the servos answer their '
              'one-off retries.', choices=READ_MODES),
    ParamSpec('write_mode', str, 'indirect',
              'How goals go out each cycle: indirect = one sync write at the goal slot of each '
              'servo (indirect entries mapped to the goal registers of its mode), whatever the '
              'mix of modes; a servo whose firmware does not apply a slot write (checked at '
              'every hold) or has no room for one (X330 before firmware 53) is written per '
              'register. per_register = one sync write per goal register.', choices=WRITE_MODES),
    ParamSpec('hardware_error_recovery', bool, False,
              'On a latched hardware error (overload, overheating, ...), reboot that servo alone '
              'and restore its configuration and torque. Off: report it and leave it to you.'),
    ParamSpec('recovery_interval', float, 5.0,
              'Minimum time between two recovery reboots of the same servo.', 's', 0.1, 3600.0),
    ParamSpec('goal_tolerance', float, 0.05,
              'How close to its last point each joint of a trajectory must come (within '
              'goal_time_tolerance after it) for the trajectory to succeed; farther is reported '
              '(log, /diagnostics, the action result). 0: not checked. A joint may set its own.',
              'rad', 0.0, 10.0, runtime=True),
    ParamSpec('goal_time_tolerance', float, 0.5,
              'How long after its last point a trajectory may take to come within its goal '
              'tolerances (an action goal may say otherwise).', 's', 0.0, 60.0, runtime=True),
    ParamSpec('action_monitor_rate', float, 20.0,
              'Rate of the feedback of follow_joint_trajectory and gripper_cmd goals.', 'Hz',
              1.0, 1000.0, runtime=True),
    ParamSpec('cycle_driver', str, 'thread',
              'What runs the bus cycle: its own thread (never waits on the executor) or a ROS '
              'timer in the executor (docs/performance.md: how the cycle is driven).',
              choices=('thread', 'timer')),
    ParamSpec('executor', str, 'events',
              "The ROS executor: rclpy's EventsExecutor (lower command latency and CPU in the "
              'benchmark) or its SingleThreadedExecutor.', choices=('single', 'events')),
    ParamSpec('temperature_warn', float, 70.0, 'Diagnostics WARN above this temperature.', 'degC',
              0.0, 100.0, runtime=True, threshold=True),
    ParamSpec('temperature_error', float, 78.0, 'Diagnostics ERROR above this temperature.',
              'degC', 0.0, 100.0, runtime=True, threshold=True),
    ParamSpec('voltage_low', float, 10.0, 'Diagnostics WARN below this input voltage.', 'V',
              0.0, 30.0, runtime=True, threshold=True),
    ParamSpec('voltage_high', float, 14.8, 'Diagnostics WARN above this input voltage.', 'V',
              0.0, 30.0, runtime=True, threshold=True),
    # A follower (docs/teleoperation.md): its joints copy a leader node's joint_states.
    ParamSpec('follow.topic', str, '',
              "A leader node's joint_states (e.g. /leader/joint_states): this node follows it in "
              'its own cycle, each joint copying `<joint>.follow`. Empty: not a follower.',
              shown='(empty)'),
    ParamSpec('follow.engaged', bool, True,
              'Follow from the start (else from `~/follow` true); `~/follow` false stops it.'),
    ParamSpec('follow.timeout', float, 0.25,
              'A leader message older than this (by its stamp or its receipt) is stale: the '
              'follower holds where it is until fresh ones come, then ramps back.', 's',
              0.01, 60.0),
    ParamSpec('follow.max_step', float, 0.05,
              "The most a follower joint's goal moves in one cycle (LeRobot's "
              'max_relative_target): a faster leader is followed at this pace.', 'rad',
              1e-4, 10.0),
    ParamSpec('follow.ramp_velocity', float, 0.5,
              'Engaging (or resuming after a stale leader) with a joint farther than '
              'follow.engage_tolerance from the leader moves it there at this speed.', 'rad/s',
              1e-3, 100.0),
    ParamSpec('follow.engage_tolerance', float, 0.05,
              'How close to the leader a joint must be to follow it at once, without a ramp.',
              'rad', 0.0, 10.0),
    ParamSpec('follow.block_error', float, 0.5,
              'A followed joint (not a gripper) whose position stays farther than this from its '
              'goal for follow.block_time is blocked: the follower stops and holds. 0: never.',
              'rad', 0.0, 100.0),
    ParamSpec('follow.block_time', float, 1.0, 'See follow.block_error.', 's', 0.01, 60.0),
)
PARAMS_BY_NAME: Dict[str, ParamSpec] = {spec.name: spec for spec in PARAMS}
RUNTIME_PARAMS: Tuple[str, ...] = tuple(spec.name for spec in PARAMS if spec.runtime)
THRESHOLDS: Tuple[str, ...] = tuple(spec.name for spec in PARAMS if spec.threshold)

# `<joint>.<key>`, one set per joint; all read at configure.
JOINT_PARAMS: Tuple[ParamSpec, ...] = (
    ParamSpec('id', int, None, "Dynamixel id of the joint's servo.", '', 0, MAX_ID,
              shown='(required)'),
    ParamSpec('operating_mode', str, 'position',
              "Operating mode at start (the XM430 manual's modes 0, 1, 3, 4, 5, 16).",
              choices=modes.NAMES, noun='operating mode'),
    ParamSpec('protocol', float, None,
              "The protocol this joint's servo speaks, when not the bus's. Unset: the bus's, "
              'or 1.0 when `model` names a Protocol 1.0 model (AX, RX, EX, MX on 1.0 firmware).',
              choices=PROTOCOLS, shown="the bus's"),
    ParamSpec('model', str, '',
              'The model the servo must be (a name such as XL430-W250, or its number); another '
              'is refused at configure. Empty: any supported model.', shown='(any supported)'),
    ParamSpec('torque_constant', float, None,
              'joint_states.effort = current x this. Unset: the datasheet stall torque over '
              'stall current of the model the servo answered with (the XM430 manual: 4.1 N*m '
              'at 2.3 A = 1.783); `ros2 param get` shows the value in use once configured.',
              'N*m/A', shown="the model's datasheet"),
    ParamSpec('offset', float, 0.0,
              "The joint's 0 in the servo's radians (raw 2048 = 0 rad): "
              'joint = (-1 if reverse else 1) * ratio * (servo - offset).', 'rad', -1e4, 1e4),
    ParamSpec('reverse', bool, False, 'The joint turns against the servo.'),
    ParamSpec('ratio', float, 1.0,
              'Joint units per servo radian: a 1:3 gearbox 1/3; a rack and pinion in m/rad (the '
              "joint's units are then m, m/s and N).", '', 1e-6, 1e6),
    ParamSpec('min_position', float, None,
              'The lowest position the joint is sent to (joint units): beyond is refused; in a '
              "single-turn position mode written to the servo's Min/Max Position Limit; in "
              'velocity, current and PWM modes the joint is stopped there.',
              '', -1e6, 1e6, shown="the servo's limit"),
    ParamSpec('max_position', float, None, 'The highest position the joint is sent to (as '
              'min_position).', '', -1e6, 1e6, shown="the servo's limit"),
    ParamSpec('secondary_id', int, -1,
              'A second servo on the same joint (a shoulder driven from both sides): it gets '
              'every goal in the same sync write, is configured, enabled, switched and disabled '
              'with the first, and is watched against it. -1: none.', '', -1, MAX_ID),
    ParamSpec('secondary_reverse', bool, False,
              "The second servo's Present Position counts against the joint's (mounted "
              'mirrored, its Drive Mode not reversing it). A mirrored servo whose Drive Mode '
              'bit 0 reverses it in firmware (`secondary_registers.drive_mode: 1`, as '
              "Interbotix's shadows) already counts with the joint: leave this false.",
              only_for='secondary_id'),
    ParamSpec('secondary_offset', float, None,
              "The joint's 0 in the second servo's radians.", 'rad', -1e4, 1e4,
              shown='offset', only_for='secondary_id'),
    ParamSpec('secondary_tolerance', float, 0.1,
              'How far the two servos of a joint may disagree (joint units): beyond, '
              'diagnostics WARN; beyond twice this, both torque off with an ERROR (a slipping '
              'shaft must not fight itself).', '', 1e-4, 100.0, only_for='secondary_id'),
    ParamSpec('path_tolerance', float, 0.0,
              'How far the joint may be from the setpoint while a trajectory runs before it '
              'ends and holds (an action goal: PATH_TOLERANCE_VIOLATED; the goal may say '
              'otherwise). 0: not checked.', 'rad (m)', 0.0, 10.0),
    ParamSpec('goal_tolerance', float, 0.0,
              "This joint's goal tolerance for trajectories (see the top-level goal_tolerance, "
              'which 0 leaves in force).', 'rad (m)', 0.0, 10.0),
    ParamSpec('gripper', bool, False,
              'A gripper (current_based_position only): ~/gripper commands, grasp detection.'),
    ParamSpec('gripper_open', float, 0.0,
              'The position of ratio 0 in ~/gripper commands. With gripper_closed it is the '
              "gripper's travel: a goal beyond it, on any path, is refused.",
              'rad (m)', only_for='gripper'),
    ParamSpec('gripper_closed', float, 0.0, 'The position of ratio 1 in ~/gripper commands '
              '(not gripper_open).', 'rad (m)', only_for='gripper'),
    ParamSpec('torque', bool, True,
              'false: a passive joint (a leader arm moved by hand): read and published, its '
              'mode and EEPROM set up, never torqued (not at activate, whatever '
              'torque_on_start, nor after a restart, reboot or reconnection); every command and '
              'torque-on naming it is refused.'),
    ParamSpec('trigger', bool, False,
              "A leader's trigger (a gripper moved by the operator): held in "
              'current_based_position at trigger_position with trigger_current, so that it '
              'springs back there when let go; torque on at activate, even in a passive arm and '
              'whatever torque_on_start; commands naming it are refused.'),
    ParamSpec('trigger_position', float, None,
              'Where the trigger rests (joint units): its goal position.', 'rad (m)', -1e6, 1e6,
              shown='(required)', only_for='trigger'),
    ParamSpec('trigger_current', float, None,
              "The trigger spring's strength: its goal current, at most the model's Current "
              'Limit.', 'A', 0.001, 100.0, shown='(required)', only_for='trigger'),
    ParamSpec('follow', str, None,
              "A follower's leader joint this joint copies (follow.topic); empty: not followed.",
              shown="the joint's name"),
    ParamSpec('follow_open', float, None,
              "The leader gripper's gripper_open: the leader's travel follow_open..follow_closed "
              "maps linearly onto this gripper's gripper_open..gripper_closed.", 'rad (m)',
              only_for='gripper', shown="this joint's gripper_open"),
    ParamSpec('follow_closed', float, None, "The leader gripper's gripper_closed (see "
              'follow_open).', 'rad (m)', only_for='gripper', shown="this joint's gripper_closed"),
)
# `<joint>.<family>.<name>`: the open families of raw register values, judged against the
# servo's control table (their rows of docs/parameters.md, tools/param_table.py).
REGISTER_FAMILIES: Tuple[Tuple[str, str], ...] = (
    ('registers', 'any writable control-table item by its snake_case name, raw units '
     '(`profile_velocity`, `position_p_gain`, `return_delay_time`, `max_position_limit`, ...), '
     "applied at configure to the joint's servo, and to its second servo too "
     '(`secondary_id`); EEPROM items only where the servo differs, with torque off, then read '
     'back'),
    ('secondary_registers', "the second servo's own value of an item, in place of the "
     "joint's `registers.<name>` (e.g. `drive_mode: 1`, a shadow reversed in firmware, "
     'beside a joint whose registers set `drive_mode: 4`); judged with the rest of what the '
     'second servo gets. Only with `<joint>.secondary_id` set.'),
)
JOINT_PARAMS_BY_NAME: Dict[str, ParamSpec] = {spec.name: spec for spec in JOINT_PARAMS}
JOINT_KEYS: Tuple[str, ...] = tuple(JOINT_PARAMS_BY_NAME)
# Parameters every rclpy node has.
ROS_PARAMS = frozenset({'use_sim_time', 'start_type_description_service'})


@dataclass(frozen=True)
class JointConfig:
    """One configured joint."""

    name: str
    servo_id: int
    operating_mode: str
    # None: the model's datasheet value (stall torque / stall current at its nominal voltage).
    torque_constant_nm_per_a: Optional[float] = None
    registers: Tuple[Tuple[str, int], ...] = ()
    # The model the servo must be (`<joint>.model`); None: any supported model.
    model: Optional[models.Model] = None
    # A gripper (current_based_position): ~/gripper commands, grasp detection; a ratio goal
    # runs from gripper_open (0) to gripper_closed (1), in rad.
    gripper: bool = False
    gripper_open: float = 0.0
    gripper_closed: float = 0.0
    # Trajectory tolerances of this joint (rad); 0: path not checked, goal the top-level one.
    path_tolerance: float = 0.0
    goal_tolerance: float = 0.0
    # The joint as the robot sees it (models.units.JointFrame) and its limits in joint units
    # (None: the servo's).
    offset: float = 0.0
    reverse: bool = False
    ratio: float = 1.0
    min_position: Optional[float] = None
    max_position: Optional[float] = None
    # A second servo on the joint: its id, whether it turns against the joint, its own offset
    # (None: the joint's), and how far the two may disagree (joint units).
    secondary_id: Optional[int] = None
    secondary_reverse: bool = False
    secondary_offset: Optional[float] = None
    secondary_tolerance: float = 0.1
    # The second servo's own register values, in place of the joint's (`secondary_registers`).
    secondary_registers: Tuple[Tuple[str, int], ...] = ()
    # Set on the secondary's own configuration: the joint it belongs to.
    secondary_of: str = ''
    # The protocol its servo speaks (resolved: the joint's, else its model's, else the bus's).
    protocol: float = 2.0
    # False: passive (read, never torqued). A trigger is held at trigger_position (joint units)
    # with trigger_current (A) in current_based_position; the operator moves it, not ROS.
    torque: bool = True
    trigger: bool = False
    trigger_position: float = 0.0
    trigger_current: float = 0.0
    # A follower's: the leader joint it copies (None: not followed), the leader gripper's
    # travel (None: this gripper's own ends).
    follow: Optional[str] = None
    follow_open: Optional[float] = None
    follow_closed: Optional[float] = None

    def refusal(self) -> str:
        """Return why this joint takes no command ('' when it does): passive, or a trigger."""
        if not self.torque:
            return f'joint {self.name!r} is passive (torque: false)'
        if self.trigger:
            return (f'joint {self.name!r} is a trigger (trigger: true): the operator moves it, '
                    'not ROS')
        return ''

    def secondary(self) -> 'JointConfig':
        """Return the configuration of the joint's second servo (secondary_id must be set)."""
        assert self.secondary_id is not None
        offset = self.offset if self.secondary_offset is None else self.secondary_offset
        own = dict(self.registers)
        own.update(self.secondary_registers)
        return dataclasses.replace(
            self, name=f'{self.name} (secondary)', servo_id=self.secondary_id,
            offset=offset, reverse=self.secondary_reverse, gripper=False, secondary_id=None,
            secondary_of=self.name, registers=tuple(sorted(own.items())))

    def register_dict(self) -> Dict[str, int]:
        """Return the configured registers as a dictionary."""
        return dict(self.registers)

    def register_key(self, register: str) -> str:
        """Return the parameter that sets a register of this servo (for error messages)."""
        if self.secondary_of:
            family = ('secondary_registers' if register in dict(self.secondary_registers)
                      else 'registers')
            return f'{self.secondary_of}.{family}.{register}'
        return f'{self.name}.registers.{register}'

    def position_limits(self) -> Tuple[Optional[float], Optional[float]]:
        """
        Return the lowest and highest position the joint may be sent to (joint units).

        min_position/max_position, narrowed for a gripper to its travel (gripper_open ..
        gripper_closed): in current_based_position the servo takes multi-turn goals, so a
        gripper goal beyond its travel would turn the claw through the mechanism. None: no
        end configured (the servo's own limits apply).
        """
        low, high = self.min_position, self.max_position
        if self.gripper:
            travel_low = min(self.gripper_open, self.gripper_closed)
            travel_high = max(self.gripper_open, self.gripper_closed)
            low = travel_low if low is None else max(low, travel_low)
            high = travel_high if high is None else min(high, travel_high)
        return low, high


@dataclass(frozen=True)
class DriverConfig:
    """A validated configuration: a field for each of PARAMS (defaults there), the joints."""

    port: str
    baud_rate: int
    protocol: float
    loop_rate: float
    state_rate: float
    torque_on_start: bool
    torque_off_on_shutdown: bool
    command_timeout: float
    autostart: bool
    latency_timer: float
    ping_retries: int
    missing_servo: str
    read_retries: int
    read_mode: str
    write_mode: str
    cycle_driver: str
    executor: str
    hardware_error_recovery: bool
    recovery_interval: float
    goal_tolerance: float
    goal_time_tolerance: float
    action_monitor_rate: float
    temperature_warn: float
    temperature_error: float
    voltage_low: float
    voltage_high: float
    follow_topic: str
    follow_engaged: bool
    follow_timeout: float
    follow_max_step: float
    follow_ramp_velocity: float
    follow_engage_tolerance: float
    follow_block_error: float
    follow_block_time: float
    trace: str = ''
    joints: Tuple[JointConfig, ...] = field(default_factory=tuple)

    def joint(self, name: str) -> JointConfig:
        """Return the joint with this name."""
        for joint in self.joints:
            if joint.name == name:
                return joint
        raise KeyError(name)


def field_of(name: str) -> str:
    """Return the DriverConfig field of a parameter (follow.topic is follow_topic)."""
    return name.replace('.', '_')


def _agrees_with_the_table() -> None:
    """
    Raise TypeError at import when DriverConfig's fields and PARAMS disagree.

    PARAMS is the one home of a parameter; DriverConfig is written out field by field so that
    type checkers and readers see each one's type (a class made from the table at run time
    would be Any to mypy). validate() fills it from PARAMS alone, and this check makes a
    parameter added to one and not the other fail at once, by name.
    """
    fields = [(f.name, f.type) for f in dataclasses.fields(DriverConfig) if f.name != 'joints']
    # `joints`, a list of names in the table, is the joints themselves here.
    table = [(field_of(spec.name), spec.kind.__name__) for spec in PARAMS
             if spec.name != 'joints']
    written = [(name, kind if isinstance(kind, str) else kind.__name__) for name, kind in fields]
    apart = sorted(set(table) ^ set(written))
    if apart:
        raise TypeError(f'DriverConfig and config.PARAMS disagree (name or type): {apart}')


_agrees_with_the_table()


def _check_type(key: str, value: Any, expected: type) -> Any:
    if expected is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(key, f'expected a number, got {value!r}')
        if not math.isfinite(float(value)):
            raise ConfigError(key, f'expected a finite number, got {value!r}')
        return float(value)
    if expected is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(key, f'expected an integer, got {value!r}')
        return value
    if expected is bool:
        if not isinstance(value, bool):
            raise ConfigError(key, f'expected true or false, got {value!r}')
        return value
    if expected is str:
        if not isinstance(value, str):
            raise ConfigError(key, f'expected a string, got {value!r}')
        return value
    if expected is list:
        if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
            raise ConfigError(key, f'expected a list of strings, got {value!r}')
        return list(value)
    raise AssertionError(expected)


def check_spec(spec: ParamSpec, value: Any, key: str = '') -> Any:
    """Return a parameter's value checked (type, choices, range); ConfigError names key if not."""
    key = key or spec.name
    value = _check_type(key, value, spec.kind)
    if spec.choices and value not in spec.choices:
        if spec.noun:
            raise ConfigError(key, f'unknown {spec.noun} {value!r} (one of {list(spec.choices)})')
        raise ConfigError(key, f'{value!r} is not one of {list(spec.choices)}')
    unit = f' {spec.unit}' if spec.unit else ''
    if spec.minimum is not None and value < spec.minimum:
        raise ConfigError(key, f'{value} is below the minimum {spec.minimum:g}{unit} '
                          f'(range {spec.minimum:g}..{spec.maximum:g})')
    if spec.maximum is not None and value > spec.maximum:
        raise ConfigError(key, f'{value} is above the maximum {spec.maximum:g}{unit} '
                          f'(range {spec.minimum:g}..{spec.maximum:g})')
    return value


def validate(params: Mapping[str, Any]) -> DriverConfig:
    """Return the configuration these parameters describe; ConfigError names the bad key."""
    values: Dict[str, Any] = {}
    for spec in PARAMS:
        if spec.name in params:
            values[field_of(spec.name)] = check_spec(spec, params[spec.name])
        else:
            values[field_of(spec.name)] = spec.default
    joint_names: List[str] = values.pop('joints')
    if not joint_names:
        raise ConfigError('joints', 'no joints configured (a list of joint names is required)')
    seen_names = set()
    for name in joint_names:
        if not name or '.' in name or name.strip() != name:
            raise ConfigError('joints', f'invalid joint name {name!r}')
        if name in seen_names:
            raise ConfigError('joints', f'joint {name!r} is listed twice')
        seen_names.add(name)
    check_thresholds(values)
    _reject_unknown_keys(params, seen_names)
    joints = []
    ids: Dict[int, str] = {}
    for name in joint_names:
        joint = _with_protocol(_joint(params, name), params, values['protocol'])
        for key, servo_id in (('id', joint.servo_id), ('secondary_id', joint.secondary_id)):
            if servo_id is None:
                continue
            if servo_id in ids:
                raise ConfigError(f'{name}.{key}', f'id {servo_id} is already used by joint '
                                  f'{ids[servo_id]!r}')
            ids[servo_id] = name
        if joint.secondary_id is None:
            given = [key for key in params if key.startswith(f'{name}.secondary_registers.')]
            for key in ('secondary_reverse', 'secondary_offset', 'secondary_tolerance'):
                if f'{name}.{key}' in params:
                    given.insert(0, f'{name}.{key}')
            if given:
                raise ConfigError(given[0], f'only a joint with a {name}.secondary_id has this')
        elif joint.gripper:
            raise ConfigError(f'{name}.secondary_id', 'a gripper has one servo')
        joints.append(joint)
    return DriverConfig(joints=tuple(joints), **values)


def _reject_unknown_keys(params: Mapping[str, Any], joint_names: set) -> None:
    for key in params:
        if key in PARAMS_BY_NAME or key in ROS_PARAMS or key.startswith('qos_overrides.'):
            continue
        head, _, rest = key.partition('.')
        if head not in joint_names:
            raise ConfigError(key, 'unknown parameter (not a driver parameter, and '
                              f'{head!r} is not in joints)')
        if rest in JOINT_KEYS or any(rest.startswith(f'{family}.')
                                     for family, _ in REGISTER_FAMILIES):
            continue
        raise ConfigError(key, f'unknown joint parameter {rest!r} (expected one of '
                          f'{list(JOINT_KEYS)}, registers.<name> or '
                          'secondary_registers.<name>)')


def _joint_value(params: Mapping[str, Any], name: str, key: str) -> Any:
    """Return `<name>.<key>` checked against its JOINT_PARAMS spec, or the spec's default."""
    spec = JOINT_PARAMS_BY_NAME[key]
    full = f'{name}.{key}'
    if full not in params:
        return spec.default
    return check_spec(spec, params[full], full)


def _joint(params: Mapping[str, Any], name: str) -> JointConfig:
    if f'{name}.id' not in params:
        raise ConfigError(f'{name}.id', f'joint {name!r} has no id')
    servo_id = _joint_value(params, name, 'id')
    key = f'{name}.model'
    wanted: Optional[models.Model] = None
    if params.get(key, '') != '':   # empty: any supported model
        wanted = _model(key, params[key])
    key = f'{name}.operating_mode'
    mode = _joint_value(params, name, 'operating_mode')
    if key not in params and params.get(f'{name}.trigger') is True:
        mode = 'current_based_position'   # a trigger's, unless the file says another
    if wanted is not None and mode not in wanted.modes:
        raise ConfigError(key, f'{wanted.name} has no {mode} mode (its modes: '
                          f'{", ".join(wanted.modes)})')
    torque_constant: Optional[float] = _joint_value(params, name, 'torque_constant')
    if torque_constant is not None and torque_constant <= 0.0:
        raise ConfigError(f'{name}.torque_constant', f'must be positive, got {torque_constant}')
    gripper = _joint_value(params, name, 'gripper')
    if gripper and mode != 'current_based_position':
        raise ConfigError(f'{name}.gripper', 'a gripper holds with a limited current: its '
                          f'operating_mode must be current_based_position, not {mode}')
    ends = []
    for key in ('gripper_open', 'gripper_closed'):
        if f'{name}.{key}' in params and not gripper:
            raise ConfigError(f'{name}.{key}', f'only a gripper (`{name}.gripper: true`) has '
                              'this')
        ends.append(_joint_value(params, name, key))
    if gripper and ends[0] == ends[1]:
        raise ConfigError(f'{name}.gripper_closed', f'equals gripper_open ({ends[0]:g}): a '
                          'gripper needs its travel (gripper_open .. gripper_closed, joint units)')
    registers = _register_values(params, f'{name}.registers.')
    joint = JointConfig(name, servo_id, mode, torque_constant, tuple(registers), wanted,
                        gripper, ends[0], ends[1], _joint_value(params, name, 'path_tolerance'),
                        _joint_value(params, name, 'goal_tolerance'),
                        *_frame_and_limits(params, name, registers),
                        *_secondary(params, name))
    own = _register_values(params, f'{name}.secondary_registers.')
    joint = dataclasses.replace(joint, secondary_registers=tuple(own))
    limits = [register for register, _ in own
              if register in ('min_position_limit', 'max_position_limit')]
    if limits and (joint.min_position is not None or joint.max_position is not None):
        raise ConfigError(f'{name}.secondary_registers.{limits[0]}', 'give the limits once: '
                          f'{name}.min_position/max_position (joint units) set them for both '
                          'servos, each through its own frame')
    joint = _torque_and_trigger(params, joint, wanted)
    joint = dataclasses.replace(joint, **_follow(params, name, gripper, ends))
    low, high = joint.position_limits()
    if low is not None and high is not None and not low < high:
        raise ConfigError(f'{name}.min_position', 'min_position..max_position leave nothing '
                          f"of the gripper's travel {joint.gripper_open:g}.."
                          f'{joint.gripper_closed:g} (gripper_open..gripper_closed)')
    # Without a model the XM430 manual's table judges the file now (a register only other
    # models have is judged at configure, against the model the servo answers with).
    table = wanted or models.model_for(xm430.MODEL_NUMBER)
    _check_registers(joint, table, lenient=wanted is None)
    if joint.secondary_id is not None:
        # What the second servo gets: the joint's registers, its own in their place.
        _check_registers(joint.secondary(), table, lenient=wanted is None)
    return joint


def _register_values(params: Mapping[str, Any], prefix: str) -> List[Tuple[str, int]]:
    """Return the (register, raw value) pairs of the keys under prefix, sorted by name."""
    values = []
    for key in sorted(k for k in params if k.startswith(prefix)):
        values.append((key[len(prefix):], _check_type(key, params[key], int)))
    return values


def _follow(params: Mapping[str, Any], name: str, gripper: bool,
            ends: Sequence[float]) -> Dict[str, Any]:
    """Return a joint's follow, follow_open and follow_closed (a gripper's: its own ends)."""
    leader: Optional[str] = _joint_value(params, name, 'follow')
    values: Dict[str, Any] = {'follow': name if leader is None else (leader or None)}
    for key in ('follow_open', 'follow_closed'):
        if f'{name}.{key}' in params and not gripper:
            raise ConfigError(f'{name}.{key}', f'only a gripper (`{name}.gripper: true`) has '
                              'this')
        values[key] = _joint_value(params, name, key)
    if (values['follow_open'] is None) != (values['follow_closed'] is None):
        given = 'follow_open' if values['follow_closed'] is None else 'follow_closed'
        raise ConfigError(f'{name}.{given}', 'give both follow_open and follow_closed (the '
                          "leader gripper's travel), or neither")
    if values['follow_open'] is not None and values['follow_open'] == values['follow_closed']:
        raise ConfigError(f'{name}.follow_closed', f'equals follow_open '
                          f"({values['follow_open']:g}): the leader's travel maps onto this "
                          "gripper's")
    if gripper and values['follow_open'] is None:
        values['follow_open'], values['follow_closed'] = ends   # the same travel
    return values


def _torque_and_trigger(params: Mapping[str, Any], joint: JointConfig,
                        wanted: Optional[models.Model]) -> JointConfig:
    """Return the joint with its torque and trigger keys, checked (ConfigError if wrong)."""
    name = joint.name
    torque = _joint_value(params, name, 'torque')
    trigger = _joint_value(params, name, 'trigger')
    for key in ('trigger_position', 'trigger_current'):
        if f'{name}.{key}' in params and not trigger:
            raise ConfigError(f'{name}.{key}', f'only a trigger (`{name}.trigger: true`) has '
                              'this')
    if not trigger:
        return dataclasses.replace(joint, torque=torque)
    if not torque:
        raise ConfigError(f'{name}.torque', 'a trigger is torqued (its motor is the spring): '
                          'leave torque out (true), or make the joint passive without trigger')
    mode = joint.operating_mode
    if f'{name}.operating_mode' not in params:
        mode = 'current_based_position'   # what a trigger runs in; another one given: refused
        if wanted is not None and mode not in wanted.modes:
            raise ConfigError(f'{name}.trigger', 'a trigger runs in current_based_position, '
                              f'which the {wanted.name} has not (its modes: '
                              f'{", ".join(wanted.modes)})')
    elif mode != 'current_based_position':
        raise ConfigError(f'{name}.operating_mode', 'a trigger springs back with a limited '
                          'current: its operating_mode must be current_based_position, not '
                          f'{mode}')
    if joint.secondary_id is not None:
        raise ConfigError(f'{name}.secondary_id', 'a trigger has one servo')
    values = []
    for key in ('trigger_position', 'trigger_current'):
        value = _joint_value(params, name, key)
        if value is None:
            raise ConfigError(f'{name}.{key}', f'a trigger needs {key} (joint {name!r})')
        values.append(value)
    rest, current = values
    low, high = joint.position_limits()
    if (low is not None and rest < low) or (high is not None and rest > high):
        raise ConfigError(f'{name}.trigger_position', f"{rest:g} is beyond the joint's limits "
                          f'{"-inf" if low is None else f"{low:g}"}..'
                          f'{"inf" if high is None else f"{high:g}"}')
    # Against the file's Current Limit, else the pinned model's (the servo's own at configure).
    table = wanted or models.model_for(xm430.MODEL_NUMBER)
    if table.current_unit_a is None or not table.has('goal_current'):
        raise ConfigError(f'{name}.trigger', f'the {table.name} has no current control: a '
                          'trigger needs current_based_position')
    given = joint.register_dict().get('current_limit')
    if given is not None or wanted is not None:
        raw = given if given is not None else table.item('current_limit').maximum
        limit_a = raw * table.current_unit_a
        if current > limit_a + 1e-9:
            where = (f'{name}.registers.current_limit {raw}' if given is not None
                     else f"the {table.name}'s Current Limit")
            raise ConfigError(f'{name}.trigger_current', f'{current:g} A is above {where} '
                              f'({limit_a:.4g} A)')
    return dataclasses.replace(joint, operating_mode=mode, trigger=True, trigger_position=rest,
                               trigger_current=current)


def _with_protocol(joint: JointConfig, params: Mapping[str, Any],
                   bus_protocol: float) -> JointConfig:
    """Return the joint with the protocol its servo speaks; ConfigError if its model cannot."""
    key = f'{joint.name}.protocol'
    given: Optional[float] = _joint_value(params, joint.name, 'protocol')
    model = joint.model
    protocol = given if given is not None else (
        1.0 if model is not None and model.protocol == 1.0 else bus_protocol)
    if model is not None and model.protocol == 1.0 and protocol != 1.0:
        raise ConfigError(key if given is not None else 'protocol',
                          f'{model.name} speaks Protocol 1.0 only (joint {joint.name!r})')
    if model is not None and protocol == 1.0 and model.protocol != 1.0 \
            and not model.has('protocol_version'):
        raise ConfigError(key if given is not None else 'protocol',
                          f'{model.name} speaks Protocol 2.0 only (joint {joint.name!r})')
    if protocol == 1.0:
        for register, _ in joint.registers:
            table = model or models.model_for(xm430.MODEL_NUMBER)
            if table.has(register) and table.item(register).address > 0xFF:
                raise ConfigError(f'{joint.name}.registers.{register}',
                                  f'address {table.item(register).address} is beyond the '
                                  'reach of Protocol 1.0 (one-byte addresses)')
    return dataclasses.replace(joint, protocol=protocol)


def _secondary(params: Mapping[str, Any], name: str) -> Tuple[Any, ...]:
    """Return (secondary_id or None, reverse, offset, tolerance) of a joint."""
    servo_id = _joint_value(params, name, 'secondary_id')
    return (None if servo_id == -1 else servo_id,
            *[_joint_value(params, name, key)
              for key in ('secondary_reverse', 'secondary_offset', 'secondary_tolerance')])


def _frame_and_limits(params: Mapping[str, Any], name: str,
                      registers: Sequence[Tuple[str, int]]) -> Tuple[Any, ...]:
    """Return (offset, reverse, ratio, min_position, max_position) of a joint, checked."""
    values = [_joint_value(params, name, key)
              for key in ('offset', 'reverse', 'ratio', 'min_position', 'max_position')]
    low, high = values[3], values[4]
    if low is not None and high is not None and not low < high:
        raise ConfigError(f'{name}.min_position', f'{low} is not below max_position {high}')
    if low is not None or high is not None:
        given = [register for register, _ in registers
                 if register in ('min_position_limit', 'max_position_limit')]
        if given:
            raise ConfigError(f'{name}.registers.{given[0]}', 'give the limits once: '
                              f'{name}.min_position/max_position (joint units) set them')
    return tuple(values)


def _model(key: str, value: Any) -> models.Model:
    """Return the model a `<joint>.model` value names (a name such as XL430-W250, or a number)."""
    if isinstance(value, bool) or not isinstance(value, (int, str)):
        raise ConfigError(key, f'expected a model name (e.g. XL430-W250) or number, got {value!r}')
    try:
        if isinstance(value, int) or value.strip().isdigit():
            return models.model_for(int(value))
        return models.model_named(value)
    except models.ModelError as exc:
        raise ConfigError(key, str(exc)) from None


def _check_registers(joint: JointConfig, table: models.Model, lenient: bool = False) -> None:
    """
    Refuse (ConfigError) the first register of the joint the model refuses.

    lenient: a register this table lacks passes if another supported model has it.
    """
    values = {item.name: item.initial for item in table.items}
    checked = {}
    for register, value in joint.registers:
        key = joint.register_key(register)
        if lenient and not table.has(register) and any(
                other.has(register) for other in models.ALL_MODELS):
            continue
        try:
            item = registers.writable_register(table, register)
            registers.check_range(item, value, table)
        except ValueError as exc:
            whose = (f'on the second servo (id {joint.servo_id}): ' if joint.secondary_of
                     else '')
            raise ConfigError(key, whose + str(exc)) from None
        checked[register] = value
    # Values bounded by another register must respect it, as the servo would refuse them (data
    # limit error) at configure: the rules of registers.check_register_set, against the file's
    # values where it sets them and the table's initial values elsewhere.
    values.update(checked)
    # The lower bound of a crossed pair is named (min_position_limit, not max_...), and a
    # profile register rather than the Drive Mode that says what it counts.
    for register in sorted(checked, key=lambda r: (r.startswith('max_'), r == 'drive_mode')):
        try:
            registers.check_register_set(table, values, register, checked[register],
                                         joint.operating_mode)
        except ValueError as exc:
            whose = (f'on the second servo (id {joint.servo_id}): ' if joint.secondary_of
                     else '')
            raise ConfigError(joint.register_key(register), whose + str(exc)) from None


def describe_register(joint: JointConfig, register: str) -> models.Item:
    """Return the item a joint's register names: its model's, the XM430 manual's, or any."""
    for table in (joint.model, models.model_for(xm430.MODEL_NUMBER), *models.ALL_MODELS):
        if table is not None and table.has(register):
            return table.item(register)
    raise KeyError(register)


def check_joint_against(joint: JointConfig, table: models.Model) -> None:
    """Refuse (ConfigurationError) a joint's configuration that does not fit its servo's model."""
    if joint.operating_mode not in table.modes:
        raise ConfigurationError(f'it has no {joint.operating_mode} mode ({joint.name}.'
                                 f'operating_mode; its modes: {", ".join(table.modes)})')
    _check_registers(joint, table)


def replace(config: DriverConfig, **changes: Any) -> DriverConfig:
    """Return the configuration with some top-level values changed (runtime parameters)."""
    return dataclasses.replace(config, **changes)


def check_thresholds(values: Mapping[str, Any]) -> None:
    """Raise ConfigError when the diagnostics thresholds contradict each other."""
    for low, high in (('temperature_warn', 'temperature_error'), ('voltage_low', 'voltage_high')):
        if values[low] > values[high]:
            raise ConfigError(low, f'{low} {values[low]:g} is above {high} {values[high]:g}')


_YAML_KINDS = ((bool, 'bool'), (int, 'integer'), (float, 'double'), (str, 'string'))


def _kind(value: Any) -> str:
    for python_type, name in _YAML_KINDS:   # bool first: it is an int too
        if isinstance(value, python_type):
            return name
    return type(value).__name__


def check_parameter_file(path: str) -> None:
    """
    Raise ParameterFileError when ROS could not read this parameter file, saying why in a line.

    ROS parses parameter files in C and answers a bad one with a traceback (or an error about
    a parameter it typed PARAMETER_NOT_SET); this checks first what it would refuse: a missing
    or unreadable file, invalid YAML (tabs included), no `<node>: ros__parameters:` mapping,
    empty lists and mappings (ROS cannot give them a type), lists of lists, mixed-type lists.
    """
    try:
        with open(path, encoding='utf-8') as stream:
            text = stream.read()
    except FileNotFoundError:
        raise ParameterFileError(f'parameter file {path} does not exist') from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ParameterFileError(f'parameter file {path} cannot be read: {exc}') from None
    try:
        tree = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, 'problem_mark', None)
        problem = getattr(exc, 'problem', None) or str(exc).splitlines()[0]
        where = f' at line {mark.line + 1}, column {mark.column + 1}' if mark else ''
        lines = text.splitlines()
        hint = ''
        if mark is not None and mark.line < len(lines) and '\t' in lines[mark.line]:
            hint = ' (a tab: YAML indents with spaces only)'
        raise ParameterFileError(f'parameter file {path}: invalid YAML{where}: {problem}'
                                 f'{hint}') from None
    if tree is None:
        return   # an empty file sets nothing; the configuration check says what is missing
    if not isinstance(tree, dict):
        raise ParameterFileError(
            f'parameter file {path}: the top level must map node names (e.g. /**) to '
            f'"ros__parameters:", not a {_kind(tree)}')
    _check_node_entries(path, tree, '')


def _check_node_entries(path: str, tree: Mapping[Any, Any], prefix: str) -> None:
    for key, entry in tree.items():
        where = f'{prefix}{key}'
        if not isinstance(entry, dict):
            raise ParameterFileError(
                f'parameter file {path}: {where!r} needs "ros__parameters:" under it (a node '
                'name, then ros__parameters, then the parameters)')
        if 'ros__parameters' in entry:
            params = entry['ros__parameters']
            if params is None:
                continue
            if not isinstance(params, dict):
                raise ParameterFileError(f'parameter file {path}: {where}.ros__parameters must '
                                         'be a mapping of parameter names to values')
            _check_values(path, params, '')
        else:
            _check_node_entries(path, entry, where + '/')   # namespaces may nest


def _check_values(path: str, params: Mapping[Any, Any], prefix: str) -> None:
    for key, value in params.items():
        name = f'{prefix}{key}'
        if isinstance(value, dict):
            if not value:
                raise ParameterFileError(
                    f'parameter file {path}: parameter {name!r}: an empty mapping is not a '
                    'parameter (ROS cannot give it a type); leave the key out')
            _check_values(path, value, name + '.')
        elif isinstance(value, list):
            if not value:
                raise ParameterFileError(
                    f'parameter file {path}: parameter {name!r}: an empty list has no type '
                    'ROS can give it; list at least one element or leave the key out')
            kinds = sorted({_kind(element) for element in value})
            if any(isinstance(element, (list, dict)) for element in value):
                raise ParameterFileError(
                    f'parameter file {path}: parameter {name!r}: a list of lists or mappings '
                    'is not a ROS parameter')
            if len(kinds) > 1:
                raise ParameterFileError(
                    f'parameter file {path}: parameter {name!r}: a list mixing '
                    f'{" and ".join(kinds)}: the elements of a ROS list all have one type')
