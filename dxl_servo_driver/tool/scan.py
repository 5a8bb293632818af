"""
`scan` and `dxl scan`: find the servos on a serial port, at every baud rate, and describe them.

  scan --port /dev/ttyUSB0 [--baud B ...] [--ids ID ...] [--protocol 1.0|2.0|both]
       [--stop-at-first] [--output FILE] [--protocol-timeout-ms MS]

One command, two ways in: the `scan` executable (main) and `dxl scan` (register; like every
`dxl` command it also takes --trace FILE), with one definition of the options (add_arguments)
and one run, which says `scan` or `dxl scan` in what it prints. The search itself is the bus's
(dxl_servo_driver.bus.scan_bus: every baud rate some supported model takes, the most common
first, in both protocols, Protocol 1.0 by default only where a 1.0 model runs out of the box;
--ids narrows it); this module parses the options, says what happens (scan_report) and writes
the parameter file (scan_file).

stderr: the estimate first (the plan's, Step.estimate_s, which docs/hardware.md compares with
measured times); then on a terminal one progress line redrawn, elsewhere one line a step; notes
and warnings. stdout: one line per servo found, saying its protocol. With --output it writes a
parameter file the driver node runs as it is. Ctrl-C (SIGINT) stops it and keeps what was
found: said, written to --output if asked, status 130.

Exit status: 0 servos found (and the file written), 1 no servo found, 2 bad arguments, 3 the port
cannot be opened or was lost, 4 the parameter file cannot be written, 130 interrupted.

Plain CLI: no ROS. It talks to the servos only through dxl_servo_driver.bus.Bus.
"""

import argparse
import os
import sys
from typing import NoReturn, Optional, Sequence, TextIO

from dxl_servo_driver import timerslack
from dxl_servo_driver.bus import (
    all_bauds, Bus, BusTrace, default_bauds, FoundServo, MAX_RETURN_DELAY_S, NO_SERVO_HINT,
    plan, protocol_1_bauds, scan_bus, ScanResult, sweep_wait_s)
from dxl_servo_driver.driver.adapter import LINUX, Measured
from dxl_servo_driver.errors import PortError
from dxl_servo_driver.port import adapter_latency_timer_ms, open_port
from dxl_servo_driver.protocol import MAX_ID
from dxl_servo_driver.tool.common import (
    EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK, EXIT_OUTPUT, EXIT_PORT, EXIT_USAGE, ToolError)
from dxl_servo_driver.tool.scan_file import measure_latency, write_output
from dxl_servo_driver.tool.scan_report import describe, plural, Progress, step_line

# The exit statuses are the dxl tool's (scan is one of its commands): 1 is 'no servo found'.
EXIT_NOT_FOUND = EXIT_FAILED

# A scan is not time-critical: wait generously for each reply beyond its wire time (the USB
# adapter's latency timer alone is 16 ms by default on Linux).
DEFAULT_PROTOCOL_TIMEOUT_MS = 50.0
PROTOCOLS = {'1.0': (1.0,), '2.0': (2.0,), 'both': (2.0, 1.0)}
DESCRIPTION = 'Find Dynamixel servos (Protocol 2.0 and 1.0) on a port.'
EXAMPLE = 'dxl scan --port /dev/ttyDXL --output robot.yaml'


class _UsageError(Exception):
    """Bad command-line arguments."""


class _Parser(argparse.ArgumentParser):
    """Argument errors raise instead of exiting, so main() returns the status."""

    def error(self, message: str) -> NoReturn:
        raise _UsageError(message)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add scan's options to a parser (`scan`'s own, and `dxl scan`'s)."""
    bauds = all_bauds()
    parser.add_argument('--port', required=True, help='serial device, e.g. /dev/ttyUSB0')
    parser.add_argument('--baud', type=int, nargs='+', metavar='B',
                        help=f'baud rates to try (default: all of {bauds})')
    parser.add_argument('--ids', type=int, nargs='+', metavar='ID',
                        help=f'ping only these ids (0..{MAX_ID}) instead of a broadcast ping')
    parser.add_argument('--protocol', choices=tuple(PROTOCOLS), default='both',
                        help='the protocols to look for servos in (default both)')
    parser.add_argument('--stop-at-first', action='store_true',
                        help='stop after the first baud rate where servos answered')
    parser.add_argument('--output', metavar='FILE',
                        help='write a parameter file for the node with the servos found')
    parser.add_argument('--protocol-timeout-ms', type=float, default=DEFAULT_PROTOCOL_TIMEOUT_MS,
                        metavar='MS',
                        help='wait for each reply beyond its time on the wire (default '
                             f'{DEFAULT_PROTOCOL_TIMEOUT_MS:g}; covers the USB latency timer)')


def check_arguments(args: argparse.Namespace) -> Optional[str]:
    """Check (and de-duplicate) parsed arguments; return what is wrong, None if nothing."""
    bauds = all_bauds()
    if args.baud is not None:
        bad = [b for b in args.baud if b not in bauds]
        if bad:
            return f'--baud {bad[0]}: no supported model runs at it ({bauds})'
        args.baud = list(dict.fromkeys(args.baud))
    if args.ids is not None:
        bad = [i for i in args.ids if not 0 <= i <= MAX_ID]
        if bad:
            return f'--ids {bad[0]}: ids are 0..{MAX_ID}'
        args.ids = list(dict.fromkeys(args.ids))
    if not 0.0 < args.protocol_timeout_ms <= 10_000.0:  # also refuses nan
        return '--protocol-timeout-ms must be in (0, 10000]'
    if args.output is not None:
        folder = os.path.dirname(os.path.abspath(args.output))
        if not os.path.isdir(folder):
            return f'--output {args.output}: folder {folder} does not exist'
        if os.path.isdir(args.output):
            return f'--output {args.output} is a folder'
    return None


def _parse_args(argv: Optional[Sequence[str]]) -> argparse.Namespace:
    parser = _Parser(prog='scan', description=DESCRIPTION)
    add_arguments(parser)
    args = parser.parse_args(argv)
    problem = check_arguments(args)
    if problem is not None:
        parser.error(problem)
    return args


def _report_bauds(servos: Sequence[FoundServo], err: TextIO, prog: str) -> None:
    bauds = list(dict.fromkeys(servo.baud_bps for servo in servos))
    if len(bauds) > 1:
        counts = ', '.join(
            f'{plural(sum(1 for s in servos if s.baud_bps == b), "servo")} at {b} bps'
            for b in bauds)
        print(f'{prog}: warning: the servos use different baud rates ({counts}); one bus runs '
              'at one baud rate, so the node can reach only one group', file=err)


def run(args: argparse.Namespace, prog: str = 'scan', trace: str = '') -> int:
    """
    Run a scan of checked arguments (add_arguments, check_arguments); return the exit status.

    prog names the command in what it says (`scan`, `dxl scan`); trace, a file every byte on
    the port is written to (`dxl scan --trace FILE`, as every `dxl` command). Ctrl-C (SIGINT)
    ends it with what was found kept: said, written to --output if asked, and status 130.
    """
    out, err = sys.stdout, sys.stderr
    bauds = args.baud or default_bauds()
    latency_ms = adapter_latency_timer_ms(args.port)
    timeout_ms = args.protocol_timeout_ms
    if latency_ms is not None:
        timeout_ms = max(timeout_ms, latency_ms + 2.0)
        if latency_ms > 1.0:
            print(f'{prog}: note: the adapter latency timer is {latency_ms:g} ms; 1 ms makes '
                  'the bus much faster (install udev/99-dxl-servo-driver.rules)', file=err)
    try:
        port = open_port(args.port, bauds[0])
    except PortError as exc:
        print(f'{prog}: error: {exc}', file=err)
        return EXIT_PORT
    bus = Bus(port, bauds[0], latency_timer_s=timeout_ms / 1000.0,
              return_delay_s=MAX_RETURN_DELAY_S)
    if trace:
        try:
            bus.trace_to(BusTrace(trace, bauds[0], f'{prog} of port {args.port}'))
        except OSError as exc:
            bus.close()
            print(f'{prog}: error: cannot write the trace {trace}: {exc.strerror or exc}',
                  file=err)
            return EXIT_OUTPUT
    # A sweep's pings are spaced by sleeps of a millisecond or two: ended on time, not late.
    timerslack.fine_timer_slack()
    asked = PROTOCOLS[args.protocol]
    # Bauds asked for are searched in every protocol asked for; by default Protocol 1.0 only
    # where a 1.0 model runs out of the box (an X servo switched to 1.0 at 4 Mbps: --baud).
    bauds_1 = None if args.baud else protocol_1_bauds()
    steps = plan(bauds, args.ids, asked, timeout_ms / 1000.0, bauds_1)
    about_s = sum(step.estimate_s for step in steps)
    print(f'{prog}: {plural(len(bauds), "baud rate")}, Protocol '
          f'{" and ".join(f"{p:.1f}" for p in asked)}: about {_seconds(about_s)} s where '
          f'nobody answers{" (or until servos answer)" if args.stop_at_first else ""}; '
          'Ctrl-C stops it and keeps what was found', file=err, flush=True)
    progress = Progress(err, out, steps, _is_terminal(err))
    result = ScanResult([], [], [])
    interrupted = False
    latency = None if latency_ms is None else Measured(latency_ms, LINUX)
    try:
        scan_bus(bus, bauds, args.ids, progress.line, lambda servo: progress.found(
            describe(servo)), asked, sweep_wait_s(latency_ms), args.stop_at_first, bauds_1,
            lambda index, step: progress.step(index, step, step_line(step, args.ids)), result)
        if args.output is not None and result.servos:
            # The file's latency_timer: what the node will find at configure.
            latency = measure_latency(bus, args.port, result.servos)
    except PortError as exc:
        progress.close()
        print(f'{prog}: error: {exc}', file=err)
        return EXIT_PORT
    except KeyboardInterrupt:
        interrupted = True
    finally:
        progress.close()
        bus.close()
    return _report(args, result, latency, interrupted, prog)


def _report(args: argparse.Namespace, result: ScanResult, latency: Optional[Measured],
            interrupted: bool, prog: str) -> int:
    """Say how the scan ended and write --output if asked; return the exit status."""
    err = sys.stderr
    for warning in result.warnings:
        print(f'{prog}: warning: {warning}', file=err)
    tried = ', '.join(str(b) for b in result.bauds_tried) or 'none'
    if interrupted:
        print(f'{prog}: interrupted: found {plural(len(result.servos), "servo")} (tried '
              f'{tried} bps)', file=err)
        if result.servos and args.output is not None:
            status = write_output(args, result, latency, err, prog)
            if status != EXIT_OK:
                return status
        return EXIT_INTERRUPTED
    if not result.servos:
        what = 'a broadcast ping' if args.ids is None else (
            'pings of id(s) ' + ' '.join(str(i) for i in args.ids))
        protocols = ' and '.join(f'{p:.1f}' for p in PROTOCOLS[args.protocol])
        print(f'{prog}: no servo answered on {args.port} ({what} at {tried} bps, Protocol '
              f'{protocols}).\n{NO_SERVO_HINT}', file=err)
        return EXIT_NOT_FOUND
    print(f'{prog}: found {plural(len(result.servos), "servo")} (tried {tried} bps)', file=err)
    _report_bauds(result.servos, err, prog)
    if args.output is not None:
        return write_output(args, result, latency, err, prog)
    return EXIT_OK


def _seconds(value_s: float) -> str:
    """Return a duration for a person: whole seconds, tenths under ten."""
    return f'{value_s:.0f}' if value_s >= 10.0 else f'{value_s:.1f}'


def _is_terminal(stream: TextIO) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):   # a replaced or closed stream
        return False


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Run the `scan` executable; return the exit status."""
    try:
        args = _parse_args(argv)
    except _UsageError as exc:
        print(f'scan: error: {exc}', file=sys.stderr)
        return EXIT_USAGE
    except SystemExit as exc:  # --help
        return exc.code if isinstance(exc.code, int) else EXIT_USAGE
    try:
        return run(args)
    except KeyboardInterrupt:   # before the scan began, or while its end was said
        print('scan: interrupted', file=sys.stderr)
        return EXIT_INTERRUPTED


def _run_dxl(args: argparse.Namespace) -> int:
    """Check the arguments as `scan` does, then run the scan as `dxl scan`."""
    problem = check_arguments(args)
    if problem is not None:
        raise ToolError(problem, EXIT_USAGE)
    return run(args, 'dxl scan', args.trace)


def register(sub: 'argparse._SubParsersAction[argparse.ArgumentParser]') -> None:
    """Add scan to `dxl`."""
    help_text = ('find the servos on a port: every baud rate some model takes, Protocol 2.0 '
                 'and 1.0; optionally write a parameter file for the node')
    parser = sub.add_parser('scan', help=help_text, description=help_text,
                            epilog=f'example:\n  {EXAMPLE}',
                            formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(parser)
    # What every `dxl` command takes beside its own options.
    parser.add_argument('--trace', default='', metavar='FILE',
                        help='write every frame sent and received to FILE (`dxl trace FILE` '
                        'decodes it)')
    parser.set_defaults(run=_run_dxl)


if __name__ == '__main__':
    sys.exit(main())
