"""
`dxl setup`: give factory-new servos their ids, the bus's baud rate and Return Delay Time 0.

  dxl setup --port P --params config/arm_sim.yaml [--yes [--wait S]]
  dxl setup --port P --ids 1 2 3 [--baud 1000000] [--protocol 2.0] [--yes [--wait S]]

Every new servo is id 1 at 57,600 bps with a Return Delay Time of 500 us, so a chain of them
answers nothing useful until each has been set up alone. For each servo of the file (its joints
in order, a joint's second servo after it) or of --ids, in order, this asks for that servo to be
connected (the servos set up before it may stay on the bus), finds it at any baud rate and
protocol (bus.find_one_servo; at the bus's own baud rate the servos set up so far are told
apart by their ids), and writes Return Delay Time 0, then its id, then the baud rate (EEPROM:
torque off for the writes, back on after if it was on), each read back; then it reads the three
again at the new id and baud as the check, says so and goes on.

It refuses a servo, saying why, when two servos answer (two ids, or replies that collide: two
new servos share id 1), when another servo on the bus already answers to the id it is to get,
when the model is not the one the file names, when the model cannot take the baud rate, or when
it speaks another protocol than the joint's. Interactively the refusal is followed by the same
prompt again (fix it, press Enter); with --yes (for scripts: the servos are connected in order
by someone or something else) it waits up to --wait seconds for a servo to appear, and a
refusal ends the run (exit 1). Ctrl-C ends it with one line saying which servos were set up
and, if it came in the middle of one, which of its items were written (exit 130).
"""

import argparse
from dataclasses import dataclass, field
import sys
import time
from typing import List, Optional, Sequence, Set, Tuple

from dxl_servo_driver import config, models
from dxl_servo_driver.bus import (
    Bus, default_bauds, find_one_servo, FRAMERS, MAX_RETURN_DELAY_S, NoServo, NotOneServo,
    OneServo, protocol_1_bauds, set_baud)
from dxl_servo_driver.errors import CommError, ConfigurationError, PortError
from dxl_servo_driver.models.base import Model
from dxl_servo_driver.protocol import MAX_ID
from dxl_servo_driver.tool.common import (
    EXIT_INTERRUPTED, EXIT_OK, EXIT_PORT, EXIT_USAGE, ToolError)
from dxl_servo_driver.tool.servo import read_items, torque_off, write_verified
from dxl_servo_driver.tool.session import connect, FACTORY_BAUD, open_bus, ServoLink
from dxl_servo_driver.tool.yaml_edit import EditError, parameters_of

DEFAULT_BAUD = 1_000_000
DEFAULT_WAIT_S = 60.0
# Between searches while waiting for a servo to be connected (--yes).
RETRY_S = 0.3
# After Enter, how long the search goes on for a servo just powered; and the time a servo
# takes to boot (power-on to its first answer: ~0.1 s), waited before the first search.
BOOT_WAIT_S = 3.0
BOOT_S = 0.5
# While waiting, every this many searches tries every baud rate (the others: the factory
# rate and the bus's only).
FULL_EVERY = 10
# A servo heard right after the bus changed baud rate may have missed a packet (it was parsing
# the bytes sent at the other rate as noise): a few tries before giving up on it.
CONNECT_ATTEMPTS = 3
# Searches that must all hear replies collide before two servos are said to share an id.
COLLISION_CHECKS = 3


@dataclass(frozen=True)
class Target:
    """One servo to set up: what it is called, its id, model (None: any) and protocol."""

    label: str
    servo_id: int
    model: Optional[Model]
    protocol: float


@dataclass
class Progress:
    """What has been done so far: servos set up, and the items written of the one in hand."""

    done: List[Tuple[Target, str]] = field(default_factory=list)
    current: Optional[Target] = None
    written: List[str] = field(default_factory=list)
    pending: List[str] = field(default_factory=list)
    unsure: bool = False   # pending[0] was being written

    def summary(self) -> str:
        """Return one line: which servos are set up, and where the one in hand stopped."""
        done = ', '.join(f'{target.label} (id {target.servo_id})' for target, _ in self.done)
        text = f'set up: {done or "none"}'
        if self.current is not None and self.pending and self.unsure:
            # The item in hand may or may not have been written when it stopped.
            text += (f'; {self.current.label}: written {", ".join(self.written) or "nothing"}, '
                     f'unsure {self.pending[0]}, not written '
                     f'{", ".join(self.pending[1:]) or "nothing"}')
        elif self.current is not None and self.written:
            text += (f'; {self.current.label}: written {", ".join(self.written)}, not written '
                     f'{", ".join(self.pending) or "nothing"}')
        elif self.current is not None:
            text += f'; {self.current.label}: nothing written'
        return text


class Refused(Exception):
    """This servo cannot be set up as it is: the message says why and what to do."""


def targets_from_params(path: str) -> Tuple[List[Target], int]:
    """Return the servos a driver parameter file configures, in order, and its baud rate."""
    try:
        config.check_parameter_file(path)
        with open(path, encoding='utf-8') as stream:
            flat = parameters_of(stream.read())
    except ConfigurationError as exc:
        raise ToolError(str(exc), EXIT_USAGE) from exc
    except OSError as exc:
        raise ToolError(f'{path} cannot be read: {exc.strerror}', EXIT_USAGE) from exc
    except EditError as exc:
        raise ToolError(f'{path}: {exc}', EXIT_USAGE) from exc
    try:
        cfg = config.validate(flat)
    except ConfigurationError as exc:
        raise ToolError(f'{path}: {exc}', EXIT_USAGE) from exc
    targets: List[Target] = []
    for joint in cfg.joints:
        targets.append(Target(f'the servo of joint {joint.name}', joint.servo_id,
                              joint.model, joint.protocol))
        if joint.secondary_id is not None:
            targets.append(Target(f'the second servo of joint {joint.name}',
                                  joint.secondary_id, joint.model, joint.protocol))
    return targets, cfg.baud_rate


def _servo_id(text: str) -> int:
    value = int(text)
    if not 0 <= value < MAX_ID:
        raise argparse.ArgumentTypeError(f'{value} is not an id a servo can take '
                                         f'(0..{MAX_ID - 1})')
    return value


def register(sub: 'argparse._SubParsersAction[argparse.ArgumentParser]') -> None:
    """Add `setup`."""
    parser = sub.add_parser(
        'setup', help='give new servos, one at a time, their id, the bus baud rate and '
        'Return Delay Time 0',
        description='Set up factory-new servos one at a time: for each servo of the parameter '
        'file (or of --ids), in order, connect it when asked; it is found at any baud rate and '
        'protocol and given its id, the bus baud rate and Return Delay Time 0, each read back.',
        epilog='examples:\n  dxl setup --port /dev/ttyDXL --params config/arm_sim.yaml\n'
        '  dxl setup --port /dev/ttyDXL --ids 1 2 3 --baud 1000000\n'
        '  dxl setup --port /dev/ttyDXL --ids 1 2 3 --yes --wait 120   # scripted',
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--port', required=True,
                        help='serial device (e.g. /dev/ttyUSB0) or a virtual_bus pty')
    which = parser.add_mutually_exclusive_group(required=True)
    which.add_argument('--params', metavar='FILE',
                       help="the driver's parameter file: its joints' ids, models, baud_rate, "
                       'protocol')
    which.add_argument('--ids', type=_servo_id, nargs='+', metavar='ID',
                       help='the ids to give, in the order the servos are connected')
    parser.add_argument('--baud', type=int, default=None, metavar='BPS',
                        help=f'with --ids: the bus baud rate to give (default {DEFAULT_BAUD})')
    parser.add_argument('--protocol', type=float, choices=tuple(FRAMERS), default=2.0,
                        help='with --ids: the protocol the servos speak (default 2.0)')
    parser.add_argument('--yes', action='store_true',
                        help='no prompts (scripts): wait for each servo to appear instead')
    parser.add_argument('--wait', type=float, default=DEFAULT_WAIT_S, metavar='S',
                        help=f'with --yes: how long to wait for each servo (default '
                        f'{DEFAULT_WAIT_S:g} s)')
    parser.set_defaults(run=run)


def _targets(args: argparse.Namespace) -> Tuple[List[Target], int]:
    if args.params:
        if args.baud is not None:
            raise ToolError('--baud comes from the parameter file (baud_rate) with --params',
                            EXIT_USAGE)
        return targets_from_params(args.params)
    if len(set(args.ids)) != len(args.ids):
        raise ToolError('--ids: an id is listed twice', EXIT_USAGE)
    baud = DEFAULT_BAUD if args.baud is None else args.baud
    if all(baud not in model.bauds.values() for model in models.ALL_MODELS):
        raise ToolError(f'--baud {baud}: no servo takes that rate', EXIT_USAGE)
    return [Target(f'servo {n + 1} of {len(args.ids)}', servo_id, None, args.protocol)
            for n, servo_id in enumerate(args.ids)], baud


def run(args: argparse.Namespace) -> int:
    """Set up every servo in turn."""
    targets, baud_bps = _targets(args)
    if not args.yes and not sys.stdin.isatty():
        raise ToolError('stdin is not a terminal: use --yes (servos connected in order)',
                        EXIT_USAGE)
    # Opened at the factory rate, where new servos are and the search begins.
    bus = open_bus(args.port, FACTORY_BAUD, return_delay_s=MAX_RETURN_DELAY_S,
                   trace=getattr(args, 'trace', ''))
    progress = Progress()
    print(f'{len(targets)} servo(s) to set up, each to {baud_bps} bps, Return Delay Time 0.')
    try:
        for number, target in enumerate(targets, 1):
            progress.current = target
            progress.written, progress.pending, progress.unsure = [], [], False
            setup_one(bus, target, baud_bps, progress, args, number, len(targets))
    except (KeyboardInterrupt, EOFError):   # Ctrl-C, or Ctrl-D at a prompt
        print(f'\ndxl setup: interrupted; {progress.summary()}', file=sys.stderr)
        return EXIT_INTERRUPTED
    except ToolError as exc:
        raise ToolError(f'{exc}; {progress.summary()}', exc.status) from exc
    except PortError as exc:
        raise ToolError(f'the port was lost: {exc}; {progress.summary()}', EXIT_PORT) from exc
    finally:
        bus.close()
    print(f'done: {len(targets)} servo(s) at {baud_bps} bps:')
    for target, model_name in progress.done:
        print(f'  {target.label}: id {target.servo_id}, {model_name}')
    return EXIT_OK


def setup_one(bus: Bus, target: Target, baud_bps: int, progress: Progress,
              args: argparse.Namespace, number: int, count: int) -> None:
    """Find the servo of one target (asking for it to be connected) and set it up."""
    what = target.label + (f' ({target.model.name})' if target.model is not None else '')
    ask = (f'[{number}/{count}] Connect {what} alone (it becomes id {target.servo_id}; the '
           'servos set up before may stay connected). Press Enter when it is ')
    known = {done.servo_id for done, _ in progress.done}
    if args.yes:
        print(f'[{number}/{count}] waiting up to {args.wait:g} s for {what} (it becomes id '
              f'{target.servo_id}) ...', flush=True)
    while True:
        if not args.yes:
            input(ask + 'powered: ')
            time.sleep(BOOT_S)
        try:
            link = search(bus, baud_bps, known, target,
                          time.monotonic() + (args.wait if args.yes else BOOT_WAIT_S),
                          args.yes)
            break
        except NoServo as exc:
            if args.yes:
                raise ToolError(f'no servo for {what} appeared within {args.wait:g} s: '
                                f'{exc}') from exc
            print(f'no servo found: {exc}', flush=True)
        except (NotOneServo, Refused) as exc:
            if args.yes:
                raise ToolError(f'{what} refused: {exc}') from exc
            print(f'refused: {exc}', flush=True)
        except CommError as exc:
            if args.yes:
                raise ToolError(f'{what}: {exc}') from exc
            print(f'failed: {exc}', flush=True)
    write_settings(link, target, baud_bps, progress)
    verify(bus, link, target, baud_bps)
    progress.done.append((target, link.model.name))
    progress.current = None
    print(f'[{number}/{count}] {what}: id {target.servo_id}, {baud_bps} bps, Return Delay '
          'Time 0: checked at its new id and baud rate', flush=True)


def search(bus: Bus, baud_bps: int, known: Set[int], target: Target, deadline_s: float,
           waiting: bool) -> ServoLink:
    """
    Find the new servo, searching again until deadline_s while none answers; check it.

    A search tries every baud rate (a used servo may be at any) first, or when waiting for a
    servo to be connected (waiting) every FULL_EVERY-th time only: the others try the factory
    rate and the bus's, where a new servo appears, so one connected while this waits is found
    within a second or so rather than after a search of every rate.
    """
    attempt = 0
    collisions = 0
    while True:
        everywhere = attempt % FULL_EVERY == (FULL_EVERY - 1 if waiting else 0)
        bauds = default_bauds() if everywhere else [FACTORY_BAUD, baud_bps]
        try:
            found = find_new(bus, baud_bps, known, bauds)
        except NoServo:
            if time.monotonic() >= deadline_s:
                raise
            time.sleep(RETRY_S)
            attempt += 1
            continue
        except NotOneServo as exc:
            # Two servos with one id collide every time; a reply that came late from the
            # rate searched before (a loaded host, a slow adapter) does not: asked again.
            collisions += 1
            if not exc.collided or collisions >= COLLISION_CHECKS:
                raise
            time.sleep(RETRY_S)
            continue
        return check(bus, found, target, baud_bps, known)


def find_new(bus: Bus, baud_bps: int, known: Set[int], bauds: Sequence[int]) -> OneServo:
    """
    Return the one servo not yet set up, at whichever of bauds it is, in either protocol.

    The servos set up so far answer at baud_bps with their new ids: there, anything else
    answering is the new servo. At every other rate scan's search finds the one servo.
    """
    order = list(dict.fromkeys(bauds))
    if not known:
        return find_one_servo(bus, bauds=order, bauds_1=protocol_1_bauds())
    try:
        set_baud(bus, baud_bps)
    except (PortError, ValueError) as exc:
        raise ToolError(f'the adapter refused {baud_bps} bps: {exc}', EXIT_PORT) from exc
    heard = bus.broadcast_sweep()
    others = sorted(set(heard.models) - known)
    if heard.garbled or heard.noise:
        raise NotOneServo(f'replies collided at {baud_bps} bps, where the servos set up so far '
                          f'answer (ids {", ".join(map(str, sorted(known)))}): the new servo '
                          'has the id of one of them, or two new servos are connected; connect '
                          'the new one alone', baud_bps, [(i, 2.0) for i in others], True)
    if len(others) > 1:
        raise NotOneServo(f'{len(others)} servos not set up answer at {baud_bps} bps (ids '
                          f'{", ".join(map(str, others))}); connect one new servo at a time',
                          baud_bps, [(i, 2.0) for i in others], False)
    if others:
        return OneServo(others[0], heard.models[others[0]], 2.0, baud_bps)
    return find_one_servo(bus, bauds=[b for b in order if b != baud_bps],
                          bauds_1=protocol_1_bauds())


def check(bus: Bus, found: OneServo, target: Target, baud_bps: int,
          known: Set[int]) -> ServoLink:
    """Return the found servo's link after the refusals: model, baud, protocol, id taken."""
    bus.speak(found.servo_id, FRAMERS[found.protocol])
    try:
        link = _connect(bus, found.servo_id)
    except ToolError as exc:
        raise Refused(str(exc)) from exc
    model = link.model
    where = f'id {found.servo_id} at {found.baud_bps} bps'
    if target.model is not None and model.name != target.model.name:
        raise Refused(f'the servo found ({where}) is a {model.name}; {target.label} is a '
                      f'{target.model.name} in the file: connect the right servo')
    if baud_bps not in model.bauds.values():
        raise Refused(f'the servo found ({where}) is a {model.name}, which cannot run at '
                      f'{baud_bps} bps (it takes {sorted(model.bauds.values())})')
    if found.protocol != target.protocol:
        raise Refused(f'the servo found ({where}) speaks Protocol {found.protocol:.1f}, '
                      f'{target.label} Protocol {target.protocol:.1f}: switch its protocol '
                      "with the manufacturer's tool first")
    if (found.servo_id, found.baud_bps) != (target.servo_id, baud_bps):
        owner = _answers(bus, target.servo_id, baud_bps, target.protocol)
        set_baud(bus, found.baud_bps)
        bus.speak(found.servo_id, FRAMERS[found.protocol])
        if owner is not None:
            who = ('a servo set up just now' if target.servo_id in known
                   else 'a servo already on the bus')
            raise Refused(f'id {target.servo_id} is taken: {who} ({owner}) answers to it at '
                          f'{baud_bps} bps; give this one another id, or take that one off')
    return link


def _connect(bus: Bus, servo_id: int) -> ServoLink:
    """Connect to a servo, again on failure: the first packets after a baud change may be lost."""
    for attempt in range(CONNECT_ATTEMPTS):
        try:
            return connect(bus, servo_id)
        except ToolError:
            if attempt == CONNECT_ATTEMPTS - 1:
                raise
            time.sleep(RETRY_S)
    raise AssertionError('unreachable')


def _answers(bus: Bus, servo_id: int, baud_bps: int, protocol: float) -> Optional[str]:
    """Return the model of what answers to servo_id at baud_bps, None when nothing does."""
    set_baud(bus, baud_bps)
    bus.speak(servo_id, FRAMERS[protocol])
    for _ in range(2):
        try:
            number = bus.ping(servo_id, probe=True)
        except CommError:
            continue
        return (models.model_for(number).name if number in models.SUPPORTED
                else f'model {number}')
    return None


def write_settings(link: ServoLink, target: Target, baud_bps: int, progress: Progress) -> None:
    """Write Return Delay Time 0, the id, the baud rate (torque off), each read back."""
    model = link.model
    baud_raw = {bps: raw for raw, bps in model.bauds.items()}[baud_bps]
    wanted = [('return_delay_time', 0), ('id', target.servo_id), ('baud_rate', baud_raw)]
    items = [model.item(name) for name, _ in wanted]
    present = read_items(link, items)
    writes = [(item, value) for item, (_, value) in zip(items, wanted)
              if present[item.name] != value]
    progress.pending = [item.name for item, _ in writes]
    with torque_off(link, bool(writes)):
        for item, value in writes:
            progress.unsure = True
            write_verified(link, item, value)
            progress.unsure = False
            progress.written.append(item.name)
            progress.pending.remove(item.name)


def verify(bus: Bus, link: ServoLink, target: Target, baud_bps: int) -> None:
    """Read the three settings again at the new id and baud rate; ToolError if they differ."""
    set_baud(bus, baud_bps)
    try:
        again = _connect(bus, target.servo_id)
    except ToolError as exc:
        raise ToolError(f'{target.label}: set up, but id {target.servo_id} does not answer at '
                        f'{baud_bps} bps: {exc}') from exc
    model = again.model
    values = read_items(again, [model.item(name) for name in
                                ('id', 'baud_rate', 'return_delay_time')])
    if model.bauds.get(values['baud_rate']) != baud_bps or values['return_delay_time'] != 0 \
            or values['id'] != target.servo_id:
        raise ToolError(f'{target.label}: id {target.servo_id} reads back {values}')
    link.servo_id = target.servo_id
