"""
The driver's cycle in this process on recorded replies: its CPU, its objects, cold and hot.

`python bench/cycle_cost.py` prints, for N XM430s on a ReplayPort (sim/replay.py: every cycle
read answered at once from a record), the node's cycle (driver/loop.CycleLoop, one whole cycle
a call as its timer driver runs it) plus the joint_states bytes as the node makes them, without
ROS:
- CPU per cycle back to back (hot) and with a 10 ms sleep between cycles (cold, as at
  loop_rate 100: the same code run after the caches were taken by others);
- the Python memory blocks alive after 1,000 cycles against before (sys.getallocatedblocks)
  and the most memory the cycles held above that meanwhile (tracemalloc's peak): what a cycle
  leaves behind, and what it holds while it runs.
"""

import gc
import pathlib
import sys
import time
import tracemalloc
from typing import Any, Callable, Dict, List

if __name__ == '__main__':   # run alone: the package of this source tree, as run_bench.py
    sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent))

from ceiling_node import replay_transport  # noqa: E402 - after the path set-up above
from dxl_servo_driver.config import validate  # noqa: E402
from dxl_servo_driver.driver.loop import CycleLoop, PrintLog  # noqa: E402
from dxl_servo_driver.driver.manager import Manager  # noqa: E402


def replay_manager(n: int, read_mode: str = 'sync') -> Manager:
    """Return an active Manager of n XM430s on recorded replies (4 Mbps, as fast as it can)."""
    params: Dict[str, Any] = {
        'port': 'sim', 'baud_rate': 4_000_000, 'latency_timer': 0.0, 'read_mode': read_mode,
        'loop_rate': 10000.0, 'joints': [f'j{i}' for i in range(1, n + 1)]}
    for i in range(1, n + 1):
        params[f'j{i}.id'] = i
        params[f'j{i}.operating_mode'] = 'position'
    manager = Manager(validate(params), info=lambda _: None, warn=lambda _: None,
                      port_factory=replay_transport)
    manager.configure()
    manager.activate()
    return manager


class HandTimer:
    """The loop's timer (driver/loop.Timers), stepped by hand: `tick` runs one cycle."""

    def __init__(self) -> None:
        self.tick: Callable[[], None] = lambda: None

    def create_timer(self, period_s: float, callback: Callable[[], None]) -> Any:
        """Keep the loop's cycle for the caller to run."""
        self.tick = callback
        return callback

    def destroy_timer(self, timer: Any) -> None:
        """Run nothing more."""
        self.tick = lambda: None


def cycle_function(manager: Manager) -> Callable[[], None]:
    """
    Return one cycle as the node runs it: read, write, the joint_states bytes.

    The node's loop (driver/loop.CycleLoop) with its timer driver, one whole cycle a call.
    """
    from dxl_servo_driver.ros.messages import JointTable   # rclpy: only when measured
    table = JointTable(manager.joints)
    table.serialize = True
    timer = HandTimer()
    loop = CycleLoop(lambda: manager, manager.config.loop_rate,
                     lambda stamp_ns, read_ok: table.message(stamp_ns), PrintLog(verbose=False),
                     timers=timer)
    loop.start('timer', manager.bus_budget().cycle_time_s)
    return timer.tick


def cpu_per_cycle_us(cycle: Callable[[], None], cycles: int, gap_s: float = 0.0,
                     rounds: int = 3) -> float:
    """Return the least CPU per cycle over rounds (gap_s of sleep between cycles)."""
    best = float('inf')
    for _ in range(rounds):
        start = time.process_time()
        for _ in range(cycles):
            cycle()
            if gap_s:
                time.sleep(gap_s)
        best = min(best, (time.process_time() - start) / cycles)
    return best * 1e6


def objects(cycle: Callable[[], None], cycles: int = 1000) -> Dict[str, float]:
    """Return blocks and bytes left after cycles against before, and the bytes held at most."""
    tracemalloc.start()
    for _ in range(cycles):
        cycle()   # warm, traced: caches filled, throttles and records made
    gc.collect()
    blocks0 = sys.getallocatedblocks()
    base, _ = tracemalloc.get_traced_memory()
    tracemalloc.reset_peak()
    for _ in range(cycles):
        cycle()
    _, peak = tracemalloc.get_traced_memory()
    gc.collect()
    current, _ = tracemalloc.get_traced_memory()
    left = sys.getallocatedblocks() - blocks0
    tracemalloc.stop()
    return {'cycles': cycles, 'blocks_left': left, 'bytes_left': current - base,
            'peak_bytes_held': peak - base}


def measure(counts: List[int] = [12, 24, 50]) -> Dict[str, Any]:
    """Measure every N: hot and cold CPU per cycle, sync and fast; objects at the first N."""
    rows = []
    result: Dict[str, Any] = {}
    for n in counts:
        for read_mode in ('sync', 'fast_sync'):
            manager = replay_manager(n, read_mode)
            try:
                cycle = cycle_function(manager)
                for _ in range(300):
                    cycle()
                row = {'n': n, 'read_mode': read_mode,
                       'hot_us': round(cpu_per_cycle_us(cycle, 3000), 1),
                       'cold_us': round(cpu_per_cycle_us(cycle, 150, 0.01, 2), 1),
                       'fresh': sum(servo.fresh for servo in manager.joints)}
                if n == counts[0] and read_mode == 'sync':
                    result['objects'] = objects(cycle)
            finally:
                manager.deactivate()
                manager.close()
            rows.append(row)
    result['rows'] = rows
    hot = {row['n']: row['hot_us'] for row in rows if row['read_mode'] == 'sync'}
    if len(counts) > 1:
        first, last = counts[0], counts[-1]
        result['us_per_added_servo'] = round((hot[last] - hot[first]) / (last - first), 2)
    return result


def lines(result: Dict[str, Any]) -> List[str]:
    """Return the figures as text."""
    out = [f'{"N":>3} {"read":<9} {"hot us":>7} {"cold us":>8}  (CPU per cycle, in process, '
           'recorded replies)']
    for row in result['rows']:
        out.append(f'{row["n"]:>3} {row["read_mode"]:<9} {row["hot_us"]:>7} {row["cold_us"]:>8}')
    if 'us_per_added_servo' in result:
        out.append(f'each added servo: {result["us_per_added_servo"]} us per cycle (hot, sync)')
    if 'objects' in result:
        o = result['objects']
        out.append(f'after {o["cycles"]} cycles: {o["blocks_left"]} memory blocks more than '
                   f'before ({o["bytes_left"]} bytes traced); at most {o["peak_bytes_held"]} '
                   'bytes held above that while cycling')
    return out


if __name__ == '__main__':
    figures = measure()
    if sys.argv[1:] == ['--json']:
        import json
        print(json.dumps(figures))
    else:
        print('\n'.join(lines(figures)))
