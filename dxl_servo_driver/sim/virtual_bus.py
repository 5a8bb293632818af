"""
`virtual_bus`: simulated servos behind a pseudo-terminal, for any serial client.

  virtual_bus --ids 1 2 3 --baud 1000000 --link /tmp/ttyDXL [--timing instant|wire]
              [--latency-ms F] [--return-delay-time RAW] [--seed N]
              [--models M [M ...]] [--firmware N] [--unplugged]
              [--trace-goals FILE] [--trace-state FILE]

--ids may repeat an id: several servos sharing one (the factory state, `--ids 1 1 1 1 1 1
--baud 57600 --return-delay-time 250`) answer together and their replies collide on the wire
(sim/collision.py). The console names a servo by its id when only one has it, or by `#N`, the
N-th of --ids. --unplugged starts every servo unplugged (configured, off the bus and the
power): `plug ID` puts each on.

Prints the pty's device path as its first stdout line, then answers control lines read on
standard input (sim/control.py, whose table `virtual_bus --help` lists) with one line each.
Clients read the device from that line, so the servos' models go to a start line on stderr
instead:
`virtual_bus: /dev/pts/N: id 1 XM430-W210 (model 1030, firmware 45), id 2 ...` (in --ids order, a
shared id's servos tagged with their #N, `unplugged` after each servo that starts so).
SIGINT/SIGTERM end it cleanly (exit 0) and remove the --link symlink. Standard input reaching
EOF does not stop it.

--models gives each servo's model, by number or name (XL430-W250, any case): one for every id,
or one per id in --ids order; the default is the XM430 manual's model 1030. --firmware sets the
Firmware Version every servo reports, which also picks the table of models whose table changed
with the firmware (the X330's indirect block, from version 53 on).

The baud rate the client sets on the terminal (including custom rates set through termios2 /
BOTHER, as pyserial does for 4.5 Mbps) is read from the slave side whenever bytes arrive; servos
at another baud neither hear nor answer.

Instruction bytes are handed to the servos as soon as they arrive on the pty, so the servo state
is sampled up to one instruction's transmission time early; with --timing wire the replies are
then released at the times computed by sim/timing.py.

Between the servos and the pty sits a USB adapter (sim/fault_engine.FaultEngine) whose faults
the `adapter ...` control lines set: the replies reach it when they would reach a real adapter
(at their wire times with --timing wire), and it hands them to the pty. While every one of its
faults is off and it holds nothing, the replies go straight to the pty. Its packets are cut by
the framing of Protocol 1.0 when every servo speaks 1.0 at start-up, else of Protocol 2.0.
"""

import argparse
import collections
import errno
import heapq
import io
import os
import select
import signal
import sys
import threading
import time
import tty
from typing import Callable, Mapping, NoReturn, Sequence, TextIO

from dxl_servo_driver import protocol

from dxl_servo_driver.models import Model, model_for, model_named, ModelError, xm430
from dxl_servo_driver.port import set_tty_speed, tty_speed_bps
from dxl_servo_driver.sim import control
from dxl_servo_driver.sim.bus import SimBus
from dxl_servo_driver.sim.dynamics import CONTROL_PERIOD_S
from dxl_servo_driver.sim.fault_engine import FaultEngine
from dxl_servo_driver.sim.memory import MANUAL_MODEL, Memory
from dxl_servo_driver.sim.timing import fine_timer_slack, hybrid_wait, LatenessStats, SPIN_S
from dxl_servo_driver.sim.timing import WireScheduler

PTS_PREFIX = '/dev/pts/'
READ_CHUNK = 4096
SETUP_TIMEOUT_S = 3.0  # servos may still be booting when the bus is created


class StartupError(Exception):
    """A start-up failure reported as one line and a non-zero exit."""


def configure_servos(bus: SimBus, baud_bps: int, return_delay_raw: int | None,
                     protocols: Mapping[int, float] | None = None) -> None:
    """
    Set every servo's Return Delay Time (when given), Baud Rate and protocol by WRITE packets.

    SimBus exposes no register writes, so this goes through the protocol at each servo's
    current baud and in the protocol it speaks, as a user would with a real servo. protocols
    sets the Protocol Version of the servos that have one (an X servo on 1.0), by id. Servos
    still booting ignore packets, so it retries until the registers read back right. Servos
    sharing an id hear one another's writes, as on a real bus: each is checked by its #N.
    """
    deadline_s = time.monotonic() + SETUP_TIMEOUT_S
    for number, servo in enumerate(bus.servos(), 1):
        ref = f'#{number}'
        servo_id = servo.servo_id
        model = servo.model
        baud_raw = {bps: raw for raw, bps in model.bauds.items()}.get(baud_bps)
        if baud_raw is None:
            raise StartupError(f'servo {servo_id} ({model.label}) cannot run at {baud_bps} bps; '
                               f'it supports {sorted(model.bauds.values())}')
        wanted: list[tuple[str, int]] = []
        if return_delay_raw is not None:
            wanted.append(('return_delay_time', return_delay_raw))
        wanted.append(('baud_rate', baud_raw))  # it changes the baud the servo listens at
        version = (protocols or {}).get(servo_id)
        if version is not None and model.has('protocol_version'):
            # Last: it changes the protocol the servo listens in.
            wanted.append(('protocol_version', int(version)))
        for name, value in wanted:
            item = model.item(name)
            while bus.read_register(ref, name) != value:
                if time.monotonic() > deadline_s:
                    raise StartupError(f'servo {servo_id} did not accept {name}={value}')
                current_bps = model.bauds[bus.read_register(ref, 'baud_rate')]
                # WRITE in the protocol the servo listens in now (the same code in both).
                framer = protocol.FRAMERS[float(servo.protocol_version)]
                packet = framer.encode(
                    servo_id, protocol.Instruction.WRITE,
                    framer.address_param(item.address, item.size) + item.encode(value))
                bus.feed(packet, current_bps)
                if bus.read_register(ref, name) != value:
                    time.sleep(0.01)


# Wire timing: a servo's physics may be up to this far behind when a packet arrives; between
# packets the server advances one servo at a time (a short step each) when the next reply is not
# due within IDLE_SLICE_S, while the bus has been busy within ACTIVE_WINDOW_S.
PHYSICS_LAG_S = 0.004
IDLE_SLICE_S = 150e-6
ACTIVE_WINDOW_S = 0.05


class GoalTracer:
    """
    Log every goal_position the host writes, with the time it reached the bus.

    One line per goal: `<time.monotonic()> <id> <raw goal>`. CLOCK_MONOTONIC is shared by every
    process of the machine, so the benchmark compares these times with its own publication times
    to measure command latency. A write through indirect entries (the driver's goal slot) is
    followed to the registers it reaches, as the servo's map stands when the write arrives.
    """

    def __init__(self, out: TextIO, bus: SimBus) -> None:
        self._out = out
        self._bus = bus
        self._parser = protocol.StreamParser()
        goal = MANUAL_MODEL.item('goal_position')
        self._address = goal.address
        self._goal = list(range(goal.address, goal.address + goal.size))
        # id -> the servo's memory: this runs in the simulator's I/O thread, on every write,
        # and must not slow the simulator it measures.
        self._memories: dict[int, Memory] = {}

    def feed(self, data: bytes, now_s: float) -> None:
        """Look at bytes from the host; log the goals found in whole packets."""
        for event in self._parser.feed(data, now_s):
            packet = event.packet
            if not event.crc_ok or len(packet.params) < 4:
                continue
            params = packet.params
            address = params[0] | (params[1] << 8)
            if packet.instruction == protocol.Instruction.WRITE:
                self._goal_in(now_s, packet.servo_id, address, params[2:])
            elif packet.instruction == protocol.Instruction.SYNC_WRITE:
                length = params[2] | (params[3] << 8)
                if length < len(self._goal):
                    continue
                for start in range(4, len(params) - length, length + 1):
                    self._goal_in(now_s, params[start], address,
                                  params[start + 1:start + 1 + length])
        self._out.flush()

    def _goal_in(self, now_s: float, servo_id: int, address: int, chunk: bytes) -> None:
        """Log the goal position in one servo's written bytes, if they hold it whole."""
        size = len(self._goal)
        if address == self._address:
            if len(chunk) >= size:
                self._log(now_s, servo_id, chunk[:size])
            return
        memory = self._memories.get(servo_id)
        # A servo may change its id: its memory is then looked up again.
        if memory is None or memory.raw[memory.table.id_address] != servo_id:
            # (Servos sharing an id: the last one's map; they share the factory's anyway.)
            self._memories = {servo.servo_id: servo.memory for servo in self._bus.servos()}
            memory = self._memories.get(servo_id)
            if memory is None:
                return   # not a servo of this bus (broadcast, or an id nobody has)
        if address not in memory.table.indirect:
            return   # neither Goal Position nor indirect data: no goal in it
        targets = [memory.target(address + k) for k in range(len(chunk))]
        for offset in range(len(chunk) - size + 1):
            if targets[offset:offset + size] == self._goal:
                self._log(now_s, servo_id, chunk[offset:offset + size])
                return

    def _log(self, now_s: float, servo_id: int, raw: bytes) -> None:
        value = int.from_bytes(raw, 'little', signed=True)
        self._out.write(f'{now_s:.6f} {servo_id} {value}\n')


# State trace: one sample of every servo this often; the file is flushed this often.
STATE_TRACE_PERIOD_S = 0.002
STATE_TRACE_FLUSH_S = 0.1


class StateTracer:
    """
    Log every servo's Present Position when it changes, and all of them every period_s.

    One line per servo and sample: `<time.time()> <id> <present_position raw>`. The value is the
    register as a read arriving at that moment would see it: the physics is not advanced for
    the trace, so tracing changes nothing the servos answer. The server looks after every
    packet and every idle physics step (sample()), from its own thread, so a sample and a reply
    never race, and a value is logged as soon as a packet could have seen it: a change is never
    dated before it was made, and the value it replaced is dated as held until then (a test
    judging a published sample against the trace can call it stale only if it was). The wall
    clock is what a ROS node stamps its messages with, so a test can tell which time a published
    sample belongs to.
    """

    def __init__(self, out: TextIO, bus: SimBus, period_s: float = STATE_TRACE_PERIOD_S,
                 wall_clock: Callable[[], float] = time.time) -> None:
        self._out = out
        self._bus = bus
        self._period_s = period_s
        self._wall_clock = wall_clock
        self._last: dict[int, int] = {}   # the last value logged, by servo id
        self.next_s = float('-inf')     # when the next sample of every servo is due
        self._flush_s = float('-inf')

    def sample(self, now_s: float) -> None:
        """Log the servos whose value changed, or every servo if a sample is due at now_s."""
        due = now_s >= self.next_s
        if due:
            self.next_s += self._period_s
            if self.next_s <= now_s:
                # Behind (a long reply wait): the next one a period from now, no burst.
                self.next_s = now_s + self._period_s
        bus = self._bus
        last = self._last
        lines = []
        with bus.lock:
            wall_s = self._wall_clock()
            for servo in sorted(bus.servos(), key=lambda servo: servo.servo_id):
                value = servo.memory.get('present_position')
                if due or last.get(servo.servo_id) != value:
                    last[servo.servo_id] = value
                    lines.append(f'{wall_s:.6f} {servo.servo_id} {value}\n')
        if lines:
            self._out.write(''.join(lines))
        if now_s >= self._flush_s:
            self._flush_s = now_s + STATE_TRACE_FLUSH_S
            self._out.flush()


class VirtualBusServer:
    """Serve a SimBus on a pseudo-terminal, through an adapter whose faults can be set."""

    def __init__(self, bus: SimBus, timing: str = 'instant', latency_s: float = 0.0,
                 clock: Callable[[], float] = time.monotonic,
                 adapter: FaultEngine | None = None) -> None:
        self.bus = bus
        self.timing = timing
        self.stats = LatenessStats()
        self._clock = clock
        self._scheduler = WireScheduler(latency_s)
        self._pending: list[tuple[float, int, bytes]] = []  # heap of (due_s, seq, data)
        self._seq = 0
        self._master = -1
        self._slave = -1
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_w, False)
        self._stopping = False
        self.device = ''
        self.goal_tracer: 'GoalTracer | None' = None
        self.state_tracer: 'StateTracer | None' = None
        self.spin_s = SPIN_S
        # The adapter in front of the pty, every fault off until a control line sets one.
        self.adapter = adapter if adapter is not None else FaultEngine(seed=None, clock=clock)
        # Its changes come from the console's thread: the loop wakes to its new timing.
        self.adapter.add_listener(self._wake)

    def open_pty(self, initial_baud_bps: int) -> str:
        """Create the pty in raw mode; return the slave's device path."""
        try:
            self._master, self._slave = os.openpty()
        except OSError as exc:
            raise StartupError(f'cannot open a pseudo-terminal: {exc}') from exc
        # Raw: no echo of what we write back to ourselves, no CR/LF or flow-control mangling.
        tty.setraw(self._slave)
        set_tty_speed(self._slave, initial_baud_bps)
        os.set_blocking(self._master, False)
        self.device = os.ttyname(self._slave)
        return self.device

    def stop(self) -> None:
        """Ask serve() to return (safe from a signal handler or another thread)."""
        self._stopping = True
        self._wake()

    def _wake(self) -> None:
        try:
            os.write(self._wake_w, b'\0')
        except OSError:
            pass  # full (a wake is pending anyway) or closed

    def serve(self) -> None:
        """Move bytes between the pty and the bus until stop()."""
        idle_physics = self.timing == 'wire'
        if idle_physics:
            if self._clock is time.monotonic:
                self.spin_s = fine_timer_slack()
            # Replies must leave on time: the physics runs between packets instead.
            self.bus.physics_lag_s = PHYSICS_LAG_S
        while not self._stopping:
            timeout_s = 0.5
            now_s = self._clock()
            if self._pending:
                timeout_s = min(timeout_s, max(0.0, self._pending[0][0] - now_s - self.spin_s))
            if (idle_physics and timeout_s > IDLE_SLICE_S
                    and now_s - self.bus.last_packet_s < ACTIVE_WINDOW_S):
                if self.bus.advance_stalest(CONTROL_PERIOD_S):
                    timeout_s = 0.0   # look for input, then the next servo
                else:
                    timeout_s = min(timeout_s, CONTROL_PERIOD_S)
            adapter_s = self.adapter.next_event_s()
            if adapter_s is not None:
                timeout_s = min(timeout_s, max(0.0, adapter_s - now_s))
            tracer = self.state_tracer
            if tracer is not None:
                timeout_s = min(timeout_s, max(0.0, tracer.next_s - now_s))
            try:
                readable, _, _ = select.select([self._master, self._wake_r], [], [], timeout_s)
            except InterruptedError:  # pragma: no cover - PEP 475 retries; kept for safety
                continue
            if self._wake_r in readable:
                os.read(self._wake_r, 64)
            if self._master in readable:
                self._receive()
            self._deliver_due()
            self._adapter_out()
            if tracer is not None:
                tracer.sample(self._clock())

    def close(self) -> None:
        """Close every descriptor."""
        for fd in (self._master, self._slave, self._wake_r, self._wake_w):
            if fd >= 0:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._master = self._slave = self._wake_r = self._wake_w = -1

    def _receive(self) -> None:
        try:
            data = os.read(self._master, READ_CHUNK)
        except BlockingIOError:
            return
        except OSError as exc:
            if exc.errno == errno.EIO:  # no slave open; cannot happen while we hold one
                time.sleep(0.01)
                return
            raise
        if not data:
            return
        now_s = self._clock()
        if self.goal_tracer is not None:
            self.goal_tracer.feed(data, now_s)
        self.adapter.host_bytes(data, now_s)   # its echo, when that fault is on
        baud_bps = tty_speed_bps(self._slave)
        replies = self.bus.feed(data, baud_bps)
        if self.timing == 'instant':
            for reply in replies:
                self._push(now_s, reply.data)
            return
        end_s = self._scheduler.instruction_end_s(now_s, len(data), baud_bps)
        for due_s, chunk in self._scheduler.schedule(end_s, replies, baud_bps):
            self._push(due_s, chunk)

    def _push(self, due_s: float, data: bytes) -> None:
        heapq.heappush(self._pending, (due_s, self._seq, data))
        self._seq += 1

    def _deliver_due(self) -> None:
        while self._pending and self._pending[0][0] <= self._clock() + self.spin_s:
            due_s, _, data = heapq.heappop(self._pending)
            # Spin for the moment only where the host's wait ends: the last reply pending. An
            # earlier one is slept for (a few us late, still long before the next is due):
            # a spin before every reply would keep a core busy and take it from the driver under
            # test.
            hybrid_wait(due_s, self._clock, spin_s=self.spin_s if not self._pending else 0.0)
            now_s = self._clock()
            self.stats.record(now_s - due_s)
            if self.adapter.engaged(now_s):
                self.adapter.servo_bytes(data, now_s)   # out by _adapter_out, when it says
                continue
            try:
                # The client is not reading and the pty buffer is full: like an adapter's
                # overflowing receive buffer, what does not fit is lost.
                os.write(self._master, data)
            except BlockingIOError:
                pass

    def _adapter_out(self) -> None:
        """Write what the adapter has released by now to the pty."""
        self.adapter.release_to(self._master, self._clock())


class _OneLineParser(argparse.ArgumentParser):
    """Argument errors as one line on stderr and exit status 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f'{self.prog}: error: {message}\n')


def _parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    bauds = sorted(xm430.BAUD_RATES.values())
    delay = MANUAL_MODEL.item('return_delay_time')
    delay_range = f'{delay.minimum}..{delay.maximum}'
    delay_unit_us = protocol.RETURN_DELAY_UNIT_S * 1e6
    parser = _OneLineParser(prog='virtual_bus',
                            description='Simulated Dynamixel servos on a pseudo-terminal.',
                            epilog=control.commands_help(),
                            formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--ids', type=int, nargs='+', required=True,
                        help=f'servo ids (0..{control.MAX_SERVO_ID}); an id may repeat: servos '
                             'sharing it answer together and collide (the console names them '
                             '#N, the N-th of --ids)')
    parser.add_argument('--baud', type=int, default=57600,
                        help=f'servo baud rate, one of {bauds} (default 57600)')
    parser.add_argument('--link', default=None, help='make this symlink to the device')
    parser.add_argument('--timing', choices=('instant', 'wire'), default='instant')
    parser.add_argument('--latency-ms', type=float, default=0.0,
                        help='USB adapter latency timer (wire timing only)')
    parser.add_argument('--return-delay-time', type=int, default=None, metavar='RAW',
                        help=f'Return Delay Time register ({delay_unit_us:g} us units, '
                             f'{delay_range})')
    parser.add_argument('--seed', type=int, default=None,
                        help='random seed of fault injection (servos and adapter)')
    parser.add_argument('--models', nargs='+', default=None, metavar='M',
                        help='model number or name of the servos (XL430-W250, any case): one '
                             'for all ids or one per id (default 1030)')
    parser.add_argument('--firmware', type=int, default=None, metavar='N',
                        help="Firmware Version the servos report (0..255); picks the model's "
                             'table for that firmware (default: the newest)')
    parser.add_argument('--unplugged', action='store_true',
                        help='start every servo unplugged (off the bus and the power; the '
                             'console\'s "plug ID" puts one on)')
    parser.add_argument('--trace-goals', default=None, metavar='FILE',
                        help='append "<monotonic time> <id> <goal_position>" per goal written')
    parser.add_argument('--trace-state', default=None, metavar='FILE',
                        help='append "<wall-clock time> <id> <present_position>" for a servo '
                             'whose position changed, after every packet, and for every servo '
                             f'every {STATE_TRACE_PERIOD_S * 1000:g} ms')
    args = parser.parse_args(argv)
    bad_ids = [i for i in args.ids if not 0 <= i <= control.MAX_SERVO_ID]
    if bad_ids:
        parser.error(f'--ids: {bad_ids[0]} is not in 0..{control.MAX_SERVO_ID}')
    if args.baud not in bauds:
        parser.error(f'--baud {args.baud}: the servo supports {bauds}')
    if not args.latency_ms >= 0.0:
        parser.error('--latency-ms must be >= 0')
    if args.latency_ms > 0.0 and args.timing != 'wire':
        parser.error('--latency-ms needs --timing wire')
    if args.return_delay_time is not None and \
            not delay.minimum <= args.return_delay_time <= delay.maximum:
        parser.error(f'--return-delay-time must be {delay_range}')
    if args.firmware is not None and not 0 <= args.firmware <= 255:
        parser.error(f'--firmware {args.firmware}: expected 0..255')
    try:
        # One per servo, in --ids order (an id may repeat); models: by id, as it always was.
        args.slot_models = _servo_models(args.ids, args.models, args.firmware)
    except ValueError as exc:
        parser.error(str(exc))
    args.models = dict(zip(args.ids, args.slot_models))
    for servo_id, model in zip(args.ids, args.slot_models):
        if args.baud not in model.bauds.values():
            parser.error(f'--baud {args.baud}: servo {servo_id} ({model.name}) supports '
                         f'{sorted(model.bauds.values())}')
    return args


def _model_of(token: str, firmware: int | None) -> Model:
    """Return the model a --models value names (a number or a name), for this firmware."""
    try:
        number = int(token, 10) if token.isdigit() else model_named(token).number
        return model_for(number, firmware)
    except ModelError as exc:
        raise ValueError(f'--models {token}: {exc}') from None


def _servo_models(ids: Sequence[int], tokens: Sequence[str] | None,
                  firmware: int | None) -> list[Model]:
    """Return the servos' models from --models (one for all, or one per id); ValueError if bad."""
    if tokens is None:
        tokens = [str(xm430.MODEL_NUMBER)]
    if len(tokens) not in (1, len(ids)):
        raise ValueError(f'--models: give one model for every id or one per id '
                         f'({len(ids)} ids, {len(tokens)} models)')
    chosen = [_model_of(token, firmware) for token in tokens]
    if len(chosen) == 1:
        chosen *= len(ids)
    return chosen


def describe_servos(bus: SimBus) -> str:
    """
    Return 'id 1 XM430-W210 (model 1030, firmware 45), id 2 ...' for the start line.

    In the order of --ids; a servo whose id another shares is '#N id 1 ...', and an unplugged
    one ends with ' unplugged'.
    """
    servos = bus.servos()
    counts = collections.Counter(servo.servo_id for servo in servos)
    parts = []
    for number, servo in enumerate(servos, 1):
        model = servo.model
        firmware = servo.memory.get('firmware_version')
        tag = f'#{number} ' if counts[servo.servo_id] > 1 else ''
        off = '' if bus.plugged(f'#{number}') else ' unplugged'
        parts.append(f'{tag}id {servo.servo_id} {model.name} (model {model.number}, '
                     f'firmware {firmware}){off}')
    return ', '.join(parts)


def _make_link(link: str, device: str) -> None:
    """Create link -> device; replace only a stale symlink to a vanished pty."""
    if os.path.islink(link):
        target = os.readlink(link)
        if target.startswith(PTS_PREFIX) and not os.path.exists(target):
            os.unlink(link)
        else:
            raise StartupError(f'link path {link} is taken (symlink to {target}); remove it')
    elif os.path.lexists(link):
        raise StartupError(f'link path {link} is taken (not a symlink); remove it')
    try:
        os.symlink(device, link)
    except OSError as exc:
        raise StartupError(f'cannot create link {link}: {exc.strerror}') from exc


def _remove_link(link: str, device: str) -> None:
    """Remove link if it is still ours."""
    try:
        if os.path.islink(link) and os.readlink(link) == device:
            os.unlink(link)
    except OSError:
        pass


class _Console:
    """Answer control lines from a text stream, one output line each."""

    def __init__(self, server: VirtualBusServer, out: TextIO) -> None:
        self._server = server
        self._out = out
        self._lock = threading.Lock()

    def say(self, line: str) -> None:
        with self._lock:
            try:
                self._out.write(line + '\n')
                self._out.flush()
            except (OSError, ValueError):
                pass  # nobody listens any more; keep serving the bus

    def run(self, stream: TextIO) -> None:
        try:
            for line in stream:
                server = self._server
                answer = control.handle_line(line, server.bus, server.stats.line, server.adapter)
                if answer is not None:
                    self.say(answer)
        except (OSError, ValueError):
            pass  # stdin closed or unreadable: keep serving the bus


def main(argv: Sequence[str] | None = None) -> int:
    """Run the virtual bus; return the exit status."""
    args = _parse_args(argv)
    try:
        firmware = None if args.firmware is None else [args.firmware] * len(args.ids)
        bus = SimBus(args.ids, seed=args.seed, models=args.slot_models, firmware=firmware)
        configure_servos(bus, args.baud, args.return_delay_time)
    except (StartupError, ValueError) as exc:  # ValueError: SimBus refused the ids
        print(f'virtual_bus: error: {exc}', file=sys.stderr, flush=True)
        return 1
    if args.unplugged:
        for number in range(1, len(args.ids) + 1):
            bus.unplug(f'#{number}')
    # The adapter cuts packets by the framing of the protocol the servos speak (a mixed bus:
    # 2.0's).
    spoken = {servo.protocol_version for servo in bus.servos()}
    framing = spoken.pop() if len(spoken) == 1 else 2
    adapter = FaultEngine(seed=args.seed, protocol=framing)
    server = VirtualBusServer(bus, args.timing, args.latency_ms / 1000.0, adapter=adapter)
    trace_files: dict[str, TextIO] = {}
    for option, path in (('goals', args.trace_goals), ('state', args.trace_state)):
        if not path:
            continue
        try:
            trace_files[option] = open(path, 'a', encoding='ascii')
        except OSError as exc:
            print(f'virtual_bus: error: cannot open {path}: {exc.strerror}',
                  file=sys.stderr, flush=True)
            for trace_file in trace_files.values():
                trace_file.close()
            return 1
    if 'goals' in trace_files:
        server.goal_tracer = GoalTracer(trace_files['goals'], server.bus)
    if 'state' in trace_files:
        server.state_tracer = StateTracer(trace_files['state'], bus)

    def on_signal(signum: int, frame: object) -> None:
        server.stop()

    # Installed before the link exists, so a signal at any later point still removes it.
    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    device = ''
    linked = False
    try:
        try:
            device = server.open_pty(args.baud)
            if args.link:
                _make_link(args.link, device)
                linked = True
        except StartupError as exc:
            print(f'virtual_bus: error: {exc}', file=sys.stderr, flush=True)
            return 1
        console = _Console(server, sys.stdout)
        console.say(device)
        print(f'virtual_bus: {device}: {describe_servos(bus)}', file=sys.stderr, flush=True)
        if sys.stdin is not None:
            if isinstance(sys.stdin, io.TextIOWrapper):
                sys.stdin.reconfigure(errors='replace')  # a stray binary byte is a bad line
            threading.Thread(target=console.run, args=(sys.stdin,), name='control',
                             daemon=True).start()
        server.serve()
    finally:
        if linked:
            _remove_link(args.link, device)
        server.close()
        for trace_file in trace_files.values():
            trace_file.close()
    return 0


if __name__ == '__main__':
    sys.exit(main())
