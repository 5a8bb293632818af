"""
`make bench`: the driver against the stock SDK on a simulated bus paced like the real wire.

For N = 1, 6, 12, 24 servos at 1 and 4 Mbps (Return Delay Time 0), one `virtual_bus --timing
wire` serves five variants in turn, interleaved round by round so that machine noise hits all
alike:
- sdk_baseline: the plain dynamixel_sdk GroupSyncRead + GroupSyncWrite loop (worker process);
- bus: the node's cycle loop (driver/loop.CycleLoop) without ROS (worker process);
- node: the full node (its installed executable), driven through its lifecycle, joint_states
  counted by a subscriber here, commands published here and seen on the wire by the simulator;
- bus_fast, node_fast: the same two with Fast Sync Read (read_mode fast_sync).
CPU per cycle comes from each process's own accounting (process_time, /proc/PID/stat for the
node). The bus limit of each variant comes from the bytes it puts on the wire. The simulator's
own pacing (how late it delivered replies) is reported so that a slow simulator is not taken
for a slow driver; a case where it was late by more than a tenth of the bus time is marked as
paced by the simulator. A cycle counts only when every servo's sample came back good; the
others are counted apart, as failed.

Then the speed cases: the node on recorded replies (ceiling_node.py: an infinitely fast bus,
no simulator beside it) at N = 12, 24, 50; what `top` shows of the node at loop_rate 100 with 6
servos at 1 Mbps, split by thread; 12 servos behind a 1 ms adapter; and the cycle in one
process on recorded replies, hot and cold, with the memory blocks it leaves (cycle_cost.py);
a leader and a follower node, from a leader's horn turned to the follower's wire at 100, 200
and 500 Hz (teleop_latency.py; alone: `python bench/run_bench.py teleop`).
Results: bench-results/bench.json, bench-results/bench.png, a table and the targets on stdout.

This module runs them and checks the targets; the cases are in bus_cases.py (the table) and
speed_cases.py, what they share (the simulated bus, the node under test) in harness.py.
"""

import json
import os
import pathlib
import sys
import tempfile
from typing import Any, Dict, List, Optional, Tuple

# The package of this source tree, not an installed one.
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent))

from bus_cases import (  # noqa: E402 - after the path set-up above
    BAUDS, COUNTS, plot, run_case_retried, table)
from harness import machine, own_dds_domain, ROOT  # noqa: E402
from speed_cases import (  # noqa: E402
    crc_comparison, extra_lines, protocol1_case, protocol1_line, scale, speed_cases)
from teleop_latency import lines as teleop_lines, teleop_case  # noqa: E402


def per_added_servo_us(rows: List[Dict[str, Any]], first: int, last: int,
                       key: str = 'cpu_per_cycle_us') -> Optional[float]:
    """Return the CPU each added servo costs a cycle between two N of these rows."""
    at = {row['n']: row[key] for row in rows if row.get(key) is not None}
    if first not in at or last not in at:
        return None
    return round((at[last] - at[first]) / (last - first), 2)


def targets(rows: List[Dict[str, Any]], extra: Dict[str, Any]) -> List[str]:
    """Check one run's figures against the targets docs/performance.md sets."""
    at = {row['variant']: row for row in rows if row['n'] == 12 and row['baud'] == 4_000_000}
    if not {'node', 'sdk_baseline'} <= set(at):
        return ['N = 12 at 4 Mbps was not measured']
    node, sdk = at['node'], at['sdk_baseline']
    period_ms = 1e3 / node['rate_hz'] if node['rate_hz'] else float('inf')
    bus_ms = 1e3 / node['bus_limit_hz']
    checks: List[Tuple[str, Optional[bool], Any]] = [
        ('node cpu <= 0.25 x bus time (N = 12, 4 Mbps)',
         node['cpu_per_cycle_over_bus_time'] <= 0.25, node['cpu_per_cycle_over_bus_time']),
        ('node rate_ratio >= 0.9 (N = 12, 4 Mbps)',
         None if node['sim_paced'] else node['rate_ratio'] >= 0.9,
         f'{node["rate_ratio"]}' + (' (the simulator set the pace)' if node['sim_paced']
                                    else '')),
        (f'node latency p99 <= period + bus time ({period_ms + bus_ms:.2f} ms)',
         node['command_latency_p99_ms'] is not None
         and node['command_latency_p99_ms'] <= period_ms + bus_ms,
         node['command_latency_p99_ms']),
        ('node faster than sdk_baseline', node['rate_hz'] > sdk['rate_hz'],
         f'{node["rate_hz"]} vs {sdk["rate_hz"]} Hz'),
    ]
    node_rows = [row for row in rows if row['variant'] == 'node' and row['baud'] == 4_000_000]
    added = per_added_servo_us(node_rows, 12, 24)
    if added is not None:
        checks.append(('node cpu per added servo <= 5 us (N = 24 against 12, 4 Mbps)',
                       added <= 5.0, f'{added} us'))
    ceiling = extra.get('ceiling') or []
    for last in (24, 50):
        added = per_added_servo_us(ceiling, 12, last)
        if added is not None:
            checks.append((f'ceiling cpu per added servo <= 5 us (N = {last} against 12)',
                           added <= 5.0, f'{added} us'))
    at_12 = [row for row in ceiling if row['n'] == 12]
    if at_12:
        checks.append(('ceiling >= 3 x the 4 Mbps bus limit (N = 12)',
                       at_12[0]['over_4mbps_limit'] >= 3.0,
                       f'{at_12[0]["rate_hz"]} Hz, {at_12[0]["over_4mbps_limit"]} x'))
    latency = extra.get('adapter_latency')
    if latency:
        checks.append(('behind a 1 ms adapter >= 0.95 of what it allows',
                       latency['ratio'] >= 0.95, latency['ratio']))
    top = extra.get('top')
    if top:
        floor = top.get('floor') or {}
        checks.append(('top: loop_rate 100, 6 servos at 1 Mbps <= 2 % of a core',
                       top['cpu_percent'] <= 2.0, f'{top["cpu_percent"]} %'
                       + (f' (the floor: {floor["cpu_percent"]} %)' if floor else '')))
    failed = sum(row['failed_cycles'] for row in rows)
    checks.append(('0 failed cycles in every fault-free case', failed == 0,
                   ', '.join(f'{row["variant"]} N={row["n"]} {row["baud"]}: '
                             f'{row["failed_cycles"]}' for row in rows
                             if row['failed_cycles']) or '0'))
    above = [row for row in rows if row['rate_ratio'] > 1.0]
    checks.append(('no rate above its wire limit', not above,
                   ', '.join(f'{row["variant"]} N={row["n"]}: {row["rate_ratio"]}'
                             for row in above) or 'none'))
    word = {True: 'met   ', False: 'MISSED', None: 'n/a   '}
    return [f'{word[ok]}  {name}: {value}' for name, ok, value in checks]


def main() -> int:
    """Run every case, write the JSON and the plot, print the table."""
    own_dds_domain()
    out_dir = ROOT / 'bench-results'
    out_dir.mkdir(exist_ok=True)
    if sys.argv[1:] == ['scale']:
        return main_scale(out_dir)
    if sys.argv[1:] == ['teleop']:
        with tempfile.TemporaryDirectory(prefix='dxl-bench-') as tmp:
            print('\n'.join(teleop_lines(teleop_case(pathlib.Path(tmp)))))
        return 0
    if sys.argv[1:] == ['protocol1']:
        with tempfile.TemporaryDirectory(prefix='dxl-bench-') as tmp:
            print(protocol1_line(protocol1_case(pathlib.Path(tmp))))
        return 0
    counts = [int(c) for c in os.environ.get('BENCH_COUNTS', ' '.join(map(str, COUNTS))).split()]
    bauds = [int(b) for b in os.environ.get('BENCH_BAUDS', ' '.join(map(str, BAUDS))).split()]
    rows: List[Dict[str, Any]] = []
    failures: List[str] = []
    print(f'bench: ROS_DOMAIN_ID {os.environ["ROS_DOMAIN_ID"]}, localhost discovery',
          file=sys.stderr)
    with tempfile.TemporaryDirectory(prefix='dxl-bench-') as tmp:
        workdir = pathlib.Path(tmp)
        for baud in bauds:
            for n in counts:
                print(f'bench: N={n} at {baud} bps ...', file=sys.stderr, flush=True)
                rows.extend(run_case_retried(n, baud, workdir, failures))
        print('bench: Protocol 1.0, N=12 AX-12A at 1000000 bps ...', file=sys.stderr, flush=True)
        try:
            p1: Optional[Dict[str, Any]] = protocol1_case(workdir)
        except Exception as exc:  # noqa: B902 - one case must not end the whole benchmark
            p1 = None
            failures.append(f'bench: Protocol 1.0 case failed: {exc}')
        extra = speed_cases(workdir, failures)
    crc = crc_comparison()
    result = {'machine': machine(), 'cases': rows, 'crc': crc, 'protocol1': p1, **extra}
    (out_dir / 'bench.json').write_text(json.dumps(result, indent=1) + '\n')
    plot(rows, out_dir / 'bench.png')
    print(table(rows))
    print()
    for line in extra_lines(extra):
        print(line)
    if p1 is not None:
        print(protocol1_line(p1))
    print(f'CRC of one cycle\'s replies (N = {crc["n"]}): {crc["implementation"]} '
          f'{crc["compiled_us_per_cycle"]} us, pure Python {crc["python_us_per_cycle"]} us '
          f'(ratio {crc["ratio"]})')
    print()
    for line in targets(rows, extra):
        print(line)
    for line in failures:
        print(line)
    print(f'\nwritten: {out_dir / "bench.json"}, {out_dir / "bench.png"}')
    return 0


def main_scale(out_dir: pathlib.Path) -> int:
    """Run `make bench-scale` (N = 50, two buses at once, a 1 ms adapter): bench-scale.json."""
    failures: List[str] = []
    print(f'bench: ROS_DOMAIN_ID {os.environ["ROS_DOMAIN_ID"]}, localhost discovery',
          file=sys.stderr)
    with tempfile.TemporaryDirectory(prefix='dxl-bench-') as tmp:
        result = scale(pathlib.Path(tmp), failures)
    result['machine'] = machine()
    (out_dir / 'bench-scale.json').write_text(json.dumps(result, indent=1) + '\n')
    print(table(result['n50']))
    print()
    for row in result['two_buses']:
        print(f'{row["case"]}: N={row["n"]} at {row["baud"]} bps: alone {row["alone_hz"]} Hz, '
              f'together {row["together_hz"]} Hz ({row["together_over_alone"]} of alone; '
              f'bus limit {row["bus_limit_hz"]} Hz)')
    latency = result['adapter_latency']
    print(f'{latency["case"]}: N={latency["n"]} at {latency["baud"]} bps: {latency["rate_hz"]} Hz '
          f'of the {latency["allowed_hz"]} Hz it allows ({latency["ratio"]})')
    for line in failures:
        print(line)
    print(f'\nwritten: {out_dir / "bench-scale.json"}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
