"""
The parameter file `scan --output FILE` writes: the node runs it as it is.

Its servos are those at the baud rate most of them answered at, of a known model and in a valid
operating mode (the rest are listed in its comments); a joint on the other protocol than the
bus's says so (`<joint>.protocol`). Its `latency_timer` is the adapter's as the node measures it
at configure (driver/adapter.measure_latency_timer: Linux's word, else the found servos'
answers timed).
"""

import argparse
import datetime
import os
from typing import Any, Dict, List, Optional, Sequence, Set, TextIO, Tuple

from dxl_servo_driver import config
from dxl_servo_driver import models
from dxl_servo_driver.bus import (
    Bus, DEFAULT_PROTOCOL, FoundServo, FRAMERS, LINUX_LATENCY_TIMER_MS, ScanResult, set_baud)
from dxl_servo_driver.driver.adapter import measure_latency_timer, Measured
from dxl_servo_driver.errors import CommError, PortError
from dxl_servo_driver.tool.common import EXIT_OK, EXIT_OUTPUT
from dxl_servo_driver.tool.scan_report import describe, plural

NOT_MEASURED = 'not measured here: the Linux default (1 with our udev rule)'


def choose_baud(servos: Sequence[FoundServo]) -> int:
    """Return the baud rate most servos answered at (ties: the one scanned first)."""
    counts: Dict[int, int] = {}
    for servo in servos:
        counts[servo.baud_bps] = counts.get(servo.baud_bps, 0) + 1
    return max(counts, key=lambda baud: counts[baud])  # max keeps the first of equals


def build_parameters(port: str, servos: Sequence[FoundServo],
                     latency_timer_ms: Optional[float] = None
                     ) -> Tuple[Dict[str, Any], List[str]]:
    """
    Return the node's flat parameters for the servos found, and the comment lines to go with them.

    Only servos at the chosen baud rate (the one most of them use), of a known model and in a
    valid operating mode become joints; the others are listed in the comments. ValueError when
    no servo qualifies; config.ConfigError when the result does not validate.
    """
    if not servos:
        raise ValueError('no servo found: nothing to write')
    baud_bps = choose_baud(servos)
    params: Dict[str, Any] = {'port': port, 'baud_rate': baud_bps}
    # The node's reply deadlines need it: the adapter's as measured, else the Linux default.
    params['latency_timer'] = float(latency_timer_ms if latency_timer_ms is not None
                                    else LINUX_LATENCY_TIMER_MS)
    comments = [describe(servo) for servo in servos]
    left_out: List[str] = []
    joints: List[str] = []
    ids: Set[int] = set()
    for servo in sorted(servos, key=lambda s: (s.baud_bps != baud_bps, s.servo_id, s.baud_bps)):
        if servo.baud_bps != baud_bps:
            raws = {} if not servo.known_model else {
                bps: raw for raw, bps in servo.table.bauds.items()}
            how = (f'set its baud_rate register to {raws[baud_bps]} ({baud_bps} bps)'
                   if baud_bps in raws else f'its model cannot run at {baud_bps} bps')
            left_out.append(f'id {servo.servo_id} answered at {servo.baud_bps} bps, not '
                            f'{baud_bps}: {how} or run a second node at its baud')
        elif not servo.known_model:
            left_out.append(f'id {servo.servo_id}: '
                            f'{models.unsupported_reason(servo.model_number)}')
        elif servo.operating_mode is None:
            left_out.append(f'id {servo.servo_id}: operating mode not read or not valid')
        elif servo.servo_id in ids:
            left_out.append(f'id {servo.servo_id}: listed twice')
        else:
            joint = f'joint_{servo.servo_id}'
            ids.add(servo.servo_id)
            joints.append(joint)
            params[f'{joint}.id'] = servo.servo_id
            params[f'{joint}.model'] = servo.table.name
            params[f'{joint}.operating_mode'] = servo.operating_mode
            params[f'{joint}.protocol'] = servo.protocol
            # The joint as the robot sees it: the servo's angle until the user says otherwise.
            params[f'{joint}.offset'] = 0.0
            params[f'{joint}.reverse'] = False
            params[f'{joint}.ratio'] = 1.0
    if not joints:
        raise ValueError('no servo the node could drive (' + '; '.join(left_out) + ')')
    params['joints'] = joints
    # The bus speaks the protocol every joint speaks, the default where they differ; a joint
    # on another protocol than the bus's says so.
    spoken = {params[f'{joint}.protocol'] for joint in joints}
    bus_protocol = spoken.pop() if len(spoken) == 1 else DEFAULT_PROTOCOL
    params['protocol'] = bus_protocol
    for joint in joints:
        if params[f'{joint}.protocol'] == bus_protocol:
            del params[f'{joint}.protocol']
    config.validate(params)
    if left_out:
        comments.append('Not configured below:')
        comments.extend(f'  {line}' for line in left_out)
    return params, comments


def _yaml_string(text: str) -> str:
    # Single-quoted YAML scalar: only the quote itself needs escaping (doubled).
    return "'" + text.replace("'", "''") + "'"


def render_parameter_file(params: Dict[str, Any], comments: Sequence[str], header: str,
                          latency_source: str = 'read from the adapter') -> str:
    """
    Return the ROS 2 parameter file (`/**: ros__parameters:`) for build_parameters' output.

    latency_source: where its latency_timer came from, said in its comment (Measured.describe).
    """
    lines = [f'# {header}']
    lines.extend(f'#   {comment}' for comment in comments)
    lines.append('/**:')
    lines.append('  ros__parameters:')
    lines.append(f'    port: {_yaml_string(params["port"])}')
    lines.append(f'    baud_rate: {params["baud_rate"]}')
    if 'protocol' in params:
        lines.append(f'    protocol: {params["protocol"]}')
    if 'latency_timer' in params:
        lines.append(f'    latency_timer: {params["latency_timer"]}  # ms, {latency_source}')
    lines.append(f'    joints: [{", ".join(params["joints"])}]')
    for joint in params['joints']:
        lines.append(f'    {joint}:')
        lines.append(f'      id: {params[joint + ".id"]}')
        lines.append(f'      model: {params[joint + ".model"]}')
        lines.append(f'      operating_mode: {params[joint + ".operating_mode"]}')
        if joint + '.protocol' in params:
            lines.append(f'      protocol: {params[joint + ".protocol"]}  # not the bus\'s')
        if joint + '.offset' in params:
            lines.append(f'      offset: {params[joint + ".offset"]!r}  # rad: the URDF zero in '
                         "the servo's radians (raw 2048 = 0)")
            lines.append(f'      reverse: {str(params[joint + ".reverse"]).lower()}  # the joint '
                         'turns against the servo')
            lines.append(f'      ratio: {params[joint + ".ratio"]!r}  # joint units per servo '
                         'radian (a 1:3 gearbox: 0.333...)')
    return '\n'.join(lines) + '\n'


def _write_file(path: str, text: str) -> None:
    temporary = f'{path}.tmp{os.getpid()}'
    try:
        with open(temporary, 'w', encoding='utf-8') as stream:
            stream.write(text)
        os.replace(temporary, path)
    finally:
        if os.path.exists(temporary):
            os.unlink(temporary)


def measure_latency(bus: Bus, port: str, servos: Sequence[FoundServo]) -> Optional[Measured]:
    """
    Return the adapter's latency timer as the node will measure it, None where it cannot be.

    The node's own measurement (driver/adapter.measure_latency_timer): Linux's word for it, else
    pings of the servos the file lists (at the baud rate it chooses, each in its protocol) timed.
    """
    baud_bps = choose_baud(servos)
    listed = [servo for servo in servos if servo.baud_bps == baud_bps and servo.known_model]
    set_baud(bus, baud_bps)
    for servo in listed:
        bus.speak(servo.servo_id, FRAMERS[servo.protocol])
    try:
        return measure_latency_timer(port, bus, [servo.servo_id for servo in listed])
    except (CommError, PortError):
        return None


def write_output(args: argparse.Namespace, result: ScanResult, latency: Optional[Measured],
                 err: TextIO, prog: str) -> int:
    """Write the parameter file of what was found to --output; return the exit status."""
    try:
        params, comments = build_parameters(args.port, result.servos,
                                            None if latency is None else latency.timer_ms)
    except (ValueError, config.ConfigError) as exc:  # ConfigError is a ValueError too
        print(f'{prog}: error: {args.output} not written: {exc}', file=err)
        return EXIT_OUTPUT
    stamp = datetime.datetime.now().isoformat(timespec='seconds')
    # Both ways of running the node: ROS 2 from PyPI has no ros2 command line.
    header = (f'Written by `{prog} --port {args.port}` at {stamp}; run it with '
              f'`ros2 run dxl_servo_driver node --ros-args --params-file {args.output}` '
              '(without the ros2 command line: install/dxl_servo_driver/lib/dxl_servo_driver/'
              f'node --ros-args --params-file {args.output}).')
    try:
        _write_file(args.output, render_parameter_file(
            params, comments, header, NOT_MEASURED if latency is None else latency.describe()))
    except OSError as exc:
        print(f'{prog}: error: cannot write {args.output}: {exc.strerror or exc}', file=err)
        return EXIT_OUTPUT
    print(f'{prog}: wrote {args.output} ({plural(len(params["joints"]), "joint")} at '
          f'{params["baud_rate"]} bps)', file=err)
    return EXIT_OK
