"""Bus traces: written by the tool (--trace) and the node (`trace`), decoded by `dxl trace`."""

import os
import pathlib
import re
import subprocess
import time
from typing import List

from ament_index_python.packages import get_package_prefix
from dxl_servo_driver.protocol import (
    decode_packet, encode_instruction, encode_status, Instruction)
from dxl_servo_driver.tool.session import open_bus, retried
from dxl_servo_driver.tool.trace import decode, read_trace
from dxl_servo_driver.wire import TracedPort
from processes import fresh_domain_id, NodeProcess, params_yaml, StartVirtualBus

TIMEOUT_S = 60.0


def dxl() -> str:
    """Return the installed `dxl` executable."""
    return os.path.join(get_package_prefix('dxl_servo_driver'), 'lib', 'dxl_servo_driver', 'dxl')


def sent_instructions(path: pathlib.Path) -> List[str]:
    """Return the instruction of every packet the trace says went out, decoded here alone."""
    names = []
    for line in path.read_text().split('\n')[:-1]:   # whole lines only (one may be coming)
        parts = line.split(None, 2)
        if len(parts) == 3 and parts[1] == 'tx':
            names.append(Instruction(decode_packet(bytes.fromhex(parts[2])).instruction).name)
    return names


def decoded_instructions(text: str) -> List[str]:
    """Return the instruction of every request line of `dxl trace`'s output."""
    return re.findall(r'^ *[\d.]+ ms >  (?:id \d+|broadcast) ([A-Z_]+)', text, re.MULTILINE)


def test_a_tool_trace_decodes_to_what_was_sent(virtual_bus: StartVirtualBus,
                                               tmp_path: pathlib.Path) -> None:
    bus_process = virtual_bus([1], 1000000)
    trace = tmp_path / 'selftest.trace'
    done = subprocess.run([dxl(), 'selftest', '1', '--port', bus_process.device, '--baud',
                           '1000000', '--trace', str(trace)], capture_output=True, text=True,
                          timeout=TIMEOUT_S)
    assert done.returncode == 0, done.stdout + done.stderr
    decoded = subprocess.run([dxl(), 'trace', str(trace), '--strict'], capture_output=True,
                             text=True, timeout=TIMEOUT_S)
    assert decoded.returncode == 0, decoded.stdout + decoded.stderr
    text = decoded.stdout
    sent = sent_instructions(trace)
    assert len(sent) > 50 and sent[0] == 'PING'
    assert decoded_instructions(text) == sent
    # Item names and values from the model the ping named.
    assert re.search(r'<  id 1 PING reply \+\d+ us: model 1030 XM430-W210, firmware 45', text)
    assert re.search(r'>  id 1 WRITE 102\+2: goal_current=112 \(0\.3013 A\)', text), text
    assert re.search(r'<  id 1 READ reply \+\d+ us: .*present_input_voltage=120 \(12 V\)', text)
    assert re.search(rf'requests: {len(sent)} \(.*\); replies: {len(sent)}$', text, re.MULTILINE)
    assert 'anomalies: 0 without reply, 0 CRC errors, 0 garbage bytes' in text


def test_a_node_trace_decodes_to_what_was_sent(virtual_bus: StartVirtualBus,
                                               workdir: pathlib.Path) -> None:
    bus_process = virtual_bus([1, 2], 1000000, extra_args=['--timing', 'wire'])
    trace = workdir / 'node.trace'
    node = NodeProcess(workdir, params_yaml(bus_process.device, {'j1': {'id': 1}, 'j2': {'id': 2}},
                                            trace=f'"{trace}"'),
                       domain_id=fresh_domain_id())
    try:
        # Wait for the cycle: sync reads of both servos' state blocks.
        deadline = time.monotonic() + TIMEOUT_S
        while not (trace.exists() and sent_instructions(trace).count('SYNC_READ') >= 20):
            node.alive()
            assert time.monotonic() < deadline, 'no cycle in the trace:\n' + node.output()
            time.sleep(0.1)
    finally:
        node.stop()
    lines = read_trace(trace.open(), str(trace))
    text, decoder = decode(lines)
    requests = [line for line in text if ' >  ' in line]
    sent = sent_instructions(trace)
    assert decoded_instructions('\n'.join(requests)) == sent
    assert {'PING', 'READ', 'WRITE', 'SYNC_READ'} <= set(sent), set(sent)
    # The state block read through indirect entries is named by the items they point to.
    assert any(re.search(r'<  id 2 SYNC_READ reply .*present_position=', line) for line in text)
    assert decoder.tally.corrupt == 0 and decoder.tally.garbage_bytes == 0


def test_anomalies_are_named(tmp_path: pathlib.Path) -> None:
    read = encode_instruction(1, Instruction.READ, bytes([132, 0, 4, 0]))
    answer = encode_status(1, 0, (2048 + 100).to_bytes(4, 'little'))
    corrupt = bytearray(answer)
    corrupt[9] ^= 0x10
    lines = [
        '# a trace written by hand',
        '1000 baud 1000000',
        f'1100 tx {encode_instruction(1, Instruction.PING).hex(" ")}',
        f'1300 rx {encode_status(1, 0, bytes([0x06, 0x04, 45])).hex(" ")}',
        f'1400 tx {read.hex(" ")}',
        f'21400 tx {read.hex(" ")}',
        f'21900 rx {bytes(corrupt).hex(" ")}',
        f'41400 tx {read.hex(" ")}',
        f'41800 rx 00 11 22 {answer.hex(" ")}',
        f'61000 drop {answer.hex(" ")}',
        f'61100 tx {encode_instruction(2, Instruction.PING).hex(" ")}',
    ]
    path = tmp_path / 'made.trace'
    path.write_text('\n'.join(lines) + '\n')
    done = subprocess.run([dxl(), 'trace', str(path), '--strict'], capture_output=True,
                          text=True, timeout=TIMEOUT_S)
    assert done.returncode == 1, done.stdout + done.stderr
    out = done.stdout
    assert '<  id 1 PING reply +200 us: model 1030 XM430-W210, firmware 45' in out
    assert re.search(r'0\.400 ms !  NO REPLY from id 1 to the READ sent here \(asked again\)',
                     out), out
    assert '!  CRC ERROR in a frame from id 1' in out
    assert '!  GARBAGE 3 bytes (no frame): 00 11 22' in out
    assert '<  id 1 READ reply +400 us: present_position=2148 (0.1534 rad)' in out
    assert '!  DROPPED 11 bytes waiting before a request' not in out   # 15: a 4-byte status
    assert '!  DROPPED 15 bytes waiting before a request' in out
    assert re.search(r'60\.100 ms !  NO REPLY from id 2 to the PING sent here \(the trace ends\)',
                     out), out
    assert out.rstrip().splitlines()[-1] == (
        'anomalies: 2 without reply, 1 CRC errors, 3 garbage bytes, 15 bytes dropped late, '
        '0 status errors, 0 echoes')


def test_a_bad_trace_is_refused(tmp_path: pathlib.Path) -> None:
    path = tmp_path / 'bad.trace'
    path.write_text('1000 tx ff ff fd\n1001 sideways ff\n')
    done = subprocess.run([dxl(), 'trace', str(path)], capture_output=True, text=True,
                          timeout=TIMEOUT_S)
    assert done.returncode == 2
    assert done.stdout == ''
    assert done.stderr.strip() == (f'dxl trace: error: {path} line 2 is not a trace line '
                                   "(unknown direction 'sideways'): '1001 sideways ff'")


def test_an_untraced_bus_has_its_port_as_it_is(virtual_bus: StartVirtualBus,
                                               tmp_path: pathlib.Path) -> None:
    bus_process = virtual_bus([1], 1000000)
    plain = open_bus(bus_process.device, 1000000)
    try:
        assert plain.trace is None and not isinstance(plain.port, TracedPort)
        retried(lambda: plain.ping(1))
    finally:
        plain.close()
    traced = open_bus(bus_process.device, 1000000, trace=str(tmp_path / 't'))
    try:
        assert isinstance(traced.port, TracedPort)
        assert retried(lambda: traced.ping(1)) == 1030
    finally:
        traced.close()
    kinds = [line.split()[1] for line in (tmp_path / 't').read_text().splitlines()
             if not line.startswith('#')]
    # One ping (more if a reply was lost on a loaded machine) and its answer, after the speed.
    assert kinds[0] == 'baud' and kinds[1] == 'tx' and kinds[-1] == 'rx', kinds
