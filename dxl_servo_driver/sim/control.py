"""
Control lines of `virtual_bus` (fault injection and inspection): one table, parsed and executed.

COMMANDS is the one list of the console's commands. Each row (a Spec) holds the command's name,
its arguments (each with its type and range), its one-line description and the function that
carries it out. The console (handle_line), its `help` answer (HELP_TEXT), `virtual_bus --help`
(commands_help) and the docs (commands_markdown) all read it: a command is added as a row, beside
the SimBus or FaultEngine method it calls.

Four groups of commands: faults of one servo (SimBus: `drop ID P`, `error ID KIND`, ...),
faults of the USB adapter between the servos and the pty (`adapter ...`: the FaultEngine of
sim/fault_engine.py, which acts on every reply), a hand on a servo's horn (`turn`, `stops`),
and inspection (`get`, `dump`, `stats`, `help`).

A servo is named by its id when exactly one servo (plugged or not) has it, or by `#N`, the N-th
servo of `--ids` (1-based), which stays that servo after its id changes: several servos may
share an id (every new servo is id 1), and a shared id is an error naming their `#N`s. The
argument's word stays ID in the usages (the contract between the simulator's users calls it
REF). An argument may be optional (shown `[WORD]`, last), and one may stand for the rest of the
line in another form (`stops ID MIN_RAD MAX_RAD|off`: `off` in place of MIN_RAD MAX_RAD).

Pure: no I/O. `parse` turns a line into a Command or raises ControlError; `execute` runs a Command
against a bus (and the adapter in front of it) and returns the one answer line; `handle_line`
does both and never raises.
"""

from dataclasses import dataclass, field
import math
from typing import Callable, Iterator

from dxl_servo_driver.models import ALL_MODELS, Model
from dxl_servo_driver.protocol import MAX_ID
from dxl_servo_driver.sim.bus import ERROR_KINDS, ServoRef, SimBus, TURN_SECONDS
from dxl_servo_driver.sim.fault_engine import FaultEngine
from dxl_servo_driver.sim.memory import MANUAL_MODEL

MAX_SERVO_ID = MAX_ID  # 253..255 are reserved / broadcast in Protocol 2.0
MAX_TICK_MS = MANUAL_MODEL.item('realtime_tick').maximum   # the Realtime Tick's range
MAX_SLOTS = 1000   # the #N a line may name (a bus has as many servos as --ids lists)
_KIND_WORDS = '|'.join(ERROR_KINDS)


class ControlError(ValueError):
    """A control line that cannot be parsed or executed; str() is the message."""


@dataclass(frozen=True)
class Command:
    """A parsed control line."""

    name: str
    servo_id: int | None = None     # the servo by id (None: by slot, or no servo)
    value: float | None = None      # the first number: probability, N*m, volts, ms, bytes
    text: str | None = None         # error kind, on|off or register name (addresses resolved)
    # The address a register was named by: resolved again against the servo's own model when
    # the line runs (126 is present_current on most models, present_load on an XL430).
    address: int | None = field(default=None, compare=False)
    extra: tuple[float, ...] = ()   # the numbers after the first (a range's bounds)
    slot: int | None = None         # the servo as #N, the N-th of the bus (1-based)

    @property
    def servo(self) -> int | str | None:
        """Return the servo the line names: its id, or '#N' (SimBus's ServoRef)."""
        return self.servo_id if self.slot is None else f'#{self.slot}'

    @property
    def numbers(self) -> tuple[float, ...]:
        """Return every number of the line, in order."""
        return self.extra if self.value is None else (self.value, *self.extra)


# ---- argument types -------------------------------------------------------------------------
@dataclass(frozen=True)
class Arg:
    """One argument of a command: its word in the usage, its type and range, how it is read."""

    word: str                       # in the usage and its error: PROBABILITY
    meaning: str                    # its type and range, for --help and the docs
    read: Callable[[str], object]   # token -> value; ControlError when it is bad
    slot: str                       # the Command field it fills: id, number, text or register
    short: str = ''                 # in the one-line help answer, when shorter than word
    optional: bool = False          # may be left out (the last arguments only)
    # A word that may stand in its place and end the line (the other form of the command).
    instead: str = ''

    @property
    def help_word(self) -> str:
        """Return its word in the one-line help answer."""
        return self.short or self.word


def _parse_servo(token: str) -> int | tuple[str, int]:
    """Return an id, or ('#', N) for the N-th servo of the bus."""
    if not token.startswith('#'):
        return _parse_id(token)
    digits = token[1:]
    if not digits.isdigit() or not 1 <= int(digits) <= MAX_SLOTS:
        raise ControlError(f'bad servo {token!r}: expected an id 0..{MAX_SERVO_ID} or #N, '
                           f'N 1..{MAX_SLOTS}')
    return '#', int(digits)


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


def _bounds_text(low: float, high: float, integer: bool) -> str:
    bounds = f'{low:g}..{high:g}' if math.isfinite(high) else f'>= {low:g}'
    return f'an integer {bounds}' if integer else bounds


def _number(what: str, low: float, high: float = math.inf,
            integer: bool = False) -> Callable[[str], float]:
    """Return a reader of a number within low..high (a whole one if integer), kept as a float."""
    expected = _bounds_text(low, high, integer)

    def read(token: str) -> float:
        value = _parse_float(token, what)
        if integer and value != int(value) or not low <= value <= high:
            raise ControlError(f'bad {what} {token!r}: expected {expected}')
        return value
    return read


def _word(what: str, words: tuple[str, ...]) -> Callable[[str], str]:
    """Return a reader of one of words, any case."""
    def read(token: str) -> str:
        text = token.lower()
        if text not in words:
            raise ControlError(f'bad {what} {token!r}: expected one of {"|".join(words)}')
        return text
    return read


def _switch(token: str) -> str:
    text = token.lower()
    if text not in ('on', 'off'):
        raise ControlError(f'bad switch {token!r}: expected on|off')
    return text


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


def _ms(word: str) -> Arg:
    return Arg(word, 'milliseconds, >= 0', _number('duration (ms)', 0.0), 'number')


SERVO_ID = Arg('ID', f'a servo: its id, 0..{MAX_SERVO_ID}, when one servo has it, or #N, the '
               'N-th of --ids', _parse_servo, 'id')
PROBABILITY = Arg('PROBABILITY', 'probability, 0..1', _number('probability', 0.0, 1.0), 'number',
                  short='P')
TORQUE = Arg('NM', 'torque in N*m, >= 0', _number('torque (N*m)', 0.0), 'number')
VOLTS = Arg('VOLTS', 'supply voltage in V, >= 0', _number('voltage (V)', 0.0), 'number')
TICK = Arg('MS', f'Realtime Tick in ms, {_bounds_text(0, MAX_TICK_MS, True)}',
           _number('tick (ms)', 0, MAX_TICK_MS, integer=True), 'number')
ERROR_KIND = Arg(_KIND_WORDS, 'the hardware error latched',
                 _word('error kind', tuple(ERROR_KINDS)), 'text')
REGISTER = Arg('NAME|ADDRESS', "a register: snake_case name, or decimal address in the servo's "
               "model's table", _parse_register, 'register')
SWITCH = Arg('on|off', 'on or off', _switch, 'text')
DURATION_MS = _ms('MS')
MIN_MS = _ms('MIN_MS')
MAX_MS = _ms('MAX_MS')
GAP_MS = _ms('GAP_MS')
PIECE_BYTES = Arg('BYTES', 'bytes a piece, an integer >= 0 (0: whole)',
                  _number('size (bytes)', 0, integer=True), 'number')
MIN_BYTES = Arg('MIN_BYTES', 'bytes, an integer >= 1', _number('size (bytes)', 1, integer=True),
                'number')
MAX_BYTES = Arg('MAX_BYTES', 'bytes, an integer >= 1', _number('size (bytes)', 1, integer=True),
                'number')
ANGLE = Arg('RAD', 'servo radians (Present Position = center + RAD / rad per pulse), any '
            'number of turns', _number('angle (rad)', -math.inf), 'number')
TURN_TIME = Arg('SECONDS', f'seconds the turn takes, >= 0 (default {TURN_SECONDS:g}; 0: at once)',
                _number('time (s)', 0.0), 'number', optional=True)
STOP_MIN = Arg('MIN_RAD', 'servo radians', _number('angle (rad)', -math.inf), 'number',
               instead='off')
STOP_MAX = Arg('MAX_RAD', 'servo radians', _number('angle (rad)', -math.inf), 'number')


# ---- what the commands act on ---------------------------------------------------------------
@dataclass(frozen=True)
class Target:
    """What control lines act on: the servos' bus, the adapter before the host, the pacing."""

    bus: SimBus
    stats_line: Callable[[], str] | None = None
    adapter: FaultEngine | None = None


Run = Callable[[Target, Command], str | None]


@dataclass(frozen=True)
class Spec:
    """One console command: a row of the table."""

    name: str                   # one word, or a group's word and the command's ('adapter late')
    args: tuple[Arg, ...]
    summary: str                # one line: what it does
    # Carries it out; returns the answer after 'ok ', or None: the command itself, normalised.
    run: Run
    group: str

    @property
    def usage(self) -> str:
        """Return the usage: the name and the arguments' words."""
        return _usage(self.name, self.args, [arg.word for arg in self.args])

    @property
    def help_usage(self) -> str:
        """Return the usage in the one-line help answer."""
        return _usage(self.name, self.args, [arg.help_word for arg in self.args])


def _usage(name: str, args: tuple[Arg, ...], words: list[str]) -> str:
    """Return a usage: optional words in brackets, a word's stand-in after the rest (|off)."""
    out = [name]
    for number, (arg, word) in enumerate(zip(args, words)):
        out.append(f'[{word}]' if arg.optional else word)
        if arg.instead:
            out += words[number + 1:]
            out[-1] += f'|{arg.instead}'
            break
    return ' '.join(out)


def _sid(command: Command) -> ServoRef:
    servo = command.servo   # parse() fills what the row's arguments name
    assert servo is not None
    return servo


def _value(command: Command) -> float:
    assert command.value is not None
    return command.value


def _adapter(target: Target) -> FaultEngine:
    if target.adapter is None:
        raise ControlError("no adapter here: the adapter commands act on virtual_bus's pty")
    return target.adapter


def _span(command: Command, first: int, unit: str) -> tuple[float, float]:
    """Return the (MIN, MAX) pair of numbers from position first; ControlError if MIN > MAX."""
    low, high = command.numbers[first:first + 2]
    if low > high:
        raise ControlError(f'bad range {low:g}..{high:g} {unit}: expected MIN <= MAX')
    return low, high


def _get(target: Target, command: Command) -> str:
    servo_id = _sid(command)
    register = _register_of(command, target.bus, servo_id)
    return f'get {servo_id} {register}={target.bus.read_register(servo_id, register)}'


def _turn(target: Target, command: Command) -> None:
    numbers = command.numbers
    seconds = numbers[1] if len(numbers) > 1 else TURN_SECONDS
    target.bus.turn(_sid(command), numbers[0], seconds)


def _stops(target: Target, command: Command) -> None:
    if command.text == 'off':
        target.bus.set_stops(_sid(command), None)
        return
    target.bus.set_stops(_sid(command), _span(command, 0, 'rad'))


def _dump(target: Target, command: Command) -> str:
    servo_id = _sid(command)
    regs = target.bus.registers(servo_id)
    return f'dump {servo_id} ' + ' '.join(f'{k}={v}' for k, v in regs.items())


def _stats(target: Target, command: Command) -> str:
    text = target.stats_line() if target.stats_line is not None else 'replies=0'
    return f'stats {text}'


def _adapter_stats(target: Target, command: Command) -> str:
    counts = _adapter(target).counts()
    return 'adapter stats ' + ' '.join(f'{name}={count}' for name, count in counts.items())


def _noise(target: Target, command: Command) -> None:
    low, high = _span(command, 1, 'bytes')
    _adapter(target).set(noise_probability=_value(command), noise_bytes=(int(low), int(high)))


SERVO = 'faults of one servo'
HAND = 'a hand on the horn (servo radians: what the driver reports with no offset or ratio)'
ADAPTER = 'faults of the USB adapter between the servos and the pty (every reply)'
INSPECTION = 'inspection'

COMMANDS: tuple[Spec, ...] = (
    Spec('drop', (SERVO_ID, PROBABILITY), "lose ID's status packets with that probability",
         lambda t, c: t.bus.set_drop(_sid(c), _value(c)), SERVO),
    Spec('corrupt', (SERVO_ID, PROBABILITY),
         "flip a bit of ID's status packets with that probability (the CRC fails)",
         lambda t, c: t.bus.set_corrupt(_sid(c), _value(c)), SERVO),
    Spec('error', (SERVO_ID, ERROR_KIND), 'latch a hardware error in ID',
         lambda t, c: t.bus.inject_error(_sid(c), c.text or ''), SERVO),
    Spec('powercycle', (SERVO_ID,), "cut ID's power and restore it",
         lambda t, c: t.bus.powercycle(_sid(c)), SERVO),
    Spec('unplug', (SERVO_ID,), 'take ID off the bus (and off the power)',
         lambda t, c: t.bus.unplug(_sid(c)), SERVO),
    Spec('plug', (SERVO_ID,), 'put ID back on the bus: a power-on',
         lambda t, c: t.bus.plug(_sid(c)), SERVO),
    Spec('load', (SERVO_ID, TORQUE), "a resisting torque at ID's horn",
         lambda t, c: t.bus.set_load(_sid(c), _value(c)), SERVO),
    Spec('voltage', (SERVO_ID, VOLTS), "ID's input voltage",
         lambda t, c: t.bus.set_voltage(_sid(c), _value(c)), SERVO),
    Spec('tick', (SERVO_ID, TICK), "set ID's Realtime Tick to MS now, counting on from there",
         lambda t, c: t.bus.set_tick(_sid(c), int(_value(c))), SERVO),
    Spec('adapter echo', (SWITCH,), 'the host hears its own bytes back before the replies',
         lambda t, c: _adapter(t).set(echo=c.text == 'on'), ADAPTER),
    Spec('adapter echo-pieces', (PIECE_BYTES, GAP_MS),
         'the echo comes in pieces of BYTES (0: whole), GAP_MS apart',
         lambda t, c: _adapter(t).set(echo_chunk=int(c.numbers[0]), echo_gap_ms=c.numbers[1]),
         ADAPTER),
    Spec('adapter late', (PROBABILITY, MIN_MS, MAX_MS),
         'a reply brings back a copy of an earlier one, MIN_MS..MAX_MS later',
         lambda t, c: _adapter(t).set(late_probability=_value(c), late_ms=_span(c, 1, 'ms')),
         ADAPTER),
    Spec('adapter duplicate', (PROBABILITY,), 'a reply is delivered twice in a row',
         lambda t, c: _adapter(t).set(duplicate_probability=_value(c)), ADAPTER),
    Spec('adapter truncate', (PROBABILITY,), 'a reply loses its tail',
         lambda t, c: _adapter(t).set(truncate_probability=_value(c)), ADAPTER),
    Spec('adapter noise', (PROBABILITY, MIN_BYTES, MAX_BYTES),
         'MIN_BYTES..MAX_BYTES of garbage come before a reply', _noise, ADAPTER),
    Spec('adapter drop', (PROBABILITY,), 'a reply vanishes in the adapter',
         lambda t, c: _adapter(t).set(drop_probability=_value(c)), ADAPTER),
    Spec('adapter delay', (MIN_MS, MAX_MS), 'every reply comes MIN_MS..MAX_MS late, in order',
         lambda t, c: _adapter(t).set(delay_ms=_span(c, 0, 'ms')), ADAPTER),
    Spec('adapter freezes', (PROBABILITY, MIN_MS, MAX_MS),
         'a reply freezes the adapter for MIN_MS..MAX_MS (held replies follow at once)',
         lambda t, c: _adapter(t).set(freeze_probability=_value(c), freeze_ms=_span(c, 1, 'ms')),
         ADAPTER),
    Spec('adapter freeze', (DURATION_MS,), 'freeze the adapter for MS from now',
         lambda t, c: _adapter(t).freeze(_value(c) / 1000.0), ADAPTER),
    Spec('adapter clear', (), 'every adapter fault off, a freeze ended',
         lambda t, c: _adapter(t).clear(), ADAPTER),
    Spec('adapter stats', (), 'what the adapter saw and did, counted', _adapter_stats, ADAPTER),
    Spec('turn', (SERVO_ID, ANGLE, TURN_TIME),
         "a hand turns ID's horn to RAD at constant speed over SECONDS and lets go (torque off "
         'only; it stops at an end stop)', _turn, HAND),
    Spec('stops', (SERVO_ID, STOP_MIN, STOP_MAX),
         "mechanical end stops at MIN_RAD..MAX_RAD that nothing moves ID's horn past (a motor "
         'pushing into one stalls); off: none', _stops, HAND),
    Spec('get', (SERVO_ID, REGISTER), 'read one register of ID', _get, INSPECTION),
    Spec('dump', (SERVO_ID,), 'every register of ID, one line', _dump, INSPECTION),
    Spec('stats', (), 'reply pacing statistics', _stats, INSPECTION),
    Spec('help', (), 'this list', lambda t, c: _help(), INSPECTION),
)
_BY_NAME = {spec.name: spec for spec in COMMANDS}


def _second_words() -> dict[str, list[str]]:
    """Return the words that start a command of two words ('adapter'), each with its seconds."""
    words: dict[str, list[str]] = {}
    for spec in COMMANDS:
        if ' ' in spec.name:
            first, second = spec.name.split(' ', 1)
            words.setdefault(first, []).append(second)
    return words


_GROUPS = _second_words()
HELP_TEXT = 'commands: ' + ' | '.join(spec.help_usage for spec in COMMANDS)


def _help() -> str:
    return HELP_TEXT


# ---- parsing and running ---------------------------------------------------------------------
def _spec_of(tokens: list[str]) -> tuple[Spec, list[str]]:
    """Return the row a line's tokens name and the argument tokens after its name."""
    word = tokens[0].lower()
    if word in _GROUPS:
        if len(tokens) < 2:
            raise ControlError(f'usage: {word} {"|".join(_GROUPS[word])} ...')
        spec = _BY_NAME.get(f'{word} {tokens[1].lower()}')
        if spec is None:
            raise ControlError(f'unknown command {" ".join(tokens[:2])!r} (try "help")')
        return spec, tokens[2:]
    spec = _BY_NAME.get(word)
    if spec is None:
        raise ControlError(f'unknown command {tokens[0]!r} (try "help")')
    return spec, tokens[1:]


def parse(line: str) -> Command:
    """Parse one control line; raise ControlError with a clear message when it is bad."""
    tokens = line.split()
    if not tokens:
        raise ControlError('empty line (try "help")')
    spec, args = _spec_of(tokens)
    if not _fits(spec.args, args):
        raise ControlError(f'usage: {spec.usage}')
    servo_id: int | None = None
    slot: int | None = None
    numbers: list[float] = []
    text: str | None = None
    address: int | None = None
    for arg, token in zip(spec.args, args):
        if arg.instead and token.lower() == arg.instead:
            text = arg.instead   # the other form: this word ends the line
            break
        value = arg.read(token)
        if arg.slot == 'register':      # (name, the address it was named by or None)
            assert isinstance(value, tuple)
            text, address = value
        elif arg.slot == 'id':
            if isinstance(value, tuple):
                slot = value[1]
            else:
                assert isinstance(value, int)
                servo_id = value
        elif arg.slot == 'number':
            assert isinstance(value, float)
            numbers.append(value)
        else:
            assert isinstance(value, str)
            text = value
    first = numbers[0] if numbers else None
    return Command(spec.name, servo_id, first, text, address, tuple(numbers[1:]), slot)


def _fits(args: tuple[Arg, ...], tokens: list[str]) -> bool:
    """Return whether a line's argument tokens are as many as the row's arguments take."""
    for number, arg in enumerate(args):
        if arg.instead and number < len(tokens) and tokens[number].lower() == arg.instead:
            return len(tokens) == number + 1
    required = sum(1 for arg in args if not arg.optional)
    return required <= len(tokens) <= len(args)


def _said(spec: Spec, command: Command) -> str:
    """Return a command as its answer repeats it: the name and the arguments, normalised."""
    numbers: Iterator[float] = iter(command.numbers)
    words = [spec.name]
    for arg in spec.args:
        if arg.instead and command.text == arg.instead:
            words.append(arg.instead)
            break
        if arg.slot == 'id':
            words.append(str(command.servo))
        elif arg.slot == 'number':
            number = next(numbers, None)
            if number is None:   # an optional argument left out
                break
            words.append(f'{number:g}')
        else:
            words.append(str(command.text))
    return ' '.join(words)


def execute(command: Command, bus: SimBus, stats_line: Callable[[], str] | None = None,
            adapter: FaultEngine | None = None) -> str:
    """
    Run a parsed command; return its 'ok …' answer.

    Errors reported by the bus or the adapter (ValueError, KeyError: unknown id, bad argument)
    become ControlError.
    """
    spec = _BY_NAME.get(command.name)
    if spec is None:
        raise ControlError(f'unknown command {command.name!r}')
    try:
        answer = spec.run(Target(bus, stats_line, adapter), command)
    except ControlError:
        raise
    except KeyError as exc:
        raise ControlError(_message(exc)) from exc
    except ValueError as exc:
        raise ControlError(_message(exc)) from exc
    return f'ok {_said(spec, command) if answer is None else answer}'


def _register_of(command: Command, bus: SimBus, servo_id: ServoRef) -> str:
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


def handle_line(line: str, bus: SimBus, stats_line: Callable[[], str] | None = None,
                adapter: FaultEngine | None = None) -> str | None:
    """
    Parse and run one line; return the single answer line ('ok …' or 'error: …').

    Blank lines and '#' comments get no answer (None). Nothing raised by the bus escapes: an
    unexpected exception is reported as an error line.
    """
    stripped = line.strip()
    if not stripped or stripped.startswith('#'):
        return None
    try:
        return execute(parse(stripped), bus, stats_line, adapter)
    except ControlError as exc:
        return f'error: {exc}'
    except Exception as exc:  # noqa: B902 - a control line must never kill the server
        return f'error: internal: {type(exc).__name__}: {_message(exc)}'


def _message(exc: BaseException) -> str:
    """Return an exception's message on one line (KeyError quotes its argument)."""
    text = str(exc.args[0]) if isinstance(exc, KeyError) and exc.args else str(exc)
    return ' '.join(text.split()) or type(exc).__name__


# ---- the table, written out ------------------------------------------------------------------
def _groups() -> list[tuple[str, list[Spec]]]:
    """Return the commands by group, in the table's order."""
    groups: dict[str, list[Spec]] = {}
    for spec in COMMANDS:
        groups.setdefault(spec.group, []).append(spec)
    return list(groups.items())


def _arguments() -> list[tuple[str, str]]:
    """
    Return (word, meaning) of every argument word, in the order the table first uses it.

    A word of two meanings (MS: a tick, a duration) has both, each with the commands it is in.
    """
    meanings: dict[str, dict[str, list[str]]] = {}
    for spec in COMMANDS:
        for arg in spec.args:
            meanings.setdefault(arg.word, {}).setdefault(arg.meaning, []).append(spec.name)
    out = []
    for word, users in meanings.items():
        if len(users) == 1:
            out.append((word, next(iter(users))))
        else:
            out.append((word, '; '.join(f'{meaning} ({", ".join(names)})'
                                        for meaning, names in users.items())))
    return out


USAGE_WIDTH = 38   # commands_help: a longer usage has its description on the next line


def commands_help() -> str:
    """Return the table as plain text for `virtual_bus --help`: usage and description a line."""
    lines = ['console: each line on standard input is one command, answered with one line',
             '("ok ..." or "error: ..."); a line starting with "#" is a comment.']
    for group, specs in _groups():
        lines.append(f'{group}:')
        for spec in specs:
            lines += _two_columns(spec.usage, spec.summary)
    lines.append('arguments:')
    for word, meaning in _arguments():
        lines += _two_columns(word, meaning)
    return '\n'.join(lines)


def _two_columns(left: str, right: str) -> list[str]:
    """Return the lines of one entry: right beside left, or below it when left is too long."""
    if len(left) > USAGE_WIDTH:
        return [f'  {left}', f'  {"":{USAGE_WIDTH}}  {right}']
    return [f'  {left:{USAGE_WIDTH}}  {right}']


def _cell(text: str) -> str:
    return text.replace('|', '\\|')   # a bare | would end the table cell (GitHub Markdown)


def commands_markdown() -> str:
    """Return the table as a Markdown table: command, arguments (type and range), effect."""
    lines = ['| Command | Arguments | What it does |', '| --- | --- | --- |']
    for group, specs in _groups():
        lines.append(f'| **{_cell(group)}** | | |')
        for spec in specs:
            args = '; '.join(f'`{_cell(arg.word)}`: {_cell(arg.meaning)}' for arg in spec.args)
            lines.append(f'| `{_cell(spec.usage)}` | {args} | {_cell(spec.summary)} |')
    return '\n'.join(lines) + '\n'
