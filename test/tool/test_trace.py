"""Bus traces: written by the tool (--trace) and the node (`trace`), decoded by `dxl trace`."""

import os
import pathlib
import re
import subprocess
import time
from typing import List

from ament_index_python.packages import get_package_prefix
from dxl_servo_driver.bus.wire import TracedPort
from dxl_servo_driver.protocol import (
    decode_packet, encode_instruction, encode_status, Instruction)
from dxl_servo_driver.protocol import protocol1
from dxl_servo_driver.protocol.protocol1 import Instruction1, PROTOCOL_1
from dxl_servo_driver.tool.session import open_bus, retried
from dxl_servo_driver.tool.trace import decode, read_trace
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


def sent_instructions_1(path: pathlib.Path) -> List[str]:
    """Return the instruction of every Protocol 1.0 packet the trace says went out."""
    names = []
    for line in path.read_text().split('\n')[:-1]:
        parts = line.split(None, 2)
        if len(parts) == 3 and parts[1] == 'tx':
            names.append(Instruction1(protocol1.decode_packet(bytes.fromhex(parts[2]))
                                      .instruction).name)
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


def test_a_protocol_1_tool_trace_decodes_to_what_was_sent(virtual_bus: StartVirtualBus,
                                                          tmp_path: pathlib.Path) -> None:
    # An MX-28 on its Protocol 1.0 firmware (model 29): no model number in a ping's answer.
    bus_process = virtual_bus([1], 1000000, extra_args=['--models', 'MX-28'])
    trace = tmp_path / 'selftest1.trace'
    done = subprocess.run([dxl(), 'selftest', '1', '--port', bus_process.device, '--baud',
                           '1000000', '--protocol', '1.0', '--trace', str(trace)],
                          capture_output=True, text=True, timeout=TIMEOUT_S)
    assert done.returncode == 0, done.stdout + done.stderr
    assert trace.read_text().splitlines()[0].endswith(', Protocol 1.0')
    decoded = subprocess.run([dxl(), 'trace', str(trace), '--strict'], capture_output=True,
                             text=True, timeout=TIMEOUT_S)
    assert decoded.returncode == 0, decoded.stdout + decoded.stderr
    text = decoded.stdout
    assert text.splitlines()[0] == "Protocol 1.0 (the trace's header says so)"
    sent = sent_instructions_1(trace)
    assert len(sent) > 50 and sent[0] == 'PING'
    assert {'PING', 'READ', 'WRITE'} <= set(sent), set(sent)
    assert decoded_instructions(text) == sent
    assert re.search(r'<  id 1 PING reply \+\d+ us$', text, re.MULTILINE), text
    # The model comes from the read of the model number, and names the items from then on.
    assert re.search(r'<  id 1 READ reply \+\d+ us: model 29 MX-28, model_number=29, '
                     r'firmware_version=\d+', text), text
    assert re.search(r'>  id 1 WRITE 30\+2: goal_position=2048 \(0 rad\)', text), text
    assert re.search(r'>  id 1 READ \d+\+\d+ .*present_position', text), text
    assert re.search(r'<  id 1 READ reply \+\d+ us: .*present_position=\d+ \(-?[\d.e-]+ rad\)',
                     text), text
    assert 'GARBAGE' not in text and 'no packet' not in text and 'STATUS ERROR' not in text
    assert re.search(rf'requests: {len(sent)} \(.*\); replies: {len(sent)}$', text, re.MULTILINE)
    assert text.rstrip().splitlines()[-1] == (
        'anomalies: 0 without reply, 0 checksum errors, 0 garbage bytes, 0 bytes dropped late, '
        '0 status errors, 0 echoes')
    # Read as Protocol 2.0 (forced), the same packets are no packets.
    forced = subprocess.run([dxl(), 'trace', str(trace), '--protocol', '2'],
                            capture_output=True, text=True, timeout=TIMEOUT_S)
    assert forced.returncode == 0, forced.stderr
    assert decoded_instructions(forced.stdout) == []
    assert re.search(r'>  8 bytes that are no packet: ff ff 01 04 02 00 ', forced.stdout)


def test_a_protocol_1_status_error_is_named_by_its_bits(virtual_bus: StartVirtualBus,
                                                        tmp_path: pathlib.Path) -> None:
    bus_process = virtual_bus([1], 1000000, extra_args=['--models', 'AX-12A'])
    bus = ['--port', bus_process.device, '--baud', '1000000', '--protocol', '1.0']
    done = subprocess.run([dxl(), 'set', '1', 'ccw_angle_limit', '600', '--raw', *bus],
                          capture_output=True, text=True, timeout=TIMEOUT_S)
    assert done.returncode == 0, done.stdout + done.stderr
    assert bus_process.control('error 1 overload').startswith('ok')
    # An echoing adapter: in 1.0 our READ and WRITE coming back look like statuses with errors.
    assert bus_process.control('adapter echo on').startswith('ok')
    # Beyond the angle limit: the servo refuses it (the angle limit bit), overloaded besides.
    trace = tmp_path / 'refused.trace'
    done = subprocess.run([dxl(), 'set', '1', 'goal_position', '1000', '--raw', *bus,
                           '--trace', str(trace)], capture_output=True, text=True,
                          timeout=TIMEOUT_S)
    assert done.returncode == 1, done.stdout + done.stderr
    decoded = subprocess.run([dxl(), 'trace', str(trace)], capture_output=True, text=True,
                             timeout=TIMEOUT_S)
    assert decoded.returncode == 0, decoded.stdout + decoded.stderr
    text = decoded.stdout
    assert re.search(r'<  id 1 READ reply \+\d+ us: ALERT 0x20: overload error \(the load exceeds '
                     r'the torque limit\), model 12 AX-12A, model_number=12', text), text
    assert re.search(r'>  id 1 WRITE 30\+2: goal_position=1000 \(2\.495 rad\)\n.*<  echo of our '
                     r'WRITE \(the adapter echoes\)\n.*<  id 1 WRITE reply \+\d+ us: STATUS ERROR '
                     r'0x02: angle limit error \(goal position outside the angle limits\), '
                     r'ALERT 0x20: overload error', text), text
    sent = len(sent_instructions_1(trace))
    assert re.search(rf'requests: {sent} \(.*\); replies: {sent}$', text, re.MULTILINE), text
    assert text.rstrip().splitlines()[-1] == (
        'anomalies: 0 without reply, 0 checksum errors, 0 garbage bytes, 0 bytes dropped late, '
        f'1 status errors, {sent} echoes')


def test_protocol_1_sync_write_and_bulk_read_decode_item_by_item(tmp_path: pathlib.Path) -> None:
    enc, status = protocol1.encode_instruction, protocol1.encode_status

    def model_read(servo_id: int) -> List[str]:
        return [f'tx {enc(servo_id, Instruction1.READ, bytes([0, 3])).hex(" ")}',
                f'rx {status(servo_id, 0, bytes([29, 0, 40])).hex(" ")}']

    sync_write = enc(protocol1.BROADCAST_ID, Instruction1.SYNC_WRITE, bytes(
        [30, 4, 1, *(1000).to_bytes(2, 'little'), *(100).to_bytes(2, 'little'),
         2, *(3000).to_bytes(2, 'little'), *(200).to_bytes(2, 'little')]))
    bulk_read = enc(protocol1.BROADCAST_ID, Instruction1.BULK_READ,
                    PROTOCOL_1.bulk_read_params([(1, 36, 2), (2, 36, 7)]))
    first = status(1, 0, (1000).to_bytes(2, 'little'))
    second = status(2, 0, bytes([*(3000).to_bytes(2, 'little'), 0, 0, 0, 0, 121]))
    read = enc(2, Instruction1.READ, bytes([43, 1]))
    corrupt = bytearray(status(2, 0, bytes([40])))
    corrupt[5] ^= 0x01
    # A ping's answer with the input voltage bit is the ping byte for byte: this adapter, whose
    # first answer came without an echo, does not echo, so it is the answer.
    ping = enc(1, Instruction1.PING)
    assert ping == status(1, protocol1.ErrorBit.INPUT_VOLTAGE)
    timed = [
        'baud 1000000', *model_read(1), *model_read(2),
        f'tx {sync_write.hex(" ")}',
        f'tx {bulk_read.hex(" ")}',
        # The adapter's echo, then the answers in the records' order, the second in two reads.
        f'rx {bulk_read.hex(" ")} {first.hex(" ")} {second[:4].hex(" ")}',
        f'rx {second[4:].hex(" ")}',
        f'tx {read.hex(" ")}',
        f'rx {bytes(corrupt).hex(" ")}',
        f'tx {ping.hex(" ")}',
        f'rx {ping.hex(" ")}',
    ]
    lines = [f'{1000 + 100 * number} {line}' for number, line in enumerate(timed)]
    path = tmp_path / 'made1.trace'
    path.write_text('\n'.join(lines) + '\n')
    done = subprocess.run([dxl(), 'trace', str(path)], capture_output=True, text=True,
                          timeout=TIMEOUT_S)
    assert done.returncode == 0, done.stdout + done.stderr
    out = done.stdout.splitlines()
    # No header names the protocol: the requests say it.
    assert out[0] == 'Protocol 1.0 (its requests are Protocol 1.0 packets)'
    assert '       0.200 ms <  id 1 READ reply +100 us: model 29 MX-28, model_number=29, ' \
           'firmware_version=40' in out
    assert ('       0.500 ms >  broadcast SYNC_WRITE 30+4 id 1: goal_position=1000 (-1.608 rad), '
            'moving_speed=100 (1.194 rad/s); id 2: goal_position=3000 (1.46 rad), '
            'moving_speed=200 (2.388 rad/s)') in out
    assert ('       0.600 ms >  broadcast BULK_READ id 1 36+2 present_position; id 2 36+7 '
            'present_position,present_speed,present_load,present_voltage') in out
    assert '       0.700 ms <  echo of our BULK_READ (the adapter echoes)' in out
    assert '       0.700 ms <  id 1 BULK_READ reply +100 us: present_position=1000 (-1.608 rad)' \
           in out
    assert ('       0.800 ms <  id 2 BULK_READ reply +200 us: present_position=3000 (1.46 rad), '
            'present_speed=0 (0 rad/s), present_load=0 (0 ratio), present_voltage=121 (12.1 V)'
            ) in out
    assert '       0.900 ms >  id 2 READ 43+1 present_temperature' in out
    assert ('       1.000 ms !  CHECKSUM ERROR in a frame from id 2 (the reply to READ): '
            f'{bytes(corrupt).hex(" ")}') in out
    assert ('       1.200 ms <  id 1 PING reply +100 us: ALERT 0x01: input voltage error (outside '
            'the voltage limits)') in out
    assert out[-3] == 'requests: 6 (1 BULK_READ, 1 PING, 3 READ, 1 SYNC_WRITE); replies: 5'
    assert out[-1] == ('anomalies: 0 without reply, 1 checksum errors, 0 garbage bytes, '
                       '0 bytes dropped late, 0 status errors, 1 echoes')


def test_a_mixed_trace_has_each_frame_read_as_its_header_says(tmp_path: pathlib.Path) -> None:
    ax_read = protocol1.encode_instruction(5, Instruction1.READ, bytes([36, 2]))
    ax_answer = protocol1.encode_status(5, 0, (612).to_bytes(2, 'little'))
    x_read = encode_instruction(1, Instruction.READ, bytes([132, 0, 4, 0]))
    # Data holding FF FF: a 1.0 header to the 1.0 scan, inside a 2.0 packet whose CRC holds.
    x_answer = encode_status(1, 0, bytes([0xFF, 0xFF, 0x05, 0x40]))
    timed = [
        f'tx {encode_instruction(1, Instruction.PING).hex(" ")}',
        f'rx {encode_status(1, 0, bytes([0x06, 0x04, 45])).hex(" ")}',
        f'tx {protocol1.encode_instruction(5, Instruction1.PING).hex(" ")}',
        f'rx {protocol1.encode_status(5, 0).hex(" ")}',
        f'tx {protocol1.encode_instruction(5, Instruction1.READ, bytes([0, 2])).hex(" ")}',
        f'rx {protocol1.encode_status(5, 0, bytes([12, 0])).hex(" ")}',
        f'tx {x_read.hex(" ")}',
        f'rx {x_answer.hex(" ")}',
        f'tx {ax_read.hex(" ")}',
        f'rx 00 {ax_answer.hex(" ")}',
        f'drop {x_answer.hex(" ")} {ax_answer.hex(" ")}',
    ]
    lines = ['# dxl bus trace: <monotonic us> tx|rx|drop <hex bytes> | baud <bps>; port /dev/x',
             *(f'{1000 + 100 * number} {line}' for number, line in enumerate(timed))]
    path = tmp_path / 'mixed.trace'
    path.write_text('\n'.join(lines) + '\n')
    done = subprocess.run([dxl(), 'trace', str(path)], capture_output=True, text=True,
                          timeout=TIMEOUT_S)
    assert done.returncode == 0, done.stdout + done.stderr
    out = done.stdout.splitlines()
    assert out[0].startswith('Protocol 2.0 and 1.0 (its requests are packets of both)')
    assert out[1:12] == [
        '       0.000 ms >  id 1 PING [2.0]',
        '       0.100 ms <  id 1 PING reply +100 us: model 1030 XM430-W210, firmware 45',
        '       0.200 ms >  id 5 PING [1.0]',
        '       0.300 ms <  id 5 PING reply +100 us',
        '       0.400 ms >  id 5 READ [1.0] 0+2',
        '       0.500 ms <  id 5 READ reply +100 us: model 12 AX-12A, model_number=12',
        '       0.600 ms >  id 1 READ [2.0] 132+4 present_position',
        '       0.700 ms <  id 1 READ reply +100 us: present_position=1074135039 (1.648e+06 rad)',
        '       0.800 ms >  id 5 READ [1.0] 36+2 present_position',
        '       0.900 ms !  GARBAGE 1 bytes (no frame): 00',
        '       0.900 ms <  id 5 READ reply +100 us: present_position=612 (0.5113 rad)',
    ]
    assert out[13:15] == [f'{"":15}      late status of id 1, error 0x00, 4 bytes',
                          f'{"":15}      late status of id 5, error 0x00, 2 bytes']
    assert out[-1] == ('anomalies: 0 without reply, 0 CRC/checksum errors, 1 garbage bytes, '
                       '23 bytes dropped late, 0 status errors, 0 echoes')
    # Forced to one protocol, the other's packets are no packets.
    forced = subprocess.run([dxl(), 'trace', str(path), '--protocol', '1.0'],
                            capture_output=True, text=True, timeout=TIMEOUT_S)
    assert forced.stdout.splitlines()[0] == 'Protocol 1.0 (--protocol 1)'
    assert '       0.000 ms >  10 bytes that are no packet: ff ff fd 00 01 03 00 01 19 4e' in \
        forced.stdout.splitlines()
    assert decoded_instructions(forced.stdout) == ['PING', 'READ', 'READ']


def test_every_request_unanswered_when_the_trace_ends_is_named() -> None:
    # Three requests wait when the trace ends: each is reported, none skipped.
    lines = ['1000 baud 1000000'] + [
        f'{1000 + 100 * servo_id} tx {encode_instruction(servo_id, Instruction.PING).hex(" ")}'
        for servo_id in (2, 3, 4)]
    text, _ = decode(read_trace(lines, 'made.trace'))
    unanswered = [line for line in text if 'NO REPLY' in line and 'the trace ends' in line]
    assert [line.split('from id ')[1].split()[0] for line in unanswered] == ['2', '3', '4']


def test_a_request_with_a_wrong_check_says_the_servo_refuses_it() -> None:
    # Both protocols' servos answer such a request with their check's error (2.0: the CRC
    # error code; 1.0: the checksum bit), as the simulator does: the decoder says so.
    ping_2 = bytearray(encode_instruction(1, Instruction.PING))
    ping_2[-1] ^= 0x01
    ping_1 = bytearray(protocol1.encode_instruction(1, Instruction1.PING))
    ping_1[-1] ^= 0x01
    for packet, protocol, check in ((ping_2, 2, 'CRC'), (ping_1, 1, 'CHECKSUM')):
        text, _ = decode(read_trace(['1000 baud 1000000', f'1100 tx {packet.hex(" ")}'],
                                    'made.trace'), protocol=protocol)
        assert any(f'({check} WRONG: the servo will refuse it)' in line for line in text), text
