"""
The table of `make bench`: five variants on one simulated bus, interleaved round by round.

For N servos at a baud rate, one `virtual_bus --timing wire` serves the sdk_baseline and bus
workers (bench/workers.py, a process each) and two nodes (node, node_fast), in turn; run_case
turns what each did into a row (rate, bus limit, ratio, CPU per cycle, latency, failed cycles,
the simulator's pacing), table() and plot() show the rows.
"""

import json
import pathlib
import statistics
import subprocess
import sys
from typing import Any, Dict, List, Tuple

from dxl_servo_driver.driver import state_block
from dxl_servo_driver.protocol import BITS_PER_BYTE
from harness import (
    HEALTH_RATE_HZ, NAMESPACE, NodeUnderTest, percentile, ROOT, ROUNDS, SECONDS, VirtualBus,
    WRITE_BYTES)

BAUDS = (1_000_000, 4_000_000)
COUNTS = (1, 6, 12, 24)
VARIANTS = ('sdk_baseline', 'bus', 'node', 'bus_fast', 'node_fast')
FAST_VARIANTS = ('bus_fast', 'node_fast')   # read_mode fast_sync: one status for all servos
SDK_READ_BYTES = 10     # present_current + present_velocity + present_position
SIM_PACED_SHARE = 0.1   # simulator late (p99) by more than this share of the bus time: its pace


def run_worker(variant: str, n: int, baud: int, link: str) -> Dict[str, float]:
    """Run the sdk or bus loop in its own process."""
    name = {'sdk_baseline': 'sdk', 'bus': 'bus', 'bus_fast': 'bus_fast'}[variant]
    out = subprocess.run(
        [sys.executable, str(ROOT / 'bench' / 'workers.py'), name, str(n), str(baud), link,
         str(SECONDS)], capture_output=True, text=True, cwd=ROOT, timeout=60)
    if out.returncode != 0:
        raise RuntimeError(f'{variant} worker failed: {out.stderr.strip()[-500:]}')
    return json.loads(out.stdout.strip().splitlines()[-1])


def wire_bytes(variant: str, n: int, rate_hz: float, writes_per_cycle: float) -> float:
    """Return the average bytes one cycle of a variant puts on the wire."""
    if variant == 'sdk_baseline':
        return (state_block.sync_read_bytes(n, SDK_READ_BYTES)
                + state_block.sync_write_bytes(n, WRITE_BYTES))
    block = state_block.BLOCK_SHAPE
    # Every read of the node's cycle carries the tick (each sample is dated).
    if variant in FAST_VARIANTS:
        read = state_block.fast_sync_read_bytes(n, block.tagged_size)
    else:
        read = state_block.sync_read_bytes(n, block.tagged_size)
    if variant in ('bus', 'bus_fast'):
        return read + state_block.sync_write_bytes(n, WRITE_BYTES)
    # The node reads the whole block HEALTH_RATE_HZ times a second and writes only when a
    # command arrived.
    full_share = min(1.0, HEALTH_RATE_HZ / rate_hz) if rate_hz else 0.0
    extra = full_share * n * (block.size - block.tagged_size)
    return read + extra + writes_per_cycle * state_block.sync_write_bytes(n, WRITE_BYTES)


def command_latencies(published: List[Tuple[float, int]],
                      seen: List[Tuple[float, int, int]]) -> List[float]:
    """Return publication-to-wire latencies (s) of the commands the simulator saw."""
    first_seen: Dict[int, float] = {}
    for t, servo_id, value in seen:
        if servo_id == 1 and value not in first_seen:
            first_seen[value] = t
    latencies = []
    for t_pub, raw in published:
        t_seen = first_seen.get(raw)
        if t_seen is not None and t_seen >= t_pub:
            latencies.append(t_seen - t_pub)
    return latencies


def run_case_retried(n: int, baud: int, workdir: pathlib.Path,
                     failures: List[str]) -> List[Dict[str, Any]]:
    """Run a case; once more if it fails (and say so); never abort the run for one case."""
    for attempt in (1, 2):
        try:
            return run_case(n, baud, workdir)
        except Exception as exc:  # noqa: B902 - one case must not end the whole benchmark
            line = f'bench: N={n} at {baud} bps failed (attempt {attempt} of 2): {exc}'
            print(line, file=sys.stderr, flush=True)
            failures.append(line)
    return []


def run_case(n: int, baud: int, workdir: pathlib.Path) -> List[Dict[str, Any]]:
    """Measure the three variants on one simulated bus."""
    bus = VirtualBus(n, baud, workdir)
    nodes: Dict[str, NodeUnderTest] = {}
    samples: Dict[str, List[Dict[str, Any]]] = {variant: [] for variant in VARIANTS}
    try:
        nodes['node'] = NodeUnderTest(n, baud, bus.link, workdir)
        nodes['node_fast'] = NodeUnderTest(n, baud, bus.link, workdir, f'{NAMESPACE}_fast',
                                           'fast_sync')
        for round_index in range(ROUNDS):
            shift = round_index % len(VARIANTS)
            for variant in VARIANTS[shift:] + VARIANTS[:shift]:
                if variant in nodes:
                    samples[variant].append(nodes[variant].measure())
                else:
                    samples[variant].append(run_worker(variant, n, baud, bus.link))
        pacing = bus.pacing()
        seen = bus.goals()
    finally:
        for node in nodes.values():
            node.close()
        bus.close()
    rows = []
    for variant in VARIANTS:
        runs = samples[variant]
        cycles = sum(run['cycles'] for run in runs)
        wall = sum(run['wall_s'] for run in runs)
        cpu = sum(run['cpu_s'] for run in runs)
        rate = cycles / wall if wall else 0.0
        writes_per_cycle = 1.0
        latencies: List[float] = []
        if variant in nodes:
            writes = 0
            for run in runs:
                start, end = run['window']
                # Both nodes publish the same goal values: only this run's own goals count.
                own = [row for row in seen if start <= row[0] <= end + 0.1]
                writes += len({t for t, servo_id, _ in own if servo_id == 1 and t <= end})
                latencies += command_latencies(run['published'], own)
            writes_per_cycle = writes / cycles if cycles else 0.0
        per_cycle_bytes = wire_bytes(variant, n, rate, writes_per_cycle)
        bus_time_s = per_cycle_bytes * BITS_PER_BYTE / baud
        row: Dict[str, Any] = {
            'n': n, 'baud': baud, 'variant': variant,
            'rate_hz': round(rate, 1),
            'bus_limit_hz': round(1.0 / bus_time_s, 1),
            'rate_ratio': round(rate * bus_time_s, 3),
            'cpu_per_cycle_over_bus_time':
                round((cpu / cycles) / bus_time_s, 3) if cycles else None,
            'cpu_per_cycle_us': round(cpu / cycles * 1e6, 1) if cycles else None,
            'bytes_per_cycle': round(per_cycle_bytes, 1),
            'cycles': cycles,
            # Cycles that did not read every servo well (not counted in rate_hz); a node's:
            # joint_states that lacked a joint (one with none is not published at all).
            'failed_cycles': sum(run['failures'] for run in runs),
            # The workers say why: samples missing at the deadline, or refused as stale.
            'missing_samples': sum(run.get('missing_samples', 0) for run in runs),
            'stale_samples': sum(run.get('stale_samples', 0) for run in runs),
            'slack_ms_at_end': [run['slack_ms'] for run in runs if 'slack_ms' in run],
            'sim_late_p50_us': pacing.get('late_p50_us'),
            'sim_late_p99_us': pacing.get('late_p99_us'),
            # The simulator set the pace: its replies were late (p99) by more than a tenth of
            # the cycle's wire time, so the rate says more of it than of the driver.
            'sim_paced': (pacing.get('late_p99_us') or 0.0) > SIM_PACED_SHARE * bus_time_s * 1e6,
        }
        if variant in nodes:
            row['writes_per_cycle'] = round(writes_per_cycle, 3)
            row['commands_seen'] = len(latencies)
            if latencies:
                row['command_latency_p50_ms'] = round(statistics.median(latencies) * 1e3, 3)
                row['command_latency_p99_ms'] = round(percentile(latencies, 0.99) * 1e3, 3)
            else:
                row['command_latency_p50_ms'] = row['command_latency_p99_ms'] = None
        rows.append(row)
    return rows


def table(rows: List[Dict[str, Any]]) -> str:
    """Format the results as a text table."""
    head = (f'{"baud":>8} {"N":>3} {"variant":<13} {"rate Hz":>8} {"limit Hz":>9} '
            f'{"ratio":>6} {"cpu/bus":>8} {"cpu us":>7} {"lat p50":>8} {"lat p99":>8} '
            f'{"sim p99us":>9} {"failed":>6} {"paced":>5}')
    lines = [head, '-' * len(head)]
    for row in rows:
        p50 = row.get('command_latency_p50_ms')
        p99 = row.get('command_latency_p99_ms')
        lines.append(
            f'{row["baud"]:>8} {row["n"]:>3} {row["variant"]:<13} {row["rate_hz"]:>8.0f} '
            f'{row["bus_limit_hz"]:>9.0f} {row["rate_ratio"]:>6.2f} '
            f'{row["cpu_per_cycle_over_bus_time"]:>8.2f} {row["cpu_per_cycle_us"]:>7.0f} '
            f'{(f"{p50:.2f}" if p50 is not None else "-"):>8} '
            f'{(f"{p99:.2f}" if p99 is not None else "-"):>8} '
            f'{row["sim_late_p99_us"] or 0:>9.0f} {row["failed_cycles"]:>6} '
            f'{"sim" if row.get("sim_paced") else "":>5}')
    return '\n'.join(lines)


def plot(rows: List[Dict[str, Any]], path: pathlib.Path) -> None:
    """Draw rate ratio and CPU ratio against N for each baud and variant."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    figure, axes = plt.subplots(2, len(BAUDS), figsize=(11, 7), sharex=True)
    for column, baud in enumerate(BAUDS):
        for variant in VARIANTS:
            points = sorted((r['n'], r['rate_ratio'], r['cpu_per_cycle_over_bus_time'])
                            for r in rows if r['baud'] == baud and r['variant'] == variant)
            if not points:
                continue
            ns = [p[0] for p in points]
            axes[0][column].plot(ns, [p[1] for p in points], marker='o', label=variant)
            axes[1][column].plot(ns, [p[2] for p in points], marker='o', label=variant)
        axes[0][column].set_title(f'{baud / 1e6:g} Mbps, Return Delay Time 0')
        axes[0][column].set_ylabel('rate / bus limit')
        axes[0][column].set_ylim(0, 1.1)
        axes[0][column].axhline(1.0, color='grey', linewidth=0.5)
        axes[1][column].set_ylabel('CPU per cycle / bus time')
        axes[1][column].set_xlabel('servos on the bus (N)')
        axes[1][column].set_xticks(list(COUNTS))
        axes[0][column].legend()
    figure.suptitle('dxl_servo_driver vs dynamixel_sdk on virtual_bus --timing wire')
    figure.tight_layout()
    figure.savefig(path, dpi=90)
    plt.close(figure)
