"""The `dxl` entry point: one parser, a subparser per command module (see the package doc)."""

import argparse
import importlib
import sys
from typing import List, Optional, Sequence

from dxl_servo_driver.tool.common import EXIT_INTERRUPTED, EXIT_USAGE, ToolError

# The command modules, in the order `dxl --help` lists them.
COMMANDS = (
    'adapters',
    'setup_servos',
    'servo',
    'backup',
    'look',
    'step',
    'selftest',
    'trace',
    'calibrate',
    'scan',
)


def build_parser() -> argparse.ArgumentParser:
    """Return the parser of every command."""
    parser = argparse.ArgumentParser(
        prog='dxl', description='Set up, inspect, back up, calibrate, look at and trace '
        'Dynamixel servos, headless (no ROS graph needed). `dxl COMMAND --help` for each.')
    sub = parser.add_subparsers(dest='command', metavar='COMMAND')
    for name in COMMANDS:
        importlib.import_module(f'dxl_servo_driver.tool.{name}').register(sub)
    return parser


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Run one command; return its exit status."""
    parser = build_parser()
    args_list: List[str] = list(sys.argv[1:] if argv is None else argv)
    try:
        args = parser.parse_args(args_list)
    except SystemExit as exc:   # --help, or a usage error argparse has printed
        return exc.code if isinstance(exc.code, int) else EXIT_USAGE
    if getattr(args, 'run', None) is None:
        parser.print_help(sys.stderr)
        return EXIT_USAGE
    try:
        return int(args.run(args))
    except ToolError as exc:
        print(f'dxl {args.command}: error: {exc}', file=sys.stderr)
        return exc.status
    except KeyboardInterrupt:
        print(f'dxl {args.command}: interrupted', file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == '__main__':
    sys.exit(main())
