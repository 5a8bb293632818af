"""
The table of parameters: each one's type, default, unit, range, description and when it is taken.

PARAMS (top level) and JOINT_PARAMS (`<joint>.<key>`) say of each parameter its type, default,
unit, range, description and when it is taken (at configure, at run time, only at a restart):
validation, the ROS declarations (`ros2 param describe`), the runtime checks and the tables of
docs/parameters.md (tools/param_table.py) all read them. REGISTER_FAMILIES names the open
families of raw register values (`<joint>.registers.<name>`), judged against the servo's control
table. The descriptions are the parameters' own: docs/parameters.md and `ros2 param describe`
print them.
"""

from dataclasses import dataclass
from typing import Any, Dict, Optional, Tuple

from dxl_servo_driver import models
from dxl_servo_driver.models import modes
from dxl_servo_driver.protocol import MAX_ID


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
