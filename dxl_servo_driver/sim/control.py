"""
Control lines of `virtual_bus` (fault injection and inspection), parsed and executed.

Pure: no I/O. `parse` turns a line into a Command or raises ControlError; `execute` runs a Command
against a bus and returns the one answer line; `handle_line` does both and never raises.

Commands (README.md, The simulator; plus inspection):
  drop ID PROBABILITY          status packets of ID lost with that probability (0..1)
  corrupt ID PROBABILITY       status packet bytes of ID altered with that probability (0..1)
  error ID KIND                latch a hardware error: overload|overheat|voltage|encoder|shock
  powercycle ID                power cut and back
  unplug ID / plug ID          servo leaves / rejoins the bus
  load ID NM                   resisting torque at the horn, N*m (>= 0)
  voltage ID VOLTS             input voltage, V (>= 0)
  tick ID MS                   Realtime Tick set to MS (0..32767) now, counting on from there
  get ID NAME                  one register, by snake_case name or decimal address (an address
                               is looked up in that servo's model's table)
  dump ID                      every register, one line
  stats                        reply pacing statistics
  help                         this list
"""

from dataclasses import dataclass, field
import math
from typing import Callable, Protocol

from dxl_servo_driver.models import ALL_MODELS, Model
from dxl_servo_driver.protocol import MAX_ID
from dxl_servo_driver.sim.memory import MANUAL_MODEL

MAX_SERVO_ID = MAX_ID  # 253..255 are reserved / broadcast in Protocol 2.0
MAX_TICK_MS = MANUAL_MODEL.item('realtime_tick').maximum   # the Realtime Tick's range
# The words of `error ID KIND` (public: README.md) and the Hardware Error Status bit each one
# latches, by the model's name for it (models.Model.hardware_error_bits has the bit values).
ERROR_KINDS: dict[str, str] = {
    'overload': 'overload', 'overheat': 'overheating', 'voltage': 'input_voltage',
    'encoder': 'motor_encoder', 'shock': 'electrical_shock',
}
_KIND_WORDS = '|'.join(ERROR_KINDS)
HELP_TEXT = ('commands: drop ID P | corrupt ID P'
             f' | error ID {_KIND_WORDS} | powercycle ID'
             ' | unplug ID | plug ID | load ID NM | voltage ID VOLTS | tick ID MS'
             ' | get ID NAME|ADDRESS | dump ID | stats | help')

# name -> argument kinds after the command word; 'id' servo id, 'prob' 0..1, 'nonneg' float >= 0,
# 'kind' one of ERROR_KINDS, 'register' name or address, 'tick' 0..32767
_SIGNATURES: dict[str, tuple[str, ...]] = {
    'drop': ('id', 'prob'),
    'corrupt': ('id', 'prob'),
    'error': ('id', 'kind'),
    'powercycle': ('id',),
    'unplug': ('id',),
    'plug': ('id',),
    'load': ('id', 'nonneg'),
    'voltage': ('id', 'nonneg'),
    'tick': ('id', 'tick'),
    'get': ('id', 'register'),
    'dump': ('id',),
    'stats': (),
    'help': (),
}
_USAGE: dict[str, str] = {
    'drop': 'drop ID PROBABILITY',
    'corrupt': 'corrupt ID PROBABILITY',
    'error': f'error ID {_KIND_WORDS}',
    'powercycle': 'powercycle ID',
    'unplug': 'unplug ID',
    'plug': 'plug ID',
    'load': 'load ID NM',
    'voltage': 'voltage ID VOLTS',
    'tick': 'tick ID MS',
    'get': 'get ID NAME|ADDRESS',
    'dump': 'dump ID',
    'stats': 'stats',
    'help': 'help',
}


class ControlError(ValueError):
    """A control line that cannot be parsed or executed; str() is the message."""


class ControlledBus(Protocol):
    """The SimBus methods the control lines use."""

    def read_register(self, servo_id: int, name: str) -> int:
        """Read one register."""
        ...

    def registers(self, servo_id: int) -> dict[str, int]:
        """Read every register."""
        ...

    def model(self, servo_id: int) -> Model:
        """Return the servo's model."""
        ...

    def set_drop(self, servo_id: int, probability: float) -> None:
        """Lose status packets."""
        ...

    def set_corrupt(self, servo_id: int, probability: float) -> None:
        """Alter status packets."""
        ...

    def inject_error(self, servo_id: int, kind: str) -> None:
        """Latch a hardware error."""
        ...

    def powercycle(self, servo_id: int) -> None:
        """Power cut and back."""
        ...

    def unplug(self, servo_id: int) -> None:
        """Leave the bus."""
        ...

    def plug(self, servo_id: int) -> None:
        """Rejoin the bus."""
        ...

    def set_load(self, servo_id: int, load_nm: float) -> None:
        """Set the resisting torque."""
        ...

    def set_voltage(self, servo_id: int, volts: float) -> None:
        """Set the input voltage."""
        ...

    def set_tick(self, servo_id: int, tick_ms: int) -> None:
        """Set the Realtime Tick."""
        ...


@dataclass(frozen=True)
class Command:
    """A parsed control line."""

    name: str
    servo_id: int | None = None
    value: float | None = None      # probability, N*m or volts
    text: str | None = None         # error kind or register name (addresses resolved to names)
    # The address a register was named by: resolved again against the servo's own model when
    # the line runs (126 is present_current on most models, present_load on an XL430).
    address: int | None = field(default=None, compare=False)


def _parse_id(token: str) -> int:
    try:
        servo_id = int(token, 10)
    except ValueError:
        raise ControlError(f'bad servo id {token!r}: expected an integer 0..{MAX_SERVO_ID}')
    if not 0 <= servo_id <= MAX_SERVO_ID:
        raise ControlError(f'bad servo id {servo_id}: expected 0..{MAX_SERVO_ID}')
    return servo_id


def _parse_float(token: str, what: str) -> float:
    try:
        value = float(token)
    except ValueError:
        raise ControlError(f'bad {what} {token!r}: expected a number')
    if not math.isfinite(value):
        raise ControlError(f'bad {what} {token!r}: expected a finite number')
    return value


# The tables a register name or address is looked up in: the XM430 manual's model first.
_TABLES: tuple[Model, ...] = (MANUAL_MODEL, *ALL_MODELS)


def _parse_register(token: str) -> tuple[str, int | None]:
    """Return (name, address the token gave or None) of a register some supported model has."""
    if token.isdigit():
        address = int(token, 10)
        for table in _TABLES:
            try:
                return table.by_address(address).name, address
            except KeyError:
                continue
        raise ControlError(f'no register starts at address {address}')
    name = token.lower()
    if not any(table.has(name) for table in _TABLES):
        raise ControlError(f'unknown register {token!r}')
    return name, None


def parse(line: str) -> Command:
    """Parse one control line; raise ControlError with a clear message when it is bad."""
    tokens = line.split()
    if not tokens:
        raise ControlError('empty line (try "help")')
    name = tokens[0].lower()
    signature = _SIGNATURES.get(name)
    if signature is None:
        raise ControlError(f'unknown command {tokens[0]!r} (try "help")')
    args = tokens[1:]
    if len(args) != len(signature):
        raise ControlError(f'usage: {_USAGE[name]}')
    servo_id: int | None = None
    value: float | None = None
    text: str | None = None
    address: int | None = None
    for kind, token in zip(signature, args):
        if kind == 'id':
            servo_id = _parse_id(token)
        elif kind == 'prob':
            value = _parse_float(token, 'probability')
            if not 0.0 <= value <= 1.0:
                raise ControlError(f'bad probability {token!r}: expected 0..1')
        elif kind == 'nonneg':
            what = 'torque (N*m)' if name == 'load' else 'voltage (V)'
            value = _parse_float(token, what)
            if value < 0.0:
                raise ControlError(f'bad {what} {token!r}: expected >= 0')
        elif kind == 'tick':
            value = _parse_float(token, 'tick (ms)')
            if value != int(value) or not 0 <= value <= MAX_TICK_MS:
                raise ControlError(f'bad tick (ms) {token!r}: expected an integer '
                                   f'0..{MAX_TICK_MS}')
        elif kind == 'kind':
            text = token.lower()
            if text not in ERROR_KINDS:
                raise ControlError(
                    f'bad error kind {token!r}: expected one of {_KIND_WORDS}')
        else:  # 'register'
            text, address = _parse_register(token)
    return Command(name, servo_id, value, text, address)


def execute(command: Command, bus: ControlledBus,
            stats_line: Callable[[], str] | None = None) -> str:
    """
    Run a parsed command; return its 'ok …' answer.

    Errors reported by the bus (ValueError, KeyError: unknown id, bad argument) become
    ControlError.
    """
    name = command.name
    sid = command.servo_id
    try:
        if name == 'help':
            return f'ok {HELP_TEXT}'
        if name == 'stats':
            text = stats_line() if stats_line is not None else 'replies=0'
            return f'ok stats {text}'
        assert sid is not None  # every other command has an id (parse guarantees it)
        valued = {'drop': bus.set_drop, 'corrupt': bus.set_corrupt, 'load': bus.set_load,
                  'voltage': bus.set_voltage}
        if name in valued:
            assert command.value is not None
            valued[name](sid, command.value)
            return f'ok {name} {sid} {command.value:g}'
        if name == 'error':
            assert command.text is not None
            bus.inject_error(sid, command.text)
            return f'ok error {sid} {command.text}'
        if name == 'tick':
            assert command.value is not None
            bus.set_tick(sid, int(command.value))
            return f'ok tick {sid} {int(command.value)}'
        if name == 'powercycle':
            bus.powercycle(sid)
        elif name == 'unplug':
            bus.unplug(sid)
        elif name == 'plug':
            bus.plug(sid)
        elif name == 'get':
            register = _register_of(command, bus, sid)
            return f'ok get {sid} {register}={bus.read_register(sid, register)}'
        elif name == 'dump':
            regs = bus.registers(sid)
            return f'ok dump {sid} ' + ' '.join(f'{k}={v}' for k, v in regs.items())
        else:  # pragma: no cover - parse() admits only the names above
            raise ControlError(f'unknown command {name!r}')
        return f'ok {name} {sid}'
    except ControlError:
        raise
    except KeyError as exc:
        raise ControlError(_message(exc)) from exc
    except ValueError as exc:
        raise ControlError(_message(exc)) from exc


def _register_of(command: Command, bus: ControlledBus, servo_id: int) -> str:
    """Return the register a get names, an address looked up in the servo's model's table."""
    assert command.text is not None
    if command.address is None:
        return command.text
    model = bus.model(servo_id)
    try:
        return model.by_address(command.address).name
    except KeyError:
        raise ControlError(f'servo {servo_id} ({model.label}) has no register starting at '
                           f'address {command.address}') from None


def handle_line(line: str, bus: ControlledBus,
                stats_line: Callable[[], str] | None = None) -> str | None:
    """
    Parse and run one line; return the single answer line ('ok …' or 'error: …').

    Blank lines and '#' comments get no answer (None). Nothing raised by the bus escapes: an
    unexpected exception is reported as an error line.
    """
    stripped = line.strip()
    if not stripped or stripped.startswith('#'):
        return None
    try:
        return execute(parse(stripped), bus, stats_line)
    except ControlError as exc:
        return f'error: {exc}'
    except Exception as exc:  # noqa: B902 - a control line must never kill the server
        return f'error: internal: {type(exc).__name__}: {_message(exc)}'


def _message(exc: BaseException) -> str:
    """Return an exception's message on one line (KeyError quotes its argument)."""
    text = str(exc.args[0]) if isinstance(exc, KeyError) and exc.args else str(exc)
    return ' '.join(text.split()) or type(exc).__name__
