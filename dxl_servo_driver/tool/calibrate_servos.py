"""
The servos `dxl calibrate` works on: its joints, their readings and writes, their torque.

A reading of something that changes by itself (`live`) and a write (`put`) are tried again when
a reply is lost: a calibration goes on for minutes and must not end over a lost reply. `Arm`
turns every servo's torque off and back as it was when the command does not finish.
"""

import math
import sys
import time
from typing import List, Sequence, Tuple

from dxl_servo_driver import config as driver_config
from dxl_servo_driver.bus import Bus, FRAMERS
from dxl_servo_driver.errors import CommError
from dxl_servo_driver.models import modes
from dxl_servo_driver.models.units import JointFrame, units_for
from dxl_servo_driver.tool.common import ToolError
from dxl_servo_driver.tool.session import connect, ServoLink

__all__ = ['Arm', 'connect_joints', 'Joint', 'live', 'put', 'torque_on_holding']

ATTEMPTS = 3                 # tries of one transaction before the bus is said to fail
LIVE_RETRY_S = 1.0           # ... and how long a live reading is tried at least


def live(link: ServoLink, name: str) -> int:
    """
    Return an item that changes by itself (a position, a current): read once, unconfirmed.

    A reply lost now and then (noise, a busy adapter, a host too loaded to read in time) is
    read again, ATTEMPTS times and for LIVE_RETRY_S at least: the readings go on for minutes,
    and a few lost replies must not end a calibration the user has half done.
    """
    item = link.item(name)
    give_up = time.monotonic() + LIVE_RETRY_S
    attempt = 0
    while True:
        try:
            return item.decode(link.bus.read(link.servo_id, item.address, item.size,
                                             confirm=False))
        except CommError:
            attempt += 1
            if attempt >= ATTEMPTS and time.monotonic() >= give_up:
                raise


def put(link: ServoLink, name: str, value: int) -> None:
    """Write an item, again if its status was lost (writing a value twice is harmless)."""
    for attempt in range(ATTEMPTS):
        try:
            link.write(name, value)
            return
        except CommError:
            if attempt == ATTEMPTS - 1:
                raise


class Joint:
    """One joint of the file being calibrated: its servos and the frame found so far."""

    def __init__(self, joint: driver_config.JointConfig, links: Sequence[ServoLink]) -> None:
        self.config = joint
        self.links = list(links)            # the joint's servo, then its second one if any
        self.offsets = [joint.offset, joint.offset if joint.secondary_offset is None
                        else joint.secondary_offset]
        self.reverse = [joint.reverse, joint.secondary_reverse]

    @property
    def name(self) -> str:
        """Return the joint's name."""
        return self.config.name

    def servo_rad(self, index: int = 0, absolute: bool = True) -> float:
        """
        Return a servo's Present Position in servo radians (raw 'zero' = 0 rad).

        absolute: as the node will read it. In a single-turn mode the node keeps no turns:
        Present Position is then re-initialised within one turn at torque on (the XM430
        manual), and so is this reading. Not absolute: as the servo counts now (for moves).
        """
        link = self.links[index]
        model = link.model
        raw = live(link, 'present_position')
        if absolute and self.config.operating_mode in modes.SINGLE_TURN:
            homing = link.read('homing_offset') if model.has('homing_offset') else 0
            raw = units_for(model).reinit_position(raw, homing)
        return (raw - model.position_zero_raw) * 2.0 * math.pi / model.pulses_per_rev

    def frame(self) -> JointFrame:
        """Return the joint's frame as calibrated so far."""
        return JointFrame(self.offsets[0], self.reverse[0], self.config.ratio)

    def joint_value(self, servo_rad: float) -> float:
        """Return a servo angle as the joint's position, in the frame found so far."""
        frame = self.frame()
        return frame.scale * (servo_rad - frame.offset_rad)


class Arm:
    """Every servo of the joints calibrated, their torque off, put back as it was on abort."""

    def __init__(self, bus: Bus, joints: Sequence[Joint]) -> None:
        self.bus = bus
        self.joints = list(joints)
        self.torque_was: List[Tuple[ServoLink, int]] = []

    def links(self) -> List[ServoLink]:
        """Return every servo, joints' order."""
        return [link for joint in self.joints for link in joint.links]

    def torque_off(self) -> None:
        """Turn every servo's torque off, keeping what it was."""
        for link in self.links():
            enabled = link.read('torque_enable')
            self.torque_was.append((link, enabled))
            if enabled:
                link.write('torque_enable', 0)

    def restore(self) -> None:
        """Torque back on where it was on, each holding where it is now (best effort)."""
        for link, enabled in self.torque_was:
            if not enabled:
                continue
            try:
                mode = modes.BY_NAME.get(_mode_name(link))
                if mode is None or mode.position:
                    torque_on_holding(link)
                else:
                    put(link, 'torque_enable', 1)
            except (CommError, ToolError) as exc:
                print(f'dxl calibrate: could not turn torque back on at id {link.servo_id}: '
                      f'{exc}', file=sys.stderr)


def torque_on_holding(link: ServoLink) -> int:
    """
    Turn torque on with the goal where the horn is; return the whole turns torque-on took.

    Torque on re-initialises Present Position within one turn (the XM430 manual) and a horn
    turned by hand may be turns away from where it was: the goal is written where the count
    will be, then again where it is once torque is on, so that the motor never chases a goal
    turns away.
    """
    model = link.model
    before = live(link, 'present_position')
    if not model.has('goal_position'):
        put(link, 'torque_enable', 1)
        return 0
    homing = link.read('homing_offset') if model.has('homing_offset') else 0
    units = units_for(model)
    put(link, 'goal_position', units.reinit_position(before, homing))
    put(link, 'torque_enable', 1)
    after = live(link, 'present_position')
    put(link, 'goal_position', after)
    return units.kept_turns(before, after)


def _mode_name(link: ServoLink) -> str:
    """Return the servo's mode's name ('' when its table has no mode register or it is odd)."""
    if not link.model.mode_register:
        return ''
    number = link.read(link.model.mode_register)
    for name, value in link.model.modes.items():
        if value == number:
            return name
    return ''


def connect_joints(bus: Bus, config: driver_config.DriverConfig,
                   names: Sequence[str]) -> List[Joint]:
    """Connect every servo of the joints named; ToolError naming a joint that does not answer."""
    joints = []
    for name in names:
        joint = config.joint(name)
        links = []
        for servo_id in (joint.servo_id, joint.secondary_id):
            if servo_id is None:
                continue
            bus.speak(servo_id, FRAMERS[joint.protocol])
            try:
                link = connect(bus, servo_id)
            except ToolError as exc:
                raise ToolError(f'joint {name!r}: {exc}', exc.status) from None
            if joint.model is not None and link.model.number != joint.model.number:
                raise ToolError(f'joint {name!r}: the file says {joint.model.name}, id '
                                f'{servo_id} is a {link.model.name}')
            links.append(link)
        joints.append(Joint(joint, links))
    return joints
