# noqa: A005 (the brief names it tool/trace.py; it is imported by its full name only)
"""
`dxl trace FILE`: a bus trace decoded, frame by frame, for a person.

A trace is what `--trace FILE` (any `dxl` command) or the node's `trace` parameter wrote: a line
per write or read of the port (wire.BusTrace: `<monotonic us> tx|rx|drop <hex>`, `baud <bps>`,
`#` comments). Each request is printed with its instruction, id and the items it names (the
model's table: --model, else the one each id's ping answer named, else addresses only), each
reply with its status error, values (raw, and SI where the item has a unit) and how long after
its request it came; and the anomalies: a request left without a reply, a corrupted frame (CRC),
bytes that are no frame (garbage), replies the bus dropped unread before a request (late ones),
our own packet coming back (the adapter's echo). Indirect data items are shown as the items
their indirect addresses point to, when the trace holds the writes that set them.

Protocol 2.0 and 1.0, read with the framers' own scans (tool/trace_decode.py decodes). Which
one: --protocol, else the one the trace's header names (the tool writes `Protocol 1.0` there),
else the one its requests are packets of (a tx line starts with FF FF FD 00 in 2.0, FF FF <id>
<length> in 1.0). A trace holding requests of both (a mixed bus,
a scan of both protocols) has each frame read as its own header says: both scans run and a frame
whose check holds claims its bytes. In 1.0 a status carries the error bits (input voltage, angle
limit, overheating, range, checksum, overload, instruction: the refusals as STATUS ERROR, the
hardware state as ALERT), no model number in a ping's answer: the model is learnt from a read of
the model number at address 0. A wrong checksum is reported as a CRC is in 2.0.
"""

import argparse
import itertools
import os
import re
import sys
from typing import FrozenSet, Iterable, List, Optional, Sequence, Tuple

from dxl_servo_driver import models
from dxl_servo_driver.models.base import Model, ModelError
from dxl_servo_driver.protocol import Framer, FRAMERS, PROTOCOL_2
from dxl_servo_driver.tool.common import (
    add_command, EXIT_FAILED, EXIT_OK, EXIT_USAGE, ToolError)
from dxl_servo_driver.tool.trace_decode import Decoder, Line, LONGEST

DIRECTIONS = ('tx', 'rx', 'drop')
# The note the tool writes in the header line (tool/session.open_bus: `Protocol 1.0`).
_HEADER_PROTOCOL = re.compile(r'^# dxl bus trace:.*\bProtocol ([12])(?:\.0)?\s*$')
# The protocol a trace is read in when nothing says another: the bus's own default.
DEFAULT_FRAMER = PROTOCOL_2


def header_protocol(line: str) -> Optional[int]:
    """Return the protocol a trace's header line names (1 or 2), or None when it names none."""
    match = _HEADER_PROTOCOL.match(line.strip())
    return int(match.group(1)) if match else None


def read_trace(stream: Iterable[str], name: str) -> List[Line]:
    """Return the lines of a trace; ToolError naming the first malformed line."""
    lines: List[Line] = []
    for number, text in enumerate(stream, 1):
        text = text.strip()
        if not text or text.startswith('#'):
            continue
        parts = text.split(None, 2)
        try:
            t_us = int(parts[0])
            kind = parts[1]
            if kind == 'baud':
                lines.append(Line(number, t_us, kind, baud=int(parts[2])))
            elif kind in DIRECTIONS:
                lines.append(Line(number, t_us, kind, bytes.fromhex(parts[2])))
            else:
                raise ValueError(f'unknown direction {kind!r}')
        except (IndexError, ValueError) as exc:
            raise ToolError(f'{name} line {number} is not a trace line ({exc}): {text[:60]!r}',
                            EXIT_USAGE) from None
    return lines


def frame_protocols(lines: Iterable[Line]) -> FrozenSet[Framer]:
    """Return the framers of the trace's requests: a tx line begins with a packet of one."""
    framers = set(FRAMERS.values())
    found = set()
    for line in lines:
        if line.kind != 'tx':
            continue
        for framer in framers:
            frames, _ = framer.scan(line.data, 0, LONGEST, True)
            if frames and frames[0].start == 0 and frames[0].crc_ok:
                found.add(framer)
        if found == framers:
            break
    return frozenset(found)


def decode(lines: Sequence[Line], model: Optional[Model] = None, protocol: Optional[int] = None,
           source: str = '--protocol') -> Tuple[List[str], Decoder]:
    """
    Return the decoded text of trace lines, and the decoder (its tally).

    protocol: 1 or 2, every frame read in it (source says who says so, for the first line);
    None: the protocols the requests are packets of (frame_protocols; none found: 2.0). A trace
    read in another protocol than 2.0 starts with a line that says which and why.
    """
    if protocol is None:
        framers = frame_protocols(lines) or frozenset({DEFAULT_FRAMER})
    else:
        framers = frozenset({FRAMERS[protocol]})
    decoder = Decoder(model, list(framers))
    out: List[str] = []
    versions = [f'{framer.version}.0' for framer in decoder.framers]
    if decoder.mixed:
        out.append(f'Protocol {" and ".join(versions)} (its requests are packets of both): each '
                   f'frame read as its header says, a request marked '
                   f'{" or ".join(f"[{version}]" for version in versions)}')
    elif decoder.framers[0] is not DEFAULT_FRAMER:
        if protocol is None:
            source = f'its requests are Protocol {versions[0]} packets'
        out.append(f'Protocol {versions[0]} ({source})')
    for line in lines:
        out.extend(decoder.feed(line))
    out.extend(decoder.finish())
    return out, decoder


def _protocol(text: str) -> int:
    """Return the major version --protocol names: 1 or 2 (1.0 and 2.0 taken too)."""
    try:
        value = float(text)
    except ValueError:
        value = 0.0
    if value not in (1.0, 2.0):
        raise argparse.ArgumentTypeError(f'{text!r} is not a protocol: 1 or 2')
    return int(value)


def run(args: argparse.Namespace) -> int:
    """Print a trace decoded; exit 1 when it shows anomalies and --strict was given."""
    model: Optional[Model] = None
    if args.model:
        try:
            model = (models.model_for(int(args.model)) if args.model.isdigit()
                     else models.model_named(args.model))
        except ModelError as exc:
            raise ToolError(f'--model: {exc}', EXIT_USAGE) from None
    try:
        with open(args.file, encoding='ascii', errors='replace') as stream:
            first = stream.readline()
            lines = read_trace(itertools.chain([first], stream), args.file)
    except OSError as exc:
        raise ToolError(f'cannot read {args.file}: {exc.strerror or exc}', EXIT_USAGE) from None
    protocol, source = args.protocol, f'--protocol {args.protocol}'
    if protocol is None:
        protocol, source = header_protocol(first), "the trace's header says so"
    text, decoder = decode(lines, model, protocol, source)
    try:
        for line in text + decoder.summary():
            print(line)
        sys.stdout.flush()
    except BrokenPipeError:
        # Read by a pager or `head` that stopped reading: not an error of the trace.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_OK
    return EXIT_FAILED if args.strict and decoder.tally.anomalies else EXIT_OK


def register(subparsers: 'argparse._SubParsersAction[argparse.ArgumentParser]') -> None:
    """Add `dxl trace`."""
    parser = add_command(
        subparsers, 'trace', 'decode a bus trace (--trace FILE, or the trace parameter of the '
        'node)', __doc__.strip().splitlines()[0],
        'dxl scan --port /dev/ttyUSB0 --trace bus.trace',
        'dxl trace bus.trace --model XM430-W350',
        'dxl get 1 present_position --port /dev/ttyUSB0 --protocol 1.0 --trace ax.trace',
        'dxl trace ax.trace                    # Protocol 1.0: its header says so',
        'dxl trace old.trace --protocol 1      # a trace whose header names none')
    parser.add_argument('file', metavar='FILE', help='the trace file')
    parser.add_argument('--model', metavar='NAME|NUMBER',
                        help='the control table of every id (default: the one the ping '
                        'answer of each id in the trace names, in Protocol 1.0 its read of '
                        'the model number; none: addresses only)')
    parser.add_argument('--protocol', type=_protocol, metavar='{1,2}',
                        help="read every frame in this protocol (default: the one the trace's "
                        'header names, else the one its requests are packets of; both, each '
                        'frame by its header, when it holds requests of both)')
    parser.add_argument('--strict', action='store_true',
                        help='exit 1 when the trace shows anomalies')
    parser.set_defaults(run=run)
