"""
What `scan` says: the line of each servo found, the line of each step, the progress line.

stdout gets one line per servo found (describe); stderr the steps and notes. Progress decides
how: on a terminal one progress line redrawn (baud k of n, the protocol, time elapsed, about
how long is left, servos found so far), elsewhere one line a step, as a log reads.
"""

import shutil
import threading
import time
from typing import Callable, Optional, Sequence, TextIO

from dxl_servo_driver import models
from dxl_servo_driver.bus import DEFAULT_PROTOCOL, FoundServo, Step
from dxl_servo_driver.models.names import OTHER_MODELS
from dxl_servo_driver.protocol import MAX_ID

UNKNOWN_MODEL = 'unknown model'
# How often the progress line on a terminal is redrawn (its clock and estimate move on).
REDRAW_S = 0.25
BAR_CELLS = 10


def plural(count: int, word: str) -> str:
    """Return a count and its word: '1 servo', '2 servos'."""
    return f'{count} {word}' + ('' if count == 1 else 's')


def model_name(model_number: int) -> str:
    """Return a model number's name (XL430-W250; unsupported ones say so), or 'unknown model'."""
    if model_number in models.SUPPORTED:
        return models.model_for(model_number).name
    other = OTHER_MODELS.get(model_number)
    return f'{other[0]}, not supported' if other is not None else UNKNOWN_MODEL


def describe(servo: FoundServo) -> str:
    """Return the one-line description of a servo that scan prints."""
    parts = [f'id {servo.servo_id}: model {servo.model_number} ({model_name(servo.model_number)})']
    fw = servo.firmware_version
    parts.append(f'firmware {fw}' if fw is not None else 'firmware ? (no reply)')
    parts.append(f'{servo.baud_bps} bps')
    if servo.protocol != DEFAULT_PROTOCOL:
        parts.append(f'Protocol {servo.protocol:.1f}')
    if not servo.known_model:
        parts.append('mode not read (unknown control table)')
        parts.append('hardware errors: not read')
    else:
        raw = servo.operating_mode_raw
        if raw is None:
            parts.append('mode ? (no reply)')
        else:
            parts.append(f'mode {servo.operating_mode or f"{raw} (not a valid mode)"}')
        errors = servo.hardware_errors
        status = servo.hardware_error_status
        if not servo.table.has('hardware_error_status'):
            parts.append('hardware errors: not in its table (each reply says them)')
        elif errors is None or status is None:
            parts.append('hardware errors: ? (no reply)')
        elif status == 0:
            parts.append('hardware errors: none')
        else:
            # Bits the manual does not name are shown as the raw value only.
            parts.append(f'hardware errors: {", ".join(errors) or "unnamed bits"} '
                         f'(0x{status:02x})')
    return ', '.join(parts)


def step_line(step: Step, ids: Optional[Sequence[int]]) -> str:
    """Return the line a step starts with (one a step where stderr is no terminal)."""
    if not step.framer.broadcast_ping:   # a sweep of the ids, in the protocol it names
        count = MAX_ID + 1 if ids is None else len(ids)
        return (f'scanning {step.baud_bps} bps, Protocol {step.protocol:.1f} (ping of {count} '
                'id(s)) ...')
    how = 'broadcast ping' if ids is None else f'ping of {len(ids)} id(s)'
    return f'scanning {step.baud_bps} bps ({how}) ...'


class Progress:
    """
    What a scan says on stderr while it runs.

    Not a terminal: one line a step (`scanning 57600 bps (broadcast ping) ...`), as a log
    reads. A terminal: one line redrawn (a bar; baud k of n, the protocol, the time elapsed,
    about how long is left, the servos found so far), every REDRAW_S and at every step; other
    lines (notes, a servo found on stdout) are printed above it. The time left is the plan's
    estimate of the steps still to run (where nobody answers), the current one's part of it
    counted down.
    """

    def __init__(self, err: TextIO, out: TextIO, steps: Sequence[Step], terminal: bool,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._err = err
        self._out = out
        self._steps = list(steps)
        self._bauds = list(dict.fromkeys(step.baud_bps for step in steps))
        self.terminal = terminal
        self._clock = clock
        self._begun_s = clock()
        self._step_s = self._begun_s
        self._index = -1
        self._found = 0
        self._shown = False
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._ticker: Optional[threading.Thread] = None
        if terminal:
            self._ticker = threading.Thread(target=self._tick, name='scan_progress',
                                            daemon=True)
            self._ticker.start()

    def line(self, text: str) -> None:
        """Say one line on stderr (above the progress line on a terminal)."""
        with self._lock:
            self._clear()
            print(text, file=self._err, flush=True)
            self._draw()

    def step(self, index: int, step: Step, text: str) -> None:
        """Begin a step: its line (not a terminal), or the progress line redrawn."""
        with self._lock:
            self._index = index
            self._step_s = self._clock()
            if not self.terminal:
                print(text, file=self._err, flush=True)
            self._draw()

    def found(self, text: str) -> None:
        """Count a servo found and print its line on stdout."""
        with self._lock:
            self._found += 1
            self._clear()
            print(text, file=self._out, flush=True)
            self._draw()

    def close(self) -> None:
        """Stop redrawing and take the progress line away."""
        self._stop.set()
        if self._ticker is not None:
            self._ticker.join()
        with self._lock:
            self._clear()

    def left_s(self) -> float:
        """Return about how long the steps not yet done take (the current one counted down)."""
        if self._index < 0:
            return sum(step.estimate_s for step in self._steps)
        current = self._steps[self._index].estimate_s - (self._clock() - self._step_s)
        return max(0.0, current) + sum(step.estimate_s for step in self._steps[self._index + 1:])

    def text(self) -> str:
        """Return the progress line as it is now."""
        elapsed_s = self._clock() - self._begun_s
        left_s = self.left_s()
        done = elapsed_s / (elapsed_s + left_s) if elapsed_s + left_s > 0.0 else 1.0
        cells = min(BAR_CELLS, int(done * BAR_CELLS))
        bar = '#' * cells + '.' * (BAR_CELLS - cells)
        if self._index < 0:
            where = 'starting'
        else:
            step = self._steps[self._index]
            where = (f'baud {self._bauds.index(step.baud_bps) + 1} of {len(self._bauds)}: '
                     f'{step.baud_bps} bps, P{step.protocol:.1f}')
        # 80 columns hold it at any baud: the line is cut at the terminal's width.
        return (f'[{bar}] {where} | {elapsed_s:.0f} s, {left_s:.0f} s left | '
                f'{self._found} found')

    def _tick(self) -> None:
        while not self._stop.wait(REDRAW_S):
            with self._lock:
                self._draw()

    def _draw(self) -> None:
        if not self.terminal or self._stop.is_set():
            return
        width = shutil.get_terminal_size((80, 24)).columns
        self._err.write('\r\x1b[K' + self.text()[:max(1, width - 1)])
        self._err.flush()
        self._shown = True

    def _clear(self) -> None:
        if self._shown:
            self._err.write('\r\x1b[K')
            self._err.flush()
            self._shown = False
