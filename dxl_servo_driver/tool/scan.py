"""
`dxl scan`: find the servos on a port, at every baud rate, in both protocols (`scan`'s own).

The same command as the `scan` executable, inside `dxl`: its options are the ones
`tool.scan_bus.add_arguments` builds (one definition for both), its run is `tool.scan_bus.run`,
so what it prints, writes and exits with is scan's (README.md, docs/hardware.md), said as
`dxl scan`; like every `dxl` command it also takes --trace FILE.
"""

import argparse

from dxl_servo_driver.tool import scan_bus as scan
from dxl_servo_driver.tool.common import EXIT_USAGE, ToolError

EXAMPLE = 'dxl scan --port /dev/ttyDXL --output robot.yaml'


def run(args: argparse.Namespace) -> int:
    """Check the arguments as `scan` does, then run the scan; return its exit status."""
    problem = scan.check_arguments(args)
    if problem is not None:
        raise ToolError(problem, EXIT_USAGE)
    return scan.run(args, 'dxl scan', args.trace)


def register(sub: 'argparse._SubParsersAction[argparse.ArgumentParser]') -> None:
    """Add scan."""
    help_text = ('find the servos on a port: every baud rate some model takes, Protocol 2.0 '
                 'and 1.0; optionally write a parameter file for the node')
    parser = sub.add_parser('scan', help=help_text, description=help_text,
                            epilog=f'example:\n  {EXAMPLE}',
                            formatter_class=argparse.RawDescriptionHelpFormatter)
    scan.add_arguments(parser)
    # What every `dxl` command takes beside its own options.
    parser.add_argument('--trace', default='', metavar='FILE',
                        help='write every frame sent and received to FILE (`dxl trace FILE` '
                        'decodes it)')
    parser.set_defaults(run=run)
