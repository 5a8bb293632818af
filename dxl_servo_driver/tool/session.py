"""
What the `dxl` commands talk to: a bus on a port, one servo on it with its table, SI values.

`open_bus` opens the port the way the driver does (a serial device or `virtual_bus`'s pty) and
turns every way it can fail into a ToolError saying so. A command's bus options
(`add_bus_arguments`) are --port, --baud, --protocol and --params FILE: the driver's parameter
file, from which the port, baud rate and protocol (and each joint's protocol) are taken where
--port, --baud and --protocol do not say them, and in which a servo may be named by its joint
(`shoulder` for its joint's id; `bus_settings` resolves them all before the bus is opened).
`connect` pings one servo, reads its firmware version and picks its model's control table; a
`ServoLink` then reads and writes items by their names (the manual's, snake_case), raw or in SI
units (`to_si`, `from_si`: the item's unit as the table states it, e.g. '0.229 rpm' read as
rad/s, 'pulse' as rad, '2.69 mA' as A).
"""

import argparse
import contextlib
from dataclasses import dataclass
import math
import signal
import threading
import time
from typing import Callable, Dict, Iterator, List, Optional, Sequence, Tuple, TypeVar, Union

from dxl_servo_driver import config as driver_config
from dxl_servo_driver import models
from dxl_servo_driver.bus import Bus, BusTrace, FRAMERS
from dxl_servo_driver.errors import CommError, ConfigurationError, PortError, StatusError
from dxl_servo_driver.models import registers
from dxl_servo_driver.models.base import Item, Model, ModelError
from dxl_servo_driver.port import adapter_latency_timer_ms, open_port
from dxl_servo_driver.protocol import MAX_ID
from dxl_servo_driver.tool import yaml_edit
from dxl_servo_driver.tool.common import EXIT_OUTPUT, EXIT_PORT, EXIT_USAGE, ToolError


T = TypeVar('T')
FACTORY_BAUD = 57600
# A tool waits generously for each reply beyond its wire time: the adapter's latency timer is
# 16 ms by default on Linux, and a factory-new servo adds 500 us of Return Delay Time.
DEFAULT_LATENCY_MS = 16.0
FACTORY_RETURN_DELAY_S = 0.0005
# Position items counted from the table's zero (an offset such as homing_offset is not).
_ABSOLUTE = ('position', 'position_limit', 'position_trajectory')
# One of an X table's firmware_version address: where any 2.0 servo says it before its model is
# known (the Protocol 1.0 tables' is read from the table of the model number the ping gave).
_MANUAL_TABLE = models.model_for(1030)


ServoRef = Union[int, str]   # a servo as a command line gives it: an id, or its joint's name


def servo_ref(text: str) -> ServoRef:
    """Return a servo argument: an id (0..MAX_ID), or a joint name for --params to resolve."""
    if text.strip().lstrip('+-').isdigit():
        value = int(text)
        if not 0 <= value <= MAX_ID:
            raise argparse.ArgumentTypeError(f'{value} is not an id (0..{MAX_ID})')
        return value
    if not text:
        raise argparse.ArgumentTypeError('an empty name is neither an id nor a joint')
    return text


# The servo arguments a command may have (an id, --other, --ids): joint names become ids.
_SERVO_ARGS = ('id', 'other', 'ids')


def add_bus_arguments(parser: argparse.ArgumentParser, baud: int = FACTORY_BAUD,
                      protocol: bool = True) -> None:
    """Add --port, --baud, --params and (unless told not to) --protocol to a command's parser."""
    parser.add_argument('--port',
                        help='serial device (e.g. /dev/ttyUSB0) or a virtual_bus pty (needed '
                        "unless --params: the file's port)")
    parser.add_argument('--baud', type=int, metavar='BPS',
                        help=f"baud rate of the bus (default: --params' baud_rate, else {baud})")
    if protocol:
        parser.add_argument('--protocol', type=float, choices=tuple(FRAMERS),
                            help="protocol the servos speak (default: --params' protocol and "
                            "each joint's, else 2.0)")
    parser.add_argument('--params', metavar='FILE',
                        help="the driver's parameter file: its port, baud rate and protocol "
                        'where --port, --baud and --protocol do not say them; a servo may then '
                        'be named by its joint')
    parser.add_argument('--trace', default='', metavar='FILE',
                        help='write every frame sent and received to FILE (`dxl trace FILE` '
                        'decodes it)')
    parser.set_defaults(default_baud=baud, bus_settings=None)


def load_params(path: str) -> driver_config.DriverConfig:
    """Return a driver parameter file's configuration; ToolError (exit 2) saying what is bad."""
    return read_params(path)[1]


def read_params(path: str, label: str = '--params ') -> Tuple[str, driver_config.DriverConfig]:
    """
    Return a driver parameter file's text and configuration; ToolError (exit 2) if it is bad.

    The error names the file as `{label}{path}: ` unless the reason names it already.
    """
    try:
        driver_config.check_parameter_file(path)
        with open(path, encoding='utf-8') as stream:
            text = stream.read()
        return text, driver_config.validate(yaml_edit.parameters_of(text))
    except (ConfigurationError, yaml_edit.EditError, OSError) as exc:
        said = str(exc)
        raise ToolError(said if path in said else f'{label}{path}: {said}', EXIT_USAGE) \
            from None


@dataclass(frozen=True)
class BusSettings:
    """Where a command's servos are: the port, baud rate and protocol, and the file's joints."""

    port: str
    baud_bps: int
    protocol: float
    # id -> protocol of every servo of the --params file (when --protocol did not say one).
    protocols: Dict[int, float]


def bus_settings(args: argparse.Namespace) -> BusSettings:
    """
    Return the bus a command's arguments name, its joint names turned into ids in args.

    --port, --baud and --protocol win; what they leave unsaid comes from --params' file, else
    the defaults (FACTORY_BAUD, Protocol 2.0). Done once (kept in args.bus_settings). ToolError
    (exit 2): no port at all, an unreadable or invalid file, a joint the file does not have.
    """
    if getattr(args, 'bus_settings', None) is not None:
        return args.bus_settings
    path = getattr(args, 'params', None)
    config = load_params(path) if path else None
    for name in _SERVO_ARGS:
        value = getattr(args, name, None)
        if isinstance(value, list):
            setattr(args, name, [_servo_id(item, config, path) for item in value])
        elif value is not None:
            setattr(args, name, _servo_id(value, config, path))
    port = args.port or (config.port if config is not None else None)
    if not port:
        raise ToolError("--port is needed (or --params FILE: the port of the driver's "
                        'parameter file)', EXIT_USAGE)
    protocol = getattr(args, 'protocol', None)
    protocols: Dict[int, float] = {}
    if config is not None and protocol is None:
        for joint in config.joints:
            for servo_id in (joint.servo_id, joint.secondary_id):
                if servo_id is not None:
                    protocols[servo_id] = joint.protocol
    settings = BusSettings(
        port, args.baud or (config.baud_rate if config is not None else args.default_baud),
        protocol if protocol is not None else (config.protocol if config is not None else 2.0),
        protocols)
    args.port, args.baud, args.bus_settings = settings.port, settings.baud_bps, settings
    if hasattr(args, 'protocol'):
        args.protocol = settings.protocol
    return settings


def _servo_id(value: ServoRef, config: Optional[driver_config.DriverConfig],
              path: Optional[str]) -> int:
    """Return the id a servo argument names (a joint's name looked up in --params' file)."""
    if isinstance(value, int):
        return value
    if config is None:
        raise ToolError(f'{value!r} is not an id: a joint name needs --params FILE', EXIT_USAGE)
    try:
        return config.joint(value).servo_id
    except KeyError:
        raise ToolError(f'no joint {value!r} in {path} (its joints: '
                        f'{", ".join(joint.name for joint in config.joints)})',
                        EXIT_USAGE) from None


def open_bus(port: str, baud_bps: int, protocol: float = 2.0,
             return_delay_s: float = FACTORY_RETURN_DELAY_S, trace: str = '') -> Bus:
    """Open a port as a bus (traced to the file trace names, if any); ToolError if it cannot."""
    latency_ms = adapter_latency_timer_ms(port)
    if latency_ms is None:
        latency_ms = DEFAULT_LATENCY_MS
    try:
        raw = open_port(port, baud_bps)
    except PortError as exc:
        raise ToolError(str(exc), EXIT_PORT) from exc
    bus_trace: Optional[BusTrace] = None
    if trace:
        try:
            bus_trace = BusTrace(trace, baud_bps, f'port {port}, Protocol {protocol}')
        except OSError as exc:
            raw.close()
            raise ToolError(f'cannot write the trace {trace}: {exc.strerror or exc}',
                            EXIT_OUTPUT) from exc
    bus = Bus(raw, baud_bps, latency_timer_s=(latency_ms + 2.0) / 1000.0,
              return_delay_s=return_delay_s, framer=FRAMERS[protocol])
    bus.trace_to(bus_trace)
    return bus


def bus_from_args(args: argparse.Namespace) -> Bus:
    """Open the bus the command's --port, --baud, --protocol, --params and --trace name."""
    settings = bus_settings(args)
    bus = open_bus(settings.port, settings.baud_bps, settings.protocol,
                   trace=getattr(args, 'trace', ''))
    for servo_id, protocol in settings.protocols.items():
        bus.speak(servo_id, FRAMERS[protocol])
    return bus


@contextlib.contextmanager
def bus_session(args: argparse.Namespace) -> Iterator[Bus]:
    """Yield bus_from_args(args), closed after; a bus failure in the block is one ToolError."""
    bus = bus_from_args(args)
    try:
        yield bus
    except CommError as exc:
        raise ToolError(str(exc)) from exc
    finally:
        bus.close()


@dataclass
class ServoLink:
    """One servo on a bus, with its model's control table."""

    bus: Bus
    servo_id: int
    model: Model
    firmware: Optional[int]

    def item(self, name: str) -> Item:
        """Return the item of this name; ToolError naming the model when it has none."""
        try:
            return self.model.lookup(name)
        except (KeyError, ModelError) as exc:
            raise ToolError(f'{self.model.name} has no item {name!r}', EXIT_USAGE) from exc

    def read(self, name: str) -> int:
        """Return an item's raw value."""
        item = self.item(name)
        # Confirmed by a second read only where the value does not change by itself.
        steady = not (item.area == 'ram' and item.access == 'R')
        return item.decode(self.bus.read(self.servo_id, item.address, item.size,
                                         confirm=steady))

    def write(self, name: str, value: int) -> None:
        """Write an item's raw value (no checks: the caller checked its range)."""
        item = self.item(name)
        self.bus.write(self.servo_id, item.address, item.encode(value))

    def read_si(self, name: str) -> Tuple[float, str]:
        """Return an item's value in SI units, and the unit."""
        item = self.item(name)
        return to_si(self.model, item, self.read(name))


def connect(bus: Bus, servo_id: int) -> ServoLink:
    """Ping a servo and pick its table; ToolError saying what did not answer or is unknown."""
    try:
        number = retried(lambda: bus.ping(servo_id))
    except CommError as exc:
        raise ToolError(f'id {servo_id} does not answer at {bus.baud_bps} bps in Protocol '
                        f'{bus.default_framer.version}.0: {exc}') from exc
    try:
        where = (models.model_for(number) if number in models.SUPPORTED
                 else _MANUAL_TABLE).item('firmware_version')
        firmware: Optional[int] = where.decode(
            retried(lambda: bus.read(servo_id, where.address, where.size)))
        model = models.model_for(number, firmware)
    except ModelError as exc:
        raise ToolError(f'id {servo_id}: {exc}') from exc
    except CommError as exc:
        raise ToolError(f'id {servo_id} stopped answering: {exc}') from exc
    return ServoLink(bus, servo_id, model, firmware)


def _scale(model: Model, item: Item, timed: bool = False) -> Tuple[float, str]:
    """
    Return (SI per raw unit, SI unit name) of an item, (1, its unit) when it has no SI form.

    timed: the servo's Drive Mode makes its profile registers times (registers.time_based), in
    ms whatever unit the table gives them as speeds.
    """
    if timed and model.role_of(item.name) in registers.PROFILE_REGISTERS:
        return 1e-3, 's'
    unit = item.unit
    if unit == 'pulse':
        return 2.0 * math.pi / model.pulses_per_rev, 'rad'
    number, _, name = unit.partition(' ')
    try:
        factor = float(number)
    except ValueError:
        return 1.0, unit
    if name == 'rpm':
        return factor * 2.0 * math.pi / 60.0, 'rad/s'
    if name == 'mA':
        return factor / 1000.0, 'A'
    if name == 'V':
        return factor, 'V'
    if name == 'us':
        return factor * 1e-6, 's'
    if name == 'ms':
        return factor * 1e-3, 's'
    if name == '%':
        return factor / 100.0, 'ratio'
    if name == 'rev/min^2':
        return factor * 2.0 * math.pi / 3600.0, 'rad/s^2'
    return 1.0, unit


def to_si(model: Model, item: Item, raw: int, timed: bool = False) -> Tuple[float, str]:
    """Return a raw value in SI units (positions from the table's zero), and the unit."""
    factor, unit = _scale(model, item, timed)
    if unit == 'rad' and item.name.endswith(_ABSOLUTE):
        return (raw - model.position_zero_raw) * factor, unit
    return raw * factor, unit


def from_si(model: Model, item: Item, value: float, timed: bool = False) -> int:
    """Return the raw value nearest to an SI value (the inverse of to_si)."""
    factor, unit = _scale(model, item, timed)
    if unit == 'rad' and item.name.endswith(_ABSOLUTE):
        return int(round(value / factor)) + model.position_zero_raw
    return int(round(value / factor))


class Saved:
    """
    Items of one servo read now and written back by restore(): what a command changes for a while.

    restore() writes back only what differs, EEPROM items with torque off (the servo refuses
    them otherwise), torque_enable last; every item it could not restore is named in one
    ToolError. Items the model lacks are skipped.
    """

    def __init__(self, link: ServoLink, names: Sequence[str]) -> None:
        self.link = link
        self.values: Dict[str, int] = {}
        try:
            for name in names:
                if link.model.has(name):
                    self.values[name] = retried(lambda: link.read(name))
        except CommError as exc:
            raise ToolError(f'id {link.servo_id} stopped answering: {exc}') from exc

    def restore(self) -> None:
        """Write back every saved item that changed; ToolError naming those that failed."""
        link = self.link
        failed: List[str] = []
        try:
            now = {name: retried(lambda: link.read(name)) for name in self.values}
        except CommError as exc:
            raise ToolError(f'id {link.servo_id} stopped answering, state not restored '
                            f'({", ".join(self.values)}): {exc}') from exc
        changed = [name for name in self.values
                   if name != 'torque_enable' and now[name] != self.values[name]]
        # Torque goes off first when it was off (a goal written back must not move the
        # servo) or when an EEPROM item is to be written.
        if now.get('torque_enable') and (self.values.get('torque_enable') == 0 or any(
                link.item(name).area == 'eeprom' for name in changed)):
            try:
                retried(lambda: link.write('torque_enable', 0))
                now['torque_enable'] = 0
            except CommError as exc:
                failed.append(f'torque_enable ({exc})')
        for name in changed:
            try:
                retried(lambda: link.write(name, self.values[name]))
            except CommError as exc:
                failed.append(f'{name} ({exc})')
        torque = self.values.get('torque_enable')
        if torque is not None and now.get('torque_enable') != torque:
            try:
                retried(lambda: link.write('torque_enable', torque))
            except CommError as exc:
                failed.append(f'torque_enable ({exc})')
        if failed:
            raise ToolError(f'id {link.servo_id}: could not restore {"; ".join(failed)}')


# A tool's transaction is tried ATTEMPTS times, and for PATIENCE_S at least, before its failure
# counts: its deadlines are a bus's (the latency timer and a few ms), and a busy computer can
# hold a reply up longer than that several times in a row. A servo that really is silent costs
# an interactive command a second.
ATTEMPTS = 3
PATIENCE_S = 1.0


def retried(call: Callable[[], T], attempts: int = ATTEMPTS,
            patience_s: float = PATIENCE_S) -> T:
    """Return call(), tried again on a CommError (a reply lost or corrupted); see PATIENCE_S."""
    give_up_s = time.monotonic() + patience_s
    tries = 0
    while True:
        tries += 1
        try:
            return call()
        except StatusError:
            raise   # the servo answered: no
        except CommError:
            if tries >= attempts and time.monotonic() >= give_up_s:
                raise


def read_retried(link: ServoLink, name: str) -> int:
    """Return an item's raw value (tried again if a reply is lost)."""
    return retried(lambda: link.read(name))


def read_present(link: ServoLink) -> int:
    """Return Present Position read once (it may be changing: no confirming second read)."""
    item = link.item('present_position')
    data = retried(lambda: link.bus.read_fresh(link.servo_id, item.address, item.size))[0]
    return item.decode(data)


def write_retried(link: ServoLink, name: str, value: int) -> None:
    """Write an item's raw value (tried again if a reply is lost: a write is idempotent)."""
    retried(lambda: link.write(name, value))


@contextlib.contextmanager
def uninterrupted() -> Iterator[None]:
    """
    Hold Ctrl-C off for a block (a restore that must finish); raise it after, if it came.

    Only in the main thread (where Python runs signal handlers); elsewhere the block runs as is.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    came: List[int] = []
    before = signal.signal(signal.SIGINT, lambda signum, frame: came.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, before)
    if came:
        raise KeyboardInterrupt
