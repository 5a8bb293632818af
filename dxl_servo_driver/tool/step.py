"""
`dxl step`: a step of Goal Position, its response recorded at the bus's full rate, its metrics.

The servo is moved to --from (default: where it is), waits there until still, then Goal
Position jumps to --to and Present Position (with current and velocity) is read back to back for
--duration seconds: one read of the block from Realtime Tick to Present Position per sample,
each dated by the servo's Realtime Tick where the model has one (when the servo took it, not when
the answer reached the host), else by the host's clock at the request. From the positions:
rise time (10 % to 90 % of the step), overshoot (% of the step), settling time (the last entry
into the 2 % band) and steady-state error (goal minus the mean of the last tenth of the run).

Each `--gains p=..,i=..,d=..` set (Position P/I/D Gain, raw, as the manual's units) runs the
same step again with those gains; --png draws every run (matplotlib, Agg) over the goal with a
legend naming its gains and metrics; --csv writes every sample. The profile (velocity,
acceleration) is set to 0 for a true step. Whatever happens (an error, Ctrl-C), the gains,
profile, operating mode, goal and torque are restored as they were.
"""

import argparse
import csv
from dataclasses import dataclass, field
import math
import time
from typing import Dict, IO, List, Optional, Sequence, Tuple

from dxl_servo_driver.models.base import Item
from dxl_servo_driver.tool.common import add_command, EXIT_OUTPUT, EXIT_USAGE, ToolError
from dxl_servo_driver.tool.session import (
    add_bus_arguments, bus_session, connect, from_si, read_present, read_retried,
    retried, Saved, servo_ref, ServoLink, to_si, uninterrupted, write_retried)

GAIN_KEYS = {'p': 'position_p_gain', 'i': 'position_i_gain', 'd': 'position_d_gain'}
MODES = ('position', 'extended_position', 'current_based_position')
# Still: no velocity read for this long (the servo's own velocity filter reads 0 at rest).
STILL_S = 0.1
SETTLE_TIMEOUT_S = 5.0
TICK_MODULO = 32768   # Realtime Tick counts 0..32767 ms
SETTLING_BAND = 0.02
SAVED = ('torque_enable', 'operating_mode', 'position_p_gain', 'position_i_gain',
         'position_d_gain', 'profile_velocity', 'profile_acceleration', 'goal_position')
COLOURS = ('tab:blue', 'tab:orange', 'tab:green', 'tab:red', 'tab:purple', 'tab:brown')


@dataclass
class Sample:
    """One sample of the response: servo time from the step (s), host time, SI values."""

    t: float
    host_t: float
    position: float
    velocity: float
    current: float


@dataclass
class Metrics:
    """What one step response measured (None: not reached within the run)."""

    rise_s: Optional[float]
    overshoot_pct: float
    settling_s: Optional[float]
    steady_error: float   # goal minus the final position, in the position's unit (rad)

    def text(self) -> str:
        """Return the metrics as one line, for a person."""
        rise = 'n/a' if self.rise_s is None else f'{self.rise_s * 1000:.1f} ms'
        settle = 'n/a' if self.settling_s is None else f'{self.settling_s * 1000:.1f} ms'
        return (f'rise {rise}, overshoot {self.overshoot_pct:.1f} %, settling {settle}, '
                f'steady-state error {self.steady_error:+.4f} rad')


@dataclass
class Run:
    """One step: its gains, start and goal, samples and metrics."""

    label: str
    gains: Dict[str, int]
    start: float
    goal: float
    samples: List[Sample] = field(default_factory=list)
    metrics: Optional[Metrics] = None


def _crossing(samples: Sequence[Sample], level: float, start: float,
              goal: float) -> Optional[float]:
    """Return when the response first reaches level (0..1 of the step), interpolated."""
    span = goal - start
    previous: Optional[Tuple[float, float]] = None
    for sample in samples:
        fraction = (sample.position - start) / span
        if fraction >= level:
            if previous is None or fraction == previous[1]:
                return sample.t
            t0, f0 = previous
            return t0 + (level - f0) * (sample.t - t0) / (fraction - f0)
        previous = (sample.t, fraction)
    return None


def metrics(samples: Sequence[Sample], start: float, goal: float) -> Metrics:
    """Return the step metrics of samples (t from the step) from start toward goal."""
    span = goal - start
    if not samples or span == 0.0:
        raise ToolError('no step to measure: --from and --to are the same position', EXIT_USAGE)
    after = [sample for sample in samples if sample.t >= 0.0]
    low = _crossing(after, 0.1, start, goal)
    high = _crossing(after, 0.9, start, goal)
    rise = None if low is None or high is None else high - low
    peak = max((sample.position - start) / span for sample in after)
    overshoot = max(0.0, (peak - 1.0) * 100.0)
    settling: Optional[float] = None
    band = SETTLING_BAND * abs(span)
    for sample in after:
        if abs(sample.position - goal) > band:
            settling = None
        elif settling is None:
            settling = sample.t
    tail = after[int(len(after) * 0.9):] or after[-1:]
    final = sum(sample.position for sample in tail) / len(tail)
    return Metrics(rise, overshoot, settling, goal - final)


def parse_gains(text: str) -> Dict[str, int]:
    """Return {item name: raw gain} of 'p=900,i=0,d=100' (any subset); ToolError if malformed."""
    gains: Dict[str, int] = {}
    for part in text.split(','):
        key, sep, value = part.strip().partition('=')
        if not sep or key.strip().lower() not in GAIN_KEYS:
            raise ToolError(f'--gains {text!r}: each entry is p=N, i=N or d=N', EXIT_USAGE)
        try:
            gains[GAIN_KEYS[key.strip().lower()]] = int(value)
        except ValueError:
            raise ToolError(f'--gains {text!r}: {value!r} is not an integer', EXIT_USAGE) from None
    return gains


class Recorder:
    """Reads one servo's state block back to back, each sample dated by its tick if it has one."""

    def __init__(self, link: ServoLink) -> None:
        model = link.model
        self.link = link
        self.position = model.item('present_position')
        self.velocity = model.item('present_velocity')
        self.current: Optional[Item] = (model.item('present_current')
                                        if model.has('present_current') else None)
        self.tick: Optional[Item] = (model.item('realtime_tick') if model.has('realtime_tick')
                                     else None)
        wanted = [item for item in (self.position, self.velocity, self.current, self.tick)
                  if item is not None]
        self.address = min(item.address for item in wanted)
        self.length = max(item.address + item.size for item in wanted) - self.address
        self._tick_base: Optional[Tuple[int, int]] = None   # (last raw tick, turns of it)

    def _value(self, item: Optional[Item], data: bytes) -> float:
        if item is None:
            return math.nan
        offset = item.address - self.address
        return to_si(self.link.model, item, item.decode(data[offset:offset + item.size]))[0]

    def sample(self) -> Tuple[Sample, Optional[int]]:
        """Read one sample; return it (t: the unwrapped tick in s, or the host's) and its tick."""
        link = self.link
        data, sent_s = retried(lambda: link.bus.read_fresh(link.servo_id, self.address,
                                                           self.length))
        raw_tick: Optional[int] = None
        t = sent_s
        if self.tick is not None:
            offset = self.tick.address - self.address
            raw_tick = self.tick.decode(data[offset:offset + self.tick.size])
            t = self._unwrap(raw_tick) / 1000.0
        return Sample(t, sent_s, self._value(self.position, data),
                      self._value(self.velocity, data), self._value(self.current, data)), raw_tick

    def _unwrap(self, raw: int) -> int:
        if self._tick_base is None:
            self._tick_base = (raw, 0)
        last, turns = self._tick_base
        if raw < last:
            turns += 1
        self._tick_base = (raw, turns)
        return raw + turns * TICK_MODULO


def _settle(link: ServoLink, recorder: Recorder, goal: float) -> Sample:
    """Wait until the servo is still (no velocity for STILL_S); return the last sample."""
    deadline = time.monotonic() + SETTLE_TIMEOUT_S
    still_since: Optional[float] = None
    while True:
        sample = recorder.sample()[0]
        now = time.monotonic()
        if sample.velocity == 0.0:
            if still_since is None:
                still_since = now
            elif now - still_since >= STILL_S:
                return sample
        else:
            still_since = None
        if now > deadline:
            raise ToolError(f'id {link.servo_id} did not come to rest at {goal:+.3f} rad within '
                            f'{SETTLE_TIMEOUT_S:.0f} s (last read {sample.position:+.3f} rad, '
                            f'{sample.velocity:+.3f} rad/s)')


def step_once(link: ServoLink, run: Run, start_raw: int, goal_raw: int, duration_s: float) -> None:
    """Go to start_raw, settle, step to goal_raw and record duration_s of the response."""
    recorder = Recorder(link)
    for name, value in run.gains.items():
        write_retried(link, name, value)
    write_retried(link, 'goal_position', start_raw)
    before = _settle(link, recorder, run.start)
    run.start = before.position
    write_retried(link, 'goal_position', goal_raw)
    # Time zero: the last sample before the write (the write follows it within one read).
    zero_t = before.t
    end = time.monotonic() + duration_s
    samples = [Sample(0.0, before.host_t - before.host_t, before.position, before.velocity,
                      before.current)]
    while time.monotonic() < end:
        sample = recorder.sample()[0]
        sample.t -= zero_t
        sample.host_t -= before.host_t
        samples.append(sample)
    run.samples = samples
    run.metrics = metrics(samples, run.start, run.goal)


def _label(gains: Dict[str, int]) -> str:
    return ' '.join(f'{key}={gains[name]}' for key, name in GAIN_KEYS.items())


def draw(runs: Sequence[Run], path: str, title: str) -> None:
    """Draw every run over its goal into a PNG at path (matplotlib, Agg)."""
    import matplotlib
    matplotlib.use('Agg')
    from matplotlib import pyplot

    figure, (top, bottom) = pyplot.subplots(2, 1, figsize=(9, 7), sharex=True,
                                            gridspec_kw={'height_ratios': (3, 1)})
    goal = runs[0].goal
    end = max(sample.t for run in runs for sample in run.samples)
    top.step([min(0.0, runs[0].samples[0].t), 0.0, end], [runs[0].start, goal, goal],
             where='post', color='black', linestyle='--', linewidth=1.2, label='goal')
    for index, run in enumerate(runs):
        colour = COLOURS[index % len(COLOURS)]
        times = [sample.t for sample in run.samples]
        assert run.metrics is not None
        top.plot(times, [sample.position for sample in run.samples], color=colour,
                 linewidth=1.4, label=f'{run.label}: {run.metrics.text()}')
        bottom.plot(times, [sample.current for sample in run.samples], color=colour,
                    linewidth=1.0)
    band = SETTLING_BAND * abs(goal - runs[0].start)
    top.axhspan(goal - band, goal + band, color='grey', alpha=0.15, label='2 % band')
    top.set_ylabel('position (rad)')
    top.set_title(title)
    top.grid(True, alpha=0.3)
    top.legend(loc='lower right' if goal > runs[0].start else 'upper right', fontsize=7)
    bottom.set_ylabel('current (A)')
    bottom.set_xlabel('time from the step (s)')
    bottom.grid(True, alpha=0.3)
    figure.tight_layout()
    try:
        figure.savefig(path, dpi=110)
    except OSError as exc:
        raise ToolError(f'cannot write {path}: {exc.strerror or exc}', EXIT_OUTPUT) from exc
    finally:
        pyplot.close(figure)


def write_csv(runs: Sequence[Run], stream: IO[str]) -> None:
    """Write every sample of every run, one row each."""
    writer = csv.writer(stream)
    writer.writerow(('run', 'gains', 't_s', 'host_t_s', 'goal_rad', 'position_rad',
                     'velocity_rad_s', 'current_a'))
    for index, run in enumerate(runs):
        for sample in run.samples:
            goal = run.goal if sample.t >= 0.0 else run.start
            writer.writerow((index, _label(run.gains), f'{sample.t:.6f}', f'{sample.host_t:.6f}',
                             f'{goal:.6f}', f'{sample.position:.6f}', f'{sample.velocity:.6f}',
                             f'{sample.current:.6f}'))


def _open_output(path: Optional[str]) -> Optional[IO[str]]:
    if not path:
        return None
    try:
        return open(path, 'w', newline='', encoding='utf-8')
    except OSError as exc:
        raise ToolError(f'cannot write {path}: {exc.strerror or exc}', EXIT_OUTPUT) from exc


def _check_range(link: ServoLink, mode: str, raws: Sequence[Tuple[str, int]]) -> None:
    """Refuse a position outside the servo's position limits (position mode) or the table."""
    if mode == 'position' and link.model.has('max_position_limit'):
        low = read_retried(link, 'min_position_limit')
        high = read_retried(link, 'max_position_limit')
    else:
        item = link.item('goal_position')
        low, high = item.minimum, item.maximum
    for flag, raw in raws:
        if not low <= raw <= high:
            low_si = to_si(link.model, link.item('goal_position'), low)[0]
            high_si = to_si(link.model, link.item('goal_position'), high)[0]
            raise ToolError(f'{flag} is outside what {mode} mode reaches on id {link.servo_id} '
                            f'({low_si:+.3f} .. {high_si:+.3f} rad)', EXIT_USAGE)


def run(args: argparse.Namespace) -> int:
    """Run the steps; print their metrics; draw and write what was asked."""
    gain_sets = [parse_gains(text) for text in args.gains or ()]
    if args.duration <= 0.0 or args.duration > 60.0:
        raise ToolError('--duration must be in (0, 60] s', EXIT_USAGE)
    with bus_session(args) as bus:
        link = connect(bus, args.id)
        model = link.model
        if not model.has('goal_position') or args.mode not in model.modes:
            raise ToolError(f'{model.name} has no {args.mode} mode', EXIT_USAGE)
        goal_item = link.item('goal_position')
        saved = Saved(link, SAVED)
        try:
            return _steps(link, saved, goal_item, gain_sets, args)
        finally:
            with uninterrupted():
                saved.restore()


def _steps(link: ServoLink, saved: Saved, goal_item: Item, gain_sets: List[Dict[str, int]],
           args: argparse.Namespace) -> int:
    model = link.model
    mode_number = model.modes[args.mode]
    if saved.values.get('operating_mode') != mode_number:
        write_retried(link, 'torque_enable', 0)
        write_retried(link, 'operating_mode', mode_number)
    start_raw = (from_si(model, goal_item, args.start) if args.start is not None
                 else read_present(link))
    goal_raw = from_si(model, goal_item, args.to)
    _check_range(link, args.mode, (('--from', start_raw), ('--to', goal_raw)))
    if start_raw == goal_raw:
        raise ToolError('--from and --to are the same position', EXIT_USAGE)
    csv_file = _open_output(args.csv)
    try:
        for name in ('profile_velocity', 'profile_acceleration'):
            if model.has(name):
                write_retried(link, name, 0)
        write_retried(link, 'torque_enable', 1)
        own = {name: saved.values[name] for name in GAIN_KEYS.values() if name in saved.values}
        runs = [Run(f'{_label(own)} (as set)', own, to_si(model, goal_item, start_raw)[0],
                    to_si(model, goal_item, goal_raw)[0])]
        for gains in gain_sets:
            full = dict(own, **gains)
            runs.append(Run(_label(full), full, runs[0].start, runs[0].goal))
        print(f'id {link.servo_id} {model.name}: step {runs[0].start:+.4f} -> '
              f'{runs[0].goal:+.4f} rad in {args.mode} mode, {args.duration:g} s each, '
              f'{"Realtime Tick" if model.has("realtime_tick") else "host clock"} dating')
        for one in runs:
            step_once(link, one, start_raw, goal_raw, args.duration)
            assert one.metrics is not None
            rate = len(one.samples) / max(1e-9, one.samples[-1].host_t)
            print(f'{one.label}: {one.metrics.text()} ({len(one.samples)} samples, '
                  f'{rate:.0f}/s)', flush=True)
        if csv_file is not None:
            write_csv(runs, csv_file)
        if args.png:
            draw(runs, args.png, f'id {link.servo_id} {model.name}: step to {args.to:+.3f} rad '
                 f'at {link.bus.baud_bps} bps ({args.mode})')
            print(f'wrote {args.png}')
    finally:
        if csv_file is not None:
            csv_file.close()
    return 0


def register(subparsers: 'argparse._SubParsersAction[argparse.ArgumentParser]') -> None:
    """Add `dxl step`."""
    parser = add_command(
        subparsers, 'step', 'a step of goal position: response, rise/overshoot/settling, PNG',
        __doc__.strip().splitlines()[0],
        'dxl step 1 --port /dev/ttyUSB0 --baud 1000000 --from 0 --to 0.5 '
        '--gains p=400 p=1600,d=400 --png step.png',
        'dxl step shoulder --to 0.5 --png step.png --params my_arm.yaml   # port, baud: the '
        "file's")
    parser.add_argument('id', type=servo_ref, metavar='ID',
                        help="servo id (or, with --params, its joint's name)")
    parser.add_argument('--to', type=float, required=True, metavar='RAD',
                        help='goal of the step (rad, from the centre of the table)')
    parser.add_argument('--from', dest='start', type=float, metavar='RAD',
                        help='where the step starts (default: where the servo is)')
    parser.add_argument('--mode', choices=MODES, default='position',
                        help='operating mode of the step (default position)')
    parser.add_argument('--duration', type=float, default=1.0, metavar='S',
                        help='how long each response is recorded (default 1 s)')
    parser.add_argument('--gains', nargs='+', metavar='p=N,i=N,d=N',
                        help='more runs, each with these Position P/I/D Gains (raw); omitted '
                        'ones keep the value the servo has')
    parser.add_argument('--png', metavar='FILE', help='draw the runs into this PNG')
    parser.add_argument('--csv', metavar='FILE', help='write every sample to this CSV')
    add_bus_arguments(parser)
    parser.set_defaults(run=run)
