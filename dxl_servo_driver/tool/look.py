"""
`dxl watch`: a live table of chosen registers of several servos, in SI units.

Each refresh reads the span of the chosen items from every servo at once: one sync read where
the protocol has it (Protocol 2.0, every servo's items at the same addresses), else one bulk
read, else a read per servo (a Protocol 1.0 model without bulk read). Refreshes follow one
another as fast as the bus answers, or at --rate. On a terminal the table is redrawn in place,
a sparkline (unicode blocks) beside each value showing its recent past; elsewhere a plain line per
shown refresh. Either is shown at most SHOW_HZ times a second; --csv records every sample (host
time from the start, id, each item in SI units). Ctrl-C (or SIGTERM) ends it after the refresh in
progress, the CSV closed whole; --duration ends it on its own.
"""

import argparse
import collections
import csv
import os
import signal
import sys
import time
from types import FrameType
from typing import Deque, Dict, IO, List, Optional, Sequence, Tuple, Union

from dxl_servo_driver.bus import Bus
from dxl_servo_driver.errors import CommError, PortError
from dxl_servo_driver.models.base import Item, Model
from dxl_servo_driver.tool.common import (
    add_command, EXIT_OUTPUT, EXIT_PORT, EXIT_USAGE, ToolError)
from dxl_servo_driver.tool.session import (
    add_bus_arguments, bus_from_args, bus_settings, connect, servo_ref, to_si)

SPARK = '▁▂▃▄▅▆▇█'
SPARK_WIDTH = 24
SHOW_HZ = 10.0
DEFAULT_ITEMS = 'present_position,present_velocity,present_current'


def sparkline(values: Sequence[float]) -> str:
    """Return values as unicode blocks, scaled between their least and greatest."""
    if not values:
        return ''
    low, high = min(values), max(values)
    if high == low:
        return SPARK[0] * len(values)
    top = len(SPARK) - 1
    return ''.join(SPARK[int(round((value - low) / (high - low) * top))] for value in values)


def si_name(name: str, unit: str) -> str:
    """Return a CSV column name: the item and its SI unit (present_position_rad)."""
    if not unit:
        return name
    return f'{name}_{unit.replace("/", "_").replace("^", "").replace(" ", "_")}'


class Reader:
    """Reads the chosen items of every servo with one group read (or one read each)."""

    def __init__(self, bus: Bus, tables: Dict[int, Model], names: Sequence[str]) -> None:
        self.bus = bus
        self.tables = tables
        self.items: Dict[int, List[Item]] = {}
        spans: Dict[int, Tuple[int, int]] = {}
        for servo_id, model in tables.items():
            chosen = []
            for name in names:
                if not model.has(name):
                    raise ToolError(f'id {servo_id} ({model.name}) has no item {name!r}',
                                    EXIT_USAGE)
                chosen.append(model.item(name))
            self.items[servo_id] = chosen
            low = min(item.address for item in chosen)
            spans[servo_id] = (low, max(item.address + item.size for item in chosen) - low)
        self.spans = spans
        ids = list(tables)
        same = len(set(spans.values())) == 1
        framer = bus.default_framer
        if framer.sync_read and same:
            self.how = 'sync read'
        elif all(model.bulk_read for model in tables.values()):
            self.how = 'bulk read'
        else:
            self.how = 'a read each'
        self.ids = ids

    def read(self) -> Tuple[float, Dict[int, Union[Dict[str, float], str]]]:
        """Return (time the request went out, id -> {item: SI value} or why not)."""
        if self.how == 'sync read':
            address, length = self.spans[self.ids[0]]
            result = self.bus.sync_read(address, length, self.ids)
            data, sent_s = result.data, result.sent_s
        elif self.how == 'bulk read':
            result = self.bus.bulk_read([(i, *self.spans[i]) for i in self.ids])
            data, sent_s = result.data, result.sent_s
        else:
            data = {}
            sent_s = time.monotonic()
            for servo_id in self.ids:
                try:
                    data[servo_id] = self.bus.read_fresh(servo_id, *self.spans[servo_id])[0]
                except CommError as exc:
                    data[servo_id] = exc
        values: Dict[int, Union[Dict[str, float], str]] = {}
        for servo_id in self.ids:
            got = data.get(servo_id)
            if not isinstance(got, (bytes, bytearray)):
                values[servo_id] = str(got) if got is not None else 'no reply'
                continue
            address = self.spans[servo_id][0]
            model = self.tables[servo_id]
            row = {}
            for item in self.items[servo_id]:
                at = item.address - address
                row[item.name] = to_si(model, item, item.decode(got[at:at + item.size]))[0]
            values[servo_id] = row
        return sent_s, values

    def unit(self, name: str) -> str:
        """Return the SI unit of an item (from the first servo's table)."""
        model = self.tables[self.ids[0]]
        return to_si(model, model.item(name), 0)[1]


class Screen:
    """What is shown: a table redrawn in place on a terminal, plain lines elsewhere."""

    def __init__(self, stream: IO[str], reader: Reader, names: Sequence[str],
                 header: str) -> None:
        self.stream = stream
        self.tty = stream.isatty()
        self.reader = reader
        self.names = names
        self.header = header
        self.history: Dict[Tuple[int, str], Deque[float]] = collections.defaultdict(
            lambda: collections.deque(maxlen=SPARK_WIDTH))
        self._drawn = 0

    def show(self, elapsed_s: float, rate_hz: float,
             values: Dict[int, Union[Dict[str, float], str]]) -> None:
        """Show one refresh."""
        for servo_id, row in values.items():
            if isinstance(row, dict):
                for name, value in row.items():
                    self.history[(servo_id, name)].append(value)
        if self.tty:
            self._table(elapsed_s, rate_hz, values)
        else:
            self._line(elapsed_s, values)

    def _cell(self, servo_id: int, name: str, value: float) -> str:
        unit = self.reader.unit(name)
        return f'{value:+10.4f} {unit:6} {sparkline(list(self.history[(servo_id, name)]))}'

    def _table(self, elapsed_s: float, rate_hz: float,
               values: Dict[int, Union[Dict[str, float], str]]) -> None:
        width = 18 + SPARK_WIDTH
        lines = [f'{self.header}   {elapsed_s:7.1f} s   {rate_hz:6.0f} reads/s   Ctrl-C ends',
                 'id  ' + ''.join(f'{name[:width - 1]:{width}}' for name in self.names)]
        for servo_id, row in values.items():
            if isinstance(row, dict):
                cells = ''.join(f'{self._cell(servo_id, name, row[name]):{width}}'
                                for name in self.names)
            else:
                cells = row
            lines.append(f'{servo_id:<3} {cells}')
        # Up to where the last table began, then each line over its old self.
        up = f'\x1b[{self._drawn}F' if self._drawn else ''
        self.stream.write(up + ''.join(f'{line}\x1b[K\n' for line in lines))
        self.stream.flush()
        self._drawn = len(lines)

    def _line(self, elapsed_s: float, values: Dict[int, Union[Dict[str, float], str]]) -> None:
        parts = [f'{elapsed_s:8.3f}']
        for servo_id, row in values.items():
            if isinstance(row, dict):
                parts.append(f'id {servo_id} ' + ' '.join(
                    f'{name}={row[name]:+.4f}{self.reader.unit(name)}' for name in self.names))
            else:
                parts.append(f'id {servo_id} {row}')
        print('  '.join(parts), file=self.stream, flush=True)


class Stop:
    """Ctrl-C and SIGTERM as a flag: the loop ends after the refresh in progress."""

    def __init__(self) -> None:
        self.asked = False
        self._before: List[Tuple[int, object]] = []

    def _handle(self, signum: int, frame: Optional[FrameType]) -> None:
        self.asked = True

    def __enter__(self) -> 'Stop':
        for sig in (signal.SIGINT, signal.SIGTERM):
            self._before.append((sig, signal.signal(sig, self._handle)))
        return self

    def __exit__(self, *exc: object) -> None:
        for sig, handler in self._before:
            signal.signal(sig, handler)  # type: ignore[arg-type]


def run(args: argparse.Namespace) -> int:
    """Watch until Ctrl-C (or --duration); return 0."""
    names = [name.strip() for name in args.items.split(',') if name.strip()]
    if not names or len(set(names)) != len(names):
        raise ToolError(f'--items {args.items!r}: name each item once', EXIT_USAGE)
    bus_settings(args)   # joint names become ids
    if len(set(args.ids)) != len(args.ids):
        raise ToolError('--ids: each servo once', EXIT_USAGE)
    if args.rate is not None and not 0.0 < args.rate <= 10000.0:
        raise ToolError('--rate must be in (0, 10000] Hz', EXIT_USAGE)
    bus = bus_from_args(args)
    csv_file: Optional[IO[str]] = None
    try:
        tables = {servo_id: connect(bus, servo_id).model for servo_id in args.ids}
        reader = Reader(bus, tables, names)
        if args.csv:
            try:
                csv_file = open(args.csv, 'w', newline='', encoding='utf-8')
            except OSError as exc:
                raise ToolError(f'cannot write {args.csv}: {exc.strerror or exc}',
                                EXIT_OUTPUT) from exc
        return _watch(bus, reader, names, csv_file, args)
    finally:
        if csv_file is not None:
            csv_file.close()
        bus.close()


def _watch(bus: Bus, reader: Reader, names: Sequence[str], csv_file: Optional[IO[str]],
           args: argparse.Namespace) -> int:
    writer = None
    if csv_file is not None:
        writer = csv.writer(csv_file)
        writer.writerow(['t_s', 'id'] + [si_name(name, reader.unit(name)) for name in names])
    header = (f'dxl watch {args.port} {bus.baud_bps} bps, {reader.how} of '
              f'{len(reader.ids)} servo{"s" if len(reader.ids) > 1 else ""}')
    screen = Screen(sys.stdout, reader, names, header)
    period = 0.0 if args.rate is None else 1.0 / args.rate
    start = time.monotonic()
    next_read = start
    next_show = start
    reads = failed = 0
    rate_window: Deque[float] = collections.deque(maxlen=200)
    with Stop() as stop:
        while not stop.asked:
            now = time.monotonic()
            if args.duration is not None and now - start >= args.duration:
                break
            if period and next_read > now:
                time.sleep(min(next_read - now, 0.05))
                continue
            next_read = max(next_read + period, now) if period else now
            try:
                sent_s, values = reader.read()
            except CommError as exc:
                raise ToolError(str(exc)) from exc
            except PortError as exc:
                raise ToolError(str(exc), EXIT_PORT) from exc
            reads += 1
            rate_window.append(sent_s)
            if writer is not None:
                for servo_id, row in values.items():
                    if isinstance(row, dict):
                        writer.writerow([f'{sent_s - start:.6f}', servo_id]
                                        + [f'{row[name]:.6g}' for name in names])
            failed += sum(1 for row in values.values() if not isinstance(row, dict))
            if sent_s >= next_show:
                next_show = sent_s + 1.0 / SHOW_HZ
                span = rate_window[-1] - rate_window[0]
                rate = (len(rate_window) - 1) / span if span > 0 else 0.0
                try:
                    screen.show(sent_s - start, rate, values)
                except BrokenPipeError:
                    # Read by `head` or a pager that stopped reading: the end, not an error.
                    os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
                    break
    elapsed = time.monotonic() - start
    print(f'{reads} reads in {elapsed:.1f} s ({reads / max(elapsed, 1e-9):.0f}/s), '
          f'{failed} missing replies' + (f'; samples in {args.csv}' if args.csv else ''),
          file=sys.stderr)
    return 0


def register(subparsers: 'argparse._SubParsersAction[argparse.ArgumentParser]') -> None:
    """Add `dxl watch`."""
    parser = add_command(
        subparsers, 'watch', 'a live table of registers of several servos (SI), sparklines, CSV',
        __doc__.strip().splitlines()[0],
        'dxl watch --port /dev/ttyUSB0 --baud 1000000 --ids 1 2 3 '
        '--items present_position,present_current --csv log.csv',
        'dxl watch --ids shoulder elbow --params my_arm.yaml')
    parser.add_argument('--ids', type=servo_ref, nargs='+', required=True, metavar='ID',
                        help="the servos watched (ids or, with --params, joints' names)")
    parser.add_argument('--items', default=DEFAULT_ITEMS, metavar='NAME,...',
                        help=f'items of the control table, snake_case (default {DEFAULT_ITEMS})')
    parser.add_argument('--rate', type=float, metavar='HZ',
                        help='refreshes a second (default: as fast as the bus answers)')
    parser.add_argument('--csv', metavar='FILE', help='record every sample to this CSV')
    parser.add_argument('--duration', type=float, metavar='S',
                        help='end after this long (default: at Ctrl-C)')
    add_bus_arguments(parser)
    parser.set_defaults(run=run)
